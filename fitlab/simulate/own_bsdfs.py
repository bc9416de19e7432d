"""The microfacet boundaries Mitsuba 3 lacks, in Dr.Jit, for the simulator's walk (protocol.py).

Mitsuba's ``roughdielectric`` / ``roughconductor`` cover GGX and Beckmann with the exact Smith G1;
fitlab's other microfacet families are written here: ``beckmann_rational`` (Beckmann D, Walter's
rational G1 of eq. 27; anisotropic by Heitz 2014 eq. 86), ``phong`` (Walter eqs 30-32, G1 by
eq. 27), ``vmf`` (the extended-NDF paper's vMF NDF, eqs 5-6, masking by its eq. 8) and
``vmf_exact`` (the same NDF, masking by eq. 7 integrated by 16-point Gauss–Legendre quadrature).
Each is the Dr.Jit twin of the formula of the same name in fitlab.microfacet / fitlab.vmf (the
JAX models this simulator judges); no code is shared with them.

Two boundaries: :class:`OwnRoughDielectric` (Walter 2007 eqs 20-22, 39-41; light from either
side) and :class:`OwnRoughConductor` (Walter eq. 20 with the exact conductor Fresnel; light from
above only). Sampling is Walter's "standard" one: m ~ D(m)|m·n|.

Every function takes and returns the arrays of the Mitsuba variant set by the caller (float32
``mi.Float``, ``mi.Vector3f``, ``mi.Spectrum``): drjit and mitsuba are imported inside the
functions. Branching is by ``dr.select`` only, so all of it traces inside a symbolic
``dr.while_loop``; lanes off the domain give finite values. Float32 care as in fitlab/vmf.py:
1 - cos θm = sin²θm / (|m|(|m| + m_z)), tan²θ from the tangential components, series where the
closed forms cancel.
"""

from __future__ import annotations

import math

from fitlab.simulate.protocol import FORCE_CHOOSE, FORCE_REFLECT, FORCE_REFRACT

#: Smallest microfacet width (fitlab.numerics.ALPHA_MIN).
ALPHA_MIN = 1e-4
#: Beckmann a = 1/(α tan θ) is capped here: G1 = 1 beyond (fitlab.microfacet._A_MAX).
_A_MAX = 30.0
#: Beckmann D is 0 beyond tan²θm/α² = _X_MAX (fitlab.microfacet._X_MAX).
_X_MAX = 750.0
#: Phong's tan²θm cap (fitlab.microfacet._TAN2_MAX).
_TAN2_MAX = 1e30
#: vMF: below this κ (or κt) the closed forms cancel and series are used (fitlab.vmf._SMALL).
_SMALL = 1.0
#: Terms of those series: 1/14! < 1e-11, float32 round-off at κ = 1.
_TERMS = 14
#: Gauss–Legendre nodes of the exact vMF masking integral (fitlab.vmf._GL_NODES).
_GL_NODES = 16
#: Newton steps of the vMF sampling (fitlab.vmf.sample_m).
_NEWTON_STEPS = 8

