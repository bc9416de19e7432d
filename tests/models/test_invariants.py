"""Physical invariants checked by deterministic quadrature (no Monte Carlo noise).

* Walter et al. 2007 eq. 4, ∫D(m)(m·n)dω = 1, and eq. 3, ∫D(m)(v·m)dω = v·n, for every
  distribution and α from 1e-4 to 1; the Smith consistency ∫G1(v)⟨v·m⟩D(m)dω = v·n that the
  separable G relies on (exact for GGX and exact Beckmann, 0.35% for eq. 27).
* Reciprocity f(i,o) = f(o,i) of every BRDF (both sides of the dielectric), and the BTDF relation
  f_t(i,o)/η_o² = f_t(o,i)/η_i² (Walter after eq. 18), with absolute indices (outside 1, inside η).
* White furnace: directional albedo ∫f|cos θo|dωo <= 1 for every model over roughness, index
  (η < 1 and incidence from inside included), incidence angle; sane lower bounds (single-scattering
  Smith models lose energy, mostly at grazing angles and large α).
* Limits: α → 0 gives a Fresnel-weighted mirror/refractor, η → 1 transmits everything, and the
  transmitted lobe obeys Snell's law.

The microfacet albedos are integrated over the microfacet normal: wo is generated from m by the
mirror/refraction maps (Walter eqs 39, 40) and dωo = |∂ωo/∂ωm| dωm is the inverse of the
Jacobians of eqs 14 and 17, all in numpy; m runs over Walter's sampling maps (eqs 28, 31, 35)
with their density D(m) cos θm written out in numpy (tests/walter_numpy.py), on a Gauss-Legendre
grid, so even α = 1e-4 lobes are resolved. fitlab contributes only the BSDF values.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab import eval_bsdf, sample_bsdf
from fitlab.microfacet import DISTRIBUTIONS

try:  # tests/ is on sys.path under pytest's default (prepend) import mode
    import walter_numpy as ref
except ImportError:  # pragma: no cover - importlib mode, run from the repository root
    from tests import walter_numpy as ref

DEG = np.pi / 180.0
DISTS = tuple(DISTRIBUTIONS)
ALPHAS = (1e-4, 1e-3, 0.01, 0.1, 0.3, 1.0)


def _a(x):
    return jnp.asarray(x, dtype=jnp.float64)


_D = {name: jax.jit(d.D) for name, d in DISTRIBUTIONS.items()}
_G1 = {name: jax.jit(d.G1) for name, d in DISTRIBUTIONS.items()}


@functools.lru_cache(maxsize=None)
def _leggauss(n):
    """Gauss-Legendre nodes and weights on [-1, 1], computed once per order (an eigenvalue
    problem of size n: 57 of them made the Smith test take 8 s per α)."""
    return np.polynomial.legendre.leggauss(n)


def _gauss(a, b, n):
    x, w = _leggauss(n)
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


def _theta_nodes(alpha, a=0.0, b=1.0, n=400):
    """Nodes and weights in θm for ∫...dθ over [θ(a), θ(b)] with tan θ = α tan(πx/2): the
    substitution puts the peak of width α in the middle of x in [0, 1] for any α (for GGX,
    2π D cos θ sin θ dθ becomes (π/2) sin(πx) dx)."""
    x, w = _gauss(a, b, n)
    t = np.tan(0.5 * np.pi * x)
    theta = np.arctan(alpha * t)
    dtheta_dx = alpha * 0.5 * np.pi * (1.0 + t * t) / (1.0 + alpha * alpha * t * t)
    return theta, w * dtheta_dx


# ============================================================================================
# Distribution normalization (Walter eqs 3, 4) and Smith consistency
# ============================================================================================


@pytest.mark.parametrize("name", DISTS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_ndf_normalization_eq4(name, alpha):
    """∫ D(m) (m·n) dωm = 2π ∫ D(θ) cos θ sin θ dθ = 1 (Walter eq. 4)."""
    theta, w = _theta_nodes(alpha)
    m = ref.sph(theta, np.zeros_like(theta))
    D = np.asarray(_D[name](_a(m), _a(alpha)))
    total = 2.0 * np.pi * np.sum(w * D * np.cos(theta) * np.sin(theta))
    assert total == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("name", DISTS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_projected_area_eq3(name, alpha):
    """∫ D(m)(v·m) dωm = v·n for any v (Walter eq. 3, signed), on a (θm, φm) product grid, with
    D evaluated at unnormalized m (random lengths) and a random azimuth offset (isotropy)."""
    rng = np.random.default_rng(5)
    theta, w = _theta_nodes(alpha, n=300)
    nphi = 24
    phi = (np.arange(nphi) + rng.uniform()) * 2 * np.pi / nphi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    m = ref.sph(T, P)
    scale = 10.0 ** rng.uniform(-2, 2, T.shape)
    D = np.asarray(_D[name](_a(m * scale[..., None]), _a(alpha)))
    dA = (w * np.sin(theta))[:, None] * (2 * np.pi / nphi)
    for tv in (0.0, 30.0, 60.0, 89.0, 90.0, 120.0, 180.0):
        v = ref.sph(tv * DEG, 0.4)
        total = np.sum(D * (m @ v) * dA)
        assert total == pytest.approx(np.cos(tv * DEG), abs=1e-9), tv


def _phi_integral_of_positive_part(tv, theta):
    """∫_0^{2π} max(0, v·m) dφm for v at θv and m at θm: with A = sin θv sin θm,
    B = cos θv cos θm >= 0 it is 2πB if B >= A, else 2(A sin φ0 + B φ0), cos φ0 = -B/A."""
    A = np.sin(tv) * np.sin(theta)
    B = np.cos(tv) * np.cos(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        p0 = np.arccos(np.clip(-B / A, -1.0, 1.0))
        return np.where(B >= A, 2 * np.pi * B, 2 * (A * np.sin(p0) + B * p0))


def _smith_ratio(name, alpha, tv):
    """G1(v) ∫⟨v·m⟩D(m)dωm / (v·n): 1 exactly when G1 is the Smith G1 of D. The φ integral is
    analytic; the θ integral is split at the kink θm = 90° - θv."""
    tk = 0.5 * np.pi - tv
    xk = 2 / np.pi * np.arctan(np.tan(tk) / alpha) if tv > 0 else 1.0
    total = 0.0
    for a, b in ((0.0, xk), (xk, 1.0)):
        if b > a:
            theta, w = _theta_nodes(alpha, a, b, n=300)
            m = ref.sph(theta, np.zeros_like(theta))
            D = np.asarray(_D[name](_a(m), _a(alpha)))
            total += np.sum(w * D * _phi_integral_of_positive_part(tv, theta) * np.sin(theta))
    g1 = float(_G1[name](_a(ref.sph(tv, 0.0)), _a(alpha)))
    return g1 * total / np.cos(tv)


SMITH_ANGLES = (0.0, 10.0, 30.0, 45.0, 60.0, 70.0, 80.0, 85.0, 88.0, 89.5)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_smith_G1_consistency(alpha):
    """Visible projected area: ∫ G1(v,m)(v·m)⁺ D(m) dωm = v·n (the Smith G1 is defined by it;
    Walter eq. 3 restricted to visible microfacets). Exact for GGX (eq. 34) and the erf
    Beckmann G1 (eq. 26); eq. 27 is within its 0.35% error."""
    for tvd in SMITH_ANGLES:
        tv = tvd * DEG
        for name in ("ggx", "beckmann"):
            assert _smith_ratio(name, alpha, tv) == pytest.approx(1.0, abs=1e-9), (name, tvd)
        assert abs(_smith_ratio("beckmann_rational", alpha, tv) - 1.0) < 0.0035, tvd


def test_phong_with_eq27_G1_is_only_consistent_for_narrow_lobes():
    """Walter recommends eq. 27 (the Beckmann G1) for Phong "based on its similarity to
    Beckmann" under α_p = 2α⁻² - 2, which holds for narrow lobes only. Measured here: the Smith
    identity holds within 0.6% for α <= 0.1, but the visible area is overestimated by up to
    3.4% at α = 0.3 and 76% at α = 1 (α_p = 0: D = 1/π, far from Beckmann α = 1) near grazing.
    Consequence: rough Phong models can reflect more than they receive (see the furnace test).
    This documents a property of the recommended approximation, not of fitlab's code."""
    narrow = max(abs(_smith_ratio("phong", a, t * DEG) - 1) for a in (1e-3, 0.01, 0.1) for t in SMITH_ANGLES)
    assert narrow < 0.006
    wide = max(_smith_ratio("phong", 1.0, t * DEG) for t in SMITH_ANGLES)
    assert 1.7 < wide < 1.8


