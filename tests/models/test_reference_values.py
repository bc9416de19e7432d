"""Reference values with their sources written next to them.

* Fresnel: Walter et al. 2007 eq. 22 against the textbook (Hecht, "Optics") amplitude
  coefficients; normal incidence, Walter's 0.04 for glass, total internal reflection, Brewster,
  Stokes reciprocity; the conductor formula against complex-index Fresnel and against the
  dielectric at k = 0; Schlick 1994; the Lazányi–Szirmay-Kalos 2005 approximation with its metal
  term (a from Hoffman 2019's 82°) against a NumPy transcription, and both it and the form Elek
  2010 appendix B prints (Schlick's) against what Elek's "5% at most" claim means for the
  appendix metals.
* Distributions and Smith G1 of Walter section 5.2 (eqs 25-27, 30, 33-34) and the Phong mapping.
* Full BSDF values: by hand at normal incidence, and over many directions against an independent
  plain-numpy transcription of Walter eqs 13, 16, 20-23 (tests/walter_numpy.py), which never
  calls fitlab.

Deterministic, float64.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import erf

from fitlab import eval_bsdf
from fitlab.fresnel import (
    CONDUCTOR_FRESNEL_METHODS,
    CONDUCTOR_PRESETS,
    fresnel_conductor_exact,
    fresnel_conductor_LazanyiSzirmayKalos,
    fresnel_dielectric_Walter2007,
    fresnel_schlick,
    schlick_f0,
)
from fitlab.microfacet import DISTRIBUTIONS, phong_exponent

try:  # tests/ is on sys.path under pytest's default (prepend) import mode
    import walter_numpy as ref
except ImportError:  # pragma: no cover - importlib mode, run from the repository root
    from tests import walter_numpy as ref

DEG = np.pi / 180.0
#: η_t/η_i on both sides of 1 (η < 1: the incident medium is the denser one).
ETAS = (1.0001, 1.05, 1.33, 1.5, 2.4, 5.0, 1 / 1.0001, 1 / 1.05, 1 / 1.33, 1 / 1.5, 1 / 2.4, 0.2)
ALPHAS = (1e-4, 1e-3, 0.01, 0.1, 0.2, 0.3, 0.5, 1.0)
#: (n, k) pairs: the Elek 2010 appendix A presets (R, G, B) and a few more.
METALS = [
    (n, k) for p in CONDUCTOR_PRESETS.values() for n, k in zip(p["n"], p["k"])
] + [(0.2, 3.9), (0.05, 10.0), (1.5, 0.1), (5.0, 20.0)]


def _a(x):
    return jnp.asarray(x, dtype=jnp.float64)


# Jitted: eager mode would compile every primitive again for every new array shape.
_fresnel_diel = jax.jit(fresnel_dielectric_Walter2007)
_fresnel_cond = jax.jit(fresnel_conductor_exact)
_lazanyi_jit = jax.jit(fresnel_conductor_LazanyiSzirmayKalos)
_schlick_cond_jit = jax.jit(CONDUCTOR_FRESNEL_METHODS["schlick"])
_D = {name: jax.jit(d.D) for name, d in DISTRIBUTIONS.items()}
_G1_jit = {name: jax.jit(d.G1) for name, d in DISTRIBUTIONS.items()}


def F_diel(c, eta):
    return np.asarray(_fresnel_diel(_a(c), _a(eta)))


def F_cond(c, n, k):
    return np.asarray(_fresnel_cond(_a(c), _a(n), _a(k)))


def _cos_grid(n=1001):
    return np.cos(np.linspace(0.0, 90.0, n) * DEG)


# ============================================================================================
# Dielectric Fresnel (Walter eq. 22)
# ============================================================================================


@pytest.mark.parametrize("eta", ETAS)
def test_fresnel_normal_incidence(eta):
    """Normal incidence: R = ((η - 1)/(η + 1))² (Hecht, from r_s = -r_p = (1 - η)/(1 + η)).
    The sign of cos_i does not matter (eq. 22 uses c = |i·m|)."""
    expected = ((eta - 1.0) / (eta + 1.0)) ** 2
    np.testing.assert_allclose(F_diel(1.0, eta), expected, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(F_diel(-1.0, eta), expected, rtol=1e-12, atol=1e-300)


def test_fresnel_glass_is_four_percent():
    """Walter section 5.1: "the Fresnel term is typically small at normal incidence (e.g., 0.04
    for glass with η_t = 1.5)": ((1.5 - 1)/(1.5 + 1))² = 0.04 exactly; also from inside."""
    assert abs(F_diel(1.0, 1.5) - 0.04) < 1e-15
    assert abs(F_diel(1.0, 1.0 / 1.5) - 0.04) < 1e-15
    assert abs(schlick_f0(1.5) - 0.04) < 1e-15


