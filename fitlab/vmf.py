"""The von Mises–Fisher (vMF) lobe and its algebra, by concentration κ: the NDF of the
extended-NDF paper (Guo, Qian, Pan 2015, eqs 5-8), its masking, sampling, and the spherical
convolution that joint spherical warping reduces to (eqs 17-18, 21, 23, 26).

Everything here is written so that κ from 1e-2 to 1e8 stays exact in float32 and float64, with
finite gradients:

* A3(κ) = coth κ - 1/κ (eq. 6) as (κ cosh κ - sinh κ)/(κ sinh κ) with the numerator's series
  below κ = 1, where the closed form cancels (κI(κ) and A3' likewise);
* a lobe is carried as its dispersion ν = 1/κ where the algebra needs it: the convolution of
  lobes multiplies their A3 (eq. 18), so it adds log A3 = log1p(-ν) exactly for κ > 20, where
  A3 = 1 - 1/κ to within e^{-40} — the large-κ asymptotics 1/κ̂ = 1/κ1 + 1/κ2 + ... are then
  what the arithmetic does, with no A3 ever rounded to 1 (Mitsuba 0.6's Newton solve returns its
  start once κ ≳ 1e5 for that reason);
* A3⁻¹ (:func:`nu_of_log_A3`) is 1 - A3 for κ̂ > 20 and otherwise a fixed number of Newton steps
  from Banerjee et al.'s start κ0 = R(3 - R²)/(1 - R²), with the implicit derivative as its JVP.

The microfacet registry's ``vmf`` and ``vmf_exact`` families (fitlab.microfacet, width α with
κ = 2/α²; masking by eq. 8 and by eq. 7 integrated) and the thin-layer model
(fitlab.models.thin_layer) use these functions.
"""

from __future__ import annotations

import functools
import math

from fitlab._jax import jax, jnp
from fitlab.numerics import ALPHA_MIN, safe_div, safe_sqrt
from fitlab.quadrature import gauss_legendre

#: Largest concentration a lobe is evaluated with: κ = 2/α² at fitlab's smallest width α.
KAPPA_MAX = 2.0 / ALPHA_MIN**2
#: Smallest concentration (an almost uniform hemisphere of normals).
KAPPA_MIN = 1e-4
#: Below this κ the closed forms of A3, A3' and κI(κ) cancel (their relative error grows like
#: eps/κ²); their power series, which converge fast there, are used instead.
_SMALL = 1.0
#: Terms of those series (enough for float64 round-off at κ = 1).
_TERMS = 18
#: Above this κ, A3(κ) = 1 - 1/κ to within 2e^{-2κ} < 1e-17.
_LARGE = 20.0
#: Smallest A3 that A3⁻¹ resolves (κ = 3e-8, far below KAPPA_MIN): a broader lobe is uniform.
_R_MIN = 1e-8
#: Newton steps of A3⁻¹ from Banerjee's start (its error is a few % at most; 6 steps reach
#: float64 round-off).
_NEWTON_STEPS = 6


def _where_small(kappa):
    small = kappa < _SMALL
    return small, jnp.where(small, kappa, 1.0), jnp.where(small, 1.0, kappa)


def _poly(x, coeffs):
    """Σ coeffs[n] x^n by Horner's rule (coeffs as Python floats: no dtype promotion)."""
    out = jnp.zeros_like(x) + coeffs[-1]
    for c in reversed(coeffs[:-1]):
        out = out * x + c
    return out


_FACT = [float(math.factorial(n)) for n in range(2 * _TERMS + 4)]
#: κ cosh κ - sinh κ = κ³ Σ_{n≥1} 2n/(2n+1)! κ^{2n-2}
_A3_NUM = [2.0 * n / _FACT[2 * n + 1] for n in range(1, _TERMS)]
#: sinh κ - κ = κ³ Σ_{n≥1} κ^{2n-2}/(2n+1)!
_SINH_TAIL = [1.0 / _FACT[2 * n + 1] for n in range(1, _TERMS)]
#: κI(κ) = κ Σ_{n≥0} (-κ)^n / (n! (n+1) (n+2))
_KI = [(-1.0) ** n / (_FACT[n] * (n + 1) * (n + 2)) for n in range(2 * _TERMS)]
#: 1 - e^{-x}(1 + x) = x² Σ_{n≥2} (-1)^n (n-1)/n! x^{n-2}
_TAIL = [(-1.0) ** n * (n - 1) / _FACT[n] for n in range(2, 2 * _TERMS)]