# ============================================================================================
# Reciprocity
# ============================================================================================


def _eval(model, params, wi, wo, options=None):
    return np.asarray(eval_bsdf(model, params, np.asarray(wi, float), np.asarray(wo, float), options))


def _hemi(rng, n, sign):
    th = np.arccos(rng.uniform(0.0, 1.0, n))
    return ref.sph(th, rng.uniform(0, 2 * np.pi, n)) * np.array([1.0, 1.0, sign])


MODEL_CASES = (
    [("rough_dielectric", {"distribution": d}, {"alpha": a, "eta": e})
     for d in DISTS for a in (1e-3, 0.05, 0.5, 1.0) for e in (1.0001, 1.5, 2.4, 1 / 1.5, 0.2)]
    + [("rough_conductor", {"distribution": d, "fresnel": f}, {"alpha": a, "n": 0.213, "k": 4.05})
       for d in DISTS for f in ("exact", "schlick", "lazanyi") for a in (1e-3, 0.3, 1.0)]
    + [("lambertian", {}, {"albedo": 0.7}),
       ("oren_nayar", {}, {"albedo": 0.7, "sigma": 0.4}),
       ("oren_nayar", {}, {"albedo": 1.0, "sigma": np.pi / 2})]
)


def _case_id(case):
    model, opts, params = case
    return "-".join([model, *opts.values(), *(f"{k}={v:.4g}" for k, v in params.items())])


