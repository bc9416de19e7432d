"""Hard inputs, in float32 and float64: every model's eval, pdf and sample stay finite and
non-negative, and gradients (w.r.t. every parameter and the direction angles) stay finite, at

* α in {1e-4, 1e-3, 0.01, 0.3, 1}, θ up to 89.99° and just past the horizon, exact normal
  incidence, wi == wo, wo == -wi, back-facing pairs, total internal reflection, η in
  {1.0001, 1.05, 1.5, 2.4} and their inverses, incidence from inside, conductor (n, k) and
  diffuse parameters at their bounds;
* plus the n-d shape contract of the public API (arbitrary leading shapes, parameter
  broadcasting, jax.jit, jax.vmap, dtype preservation, NaN handling) and a Hypothesis property
  test over the whole parameter domain.

Float32 runs cast everything to float32 (conftest enables strict dtype promotion, so a float64
constant sneaking into a float32 evaluation fails loudly). The gradient grid runs op by op
(without jit: compiling every model's gradient would dominate the run time); the jitted
gradients of the main configurations are checked separately.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fitlab import eval_bsdf, pdf_bsdf, sample_bsdf
from fitlab.models import get_model

DEG = np.pi / 180.0

HARD_THETAS = np.array(
    [0.0, 1e-6, 10.0, 45.0, 80.0, 89.0, 89.99, 90.0, 90.01, 91.0, 100.0, 135.0, 170.0, 180.0 - 1e-6, 180.0]
) * DEG
#: φo - φi: same azimuth (wi == wo when θi == θo), opposite (mirror and straight-through
#: configurations, e.g. wo == -wi), generic, and opposite up to rounding.
HARD_DPHIS = (0.0, np.pi, 0.5, np.pi - 1e-7)
ALPHAS = (1e-4, 1e-3, 0.01, 0.3, 1.0)
ETAS = (1.0001, 1.05, 1.5, 2.4, 1 / 1.0001, 1 / 1.05, 1 / 1.5, 1 / 2.4)
DISTS = ("ggx", "beckmann", "beckmann_rational", "phong")

#: (model, options, parameter grid). Conductor Fresnel variants are checked with GGX and
#: Beckmann, the dielectric's Schlick with GGX; the exact ones with every distribution.
CONFIGS = (
    [("rough_dielectric", {"distribution": d}, {"alpha": ALPHAS, "eta": ETAS}) for d in DISTS]
    + [("rough_conductor", {"distribution": d, "fresnel": "exact"},
        {"alpha": ALPHAS, "n": (0.01, 1.0, 10.0), "k": (0.0, 3.9, 20.0)}) for d in DISTS]
    + [("rough_conductor", {"distribution": d, "fresnel": f},
        {"alpha": ALPHAS, "n": (0.01, 1.0, 10.0), "k": (0.0, 20.0)})
       for d in ("ggx", "beckmann") for f in ("schlick", "lazanyi")]
    + [("rough_dielectric", {"distribution": "ggx", "fresnel": "schlick"},
        {"alpha": ALPHAS, "eta": ETAS})]
    + [("lambertian", {}, {"albedo": (0.0, 0.5, 1.0)}),
       ("oren_nayar", {}, {"albedo": (0.0, 0.5, 1.0), "sigma": (0.0, 1e-4, 0.3, np.pi / 2)})]
)


def _config_id(config):
    model, opts, _ = config
    return "-".join([model, *opts.values()])


def _dirs(theta, phi):
    """Unit directions from angles, in the angles' dtype (gradients flow to θ and φ)."""
    st_ = jnp.sin(theta)
    return jnp.stack([st_ * jnp.cos(phi), st_ * jnp.sin(phi), jnp.cos(theta)], axis=-1)


#: Every grid is padded to this many rows (by repeating its first row): op-by-op execution
#: compiles each primitive once per shape and dtype, so one shape for every model and test
#: keeps that to one compilation per primitive.
N_ROWS = 40_500


def _pad(x, n=N_ROWS):
    assert len(x) <= n
    return np.concatenate([x, np.repeat(x[:1], n - len(x), axis=0)])