def A3(kappa):
    """Mean resultant length A3(κ) = coth κ - 1/κ (eq. 6); below κ = 1 as
    (κ cosh κ - sinh κ)/(κ sinh κ) with the numerator's series (no cancellation)."""
    small, ks, kb = _where_small(kappa)
    k2 = ks * ks
    series = ks * k2 * _poly(k2, _A3_NUM) / (ks * jnp.sinh(ks))
    e = jnp.exp(-2.0 * kb)
    closed = (1.0 + e) / (1.0 - e) - 1.0 / kb
    return jnp.where(small, series, closed)


def dA3(kappa):
    """A3'(κ) = 1/κ² - 1/sinh²κ; below κ = 1 as ((sinh κ - κ)/κ³)((sinh κ + κ)/κ)(κ/sinh κ)²
    with the series of the first factor (→ 1/3; no intermediate under- or overflows)."""
    small, ks, kb = _where_small(kappa)
    sh = jnp.sinh(ks)
    series = _poly(ks * ks, _SINH_TAIL) * ((sh + ks) / ks) * (ks / sh) ** 2
    e = jnp.exp(-2.0 * jnp.minimum(kb, 350.0))
    closed = 1.0 / (kb * kb) - 4.0 * e / (1.0 - e) ** 2
    return jnp.where(small, series, closed)


def kappa2_dA3(kappa):
    """κ² A3'(κ) = 1 - κ²/sinh²κ (→ 1 for large κ, κ²/3 for small)."""
    small, ks, kb = _where_small(kappa)
    e = jnp.exp(-2.0 * jnp.minimum(kb, 350.0))
    closed = 1.0 - 4.0 * kb * kb * e / (1.0 - e) ** 2
    return jnp.where(small, ks * ks * dA3(ks), closed)


def log_A3_of_nu(nu):
    """log A3(1/ν) for a dispersion ν = 1/κ ≥ 0: log1p(-ν) for κ > 20 (exact there, and exactly
    0 for ν = 0: a sharp lobe does not widen a convolution)."""
    sharp = nu < 1.0 / _LARGE
    nu_s = jnp.where(sharp, nu, 0.0)
    kappa = 1.0 / jnp.where(sharp, 1.0, nu)
    return jnp.where(sharp, jnp.log1p(-nu_s), jnp.log(A3(kappa)))


def _kappa_newton(R):
    """κ with A3(κ) = R for R in (0, 1 - 1/20]: Banerjee's start, then Newton."""
    R = jnp.clip(R, _R_MIN, 1.0 - 1.0 / _LARGE)
    kappa = R * (3.0 - R * R) / (1.0 - R * R)
    for _ in range(_NEWTON_STEPS):
        kappa = jnp.maximum(kappa - (A3(kappa) - R) / dA3(kappa), 0.5 * kappa)
    return kappa


def nu_of_log_A3(L):
    """Dispersion ν = 1/κ of the vMF lobe whose log A3 is L ≤ 0 (A3⁻¹ of eq. 18), differentiated
    as the inverse function (not through its Newton steps)."""
    return _nu_of_log_A3()(L)


def _nu_of_log_A3_value(L):
    B = -jnp.expm1(L)  # 1 - A3
    broad = B >= 1.0 / _LARGE
    kappa = _kappa_newton(jnp.exp(jnp.where(broad, L, -1.0)))
    return jnp.where(broad, 1.0 / kappa, B)


def _nu_of_log_A3_jvp(primals, tangents):
    (L,), (dL,) = primals, tangents
    nu = nu_of_log_A3(L)
    # A3(κ) = e^L: dκ = e^L dL / A3'(κ), dν = -ν² dκ = -e^L dL / (κ² A3'(κ))
    kappa = 1.0 / jnp.maximum(nu, 1e-30)
    return nu, -jnp.exp(L) * dL / kappa2_dA3(kappa)