@pytest.mark.parametrize("case", MODEL_CASES, ids=_case_id)
def test_reciprocity_of_reflection(case):
    """f(i,o) = f(o,i) for both directions on the same side (Helmholtz reciprocity of the BRDF;
    for the dielectric also internal reflection on the inside): random pairs plus pairs in the
    specular lobe (o within about α of the mirror direction of i)."""
    model, opts, params = case
    rng = np.random.default_rng(17)
    sides = (1.0, -1.0) if model == "rough_dielectric" else (1.0,)
    for s in sides:
        wi, wo = _hemi(rng, 200, s), _hemi(rng, 200, s)
        mirror = wi * np.array([-1.0, -1.0, 1.0]) + 0.5 * params.get("alpha", 0.1) * rng.normal(size=wi.shape)
        mirror[:, 2] = np.abs(mirror[:, 2]) * s
        wo = np.concatenate([wo, mirror / np.linalg.norm(mirror, axis=1, keepdims=True)])
        wi = np.concatenate([wi, wi])
        f_io, f_oi = _eval(model, params, wi, wo, opts), _eval(model, params, wo, wi, opts)
        np.testing.assert_allclose(f_io, f_oi, rtol=1e-9, atol=1e-300)
        assert np.count_nonzero(f_io) > 100


def _refracted_pairs(rng, n, dist, alpha, eta):
    """n pairs (wi above, wo below) in the transmitted lobe: wo refracts wi (Walter eq. 40, numpy)
    about a normal drawn from D(m) cos θm; where that fails (TIR, wrong side) a random pair."""
    smax = min(1.0, 0.95 * eta)  # incidence angles that can refract at all
    wi = ref.sph(np.arccos(rng.uniform(np.sqrt(1 - smax**2), 1.0, n)), rng.uniform(0, 2 * np.pi, n))
    m = ref.sample_m_ref(dist, rng.uniform(size=n), rng.uniform(size=n), alpha)
    c = np.sum(wi * m, 1)
    k = 1 + (c * c - 1) / eta**2
    ok = (c > 0) & (k > 0)
    wo = (c / eta - np.sqrt(np.where(ok, k, 1.0)))[:, None] * m - wi / eta
    ok &= wo[:, 2] < 0
    return wi, np.where(ok[:, None], wo, _hemi(rng, n, -1.0))