_FACT = [float(math.factorial(n)) for n in range(2 * _TERMS + 4)]
#: κ cosh κ - sinh κ = κ³ Σ_{n≥1} 2n/(2n+1)! κ^{2n-2}
_A3_NUM = [2.0 * n / _FACT[2 * n + 1] for n in range(1, _TERMS // 2 + 2)]
#: κI(κ) = κ Σ_{n≥0} (-κ)^n / (n! (n+1) (n+2))
_KI = [(-1.0) ** n / (_FACT[n] * (n + 1) * (n + 2)) for n in range(_TERMS)]
#: 1 - e^{-x}(1 + x) = x² Σ_{n≥2} (-1)^n (n-1)/n! x^{n-2}
_TAIL = [(-1.0) ** n * (n - 1) / _FACT[n] for n in range(2, _TERMS + 2)]


# --------------------------------------------------------------------------------------------
# Small helpers (Dr.Jit has no log1p / expm1)
# --------------------------------------------------------------------------------------------


def _safe_div(num, den, fallback=0.0):
    import drjit as dr

    ok = den != 0
    return dr.select(ok, num / dr.select(ok, den, 1.0), fallback)


def _log1p(x):
    """log(1 + x) without cancellation (Goldberg: log(u) x / (u - 1), u = 1 + x)."""
    import drjit as dr

    u = 1.0 + x
    d = u - 1.0
    return dr.select(d == 0, x, dr.log(u) * x / dr.select(d == 0, 1.0, d))


def _expm1(x):
    """e^x - 1 without cancellation (Kahan: (u - 1) x / log u, u = e^x, for |x| < 1/2)."""
    import drjit as dr

    u = dr.exp(x)
    d = u - 1.0
    lu = dr.log(u)
    ok = (d != 0) & (lu != 0)
    small = d * x / dr.select(ok, lu, 1.0)
    return dr.select(dr.abs(x) > 0.5, d, dr.select(ok, small, x))


def _poly(x, coeffs):
    """Σ coeffs[n] x^n by Horner's rule."""
    out = x * 0.0 + coeffs[-1]
    for c in reversed(coeffs[:-1]):
        out = out * x + c
    return out


def _sin2_cos2(v):
    return v.x * v.x + v.y * v.y, v.z * v.z


def _dot(a, b):
    return a.x * b.x + a.y * b.y + a.z * b.z


def _flip_z(w, s):
    import mitsuba as mi

    return mi.Vector3f(w.x, w.y, w.z * s)


def _sign_nonzero(x):
    """±1 with sign(0) = +1 (fitlab.numerics.sign_nonzero)."""
    import drjit as dr

    return dr.select(x < 0, -1.0, 1.0)


def _as_param(x, spectrum=False):
    """A parameter as a Dr.Jit array: arrays pass through, Python numbers become opaque (never
    baked into a kernel as a literal)."""
    import drjit as dr
    import mitsuba as mi

    if dr.is_array_v(x):
        return x
    return dr.opaque(mi.Spectrum if spectrum else mi.Float, x)


def _widths(alpha, alpha_y):
    """(α_x, k = α_y/α_x), clamped to ALPHA_MIN; k is None for an isotropic distribution."""
    import drjit as dr

    ax = dr.maximum(alpha, ALPHA_MIN)
    if alpha_y is None:
        return ax, None
    return ax, dr.maximum(alpha_y, ALPHA_MIN) / ax


def _normal_from_cos2(cos2, sin2, u2, k=None):
    """Unit normal at cos²θm, sin²θm and azimuth 2π u2 (Walter eqs 29, 32, 36); anisotropic:
    the azimuth of the stretched slope (cos φ, k sin φ) (Heitz 2014 section 5.3)."""
    import drjit as dr
    import mitsuba as mi

    sy, cx = dr.sincos(2.0 * dr.pi * u2)
    st = dr.sqrt(dr.maximum(sin2, 0.0))
    ct = dr.sqrt(dr.maximum(cos2, 0.0))
    if k is not None:
        sy = k * sy
        r = dr.rsqrt(cx * cx + sy * sy)
        cx, sy = cx * r, sy * r
    return mi.Vector3f(st * cx, st * sy, ct)


# --------------------------------------------------------------------------------------------
# Beckmann D (Walter eq. 25; anisotropic Heitz 2014 eq. 86), rational G1 (Walter eq. 27),
# sampling (Walter eq. 28)
# --------------------------------------------------------------------------------------------


def D_Beckmann(m, alpha, alpha_y=None):
    """Walter eq. 25: χ⁺(m·n) exp(-tan²θm/α²) / (π α² cos⁴θm); anisotropic (Heitz 2014 eq. 86):
    exp(-s(m)/m_z²)/(π α_x α_y cos⁴θm), s(m) = m_x²/α_x² + m_y²/α_y². 1/cos⁴ = (1 + tan²)²;
    m need not be normalized (degree-0 homogeneous)."""
    import drjit as dr

    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(m)
    a2 = ax * ax
    st = s2 if k is None else m.x * m.x + m.y * m.y / (k * k)
    ok = (m.z > 0) & (st < _X_MAX * a2 * c2)
    cz = dr.select(ok, c2, 1.0)
    tan2 = dr.select(ok, s2, 0.0) / cz
    x = tan2 if k is None else dr.select(ok, st, 0.0) / cz
    val = dr.exp(-x / a2) * dr.square(1.0 + tan2) / (dr.pi * (a2 if k is None else a2 * k))
    return dr.select(ok, val, 0.0)


def _beckmann_a(v, alpha, alpha_y=None):
    """a = 1/(α(v) tan θv) (Walter eq. 26; α(v) the projected width, Heitz 2014 eq. 80),
    capped at _A_MAX, decided without a division."""
    import drjit as dr

    ax, k = _widths(alpha, alpha_y)
    s2, c2 = _sin2_cos2(v)
    p = s2 if k is None else v.x * v.x + (k * k) * v.y * v.y
    ok = c2 < dr.square(_A_MAX * ax) * p
    s = dr.sqrt(dr.select(ok, p, 1.0))
    return dr.select(ok, dr.abs(v.z) / (ax * s), _A_MAX)


def G1_Beckmann_rational(v, alpha, alpha_y=None):
    """Walter eq. 27: (3.535a + 2.181a²)/(1 + 2.276a + 2.577a²) for a < 1.6, else 1. Also
    Phong's G1 (a = sqrt(0.5α_p + 1)/tan θv = 1/(α tan θv) under α_p = 2α⁻² - 2)."""
    import drjit as dr

    a = _beckmann_a(v, alpha, alpha_y)
    r = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return dr.select(a < 1.6, r, 1.0)


def G1_Beckmann(v, alpha, alpha_y=None):
    """Exact Beckmann Smith G1, Walter eq. 26: 2 / (1 + erf(a) + exp(-a²)/(a√π)), a = 1/(α tanθv),
    written 2a / (a (1 + erf a) + exp(-a²)/√π): no division by a. Mitsuba's ``beckmann``
    uses eq. 27's rational approximation instead (0.3 % from this, measured in
    tests/simulate/test_simulate_engine.py), so fitlab's exact family is written here."""
    import drjit as dr

    a = _beckmann_a(v, alpha, alpha_y)
    return 2.0 * a / (a * (1.0 + dr.erf(a)) + dr.exp(-a * a) * 0.5641895835477563)


def _stretch2(u2, k):
    """α_φ²/α_x² = cos²φ + k² sin²φ of φ = 2π u2 (Heitz 2014 section 5.3)."""
    import drjit as dr

    s, c = dr.sincos(2.0 * dr.pi * u2)
    return c * c + (k * k) * s * s


def sample_m_Beckmann(u1, u2, alpha, alpha_y=None):
    """Walter eq. 28: tan²θm = -α² log(1 - u1); φ = 2π u2 (eq. 29)."""
    ax, k = _widths(alpha, alpha_y)
    a2 = ax * ax if k is None else ax * ax * _stretch2(u2, k)
    t2 = -a2 * _log1p(-u1)
    return _normal_from_cos2(1.0 / (1.0 + t2), t2 / (1.0 + t2), u2, k)


# --------------------------------------------------------------------------------------------
# Phong (Walter eqs 30-32), α_p = 2α⁻² - 2
# --------------------------------------------------------------------------------------------


def phong_exponent(alpha):
    """Walter's α_p = 2α⁻² - 2 (section 5.2)."""
    import drjit as dr

    a = dr.maximum(alpha, ALPHA_MIN)
    return 2.0 / (a * a) - 2.0


def D_Phong(m, alpha, alpha_y=None):
    """Walter eq. 30: χ⁺(m·n) (α_p + 2)/(2π) cos^α_p θm, as (1 + tan²θm)^(-α_p/2)."""
    import drjit as dr

    ap = phong_exponent(alpha)
    s2, c2 = _sin2_cos2(m)
    ok = m.z > 0
    keep = ok & (s2 < _TAN2_MAX * c2)
    tan2 = dr.select(keep, s2, _TAN2_MAX) / dr.select(keep, c2, 1.0)
    val = (ap + 2.0) / (2.0 * dr.pi) * dr.exp(-0.5 * ap * _log1p(tan2))
    return dr.select(ok, val, 0.0)


def sample_m_Phong(u1, u2, alpha, alpha_y=None):
    """Walter eq. 31: cos θm = u1^(1/(α_p + 2)); sin²θm = -expm1(log cos²θm); φ by eq. 32."""
    import drjit as dr

    ap = phong_exponent(alpha)
    ok = u1 > 0
    x = 2.0 * dr.log(dr.select(ok, u1, 1.0)) / (ap + 2.0)
    return _normal_from_cos2(dr.select(ok, dr.exp(x), 0.0), dr.select(ok, -_expm1(x), 1.0), u2)


# --------------------------------------------------------------------------------------------
# vMF NDF (extended-NDF paper eqs 5-8), κ = 2/α² (fitlab.microfacet.vmf_kappa)
# --------------------------------------------------------------------------------------------


def vmf_kappa(alpha):
    """κ = 2/α² (fitlab.microfacet.vmf_kappa)."""
    import drjit as dr

    a = dr.maximum(alpha, ALPHA_MIN)
    return 2.0 / (a * a)


def _where_small(x):
    import drjit as dr

    small = x < _SMALL
    return small, dr.select(small, x, 1.0), dr.select(small, 1.0, x)


def vmf_A3(kappa):
    """A3(κ) = coth κ - 1/κ (paper eq. 6); below κ = 1 as (κ cosh κ - sinh κ)/(κ sinh κ) with
    the numerator's series (fitlab.vmf.A3)."""
    import drjit as dr

    small, ks, kb = _where_small(kappa)
    k2 = ks * ks
    series = ks * k2 * _poly(k2, _A3_NUM) / (ks * dr.sinh(ks))
    e = dr.exp(-2.0 * kb)
    closed = (1.0 + e) / (1.0 - e) - 1.0 / kb
    return dr.select(small, series, closed)


def vmf_kappa_I(kappa):
    """κI(κ) = κ ∫_0^1 μ e^{κ(μ-1)} dμ, the upper-hemisphere normalization of eqs 5-6
    (fitlab.vmf.kappa_I): 1 - e^{-κ} - (1 - e^{-κ}(1 + κ))/κ; its series below κ = 1."""
    import drjit as dr

    small, ks, kb = _where_small(kappa)
    series = ks * _poly(ks, _KI)
    closed = -_expm1(-kb) - (1.0 - dr.exp(-kb) * (1.0 + kb)) / kb
    return dr.select(small, series, closed)


def D_vMF(m, alpha, alpha_y=None):
    """Paper eqs 5-6, mean direction n: χ⁺(m·n) κ e^{-κ(1 - cos θm)} / (2π κI(κ)), exactly
    normalized over the upper hemisphere (fitlab.vmf.D); 1 - cos θm = sin²/(|m|(|m| + m_z))."""
    import drjit as dr

    kappa = vmf_kappa(alpha)
    s2, c2 = _sin2_cos2(m)
    ok = m.z > 0
    r = dr.sqrt(dr.select(ok, s2 + c2, 1.0))
    omm = dr.select(ok, s2, 0.0) / (r * (r + dr.select(ok, m.z, 1.0)))
    val = kappa * dr.exp(-kappa * omm) / (2.0 * dr.pi * vmf_kappa_I(kappa))
    return dr.select(ok, val, 0.0)


def vmf_one_minus_A3(kappa):
    """1 - A3(κ) without cancellation: 1/κ - 2e^{-2κ}/(1 - e^{-2κ}) for κ ≥ 1 (→ 1/κ)."""
    import drjit as dr

    small, _, kb = _where_small(kappa)
    e = dr.exp(-2.0 * kb)
    return dr.select(small, 1.0 - vmf_A3(kappa), 1.0 / kb - 2.0 * e / (1.0 - e))


def G1_vMF(v, alpha, alpha_y=None):
    """Paper eq. 8: G1 = A3 cos θv / (a cos(b θv)), a = (A3 + 1)²/4, b = A3^{1/3}, clamped to
    [0, 1] (fitlab.vmf.G1_approx). Near the horizon cos(b θv) of a sharp lobe (b → 1) cancels:
    written as sin((π/2 - θv) + (1 - b) θv), with the elevation π/2 - θv = atan2(|v_z|, sin θv)
    and 1 - b = (1 - A3)/(1 + b + b²)."""
    import drjit as dr

    kappa = vmf_kappa(alpha)
    a3 = vmf_A3(kappa)
    a = 0.25 * dr.square(a3 + 1.0)
    b = dr.cbrt(a3)
    one_minus_b = vmf_one_minus_A3(kappa) / (1.0 + b + b * b)
    s2, _ = _sin2_cos2(v)
    sin_v = dr.sqrt(s2)
    cz = dr.abs(v.z)
    theta = dr.atan2(sin_v, cz)
    cos_b_theta = dr.sin(dr.atan2(cz, sin_v) + one_minus_b * theta)
    return dr.clip(_safe_div(a3 * cz, a * cos_b_theta), 0.0, 1.0)


def _gl_rule():
    from fitlab.quadrature import gauss_legendre

    x, w = gauss_legendre(_GL_NODES, 0.0, 1.0)
    return [float(v) for v in x], [float(v) for v in w]


def vmf_projected_area(v, kappa):
    """∫ max(0, v·m) D(m) dω_m, the denominator of paper eq. 7, by the 16-point Gauss–Legendre
    rule of fitlab.vmf.projected_area (same nodes, same substitution t = 1 - μ =
    -log(1 - u(1 - e^{-κ}))/κ); the clamped cosine's azimuthal integral is closed,
    2(a φc + b sin φc), cos φc = clip(-a/b). 1 - μ² = t(2 - t) (exact for sharp lobes)."""
    import drjit as dr

    nodes, weights = _gl_rule()
    span = -_expm1(-kappa)
    s2, _ = _sin2_cos2(v)
    sin_v = dr.sqrt(s2)
    cos_v = dr.abs(v.z)
    total = kappa * 0.0
    for u, wq in zip(nodes, weights):
        t = -_log1p(-u * span) / kappa
        mu = 1.0 - t
        a = cos_v * mu
        b = sin_v * dr.sqrt(dr.maximum(t * (2.0 - t), 0.0))
        inside = b > dr.abs(a)
        r = -a / dr.select(inside, b, 1.0)
        phi_c = dr.select(inside, dr.acos(dr.clip(dr.select(inside, r, 0.0), -1.0, 1.0)),
                          dr.select(a > 0, dr.pi, 0.0))
        total += wq * 2.0 * (a * phi_c + b * dr.sin(phi_c))
    return total * span / (2.0 * dr.pi * vmf_kappa_I(kappa))


def G1_vMF_exact(v, alpha, alpha_y=None):
    """Paper eq. 7 integrated: G1 = cos θv / ∫⟨v, m⟩ D(m) dω_m, clamped to [0, 1]
    (fitlab.vmf.G1_exact)."""
    import drjit as dr

    return dr.clip(_safe_div(dr.abs(v.z), vmf_projected_area(v, vmf_kappa(alpha))), 0.0, 1.0)


def sample_m_vMF(u1, u2, alpha, alpha_y=None):
    """D(m) cos θm: t = 1 - cos θm has density ∝ (1 - t)e^{-κt} on [0, 1], CDF
    G(t) = (1 - e^{-κt} - (1 - e^{-κt}(1 + κt))/κ)/κI(κ); Newton from the truncated-exponential
    guess (fitlab.vmf.sample_m); φ = 2π u2."""
    import drjit as dr

    kappa = vmf_kappa(alpha)
    kI = vmf_kappa_I(kappa)
    t = -_log1p(-u1 * -_expm1(-kappa)) / kappa
    for _ in range(_NEWTON_STEPS):
        x = kappa * t
        e = dr.exp(-x)
        small, xs, xb = _where_small(x)
        tail = dr.select(small, xs * xs * _poly(xs, _TAIL), 1.0 - dr.exp(-xb) * (1.0 + xb))
        G = (-_expm1(-x) - tail / kappa) / kI
        g = kappa * (1.0 - t) * e / kI
        t = dr.clip(t - (G - u1) / dr.maximum(g, 1e-30), 0.0, 1.0)
    return _normal_from_cos2(dr.square(1.0 - t), t * (2.0 - t), u2)


# --------------------------------------------------------------------------------------------
# The families (names of fitlab.microfacet.REGISTRY)
# --------------------------------------------------------------------------------------------


class OwnFamily:
    """A family's Dr.Jit functions: D(m, α, α_y), G1(v, α, α_y), sample_m(u1, u2, α, α_y)."""

    def __init__(self, name, D, G1, sample_m, anisotropic, reference):
        self.name, self.D, self.G1, self.sample_m = name, D, G1, sample_m
        self.anisotropic, self.reference = anisotropic, reference


FAMILIES = {
    f.name: f
    for f in (
        OwnFamily("beckmann", D_Beckmann, G1_Beckmann, sample_m_Beckmann, True,
                  "Walter 2007 eqs 25, 26 (exact erf G1), 28-29; anisotropic Heitz 2014 eqs 83, 86"),
        OwnFamily("beckmann_rational", D_Beckmann, G1_Beckmann_rational, sample_m_Beckmann,
                  True, "Walter 2007 eqs 25, 27, 28-29; anisotropic Heitz 2014 eq. 86"),
        OwnFamily("phong", D_Phong, G1_Beckmann_rational, sample_m_Phong, False,
                  "Walter 2007 eqs 30-32, G1 by eq. 27"),
        OwnFamily("vmf", D_vMF, G1_vMF, sample_m_vMF, False,
                  "extended-NDF paper eqs 5-6, 8; kappa = 2/alpha^2"),
        OwnFamily("vmf_exact", D_vMF, G1_vMF_exact, sample_m_vMF, False,
                  "extended-NDF paper eqs 5-7 (eq. 7 by 16-point Gauss-Legendre)"),
    )
}


def get_family(name: str) -> OwnFamily:
    try:
        return FAMILIES[name]
    except KeyError:
        raise ValueError(f"no Dr.Jit microfacet family {name!r} here (ggx and beckmann are "
                         f"Mitsuba's own); choose one of {', '.join(FAMILIES)}") from None


# --------------------------------------------------------------------------------------------
# Fresnel
# --------------------------------------------------------------------------------------------


def fresnel_dielectric(cos_theta_i, eta):
    """Walter eq. 22 with Snell's law, as fitlab.fresnel.fresnel_dielectric: ``eta`` =
    η_inside/η_outside (the -normal side over the +normal side), ``cos_theta_i`` signed.
    Returns (F, cos_theta_t, eta_it, eta_ti); cos_theta_t signed opposite to cos_theta_i, 0
    under total internal reflection (F = 1). g² = η² - 1 + c² with η² - 1 = (η - 1)(η + 1) and
    g - c = (η² - 1)/(g + c): exact for η near 1."""
    import drjit as dr

    outside = cos_theta_i >= 0
    inv_eta = _safe_div(1.0, eta)
    eta_it = dr.select(outside, eta, inv_eta)
    eta_ti = dr.select(outside, inv_eta, eta)
    c = dr.abs(cos_theta_i)
    e2m1 = (eta_it - 1.0) * (eta_it + 1.0)
    g2 = e2m1 + c * c
    tir = g2 <= 0
    g = dr.select(tir, 0.0, dr.sqrt(dr.select(tir, 1.0, g2)))
    # F = 1/2 (g-c)²/(g+c)² (1 + (c(g+c) - 1)²/(c(g-c) + 1)²), g - c = (η² - 1)/(g + c)
    gc = g + c
    a = _safe_div(e2m1, gc * gc)
    g_c = _safe_div(e2m1, gc)
    b = _safe_div(c * gc - 1.0, c * g_c + 1.0)
    F = dr.select(tir, 1.0, dr.clip(0.5 * a * a * (1.0 + b * b), 0.0, 1.0))
    cos_t = dr.minimum(g * eta_ti, 1.0)
    return F, dr.select(outside, -cos_t, cos_t), eta_it, eta_ti


def fresnel_conductor(cos_i, n, k):
    """Exact unpolarized conductor Fresnel for the complex index n + ik relative to the incident
    medium (the closed form of fitlab.fresnel.fresnel_conductor_exact, pbrt-v3 FrConductor), a²
    rationalized where n² - k² - sin² < 0. ``n``, ``k``: mi.Spectrum; returns mi.Spectrum."""
    import drjit as dr
    import mitsuba as mi

    c = dr.clip(dr.abs(cos_i), 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    n, k = mi.Spectrum(n), mi.Spectrum(k)
    t0 = n * n - k * k - s2
    nk4 = 4.0 * n * n * k * k
    a2b2 = dr.sqrt(dr.maximum(t0 * t0 + nk4, 0.0))
    a2 = dr.select(t0 >= 0, 0.5 * (a2b2 + t0), _safe_div(0.5 * nk4, a2b2 - t0))
    a = dr.sqrt(dr.maximum(a2, 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * c * a
    Rs = _safe_div(t1 - t2, t1 + t2, 1.0)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    Rp = Rs * _safe_div(t3 - t4, t3 + t4, 1.0)
    return dr.clip(0.5 * (Rp + Rs), 0.0, 1.0)


# --------------------------------------------------------------------------------------------
# The boundaries
# --------------------------------------------------------------------------------------------


class _Microfacet:
    """What both boundaries share: the family's D, G1 (with Walter's sidedness factor), the
    sampling of D(m)|m·n| and the weight of eq. 41. ``sample`` also takes ``need_pdf`` (the
    adapter's keyword, components.py); the pdf is always computed."""

    nonspecular = True

    def __init__(self, family, alpha, alpha_y):
        self.family = get_family(family) if isinstance(family, str) else family
        if alpha_y is not None and not self.family.anisotropic:
            raise ValueError(f"the {self.family.name} distribution is isotropic only: give "
                             "alpha_y=None (anisotropic widths need beckmann_rational here)")
        self.alpha = _as_param(alpha)
        self.alpha_y = None if alpha_y is None else _as_param(alpha_y)

    def D(self, m):
        return self.family.D(m, self.alpha, self.alpha_y)

    def G1(self, v):
        return self.family.G1(v, self.alpha, self.alpha_y)

    def smith_G1(self, v, v_m):
        """G1 with the sidedness factor χ⁺((v·m)/(v·n)) (Walter eqs 23, 27), given v·m."""
        import drjit as dr

        return dr.select(v_m * v.z > 0, self.G1(v), 0.0)

    def sample_m(self, u):
        return self.family.sample_m(u.x, u.y, self.alpha, self.alpha_y)

    def eval_pdf(self, wi, wo, active=True):
        """(eval, pdf) of one direction pair (protocol.py)."""
        return self.eval(wi, wo, active), self.pdf(wi, wo, active)

    def weight_41(self, wi, wo, m, c):
        """Walter eq. 41: (i·m) G1(i, m) G1(o, m) / (|i·n||m·n|), wi on the upper side."""
        G = self.smith_G1(wi, c) * self.smith_G1(wo, _dot(wo, m))
        return _safe_div(c * G, wi.z * m.z)


class OwnRoughDielectric(_Microfacet):
    """Rough dielectric interface, Walter 2007 (BRDF eq. 20 + BTDF eq. 21, Fresnel eq. 22,
    sampling eqs 39-41), the twin of fitlab.models.rough_dielectric with ``sampling=standard``.
    ``eta`` = n_below / n_above; incidence from below is mirrored to the upper frame with
    1/eta (rough_dielectric._to_upper_frame)."""

    def __init__(self, family, alpha, alpha_y, eta):
        super().__init__(family, alpha, alpha_y)
        self.eta = _as_param(eta)

    def _upper(self, wi):
        import drjit as dr

        s = _sign_nonzero(wi.z)
        return s, dr.select(s > 0, self.eta, 1.0 / self.eta)

    def sample(self, wi, sample1, sample2, force, active=True, need_pdf=True):
        """Walter section 5.3 (fitlab.models.rough_dielectric.walter_sample): m ~ D(m)|m·n|,
        reflection if sample1 < F(i·m) (or as ``force`` says), reflect (eq. 39) or refract
        (eq. 40), weight by eq. 41 (times F or 1 - F when forced). pdf: the unforced density of
        wo, p_m(m) times F/(4|o·m|) (eq. 14) or (1 - F) η²|o·m|/(i·m + η o·m)² (eq. 17)."""
        import drjit as dr
        import mitsuba as mi

        s, eta = self._upper(wi)
        wi = _flip_z(wi, s)
        ci = wi.z
        m = self.sample_m(sample2)
        c = _dot(wi, m)
        F, cos_t, _, eta_ti = fresnel_dielectric(c, eta)
        chosen = sample1 < F
        choose_r = dr.select(force == FORCE_CHOOSE, chosen, force == FORCE_REFLECT)
        wo_r = 2.0 * c * m - wi  # Walter eq. 39
        wo_t = (eta_ti * c + cos_t) * m - eta_ti * wi  # Walter eq. 40
        wo = dr.select(choose_r, wo_r, wo_t)
        co = wo.z
        valid = active & (ci > 0) & (c > 0) & dr.select(choose_r, co > 0, co < 0)
        weight = self.weight_41(wi, wo, m, c)
        weight *= dr.select(force == FORCE_CHOOSE, 1.0, dr.select(choose_r, F, 1.0 - F))
        o_m = _dot(wo, m)
        p_m = self.D(m) * dr.abs(m.z)  # Walter eq. 24
        h = c + eta * o_m
        p = p_m * dr.select(choose_r, F * _safe_div(1.0, 4.0 * dr.abs(o_m)),
                            (1.0 - F) * _safe_div(eta * eta * dr.abs(o_m), h * h))
        weight = dr.select(valid, weight, 0.0)
        p = dr.select(valid, p, 0.0)
        return _flip_z(wo, s), mi.Spectrum(weight), p

    def _half(self, wi, wo):
        """Upper frame: (ci, co, eta, is_r, h unnormalized (eq. 13 or 16, turned to +z), |h|²,
        i·ĥ, o·ĥ), with wi, wo mirrored so that wi.z >= 0."""
        import drjit as dr
        import mitsuba as mi

        s, eta = self._upper(wi)
        ci, co = wi.z * s, wo.z * s
        is_r = co > 0
        e = dr.select(is_r, 1.0, eta)
        t = _sign_nonzero(ci + e * co)
        h = mi.Vector3f((wi.x + e * wo.x) * t, (wi.y + e * wo.y) * t, (ci + e * co) * t)
        h2 = _dot(h, h)
        r = dr.select(h2 > 0, dr.rsqrt(dr.select(h2 > 0, h2, 1.0)), 0.0)
        i_h = (wi.x * h.x + wi.y * h.y + ci * h.z) * r
        o_h = (wo.x * h.x + wo.y * h.y + co * h.z) * r
        return ci, co, eta, is_r, h, h2, r, i_h, o_h

    def eval(self, wi, wo, active=True):
        """f_r (Walter eq. 20) + f_t (eq. 21) in 1/sr without the cosine, radiance convention:
        F G D / (4|i·n||o·n|) or |i·h||o·h| η² (1 - F) G D / (|i·n||o·n| |h_t|²) with η_i = 1,
        η_o = η in the upper frame and h_t = i + η o unnormalized."""
        import drjit as dr
        import mitsuba as mi

        ci, co, eta, is_r, h, h2, _, i_h, o_h = self._half(wi, wo)
        F = fresnel_dielectric(dr.abs(i_h), eta)[0]
        D = self.D(h)
        wiu = mi.Vector3f(wi.x, wi.y, ci)
        wou = mi.Vector3f(wo.x, wo.y, co)
        G = self.smith_G1(wiu, i_h) * self.smith_G1(wou, o_h)  # Walter eq. 23
        num = dr.select(is_r, F, dr.abs(i_h * o_h) * eta * eta * (1.0 - F)) * G * D
        f = _safe_div(num, ci * dr.abs(co) * dr.select(is_r, 4.0, h2))
        return mi.Spectrum(dr.select(active & (ci > 0), f, 0.0))

    def pdf(self, wi, wo, active=True):
        """Density of ``sample`` (unforced): D(h)|ĥ·n| (eq. 24) times F/(4|o·ĥ|) (eq. 14) or
        (1 - F) η²|o·ĥ|/|h_t|² (eq. 17); 0 unless i·ĥ > 0 and (o·ĥ)(o·n) > 0."""
        import drjit as dr

        ci, co, eta, is_r, h, h2, r, i_h, o_h = self._half(wi, wo)
        F = fresnel_dielectric(dr.abs(i_h), eta)[0]
        p_m = self.D(h) * dr.abs(h.z) * r
        jac = dr.select(is_r, _safe_div(1.0, 4.0 * dr.abs(o_h)),
                        _safe_div(eta * eta * dr.abs(o_h), h2))
        p = p_m * dr.select(is_r, F, 1.0 - F) * jac
        facing = active & (i_h > 0) & (o_h * co > 0) & (ci > 0)
        return dr.select(facing, p, 0.0)


class OwnRoughConductor(_Microfacet):
    """Rough conductor, Walter 2007 eq. 20 with the exact conductor Fresnel (complex index
    n + ik relative to the medium above), one-sided (light from above), the twin of
    fitlab.models.rough_conductor with ``fresnel=exact``, ``sampling=standard``."""

    def __init__(self, family, alpha, alpha_y, n, k):
        super().__init__(family, alpha, alpha_y)
        self.n = _as_param(n, spectrum=True)
        self.k = _as_param(k, spectrum=True)

    def sample(self, wi, sample1, sample2, force=None, active=True, need_pdf=True):
        """m ~ D(m)|m·n|, o = reflect(i, m) (eq. 39), weight F · eq. 41, pdf p_m/(4 i·m)
        (eqs 14, 24). ``sample1`` and ``force`` are unused (opaque boundary)."""
        import drjit as dr

        ci = wi.z
        m = self.sample_m(sample2)
        c = _dot(wi, m)
        wo = 2.0 * c * m - wi
        valid = active & (ci > 0) & (c > 0) & (wo.z > 0)
        F = fresnel_conductor(c, self.n, self.k)
        w = dr.select(valid, self.weight_41(wi, wo, m, c), 0.0)
        p = _safe_div(self.D(m) * dr.abs(m.z), 4.0 * c)
        return wo, F * w, dr.select(valid, p, 0.0)

    def _half(self, wi, wo):
        """(h = i + o unnormalized (eq. 13), 1/|h|, i·ĥ, o·ĥ)."""
        import drjit as dr

        h = wi + wo  # Walter eq. 13
        h2 = _dot(h, h)
        r = dr.select(h2 > 0, dr.rsqrt(dr.select(h2 > 0, h2, 1.0)), 0.0)
        return h, r, _dot(wi, h) * r, _dot(wo, h) * r

    def eval(self, wi, wo, active=True):
        """Walter eq. 20: F(i·ĥ) G1(i, ĥ) G1(o, ĥ) D(h) / (4|i·n||o·n|); 0 unless both above."""
        import drjit as dr

        ci, co = wi.z, wo.z
        h, r, i_h, o_h = self._half(wi, wo)
        F = fresnel_conductor(i_h, self.n, self.k)
        G = self.smith_G1(wi, i_h) * self.smith_G1(wo, o_h)
        f = _safe_div(G * self.D(h), 4.0 * ci * co)
        ok = active & (ci > 0) & (co > 0)
        return F * dr.select(ok, f, 0.0)

    def pdf(self, wi, wo, active=True):
        """D(h)|ĥ·n| / (4 o·ĥ) (eqs 14, 24)."""
        import drjit as dr

        ci, co = wi.z, wo.z
        h, r, i_h, o_h = self._half(wi, wo)
        p = _safe_div(self.D(h) * dr.abs(h.z) * r, 4.0 * o_h)
        return dr.select(active & (ci > 0) & (co > 0) & (o_h > 0), p, 0.0)


__all__ = ["FAMILIES", "FORCE_CHOOSE", "FORCE_REFLECT", "FORCE_REFRACT", "OwnRoughConductor",
           "OwnRoughDielectric", "fresnel_conductor", "fresnel_dielectric", "get_family"]
