"""Microfacet distributions of Walter et al. 2007, section 5.2 (eqs 24-36), isotropic and
anisotropic, and the vMF NDF of the extended-NDF paper (eqs 5-8), with its masking by eq. 8
(``vmf``) or by eq. 7 integrated (``vmf_exact``).

Every distribution is parameterized by its width α (Walter's α_b for Beckmann, α_g for GGX);
an anisotropic one by the widths (α_x, α_y) along the tangent frame's +x and +y (pbrt-v4's
``TrowbridgeReitzDistribution(alpha_x, alpha_y)``, Mitsuba's ``alpha_u, alpha_v``). Phong is
parameterized by the same α through Walter's recommended mapping α_p = 2 α⁻² - 2 (eq. 30 note),
so all distributions share one roughness axis; Phong and vMF are isotropic only.

Two ways to use a distribution:

* the registry entry (:class:`Family`, ``DISTRIBUTIONS["ggx"]``) has the pure functions
  ``D(m, alpha_x, alpha_y=None)``, ``G1(v, alpha_x, alpha_y=None)``,
  ``sample_m(u1, u2, alpha_x, alpha_y=None)`` (``alpha_y=None``: isotropic);
* calling it, ``DISTRIBUTIONS["ggx"](alpha_x, alpha_y)``, gives a :class:`MicrofacetDistribution`
  that owns its widths and offers ``D(m)``, ``Lambda(w)``, ``G1(w)``, ``G(wi, wo)``,
  ``sample_m(u)``, ``pdf_m(m)``, ``sample_visible(w, u)``, ``pdf_visible(w, m)``: what the models use.

Anisotropy stretches the slope space (Heitz 2014, "Understanding the masking-shadowing function",
section 5.3): with the stretched tangential length s(m) = m_x²/α_x² + m_y²/α_y² every formula is
the isotropic one of width 1 in the stretched frame; the projected width of a direction w is
α(w)² = (α_x² w_x² + α_y² w_y²)/(w_x² + w_y²). The formulas below carry the ratio k = α_y/α_x,
which is None for an isotropic distribution, so that the isotropic path computes exactly the
isotropic formulas.

Functions take microfacet normals ``m`` that need not be normalized: D is written as a
degree-0 homogeneous function of m, so the unnormalized half-vectors of eqs 13 and 16 go in
directly, and tan θ comes from the tangential components (exact near the normal in float32,
unlike 1 - cos²θ). Every function broadcasts over leading dimensions.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from fitlab._jax import jax, jnp, jsp_special
from fitlab import vmf
from fitlab.frame import dot
from fitlab.numerics import clamp_alpha, safe_div, safe_rsqrt, safe_sqrt
from fitlab.registry import Registry

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


def _widths(alpha_x, alpha_y):
    """(α_x, k = α_y/α_x), both clamped; k is None for an isotropic distribution."""
    ax = clamp_alpha(alpha_x)
    if alpha_y is None:
        return ax, None
    return ax, clamp_alpha(alpha_y) / ax


def _stretched_tangential(m, k, s2):
    """m_x² + m_y²/k² = α_x² s(m): the tangential length in the stretched slope space, in units
    of α_x; ``s2`` = m_x² + m_y² (isotropic)."""
    return s2 if k is None else m[..., 0] ** 2 + m[..., 1] ** 2 / (k * k)


def _projected_tangential(v, k, s2):
    """v_x² + k² v_y² = α(v)² (v_x² + v_y²)/α_x²: the tangential length weighted by the
    projected width (Heitz 2014 eq. 80), in units of α_x; ``s2`` = v_x² + v_y² (isotropic)."""
    return s2 if k is None else v[..., 0] ** 2 + (k * k) * v[..., 1] ** 2


# --------------------------------------------------------------------------------------------
# D(m)
# --------------------------------------------------------------------------------------------


def D_GGX(m, alpha, alpha_y=None):
    """GGX distribution, Walter eq. 33: α² χ⁺(m·n) / (π cos⁴θm (α² + tan²θm)²) = α² / (π q²),
    q = cos²θm (α² + tan²θm) = (m_x² + m_y² + α² m_z²) / |m|² in [min(α², 1), 1].
    Anisotropic (Heitz 2014 eq. 85): 1 / (π α_x α_y cos⁴θm (1 + s(m)/m_z²)²), the same with
    q = (k m_x² + m_y²/k + α_x α_y m_z²)/|m|² and α² → α_x α_y.

    Written through the ratio q rather than α²|m|⁴ / (π (m_x² + m_y² + α² m_z²)²): for a short
    unnormalized half-vector the |m|⁴ form under/overflows in float32 (NaN gradients)."""
    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(m)
    a2 = ax * ax if k is None else ax * ax * k  # α_x α_y
    t = s2 if k is None else m[..., 0] ** 2 * k + m[..., 1] ** 2 / k
    ok = m[..., 2] > 0
    q = jnp.where(ok, (t + a2 * c2) / jnp.where(ok, s2 + c2, 1.0), 1.0)
    return jnp.where(ok, a2 / (jnp.pi * q * q), 0.0)


def D_Beckmann(m, alpha, alpha_y=None):
    """Beckmann distribution, Walter eq. 25: χ⁺(m·n) exp(-tan²θm / α²) / (π α² cos⁴θm);
    anisotropic (Heitz 2014 eq. 86): exp(-s(m)/m_z²) / (π α_x α_y cos⁴θm)."""
    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(m)
    a2 = ax * ax
    st = _stretched_tangential(m, k, s2)
    # 1/cos⁴θm = (1 + tan²θm)² (no |m|⁴ that under/overflows in float32); D = 0 beyond
    # s(m)/m_z² = _X_MAX (tested without a division) so the tan² gradient stays finite there.
    ok = (m[..., 2] > 0) & (st < _X_MAX * a2 * c2)
    cz = jnp.where(ok, c2, 1.0)
    tan2 = jnp.where(ok, s2, 0.0) / cz
    x = tan2 if k is None else jnp.where(ok, st, 0.0) / cz
    val = jnp.exp(-x / a2) * (1.0 + tan2) ** 2 / (jnp.pi * (a2 if k is None else a2 * k))
    return jnp.where(ok, val, 0.0)


def phong_exponent(alpha):
    """Walter's mapping from Beckmann width to Phong exponent: α_p = 2 α⁻² - 2 (section 5.2)."""
    alpha = clamp_alpha(alpha)
    return 2.0 / (alpha * alpha) - 2.0