@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize("eta", (1.0001, 1.05, 1.5, 2.4, 1 / 1.5, 0.2))
def test_btdf_index_relation(dist, eta):
    """Walter after eq. 18: f_t(i,o)/η_o² = f_t(o,i)/η_i² with η_i, η_o the absolute indices of
    the sides of i and o (outside 1, inside η): eq. 21 transports radiance, which is not
    reciprocal across an index change. Pairs in the transmitted lobe and random pairs."""
    rng = np.random.default_rng(23)
    for alpha in (1e-3, 0.1, 0.6):
        li, lo = _refracted_pairs(rng, 300, dist, alpha, eta)
        wi = np.concatenate([li, _hemi(rng, 300, 1.0)])
        wo = np.concatenate([lo, _hemi(rng, 300, -1.0)])
        p = {"alpha": alpha, "eta": eta}
        o = {"distribution": dist}
        f_io = _eval("rough_dielectric", p, wi, wo, o)  # outside (η_i = 1) -> inside (η_o = η)
        f_oi = _eval("rough_dielectric", p, wo, wi, o)  # inside (η_i = η) -> outside (η_o = 1)
        # rtol: near the critical angle 1 - F ~ sqrt(g²) (eq. 22) turns the rounding of g² =
        # η² - 1 + c² in the two evaluation paths into relative differences up to ~1e-6
        np.testing.assert_allclose(f_io / eta**2, f_oi / 1.0, rtol=1e-5, atol=1e-300)
        assert np.count_nonzero(f_io[:300]) > 100


@pytest.mark.parametrize("dist", DISTS)
def test_inside_incidence_is_the_mirrored_configuration(dist):
    """η = n_inside/n_outside: seen from inside, the interface is the same interface seen from
    outside with the relative index 1/η (mirror the configuration through the tangent plane)."""
    rng = np.random.default_rng(29)
    flip = np.array([1.0, 1.0, -1.0])
    for eta in (1.5, 1 / 1.33, 2.4):
        wi = _hemi(rng, 200, -1.0)
        wo = np.concatenate([_hemi(rng, 100, -1.0), _hemi(rng, 100, 1.0)])
        p, q = {"alpha": 0.2, "eta": eta}, {"alpha": 0.2, "eta": 1 / eta}
        o = {"distribution": dist}
        np.testing.assert_allclose(
            _eval("rough_dielectric", p, wi, wo, o), _eval("rough_dielectric", q, wi * flip, wo * flip, o),
            rtol=1e-12, atol=1e-300,
        )


# ============================================================================================
# White furnace
# ============================================================================================

N1, N2 = 128, 48  # Gauss-Legendre nodes in s (u1 = 3s² - 2s³), uniform nodes in u2


@functools.lru_cache(maxsize=None)
def _m_grid(dist, alpha):
    """Microfacet normals over Walter's sampling map and the weights of ∫ g(m) dωm
    (= ∫∫ g(m(u)) / (D(m) cos θm) du1 du2). u1 = 3s² - 2s³ (du1/ds = 6s(1-s)) removes the
    1/sqrt endpoint singularities at the horizon end of the maps (u1 → 1 for the heavy GGX tail,
    u1 → 0 for wide Phong lobes)."""
    s, ws = _gauss(0.0, 1.0, N1)
    u1 = s * s * (3.0 - 2.0 * s)
    w1 = ws * 6.0 * s * (1.0 - s)
    u2 = (np.arange(N2) + 0.5) / N2
    U1, U2 = np.meshgrid(u1, u2, indexing="ij")
    m = ref.sample_m_ref(dist, U1, U2, alpha)
    tan2 = (m[..., 0] ** 2 + m[..., 1] ** 2) / m[..., 2] ** 2
    pm = ref.D_ref(dist, m[..., 2], alpha, tan2=tan2) * m[..., 2]
    return m, np.outer(w1, np.full(N2, 1.0 / N2)) / pm


