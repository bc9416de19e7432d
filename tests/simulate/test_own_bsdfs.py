"""fitlab's own Dr.Jit microfacet boundaries (fitlab/simulate/own_bsdfs.py) against fitlab's JAX
models, the independent reference: rough_dielectric / rough_conductor (and their anisotropic
variants) with ``distribution`` = beckmann_rational, phong, vmf, vmf_exact (the models' functions
take every family of fitlab.microfacet.REGISTRY; their option lists only Walter's).

* eval and pdf on ~2000 direction pairs per family and boundary (both sides, normal incidence,
  89°, α 1e-3 … 1 (κ = 2/α² from 2 to 2e6, and κ = 0.01 for vMF), η 1.5, 1/1.5, 1.01; three
  (n, k) per conductor): float32 against float64. The criterion is
  relative 1e-3, widened by the problem's own conditioning: the spread of the float64 reference
  under perturbations of the directions by ~8 float32 ulps (near the critical angle, or for
  η = 1.01 with α = 1e-3, a float32 evaluation cannot do better whatever its formulas);
* sampling: the sampled wo agrees with the JAX sampler's for the same random numbers; weight,
  forced weights (times F or 1 - F) and pdf equal the reference's eval·|cos θo|/pdf, F and pdf at
  the sampled direction (flux transport: Walter eq. 41, no η² factor);
* the mean sample weight (and two weighted means) over 1e6 samples equals the quadrature of
  f|cos θo| (the albedo; f the eval checked above); the exact vMF masking's albedo is ≤ 1, and a
  k → ∞ conductor's is the Smith energy of its NDF (JAX's D and G1 integrated over m);
* everything traces inside a symbolic ``dr.while_loop`` and is finite at the hard cases.

Needs Mitsuba's llvm_ad_rgb variant on a libLLVM ≥ 17 (fitlab.simulate.engine picks it).
"""

from __future__ import annotations

import zlib

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import skip_or_fail

pytestmark = pytest.mark.mitsuba

#: (family, anisotropic) pairs tested
FAMILIES = [("beckmann_rational", False), ("beckmann_rational", True), ("phong", False),
            ("vmf", False), ("vmf_exact", False)]
ALPHAS = (1e-3, 1e-2, 0.1, 0.5, 1.0)
#: and for the vMF families α = 14.1, κ = 2/α² = 0.01, the broadest lobe (α > 1 is outside the
#: models' parameter range; the hard cases evaluate it for every family)
ALPHA_BROAD = 14.1421356
ETAS = (1.5, 1 / 1.5, 1.01)
#: conductor (n, k) per RGB channel: a metal (0.2, 3.9), a weak absorber (1, 0.05), a dielectric
#: (1.5, 0)
N_RGB = (0.2, 1.0, 1.5)
K_RGB = (3.9, 0.05, 0.0)
#: lanes of a test batch (every grid of parameters divides it: one shape for every JAX call)
N_LANES = 2160
RTOL = 1e-3
#: values below this (1/sr) are "tiny": compared in absolute terms
ATOL = 1e-5
#: relative size of the perturbations that measure the reference's conditioning (~8 ulps)
DELTA = 1e-6


@pytest.fixture(scope="module")
def mi():
    """Mitsuba in its llvm_ad_rgb variant, on the libLLVM fitlab's engine picks (LLVM >= 17: an
    older one aborts the process on these kernels; tests/conftest.py selects it before Dr.Jit
    loads)."""
    from fitlab.errors import FitlabError

    try:
        from fitlab.simulate import engine

        mitsuba = engine.load("cpu").mi
        mitsuba.set_variant("llvm_ad_rgb")
    except (ImportError, FitlabError) as exc:
        skip_or_fail(f"Mitsuba's llvm_ad_rgb variant is unavailable: {exc}")
    return mitsuba


@pytest.fixture(scope="module")
def ob(mi):
    from fitlab.simulate import own_bsdfs

    return own_bsdfs


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def _rng(*key):
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _sphere(rng, n):
    return _normalize(rng.normal(size=(n, 3)))