def D_Phong(m, alpha, alpha_y=None):
    """Phong distribution, Walter eq. 30: χ⁺(m·n) (α_p + 2)/(2π) cos^α_p θm, α_p = 2α⁻² - 2.
    Isotropic only."""
    _isotropic_only("phong", alpha_y)
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


def _isotropic_only(name, alpha_y):
    if alpha_y is not None:
        raise ValueError(f"the {name} distribution is isotropic only: give one width alpha "
                         "(anisotropic widths need ggx, beckmann or beckmann_rational)")


# --------------------------------------------------------------------------------------------
# Smith Λ(v) and G1(v) = 1/(1 + Λ(v)): the monodirectional shadowing of eq. 23, without the
# sidedness factor χ⁺((v·m)/(v·n)), which MicrofacetDistribution.smith_G1 applies.
# --------------------------------------------------------------------------------------------


def G1_GGX(v, alpha, alpha_y=None):
    """GGX Smith G1, Walter eq. 34: 2 / (1 + sqrt(1 + α² tan²θv)), written as
    2|v_z| / (|v_z| + sqrt(v_z² + α²(v_x² + v_y²))) so it is finite at the horizon and normal;
    anisotropic: α²(v_x² + v_y²) → α_x² v_x² + α_y² v_y² (projected width)."""
    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(v)
    p = _projected_tangential(v, k, s2)
    cz = jnp.abs(v[..., 2])  # not sqrt(c2): its gradient is NaN at the horizon
    return safe_div(2.0 * cz, cz + jnp.sqrt(c2 + ax * ax * p))


def Lambda_GGX(v, alpha, alpha_y=None):
    """GGX Smith Λ(v) = (sqrt(1 + α(v)² tan²θv) - 1)/2 (Heitz 2014 eq. 72), infinite at the
    horizon (returned as a large finite number there)."""
    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(v)
    p = ax * ax * _projected_tangential(v, k, s2)
    cz = jnp.abs(v[..., 2])
    # (sqrt(c2 + p) - |v_z|) / (2|v_z|) = p / (2|v_z| (sqrt(c2 + p) + |v_z|)): no cancellation
    return safe_div(p, 2.0 * cz * (jnp.sqrt(c2 + p) + cz), 1e30)