def microfacet_albedo(model, params, options, dist, alpha, wi, eta=None):
    """Directional albedo (R, T) of ``model`` for incident directions wi (K, 3) (either side),
    integrated over the microfacet normal m of Walter's sampling map for ``dist``.

    In the frame mirrored so that wi is above: reflection o = 2(i·m)m - i (eq. 39), dωo =
    4|o·m| dωm (eq. 14); refraction o = refract(i, m) (eq. 40) with the relative index ``eta``
    (η_o/η_i for each wi, shape (K,); None: no transmission), dωo = (i·m + η o·m)²/(η²|o·m|) dωm
    (eq. 17). Every wo is reached from at most one m, and the wo reached by none have f = 0."""
    m, wq = _m_grid(dist, alpha)
    m = m[None]
    s = np.where(wi[:, 2] < 0, -1.0, 1.0)
    flip = np.stack([np.ones_like(s), np.ones_like(s), s], -1)[:, None, None, :]
    iu = (wi[:, None, None, :] * flip)
    c = np.sum(iu * m, -1)
    shape = np.broadcast_shapes(iu.shape, m.shape)
    wi_b = np.broadcast_to(wi[:, None, None, :], shape)

    o = 2 * c[..., None] * m - iu
    ok = (c > 0) & (o[..., 2] > 0)
    o = np.where(ok[..., None], o, [0.0, 0.0, 1.0])
    f = np.asarray(eval_bsdf(model, params, wi_b, o * flip, options))
    R = np.sum(np.where(ok, f * o[..., 2] * 4 * np.abs(np.sum(o * m, -1)), 0.0) * wq, axis=(1, 2))
    if eta is None:
        return R, None
    e = np.asarray(eta, dtype=float)[:, None, None]
    k = 1 + (c * c - 1) / (e * e)
    okk = (k > 0) & (c > 0)
    o = (c / e - np.sqrt(np.where(okk, k, 1.0)))[..., None] * m - iu / e[..., None]
    om = np.sum(o * m, -1)
    ok = okk & (o[..., 2] < 0)
    o = np.where(ok[..., None], o, [0.0, 0.0, -1.0])
    om = np.where(ok, om, -1.0)
    f = np.asarray(eval_bsdf(model, params, wi_b, o * flip, options))
    jac = (c + e * om) ** 2 / (e * e * np.abs(om))
    T = np.sum(np.where(ok, f * np.abs(o[..., 2]) * jac, 0.0) * wq, axis=(1, 2))
    return R, T


FURNACE_THETAS = np.array([0.0, 30.0, 60.0, 80.0, 89.9])
FURNACE_ETAS = (1.0001, 1.5, 2.4, 1 / 1.5, 1 / 2.4)
FURNACE_ALPHAS = (1e-4, 0.01, 0.1, 0.3, 1.0)
#: Upper-bound allowance: quadrature error (the albedos that come near 1 are those of narrow
#: lobes, whose m-space integrands are smooth: measured max for GGX and Beckmann is 1 + 6e-10),
#: plus twice the 0.35% error of the approximate G1 of eq. 27.
QUAD_TOL = 1e-5
G1_EXCESS = {"ggx": 0.0, "beckmann": 0.0, "beckmann_rational": 0.007, "phong": 0.007}


def _incident(thetas, side):
    wi = ref.sph(thetas * DEG, np.full(thetas.shape, 0.3))
    return wi * np.array([1.0, 1.0, side])


