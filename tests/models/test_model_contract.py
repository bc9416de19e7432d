"""The contract every registry model keeps, tested over the whole registry: every model in
``fitlab.models.MODELS``, every layered constructor applied to every registry model it accepts,
and a sum, so a model is tested the moment it is registered.

Checks, on a hard-case grid built from each parameter's declared bounds and role (roughness
1e-4 to 1 and vMF concentrations κ at their bounds, index ratios at their bounds, near 1 and below 1, thick and absorbing layers) and
directions (normal incidence, grazing to 89.99°, wi == wo, mirror pairs, transmission pairs,
incidence from below):

1. values and parameter gradients finite in float32 and float64, f >= 0;
2. sampling: weight == f|cos θo|/pdf and ``pdf`` == the pdf ``sample`` returns;
3. reciprocity where the model declares it (f(i, o) = f(o, i) on the reflection side; the
   generalized form f(i, o)/η_o² = f(o, i)/η_i² across a transmitting interface);
4. white furnace: the directional albedo (mean sample weight) is at most 1;
4b. lobes a model declares interchangeable (``model.exchangeable``) trade places without
   changing f or the pdf;
5. (slow) χ² goodness of fit of ``sample`` against ``pdf`` (tests/chi2.py).
"""

from __future__ import annotations

import functools
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.models import CONSTRUCTORS, MODELS, get_model

try:
    from chi2 import chi2_test, sidak_level, sidak_z
except ImportError:  # pragma: no cover
    from tests.chi2 import chi2_test, sidak_level, sidak_z


def _registry_models():
    """Every registry model, every constructor over every plain model it accepts, a sum."""
    plain = [n for n in MODELS if "(" not in n]
    names = list(MODELS)
    for ctor in CONSTRUCTORS:
        for inner in plain:
            name = f"{ctor}({inner})"
            try:
                get_model(name)
            except ValueError:  # refused by the constructor (e.g. a transmitting base)
                continue
            names.append(name)
    names += ["lambertian+rough_conductor", "coated(lambertian,specular=lobe)",
              "weidlich_wilkie(oren_nayar,layers=3)",
              "lambertian+rough_conductor+rough_conductor"]  # a sum that repeats a component
    return tuple(dict.fromkeys(names))


NAMES = _registry_models()

# ----------------------------------------------------------------------------------------------
# Hard-case parameters and directions
# ----------------------------------------------------------------------------------------------


def _clip(p, x):
    return float(min(max(x, p.lower), p.upper))


#: Each set maps a role to a value chooser (parameter -> value); other roles keep the default.
PARAMETER_SETS = {
    "default": {},
    "smooth": {"roughness": lambda p: p.lower, "concentration": lambda p: p.upper,
               "index": lambda p: _clip(p, 1.5)},
    "rough": {"roughness": lambda p: p.upper, "concentration": lambda p: p.lower,
              "albedo": lambda p: p.upper},
    "index_near_1": {"index": lambda p: _clip(p, 1.0001), "roughness": lambda p: _clip(p, 1e-3),
                     "concentration": lambda p: _clip(p, 2e6)},
    "index_below_1": {"index": lambda p: _clip(p, 1 / 1.5)},
    "index_bounds": {"index": lambda p: p.upper, "extinction": lambda p: p.upper,
                     "roughness": lambda p: _clip(p, 0.05), "concentration": lambda p: _clip(p, 800.0)},
    "thick_absorbing": {"optical_depth": lambda p: p.upper, "extinction": lambda p: p.upper,
                        "albedo": lambda p: p.lower},
    "anisotropic": {"roughness": None},  # alternating widths, see _values
}


def _values(model, set_name):
    choose = PARAMETER_SETS[set_name]
    out, k = {}, 0
    for p in model.parameters:
        if set_name == "anisotropic" and p.role == "roughness":
            out[p.name] = _clip(p, (0.03, 0.6)[k % 2])
            k += 1
        elif p.role in choose and choose[p.role] is not None:
            out[p.name] = choose[p.role](p)
        else:
            out[p.name] = p.default
    return out