def G_GGX(wi, wo, alpha, alpha_y=None):
    """Separable GGX Smith G1(i) G1(o) (Walter eqs 23, 34) without the sidedness factors, with
    one division: 4|i_z||o_z| / ((|i_z| + sqrt(i_z² + α²(i_x² + i_y²))) (|o_z| + ...)).

    Equal to ``G1_GGX(wi, alpha) * G1_GGX(wo, alpha)`` up to float rounding."""
    ax, k = _widths(alpha, alpha_y)
    a2 = ax * ax
    si2, ci2 = _sin2_cos2(wi)
    so2, co2 = _sin2_cos2(wo)
    pi, po = _projected_tangential(wi, k, si2), _projected_tangential(wo, k, so2)
    ci, co = jnp.abs(wi[..., 2]), jnp.abs(wo[..., 2])
    return safe_div(4.0 * ci * co, (ci + jnp.sqrt(ci2 + a2 * pi)) * (co + jnp.sqrt(co2 + a2 * po)))


def _beckmann_a(v, alpha, alpha_y=None):
    """a = 1 / (α(v) tan θv) (Walter eq. 26; α(v) the projected width), capped at _A_MAX where
    G1 == 1.

    The cap is decided without a division (a < _A_MAX <=> v_z² < _A_MAX² α² sin²): computing a
    first and clamping it leaves NaN gradients near the normal, and sqrt(v_z²) at the horizon."""
    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(v)
    p = _projected_tangential(v, k, s2)
    ok = c2 < (_A_MAX * ax) ** 2 * p
    s = jnp.sqrt(jnp.where(ok, p, 1.0))
    return jnp.where(ok, jnp.abs(v[..., 2]) / (ax * s), _A_MAX)


def G1_Beckmann(v, alpha, alpha_y=None):
    """Exact Beckmann Smith G1, Walter eq. 26: 2 / (1 + erf(a) + exp(-a²)/(a√π)), a = 1/(α tanθv).

    Rewritten as 2a / (a (2 - erfc a) + exp(-a²)/√π): no division by a, no erf cancellation."""
    a = _beckmann_a(v, alpha, alpha_y)
    return 2.0 * a / (a * (2.0 - jsp_special.erfc(a)) + jnp.exp(-a * a) * _INV_SQRT_PI)


def Lambda_Beckmann(v, alpha, alpha_y=None):
    """Beckmann Smith Λ = (erfc(a) - ... )/2 = (exp(-a²)/(a√π) - erfc(a))/2 (Heitz 2014 eq. 83),
    0 where a reaches the cap."""
    a = _beckmann_a(v, alpha, alpha_y)
    return 0.5 * (jnp.exp(-a * a) * _INV_SQRT_PI / a - jsp_special.erfc(a))


def G1_Beckmann_rational(v, alpha, alpha_y=None):
    """Walter's rational approximation to the Beckmann Smith G1, eq. 27 (error < 0.35%).

    This is also the G1 Walter recommends for Phong (a = sqrt(0.5 α_p + 1)/tanθv, which equals
    1/(α tanθv) under the mapping α_p = 2α⁻² - 2) and the one Mitsuba 3 uses for Beckmann."""
    a = _beckmann_a(v, alpha, alpha_y)
    r = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return jnp.where(a < 1.6, r, 1.0)


def Lambda_from_G1(G1):
    """Λ = 1/G1 - 1 for a G1 given without Λ of its own (Phong/rational, vMF)."""
    def Lambda(v, alpha, alpha_y=None):
        g = G1(v, alpha, alpha_y)
        return safe_div(1.0 - g, g, 1e30)
    return Lambda


# --------------------------------------------------------------------------------------------
# Sampling of D(m)|m·n| (Walter eqs 28-29, 31-32, 35-36). u1, u2 in [0, 1).
# Anisotropic: the slopes of the unit-width distribution stretched by (α_x, α_y) (Heitz 2014
# section 5.3), i.e. tan²θm = α_φ² T(u1) with α_φ² = α_x² cos²φ + α_y² sin²φ and the normal's
# azimuth along (α_x cos φ, α_y sin φ).
# --------------------------------------------------------------------------------------------


def _normal_from_cos2(cos2, sin2, u2, k=None):
    phi = 2.0 * jnp.pi * u2  # Walter eqs 29, 32, 36
    st = jnp.sqrt(jnp.maximum(sin2, 0.0))
    ct = jnp.sqrt(jnp.maximum(cos2, 0.0))
    cx, sy = jnp.cos(phi), jnp.sin(phi)
    if k is not None:  # azimuth of the stretched slope (cos φ, k sin φ)/|...|
        sy = k * sy
        r = jnp.sqrt(cx * cx + sy * sy)
        cx, sy = cx / r, sy / r
    return jnp.stack([st * cx, st * sy, ct], axis=-1)