@functools.cache
def _nu_of_log_A3():
    """The jax.custom_jvp of nu_of_log_A3, made at its first use (making it needs JAX)."""
    f = jax.custom_jvp(_nu_of_log_A3_value)
    f.defjvp(_nu_of_log_A3_jvp)
    return f


def convolve_nu(*nus):
    """Dispersion of the spherical convolution of vMF lobes with dispersions ``nus`` (eq. 18:
    the moment-matched lobe with A3(κ̂) = Π A3(κ_j); eq. 26 chains three)."""
    return nu_of_log_A3(sum(log_A3_of_nu(nu) for nu in nus))


def kappa_I(kappa):
    """κ I(κ), I(κ) = ∫_0^1 μ e^{κ(μ-1)} dμ: the hemispherical normalization of the vMF NDF
    (∫ D cos θm dω = 1 over the upper hemisphere; eq. 6's 1/A3 over the whole sphere agrees
    with it within e^{-2κ} for κ ≥ 100). Below κ = 1 by its series κ Σ (-κ)^n/(n!(n+1)(n+2))."""
    small, ks, kb = _where_small(kappa)
    series = ks * _poly(ks, _KI)
    closed = -jnp.expm1(-kb) - (1.0 - jnp.exp(-kb) * (1.0 + kb)) / kb
    return jnp.where(small, series, closed)


def _sin2_cos2(m):
    return m[..., 0] ** 2 + m[..., 1] ** 2, m[..., 2] ** 2


def D(m, kappa):
    """vMF NDF with mean direction n (eqs 5-6): χ⁺(m·n) κ e^{κ(cos θm - 1)} / (2π κI(κ)), exactly
    normalized over the upper hemisphere. ``m`` need not be normalized; 1 - cos θm =
    sin²/(|m|(|m| + m_z)) keeps narrow lobes exact in float32."""
    s2, c2 = _sin2_cos2(m)
    ok = m[..., 2] > 0
    r = jnp.sqrt(jnp.where(ok, s2 + c2, 1.0))
    one_minus_mu = jnp.where(ok, s2, 0.0) / (r * (r + jnp.where(ok, m[..., 2], 1.0)))
    val = kappa * jnp.exp(-kappa * one_minus_mu) / (2.0 * jnp.pi * kappa_I(kappa))
    return jnp.where(ok, val, 0.0)


def G1_approx(v, kappa):
    """Masking of eqs 7-8: G1 = A3(κ) cos θv / (a cos(b θv)), a = (A3 + 1)²/4, b = A3^{1/3},
    clamped to [0, 1] (the paper's approximation of the clamped-cosine integral)."""
    a3 = A3(kappa)
    a = 0.25 * (a3 + 1.0) ** 2
    b = jnp.cbrt(a3)
    s2, _ = _sin2_cos2(v)
    cz = jnp.abs(v[..., 2])
    theta = jnp.arctan2(safe_sqrt(s2), cz)
    return jnp.clip(safe_div(a3 * cz, a * jnp.cos(b * theta)), 0.0, 1.0)


#: Gauss–Legendre nodes of the exact masking integral (in the variable that flattens e^{-κt}):
#: relative error ≤ 5e-4 against 400 nodes over κ 1e-2 – 1e6 and θ up to 89.99° (48: 5e-5).
_GL_NODES = 16