def _polar(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _incident(rng, n):
    """Incident directions: uniform on the sphere, with normal incidence and 89° on both sides."""
    wi = _sphere(rng, n)
    k = n // 10
    wi[:k] = [0.0, 0.0, 1.0]
    wi[k:2 * k] = _polar(np.full(k, 89.0), rng.uniform(0, 360, k))
    wi[2 * k:3 * k] = -wi[k:2 * k]
    wi[3 * k:int(3.5 * k)] = [0.0, 0.0, -1.0]
    return wi


def _f32(v):
    """float32 rounding (what the Dr.Jit side sees), back in float64 for the reference."""
    return np.asarray(v, np.float32).astype(np.float64)


def _vec(mi, v):
    v = np.asarray(v, np.float32)
    return mi.Vector3f(v[:, 0], v[:, 1], v[:, 2])


def _evaluated(*xs):
    """Evaluate the outputs of one call together (one kernel; reading them one by one would
    run one kernel each)."""
    import drjit as dr

    dr.eval(*xs)
    return xs


def _np_vec(v):
    return np.stack([np.array(v.x), np.array(v.y), np.array(v.z)], axis=-1).astype(np.float64)


def _np_spec(s):
    return np.stack([np.array(s[c]) for c in range(3)], axis=-1).astype(np.float64)


def _perturb(rng, v):
    return _normalize(v * (1.0 + DELTA * rng.normal(size=v.shape)))


def _assert_close(got, ref, spread, what):
    """|got - ref| ≤ RTOL |ref| + 4 spread + ATOL, all finite."""
    got, ref = np.asarray(got, np.float64), np.asarray(ref, np.float64)
    assert np.all(np.isfinite(got)), f"{what}: non-finite values"
    err = np.abs(got - ref)
    tol = RTOL * np.abs(ref) + 4.0 * spread + ATOL
    bad = err > tol
    if bad.any():
        i = np.argsort((err - tol).ravel())[-5:]
        pytest.fail(f"{what}: {bad.sum()} of {bad.size} outside tolerance; worst (lanes {i}) "
                    f"got {got.ravel()[i]}, ref {ref.ravel()[i]}, tol {tol.ravel()[i]}")


def _reference(fn, rng, wi, wo, n_perturb=3):
    """fn(wi, wo) in float64 at the float32 directions, and its spread under perturbations of
    the directions by DELTA (the conditioning of the value: what float32 arithmetic may miss)."""
    ref = np.asarray(fn(wi, wo))
    spread = np.zeros_like(ref)
    for _ in range(n_perturb):
        p = np.asarray(fn(_perturb(rng, wi), _perturb(rng, wo)))
        spread = np.maximum(spread, np.abs(p - ref))
    return ref, spread


def _reference_fn(model, name, family):
    """The JAX model's function for one family, run op by op (not jitted: every call in this file
    has the same lane count, so JAX compiles each operation once for all families and models,
    which takes a fraction of the time of compiling each model function whole)."""
    fn = getattr(model, name)
    return lambda params, wi, wo: fn(params, wi, wo, distribution=family)


def _fresnel_fn(kind):
    from fitlab.fresnel import fresnel_conductor_exact, fresnel_dielectric

    if kind == "conductor":
        return fresnel_conductor_exact
    return lambda c, eta: fresnel_dielectric(jnp.asarray(c), jnp.asarray(eta))[0]


class Case:
    """One family and boundary kind over a batch of lanes, each with its own parameters: the
    Dr.Jit boundary (parameters as per-lane Dr.Jit arrays) and the JAX reference."""

    def __init__(self, mi, ob, kind, family, aniso, alpha, eta=None, alpha_y=None):
        from fitlab.models import rough_conductor, rough_dielectric

        self.kind, self.family, self.aniso = kind, family, aniso
        self.params = ({"alpha_x": jnp.asarray(alpha), "alpha_y": jnp.asarray(alpha_y)} if aniso
                       else {"alpha": jnp.asarray(alpha)})
        a = mi.Float(np.asarray(alpha, np.float32))
        ay = mi.Float(np.asarray(alpha_y, np.float32)) if aniso else None
        if kind == "dielectric":
            self.params["eta"] = jnp.asarray(eta)
            self.model = rough_dielectric.ANISOTROPIC if aniso else rough_dielectric.MODEL
            self.bsdf = ob.OwnRoughDielectric(family, a, ay, mi.Float(np.asarray(eta, np.float32)))
        else:
            self.model = rough_conductor.ANISOTROPIC if aniso else rough_conductor.MODEL
            n = np.ones_like(alpha)
            self.bsdf = ob.OwnRoughConductor(
                family, a, ay, mi.Spectrum(*(mi.Float(np.float32(c) * n) for c in N_RGB)),
                mi.Spectrum(*(mi.Float(np.float32(c) * n) for c in K_RGB)))

    def channel_params(self, c=0):
        if self.kind == "dielectric":
            return self.params
        ones = jnp.ones_like(next(iter(self.params.values())))
        return {**self.params, "n": N_RGB[c] * ones, "k": K_RGB[c] * ones}

    def ref(self, name, wi, wo, c=0):
        fn = _reference_fn(self.model, name, self.family)
        return np.asarray(fn(self.channel_params(c), jnp.asarray(wi), jnp.asarray(wo)))

    def F_ref(self, wi, wo, c=0):
        """The Fresnel factor of the branch of (wi, wo) at their half-vector (the sampled m):
        F for reflection, 1 - F for refraction (fitlab.fresnel, float64)."""
        if self.kind == "conductor":
            h = _normalize(wi + wo)
            return np.asarray(_fresnel_fn("conductor")(np.sum(wi * h, -1), N_RGB[c],
                                                          K_RGB[c]))
        eta = np.asarray(self.params["eta"])
        s = np.where(wi[:, 2] < 0, -1.0, 1.0)
        wi_u, wo_u = wi.copy(), wo.copy()
        wi_u[:, 2] *= s
        wo_u[:, 2] *= s
        e = np.where(s > 0, eta, 1 / eta)
        is_r = wo_u[:, 2] > 0
        h = wi_u + np.where(is_r, 1.0, e)[:, None] * wo_u
        h = _normalize(h * np.where(h[:, 2] < 0, -1.0, 1.0)[:, None])
        F = np.asarray(_fresnel_fn("dielectric")(np.sum(wi_u * h, -1), e))
        return np.where(is_r, F, 1.0 - F)


def _lanes(rng, family, aniso, kind):
    """Per-lane parameters over the grid of α (× η for a dielectric), N_LANES lanes."""
    alphas = ALPHAS + ((ALPHA_BROAD,) if family.startswith("vmf") else ())
    grid = [(a, e) for a in alphas for e in (ETAS if kind == "dielectric" else (None,))]
    per_case = N_LANES // len(grid)
    alpha = np.repeat([g[0] for g in grid], per_case)
    eta = np.repeat([g[1] or 1.0 for g in grid], per_case)
    ratio = rng.choice([0.25, 4.0], size=alpha.size)
    alpha_y = np.minimum(alpha * ratio, 1.0) if aniso else None
    return alpha, eta, alpha_y


def _case_and_pairs(mi, ob, rng, kind, family, aniso):
    alpha, eta, alpha_y = _lanes(rng, family, aniso, kind)
    n = alpha.size
    case = Case(mi, ob, kind, family, aniso, alpha, eta if kind == "dielectric" else None, alpha_y)
    wi = _incident(rng, n)
    if kind == "conductor":  # mostly from above (the only side that scatters)
        wi[:, 2] = np.where(rng.random(n) < 0.85, np.abs(wi[:, 2]), wi[:, 2])
    # wo: half from the reference sampler (inside the lobes), half uniform, a few mirrors / -wi
    wo_s = np.asarray(_reference_fn(case.model, "sample", family)(
        case.channel_params(0), jnp.asarray(wi), jnp.asarray(rng.random((n, 3))))[0])
    ok = np.all(np.isfinite(wo_s), -1) & (np.linalg.norm(wo_s, axis=-1) > 0.5)
    wo = np.where(ok[:, None] & (rng.random(n) < 0.5)[:, None], wo_s, _sphere(rng, n))
    j = rng.random(n)
    wo = np.where((j < 0.03)[:, None], wi * [-1, -1, 1], np.where((j > 0.97)[:, None], -wi, wo))
    return case, _f32(wi), _f32(_normalize(wo))


# --------------------------------------------------------------------------------------------
# eval and pdf
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["dielectric", "conductor"])
@pytest.mark.parametrize("family,aniso", FAMILIES)
def test_eval_pdf_agree_with_jax(mi, ob, kind, family, aniso):
    rng = _rng(kind, family, aniso)
    case, wi, wo = _case_and_pairs(mi, ob, rng, kind, family, aniso)
    f, p = _evaluated(case.bsdf.eval(_vec(mi, wi), _vec(mi, wo), True),
                      case.bsdf.pdf(_vec(mi, wi), _vec(mi, wo), True))
    f, p = _np_spec(f), np.array(p).astype(np.float64)
    for c in range(3 if kind == "conductor" else 1):
        ref, spread = _reference(lambda a, b: case.ref("eval", a, b, c), rng, wi, wo)
        _assert_close(f[:, c], ref, spread, f"{kind} {family} eval channel {c}")
    ref, spread = _reference(lambda a, b: case.ref("pdf", a, b), rng, wi, wo)
    _assert_close(p, ref, spread, f"{kind} {family} pdf")
    if kind == "dielectric":  # the three channels are one
        assert np.array_equal(f[:, 0], f[:, 2])
    assert (np.count_nonzero(p) > 0.3 * p.size) and (np.count_nonzero(f[:, 0]) > 0.3 * p.size)