def _stretch2(u2, k):
    """α_φ²/α_x² = cos²φ + k² sin²φ of the sampled azimuth φ = 2π u2."""
    phi = 2.0 * jnp.pi * u2
    return jnp.cos(phi) ** 2 + (k * k) * jnp.sin(phi) ** 2


def sample_m_GGX(u1, u2, alpha, alpha_y=None):
    """Walter eq. 35, θm = arctan(α sqrt(u1 / (1 - u1))), as cos²θm = (1-u1)/(1 + (α²-1)u1)."""
    ax, k = _widths(alpha, alpha_y)
    a2 = ax**2 if k is None else ax**2 * _stretch2(u2, k)
    den = 1.0 - u1 + a2 * u1
    return _normal_from_cos2((1.0 - u1) / den, a2 * u1 / den, u2, k)


def sample_m_Beckmann(u1, u2, alpha, alpha_y=None):
    """Walter eq. 28, tan²θm = -α² log(1 - u1)."""
    ax, k = _widths(alpha, alpha_y)
    t2 = -(ax**2 if k is None else ax**2 * _stretch2(u2, k)) * jnp.log1p(-u1)
    return _normal_from_cos2(1.0 / (1.0 + t2), t2 / (1.0 + t2), u2, k)


def sample_m_Phong(u1, u2, alpha, alpha_y=None):
    """Walter eq. 31, cos θm = u1^(1/(α_p + 2))."""
    _isotropic_only("phong", alpha_y)
    ap = phong_exponent(alpha)
    ok = u1 > 0
    x = 2.0 * jnp.log(jnp.where(ok, u1, 1.0)) / (ap + 2.0)  # log cos²θm
    # sin²θm = -expm1(x): 1 - cos²θm would round to 0 for narrow lobes (α_p + 2 = 2e8 at α = 1e-4)
    return _normal_from_cos2(jnp.where(ok, jnp.exp(x), 0.0), jnp.where(ok, -jnp.expm1(x), 1.0), u2)


def _unit_width_view(w, ax, ay):
    """The view direction w (upper side) in the configuration stretched to unit width
    (Heitz 2018 section 3.2; Heitz & d'Eon 2014 section 4): normalize(α_x w_x, α_y w_y, |w_z|)."""
    vx, vy, vz = ax * w[..., 0], ay * w[..., 1], jnp.abs(w[..., 2])
    r = safe_rsqrt(vx * vx + vy * vy + vz * vz)
    return vx * r, vy * r, vz * r


def _unstretched_normal(nx, ny, nz, ax, ay):
    """A unit-width configuration's normal (nx, ny, nz) back in the distribution's: the unit
    normalize(α_x n_x, α_y n_y, n_z) (Heitz 2018 section 3.4)."""
    mx, my = ax * nx, ay * ny
    r = safe_rsqrt(mx * mx + my * my + nz * nz)
    return jnp.stack([mx * r, my * r, nz * r], axis=-1)


def sample_visible_GGX(w, u1, u2, alpha, alpha_y=None):
    """Heitz 2018, "Sampling the GGX distribution of visible normals" (listing 1): a microfacet
    normal with density D_w(m) = G1(w) max(0, w·m) D(m) / w_z for w.z > 0 (the caller turns w to
    the upper side). Stretch w to the unit-width configuration, sample the projected area of the
    visible hemisphere (a disk whose lower half is squeezed by (1 + V_z)/2), unstretch."""
    ax, k = _widths(alpha, alpha_y)
    ay = ax if k is None else ax * k
    # Section 3.2: the view direction in the hemisphere (unit-width) configuration
    vx, vy, vz = _unit_width_view(w, ax, ay)
    # Section 4.1: orthonormal basis (with the special case at normal incidence)
    lensq = vx * vx + vy * vy
    il = safe_rsqrt(lensq)
    t1x = jnp.where(lensq > 0, -vy * il, 1.0)
    t1y = jnp.where(lensq > 0, vx * il, 0.0)
    t2x, t2y, t2z = -vz * t1y, vz * t1x, vx * t1y - vy * t1x  # cross(V, T1), T1.z = 0
    # Section 4.2: parameterization of the projected area
    rr = jnp.sqrt(u1)
    phi = 2.0 * jnp.pi * u2
    p1, p2 = rr * jnp.cos(phi), rr * jnp.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * safe_sqrt(1.0 - p1 * p1) + s * p2
    # Section 4.3: reprojection onto the hemisphere
    p3 = safe_sqrt(1.0 - p1 * p1 - p2 * p2)
    nx = p1 * t1x + p2 * t2x + p3 * vx
    ny = p1 * t1y + p2 * t2y + p3 * vy
    nz = p2 * t2z + p3 * vz
    # Section 3.4: back to the ellipsoid configuration
    return _unstretched_normal(nx, ny, jnp.maximum(nz, 0.0), ax, ay)