def _grid(param_grid):
    """Every parameter combination times every hard direction pair: names, (N_ROWS, names)
    parameters and (N_ROWS, 4) angles (θi, φi, θo, φo), and the number of rows before padding."""
    names = list(param_grid)
    combos = np.array(list(itertools.product(*param_grid.values())), dtype=float)
    pairs = np.array([(ti, 0.3, to, 0.3 + dp) for ti in HARD_THETAS for to in HARD_THETAS for dp in HARD_DPHIS])
    P = np.repeat(combos, len(pairs), axis=0)
    A = np.tile(pairs, (len(combos), 1))
    return names, _pad(P), _pad(A), len(P)


def _columns(x, dtype):
    return tuple(jnp.asarray(x[:, j], dtype=dtype) for j in range(x.shape[1]))


def _values_and_grads(model, opts, names, which, P, A, dtype):
    """Values and per-row gradients w.r.t. every parameter and the four angles."""
    def f(pv, ang):
        params = dict(zip(names, pv))
        return getattr(model, which)(params, _dirs(ang[0], ang[1]), _dirs(ang[2], ang[3]), **opts)

    pv, ang = _columns(P, dtype), _columns(A, dtype)
    val = f(pv, ang)
    # each output depends on its own row only, so the gradient of the sum is the per-row gradient
    gp, ga = jax.grad(lambda p, a: jnp.sum(f(p, a)), argnums=(0, 1))(pv, ang)
    return np.asarray(val), np.stack([np.asarray(g) for g in gp], -1), np.stack([np.asarray(g) for g in ga], -1)


def _report(bad, names, P, A):
    idx = np.nonzero(bad)[0][:5]
    return [(dict(zip(names, P[i])), tuple(np.round(A[i] / DEG, 6))) for i in idx]


#: Slow tier: tests/models/test_model_contract.py checks the same property for every registry model
#: (layered ones included) in the quick loop; these per-option grids run in the full suite.
@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS, ids=_config_id)
def test_eval_pdf_and_gradients_finite_on_hard_grid(config, dtype):
    """eval and pdf finite and >= 0, and d/d(parameters, θi, φi, θo, φo) finite, on the whole
    hard grid. The float32 results must also be float32."""
    model_name, opts, param_grid = config
    model = get_model(model_name)
    names, P, A, n = _grid(param_grid)
    for which in ("eval", "pdf"):
        val, gp, ga = _values_and_grads(model, opts, names, which, P, A, dtype)
        assert val.dtype == dtype and gp.dtype == dtype and ga.dtype == dtype
        bad = ~np.isfinite(val) | (val < 0)
        assert not bad.any(), (which, _report(bad, names, P, A))
        bad = ~np.isfinite(gp).all(-1) | ~np.isfinite(ga).all(-1)
        assert not bad.any(), (which, "gradient", _report(bad, names, P, A))
        assert np.count_nonzero(val[:n]) > 0.05 * n


def test_index_matched_interface_eta_exactly_one(dtype):
    """η = 1 exactly (inside the parameter bounds): Walter notes h_t is ill-defined for equal
    indices, and eq. 21 degenerates to a Dirac delta at wo = -wi in disguise (f_t ∝ 1/|wi + wo|²).
    Values stay finite and >= 0 everywhere on the hard grid (gradients are not defined at the
    delta itself, so they are not required there)."""
    model = get_model("rough_dielectric")
    names, P, A, _ = _grid({"alpha": ALPHAS, "eta": (1.0,)})

    @jax.jit
    def every_case(pv, ang):  # one compiled call for every distribution, eval and pdf
        params = dict(zip(names, pv))
        wi, wo = _dirs(ang[0], ang[1]), _dirs(ang[2], ang[3])
        return {(dist, which): getattr(model, which)(params, wi, wo, distribution=dist)
                for dist in DISTS for which in ("eval", "pdf")}

    for (dist, which), val in every_case(_columns(P, dtype), _columns(A, dtype)).items():
        val = np.asarray(val)
        assert val.dtype == dtype and np.all(np.isfinite(val) & (val >= 0)), (dist, which)


#: uniforms at and near the ends of [0, 1)
HARD_U = (0.0, 1e-7, 0.5, 0.9999, 1.0 - 1e-7)