def _dir(theta_deg, phi_deg=0.0):
    t, f = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)])


#: θi (degrees; > 90: from below) and outgoing (θo, φo) relative to φi = 30°.
THETA_I = (0.0, 30.0, 60.0, 89.0, 89.99, 120.0, 179.0)
THETA_O = (0.0, 10.0, 45.0, 80.0, 89.99, 100.0, 135.0, 170.0, 180.0)
PHI_O = (0.0, 75.0, 180.0, 210.0)


def _pairs():
    wi, wo = [], []
    for ti in THETA_I:
        i = _dir(ti, 30.0)
        for to in THETA_O:
            for po in PHI_O:
                wi.append(i)
                wo.append(_dir(to, 30.0 + po))
        wi += [i, i]
        wo += [i, i * np.array([-1.0, -1.0, 1.0])]  # wi == wo and the mirror direction
    return np.array(wi), np.array(wo)


WI, WO = _pairs()


def _batch(model, dtype):
    """Every parameter set × every direction pair, as arrays of one shape."""
    sets = list(PARAMETER_SETS)
    n = len(WI)
    params = {p.name: np.repeat([_values(model, s)[p.name] for s in sets], n).astype(dtype)
              for p in model.parameters}
    wi = np.tile(WI, (len(sets), 1)).astype(dtype)
    wo = np.tile(WO, (len(sets), 1)).astype(dtype)
    return params, wi, wo


@functools.lru_cache(maxsize=None)
def _eval_and_grad(name):
    model = get_model(name)

    def total(params, wi, wo):
        f = model.eval(params, wi, wo)
        return jnp.sum(f), f

    return jax.jit(jax.grad(total, has_aux=True))


def _eval(name, params, wi, wo):
    """f at a batch of the shape :func:`_batch` makes, through the compiled call of test 1 (its
    gradients unused): the reciprocity and exchange checks compile nothing of their own."""
    _, f = _eval_and_grad(name)({k: jnp.asarray(v) for k, v in params.items()},
                                jnp.asarray(wi), jnp.asarray(wo))
    return np.asarray(f)


#: f(wi, wo) and, for a reciprocal model, f(wo, wi) of each model's float64 batch
#: (:func:`_batch`), made by test 1 while its compiled call is at hand: the reciprocity and
#: exchange checks read them instead of running that call again, after the compiled code has
#: been released in between (retracing a SpongeCake lobe took 5-12 s a model)
_F64 = {}


def _f64(name, swapped=False):
    """f of the float64 batch, wi and wo swapped or not (:data:`_F64`; computed if absent)."""
    if (name, swapped) not in _F64:
        params, wi, wo = _batch(get_model(name), "float64")
        _F64[name, swapped] = _eval(name, params, *((wo, wi) if swapped else (wi, wo)))
    return _F64[name, swapped]


def _sample_eval_pdf(model, params, wi, u, **options):
    """``sample``, then ``eval`` and ``pdf`` at the sampled directions: one compiled call (about
    30% less compiling and running than three)."""
    wo, weight, pdf_s = model.sample(params, wi, u, **options)
    return wo, weight, pdf_s, model.eval(params, wi, wo, **options), \
        model.pdf(params, wi, wo, **options)


@functools.lru_cache(maxsize=None)
def _jit(name, which, options=()):
    model = get_model(name)
    if which == "sample_eval_pdf":
        return jax.jit(functools.partial(_sample_eval_pdf, model, **dict(options)))
    return jax.jit(functools.partial(getattr(model, which), **dict(options)))


CHUNK = 8192