# --------------------------------------------------------------------------------------------
# sampling
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["dielectric", "conductor"])
@pytest.mark.parametrize("family,aniso", FAMILIES)
def test_sample_matches_eval_over_pdf(mi, ob, kind, family, aniso):
    """Same u as the JAX sampler: the same wo (away from the Fresnel choice's boundary); weight
    = f|cos θo|/pdf (times F or 1 - F when forced) and pdf = the reference's at that wo."""
    rng = _rng(kind, family, aniso, 1)
    alpha, eta, alpha_y = _lanes(rng, family, aniso, kind)
    case = Case(mi, ob, kind, family, aniso, alpha, eta if kind == "dielectric" else None,
                alpha_y)
    n = alpha.size
    wi = _f32(_incident(rng, n))
    if kind == "conductor":
        wi[:, 2] = np.abs(wi[:, 2])
    u = rng.random((n, 3)).astype(np.float32)
    forces = ((ob.FORCE_CHOOSE, ob.FORCE_REFLECT, ob.FORCE_REFRACT) if kind == "dielectric"
              else (ob.FORCE_CHOOSE,))
    out = {}
    for force in forces:
        wo, w, p = case.bsdf.sample(_vec(mi, wi), mi.Float(u[:, 2]), mi.Point2f(u[:, 0], u[:, 1]),
                                    mi.UInt32(np.full(n, force, np.uint32)), True)
        wo, w, p = _evaluated(wo, w, p)
        out[force] = _np_vec(wo), _np_spec(w), np.array(p).astype(np.float64)
    wo, w, p = out[ob.FORCE_CHOOSE]
    assert np.all(np.isfinite(wo)) and np.all(np.isfinite(w)) and np.all(np.isfinite(p))
    valid = p > 0
    assert valid.mean() > 0.5
    assert np.all(w[~valid] == 0)

    # the JAX sampler with the same u (unforced; walter_sample for the dielectric)
    wo_ref, _, p_ref = _reference_fn(case.model, "sample", family)(
        case.channel_params(0), jnp.asarray(wi), jnp.asarray(_f32(u)))
    wo_ref, p_ref = np.asarray(wo_ref), np.asarray(p_ref)
    both = valid & (p_ref > 0)
    if kind == "dielectric":
        F = case.F_ref(wi, wo_ref)
        F_r = np.where(wo_ref[:, 2] * wi[:, 2] > 0, F, 1.0 - F)
        both &= np.abs(u[:, 2] - F_r) > 1e-3  # away from the Fresnel choice's boundary
    assert both.mean() > 0.4
    dev = np.linalg.norm(wo - wo_ref, axis=-1)[both]
    assert np.quantile(dev, 0.99) < 1e-4 and dev.max() < 2e-3, (np.quantile(dev, 0.99), dev.max())

    # weight and pdf against the reference at the sampled direction (all lanes, so that the
    # reference keeps its shapes; invalid ones get a placeholder and are not compared)
    for force in forces:
        wo_f, w_f, p_f = out[force]
        ok = p_f > 0
        assert np.all(w_f[~ok] == 0)
        wo_f = _f32(np.where(ok[:, None], wo_f, wi * [-1, -1, 1]))

        def weight_ref(a, b, c=0):  # f|cos θo|/pdf, times F or 1 - F when forced
            f = case.ref("eval", a, b, c)
            q = case.ref("pdf", a, b)
            r = np.where(q > 0, f * np.abs(b[:, 2]) / np.where(q > 0, q, 1.0), 0.0)
            return r if force == ob.FORCE_CHOOSE else r * case.F_ref(a, b, c)

        for c in range(3 if kind == "conductor" else 1):
            ref, spread = _reference(lambda a, b: weight_ref(a, b, c), rng, wi, wo_f)
            _assert_close(w_f[ok, c], ref[ok], spread[ok],
                          f"{kind} {family} weight force={force} channel {c}")
        ref, spread = _reference(lambda a, b: case.ref("pdf", a, b), rng, wi, wo_f)
        _assert_close(p_f[ok], ref[ok], spread[ok], f"{kind} {family} pdf of sample force={force}")

    if kind == "dielectric":
        # forcing the branch the Fresnel choice took changes only the weight: times F or 1 - F
        for force, is_r in ((ob.FORCE_REFLECT, True), (ob.FORCE_REFRACT, False)):
            wo_f, w_f, p_f = out[force]
            same = valid & ((wo[:, 2] * wi[:, 2] > 0) == is_r)
            assert np.array_equal(wo_f[same], wo[same]) and np.array_equal(p_f[same], p[same])
            Fb = case.F_ref(wi, _f32(wo))[same]
            np.testing.assert_allclose(w_f[same, 0], w[same, 0] * Fb, rtol=2e-3, atol=1e-6)