#: Slow tier: tests/models/test_model_contract.py checks the same property for every registry model
#: (layered ones included) in the quick loop; these per-option grids run in the full suite.
@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS, ids=_config_id)
def test_sample_finite_on_hard_inputs(config, dtype):
    """sample(): wo, weight and pdf finite for every hard incident direction and uniforms at the
    ends of [0, 1); weight, pdf >= 0; a sample with weight > 0 has pdf > 0 and a unit wo."""
    model_name, opts, param_grid = config
    model = get_model(model_name)
    names = list(param_grid)
    combos = np.array(list(itertools.product(*param_grid.values())), dtype=float)
    us = list(itertools.product(HARD_U, repeat=3))
    rows = np.array([(*c, t, 0.3, *u) for c in combos for t in HARD_THETAS for u in us])
    n = len(rows)
    rows = _pad(rows, 90_000)
    X = _columns(rows, dtype)
    k = len(names)
    params = dict(zip(names, X[:k]))
    u = jnp.stack(X[k + 2:], axis=-1)
    wo, weight, pdf = (np.asarray(x) for x in model.sample(params, _dirs(X[k], X[k + 1]), u, **opts))
    assert wo.dtype == weight.dtype == pdf.dtype == dtype
    assert np.all(np.isfinite(wo)) and np.all(np.isfinite(weight)) and np.all(np.isfinite(pdf))
    assert np.all(weight >= 0) and np.all(pdf >= 0)
    ok = weight > 0
    assert np.all(pdf[ok] > 0)
    tol = 1e-3 if dtype == jnp.float32 else 1e-9
    np.testing.assert_allclose(np.linalg.norm(wo[ok], axis=-1), 1.0, atol=tol)
    assert ok[:n].mean() > 0.2


#: the main configurations, for the jitted gradient (one compilation each: slow)
JIT_CONFIGS = [
    ("rough_dielectric", {"distribution": "ggx"}, {"alpha": ALPHAS, "eta": ETAS}),
    ("rough_dielectric", {"distribution": "beckmann"}, {"alpha": ALPHAS, "eta": ETAS}),
    ("rough_conductor", {"distribution": "ggx", "fresnel": "exact"},
     {"alpha": ALPHAS, "n": (0.01, 1.0, 10.0), "k": (0.0, 3.9, 20.0)}),
]


@pytest.mark.slow
@pytest.mark.parametrize("config", JIT_CONFIGS, ids=_config_id)
def test_jitted_gradients_finite_on_hard_grid(config):
    """The same grid through jax.jit(jax.grad(...)), which is how the fitter differentiates
    (XLA fusion may round differently from op-by-op execution); float32, where fused
    intermediates are likeliest to under/overflow."""
    dtype = jnp.float32
    model_name, opts, param_grid = config
    model = get_model(model_name)
    names, P, A, _ = _grid(param_grid)

    def total(pv, ang):
        params = {k: pv[..., j] for j, k in enumerate(names)}
        return jnp.sum(model.eval(params, _dirs(ang[..., 0], ang[..., 1]), _dirs(ang[..., 2], ang[..., 3]), **opts))

    gp, ga = jax.jit(jax.grad(total, argnums=(0, 1)))(jnp.asarray(P, dtype=dtype), jnp.asarray(A, dtype=dtype))
    bad = ~np.isfinite(np.asarray(gp)).all(-1) | ~np.isfinite(np.asarray(ga)).all(-1)
    assert not bad.any(), _report(bad, names, P, A)


# ============================================================================================
# Shape contract of the public API
# ============================================================================================

DEFAULTS = {
    "rough_dielectric": {"alpha": 0.3, "eta": 1.5},
    "rough_conductor": {"alpha": 0.3, "n": 0.2, "k": 3.9},
    "lambertian": {"albedo": 0.5},
    "oren_nayar": {"albedo": 0.5, "sigma": 0.3},
}


def _random_dirs(rng, shape, upper_fraction=0.7):
    v = rng.normal(size=shape + (3,))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    up = rng.uniform(size=shape) < upper_fraction
    v[..., 2] = np.where(up, np.abs(v[..., 2]), -np.abs(v[..., 2]))
    return v