def _fn(name, which, options=()):
    """``model.<which>`` over fixed-size padded chunks of float64 rows: one compilation per
    (model, function, options) whatever the batch size."""
    fn = _jit(name, which, tuple(sorted(dict(options).items())))

    def call(params, a, b):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        n = len(a)
        pad = (-n) % CHUNK
        grow = lambda x: np.concatenate([x, np.repeat(x[-1:], pad, axis=0)])  # noqa: E731
        params = {k: grow(np.broadcast_to(np.asarray(v, np.float64), (n,))) for k, v in params.items()}
        a, b = grow(a), grow(b)
        outs = [jax.tree.map(np.asarray, fn({k: v[s:s + CHUNK] for k, v in params.items()},
                                            a[s:s + CHUNK], b[s:s + CHUNK]))
                for s in range(0, n + pad, CHUNK)]
        return jax.tree.map(lambda *x: np.concatenate(x)[:n], *outs)

    return call


# ----------------------------------------------------------------------------------------------
# 1. values and gradients
# ----------------------------------------------------------------------------------------------


#: Layered models in float32 compile a second copy of the costliest kernels: in the quick tier
#: one of each constructor, all of them in the whole suite.
QUICK_FLOAT32_LAYERED = {"coated(rough_conductor)", "weidlich_wilkie(rough_conductor)"}

#: Models whose every contract case runs in the whole suite only: the thin layer's kernels (its
#: masking integral in every crossing) take 10-20 s each to compile; tests/models/test_thin_layer.py
#: keeps its quick checks.
SLOW_MODELS = {"thin_layer(rough_conductor)", "thin_layer(rough_dielectric)",
               # two-layer SpongeCake stacks: their one-layer siblings stay in the quick tier
               "spongecake(fiber,surface)", "spongecake(fiber_z,surface_z)",
               "spongecake(fiber,surface,multiple=learned)",
               # the lobe's energy budget: its tables cost 20-40 s of compiling and tabulating
               # per model with oriented layers, 20 s over a substrate; the quick tier keeps the
               # budget on spongecake(hg,multiple=only), and tests/models/test_directional_albedo.py
               # the azimuthal tables and the budget of an oriented lobe
               "spongecake(surface,multiple=lobe)", "spongecake(fiber,multiple=learned)",
               "spongecake(surface_z,substrate=lambertian,multiple=lobe)"}


#: Layered models whose every contract case runs in the whole suite only: in the quick tier,
#: and under XLA's defaults (tests/project/test_compiler_settings.py), each constructor runs
#: over one base of each kind (a conductor, a dielectric, a diffuse one, a sum-like lobe) and
#: its anisotropic, glTF and OpenPBR bases run in the whole suite: their code is the constructor's,
#: already checked, over bases checked on their own. (The coated and Weidlich–Wilkie models
#: over every base took 42 of the quick tier's 105 s in this module.)
SLOW_LAYERED = {f"{ctor}({base})" for ctor in ("coated", "weidlich_wilkie")
                for base in ("gltf_pbr", "gltf_pbr_clearcoat", "gltf_pbr_anisotropic",
                             "gltf_pbr_transmission", "rough_conductor_anisotropic",
                             "rough_dielectric_anisotropic", "openpbr")} | {"weidlich_wilkie(oren_nayar)"}


def _marks(name, slow=False):
    return [pytest.mark.slow] if slow or name in SLOW_MODELS or name in SLOW_LAYERED else []


def _value_cases():
    for name in NAMES:
        for dtype in ("float32", "float64"):
            slow = dtype == "float32" and "(" in name and name not in QUICK_FLOAT32_LAYERED
            yield pytest.param(name, dtype, id=f"{name}-{dtype}", marks=_marks(name, slow))