# --------------------------------------------------------------------------------------------
# the sampled directions follow pdf: mean weights against the quadrature of f|cos θo|
# --------------------------------------------------------------------------------------------

_NQ = 160


def _sphere_rule():
    """Gauss–Legendre in cos θ on each hemisphere × the trapezoid rule in φ (exact for the
    periodic integrand): nodes (M, 3), weights (M,) with Σw = 4π."""
    from fitlab.quadrature import gauss_legendre

    mu, wm = gauss_legendre(_NQ, 0.0, 1.0)
    phi = (np.arange(2 * _NQ) + 0.5) * np.pi / _NQ
    M, P = np.meshgrid(mu, phi, indexing="ij")
    W = np.repeat(wm[:, None], phi.size, 1) * (np.pi / _NQ)
    s = np.sqrt(1 - M**2)
    up = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    return np.concatenate([up, up * [1, 1, -1]]), np.concatenate([W.ravel(), W.ravel()])


STAT_CASES = [  # kind, θi (deg, > 90: from below), α, η
    ("dielectric", 50.0, 0.3, 1.5), ("dielectric", 140.0, 0.6, 1.5),
    ("dielectric", 0.0, 1.0, 1.1), ("conductor", 60.0, 0.4, None),
    ("conductor_kinf", 30.0, 0.8, None),
]


