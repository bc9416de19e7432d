"""Microfacet distributions of Walter et al. 2007, section 5.2 (eqs 24-36).

Every distribution is parameterized by its width α (Walter's α_b for Beckmann, α_g for GGX).
Phong is parameterized by the same α through Walter's recommended mapping α_p = 2 α⁻² - 2
(eq. 30 note), so all distributions share one roughness axis.

Functions take microfacet normals ``m`` that need not be normalized: D is written as a
degree-0 homogeneous function of m, so the unnormalized half-vectors of eqs 13 and 16 go in
directly, and tan θ comes from the tangential components (exact near the normal in float32,
unlike 1 - cos²θ). Every function broadcasts over leading dimensions.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax.numpy as jnp
from jax.scipy.special import erfc

from fitlab.frame import dot
from fitlab.numerics import clamp_alpha, safe_div, safe_sqrt

#: Beckmann-style a = 1 / (α tan θ) is capped here: G1 is 1 to machine precision beyond it.
_A_MAX = 30.0
#: Beckmann D is 0 beyond tan²θm/α² = _X_MAX: exp(-x)(1 + tan²θm)² underflows to 0 in float64
#: there, and cutting it off keeps the gradient of tan²θm = sin²/cos² finite near the horizon.
_X_MAX = 750.0
#: Phong's tan²θm is capped here (cos^α_p of a steeper m is 0 unless α_p ≈ 0).
_TAN2_MAX = 1e30
_INV_SQRT_PI = 0.5641895835477563


def _sin2_cos2(m):
    s2 = m[..., 0] ** 2 + m[..., 1] ** 2
    c2 = m[..., 2] ** 2
    return s2, c2


# --------------------------------------------------------------------------------------------
# D(m)
# --------------------------------------------------------------------------------------------


def D_GGX(m, alpha):
    """GGX distribution, Walter eq. 33: α² χ⁺(m·n) / (π cos⁴θm (α² + tan²θm)²) = α² / (π q²),
    q = cos²θm (α² + tan²θm) = (m_x² + m_y² + α² m_z²) / |m|² in [min(α², 1), 1].

    Written through the ratio q rather than α²|m|⁴ / (π (m_x² + m_y² + α² m_z²)²): for a short
    unnormalized half-vector the |m|⁴ form under/overflows in float32 (NaN gradients)."""
    alpha = clamp_alpha(alpha)
    s2, c2 = _sin2_cos2(m)
    a2 = alpha * alpha
    ok = m[..., 2] > 0
    q = jnp.where(ok, (s2 + a2 * c2) / jnp.where(ok, s2 + c2, 1.0), 1.0)
    return jnp.where(ok, a2 / (jnp.pi * q * q), 0.0)


def D_Beckmann(m, alpha):
    """Beckmann distribution, Walter eq. 25: χ⁺(m·n) exp(-tan²θm / α²) / (π α² cos⁴θm)."""
    alpha = clamp_alpha(alpha)
    s2, c2 = _sin2_cos2(m)
    a2 = alpha * alpha
    # 1/cos⁴θm = (1 + tan²θm)² (no |m|⁴ that under/overflows in float32); D = 0 beyond
    # tan²θm/α² = _X_MAX (tested without a division) so the tan² gradient stays finite there.
    ok = (m[..., 2] > 0) & (s2 < _X_MAX * a2 * c2)
    tan2 = jnp.where(ok, s2, 0.0) / jnp.where(ok, c2, 1.0)
    val = jnp.exp(-tan2 / a2) * (1.0 + tan2) ** 2 / (jnp.pi * a2)
    return jnp.where(ok, val, 0.0)


def phong_exponent(alpha):
    """Walter's mapping from Beckmann width to Phong exponent: α_p = 2 α⁻² - 2 (section 5.2)."""
    alpha = clamp_alpha(alpha)
    return 2.0 / (alpha * alpha) - 2.0


def D_Phong(m, alpha):
    """Phong distribution, Walter eq. 30: χ⁺(m·n) (α_p + 2)/(2π) cos^α_p θm, α_p = 2α⁻² - 2."""
    ap = phong_exponent(alpha)
    s2, c2 = _sin2_cos2(m)
    ok = m[..., 2] > 0
    # cos^α_p θm = (1 + tan²θm)^(-α_p/2) with tan² from the tangential components: log(cos²θm)
    # of a cos² near 1 keeps no digits for narrow lobes (α_p = 2e8 at α = 1e-4). tan² is capped
    # at _TAN2_MAX (θm within 1e-15 of the horizon) so that its gradient stays finite.
    keep = ok & (s2 < _TAN2_MAX * c2)
    tan2 = jnp.where(keep, s2, _TAN2_MAX) / jnp.where(keep, c2, 1.0)
    val = (ap + 2.0) / (2.0 * jnp.pi) * jnp.exp(-0.5 * ap * jnp.log1p(tan2))
    return jnp.where(ok, val, 0.0)