@pytest.mark.parametrize("name, dtype", list(_value_cases()))
def test_values_and_gradients_finite_and_nonnegative(name, dtype):
    model = get_model(name)
    params, wi, wo = _batch(model, dtype)
    grads, f = _eval_and_grad(name)({k: jnp.asarray(v) for k, v in params.items()},
                                    jnp.asarray(wi), jnp.asarray(wo))
    f = np.asarray(f)
    assert f.dtype == np.dtype(dtype)
    bad = ~np.isfinite(f) | (f < 0)
    assert not bad.any(), (f"{name} {dtype}: {bad.sum()} non-finite or negative values, first at "
                           f"wi={wi[bad][0]}, wo={wo[bad][0]}, "
                           f"{ {k: v[bad][0] for k, v in params.items()} }")
    for k, g in grads.items():
        g = np.asarray(g)
        assert np.all(np.isfinite(g)), f"{name} {dtype}: d f/d {k} not finite at " \
            f"wi={wi[~np.isfinite(g)][0]}, wo={wo[~np.isfinite(g)][0]}"
    # a one-sided model is zero for incidence from below and toward the other side
    if not model.capabilities.transmission:
        assert np.all(f[(wi[:, 2] * wo[:, 2]) < 0] == 0)
    if dtype == "float64":  # for tests 3 and 4b (_F64)
        _F64[name, False] = f
        if model.capabilities.reciprocal:
            _f64(name, swapped=True)


# ----------------------------------------------------------------------------------------------
# 2. sampling consistency
# ----------------------------------------------------------------------------------------------

N_U = 256
SAMPLE_SETS = ("default", "rough", "index_below_1", "anisotropic", "thick_absorbing")
SAMPLE_THETAS = (0.0, 40.0, 85.0, 89.9, 130.0)


def _sample_batch(model, seed=3):
    rng = np.random.default_rng(seed)
    rows = [(s, t) for s in SAMPLE_SETS for t in SAMPLE_THETAS]
    params = {p.name: np.repeat([_values(model, s)[p.name] for s, _ in rows], N_U)
              for p in model.parameters}
    wi = np.repeat([_dir(t, 20.0) for _, t in rows], N_U, axis=0)
    u = rng.random((len(rows) * N_U, 3))
    return params, wi, u


#: Models whose non-default options are tested on a sibling with the same option code (the
#: thin layer's options do not depend on its bottom): their defaults only.
DEFAULTS_ONLY = {"thin_layer(rough_dielectric)"}


def _option_variants():
    """Default options (fast), and each other choice of each option on its own (slow)."""
    cases = []
    for n in NAMES:
        cases.append(pytest.param(n, {}, id=n, marks=_marks(n)))
        for o in (() if n in DEFAULTS_ONLY else get_model(n).options):
            for c in o.choices:
                if c != o.default:
                    cases.append(pytest.param(n, {o.name: c}, id=f"{n}-{o.name}={c}",
                                              marks=pytest.mark.slow))
    return cases


@pytest.mark.parametrize("name, options", _option_variants())
def test_sample_weight_is_f_cos_over_pdf_and_pdf_matches(name, options):
    model = get_model(name)
    params, wi, u = _sample_batch(model)
    try:
        wo, weight, pdf_s, f, pdf_e = _fn(name, "sample_eval_pdf", options)(params, wi, u)
    except ValueError as exc:  # a combination the model refuses, with a message
        assert "option" in str(exc) or "isotropic" in str(exc), exc
        return
    assert np.all(np.isfinite(wo)) and np.all(np.isfinite(weight)) and np.all(np.isfinite(pdf_s))
    assert np.all(weight >= 0) and np.all(pdf_s >= 0)
    valid = pdf_s > 0
    assert valid.any()
    assert np.all(weight[~valid] == 0)
    # narrow lobes: the recomputed half-vector moves D by (δθ/α)²; compare where pdf is moderate
    ok = valid & (pdf_s < 1e6)
    np.testing.assert_allclose(pdf_e[ok], pdf_s[ok], rtol=2e-5, atol=1e-12,
                               err_msg=f"{name}: pdf(wi, wo) != the pdf sample() returned")
    expected = f[ok] * np.abs(wo[ok, 2]) / pdf_s[ok]
    np.testing.assert_allclose(weight[ok], expected, rtol=2e-5, atol=1e-12,
                               err_msg=f"{name}: weight != f |cos θo| / pdf")


# ----------------------------------------------------------------------------------------------
# 3. reciprocity
# ----------------------------------------------------------------------------------------------