@pytest.mark.parametrize("family", ["beckmann_rational", "phong", "vmf", "vmf_exact"])
def test_mean_weight_is_albedo(mi, ob, family):
    """E[weight g(wo)] over 1e6 samples = ∫ f |cos θo| g dωo by quadrature (g = 1: the albedo;
    the reflected fraction; wo.x), with f the eval that test_eval_pdf_agree_with_jax checks."""
    rng = _rng(family)
    nodes, wq = _sphere_rule()
    N = 1_000_000
    u = rng.random((N, 3)).astype(np.float32)
    for kind, theta_i, alpha, eta in STAT_CASES:
        wi1 = _f32(_polar(np.array([theta_i]), np.array([20.0])))
        if kind == "dielectric":
            bsdf = ob.OwnRoughDielectric(family, alpha, None, eta)
        else:
            k = 1e4 if kind == "conductor_kinf" else K_RGB[0]
            n = 1.0 if kind == "conductor_kinf" else N_RGB[0]
            bsdf = ob.OwnRoughConductor(family, alpha, None, n, k)
        (f,) = _evaluated(bsdf.eval(_vec(mi, wi1), _vec(mi, nodes), True))
        f = np.array(f[0]).astype(np.float64)
        fc = f * np.abs(nodes[:, 2]) * wq
        tests = {"albedo": np.ones(len(nodes)), "reflected": (nodes[:, 2] * wi1[0, 2] > 0) * 1.0,
                 "wo.x": nodes[:, 0]}
        wo, w, _ = bsdf.sample(_vec(mi, wi1), mi.Float(u[:, 2]),
                               mi.Point2f(u[:, 0], u[:, 1]), mi.UInt32(0), True)
        wo, w = _evaluated(wo, w)
        wo, w = _np_vec(wo), np.array(w[0]).astype(np.float64)
        assert np.all(np.isfinite(w)) and w.min() >= 0
        g_of_wo = {"albedo": np.ones(N), "reflected": (wo[:, 2] * wi1[0, 2] > 0) * 1.0,
                   "wo.x": wo[:, 0]}
        for name, g in tests.items():
            quad = float(np.sum(fc * g))
            x = w * g_of_wo[name]
            mean, se = x.mean(), x.std() / np.sqrt(N)
            assert abs(mean - quad) < 4 * se + 2e-3 * abs(quad) + 1e-5, \
                (family, kind, theta_i, name, mean, quad, se)
        albedo = float(np.sum(fc))
        if family == "vmf_exact":  # the exact Smith masking conserves energy
            assert albedo <= 1.0 + 1e-3, (kind, albedo)
        if kind == "conductor_kinf":  # F = 1: the Smith energy of the NDF, by quadrature over m
            assert albedo == pytest.approx(_smith_energy(family, alpha, wi1[0]), rel=2e-3)