# --------------------------------------------------------------------------------------------
# Smith G1(v): the monodirectional shadowing of eq. 23, without the sidedness factor
# χ⁺((v·m)/(v·n)), which smith_G1 applies.
# --------------------------------------------------------------------------------------------


def G1_GGX(v, alpha):
    """GGX Smith G1, Walter eq. 34: 2 / (1 + sqrt(1 + α² tan²θv)), written as
    2|v_z| / (|v_z| + sqrt(v_z² + α²(v_x² + v_y²))) so it is finite at the horizon and normal."""
    alpha = clamp_alpha(alpha)
    s2, c2 = _sin2_cos2(v)
    cz = jnp.abs(v[..., 2])  # not sqrt(c2): its gradient is NaN at the horizon
    return safe_div(2.0 * cz, cz + jnp.sqrt(c2 + alpha * alpha * s2))


def G_GGX(wi, wo, alpha):
    """Separable GGX Smith G1(i) G1(o) (Walter eqs 23, 34) without the sidedness factors, with
    one division: 4|i_z||o_z| / ((|i_z| + sqrt(i_z² + α²(i_x² + i_y²))) (|o_z| + ...)).

    Equal to ``G1_GGX(wi, alpha) * G1_GGX(wo, alpha)`` up to float rounding."""
    alpha = clamp_alpha(alpha)
    a2 = alpha * alpha
    si2, ci2 = _sin2_cos2(wi)
    so2, co2 = _sin2_cos2(wo)
    ci, co = jnp.abs(wi[..., 2]), jnp.abs(wo[..., 2])
    return safe_div(4.0 * ci * co, (ci + jnp.sqrt(ci2 + a2 * si2)) * (co + jnp.sqrt(co2 + a2 * so2)))


def _beckmann_a(v, alpha):
    """a = 1 / (α tan θv) (Walter eq. 26), capped at _A_MAX where G1 == 1.

    The cap is decided without a division (a < _A_MAX <=> v_z² < _A_MAX² α² sin²): computing a
    first and clamping it leaves NaN gradients near the normal, and sqrt(v_z²) at the horizon."""
    alpha = clamp_alpha(alpha)
    s2, c2 = _sin2_cos2(v)
    ok = c2 < (_A_MAX * alpha) ** 2 * s2
    s = jnp.sqrt(jnp.where(ok, s2, 1.0))
    return jnp.where(ok, jnp.abs(v[..., 2]) / (alpha * s), _A_MAX)


def G1_Beckmann(v, alpha):
    """Exact Beckmann Smith G1, Walter eq. 26: 2 / (1 + erf(a) + exp(-a²)/(a√π)), a = 1/(α tanθv).

    Rewritten as 2a / (a (2 - erfc a) + exp(-a²)/√π): no division by a, no erf cancellation."""
    a = _beckmann_a(v, alpha)
    return 2.0 * a / (a * (2.0 - erfc(a)) + jnp.exp(-a * a) * _INV_SQRT_PI)


def G1_Beckmann_rational(v, alpha):
    """Walter's rational approximation to the Beckmann Smith G1, eq. 27 (error < 0.35%).

    This is also the G1 Walter recommends for Phong (a = sqrt(0.5 α_p + 1)/tanθv, which equals
    1/(α tanθv) under the mapping α_p = 2α⁻² - 2) and the one Mitsuba 3 uses for Beckmann."""
    a = _beckmann_a(v, alpha)
    r = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return jnp.where(a < 1.6, r, 1.0)


# --------------------------------------------------------------------------------------------
# Sampling of D(m)|m·n| (Walter eqs 28-29, 31-32, 35-36). u1, u2 in [0, 1).
# --------------------------------------------------------------------------------------------


def _normal_from_cos2(cos2, sin2, u2):
    phi = 2.0 * jnp.pi * u2  # Walter eqs 29, 32, 36
    st = jnp.sqrt(jnp.maximum(sin2, 0.0))
    ct = jnp.sqrt(jnp.maximum(cos2, 0.0))
    return jnp.stack([st * jnp.cos(phi), st * jnp.sin(phi), ct], axis=-1)