@pytest.mark.parametrize("eta", ETAS)
def test_fresnel_matches_textbook_s_and_p(eta):
    """Eq. 22 ([CT82]) equals (R_s + R_p)/2 of the textbook amplitude coefficients at every angle,
    total internal reflection included (both are 1 there)."""
    c = _cos_grid()
    np.testing.assert_allclose(F_diel(c, eta), ref.fresnel_textbook(c, eta), rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(F_diel(c, eta), ref.fresnel_walter_eq22(c, eta), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("eta", ETAS)
def test_fresnel_grazing_incidence_is_one(eta):
    """At grazing incidence (c = 0) eq. 22 gives 1/2 (g/g)² (1 + 1) = 1 (or TIR for η < 1)."""
    assert F_diel(0.0, eta) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("eta", [e for e in ETAS if e < 1])
def test_total_internal_reflection_beyond_critical_angle(eta):
    """From the denser side (η = η_t/η_i < 1) Snell has no solution beyond θc = asin η: F = 1
    (Walter: "if g is imaginary, this indicates total internal reflection and F = 1"). Below θc,
    F < 1, and F is continuous at θc (g → 0 gives F → 1)."""
    tc = np.arcsin(eta)
    beyond = np.linspace(tc + 1e-9, 90 * DEG, 500)
    assert np.all(F_diel(np.cos(beyond), eta) == 1.0)
    below = np.linspace(0.0, tc - 1e-3, 500)
    assert np.all(F_diel(np.cos(below), eta) < 1.0)
    assert F_diel(np.cos(tc - 1e-10), eta) > 0.99


@pytest.mark.parametrize("eta", ETAS)
def test_brewster_angle(eta):
    """At Brewster's angle θB = atan(η) the p-reflectance vanishes (Hecht), so the unpolarized
    F = R_s/2 with the textbook R_s = ((cos i - η cos t)/(cos i + η cos t))², which also equals
    sin²(θi - θt)/sin²(θi + θt) (Fresnel's sine law)."""
    tb = np.arctan(eta)
    ci = np.cos(tb)
    ct = np.sqrt(1.0 - np.sin(tb) ** 2 / eta**2)
    rs = ((ci - eta * ct) / (ci + eta * ct)) ** 2
    tt = np.arcsin(np.sin(tb) / eta)
    assert rs == pytest.approx(np.sin(tb - tt) ** 2 / np.sin(tb + tt) ** 2, rel=1e-9, abs=1e-15)
    _, rp = ref.fresnel_rs_rp(ci, eta)
    assert rp < 1e-25
    assert F_diel(ci, eta) == pytest.approx(rs / 2.0, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("eta", ETAS)
def test_fresnel_same_from_both_sides_at_snell_angles(eta):
    """Stokes relations (r' = -r, t t' = 1 - r²): the reflectance seen from the incident side at
    θi equals the reflectance seen from the other side at the refracted angle θt (sin θt =
    sin θi / η), so transmittance is reciprocal: F(θi, η) = F(θt, 1/η)."""
    ti = np.linspace(0.0, 89.99, 400) * DEG
    st = np.sin(ti) / eta
    ok = st < 1.0  # outside total internal reflection
    ti, tt = ti[ok], np.arcsin(st[ok])
    np.testing.assert_allclose(F_diel(np.cos(ti), eta), F_diel(np.cos(tt), 1.0 / eta), rtol=1e-9, atol=1e-14)


# ============================================================================================
# Conductor Fresnel
# ============================================================================================


@pytest.mark.parametrize("n", ETAS)
def test_conductor_exact_with_k0_equals_dielectric(n):
    """A "conductor" with k = 0 is a dielectric of index n: same reflectance at every angle,
    including total internal reflection for n < 1."""
    c = _cos_grid()
    np.testing.assert_allclose(F_cond(c, n, 0.0), F_diel(c, n), rtol=1e-9, atol=1e-13)


@pytest.mark.parametrize("n, k", METALS)
def test_conductor_exact_matches_complex_fresnel(n, k):
    """The closed form (pbrt-v3 FrConductor) equals the textbook amplitude coefficients with a
    complex index N = n + ik and complex cos θt = sqrt(1 - sin²θi/N²); normal incidence gives
    ((n-1)² + k²)/((n+1)² + k²) and grazing incidence 1."""
    c = _cos_grid()
    np.testing.assert_allclose(F_cond(c, n, k), ref.fresnel_complex(c, n, k), rtol=1e-9, atol=1e-13)
    assert F_cond(1.0, n, k) == pytest.approx(((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k), rel=1e-12)
    assert F_cond(0.0, n, k) == pytest.approx(1.0, abs=1e-12)


def test_schlick_limits():
    """Schlick 1994: F(θ) = F0 + (1 - F0)(1 - cos θ)⁵: F0 at normal incidence, 1 at grazing,
    F0 + (1 - F0)/32 at cos θ = 1/2; F0 = ((n-1)² + k²)/((n+1)² + k²)."""
    for f0 in (0.0, 0.04, 0.5, 0.95, 1.0):
        F = lambda c: float(fresnel_schlick(_a(c), _a(f0)))  # noqa: E731
        assert F(1.0) == pytest.approx(f0, abs=1e-15)
        assert F(0.0) == pytest.approx(1.0, abs=1e-15)
        assert F(-1.0) == pytest.approx(f0, abs=1e-15)
        assert F(0.5) == pytest.approx(f0 + (1 - f0) / 32.0, abs=1e-15)
    for n, k in METALS:
        assert float(schlick_f0(_a(n), _a(k))) == pytest.approx(F_cond(1.0, n, k), rel=1e-12)


def _lazanyi(c, n, k):
    return np.asarray(_lazanyi_jit(_a(c), _a(n), _a(k)))


def _lazanyi_numpy(c, n, k):
    """Lazányi & Szirmay-Kalos 2005, F = F_Schlick(μ) - a μ(1 - μ)^6, with a from Hoffman 2019
    (OpenPBR's F82: the approximation equals the exact reflectance at μ̄ = 1/7), in NumPy with
    the textbook complex-index reflectance (walter_numpy.fresnel_complex)."""
    f0 = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
    schlick = lambda mu: f0 + (1 - f0) * (1 - mu) ** 5  # noqa: E731
    mu = 1.0 / 7.0
    a = (schlick(mu) - ref.fresnel_complex(mu, n, k)) / (mu * (1 - mu) ** 6)
    return np.clip(schlick(c) - a * c * (1 - c) ** 6, 0.0, 1.0)


@pytest.mark.parametrize("n, k", METALS)
def test_lazanyi_exact_at_normal_grazing_and_82_degrees(n, k):
    """The correction term a μ(1 - μ)^6 vanishes at normal and grazing incidence, where Schlick
    with F0 = ((n-1)² + k²)/((n+1)² + k²) is exact (1 at grazing: (n-1)² + 4n = (n+1)²), and a is
    fitted so that F equals the exact reflectance at μ̄ = 1/7; elsewhere it is the NumPy form."""
    assert _lazanyi(1.0, n, k) == pytest.approx(F_cond(1.0, n, k), rel=1e-12)
    assert _lazanyi(0.0, n, k) == pytest.approx(1.0, abs=1e-14)
    assert _lazanyi(1.0 / 7.0, n, k) == pytest.approx(F_cond(1.0 / 7.0, n, k), rel=1e-12)
    c = _cos_grid(91)
    np.testing.assert_allclose(_lazanyi(c, n, k), _lazanyi_numpy(c, n, k), rtol=1e-10, atol=1e-14)


def test_lazanyi_accuracy_for_the_appendix_metals():
    """Elek 2010 section 3.1: Lazányi and Szirmay-Kalos "presented an accurate and inexpensive
    approximation of the full Fresnel term, which deviates from the full formula in 5% at most".

    Measured here against the exact complex-index reflectance on a 0.01° grid, for the appendix
    A metals at 690/550/450 nm (relative error, every channel):

    * the form Elek's appendix B prints, ((n-1)² + 4n(1-μ)⁵ + k²)/((n+1)² + k²), is Schlick's
      with F0 from (n, k) (fitlab's ``schlick``, equal to rounding): within 5% up to 55°, but
      copper reaches 5.7% (green, near 79°) and chromium 41% (red, near 82.6°);
    * the published form with its metal term (fitlab's ``lazanyi``, a from Hoffman's 82°):
      copper within 1% at every angle, chromium within 6% (5.8%, red, near 86.8°).

    The limits are the measured ones, rounded, so a change of either formula is noticed."""
    th = np.linspace(0.0, 90.0, 9001) * DEG
    c = np.cos(th)
    worst = {}
    for name, fn in (("schlick", _schlick_cond_jit), ("lazanyi", _lazanyi_jit)):
        for metal in ("copper", "chromium"):
            p = CONDUCTOR_PRESETS[metal]
            rel = np.stack([
                np.abs(np.asarray(fn(_a(c), _a(n), _a(k))) - ref.fresnel_complex(c, n, k))
                / ref.fresnel_complex(c, n, k) for n, k in zip(p["n"], p["k"])
            ])
            assert rel[:, th <= 55 * DEG].max() < 0.05, (name, metal)
            worst[name, metal] = rel.max()
    assert 0.056 < worst["schlick", "copper"] < 0.06
    assert 0.40 < worst["schlick", "chromium"] < 0.42
    assert worst["lazanyi", "copper"] < 0.01
    assert 0.055 < worst["lazanyi", "chromium"] < 0.06


# ============================================================================================
# Distributions and Smith G1 (Walter section 5.2)
# ============================================================================================


@pytest.mark.parametrize("name", list(DISTRIBUTIONS))
@pytest.mark.parametrize("alpha", ALPHAS)
def test_D_at_the_normal(name, alpha):
    """D(n) = 1/(π α²): eq. 25 (Beckmann) and eq. 33 (GGX) at θm = 0, and eq. 30 (Phong) with
    (α_p + 2)/(2π) = 1/(π α²) under the mapping α_p = 2α⁻² - 2."""
    d = _D[name]
    n = _a([0.0, 0.0, 1.0])
    assert float(d(n, _a(alpha))) == pytest.approx(1.0 / (np.pi * alpha**2), rel=1e-12)
    assert float(d(7.5 * n, _a(alpha))) == pytest.approx(1.0 / (np.pi * alpha**2), rel=1e-12)


@pytest.mark.parametrize("name", list(DISTRIBUTIONS))
@pytest.mark.parametrize("alpha", ALPHAS)
def test_D_matches_walter_equations(name, alpha):
    """D(m) over θm in [0°, 90°] and random azimuths against eqs 25/30/33 written with
    trigonometry; fitlab takes unnormalized m (scaled here by factors in [1e-3, 1e3]); D = 0 for
    m·n <= 0 (the χ⁺ factor)."""
    rng = np.random.default_rng(1)
    theta = np.concatenate([np.linspace(0.0, 89.999, 300) * DEG, [89.9999999 * DEG]])
    phi = rng.uniform(0, 2 * np.pi, theta.size)
    scale = 10.0 ** rng.uniform(-3, 3, theta.size)
    m = ref.sph(theta, phi) * scale[:, None]
    got = np.asarray(_D[name](_a(m), _a(alpha)))
    expected = ref.D_ref(name, np.cos(theta), alpha, tan2=np.tan(theta) ** 2)
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-300)
    below = ref.sph(np.linspace(90.0, 180.0, 50) * DEG, phi[:50])
    below[:, 2] = np.minimum(below[:, 2], 0.0)  # m_z <= 0 (cos 90° would be +6e-17)
    assert np.all(np.asarray(_D[name](_a(below), _a(alpha))) == 0.0)


def test_phong_exponent_mapping():
    """Walter section 5.2: α_p = 2 α_b⁻² - 2 makes Phong and Beckmann similar; Figure 8 pairs
    α_b = 0.2 with α_p = 48. α = 1 gives α_p = 0 (D = 1/π, a cosine-weighted uniform lobe)."""
    assert float(phong_exponent(0.2)) == pytest.approx(48.0, rel=1e-12)
    assert float(phong_exponent(1.0)) == 0.0
    for a in ALPHAS:
        assert float(phong_exponent(a)) == pytest.approx(2.0 / a**2 - 2.0, rel=1e-12)
    m = ref.sph(np.array([0.0, 30.0, 60.0, 89.0]) * DEG, np.zeros(4))
    np.testing.assert_allclose(np.asarray(_D["phong"](_a(m), _a(1.0))), 1 / np.pi, rtol=1e-12)


def _G1(name, v, alpha):
    return np.asarray(_G1_jit[name](_a(v), _a(alpha)))


def test_ggx_G1_closed_form_values():
    """Eq. 34, G1 = 2/(1 + sqrt(1 + α² tan²θv)), by hand: α = 1, θ = 45° gives 2/(1 + √2);
    α = 0.5, θ = 60° (tan² = 3) gives 2/(1 + √1.75); α = 0.2, θ = 80° gives
    2/(1 + sqrt(1 + 0.04 tan²80°)); 1 at the normal, 0 at the horizon, no sidedness (v_z < 0
    gives the same value)."""
    cases = [
        (1.0, 45.0, 2.0 / (1.0 + np.sqrt(2.0))),
        (0.5, 60.0, 2.0 / (1.0 + np.sqrt(1.75))),
        (0.2, 80.0, 2.0 / (1.0 + np.sqrt(1.0 + 0.04 * np.tan(80 * DEG) ** 2))),
        (0.3, 0.0, 1.0),
        (0.3, 90.0, 0.0),
    ]
    for alpha, tdeg, expected in cases:
        v = ref.sph(tdeg * DEG, 0.7)
        assert float(_G1("ggx", v, alpha)) == pytest.approx(expected, rel=1e-12, abs=1e-15)
        assert float(_G1("ggx", v * np.array([1, 1, -1]), alpha)) == pytest.approx(expected, rel=1e-12, abs=1e-15)
    assert 2.0 / (1.0 + np.sqrt(2.0)) == pytest.approx(0.8284271247461902, rel=1e-15)


def _g1_grid():
    theta = np.concatenate([np.linspace(0.0, 89.9, 600), [89.99, 89.999, 90.0]]) * DEG
    return theta, ref.sph(theta, 0.3 * np.ones_like(theta))


@pytest.mark.parametrize("alpha", ALPHAS)
def test_G1_matches_walter_equations(alpha):
    """Eq. 26 (exact Beckmann with erf, written out with scipy), eq. 27 (rational, Beckmann and
    Walter's choice for Phong) and eq. 34 (GGX), over θv in [0°, 90°]."""
    theta, v = _g1_grid()
    for name in DISTRIBUTIONS:
        np.testing.assert_allclose(
            _G1(name, v, alpha), ref.G1_ref(name, np.cos(theta), alpha), rtol=1e-11, atol=1e-14,
            err_msg=name,
        )


def test_rational_G1_within_035_percent_of_exact():
    """Walter: eq. 27 is a rational approximation to the Smith G1 of eq. 26 "with relative error
    of less than 0.35%". Checked on a dense grid of a = 1/(α tan θv) covering (0, ∞) (the
    measured maximum is about 0.32%, near a = 0.23)."""
    worst = 0.0
    for alpha in (1e-3, 0.01, 0.1, 0.3, 1.0):
        theta = np.linspace(1e-3, 89.9999, 20001) * DEG
        v = ref.sph(theta, np.zeros_like(theta))
        exact = _G1("beckmann", v, alpha)
        approx = _G1("beckmann_rational", v, alpha)
        ok = exact > 1e-3  # the relative error at a → 0 is a ratio of two vanishing values
        worst = max(worst, float(np.max(np.abs(approx[ok] / exact[ok] - 1.0))))
    assert worst < 0.0035
    # And directly in a (G1 depends on a only), a in [1e-4, 30]
    a = np.geomspace(1e-4, 30.0, 100001)
    exact = 2.0 / (1.0 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))
    rational = np.where(a < 1.6, (3.535 * a + 2.181 * a * a) / (1 + 2.276 * a + 2.577 * a * a), 1.0)
    assert np.max(np.abs(rational / exact - 1.0)) < 0.0035


# ============================================================================================
# Full BSDF values
# ============================================================================================


def _eval(model, params, wi, wo, options=None):
    return np.asarray(eval_bsdf(model, params, np.asarray(wi, float), np.asarray(wo, float), options))


def test_hand_computed_values_at_normal_incidence():
    """Worked by hand from Walter eqs 20-22 with G = 1 (G1(n) = 1) and D(n) = 1/(π α²):

    * dielectric reflection, wi = wo = n, α = 0.5, η = 1.5:  f_r = F D/4 = 0.04 (4/π)/4 = 0.04/π;
    * transmission wi = n, wo = -n: h_t = -(n + 1.5(-n)) = 0.5 n, i·h = 1, o·h = -1, so
      f_t = η_o² (1-F) D / (η_i - η_o)² = 2.25 · 0.96 · (4/π) / 0.25 = 34.56/π;
    * the reverse (from inside, η_i = 1.5, η_o = 1): f_t = 1 · 0.96 · (4/π) / 0.25 = 15.36/π,
      and 34.56/15.36 = 2.25 = η_o²/η_i² (the non-reciprocity of eq. 18);
    * conductor (n, k) = (0.2, 3.9), Beckmann α = 0.2: F0 = (0.64 + 15.21)/(1.44 + 15.21) =
      15.85/16.65, f_r = F0 D/4 = (15.85/16.65)/(4 π 0.04);
    * Lambertian ρ = 0.5: 0.5/π; Oren–Nayar at the normal (sin α tan β = 0): ρ A/π with
      A = 1 - σ²/(2(σ² + 0.33)), σ = 0.5: A = 1 - 0.25/1.16.
    """
    n, m = [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]
    for dist in DISTRIBUTIONS:
        o = {"distribution": dist}
        p = {"alpha": 0.5, "eta": 1.5}
        assert _eval("rough_dielectric", p, n, n, o) == pytest.approx(0.04 / np.pi, rel=1e-12)
        assert _eval("rough_dielectric", p, n, m, o) == pytest.approx(34.56 / np.pi, rel=1e-12)
        assert _eval("rough_dielectric", p, m, n, o) == pytest.approx(15.36 / np.pi, rel=1e-12)
        assert _eval("rough_dielectric", p, m, m, o) == pytest.approx(0.04 / np.pi, rel=1e-12)
    for dist in ("beckmann", "beckmann_rational"):
        f = _eval("rough_conductor", {"alpha": 0.2, "n": 0.2, "k": 3.9}, n, n, {"distribution": dist})
        assert f == pytest.approx((15.85 / 16.65) / (4 * np.pi * 0.04), rel=1e-12)
    assert _eval("lambertian", {"albedo": 0.5}, n, n) == pytest.approx(0.5 / np.pi, rel=1e-15)
    f = _eval("oren_nayar", {"albedo": 0.5, "sigma": 0.5}, n, n)
    assert f == pytest.approx(0.5 * (1 - 0.25 / 1.16) / np.pi, rel=1e-12)


def _random_pairs(rng, n, kind):
    """Unit direction pairs: 'rr' both above; 'rt' above/below; 'tr' below/above; 'tt' below."""
    def up(k):
        th = np.arccos(rng.uniform(0.02, 1.0, k))
        return ref.sph(th, rng.uniform(0, 2 * np.pi, k))
    wi, wo = up(n), up(n)
    if kind[0] == "t":
        wi = wi * np.array([1, 1, -1])
    if kind[1] == "t":
        wo = wo * np.array([1, 1, -1])
    return wi, wo


def _lobe_pairs(rng, n, kind, dist, alpha, eta):
    """n pairs inside the lobes: wo is the mirror (eq. 39) or refracted (eq. 40) direction of wi
    about a microfacet normal drawn from D(m) cos θm (eqs 28, 31, 35), all in numpy; candidates
    on the wrong side or in total internal reflection are replaced (fixed n: one compilation)."""
    out_i, out_o = [], []
    while len(out_i) < n:
        wi, _ = _random_pairs(rng, 1, kind)
        i = wi[0]
        mm = ref.sample_m_ref(dist, rng.uniform(0, 1), rng.uniform(0, 1), alpha)
        s = 1.0 if i[2] > 0 else -1.0
        iu = i * np.array([1, 1, s])
        if iu @ mm <= 0:
            continue
        if kind[0] == kind[1]:
            o = 2 * (iu @ mm) * mm - iu
            if o[2] <= 0:
                continue
        else:
            o = ref.refract_ref(iu, mm, eta if s > 0 else 1 / eta)
            if o is None or o[2] >= 0:
                continue
        out_i.append(i)
        out_o.append(o * np.array([1, 1, s]))
    return np.array(out_i), np.array(out_o)


@pytest.mark.parametrize("dist", list(DISTRIBUTIONS))
def test_rough_dielectric_against_numpy_walter(dist):
    """rough_dielectric against eqs 13, 16, 20-23 in numpy with absolute indices (outside 1,
    inside η): reflection outside and inside, transmission in both directions, η on both sides of
    1 (TIR from the denser side included); random pairs and pairs inside the lobes."""
    rng = np.random.default_rng(7)
    for alpha in (0.05, 0.5):
        for eta in (1.5, 1 / 1.33, 2.4, 1.05):
            for kind in ("rr", "rt", "tr", "tt"):
                wi, wo = _random_pairs(rng, 40, kind)
                li, lo = _lobe_pairs(rng, 40, kind, dist, alpha, eta)
                wi, wo = np.concatenate([wi, li]), np.concatenate([wo, lo])
                got = _eval("rough_dielectric", {"alpha": alpha, "eta": eta}, wi, wo, {"distribution": dist})
                expect = []
                for i, o in zip(wi, wo):
                    n_i, n_t = (1.0, eta) if i[2] > 0 else (eta, 1.0)
                    expect.append(ref.walter_bsdf(dist, alpha, n_i, n_t, i, o))
                # rtol: near the critical angle 1 - F ~ sqrt(g²) (eq. 22) turns rounding
                # differences of g² = η² - 1 + c² into relative differences up to ~1e-6
                np.testing.assert_allclose(got, expect, rtol=1e-6, atol=1e-300,
                                           err_msg=f"{alpha=} {eta=} {kind}")
                assert np.all(got[40:] > 0), (alpha, eta, kind)  # in-lobe pairs: F, G, D > 0


@pytest.mark.parametrize("fresnel", ["exact", "schlick", "lazanyi"])
@pytest.mark.parametrize("dist", list(DISTRIBUTIONS))
def test_rough_conductor_against_numpy_walter(dist, fresnel):
    """rough_conductor against eq. 20 in numpy, with F from complex-index Fresnel, Schlick with
    F0 = ((n-1)² + k²)/((n+1)² + k²), or Lazányi–Szirmay-Kalos with Hoffman's a; zero on the
    back side."""
    rng = np.random.default_rng(11)
    fresnels = {
        "exact": ref.fresnel_complex,
        "schlick": lambda c, n, k: (((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k))
        + (1 - ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)) * (1 - c) ** 5,
        "lazanyi": _lazanyi_numpy,
    }
    for alpha in (0.05, 0.5):
        for n, k in [(0.213, 4.05), (3.84, 4.37), (1.5, 0.0)]:
            wi, wo = _random_pairs(rng, 40, "rr")
            li, lo = _lobe_pairs(rng, 40, "rr", dist, alpha, 1.0)
            wi, wo = np.concatenate([wi, li]), np.concatenate([wo, lo])
            p = {"alpha": alpha, "n": n, "k": k}
            got = _eval("rough_conductor", p, wi, wo, {"distribution": dist, "fresnel": fresnel})
            expect = [
                ref.walter_bsdf(dist, alpha, 1.0, 1.0, i, o, fresnel=lambda c: fresnels[fresnel](c, n, k))
                for i, o in zip(wi, wo)
            ]
            np.testing.assert_allclose(got, expect, rtol=1e-9, atol=1e-300)
            assert np.all(got[40:] > 0)
            for kind in ("rt", "tr", "tt"):
                wi, wo = _random_pairs(rng, 20, kind)
                assert np.all(_eval("rough_conductor", p, wi, wo, {"distribution": dist}) == 0.0)


def test_diffuse_models_against_their_formulas():
    """Lambertian ρ/π; Oren–Nayar qualitative model against its trigonometric form
    ρ/π (A + B max(0, cos(φi - φo)) sin α tan β) (fitlab uses a trigonometry-free rewrite);
    both zero unless wi and wo are above the surface."""
    rng = np.random.default_rng(3)
    wi, wo = _random_pairs(rng, 200, "rr")
    for rho in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(_eval("lambertian", {"albedo": rho}, wi, wo), rho / np.pi, rtol=1e-15)
        for sigma in (0.0, 0.2, 0.6, np.pi / 2):
            got = _eval("oren_nayar", {"albedo": rho, "sigma": sigma}, wi, wo)
            expect = [ref.oren_nayar_ref(rho, sigma, i, o) for i, o in zip(wi, wo)]
            np.testing.assert_allclose(got, expect, rtol=1e-11, atol=1e-15)
    for kind in ("rt", "tr", "tt"):
        wi, wo = _random_pairs(rng, 20, kind)
        assert np.all(_eval("lambertian", {"albedo": 0.5}, wi, wo) == 0.0)
        assert np.all(_eval("oren_nayar", {"albedo": 0.5, "sigma": 0.3}, wi, wo) == 0.0)