@functools.lru_cache(maxsize=None)
def _dielectric_albedos(dist):
    """{(alpha, eta, side): (R, T)} over the furnace grid; side -1: incidence from inside."""
    out = {}
    for alpha in FURNACE_ALPHAS:
        for eta in FURNACE_ETAS:
            for side in (1.0, -1.0):
                wi = _incident(FURNACE_THETAS, side)
                rel = np.full(len(wi), eta if side > 0 else 1 / eta)
                out[alpha, eta, side] = microfacet_albedo(
                    "rough_dielectric", {"alpha": alpha, "eta": eta}, {"distribution": dist}, dist, alpha, wi, rel
                )
    return out


@pytest.mark.parametrize("dist", DISTS)
def test_white_furnace_rough_dielectric(dist):
    """R + T <= 1 (single scattering with a separable Smith G loses energy, never gains it) for
    α in [1e-4, 1], η on both sides of 1, incidence from outside and inside, θi up to 89.9°;
    and R + T >= 0.95 for α <= 0.1 up to 60° incidence, >= 0.99 for α <= 0.01 up to 80°.
    Phong is only bounded for α <= 0.1 (see the Smith-consistency test); its wide-lobe
    excess is pinned down in test_phong_furnace_excess_for_wide_lobes."""
    for (alpha, eta, side), (R, T) in _dielectric_albedos(dist).items():
        tot = R + T
        assert np.all(R >= 0) and np.all(T >= 0)
        if dist != "phong" or alpha <= 0.1:
            assert np.all(tot <= 1 + QUAD_TOL + G1_EXCESS[dist]), (alpha, eta, side, tot)
        if alpha <= 0.1:
            assert np.all(tot[FURNACE_THETAS <= 60] >= 0.95), (alpha, eta, side, tot)
        if alpha <= 0.01:
            assert np.all(tot[FURNACE_THETAS <= 80] >= 0.99), (alpha, eta, side, tot)


def test_phong_furnace_excess_for_wide_lobes():
    """Known limitation of Walter's recommended G1 for Phong (eq. 27 with the α_p mapping):
    at α = 1 the rough dielectric returns up to about 19% more energy than it receives near
    grazing incidence (measured 1.185; 1.008 at α = 0.3). Pinned so that a change
    (e.g. a proper Phong Smith G1) is noticed and this test updated."""
    worst = max(float(np.max(R + T)) for (a, _, _), (R, T) in _dielectric_albedos("phong").items() if a == 1.0)
    assert 1.15 < worst < 1.22


@pytest.mark.parametrize("dist", DISTS)
def test_smooth_limit_is_a_fresnel_mirror_and_refractor(dist):
    """α = 1e-4: R(θi) = F(θi) and T(θi) = 1 - F(θi) (the smooth interface: Walter eq. 22
    written out in numpy), including total internal reflection from inside; within 1e-4 up to
    80°, and 1e-2 at 89.9°, where the 0.1° to the horizon is 17α: the GGX tail (P(tan θm > t)
    = α²/(α² + t²), 0.35% here) sends that much below the horizon, plus shadowing."""
    for (alpha, eta, side), (R, T) in _dielectric_albedos(dist).items():
        if alpha != 1e-4:
            continue
        F = ref.fresnel_textbook(np.cos(FURNACE_THETAS * DEG), eta if side > 0 else 1 / eta)
        tol = np.where(FURNACE_THETAS <= 80, 1e-4, 1e-2)
        assert np.all(np.abs(R - F) <= tol), (eta, side, R, F)
        assert np.all(np.abs(T - (1 - F)) <= tol), (eta, side, T, F)


@pytest.mark.parametrize("dist", DISTS)
def test_index_matched_interface_transmits_everything(dist):
    """η → 1 (1.0001): F is below 1e-7 up to 60°, so nearly all energy is transmitted: T >= 0.9999
    for α <= 0.01, and R < 1e-6."""
    alb = _dielectric_albedos(dist)
    for alpha in (1e-4, 0.01):
        for side in (1.0, -1.0):
            R, T = alb[alpha, 1.0001, side]
            sel = FURNACE_THETAS <= 60
            assert np.all(T[sel] >= 0.9999), (alpha, side, T)
            assert np.all(R[sel] < 1e-6), (alpha, side, R)


