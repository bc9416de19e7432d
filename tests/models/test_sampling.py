"""Importance sampling of every registry model against its own pdf and eval.

* χ² goodness of fit (tests/chi2.py, after Mitsuba 3's chi2 harness) of the sampled directions
  against ``pdf`` over the whole sphere, for every distribution and sampling strategy a model
  offers (read from its options; sampling=visible only where the distribution has visible-normal
  sampling) and the hard configurations (normal, 45°, grazing incidence, incidence from inside
  with total internal reflection, a denser outside medium, η near 1, narrow and wide lobes; for
  the anisotropic models α_x ≠ α_y with the plane of incidence off both tangent axes). The
  invalid samples are one more χ² category, and the pdf mass is separately checked against the
  valid fraction. The significance level 0.01 is Šidák-corrected for the number of χ² tests in
  this module.
* The returned weight equals f·|cos θo|/pdf (Walter eq. 37/41) for valid samples and is exactly
  0 for invalid ones; the returned pdf equals ``pdf`` at the sampled direction.

Deterministic: fixed seeds, float64.
"""

from __future__ import annotations

import functools
import itertools
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.microfacet import get_distribution
from fitlab.models import get_model

try:  # tests/ is on sys.path under pytest's default (prepend) import mode
    from chi2 import chi2_test, sidak_level, sidak_z
except ImportError:  # pragma: no cover - importlib mode, run from the repository root
    from tests.chi2 import chi2_test, sidak_level, sidak_z

SIGNIFICANCE = 0.01
N_SAMPLES = 300_000
CHUNK = 1 << 15


# ----------------------------------------------------------------------------------------------
# Jitted model functions (one compilation per model, function, options and batch shape)
# ----------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _jitted(model_name: str, which: str, options: tuple):
    return jax.jit(functools.partial(getattr(get_model(model_name), which), **dict(options)))


def call(model_name, which, options, params, wi, x):
    """``model.<which>(params, wi, x)`` as numpy, over fixed-size padded chunks so that every
    batch size shares one compilation per (model, function, options). ``params`` values and
    ``wi`` broadcast against the leading shape of ``x`` (n, 3)."""
    fn = _jitted(model_name, which, tuple(sorted(options.items())))
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    wi = np.broadcast_to(np.asarray(wi, dtype=np.float64), x.shape)
    params = {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)) for k, v in params.items()}
    pad = (-n) % CHUNK
    padded = [np.concatenate([a, np.repeat(a[-1:], pad, axis=0)]) for a in (wi, x)]
    params = {k: np.concatenate([v, np.repeat(v[-1:], pad)]) for k, v in params.items()}
    outs = []
    for s in range(0, n + pad, CHUNK):
        p = {k: jnp.asarray(v[s:s + CHUNK]) for k, v in params.items()}
        out = fn(p, jnp.asarray(padded[0][s:s + CHUNK]), jnp.asarray(padded[1][s:s + CHUNK]))
        outs.append(jax.tree.map(np.asarray, out))
    return jax.tree.map(lambda *a: np.concatenate(a)[:n], *outs)