def projected_area(v, kappa):
    """∫ max(0, v·m) D(m) dω_m over the upper hemisphere (the denominator of eq. 7), by
    Gauss–Legendre quadrature in μ = cos θm after the substitution that makes the weight
    e^{κ(μ-1)} uniform; the azimuthal integral of the clamped cosine is closed:
    ∫ max(0, a + b cos φ) dφ = 2(a φc + b sin φc), cos φc = clip(-a/b, -1, 1)."""
    x, w = gauss_legendre(_GL_NODES, 0.0, 1.0)
    dt = v.dtype if hasattr(v, "dtype") else jnp.float64
    u = jnp.asarray(x, dt)
    wq = jnp.asarray(w, dt)
    kappa = jnp.asarray(kappa, dt)[..., None]
    span = -jnp.expm1(-kappa)  # 1 - e^{-κ}
    t = -jnp.log1p(-u * span) / kappa  # 1 - μ, density ∝ e^{-κt} → uniform in u
    mu = 1.0 - t
    s2, _ = _sin2_cos2(v)
    sin_v = safe_sqrt(s2)[..., None]
    cos_v = jnp.abs(v[..., 2])[..., None]
    a = cos_v * mu
    b = sin_v * safe_sqrt(1.0 - mu * mu)
    # where |a| < b: cos φc = -a/b, so b sin φc = s = √(b² - a²) and φc = atan2(s, -a) (one
    # atan2 and one root instead of arccos and sin: 1.6x faster); elsewhere the clamped cosine
    # is a + b cos φ ≥ 0 throughout (a > 0: φc = π) or 0 (φc = 0). Double where: s' is
    # infinite at the edge |a| = b
    inside = b > jnp.abs(a)
    s = jnp.sqrt(jnp.where(inside, b * b - a * a, 1.0))
    phi_c = jnp.where(inside, jnp.arctan2(s, -a), jnp.where(a > 0, jnp.pi, 0.0))
    azimuthal = 2.0 * (a * phi_c + jnp.where(inside, s, 0.0))
    # ∫_0^1 A(μ) κ e^{κ(μ-1)} dμ / (2π κI) with κ e^{-κt} dt = span du
    return jnp.sum(wq * azimuthal, axis=-1) * span[..., 0] / (2.0 * jnp.pi * kappa_I(kappa[..., 0]))


def G1_exact(v, kappa):
    """Masking of eq. 7 with the integral evaluated (:func:`projected_area`): cos θv / ∫⟨v,m⟩D."""
    return jnp.clip(safe_div(jnp.abs(v[..., 2]), projected_area(v, kappa)), 0.0, 1.0)


#: Masking choices of the thin-layer model (the microfacet families ``vmf`` = approx and
#: ``vmf_exact`` = exact, fitlab.microfacet.VMF_MASKING).
MASKING = {"approx": G1_approx, "exact": G1_exact}


def sample_m(u1, u2, kappa):
    """Sample D(m) cos θm: t = 1 - cos θm has density ∝ (1 - t) e^{-κt} on [0, 1] with CDF
    G(t) = (1 - e^{-κt} - (1 - e^{-κt}(1 + κt))/κ) / κI(κ); Newton's method from the
    truncated-exponential guess (G is concave, so the iteration converges monotonically)."""
    kI = kappa_I(kappa)
    t = -jnp.log1p(-u1 * (-jnp.expm1(-kappa))) / kappa
    for _ in range(8):
        x = kappa * t
        e = jnp.exp(-x)
        # 1 - e^{-x}(1 + x) = x²/2 - x³/3 + ... cancels for small x: its series there
        small, xs, xb = _where_small(x)
        tail = jnp.where(small, xs * xs * _poly(xs, _TAIL), 1.0 - jnp.exp(-xb) * (1.0 + xb))
        G = (-jnp.expm1(-x) - tail / kappa) / kI
        g = kappa * (1.0 - t) * e / kI
        t = jnp.clip(t - (G - u1) / jnp.maximum(g, 1e-30), 0.0, 1.0)
    cos2, sin2 = (1.0 - t) ** 2, t * (2.0 - t)
    phi = 2.0 * jnp.pi * u2
    s = jnp.sqrt(sin2)
    return jnp.stack([s * jnp.cos(phi), s * jnp.sin(phi), jnp.sqrt(cos2)], axis=-1)


def pdf_m(m, kappa):
    """Density of :func:`sample_m` per solid angle of m: D(m) cos θm."""
    s2, c2 = _sin2_cos2(m)
    return D(m, kappa) * jnp.where(m[..., 2] > 0, m[..., 2], 0.0) * jax.lax.rsqrt(
        jnp.where(s2 + c2 > 0, s2 + c2, 1.0))