@pytest.mark.parametrize("model", list(DEFAULTS))
def test_arbitrary_leading_shapes_and_parameter_broadcasting(model):
    """Directions (2, 3, 4, 3) give results (2, 3, 4) equal to the flat evaluation; a parameter
    of shape (2, 1, 1) broadcasts against the leading shape; sample returns (2, 3, 4, 3) and
    two (2, 3, 4) arrays."""
    rng = np.random.default_rng(41)
    shape = (2, 3, 4)
    wi, wo = _random_dirs(rng, shape), _random_dirs(rng, shape)
    p = DEFAULTS[model]
    f = np.asarray(eval_bsdf(model, p, wi, wo))
    pdf = np.asarray(pdf_bsdf(model, p, wi, wo))
    assert f.shape == shape and pdf.shape == shape
    np.testing.assert_allclose(f.reshape(-1), np.asarray(eval_bsdf(model, p, wi.reshape(-1, 3), wo.reshape(-1, 3))), rtol=1e-13)
    np.testing.assert_allclose(pdf.reshape(-1), np.asarray(pdf_bsdf(model, p, wi.reshape(-1, 3), wo.reshape(-1, 3))), rtol=1e-13)
    first = next(iter(p))
    values = np.array([0.2, 0.9]) if first != "alpha" else np.array([0.05, 0.7])
    pb = dict(p, **{first: values.reshape(2, 1, 1)})
    fb = np.asarray(eval_bsdf(model, pb, wi, wo))
    assert fb.shape == shape
    for j in range(2):
        np.testing.assert_allclose(fb[j], np.asarray(eval_bsdf(model, dict(p, **{first: values[j]}), wi[j], wo[j])), rtol=1e-13)
    u = rng.uniform(size=shape + (3,))
    wo_s, weight, pdf_s = (np.asarray(x) for x in sample_bsdf(model, p, wi, u))
    assert wo_s.shape == shape + (3,) and weight.shape == shape and pdf_s.shape == shape
    np.testing.assert_allclose(weight.reshape(-1), np.asarray(sample_bsdf(model, p, wi.reshape(-1, 3), u.reshape(-1, 3))[1]), rtol=1e-13)


@pytest.mark.parametrize("model", list(DEFAULTS))
def test_works_under_jit_grad_and_vmap(model):
    """eval_bsdf/pdf_bsdf/sample_bsdf inside jax.jit (parameters as traced arguments), under
    jax.vmap over a batch axis, and under jax.grad w.r.t. a parameter: same values as the direct
    call, finite gradient."""
    rng = np.random.default_rng(43)
    wi, wo = _random_dirs(rng, (6,), 1.0), _random_dirs(rng, (6,), 0.5)
    u = rng.uniform(size=(6, 3))
    p = DEFAULTS[model]
    direct = np.asarray(eval_bsdf(model, p, wi, wo))
    direct_pdf = np.asarray(pdf_bsdf(model, p, wi, wo))
    direct_s = [np.asarray(x) for x in sample_bsdf(model, p, wi, u)]
    jitted = jax.jit(lambda p, wi, wo: eval_bsdf(model, p, wi, wo))
    np.testing.assert_allclose(np.asarray(jitted(p, wi, wo)), direct, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(jax.jit(lambda p, a, b: pdf_bsdf(model, p, a, b))(p, wi, wo)), direct_pdf, rtol=1e-13)
    js = jax.jit(lambda p, a, u: sample_bsdf(model, p, a, u))(p, wi, u)
    for a, b in zip(js, direct_s):
        np.testing.assert_allclose(np.asarray(a), b, rtol=1e-13, atol=1e-15)
    vm = jax.vmap(lambda a, b: eval_bsdf(model, p, a, b))(jnp.asarray(wi), jnp.asarray(wo))
    np.testing.assert_allclose(np.asarray(vm), direct, rtol=1e-13)
    vs = jax.vmap(lambda a, u: sample_bsdf(model, p, a, u))(jnp.asarray(wi), jnp.asarray(u))
    for a, b in zip(vs, direct_s):
        np.testing.assert_allclose(np.asarray(a), b, rtol=1e-13, atol=1e-15)
    name = next(iter(p))
    g = jax.grad(lambda x: jnp.sum(eval_bsdf(model, dict(p, **{name: x}), wi, wo)))(p[name])
    assert np.isfinite(float(g))