def _smith_energy(family, alpha, wi):
    """∫ (i·m) G1(i) G1(o(m)) D(m) / |i·n| dω_m over the facets that reflect wi upward (the k → ∞
    conductor's albedo, Walter eqs 20, 14 rewritten in m), by quadrature over m."""
    from fitlab import microfacet

    nodes, wq = _sphere_rule()
    up = nodes[:, 2] > 0
    m, w = nodes[up], wq[up]

    def integrand(m, wi):
        dist = microfacet.REGISTRY[family](alpha)
        c = m @ wi
        wo = 2 * c[:, None] * m - wi
        G = dist.G1(jnp.broadcast_to(wi, m.shape)) * dist.G1(wo)
        return jnp.where((c > 0) & (wo[:, 2] > 0), c * G * dist.D(m) / wi[2], 0.0)

    return float(np.sum(np.asarray(integrand(jnp.asarray(m), jnp.asarray(wi))) * w))


# --------------------------------------------------------------------------------------------
# symbolic loops, hard cases
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["dielectric", "conductor"])
def test_traces_inside_symbolic_while_loop(mi, ob, kind):
    import drjit as dr

    rng = np.random.default_rng(7)
    n = 64
    wi_np = _f32(_incident(rng, n))
    if kind == "conductor":
        wi_np[:, 2] = np.abs(wi_np[:, 2])
    u = rng.random((n, 3)).astype(np.float32)
    for family, aniso in FAMILIES:
        a = dr.opaque(mi.Float, 0.3)
        ay = dr.opaque(mi.Float, 0.1) if aniso else None
        bsdf = (ob.OwnRoughDielectric(family, a, ay, dr.opaque(mi.Float, 1.5))
                if kind == "dielectric" else
                ob.OwnRoughConductor(family, a, ay, dr.opaque(mi.Spectrum, 0.2),
                                     dr.opaque(mi.Spectrum, 3.9)))
        wi, s1, s2 = _vec(mi, wi_np), mi.Float(u[:, 2]), mi.Point2f(u[:, 0], u[:, 1])
        force = mi.UInt32(np.arange(n, dtype=np.uint32) % 3)

        def once(active):
            wo, w, p = bsdf.sample(wi, s1, s2, force, active)
            return w[0] + bsdf.eval(wi, wo, active)[0] + bsdf.pdf(wi, wo, active) + wo.z

        def body(i, acc):
            return i + 1, acc + once(mi.Bool(True))

        _, acc = dr.while_loop(state=(mi.UInt32(0), mi.Float(np.zeros(n, np.float32))),
                               cond=lambda i, acc: i < 3, body=body, mode="symbolic")
        direct = np.array(once(mi.Bool(True)))
        np.testing.assert_allclose(np.array(acc), 3 * direct, rtol=1e-5, atol=1e-5,
                                   err_msg=f"{kind} {family}")