def sample_m_GGX(u1, u2, alpha):
    """Walter eq. 35, θm = arctan(α sqrt(u1 / (1 - u1))), as cos²θm = (1-u1)/(1 + (α²-1)u1)."""
    a2 = clamp_alpha(alpha) ** 2
    den = 1.0 - u1 + a2 * u1
    return _normal_from_cos2((1.0 - u1) / den, a2 * u1 / den, u2)


def sample_m_Beckmann(u1, u2, alpha):
    """Walter eq. 28, tan²θm = -α² log(1 - u1)."""
    t2 = -(clamp_alpha(alpha) ** 2) * jnp.log1p(-u1)
    return _normal_from_cos2(1.0 / (1.0 + t2), t2 / (1.0 + t2), u2)


def sample_m_Phong(u1, u2, alpha):
    """Walter eq. 31, cos θm = u1^(1/(α_p + 2))."""
    ap = phong_exponent(alpha)
    ok = u1 > 0
    x = 2.0 * jnp.log(jnp.where(ok, u1, 1.0)) / (ap + 2.0)  # log cos²θm
    # sin²θm = -expm1(x): 1 - cos²θm would round to 0 for narrow lobes (α_p + 2 = 2e8 at α = 1e-4)
    return _normal_from_cos2(jnp.where(ok, jnp.exp(x), 0.0), jnp.where(ok, -jnp.expm1(x), 1.0), u2)


# --------------------------------------------------------------------------------------------
# von Mises-Fisher NDF (extended-NDF paper, "Extended NDFs for thin layers", eqs 5-8), on the
# shared α axis through κ = 2/α²: vMF e^{κ(cosθ-1)} ≈ e^{-κθ²/2} matches Beckmann's e^{-θ²/α²}
# for narrow lobes, as Walter's α_p = 2α⁻² - 2 does for Phong.
# --------------------------------------------------------------------------------------------


def vmf_kappa(alpha):
    """Concentration κ = 2/α² of the vMF NDF with width α."""
    a = clamp_alpha(alpha)
    return 2.0 / (a * a)


def vmf_A3(kappa):
    """Mean resultant length A3(κ) = coth κ - 1/κ (paper eq. 6)."""
    e = jnp.exp(-2.0 * kappa)
    return (1.0 + e) / (1.0 - e) - 1.0 / kappa


def _vmf_kI(kappa):
    """κ I(κ), I(κ) = ∫_0^1 μ e^{κ(μ-1)} dμ = (1 - e^{-κ})/κ - (1 - e^{-κ}(1+κ))/κ²."""
    return -jnp.expm1(-kappa) - (1.0 - jnp.exp(-kappa) * (1.0 + kappa)) / kappa


def D_vMF(m, alpha):
    """vMF NDF, paper eqs 5-6 with mean direction µ = n: D(m) = χ⁺(m·n) e^{κ(cos θm - 1)} / Z.

    The paper normalizes by 1/A3(κ) over the whole sphere (eq. 6) and notes that D ≈ M for
    κ > 100; here Z = 2π I(κ) normalizes exactly over the upper hemisphere, ∫ D cos θm dω = 1,
    so that the microfacet BSDFs and their sampling stay consistent for every κ ≥ 2.
    1 - cos θm = sin²/(|m|(|m| + m_z)) keeps the narrow lobes exact in float32."""
    kappa = vmf_kappa(alpha)
    s2, c2 = _sin2_cos2(m)
    ok = m[..., 2] > 0
    r = jnp.sqrt(jnp.where(ok, s2 + c2, 1.0))
    one_minus_mu = jnp.where(ok, s2, 0.0) / (r * (r + jnp.where(ok, m[..., 2], 1.0)))
    val = kappa * jnp.exp(-kappa * one_minus_mu) / (2.0 * jnp.pi * _vmf_kI(kappa))
    return jnp.where(ok, val, 0.0)


def G1_vMF(v, alpha):
    """vMF masking, paper eqs 7-8: G1 = A3(κ) cos θv / (a cos(b θv)), a = (A3 + 1)²/4,
    b = A3^{1/3}, clamped to [0, 1] (the approximation of the clamped-cosine integral is the
    paper's; it is not derived from D_vMF by Smith's Λ, so a vMF interface is not exactly
    energy-consistent)."""
    A3 = vmf_A3(vmf_kappa(alpha))
    a = 0.25 * (A3 + 1.0) ** 2
    b = jnp.cbrt(A3)
    s2, _ = _sin2_cos2(v)
    cz = jnp.abs(v[..., 2])
    theta = jnp.arctan2(safe_sqrt(s2), cz)
    return jnp.clip(safe_div(A3 * cz, a * jnp.cos(b * theta)), 0.0, 1.0)