#: 1/sr: values this small are the underflowing tails of a lobe (its peak is O(1) to O(1e6)).
TAIL = 1e-30


@pytest.mark.parametrize("name", [pytest.param(n, marks=_marks(n)) for n in NAMES
                                  if get_model(n).capabilities.reciprocal])
def test_reciprocity_where_declared(name):
    model = get_model(name)
    params, wi, wo = _batch(model, "float64")
    f_io, f_oi = _f64(name), _f64(name, swapped=True)
    reflection = wi[:, 2] * wo[:, 2] > 0
    # atol: a tail that underflows (exp of -100 and below) may reach 0 on one side first
    np.testing.assert_allclose(f_io[reflection], f_oi[reflection], rtol=1e-7, atol=TAIL,
                               err_msg=f"{name}: f(i, o) != f(o, i) on the reflection side")
    index = model.parameters_with_role("index")
    if model.capabilities.transmission and len(index) == 1:
        # Walter eq. 21: f(i, o)/η_o² = f(o, i)/η_i², with η = n_inside/n_outside (inside = -z)
        t = ~reflection & (wi[:, 2] > 0)
        eta = params[index[0].name][t]
        np.testing.assert_allclose(f_io[t] / eta**2, f_oi[t], rtol=1e-7, atol=TAIL,
                                   err_msg=f"{name}: generalized reciprocity fails")


# ----------------------------------------------------------------------------------------------
# 4. white furnace
# ----------------------------------------------------------------------------------------------

#: samples per (parameter set, θi) row in the first round: a multiple of CHUNK, so that every
#: compiled call of the sampling check's function holds one row's parameters; a model that
#: tabulates per call samples in blocks of N_FURNACE (:func:`_furnace_block`)
N_FURNACE = 4 * 8192
N_FURNACE_FIRST = 2 * CHUNK
#: a row whose standard error is above FURNACE_SE is sampled again, to the count its sample
#: variance says it needs times FURNACE_MARGIN (at least one more granule), up to N_FURNACE_MAX
#: (the count is stated when the test fails); only that row is sampled again
FURNACE_SE, FURNACE_MARGIN, N_FURNACE_MAX = 0.003, 1.25, 81 * N_FURNACE
FURNACE_LIMIT = 1.01
FURNACE_SETS = ("default", "rough", "smooth", "anisotropic")
FURNACE_THETAS = (0.0, 60.0, 85.0, 89.0, 89.9)


def _tabulates_per_call(model) -> bool:
    """Whether each call of the model tabulates per parameter set: SpongeCake's
    multiple-scattering lobe (``multiple=``, asked of the model's arguments) makes the albedo
    tables of its energy budget (fitlab/models/directional_albedo.py) in every call."""
    return model.argument("multiple", "none") != "none"


@functools.lru_cache(maxsize=None)
def _furnace_block(name, options=()):
    """The sum and the sum of squares of ``sample``'s weights for N_FURNACE uniforms of one
    (parameter set, θi) row, its parameters as scalars: one table per block of a model that
    tabulates per call (:func:`_tabulates_per_call`), one compilation per model and options."""
    model = get_model(name)

    def moments(params, wi, u):
        w = model.sample(params, jnp.broadcast_to(wi, u.shape), u, **dict(options))[1]
        return jnp.sum(w), jnp.sum(w * w)

    return jax.jit(moments)