@pytest.mark.parametrize("kind", ["dielectric", "conductor"])
def test_hard_cases_finite(mi, ob, kind):
    """κ up to 2e8 (α = 1e-4), normal, 89.99° and horizontal directions, wo = ±wi and mirrors,
    η = 1.01, 1/1.5, 1.5, extreme random numbers, inactive lanes: every output finite and ≥ 0
    (inactive lanes: 0). Each lane has its own (α, η)."""
    th = np.array([0.0, 30.0, 89.0, 89.99, 90.0, 90.01, 91.0, 150.0, 180.0])
    wi = _polar(np.repeat(th, th.size), np.full(th.size**2, 10.0))
    wo = _polar(np.tile(th, th.size), np.full(th.size**2, 190.0))
    wi = np.concatenate([wi, wi, wi, wi])
    wo = np.concatenate([wo, -wo, wi[: len(wo)] * [-1, -1, 1], -wi[: len(wo)]])
    u_vals = np.array([0.0, 0.5, 1 - 2**-24], np.float32)
    u = np.stack(np.meshgrid(u_vals, u_vals, u_vals, indexing="ij"), -1).reshape(-1, 3)
    params = [(a, e) for a in (1e-4, 1e-3, 1.0, ALPHA_BROAD)
              for e in ((1.01, 1 / 1.5, 1.5) if kind == "dielectric" else (1.0,))]
    # every (direction pair, parameters) and every (wi, u, parameters)
    P = len(params)
    pa = np.array([p[0] for p in params], np.float32)
    pe = np.array([p[1] for p in params], np.float32)
    e_wi, e_wo = np.repeat(wi, P, 0), np.repeat(wo, P, 0)
    e_a, e_e = np.tile(pa, len(wi)), np.tile(pe, len(wi))
    s_wi = np.repeat(wi, len(u) * P, 0)
    s_u = np.tile(np.repeat(u, P, 0), (len(wi), 1))
    s_a, s_e = np.tile(pa, len(wi) * len(u)), np.tile(pe, len(wi) * len(u))

    def make(family, aniso, a, e):
        a_y = mi.Float(np.minimum(4 * a, 1.0)) if aniso else None
        if kind == "dielectric":
            return ob.OwnRoughDielectric(family, mi.Float(a), a_y, mi.Float(e))
        return ob.OwnRoughConductor(family, mi.Float(a), a_y, mi.Spectrum(0.2, 0.2, 0.2),
                                    mi.Spectrum(3.9, 3.9, 3.9))

    for family, aniso in FAMILIES:
        b_e, b_s = make(family, aniso, e_a, e_e), make(family, aniso, s_a, s_e)
        for active in (True, False):
            act = mi.Bool(active)
            f, p = _evaluated(b_e.eval(_vec(mi, e_wi), _vec(mi, e_wo), act),
                              b_e.pdf(_vec(mi, e_wi), _vec(mi, e_wo), act))
            vals = [_np_spec(f), np.array(p)]
            for force in (0, 1, 2):
                wo_s, w_s, p_s = b_s.sample(_vec(mi, s_wi), mi.Float(s_u[:, 2]),
                                            mi.Point2f(s_u[:, 0], s_u[:, 1]), mi.UInt32(force),
                                            act)
                wo_s, w_s, p_s = _evaluated(wo_s, w_s, p_s)
                vals += [_np_vec(wo_s), _np_spec(w_s), np.array(p_s)]
            what = f"{kind} {family} anisotropic={aniso} active={active}"
            for v in vals:
                assert np.all(np.isfinite(v)), what
            values = vals[:2] + vals[3::3] + vals[4::3]
            assert all(np.all(v >= 0) for v in values), what
            if not active:
                assert all(np.all(v == 0) for v in values), what


def test_anisotropic_needs_a_family_that_has_it(mi, ob):
    with pytest.raises(ValueError, match="isotropic only"):
        ob.OwnRoughDielectric("vmf_exact", 0.1, 0.2, 1.5)
    with pytest.raises(ValueError, match="no Dr.Jit microfacet family"):
        ob.OwnRoughConductor("ggx", 0.1, None, 0.2, 3.9)