CONDUCTORS = {
    "near_perfect_mirror": (0.01, 20.0),  # F0 = 0.9999: the furnace measures the G loss only
    "copper_g": (1.04, 2.59),
    "chromium_r": (3.84, 4.37),
    "k0_glass": (1.5, 0.0),
}


@pytest.mark.parametrize("fresnel", ["exact", "schlick", "lazanyi"])
@pytest.mark.parametrize("dist", DISTS)
def test_white_furnace_rough_conductor(dist, fresnel):
    """R <= 1 for every conductor, α, θi; with the near-perfect mirror (F ≈ 1) R >= 0.95 for
    α <= 0.1 up to 60°; α = 1e-4 gives R = F(θi) of the chosen Fresnel (a smooth mirror)."""
    wi = _incident(FURNACE_THETAS, 1.0)
    for alpha in FURNACE_ALPHAS:
        for label, (n, k) in CONDUCTORS.items():
            p = {"alpha": alpha, "n": n, "k": k}
            R, _ = microfacet_albedo("rough_conductor", p, {"distribution": dist, "fresnel": fresnel}, dist, alpha, wi)
            assert np.all(R >= 0)
            if dist != "phong" or alpha <= 0.1:
                assert np.all(R <= 1 + QUAD_TOL + G1_EXCESS[dist]), (alpha, label, R)
            if label == "near_perfect_mirror" and alpha <= 0.1:
                assert np.all(R[FURNACE_THETAS <= 60] >= 0.95), (alpha, R)
            if alpha == 1e-4 and fresnel == "exact":
                F = ref.fresnel_complex(np.cos(FURNACE_THETAS * DEG), n, k)
                tol = np.where(FURNACE_THETAS <= 80, 1e-4, 1e-2)  # see the dielectric limit test
                assert np.all(np.abs(R - F) <= tol), (label, R, F)


def _direction_albedo(model, params, wi, options=None, n_mu=128, n_phi=128, side=1.0):
    """∫ f(wi, wo)|cos θo| dωo over the hemisphere ``side`` of wo: Gauss-Legendre in cos θo,
    uniform in φo."""
    mu, wmu = _gauss(0.0, 1.0, n_mu)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    MU, PH = np.meshgrid(mu, phi, indexing="ij")
    wo = ref.sph(np.arccos(MU), PH) * np.array([1.0, 1.0, side])
    W = np.outer(wmu, np.full(n_phi, 2 * np.pi / n_phi)) * MU
    wo_b = np.broadcast_to(wo, (len(wi),) + wo.shape)
    wi_b = np.broadcast_to(wi[:, None, None, :], wo_b.shape)
    f = np.asarray(eval_bsdf(model, params, wi_b, wo_b, options))
    return np.sum(f * W, axis=(1, 2))


def test_white_furnace_diffuse():
    """Lambertian: albedo = ρ exactly. Oren–Nayar qualitative model: <= ρ for σ >= 0.6, but it
    is not exactly energy conserving: with ρ = 1 its albedo reaches 1.008 at grazing incidence
    for σ ≈ 0.1 (measured here: the B term is not normalized and the model has no
    inter-reflection term), so the bound is 1.01 ρ; it decreases with σ at normal incidence
    (0.56 ρ at σ = π/2)."""
    wi = _incident(np.array([0.0, 30.0, 60.0, 80.0, 89.0, 89.99]), 1.0)
    for rho in (0.3, 1.0):
        np.testing.assert_allclose(_direction_albedo("lambertian", {"albedo": rho}, wi), rho, rtol=1e-12)
        prev = None
        for sigma in (0.0, 0.1, 0.3, 0.6, 1.0, np.pi / 2):
            a = _direction_albedo("oren_nayar", {"albedo": rho, "sigma": sigma}, wi)
            assert np.all(a <= 1.01 * rho) and np.all(a > 0.5 * rho), (sigma, a)
            if sigma >= 0.6:
                assert np.all(a <= rho), (sigma, a)
            if prev is not None:
                assert a[0] < prev  # normal incidence: rougher is darker
            prev = a[0]
        assert _direction_albedo("oren_nayar", {"albedo": rho, "sigma": 0.0}, wi) == pytest.approx(rho, rel=1e-12)