def _beckmann_visible_slopes(cos_theta, u1, u2):
    """Slopes (x along the projection of w, y across it) of the visible normals of the unit-width
    Beckmann distribution seen from a direction at cos θ (Heitz & d'Eon 2014, "Importance
    sampling microfacet-based BSDFs using the distribution of visible normals", section 4 and
    appendix: the x slope has CDF (1 + erf(x) + tan θ exp(-x²)/√π) / (1 + erf(cot θ) + tan θ
    exp(-cot²θ)/√π) on (-∞, cot θ], inverted here in the erf domain b = erf(x) by a safeguarded
    Newton iteration from pbrt-v3's fitted guess; the y slope is an independent Gaussian)."""
    eps = 4.0 * jnp.finfo(jnp.result_type(cos_theta)).eps
    c_t = jnp.clip(cos_theta, 0.0, 1.0)
    sin_t = jnp.sqrt(jnp.maximum(1.0 - c_t * c_t, 0.0))
    normal = c_t > 0.9999
    tan_t = jnp.where(normal, 0.0, sin_t / jnp.where(normal, 1.0, c_t))
    cot_t = jnp.where(normal, 1e30, c_t / jnp.where(normal, 1.0, sin_t))
    x = jnp.clip(u1, 1e-6, 1.0 - 1e-6)
    lo = jnp.full_like(c_t, -1.0)
    hi = jsp_special.erf(jnp.minimum(cot_t, 30.0))
    theta = jnp.arccos(c_t)
    fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta))
    b = hi - (1.0 + hi) * jnp.power(1.0 - x, fit)
    norm = 1.0 / (1.0 + hi + _INV_SQRT_PI * tan_t * jnp.exp(-jnp.minimum(cot_t, 30.0) ** 2))
    for _ in range(16):
        b = jnp.where((b >= lo) & (b <= hi), b, 0.5 * (lo + hi))  # bisection safeguard
        s = jsp_special.erfinv(jnp.clip(b, -1.0 + eps, 1.0 - eps))
        value = norm * (1.0 + b + _INV_SQRT_PI * tan_t * jnp.exp(-s * s)) - x
        derivative = norm * (1.0 - s * tan_t)
        lo = jnp.where(value > 0, lo, b)
        hi = jnp.where(value > 0, b, hi)
        b = b - value / jnp.where(derivative != 0, derivative, 1.0)
    b = jnp.where((b >= lo) & (b <= hi), b, 0.5 * (lo + hi))
    slope_x = jsp_special.erfinv(jnp.clip(b, -1.0 + eps, 1.0 - eps))
    slope_y = jsp_special.erfinv(jnp.clip(2.0 * jnp.clip(u2, 1e-6, 1.0 - 1e-6) - 1.0,
                                          -1.0 + eps, 1.0 - eps))
    # normal incidence: the visible normals are the normals (Walter eq. 28 in slope form)
    r = jnp.sqrt(-jnp.log1p(-jnp.clip(u1, 0.0, 1.0 - 1e-16)))
    phi = 2.0 * jnp.pi * u2
    return (jnp.where(normal, r * jnp.cos(phi), slope_x),
            jnp.where(normal, r * jnp.sin(phi), slope_y))


def sample_visible_Beckmann(w, u1, u2, alpha, alpha_y=None):
    """Visible normals of the (exact-G1) Beckmann distribution, density D_w(m) =
    G1(w) max(0, w·m) D(m) / w_z for w.z > 0: stretch w to unit width, sample the slopes of
    :func:`_beckmann_visible_slopes`, rotate them to w's azimuth, unstretch (Heitz & d'Eon 2014
    section 4; pbrt-v3's ``BeckmannSample``)."""
    ax, k = _widths(alpha, alpha_y)
    ay = ax if k is None else ax * k
    vx, vy, vz = _unit_width_view(w, ax, ay)
    t = vx * vx + vy * vy
    it = safe_rsqrt(t)
    cos_phi = jnp.where(t > 0, vx * it, 1.0)
    sin_phi = jnp.where(t > 0, vy * it, 0.0)
    sx, sy = _beckmann_visible_slopes(vz, u1, u2)
    sx, sy = cos_phi * sx - sin_phi * sy, sin_phi * sx + cos_phi * sy
    # the normal of slopes (sx, sy) is normalize(-sx, -sy, 1); computed once: XLA would otherwise recompute the iteration inside every consumer's
    # fusion, where a different contraction of its floating-point ops can end on another
    # iterate, so that m·wi and the refracted direction would disagree
    return jax.lax.optimization_barrier(_unstretched_normal(-sx, -sy, jnp.ones_like(sx), ax, ay))