def _furnace(name, seed=11):
    """{(set, θi): (mean weight, its standard error, samples)} of the white furnace, albedo
    parameters at their upper bound; rows are sampled until their standard error is at most
    FURNACE_SE (or N_FURNACE_MAX samples).

    Rows go through the sampling check's compiled call (test 2: per-row parameters in chunks of
    CHUNK), except for a model that tabulates per call: it samples each row in blocks of
    N_FURNACE with scalar parameters (:func:`_furnace_block`), one table per block instead of
    one per chunk (the learned two-layer SpongeCake's furnace: 66 s -> 34 s). Either way the
    uniforms are drawn row after row, so both give the same sample."""
    model = get_model(name)
    rng = np.random.default_rng(seed)
    base = {s: {**_values(model, s), **{p.name: p.upper for p in model.parameters_with_role("albedo")}}
            for s in FURNACE_SETS}
    stats = {(s, t): [0.0, 0.0, 0] for s in FURNACE_SETS for t in FURNACE_THETAS}
    # a model offering the visible-normal sampler is sampled with it (the albedo does not depend
    # on the sampler, its variance does: the standard one needed 2.6 million samples a row at 89.9°)
    visible = any(o.name == "sampling" and "visible" in o.choices for o in model.options)
    options = {"sampling": "visible"} if visible else {}
    if _tabulates_per_call(model):
        block = _furnace_block(name, tuple(options.items()))

        def draw(rows, n):
            for s, t in rows:
                params = {p.name: jnp.asarray(np.float64(base[s][p.name])) for p in model.parameters}
                wi = jnp.asarray(_dir(t, 10.0))
                for _ in range(n // N_FURNACE):
                    a, b = block(params, wi, jnp.asarray(rng.random((N_FURNACE, 3))))
                    yield (s, t), float(a), float(b), N_FURNACE
    else:
        call = _fn(name, "sample_eval_pdf", options)  # the sampling check's compiled call

        def draw(rows, n):
            params = {p.name: np.repeat([base[s][p.name] for s, _ in rows], n)
                      for p in model.parameters}
            wi = np.repeat([_dir(t, 10.0) for _, t in rows], n, axis=0)
            w = call(params, wi, rng.random((len(rows) * n, 3)))[1].reshape(len(rows), n)
            for row, wr in zip(rows, w):
                yield row, wr.sum(), (wr * wr).sum(), n

    granule = N_FURNACE if _tabulates_per_call(model) else CHUNK
    need = {r: max(granule, N_FURNACE_FIRST) for r in stats}
    while need:
        rows = sorted(need, key=lambda r: need[r])
        for count in sorted(set(need.values())):  # rows needing the same count drawn together
            same = [r for r in rows if need[r] == count]
            step = max(1, 4 * N_FURNACE // count)  # <= 4 N_FURNACE samples a call
            for start in range(0, len(same), step):
                for row, a, b, m in draw(same[start:start + step], count):
                    stats[row][0] += a
                    stats[row][1] += b
                    stats[row][2] += m
        out = {r: (a / m, float(np.sqrt(max(b / m - (a / m) ** 2, 0.0) / m)), m)
               for r, (a, b, m) in stats.items()}
        need = {r: _furnace_more(stats[r], granule) for r in stats
                if out[r][1] > FURNACE_SE and stats[r][2] < N_FURNACE_MAX}
    return out


def _furnace_more(stat, granule):
    """Samples a row needs beyond its ``stat`` = [Σw, Σw², n] for a standard error of
    FURNACE_SE: its sample variance's count times FURNACE_MARGIN, in whole granules, at least
    one, so that it never passes N_FURNACE_MAX."""
    a, b, m = stat
    var = max(b / m - (a / m) ** 2, 0.0)
    want = int(np.ceil(FURNACE_MARGIN * var / FURNACE_SE ** 2 / granule)) * granule
    return int(min(max(want - m, granule), N_FURNACE_MAX - m))


def _furnace_marks(name):
    """A whole-suite model that tabulates per call (the lobe's energy budget over a fibre or
    surface layer, the learned lobes) samples up to 2 million weights through the lobe's budget:
    its furnace's time is running compiled code, so it is compiled at XLA's default
    optimization level (``optimized``: the learned two-layer model's furnace 34 -> 16-21 s)."""
    marks = _marks(name)
    return marks + [pytest.mark.optimized] if marks and _tabulates_per_call(get_model(name)) else marks


@pytest.mark.parametrize("name", [pytest.param(n, marks=_furnace_marks(n)) for n in NAMES
                                  if get_model(n).capabilities.energy_conserving])
def test_white_furnace_albedo_at_most_one(name):
    """The mean sample weight estimates ∫ f |cos θo| dωo (the albedo); with albedo parameters
    at their upper bound it is at most FURNACE_LIMIT = 1.01 at every θi up to 89.9°, with a
    standard error of at most FURNACE_SE = 0.003 (rows are sampled until they have it)."""
    out = _furnace(name)
    over = {r: v for r, v in out.items() if v[0] > FURNACE_LIMIT}
    noisy = {r: v for r, v in out.items() if v[1] > FURNACE_SE}
    fmt = lambda d: ", ".join(f"{r}: {m:.4f} ± {e:.4f} ({n:,} samples)"  # noqa: E731
                              for r, (m, e, n) in d.items())
    assert not over, f"{name}: albedo > {FURNACE_LIMIT} at " + fmt(over)
    assert not noisy, f"{name}: standard error > {FURNACE_SE} at " + fmt(noisy)


# ----------------------------------------------------------------------------------------------
# 4b. interchangeable lobes
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", [n for n in NAMES if get_model(n).exchangeable])
def test_exchangeable_lobes_trade_places(name):
    """Swapping the values of two interchangeable lobes (alternating widths 0.03 / 0.6 from the
    'anisotropic' set, so the lobes differ) leaves f and the pdf unchanged."""
    model = get_model(name)
    params, wi, wo = _batch(model, "float64")
    for ex in model.exchangeable:
        a, b = ex.parameters[0], ex.parameters[1]
        swapped = dict(params)
        for x, y in zip(a, b):
            swapped[x], swapped[y] = params[y], params[x]
        assert any(np.any(params[x] != params[y]) for x, y in zip(a, b))
        for which, fn, unswapped in (("eval", functools.partial(_eval, name), _f64(name)),
                                     ("pdf", _fn(name, "pdf"), None)):
            if unswapped is None:
                unswapped = fn(params, wi, wo)
            np.testing.assert_allclose(fn(swapped, wi, wo), unswapped, rtol=1e-12,
                                       atol=0, err_msg=f"{name}: {which} changes when lobes "
                                       f"{a} and {b} trade places")


# ----------------------------------------------------------------------------------------------
# 5. χ² sampling test (slow)
# ----------------------------------------------------------------------------------------------

CHI2_THETAS = (30.0, 80.0)
CHI2_CASES = [pytest.param(n, t, id=f"{n}-{t:g}", marks=pytest.mark.slow)
              for n in NAMES for t in CHI2_THETAS]
CHI2_LEVEL = sidak_level(0.01, len(CHI2_CASES))
CHI2_Z = sidak_z(0.01, len(CHI2_CASES))
N_CHI2 = 100_000


# its time goes into running the sampler and the pdf's cell integrals (tests/chi2.py) on
# 10^5 samples: compiled at XLA's default optimization level (22% less time in the whole suite)
@pytest.mark.optimized
@pytest.mark.parametrize("name, theta", CHI2_CASES)
def test_chi2_sampling_matches_pdf(name, theta, request):
    model = get_model(name)
    p = _values(model, "anisotropic")
    wi = _dir(theta, 20.0)
    sample_fn, pdf_fn = _fn(name, "sample"), _fn(name, "pdf")

    def sample(u):
        wo, _, pdf = sample_fn(p, np.broadcast_to(wi, np.shape(u)), u)
        return wo, pdf

    def density(wo):
        return pdf_fn(p, np.broadcast_to(wi, np.shape(wo)), wo)

    seed = zlib.crc32(request.node.callspec.id.encode())
    res = chi2_test(sample, density, N_CHI2, seed)
    print(res.report())
    assert res.pdf_mass <= 1.0 + 1e-6, res.report()
    assert abs(res.pdf_mass - res.valid_fraction) <= CHI2_Z * res.mass_sigma() + 1e-6, res.report()
    assert res.p_value >= CHI2_LEVEL, f"rejected at Šidák level {CHI2_LEVEL:.3g}: {res.report()}"
