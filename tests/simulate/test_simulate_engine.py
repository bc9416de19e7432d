"""The Dr.Jit walk's engine: Mitsuba's components against fitlab's JAX models (the conventions
converted in components.py), the SGGX sampling that Mitsuba's own plugin gets wrong, the same
bytes whatever the thread count, and no code shared between the walk and the models it judges.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.simulate import engine, scene_from_dict, simulate

ROOT = Path(__file__).resolve().parents[2]
RNG = np.random.default_rng(20261206)


@pytest.fixture(scope="module")
def mi():
    return engine.load("cpu").mi


def _directions(n, up=None):
    v = RNG.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if up is not None:
        v[:, 2] = np.abs(v[:, 2]) * (1 if up else -1)
    return v


def _vec(mi, a):
    return mi.Vector3f(np.ascontiguousarray(a.T, dtype=np.float32))


def _boundary(kind, distribution, **values):
    from fitlab.simulate import components as comp

    aniso = "alpha_y" in values and values["alpha_y"] != values.get("alpha")
    v = comp.BoundaryValues(**{"alpha_y": values.get("alpha", 0.0), **values})
    return comp.make_boundary(comp.BoundarySpec(kind, distribution, aniso), v)


CASES = [
    # (components boundary, JAX model, its params and options)
    (("dielectric", "ggx", {"alpha": 0.3, "eta": 1.5}), "rough_dielectric",
     {"alpha": 0.3, "eta": 1.5}, {"distribution": "ggx"}),
    (("dielectric", "beckmann", {"alpha": 0.15, "eta": 1 / 1.33}), "rough_dielectric",
     {"alpha": 0.15, "eta": 1 / 1.33}, {"distribution": "beckmann"}),
    (("conductor", "beckmann", {"alpha": 0.1, "alpha_y": 0.3, "n": (0.2, 1.1, 1.4),
                                "k": (3.9, 2.5, 2.2)}), "rough_conductor_anisotropic",
     {"alpha_x": 0.1, "alpha_y": 0.3, "n": jnp.array([0.2, 1.1, 1.4]),
      "k": jnp.array([3.9, 2.5, 2.2])}, {"distribution": "beckmann"}),
    (("dielectric", "ggx", {"alpha": 0.1, "alpha_y": 0.4, "eta": 1.5}),
     "rough_dielectric_anisotropic", {"alpha_x": 0.1, "alpha_y": 0.4, "eta": 1.5},
     {"distribution": "ggx"}),
    (("conductor", "ggx", {"alpha": 0.25, "n": (0.2, 1.1, 1.4), "k": (3.9, 2.5, 2.2)}),
     "rough_conductor", {"alpha": 0.25, "n": jnp.array([0.2, 1.1, 1.4]),
                         "k": jnp.array([3.9, 2.5, 2.2])}, {"distribution": "ggx"}),
    (("lambertian", "smooth", {"albedo": (0.2, 0.5, 0.8)}), "lambertian",
     {"albedo": jnp.array([0.2, 0.5, 0.8])}, {}),
]


@functools.lru_cache(maxsize=None)
def _jitted_eval(name, options):
    from fitlab.models import get_model

    return jax.jit(functools.partial(get_model(name).eval, **dict(options)))


def _model_f(model, params, wi, wo, options, shape):
    """The JAX model's f per direction pair and channel (per-channel parameters broadcast
    against a channel axis): one compiled call (op by op, each of the model's operations
    compiled on its own)."""
    per_channel = any(np.ndim(v) == 1 for v in params.values())
    a, b = (wi[:, None, :], wo[:, None, :]) if per_channel else (wi, wo)
    f = np.asarray(_jitted_eval(model.name, tuple(sorted(options.items())))(
        params, jnp.asarray(a), jnp.asarray(b)))
    return np.broadcast_to(f.reshape(len(wi), -1), shape)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[1]}-{c[0][1]}")
def test_mitsuba_eval_is_fitlabs_f_and_its_weight_is_the_flux_fraction(mi, case):
    """components.f_from_mitsuba: Mitsuba's importance-transport eval divided by |cos θo| is
    fitlab's f (radiance convention) on both sides of an interface; the sample weight equals
    f|cos θo|/pdf (no 1/η² of radiance transport)."""
    from fitlab.models import get_model

    (kind, dist, values), name, params, options = case
    bd = _boundary(kind, dist, **values)
    model = get_model(name)
    n = 400
    sides = kind == "dielectric"
    wi = np.concatenate([_directions(n, True), _directions(n, False)]) if sides \
        else _directions(n, True)
    wo = _directions(len(wi))
    f = np.array(bd.eval(_vec(mi, wi), _vec(mi, wo), mi.Bool(True))).T
    ref = _model_f(model, params, wi, wo, options, f.shape)
    big = ref > 1e-3 * ref.max()
    np.testing.assert_allclose(f[big], ref[big], rtol=2e-3)
    # sampling: weight = eval·|cos θo| / pdf at the sampled direction
    u = RNG.random((len(wi), 3)).astype(np.float32)
    wo_s, w_s, p_s = bd.sample(_vec(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                               mi.UInt32(0), mi.Bool(True))
    wo_s = np.array(wo_s).T.astype(float)
    w_s, p_s = np.array(w_s).T, np.array(p_s)
    ok = (p_s > 1e-2) & (w_s[:, 0] > 0)
    # every row, the rows of f's call: one compiled shape (ok selects after)
    f_s = _model_f(model, params, wi, wo_s, options, w_s.shape)[ok]
    np.testing.assert_allclose(w_s[ok], f_s * np.abs(wo_s[ok, 2:3]) / p_s[ok, None],
                               rtol=5e-3, atol=1e-6)


def test_mitsubas_beckmann_masking_is_the_rational_approximation(mi):
    """Why fitlab's exact Beckmann is its own: Mitsuba's roughdielectric with ``beckmann``
    differs from fitlab's erf masking by up to ~0.3 % (Walter eq. 27's error), fitlab's own
    Dr.Jit family by float32 rounding only."""
    import mitsuba

    wi, wo = _directions(2000, True), _directions(2000)
    ref = np.asarray(_jitted_eval("rough_dielectric", (("distribution", "beckmann"),))(
        {"alpha": 0.15, "eta": 1.5}, jnp.asarray(wi), jnp.asarray(wo)))
    bsdf = mitsuba.load_dict({"type": "roughdielectric", "distribution": "beckmann",
                              "alpha": 0.15, "int_ior": 1.5, "ext_ior": 1.0})
    from fitlab.simulate.components import _local_si, f_from_mitsuba

    ctx = mitsuba.BSDFContext(mitsuba.TransportMode.Importance)
    f_mi = np.array(f_from_mitsuba(bsdf.eval(ctx, _local_si(_vec(mi, wi)), _vec(mi, wo), True),
                                   _vec(mi, wo)))[0]
    f_own = np.array(_boundary("dielectric", "beckmann", alpha=0.15, eta=1.5).eval(
        _vec(mi, wi), _vec(mi, wo), mi.Bool(True)))[0]
    big = ref > 1e-3 * ref.max()
    rel_mi = np.abs(f_mi[big] / ref[big] - 1).max()
    rel_own = np.abs(f_own[big] / ref[big] - 1).max()
    assert 1e-3 < rel_mi < 5e-3 and rel_own < 1e-3, (rel_mi, rel_own)


def test_phase_functions_match_fitlab_and_sample_their_own_density(mi):
    """HG (Mitsuba's ``hg``) and SGGX (Mitsuba's sggx functions in fitlab's frame) against
    fitlab.phase; the sampled directions' mean equals the density's by quadrature. Mitsuba's own
    ``sggx`` plugin fails the second check for a fiber along x (mean off by 0.8)."""
    from fitlab import phase
    from fitlab.simulate import components as comp

    N = 300_000
    i = np.arange(N) + 0.5
    z = 1 - 2 * i / N
    r = np.sqrt(1 - z * z)
    ang = np.pi * (1 + 5**0.5) * i
    grid = np.stack([r * np.cos(ang), r * np.sin(ang), z], 1)
    S = comp.sggx_matrix("fiber", 0.1, (1.0, 0.0, 0.0))
    cases = [(comp.PHASES["hg"]({"g": 0.6}), phase.eval_hg, {"g": jnp.asarray(0.6)}),
             (comp.PHASES["sggx"]({"S": S}), phase.eval_sggx, {"S": jnp.asarray(S)}),
             (comp.PHASES["sggx"]({"S": comp.sggx_matrix("surface", 0.3, (0.3, 0.4, 0.866))}),
              phase.eval_sggx,
              {"S": jnp.asarray(comp.sggx_matrix("surface", 0.3, (0.3, 0.4, 0.866)))})]
    for ph, ref_eval, params in cases:
        wi, wo = _directions(50), _directions(50)
        p = np.array(ph.eval(_vec(mi, wi), _vec(mi, wo), mi.Bool(True)))
        np.testing.assert_allclose(p, np.asarray(ref_eval(params, jnp.asarray(wi),
                                                          jnp.asarray(wo))), rtol=1e-4)
        w1 = np.tile(_directions(1), (N, 1))
        dens = np.asarray(ref_eval(params, jnp.asarray(w1), jnp.asarray(grid)))
        mean_q = (dens[:, None] * grid).sum(0) * 4 * np.pi / N
        u = RNG.random((N, 3)).astype(np.float32)
        wo_s, _, _ = ph.sample(_vec(mi, w1), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                               mi.Bool(True))
        np.testing.assert_allclose(np.array(wo_s).T.mean(0), mean_q, atol=0.01)


def _slab_scene(**over):
    d = {"stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                   {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2,
                    "sigma_s": 0.8, "phase": "hg", "g": 0.5},
                   {"type": "interface", "distribution": "beckmann", "alpha": 0.3}],
         "illumination": {"theta_i": [30.0]},
         "detector": {"type": "hemisphere", "theta_bins": 3, "phi_bins": 4}}
    d.update(over)
    return scene_from_dict(d)


@pytest.mark.parametrize("detector", [None, {"type": "inplane", "theta_o": [-40, 10, 150],
                                             "estimator": "point"},
                                      {"type": "inplane", "theta_o": [-40, 10, 150],
                                       "acceptance_sr": 0.05}])
def test_same_seed_same_bytes_whatever_the_thread_count_and_batch(detector):
    """Bins, point estimates and cones accumulate per path and are summed per block in path
    order: 1 or 2 Dr.Jit threads, one launch or many, give identical numbers; the walk parks
    Dr.Jit's thread pool between its kernels (walk._Cores) and leaves it the size it found."""
    import drjit as dr

    scene = _slab_scene(**({"detector": detector} if detector else {}))
    before = dr.thread_count()
    try:
        dr.set_thread_count(1)
        a = simulate(scene, 3000, seed=3)
        assert dr.thread_count() == 1
        dr.set_thread_count(2)
        b = simulate(scene, 3000, seed=3, batch_size=1024)
        assert dr.thread_count() == 2
    finally:
        dr.set_thread_count(before)
    np.testing.assert_array_equal(a.value, b.value)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    np.testing.assert_array_equal(a.energy, b.energy)
    assert a.value.sum() > 0


#: The walk's modules: Dr.Jit and Mitsuba, never the JAX models they judge.
WALK_MODULES = ("walk.py", "components.py", "own_bsdfs.py", "protocol.py", "engine.py")
MODEL_CODE = ("fitlab.models", "fitlab.microfacet", "fitlab.fresnel", "fitlab.phase",
              "fitlab.vmf", "fitlab.frame", "fitlab.numerics", "jax")


@pytest.mark.parametrize("name", WALK_MODULES)
def test_the_walk_shares_no_code_with_the_models(name):
    tree = ast.parse((ROOT / "fitlab" / "simulate" / name).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module)
    shared = sorted(m for m in imported if any(m == c or m.startswith(c + ".")
                                               for c in MODEL_CODE))
    assert not shared, f"{name} imports {shared}"


@pytest.mark.parametrize("name, params, options, theta_o, tol", [
    # one rough interface: the first event's BSDF, exact up to float32 rounding, both sides
    ("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, {"distribution": "ggx"},
     [-70, -30, 0, 20, 45, 110, 150, 175], 1e-4),
    # a smooth coat over a Lambertian base, every bounce in closed form
    ("coated(lambertian)", {"coat_eta": 1.5, "coat_tau": 0.3, "albedo": 0.7},
     {"interreflection": "closed_form"}, [-60, -20, 0, 30, 60], 0.01),
    # an index-matched Henyey–Greenstein slab, single scattering (SpongeCake eqs 8-14)
    ("spongecake(hg)", None, {}, [-60, -20, 10, 40, 120, 160], 0.01),
], ids=["single_interface", "coated_lambertian", "hg_slab"])
def test_simulator_and_jax_models_agree(name, params, options, theta_o, tol):
    """The simulator (Dr.Jit + Mitsuba) against the JAX model of the same stack
    (``Model.scene_of``), point estimates at 30°: within 4 standard errors plus ``tol``; the
    two share no code (test_the_walk_shares_no_code_with_the_models)."""
    import jax

    from fitlab.models import get_model

    model = get_model(name)
    if params is None:
        params = {p.name: p.default for p in model.parameters}
    options = {**model.default_options(), **options}
    scene = model.scene_of(params, options)
    scene = {**scene, "illumination": {"theta_i": [30.0]},
             "detector": {"type": "inplane", "theta_o": theta_o, "estimator": "point"}}
    if name.startswith("spongecake"):
        scene["effects"] = {**scene.get("effects", {}), "volume_scattering": "single"}
    res = simulate(scene_from_dict(scene), 60_000, seed=9)
    t, p = np.radians(res.theta_o), np.radians(res.phi_o)
    wo = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], 1)
    wi = np.broadcast_to([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))], wo.shape)
    pj = {k: jnp.float64(v) for k, v in params.items()}
    f = np.asarray(jax.jit(lambda a, b: model.eval(pj, a, b, **options))(
        jnp.asarray(wi), jnp.asarray(wo)))
    v, s = res.value[:, 0], res.sigma[:, 0]
    assert np.count_nonzero(f) >= len(f) - 1 and np.all((v > 0) == (f > 0)), \
        np.c_[res.theta_o, f, v, s]
    assert np.all(np.abs(f - v) <= 4 * s + tol * f), np.c_[res.theta_o, f, v, s]