# --------------------------------------------------------------------------------------------
# von Mises-Fisher NDF (extended-NDF paper, "Extended NDFs for thin layers", eqs 5-8), on the
# shared α axis through κ = 2/α²: vMF e^{κ(cosθ-1)} ≈ e^{-κθ²/2} matches Beckmann's e^{-θ²/α²}
# for narrow lobes, as Walter's α_p = 2α⁻² - 2 does for Phong. Isotropic only.
# --------------------------------------------------------------------------------------------


def vmf_kappa(alpha):
    """Concentration κ = 2/α² of the vMF NDF with width α."""
    a = clamp_alpha(alpha)
    return 2.0 / (a * a)


def vmf_A3(kappa):
    """Mean resultant length A3(κ) = coth κ - 1/κ (paper eq. 6; fitlab.vmf.A3)."""
    return vmf.A3(kappa)


def D_vMF(m, alpha, alpha_y=None):
    """vMF NDF, paper eqs 5-6 with mean direction µ = n: D(m) = χ⁺(m·n) e^{κ(cos θm - 1)} / Z.

    The paper normalizes by 1/A3(κ) over the whole sphere (eq. 6) and notes that D ≈ M for
    κ > 100; here Z = 2π I(κ) normalizes exactly over the upper hemisphere, ∫ D cos θm dω = 1,
    so that the microfacet BSDFs and their sampling stay consistent for every κ (fitlab.vmf.D)."""
    _isotropic_only("vmf", alpha_y)
    return vmf.D(m, vmf_kappa(alpha))


def G1_vMF(v, alpha, alpha_y=None):
    """vMF masking, paper eqs 7-8: G1 = A3(κ) cos θv / (a cos(b θv)), a = (A3 + 1)²/4,
    b = A3^{1/3}, clamped to [0, 1] (the approximation of the clamped-cosine integral is the
    paper's; it is not derived from D_vMF by Smith's Λ, so a vMF interface is not exactly
    energy-consistent; fitlab.vmf.G1_approx). :func:`G1_vMF_exact` is the exact one."""
    _isotropic_only("vmf", alpha_y)
    return vmf.G1_approx(v, vmf_kappa(alpha))


def G1_vMF_exact(v, alpha, alpha_y=None):
    """vMF masking of paper eq. 7 with its integral evaluated, G1 = cos θv / ∫⟨v,m⟩D_vMF(m) dω_m:
    the Smith masking derived from D_vMF as normalized here (∫G1(v)⟨v,m⟩D dω = v·n holds, so a
    vMF interface is energy-consistent). 16-point Gauss–Legendre quadrature in cos θm with the
    clamped cosine's azimuthal integral in closed form, relative error ≤ 5e-4 for κ 1e-2 – 1e6
    and θv up to 89.99° (fitlab.vmf.G1_exact). Eq. 8 (:func:`G1_vMF`) differs most near the
    horizon: 0.769 against 0.043 at κ = 1e4, θv = 89.99°; 0.909 against 1 at κ = 2, θv = 0."""
    _isotropic_only("vmf", alpha_y)
    return vmf.G1_exact(v, vmf_kappa(alpha))


def sample_m_vMF(u1, u2, alpha, alpha_y=None):
    """Sample D_vMF(m) cos θm (fitlab.vmf.sample_m)."""
    _isotropic_only("vmf", alpha_y)
    return vmf.sample_m(u1, u2, vmf_kappa(alpha))


# --------------------------------------------------------------------------------------------
# du1/dt of the sampling in the variable t with tan θm = α tan t, where u1 is the CDF of
# D(m)|m·n| in θm: the inverse of Walter eq. 35 (GGX, tan²θm = α² u1/(1 - u1), so u1 = sin²t)
# and of eq. 28 (Beckmann, tan²θm = -α² log(1 - u1), so u1 = 1 - exp(-tan²t)). In t the lobe
# (θm ~ α) and the horizon (θm -> 90°) are both smooth: in u1 the horizon is a square-root
# endpoint singularity. The albedo quadrature (fitlab.lut.albedo) integrates in t.
# --------------------------------------------------------------------------------------------