def sample_m_vMF(u1, u2, alpha):
    """Sample D_vMF(m) cos θm: t = 1 - cos θm has density ∝ (1 - t) e^{-κt} on [0, 1] with CDF
    G(t) = (1 - e^{-κt} - (1 - e^{-κt}(1 + κt))/κ) / (κ I(κ)); solved by Newton's method from
    the truncated-exponential guess (G is concave, so the iteration converges monotonically)."""
    kappa = vmf_kappa(alpha)
    kI = _vmf_kI(kappa)
    t = -jnp.log1p(-u1 * (-jnp.expm1(-kappa))) / kappa
    for _ in range(8):
        x = kappa * t
        e = jnp.exp(-x)
        G = (-jnp.expm1(-x) - (1.0 - e * (1.0 + x)) / kappa) / kI
        g = kappa * (1.0 - t) * e / kI
        t = jnp.clip(t - (G - u1) / jnp.maximum(g, 1e-30), 0.0, 1.0)
    return _normal_from_cos2((1.0 - t) ** 2, t * (2.0 - t), u2)


# --------------------------------------------------------------------------------------------
# Registry of distributions
# --------------------------------------------------------------------------------------------


class Distribution(NamedTuple):
    """A microfacet distribution: D(m, α), Smith G1(v, α) without sidedness, sampling of
    D(m)|m·n| from two uniforms; optionally G(i, o, α) = G1(i) G1(o) in a cheaper fused form."""

    name: str
    D: Callable
    G1: Callable
    sample_m: Callable
    reference: str
    G: Callable | None = None


DISTRIBUTIONS = {
    "ggx": Distribution("ggx", D_GGX, G1_GGX, sample_m_GGX, "Walter 2007 eqs 33-36", G_GGX),
    "beckmann": Distribution(
        "beckmann", D_Beckmann, G1_Beckmann, sample_m_Beckmann, "Walter 2007 eqs 25, 26, 28-29"
    ),
    "beckmann_rational": Distribution(
        "beckmann_rational",
        D_Beckmann,
        G1_Beckmann_rational,
        sample_m_Beckmann,
        "Walter 2007 eqs 25, 27 (rational G1), 28-29",
    ),
    "phong": Distribution(
        "phong", D_Phong, G1_Beckmann_rational, sample_m_Phong, "Walter 2007 eqs 30-32, G1 by eq. 27"
    ),
}

#: Distributions outside Walter's family, reachable through get_distribution but not listed in
#: DISTRIBUTIONS (whose members share Walter's reference values, D(n) = 1/(πα²) among them, and
#: are the choices of the fitted models). The simulator's vMF interfaces use this one.
EXTRA_DISTRIBUTIONS = {
    "vmf": Distribution(
        "vmf", D_vMF, G1_vMF, sample_m_vMF,
        "extended-NDF paper eqs 5-8 (vMF NDF, masking approximation), kappa = 2/alpha^2"
    ),
}


def get_distribution(name: str) -> Distribution:
    try:
        return DISTRIBUTIONS[name] if name in DISTRIBUTIONS else EXTRA_DISTRIBUTIONS[name]
    except KeyError:
        raise ValueError(
            f"unknown microfacet distribution {name!r}; choose one of {', '.join(DISTRIBUTIONS)}"
        ) from None


def smith_G1(dist: Distribution, v, m, alpha):
    """Smith G1(v, m) with the sidedness factor χ⁺((v·m)/(v·n)) of eqs 26, 27, 34."""
    side = dot(v, m) * v[..., 2] > 0
    return jnp.where(side, dist.G1(v, alpha), 0.0)


def smith_G(dist: Distribution, wi, wo, side_i, side_o, alpha):
    """Separable Smith G(i, o, m) = G1(i, m) G1(o, m) (Walter eq. 23), given the sidedness masks
    side_v = (v·m)(v·n) > 0 computed by the caller."""
    g = dist.G(wi, wo, alpha) if dist.G is not None else dist.G1(wi, alpha) * dist.G1(wo, alpha)
    return jnp.where(side_i & side_o, g, 0.0)


def widened_alpha(alpha, cos_i):
    """Walter's widened sampling width α† = (1.2 - 0.2 sqrt|i·n|) α (section 5.3), which caps
    the sample weight near four."""
    return (1.2 - 0.2 * jnp.sqrt(jnp.abs(cos_i))) * alpha


def pdf_m(dist: Distribution, m, alpha):
    """Density of sampled normals, p_m(m) = D(m)|m·n| (Walter eq. 24), for unit m."""
    return dist.D(m, alpha) * jnp.abs(m[..., 2])