def _direction(theta_deg, phi_deg=180.0):
    """Incident direction at θ from +z and azimuth φ from +x (degrees). The default φ = 180°
    (exactly in the x-z plane) puts the reflected and the transmitted lobes around φ = 0, away
    from the φ = ±π seam of the χ² grid; the anisotropic cases turn the plane of incidence off
    both tangent axes, their lobes (around φ + 180°) staying away from the seam too."""
    t = np.radians(theta_deg)
    if phi_deg == 180.0:
        return np.stack([-np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)
    p = np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def sampler(model_name, params, wi, options):
    def sample(u):
        wo, _, pdf = call(model_name, "sample", options, params, wi, u)
        return wo, pdf

    return sample


def density(model_name, params, wi, options):
    return lambda wo: call(model_name, "pdf", options, params, wi, wo)


# ----------------------------------------------------------------------------------------------
# χ² cases
# ----------------------------------------------------------------------------------------------

#: (id, alpha, eta, θi in degrees; θi > 90° is incidence from inside, wi.z < 0)
DIELECTRIC_CONFIGS = (
    ("normal", 0.3, 1.5, 0.0),
    ("45deg", 0.3, 1.5, 45.0),
    ("grazing87", 0.3, 1.5, 87.0),
    ("inside30", 0.3, 1.5, 150.0),  # partly beyond the critical angle 41.8° for tilted facets
    ("inside60_tir", 0.3, 1.5, 120.0),  # mostly total internal reflection
    ("denser_outside45", 0.3, 1 / 1.5, 45.0),
    ("denser_outside_grazing85", 0.3, 1 / 1.5, 85.0),
    ("eta1.05_30deg", 0.3, 1.05, 30.0),
    ("eta1.05_inside20", 0.3, 1.05, 160.0),
    ("alpha0.05_45deg", 0.05, 1.5, 45.0),
    ("alpha0.05_inside40", 0.05, 1.5, 140.0),
    ("alpha0.05_eta1.05", 0.05, 1.05, 60.0),
    ("alpha1_45deg", 1.0, 1.5, 45.0),
    ("alpha1_grazing89", 1.0, 1.5, 89.0),
    ("alpha1_inside70", 1.0, 1.5, 110.0),
)

#: (id, alpha, θi in degrees)
CONDUCTOR_CONFIGS = (
    ("normal", 0.3, 0.0),
    ("45deg", 0.3, 45.0),
    ("grazing87", 0.3, 87.0),
    ("alpha0.05_45deg", 0.05, 45.0),
    ("alpha0.05_grazing85", 0.05, 85.0),
    ("alpha1_60deg", 1.0, 60.0),
    ("alpha1_grazing89", 1.0, 89.0),
)

#: (id, alpha_x, alpha_y, eta, θi, φi in degrees): α_x ≠ α_y, the plane of incidence off the
#: tangent axes (φi ∉ {0°, ±90°, 180°}), incidence from inside (θi > 90°) included
DIELECTRIC_ANISO_CONFIGS = (
    ("0.05x0.4_normal", 0.05, 0.4, 1.5, 0.0, 180.0),
    ("0.05x0.4_45deg_phi-120", 0.05, 0.4, 1.5, 45.0, -120.0),
    ("0.5x0.1_inside30_phi135", 0.5, 0.1, 1.5, 150.0, 135.0),
    ("0.4x0.05_inside60_tir_phi-150", 0.4, 0.05, 1.5, 120.0, -150.0),
    ("0.3x0.02_grazing85_phi-100", 0.3, 0.02, 1.5, 85.0, -100.0),
    ("0.1x0.6_denser_outside60_phi120", 0.1, 0.6, 1 / 1.5, 60.0, 120.0),
    ("1x0.2_eta1.05_inside20_phi-135", 1.0, 0.2, 1.05, 160.0, -135.0),
)

#: (id, alpha_x, alpha_y, θi, φi in degrees)
CONDUCTOR_ANISO_CONFIGS = (
    ("0.02x0.3_normal", 0.02, 0.3, 0.0, 180.0),
    ("0.05x0.4_45deg_phi-120", 0.05, 0.4, 45.0, -120.0),
    ("0.5x0.1_70deg_phi135", 0.5, 0.1, 70.0, 135.0),
    ("0.3x0.02_grazing85_phi-100", 0.3, 0.02, 85.0, -100.0),
    ("1x0.1_60deg_phi-150", 1.0, 0.1, 60.0, -150.0),
)

DIFFUSE_CONFIGS = (
    ("lambertian", {"albedo": 0.7}),
    ("oren_nayar", {"albedo": 0.7, "sigma": 0.5}),
)

#: The unmarked (fast) χ² cases besides GGX with standard sampling on the isotropic models'
#: configurations and the diffuse models; every other case is marked slow.
FAST_CHI2 = {
    "rough_dielectric-ggx-visible-45deg",
    "rough_dielectric-ggx-visible-inside30",
    "rough_conductor-ggx-visible-45deg",
    "rough_dielectric_anisotropic-ggx-standard-0.05x0.4_45deg_phi-120",
    "rough_dielectric_anisotropic-ggx-visible-0.5x0.1_inside30_phi135",
    "rough_conductor_anisotropic-ggx-standard-0.5x0.1_70deg_phi135",
    "rough_conductor_anisotropic-ggx-visible-0.05x0.4_45deg_phi-120",
}


def _choices(model_name, option):
    """The choices a model declares for one of its options."""
    return next(o.choices for o in get_model(model_name).options if o.name == option)


def _refused(options):
    """An option combination the microfacet models refuse: visible-normal sampling of a
    distribution that has none (asked of the distribution registry)."""
    return (options.get("sampling") == "visible"
            and get_distribution(options["distribution"]).sample_visible is None)


def _sampling_option_sets(model_name):
    """Every (distribution, sampling) the model offers and accepts."""
    for dist, smp in itertools.product(_choices(model_name, "distribution"),
                                       _choices(model_name, "sampling")):
        opts = {"distribution": dist, "sampling": smp}
        if not _refused(opts):
            yield opts


def _chi2_cases():
    cases = []

    def add(model_name, params, theta, phi, opts, cid):
        case_id = f"{model_name}-{opts['distribution']}-{opts['sampling']}-{cid}"
        isotropic_default = (get_model(model_name).capabilities.isotropic
                             and (opts["distribution"], opts["sampling"]) == ("ggx", "standard"))
        marks = () if isotropic_default or case_id in FAST_CHI2 else (pytest.mark.slow,)
        cases.append(pytest.param(model_name, params, theta, phi, opts, id=case_id, marks=marks))

    for opts in _sampling_option_sets("rough_dielectric"):
        for cid, alpha, eta, theta in DIELECTRIC_CONFIGS:
            add("rough_dielectric", {"alpha": alpha, "eta": eta}, theta, 180.0, opts, cid)
    for opts in _sampling_option_sets("rough_conductor"):
        for cid, alpha, theta in CONDUCTOR_CONFIGS:
            add("rough_conductor", {"alpha": alpha, "n": 0.2, "k": 3.9}, theta, 180.0, opts, cid)
    for opts in _sampling_option_sets("rough_dielectric_anisotropic"):
        for cid, ax, ay, eta, theta, phi in DIELECTRIC_ANISO_CONFIGS:
            add("rough_dielectric_anisotropic", {"alpha_x": ax, "alpha_y": ay, "eta": eta},
                theta, phi, opts, cid)
    for opts in _sampling_option_sets("rough_conductor_anisotropic"):
        for cid, ax, ay, theta, phi in CONDUCTOR_ANISO_CONFIGS:
            add("rough_conductor_anisotropic", {"alpha_x": ax, "alpha_y": ay, "n": 0.2, "k": 3.9},
                theta, phi, opts, cid)
    for name, params in DIFFUSE_CONFIGS:
        for theta in (0.0, 45.0, 85.0):
            cases.append(pytest.param(name, params, theta, 180.0, {}, id=f"{name}-{theta:g}deg"))
    assert FAST_CHI2 <= {c.id for c in cases}, FAST_CHI2 - {c.id for c in cases}
    return cases


CHI2_CASES = _chi2_cases()
#: Šidák correction over every χ² case of the module (the fast subset is tested at the same level).
N_CHI2_TESTS = len(CHI2_CASES)
LEVEL = sidak_level(SIGNIFICANCE, N_CHI2_TESTS)
Z_MASS = sidak_z(SIGNIFICANCE, N_CHI2_TESTS)


def _transmission_edge(model_name, params, wi):
    """θo of the edge of a rough dielectric's transmission support, as a χ² grid edge: refraction
    through normals with m_z > 0 reaches only |wo_z| > |wi_z| η_i/η_o, and at that cone the
    visible-normal pdf (and f_t) jumps, GGX's D(m) staying non-zero as m reaches the horizon.
    ``eta`` = n_inside / n_outside; () where there is no such cone or no transmission."""
    if not get_model(model_name).capabilities.transmission or "eta" not in params:
        return ()
    c = float(wi[2])
    edge = abs(c) / (params["eta"] if c > 0 else 1.0 / params["eta"])  # |wi_z| η_i/η_o
    return (float(np.arccos(-np.sign(c) * edge)),) if edge < 1.0 else ()


# its time goes into running the sampler and the pdf's cell integrals (tests/chi2.py) on
# 10^5 samples: compiled at XLA's default optimization level (22% less time in the whole suite)
@pytest.mark.optimized
@pytest.mark.parametrize("model_name, params, theta_i, phi_i, options", CHI2_CASES)
def test_chi2_sampling_matches_pdf(model_name, params, theta_i, phi_i, options, request):
    wi = _direction(theta_i, phi_i)
    seed = zlib.crc32(request.node.callspec.id.encode())  # fixed per case, hash-seed independent
    res = chi2_test(sampler(model_name, params, wi, options),
                    density(model_name, params, wi, options), N_SAMPLES, seed,
                    fixed_theta=_transmission_edge(model_name, params, wi))
    print(res.report())
    # The quadrature error bound (|4-child - parent| summed over leaf cells, a large
    # overestimate of the error of the 4-child values used) stays below one expected sample.
    assert res.quadrature_error * N_SAMPLES < 1.0, res.report()
    # pdf mass at most one and equal to the fraction of valid samples (binomial error).
    assert res.pdf_mass <= 1.0 + 1e-6, res.report()
    assert abs(res.pdf_mass - res.valid_fraction) <= Z_MASS * res.mass_sigma() + 1e-6, res.report()
    assert res.p_value >= LEVEL, f"rejected at Šidák level {LEVEL:.3g}: {res.report()}"


# ----------------------------------------------------------------------------------------------
# Weight = f |cos θo| / pdf, pdf = pdf(wo)
# ----------------------------------------------------------------------------------------------


def _option_sets(model_name):
    """Every combination of the model's option choices that it accepts."""
    model = get_model(model_name)
    names = [o.name for o in model.options]
    for values in itertools.product(*(o.choices for o in model.options)):
        opts = dict(zip(names, values))
        if not _refused(opts):
            yield opts


#: The dielectric's Schlick Fresnel only changes F after the normal is sampled (the same code for
#: every distribution and sampling): checked with the default distribution and sampling only.
FRESNEL_DEFAULTS_ONLY = ("rough_dielectric", "rough_dielectric_anisotropic")


def _weight_option_sets(name):
    defaults = get_model(name).default_options()
    for opts in _option_sets(name):
        if (name in FRESNEL_DEFAULTS_ONLY and opts.get("fresnel") != defaults.get("fresnel")
                and any(opts[k] != v for k, v in defaults.items() if k != "fresnel")):
            continue
        yield opts


WEIGHT_CASES = [
    pytest.param(name, opts, id="-".join([name, *opts.values()]),
                 marks=() if opts == get_model(name).default_options() else (pytest.mark.slow,))
    for name in ("rough_dielectric", "rough_conductor", "rough_dielectric_anisotropic",
                 "rough_conductor_anisotropic", "lambertian", "oren_nayar")
    for opts in _weight_option_sets(name)
]

#: Incidence angles in degrees (> 90°: from inside) and per-model parameter grids.
WEIGHT_THETAS = (0.0, 30.0, 60.0, 85.0, 89.9, 100.0, 120.0, 150.0, 180.0)
WEIGHT_PARAMS = {
    "rough_dielectric": {"alpha": (0.01, 0.05, 0.3, 1.0),
                         "eta": (1.5, 1 / 1.5, 1.05, 1 / 1.05, 3.0)},
    "rough_conductor": {"alpha": (0.01, 0.05, 0.3, 1.0), "n": (0.2, 1.5), "k": (3.9, 0.0)},
    # α_x ≠ α_y throughout (the random φi of _weight_batch probes every azimuth)
    "rough_dielectric_anisotropic": {"alpha_x": (0.01, 0.3, 1.0), "alpha_y": (0.05, 0.5),
                                     "eta": (1.5, 1 / 1.5, 1.05, 3.0)},
    "rough_conductor_anisotropic": {"alpha_x": (0.01, 0.3, 1.0), "alpha_y": (0.05, 0.5),
                                    "n": (0.2, 1.5), "k": (3.9, 0.0)},
    "lambertian": {"albedo": (0.3, 1.0)},
    "oren_nayar": {"albedo": (0.3, 1.0), "sigma": (0.0, 0.3, 1.2)},
}
SAMPLES_PER_CONFIG = 512


def _weight_batch(model_name, seed=7):
    """Every (θi, parameter combination) × SAMPLES_PER_CONFIG uniforms, plus edge uniforms."""
    grid = WEIGHT_PARAMS[model_name]
    combos = list(itertools.product(WEIGHT_THETAS, *grid.values()))
    rng = np.random.default_rng(seed)
    u = rng.random((len(combos), SAMPLES_PER_CONFIG, 3))
    edge = np.array([0.0, 0.5, 1.0 - 2.0**-53])
    u[:, :27] = np.stack(np.meshgrid(edge, edge, edge, indexing="ij"), -1).reshape(27, 3)
    combos = np.array(combos)
    wi = np.repeat(_direction(combos[:, 0])[:, None, :], SAMPLES_PER_CONFIG, axis=1)
    # rotate each configuration's wi about z so that φi varies too
    phi = rng.uniform(-np.pi, np.pi, len(combos))[:, None]
    wi = np.stack([wi[..., 0] * np.cos(phi), wi[..., 0] * np.sin(phi), wi[..., 2]], -1)
    params = {k: np.repeat(combos[:, 1 + j][:, None], SAMPLES_PER_CONFIG, axis=1).ravel()
              for j, k in enumerate(grid)}
    return params, wi.reshape(-1, 3), u.reshape(-1, 3)


@pytest.mark.parametrize("model_name, options", WEIGHT_CASES)
def test_sample_weight_and_pdf_consistent(model_name, options):
    model = get_model(model_name)
    params, wi, u = _weight_batch(model_name)
    wo, weight, pdf_s = call(model_name, "sample", options, params, wi, u)
    f = call(model_name, "eval", options, params, wi, wo)
    pdf_e = call(model_name, "pdf", options, params, wi, wo)

    assert np.all(np.isfinite(wo)) and np.all(np.isfinite(weight)) and np.all(np.isfinite(pdf_s))
    assert np.all(pdf_s >= 0) and np.all(weight >= 0)
    valid = pdf_s > 0
    assert valid.any()
    # invalid samples: weight exactly zero
    assert np.all(weight[~valid] == 0.0), np.flatnonzero(~valid & (weight != 0))[:10]
    # one-sided models never produce a valid sample for incidence from below
    if model.lobes == "reflection":
        assert not np.any(valid & (wi[:, 2] <= 0))
        assert np.all(wo[valid, 2] > 0)
    np.testing.assert_allclose(np.linalg.norm(wo[valid], axis=-1), 1.0, rtol=1e-12)
    # the pdf returned with the sample is pdf() at the sampled direction
    np.testing.assert_allclose(pdf_e[valid], pdf_s[valid], rtol=1e-5)
    # Walter eq. 37/41: weight = f |cos θo| / pdf. Weights are of order 1; the absolute floor
    # covers samples that leave at exactly grazing (cos θo of one ulp, 2.2e-16 at α = 1), whose
    # weight ∝ cos θo is rounding noise that differs between two compilations (0.7 vs 1 ulp).
    expected = f[valid] * np.abs(wo[valid, 2]) / pdf_e[valid]
    np.testing.assert_allclose(weight[valid], expected, rtol=1e-5, atol=1e-12)