def du1_dt_GGX(t):
    return jnp.sin(2.0 * t)


def du1_dt_Beckmann(t):
    c = jnp.cos(t)
    ok = c > 1e-150
    tan_t = jnp.sin(t) / jnp.where(ok, c, 1.0)
    x = jnp.where(ok & (tan_t < 30.0), tan_t, 30.0)  # exp(-900) = 0: the density has vanished
    return jnp.where(ok, 2.0 * x * (1.0 + x * x) * jnp.exp(-x * x), 0.0)


# --------------------------------------------------------------------------------------------
# Distribution objects and the registry
# --------------------------------------------------------------------------------------------


class Family(NamedTuple):
    """A microfacet distribution family (the registry entry): its pure functions of (α_x, α_y)
    and what it supports. Call it with the widths to get a :class:`MicrofacetDistribution`."""

    name: str
    D: Callable
    G1: Callable
    sample_m: Callable
    reference: str
    #: G(i, o) = G1(i) G1(o) in a cheaper fused form, or None
    G: Callable | None = None
    Lambda: Callable | None = None
    #: sampling of the visible normals D_w(m), or None where the family has none here
    sample_visible: Callable | None = None
    #: supports α_x ≠ α_y
    anisotropic: bool = False
    #: one of Walter 2007's distributions (shares D(n) = 1/(πα²)), offered by the microfacet models
    walter: bool = True
    #: du1/dt of the sampling of D(m)|m·n| in t (tan θm = α tan t), for quadrature over
    #: normals (the albedo tables); None where there is no closed form here (Phong, vMF)
    du1_dt: Callable | None = None

    def __call__(self, alpha_x, alpha_y=None) -> "MicrofacetDistribution":
        if alpha_y is not None and not self.anisotropic:
            _isotropic_only(self.name, alpha_y)
        return MicrofacetDistribution(self, alpha_x, alpha_y)


class MicrofacetDistribution:
    """A distribution that owns its widths (pbrt-v4's ``TrowbridgeReitzDistribution``).
    ``alpha_y=None`` is isotropic (and evaluates exactly the isotropic formulas)."""

    __slots__ = ("family", "alpha_x", "alpha_y")

    def __init__(self, family: Family, alpha_x, alpha_y=None):
        self.family, self.alpha_x, self.alpha_y = family, alpha_x, alpha_y

    @property
    def isotropic(self) -> bool:
        return self.alpha_y is None

    def scaled(self, s) -> "MicrofacetDistribution":
        """Both widths times s (Walter's widened sampling width α† = s α, section 5.3)."""
        return MicrofacetDistribution(self.family, s * self.alpha_x,
                                      None if self.alpha_y is None else s * self.alpha_y)

    def D(self, m):
        """D(m) in 1/sr (m unnormalized; 0 below the horizon)."""
        return self.family.D(m, self.alpha_x, self.alpha_y)

    def G1(self, w):
        """Smith G1(w) without the sidedness factor."""
        return self.family.G1(w, self.alpha_x, self.alpha_y)

    def Lambda(self, w):
        Lambda = self.family.Lambda or Lambda_from_G1(self.family.G1)
        return Lambda(w, self.alpha_x, self.alpha_y)

    def G(self, wi, wo):
        """Separable Smith G1(i) G1(o) (Walter eq. 23) without the sidedness factors."""
        if self.family.G is not None:
            return self.family.G(wi, wo, self.alpha_x, self.alpha_y)
        return self.G1(wi) * self.G1(wo)

    def smith_G1(self, v, m):
        """Smith G1(v, m) with the sidedness factor χ⁺((v·m)/(v·n)) of eqs 26, 27, 34."""
        return jnp.where(dot(v, m) * v[..., 2] > 0, self.G1(v), 0.0)

    def smith_G(self, wi, wo, side_i, side_o):
        """Separable Smith G(i, o, m) = G1(i, m) G1(o, m) (Walter eq. 23), given the sidedness
        masks side_v = (v·m)(v·n) > 0 computed by the caller."""
        return jnp.where(side_i & side_o, self.G(wi, wo), 0.0)

    def sample_m(self, u):
        """Unit m with density D(m)|m·n| from u[..., 0:2] (Walter eqs 28-36)."""
        return self.family.sample_m(u[..., 0], u[..., 1], self.alpha_x, self.alpha_y)

    def pdf_m(self, m):
        """Density of sample_m, p_m(m) = D(m)|m·n| (Walter eq. 24), for unit m."""
        return self.D(m) * jnp.abs(m[..., 2])

    @property
    def has_visible_sampling(self) -> bool:
        return self.family.sample_visible is not None

    def sample_visible(self, w, u):
        """Unit m with density D_w(m) = G1(w) max(0, w·m) D(m)/|w_z| (Heitz 2018), for w on the
        upper side (w.z > 0)."""
        if self.family.sample_visible is None:
            raise ValueError(f"the {self.family.name} distribution has no visible-normal "
                             "sampling here; use sampling=standard, or distribution=ggx or "
                             "beckmann")
        return self.family.sample_visible(w, u[..., 0], u[..., 1], self.alpha_x, self.alpha_y)

    def pdf_visible(self, w, m):
        """D_w(m) = G1(w) max(0, w·m) D(m) / |w_z| (Heitz 2018 eq. 1), for unit m."""
        return safe_div(self.G1(w) * jnp.maximum(dot(w, m), 0.0) * self.D(m), jnp.abs(w[..., 2]))