@pytest.mark.parametrize("model", list(DEFAULTS))
@pytest.mark.parametrize("dtype_name", ["float32", "float64"])
def test_output_dtype_follows_directions(model, dtype_name):
    """float32 directions give float32 eval, pdf and sample outputs (parameters are cast to the
    directions' dtype); float64 gives float64. Six rows, as test_works_under_jit_grad_and_vmap
    has: the float64 calls reuse its compiled kernels (fitlab.api's, per shape and dtype)."""
    dt = np.dtype(dtype_name)
    rng = np.random.default_rng(47)
    wi, wo = _random_dirs(rng, (6,), 1.0).astype(dt), _random_dirs(rng, (6,)).astype(dt)
    u = rng.uniform(size=(6, 3)).astype(dt)
    p = DEFAULTS[model]
    assert np.asarray(eval_bsdf(model, p, wi, wo)).dtype == dt
    assert np.asarray(pdf_bsdf(model, p, wi, wo)).dtype == dt
    for x in sample_bsdf(model, p, wi, u):
        assert np.asarray(x).dtype == dt


#: What a NaN direction gives (documented behaviour, asserted below). Every model first tests
#: the side of wi (NaN > 0 is False), so:
#: * NaN in wi's z component (or all of wi): eval and pdf 0; sample weight 0, pdf 0.
#: * NaN wo: the one-sided models (conductor, Lambertian, Oren–Nayar) test wo.z > 0 too and
#:   return 0; rough_dielectric takes a wo that is not above as transmission and returns NaN
#:   from eval (its pdf masks with sidedness tests and returns 0).
#: * NaN only in the tangential (x, y) components of a valid pair: NaN from the microfacet
#:   models and Oren–Nayar; Lambertian (f = ρ/π) depends on the z components only: ρ/π.
NAN_WO = {"rough_dielectric": "nan", "rough_conductor": 0.0, "oren_nayar": 0.0, "lambertian": 0.0}
NAN_TANGENTIAL = {"rough_dielectric": "nan", "rough_conductor": "nan", "oren_nayar": "nan", "lambertian": "rho/pi"}


def _expect(value, expected, p):
    if expected == "nan":
        assert np.isnan(value)
    elif expected == "rho/pi":
        assert value == pytest.approx(p["albedo"] / np.pi, rel=1e-6)
    else:
        assert value == expected


@pytest.mark.parametrize("model", list(DEFAULTS))
@pytest.mark.parametrize("dtype_name", ["float32", "float64"])
def test_nan_directions(model, dtype_name):
    """NaN in: NaN or 0 out, never an exception or a plausible finite value (see the table
    above); NaN parameters are rejected by the API with ValueError (check_params), and give
    NaN or 0, not a crash, when traced under jit (where bounds are not checked)."""
    dt = np.dtype(dtype_name)
    p = DEFAULTS[model]
    good = np.array([0.3, 0.1, 0.9], dtype=dt)
    good /= np.linalg.norm(good)
    allnan = np.full(3, np.nan, dtype=dt)
    xnan = np.array([np.nan, 0.0, 1.0], dtype=dt)
    for a in (allnan, np.array([0.0, 0.0, np.nan], dtype=dt)):
        assert float(eval_bsdf(model, p, a, good)) == 0.0
        assert float(pdf_bsdf(model, p, a, good)) == 0.0
        _, weight, pdf = sample_bsdf(model, p, a, np.array([0.3, 0.6, 0.2], dtype=dt))
        assert float(weight) == 0.0 and float(pdf) == 0.0
    _expect(float(eval_bsdf(model, p, good, allnan)), NAN_WO[model], p)
    assert float(pdf_bsdf(model, p, good, allnan)) == 0.0
    _expect(float(eval_bsdf(model, p, good, xnan)), NAN_TANGENTIAL[model], p)
    _expect(float(eval_bsdf(model, p, xnan, good)), NAN_TANGENTIAL[model], p)
    name = next(iter(p))
    with pytest.raises(ValueError, match="finite"):
        eval_bsdf(model, dict(p, **{name: np.nan}), good, good)
    traced = jax.jit(lambda x: eval_bsdf(model, dict(p, **{name: x}), good, good))(jnp.asarray(np.nan, dtype=dt))
    assert np.isnan(float(traced)) or float(traced) == 0.0