@pytest.mark.parametrize("dist", DISTS)
def test_direction_space_quadrature_agrees_for_wide_lobes(dist):
    """Cross-check of the microfacet-space albedo with a plain quadrature over wo for lobes wide
    enough for it (α = 0.3, 1), so the m-space maps and Jacobians are not trusted blindly."""
    wi = _incident(np.array([0.0, 45.0, 75.0]), 1.0)
    for alpha in (0.3, 1.0):
        p = {"alpha": alpha, "eta": 1.5}
        o = {"distribution": dist}
        R, T = microfacet_albedo("rough_dielectric", p, o, dist, alpha, wi, np.full(3, 1.5))
        Rd = _direction_albedo("rough_dielectric", p, wi, o, n_mu=256, n_phi=256)
        Td = _direction_albedo("rough_dielectric", p, wi, o, n_mu=256, n_phi=256, side=-1.0)
        np.testing.assert_allclose(R, Rd, atol=3e-3)
        np.testing.assert_allclose(T, Td, atol=3e-3)


# ============================================================================================
# Snell's law
# ============================================================================================


@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize("eta, side", [(1.5, 1.0), (2.4, 1.0), (1 / 1.5, 1.0), (1.5, -1.0), (1.33, -1.0)])
def test_snell_law_of_sampled_and_peak_transmission(eta, side, dist):
    """At α = 1e-4 the transmitted samples obey η_i sin θi = η_o sin θo (absolute indices,
    outside 1, inside η) within 2e-3 (= 20α) and leave in the plane of incidence on the far
    side: all of them for the Gaussian-tailed Beckmann and Phong lobes, 99% for GGX, whose
    tail puts P(tan θm > t) = α²/(α² + t²) of the normals beyond t. And the maximum of f_t over
    θo in the plane of incidence is at the Snell angle (α = 1e-3)."""
    eta_i, eta_o = (1.0, eta) if side > 0 else (eta, 1.0)
    rng = np.random.default_rng(31)
    share = 0.99 if dist == "ggx" else 1.0
    for tdeg in (0.0, 20.0, 40.0, 60.0, 80.0):
        ti = tdeg * DEG
        if eta_i * np.sin(ti) / eta_o >= 0.98:  # total internal reflection (or nearly)
            continue
        wi = ref.sph(ti, 0.7) * np.array([1.0, 1.0, side])
        u = rng.uniform(size=(4096, 3))
        wo, weight, pdf = (np.asarray(x) for x in sample_bsdf(
            "rough_dielectric", {"alpha": 1e-4, "eta": eta}, np.broadcast_to(wi, u.shape), u,
            {"distribution": dist}))
        trans = (weight > 0) & (wo[:, 2] * side < 0)
        assert trans.sum() > 1000
        so = np.sqrt(wo[trans, 0] ** 2 + wo[trans, 1] ** 2)
        assert np.mean(np.abs(eta_o * so - eta_i * np.sin(ti)) < 2e-3) >= share, tdeg
        if tdeg > 0:
            az = np.arctan2(wo[trans, 1], wo[trans, 0])
            assert np.mean(np.abs(np.cos(az - 0.7) + 1.0) < 1e-3) >= share, tdeg
        # peak of f_t along the plane of incidence
        tt = np.arcsin(eta_i * np.sin(ti) / eta_o)
        grid = tt + np.linspace(-0.02, 0.02, 4001)
        wos = ref.sph(grid, np.full(grid.shape, 0.7 + np.pi)) * np.array([1.0, 1.0, -side])
        f = _eval("rough_dielectric", {"alpha": 1e-3, "eta": eta}, np.broadcast_to(wi, wos.shape), wos,
                  {"distribution": dist})
        assert abs(grid[np.argmax(f)] - tt) < 2e-4, (tdeg, grid[np.argmax(f)], tt)