def test_forced_branches_weigh_as_mitsubas_one_lobe_contexts(mi):
    """A forced reflection or refraction of a rough dielectric (one unforced Mitsuba sample,
    its lobe choice forced through sample1, weighted by F or 1 − F) equals Mitsuba's own
    sampling with only that lobe enabled (BSDFContext type_mask), direction and weight."""
    import mitsuba

    from fitlab.simulate import components as comp
    from fitlab.simulate.protocol import FORCE_REFLECT, FORCE_REFRACT

    bd = comp.make_boundary(comp.BoundarySpec("dielectric", "ggx"),
                            comp.BoundaryValues(alpha=0.3, alpha_y=0.3, eta=1.5), True)
    n = 2000
    wi = np.concatenate([_directions(n, True), _directions(n, False)])
    u = RNG.random((len(wi), 3)).astype(np.float32)
    si = comp._local_si(_vec(mi, wi))
    for code, flags in ((FORCE_REFLECT, mitsuba.BSDFFlags.Reflection),
                        (FORCE_REFRACT, mitsuba.BSDFFlags.Transmission)):
        wo, w, _ = bd.sample(_vec(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                             mi.UInt32(code), mi.Bool(True))
        ctx = mitsuba.BSDFContext(mitsuba.TransportMode.Importance, flags)
        bs, w_ref = bd.bsdf.sample(ctx, si, mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                                   True)
        w, w_ref = np.array(w)[0], np.array(w_ref)[0]
        ok = np.isfinite(w_ref) & (w_ref > 1e-4)
        assert ok.sum() > n // 2
        np.testing.assert_allclose(w[ok], w_ref[ok], rtol=2e-4, atol=1e-6)
        np.testing.assert_allclose(np.array(wo).T[ok], np.array(bs.wo).T[ok], atol=2e-5)
        # one branch for every lane (force one int, as the split's reflections): that lobe's
        # context itself, the same weights, directions and unforced density
        wo1, w1, p1 = bd.sample(_vec(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                                code, mi.Bool(True), True)
        _, _, p = bd.sample(_vec(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]),
                            mi.UInt32(code), mi.Bool(True), True)
        np.testing.assert_array_equal(np.array(w1)[0][ok], w_ref[ok])
        np.testing.assert_allclose(np.array(wo1).T[ok], np.array(bs.wo).T[ok], atol=2e-6)
        np.testing.assert_allclose(np.array(p1)[ok], np.array(p)[ok], rtol=1e-3)


@pytest.mark.parametrize("distribution", ["smooth", "beckmann", "vmf"])
def test_a_branch_forced_for_every_lane_is_the_per_lane_forcing(mi, distribution):
    """``force`` as one int (the split's reflections): fitlab's own dielectrics and the smooth
    one give exactly what the same code per lane gives (Mitsuba's, in its one-lobe context, is
    tested against that context above)."""
    from fitlab.simulate import components as comp
    from fitlab.simulate.protocol import FORCE_REFLECT, FORCE_REFRACT

    bd = comp.make_boundary(comp.BoundarySpec("dielectric", distribution),
                            comp.BoundaryValues(alpha=0.3, alpha_y=0.3, eta=1.5), True)
    wi = np.concatenate([_directions(500, True), _directions(500, False)])
    u = RNG.random((len(wi), 3)).astype(np.float32)
    for code in (FORCE_REFLECT, FORCE_REFRACT):
        args = (_vec(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]))
        one = bd.sample(*args, code, mi.Bool(True), True)
        per_lane = bd.sample(*args, mi.UInt32(code), mi.Bool(True), True)
        assert np.array(one[1])[0].max() > 0
        for a, b in zip(one, per_lane):
            np.testing.assert_array_equal(np.broadcast_to(np.array(a), np.shape(np.array(b))),
                                          np.array(b))