REGISTRY: Registry[Family] = Registry("microfacet distribution", {
    f.name: f
    for f in (
        Family("ggx", D_GGX, G1_GGX, sample_m_GGX, "Walter 2007 eqs 33-36; anisotropic: "
               "Heitz 2014 eqs 72, 85; visible normals: Heitz 2018", G_GGX, Lambda_GGX,
               sample_visible_GGX, anisotropic=True, du1_dt=du1_dt_GGX),
        Family("beckmann", D_Beckmann, G1_Beckmann, sample_m_Beckmann,
               "Walter 2007 eqs 25, 26, 28-29; anisotropic: Heitz 2014 eqs 83, 86; visible "
               "normals: Heitz & d'Eon 2014",
               Lambda=Lambda_Beckmann, sample_visible=sample_visible_Beckmann,
               anisotropic=True, du1_dt=du1_dt_Beckmann),
        Family("beckmann_rational", D_Beckmann, G1_Beckmann_rational, sample_m_Beckmann,
               "Walter 2007 eqs 25, 27 (rational G1), 28-29; anisotropic: Heitz 2014 eq. 86",
               anisotropic=True, du1_dt=du1_dt_Beckmann),
        Family("phong", D_Phong, G1_Beckmann_rational, sample_m_Phong,
               "Walter 2007 eqs 30-32, G1 by eq. 27 (isotropic only)"),
        Family("vmf", D_vMF, G1_vMF, sample_m_vMF,
               "extended-NDF paper eqs 5-8 (vMF NDF, masking approximation), kappa = 2/alpha^2 "
               "(isotropic only)", walter=False),
        Family("vmf_exact", D_vMF, G1_vMF_exact, sample_m_vMF,
               "extended-NDF paper eqs 5-7 (vMF NDF, the exact masking of eq. 7 integrated by "
               "16-point Gauss-Legendre quadrature), kappa = 2/alpha^2 (isotropic only)",
               walter=False),
    )
})

#: The vMF NDF's registry families by masking, keyed by the choices of the thin layer's
#: ``masking`` option (fitlab.vmf.MASKING): eq. 7 integrated (exact) or eq. 8 (approx). A scene
#: names the NDF ``vmf`` and chooses its masking with a key of its own (fitlab.simulate.scene).
VMF_MASKING = {"exact": "vmf_exact", "approx": "vmf"}


def names(*, walter: bool | None = True, anisotropic: bool | None = None) -> tuple[str, ...]:
    """Registry names, filtered: ``walter=True`` the distributions of Walter 2007 that the
    microfacet models offer (ggx, beckmann, beckmann_rational, phong), ``anisotropic=True``
    those that support α_x ≠ α_y."""
    return tuple(n for n, f in REGISTRY.items()
                 if (walter is None or f.walter == walter)
                 and (anisotropic is None or f.anisotropic == anisotropic))


#: Walter 2007's distributions (the microfacet models' choices), by name: a view of REGISTRY.
DISTRIBUTIONS: Registry[Family] = Registry("microfacet distribution",
                                           {n: REGISTRY[n] for n in names()})


def get_distribution(name: str) -> Family:
    return REGISTRY.get_entry(name)


def widened_alpha(alpha, cos_i):
    """Walter's widened sampling width α† = (1.2 - 0.2 sqrt|i·n|) α (section 5.3), which caps
    the sample weight near four."""
    return widening_factor(cos_i) * alpha


def widening_factor(cos_i):
    """1.2 - 0.2 sqrt|i·n| (Walter section 5.3)."""
    return 1.2 - 0.2 * jnp.sqrt(jnp.abs(cos_i))