# ============================================================================================
# Property-based test over the whole domain
# ============================================================================================

_angle_theta = st.one_of(
    st.floats(0.0, np.pi),
    st.sampled_from([0.0, np.pi / 2, np.pi, np.pi / 2 - 1e-7, np.pi / 2 + 1e-7, 1e-9, np.pi - 1e-9]),
)
_angle_phi = st.floats(0.0, 2 * np.pi)


def _cases(alpha, eta, n, k, albedo, sigma):
    for d in DISTS:
        yield "rough_dielectric", (("distribution", d),), {"alpha": alpha, "eta": eta}
        yield "rough_conductor", (("distribution", d), ("fresnel", "exact")), {"alpha": alpha, "n": n, "k": k}
    for f in ("schlick", "lazanyi"):
        yield "rough_conductor", (("distribution", "ggx"), ("fresnel", f)), {"alpha": alpha, "n": n, "k": k}
    yield "lambertian", (), {"albedo": albedo}
    yield "oren_nayar", (), {"albedo": albedo, "sigma": sigma}


@jax.jit
def _every_case(values, pair_i, pair_o):
    """f and pdf of every case of :func:`_cases` at the pairs: one compiled call per example
    (a compilation per model, function and options before)."""
    out = []
    for model, opts, params in _cases(*values):
        m = get_model(model)
        out.append((m.eval(params, pair_i, pair_o, **dict(opts)),
                    m.pdf(params, pair_i, pair_o, **dict(opts))))
    return out


@settings(derandomize=True, database=None, max_examples=60, deadline=None)
@given(
    ti=_angle_theta, pi=_angle_phi, to=_angle_theta, po=_angle_phi,
    log_alpha=st.floats(-4.0, 0.0), eta=st.floats(0.2, 5.0),
    n=st.floats(0.01, 10.0), k=st.floats(0.0, 20.0),
    albedo=st.floats(0.0, 1.0), sigma=st.floats(0.0, np.pi / 2),
)
def test_property_finite_nonnegative_reciprocal(ti, pi, to, po, log_alpha, eta, n, k, albedo, sigma):
    """For random unit directions on both sides (horizon and poles included), α in [1e-4, 1]
    (log-uniform), η in [0.2, 5], n in [0.01, 10], k in [0, 20], every distribution: eval and
    pdf are finite and >= 0 in both orders; reflection (both directions on the same side) is
    reciprocal; transmission satisfies f(i,o)/η_o² = f(o,i)/η_i²."""
    wi = np.array([np.sin(ti) * np.cos(pi), np.sin(ti) * np.sin(pi), np.cos(ti)])
    wo = np.array([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)])
    pair_i = jnp.asarray(np.stack([wi, wo]))
    pair_o = jnp.asarray(np.stack([wo, wi]))
    values = (10.0**log_alpha, eta, n, k, albedo, sigma)
    results = _every_case(tuple(jnp.asarray(v, dtype=jnp.float64) for v in values), pair_i, pair_o)
    for (model, opts, _), (f, pdf) in zip(_cases(*values), results):
        f, pdf = np.asarray(f), np.asarray(pdf)
        assert np.all(np.isfinite(f)) and np.all(f >= 0), (model, opts, f)
        assert np.all(np.isfinite(pdf)) and np.all(pdf >= 0), (model, opts, pdf)
        if wi[2] * wo[2] > 0:
            np.testing.assert_allclose(f[0], f[1], rtol=1e-6, atol=1e-300, err_msg=f"{model} {opts}")
        elif model == "rough_dielectric" and wi[2] * wo[2] < 0:
            eta_i, eta_o = (1.0, eta) if wi[2] > 0 else (eta, 1.0)
            np.testing.assert_allclose(f[0] / eta_o**2, f[1] / eta_i**2, rtol=1e-5, atol=1e-300)