@pytest.mark.parametrize("top, detector", [
    ("ggx", {"type": "inplane", "theta_o": [-40, -30, 10, 150], "acceptance_sr": 0.05}),
    ("smooth", {"type": "inplane", "theta_o": [-40, -30, 10, 150], "acceptance_sr": 0.05}),
    ("ggx", None)], ids=["rough-cones", "smooth-cones", "rough-bins"])
def test_split_same_bytes_whatever_the_thread_count_and_batch(top, detector):
    """Splitting at the first interface (its reflections tallied per block apart from the
    walk, a smooth top's computed once and counted per path): 1 or 2 threads, one launch or
    many, identical numbers; the split's reflection (order 0, the mirror cone) is there."""
    import drjit as dr

    stack = [{"type": "interface", "distribution": "ggx", "alpha": 0.2} if top == "ggx"
             else {"type": "interface"},
             {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2,
              "sigma_s": 0.8, "phase": "hg", "g": 0.5},
             {"type": "interface", "distribution": "beckmann", "alpha": 0.3}]
    scene = _slab_scene(stack=stack, effects={"split_first_interface": True},
                        **({"detector": detector} if detector else {}))
    before = dr.thread_count()
    try:
        dr.set_thread_count(1)
        a = simulate(scene, 9000, seed=3)
        dr.set_thread_count(2)
        b = simulate(scene, 9000, seed=3, batch_size=4096)
    finally:
        dr.set_thread_count(before)
    for f in ("value", "sigma", "by_order", "sigma_by_order", "energy", "energy_sigma"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert a.plan.split_first and a.by_order[0].max() > 0


def test_split_cones_are_sought_only_where_a_cell_has_candidates(mi):
    """The split finds its reflections' cones in two passes, the second only for directions
    whose cell has a candidate cone (ConeIndex.device_near): every direction inside a cone is
    among them, for narrow and wide cones, at the poles and near the cell edges."""
    from fitlab.simulate import walk

    for sr in (0.0005, 0.01, 0.3):
        axes = np.concatenate([[[0, 0, 1], [0, 0, -1], [1, 0, 0], [0.6, 0.8, 0]],
                               _directions(40)])
        det = walk.Detector(axes, np.full(len(axes), 1.0 - sr / (2 * np.pi)))
        cones = walk.ConeIndex(det)
        gamma = np.arccos(det.cone_cos[0])
        near_axes = axes[RNG.integers(0, len(axes), 40_000)] + RNG.normal(size=(40_000, 3)) \
            * gamma
        w = np.concatenate([_directions(40_000), near_axes])
        w = (w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32)
        near = np.array(cones.device_near(_vec(mi, w)))
        p, _ = cones.pairs(w)
        assert len(p) > 1000 and near[p].all(), sr
        assert near.mean() < 0.9 or sr == 0.3


def test_cones_no_path_reaches_tally_zero():
    """Cones so narrow that no path's exit (nor, split, its first reflection) lands in one:
    every launch finds no (path, cone) pair, and the values are zeros with zero errors."""
    for effects in ({}, {"split_first_interface": True}):
        scene = _slab_scene(detector={"type": "inplane", "theta_o": [-80.0, 150.0],
                                      "acceptance_sr": 1e-9}, effects=effects)
        res = simulate(scene, 3000, seed=1, batch_size=1024)
        assert np.all(res.value == 0) and np.all(res.sigma == 0) and res.energy.sum() > 0


def test_cones_found_on_the_host_tally_as_the_kernels(monkeypatch):
    """Cone tables wider than ConeIndex.DEVICE_WIDTH are tested on the host from the exit
    directions: the same tallies as the kernel's own cone members (the sums' order aside)."""
    from fitlab.simulate import walk

    scene = _slab_scene(detector={"type": "inplane", "theta_o": [-40, -20, 10, 150],
                                  "acceptance_sr": 0.05})
    kernel = simulate(scene, 20_000, seed=5)
    monkeypatch.setattr(walk.ConeIndex, "DEVICE_WIDTH", 0)
    host = simulate(scene, 20_000, seed=5)
    assert kernel.value.sum() > 0
    np.testing.assert_allclose(host.value, kernel.value, rtol=1e-12, atol=0)
    np.testing.assert_allclose(host.sigma, kernel.sigma, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(host.energy, kernel.energy)
