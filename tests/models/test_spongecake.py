"""SpongeCake (``spongecake(...)``, fitlab/models/spongecake.py): the exact single scattering of
volumetric layers against the simulator's single-scattering point estimates, its closed forms,
and its numerics on the hard cases the issue names (α 1e-3…1, Tρ 1e-4…100, θ to 89.99°, fibers
along and across the normal, any orientation; float32 and float64; under jit and vmap). The
registry contract (tests/models/test_model_contract.py) covers sampling, reciprocity and the furnace
for the listed examples."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.models import get_model
from fitlab.models import spongecake as sc
from fitlab.phase import sggx_D, sggx_matrix, sggx_sigma, sggx_axial_D, sggx_axial_sigma
from fitlab.simulate.scene import scene_from_dict

try:
    from conftest import user_environment
except ImportError:  # pragma: no cover
    from tests.conftest import user_environment


def _dir(theta, phi=0.0):
    t, p = np.radians(theta), np.radians(phi)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def _params(model, **values):
    p = {q.name: q.default for q in model.parameters}
    p.update(values)
    return p


# ----------------------------------------------------------------------------------------------
# Closed forms
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["surface", "fiber"])
def test_axial_sggx_equals_the_matrix_forms(kind):
    rng = np.random.default_rng(0)
    w = rng.normal(size=(500, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    a = rng.normal(size=(500, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    alpha = rng.uniform(0.05, 1.0, 500)
    S = sggx_matrix(kind, jnp.asarray(alpha), jnp.asarray(a))
    np.testing.assert_allclose(sggx_axial_sigma(kind, jnp.asarray(alpha), jnp.asarray(a),
                                                jnp.asarray(w)),
                               sggx_sigma(S, jnp.asarray(w)), rtol=1e-10)
    np.testing.assert_allclose(sggx_axial_D(kind, jnp.asarray(alpha), jnp.asarray(a),
                                            jnp.asarray(w)),
                               sggx_D(S, jnp.asarray(w)), rtol=1e-8)


def test_phi_is_the_stable_form_of_one_minus_exp_over_x():
    x = jnp.asarray([0.0, 1e-9, 1e-4, 9.99e-4, 1e-3, 0.5, 3.0, 50.0, 1e9])
    ref = np.where(np.asarray(x) > 0, -np.expm1(-np.asarray(x)) / np.maximum(x, 1e-300), 1.0)
    np.testing.assert_allclose(sc.phi(x), ref, rtol=1e-12)
    x32 = jnp.asarray([0.0, 1e-6, 1e-3, 1.0, 1e9], jnp.float32)
    g = jax.vmap(jax.grad(sc.phi))(x32)
    assert np.all(np.isfinite(np.asarray(g))) and abs(float(g[0]) + 0.5) < 1e-6


def test_one_layer_is_eqs_10_12_14_as_printed():
    """In float64 at moderate depths the stable forms equal the paper's G of eqs 12 and 14."""
    m = get_model("spongecake(surface)")
    p = {k: jnp.asarray(v) for k, v in _params(m, alpha1=0.4, theta_p1=25.0, phi_p1=40.0,
                                               albedo1=0.9, f0_1=0.3, tau1=1.7).items()}
    L = sc.Layer("surface", 1)
    wi = jnp.asarray(_dir(35.0, 10.0))
    for wo in (_dir(60.0, 200.0), _dir(150.0, 80.0), _dir(100.0, 0.0)):
        wo = jnp.asarray(wo)
        Li = sc.projected_area(L, p, wi) / wi[2]
        Lo = sc.projected_area(L, p, wo) / wo[2]  # negative below the horizon
        G = (1 - jnp.exp(-p["tau1"] * (Li + Lo))) / (Li + Lo)
        if wo[2] < 0:
            G = G * jnp.exp(p["tau1"] * Lo)  # eq. 14
        # eq. 11 (with eq. 5's F): F D G / (4 |cos i cos o|)
        f_ref = sc.reduced_phase(L, p, wi, wo) * G / abs(float(wi[2] * wo[2]))
        np.testing.assert_allclose(m.eval(p, wi, wo), f_ref, rtol=1e-12)


def test_layers_attenuate_each_other_and_the_substrate():
    """Two identical layers of Tρ/2 are one layer of Tρ (§4.3); the substrate term is the
    substrate's f times the stack's transmittance along both directions (§4.4)."""
    one, two = get_model("spongecake(fiber)"), get_model("spongecake(fiber,fiber)")
    layer = dict(alpha=0.35, theta_p=70.0, phi_p=-30.0, albedo=0.8, f0=0.6)
    p1 = {f"{k}1" if k != "f0" else "f0_1": v for k, v in layer.items()} | {"tau1": 2.4}
    p2 = dict(p1) | {f"{k}2" if k != "f0" else "f0_2": v for k, v in layer.items()}
    p2.update(tau1=1.2, tau2=1.2)
    rng = np.random.default_rng(1)
    wi = rng.normal(size=(64, 3))
    wo = rng.normal(size=(64, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    np.testing.assert_allclose(one.eval(p1, wi, wo), two.eval(p2, wi, wo), rtol=1e-10)
    sub = get_model("spongecake(fiber,substrate=lambertian)")
    lone = get_model("spongecake(fiber,delta=false)")
    up_i, up_o = _dir(20.0), _dir(50.0, 120.0)
    ps = p1 | {"albedo": 0.6}
    layers = (sc.Layer("fiber", 1),)
    t = (sc.delta_transmittance(layers, p1, jnp.asarray(up_i))
         * sc.delta_transmittance(layers, p1, jnp.asarray(up_o)))
    np.testing.assert_allclose(sub.eval(ps, up_i, up_o),
                               lone.eval(p1, up_i, up_o) + 0.6 / np.pi * t, rtol=1e-12)


# ----------------------------------------------------------------------------------------------
# Hard cases: values and gradients finite in float32 and float64, under jit and vmap
# ----------------------------------------------------------------------------------------------

HARD_ALPHA = (1e-3, 0.05, 1.0)
HARD_TAU = (1e-4, 1.0, 100.0)
HARD_AXES = ((0.0, 0.0), (90.0, 0.0), (90.0, 45.0), (37.0, 123.0))  # along, across, any
HARD_THETA = (0.0, 45.0, 89.99, 90.01, 135.0, 180.0)


def _hard_batch(kind, dtype):
    rows = []
    for alpha, tau, (tp, pp), ti, to, po in itertools.product(
            HARD_ALPHA, HARD_TAU, HARD_AXES, HARD_THETA, HARD_THETA, (0.0, 90.0, 180.0)):
        rows.append((alpha, tau, tp, pp, _dir(ti, 15.0), _dir(to, 15.0 + po)))
    rows += [(a, t, tp, pp, _dir(89.99), _dir(89.99)) for a, t, (tp, pp) in
             itertools.product(HARD_ALPHA, HARD_TAU, HARD_AXES)]  # wi == wo at grazing
    alpha, tau, tp, pp = (np.array([r[k] for r in rows], dtype) for k in range(4))
    wi = np.array([r[4] for r in rows], dtype)
    wo = np.array([r[5] for r in rows], dtype)
    return alpha, tau, tp, pp, wi, wo


@pytest.mark.parametrize("kind, dtype", [(k, d) for k in ("surface", "fiber")
                                         for d in ("float32", "float64")])
def test_hard_cases_finite_under_jit_and_vmap(kind, dtype):
    model = get_model(f"spongecake({kind})")
    alpha, tau, tp, pp, wi, wo = _hard_batch(kind, dtype)

    def f(a, t, theta_p, phi_p, i, o):
        p = {"alpha1": a, "tau1": t, "theta_p1": theta_p, "phi_p1": phi_p,
             "albedo1": jnp.asarray(0.9, a.dtype), "f0_1": jnp.asarray(0.5, a.dtype)}
        return model.eval(p, i, o)

    grad = jax.jit(jax.vmap(jax.value_and_grad(f, argnums=(0, 1, 2, 3))))
    val, grads = grad(*(jnp.asarray(x) for x in (alpha, tau, tp, pp, wi, wo)))
    val = np.asarray(val)
    assert val.dtype == np.dtype(dtype)
    assert np.all(np.isfinite(val)) and np.all(val >= 0)
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))
    # the lobe is there: some values are large at α = 1e-3 along the mirror / flake directions
    assert val.max() > 1.0


def test_delta_transmittance_and_its_declaration():
    m = get_model("spongecake(surface,fiber)")
    assert "δ(ωo + ωi)" in m.capabilities.delta
    assert get_model("spongecake(surface,delta=false)").capabilities.delta == ""
    assert get_model("spongecake(surface,substrate=lambertian)").capabilities.delta == ""
    layers = (sc.Layer("surface", 1),)
    p = {"alpha1": 0.2, "theta_p1": 0.0, "phi_p1": 0.0, "tau1": 2.0}
    # surface flakes along the normal: σ(z) = 1, so the normal transmittance is e^{-Tρ}
    np.testing.assert_allclose(sc.delta_transmittance(layers, p, jnp.asarray(_dir(0.0))),
                               np.exp(-2.0), rtol=1e-6)


@pytest.mark.parametrize("name, why", [
    ("spongecake()", "empty term"),
    ("spongecake(lambertian)", "unknown layer"),
    ("spongecake(surface,delta=maybe)", "true or false"),
    ("spongecake(surface,substrate=lambertian,delta=true)", "drop delta=true"),
    ("spongecake(surface,colour=red)", "unknown keyword"),
    ("spongecake(" + ",".join(["hg"] * 7) + ")", "at most 6"),
])
def test_bad_names_are_refused_with_the_usage(name, why):
    with pytest.raises(ValueError, match=why):
        get_model(name)


# ----------------------------------------------------------------------------------------------
# Against the simulator's single scattering (point estimates, delta dropped)
# ----------------------------------------------------------------------------------------------

THETA_O = [-80, -50, -20, 0, 20, 50, 80, 100, 130, 160, -110, -150]


_CHILD = """
import json, sys
import numpy as np
from fitlab.simulate import simulate
from fitlab.simulate.scene import scene_from_dict
job = json.load(sys.stdin)
r = simulate(scene_from_dict(job["scene"]), samples=job["samples"], seed=job["seed"])
np.savez(job["out"], theta_i=r.theta_i, phi_i=r.phi_i, theta_o=r.theta_o, phi_o=r.phi_o,
         value=r.value, sigma=r.sigma)
"""


class _Result:
    def __init__(self, z):
        for k in z.files:
            setattr(self, k, z[k])


def simulate_as_user(scene, samples, seed):
    """The simulator's result for a scene dict, run in a child process under XLA's defaults
    (conftest.user_environment), as a user runs it: the walk runs twice as fast compiled at the
    default settings as at the suite's fast-compile ones (conftest.TEST_XLA_FLAGS)."""
    import json
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        out = str(Path(d) / "r.npz")
        job = json.dumps({"scene": scene, "samples": samples, "seed": seed, "out": out})
        r = subprocess.run([sys.executable, "-c", _CHILD], input=job, text=True,
                           capture_output=True, env=user_environment(), timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        with np.load(out) as z:
            return _Result(z)


def simulator_scene(layers, theta_i, theta_o, volume_scattering="single", substrate=None):
    """A scene dict of SpongeCake layers (dicts of one layer's parameters without the index,
    plus ``kind``): index-matched media of thickness Tρ with σs = γ, σa = 1 - γ."""
    stack = []
    for L in layers:
        item = {"type": "medium", "index": 1.0, "thickness": L["tau"],
                "sigma_s": L["albedo"], "sigma_a": 1.0 - L["albedo"]}
        if L["kind"] == "hg":
            item.update(phase="hg", g=L["g"])
        else:
            item.update(phase=f"sggx_{L['kind']}", roughness=L["alpha"],
                        orientation=np.asarray(sc.axis(L["theta_p"], L["phi_p"])).tolist())
            if "f0" in L:
                item["flake_f0"] = L["f0"]
        stack.append(item)
    d = {"stack": stack, "illumination": {"theta_i": list(theta_i)},
         "detector": {"type": "inplane", "theta_o": theta_o, "estimator": "point"},
         "effects": {"volume_scattering": volume_scattering, "delta": False}}
    if substrate is not None:
        d["substrate"] = substrate
        d["detector"]["theta_o"] = [t for t in theta_o if abs(t) < 90]
    scene_from_dict(d)  # valid
    return d


def _model_at(name, layers, res, extra=None):
    m = get_model(name)
    p = {}
    for i, L in enumerate(layers, 1):
        for k, v in L.items():
            if k != "kind":
                p[f"{k}{i}" if k != "f0" else f"f0_{i}"] = v
        if L["kind"] != "hg":
            p.setdefault(f"f0_{i}", 1.0)
    p.update(extra or {})
    wi = np.stack([_dir(t, f) for t, f in zip(res.theta_i, res.phi_i)])
    wo = np.stack([_dir(t, f) for t, f in zip(res.theta_o, res.phi_o)])
    return np.asarray(m.eval({k: jnp.asarray(v) for k, v in p.items()}, wi, wo))


def _agree(res, f, z=4.5):
    v, s = res.value[:, 0], res.sigma[:, 0]
    keep = v > 1e-3 * v.max()
    dev = np.abs(f - v)[keep]
    bound = z * s[keep] + 1e-3 * v[keep]
    assert np.all(dev <= bound), np.c_[res.theta_i, res.theta_o, v, f, s][keep][dev > bound]
    return float(np.max(np.abs(f - v)[keep] / s[keep]))


SURFACE = dict(kind="surface", alpha=0.3, theta_p=15.0, phi_p=40.0, albedo=0.8, tau=1.0, f0=0.2)
FIBER = dict(kind="fiber", alpha=0.5, theta_p=90.0, phi_p=30.0, albedo=0.9, tau=2.0)
HG = dict(kind="hg", g=0.5, albedo=0.7, tau=0.5)


def test_single_surface_layer_equals_simulated_single_scattering():
    layers = [SURFACE]
    res = simulate_as_user(simulator_scene(layers, (30.0, 70.0), THETA_O), samples=60_000, seed=1)
    _agree(res, _model_at("spongecake(surface)", layers, res))


@pytest.mark.slow
@pytest.mark.parametrize("layers", [[FIBER], [HG, dict(SURFACE, alpha=0.2, albedo=1.0, tau=3.0)],
                                    [dict(FIBER, theta_p=0.0, alpha=0.1), SURFACE]],
                         ids=["fiber", "hg-surface", "fiber_along_normal-surface"])
def test_layers_equal_simulated_single_scattering(layers):
    name = f"spongecake({','.join(L['kind'] for L in layers)})"
    res = simulate_as_user(simulator_scene(layers, (0.0, 40.0, 75.0), THETA_O), samples=200_000, seed=2)
    _agree(res, _model_at(name, layers, res))


@pytest.mark.slow
def test_substrate_term_equals_the_simulated_unscattered_substrate():
    """Over a Lambertian substrate the reflection is the layers' single scattering (which never
    reaches the substrate) plus the substrate seen through the stack: the simulator with volume
    scattering off gives the second term, without the substrate the first."""
    layers = [FIBER]
    th = [t for t in THETA_O if abs(t) < 90]
    sub = simulate_as_user(simulator_scene(layers, (20.0, 60.0), th, "none",
                                   {"type": "lambertian", "albedo": 0.6}), samples=200_000,
                   seed=3)
    ss = simulate_as_user(simulator_scene(layers, (20.0, 60.0), th), samples=200_000, seed=4)
    f = _model_at("spongecake(fiber,substrate=lambertian)", layers, sub, {"albedo": 0.6})
    v = sub.value[:, 0] + ss.value[:, 0]
    s = np.hypot(sub.sigma[:, 0], ss.sigma[:, 0])
    assert np.all(np.abs(f - v) <= 4.5 * s + 1e-3 * v), np.c_[sub.theta_o, v, f, s]


# ----------------------------------------------------------------------------------------------
# Presets (the paper's Table 2): models, tables and simulator scenes
# ----------------------------------------------------------------------------------------------

SPONGECAKE_PRESETS = ("window_shade", "fabric", "plant_leaf", "varnished_wood")


@pytest.mark.parametrize("name", SPONGECAKE_PRESETS)
def test_preset_scene_files_are_the_presets(name):
    from pathlib import Path

    from fitlab.models.presets import preset_scene
    from fitlab.simulate.scene import load_scene

    path = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "scenes" / \
        f"spongecake_{name}.toml"
    a, b = load_scene(path), scene_from_dict(preset_scene(name))
    assert (a.media, a.theta_i, a.detector.theta_o, a.effects) == \
        (b.media, b.theta_i, b.detector.theta_o, b.effects)


def test_presets_evaluate_and_tabulate_through_the_cli(tmp_path, capsys):
    """In this process (the console script itself is tests/cli/test_cli.py's)."""
    from fitlab.cli import main

    d = tmp_path / "dirs.csv"
    d.write_text("theta_i,phi_i,theta_o,phi_o\n30,0,30,180\n30,0,140,180\n60,0,20,90\n")
    assert main(["eval", "--preset", "fabric", "--channel", "R", "--directions", str(d)]) == 0
    rows = [line for line in capsys.readouterr().out.strip().splitlines()
            if not line.startswith("#")]
    values = [float(line.split(",")[-1]) for line in rows[1:]]
    assert len(values) == 3 and all(v > 0 and np.isfinite(v) for v in values)
    out = tmp_path / "leaf.exr"
    assert main(["lut", "model", "--preset", "plant_leaf", "--size", "16x16", "--phi-d", "slice",
                 "--check-points", "64", "--out", str(out)]) == 0
    assert out.exists() and "3 channel(s) (R, G, B)" in capsys.readouterr().err
    # an anisotropic preset cannot go into the isotropic (θh, θd) table: exit 2, with the reason
    assert main(["lut", "model", "--preset", "fabric", "--size", "16x16", "--out",
                 str(tmp_path / "f.exr")]) == 2
    assert "anisotropic" in capsys.readouterr().err and not (tmp_path / "f.exr").exists()


@pytest.mark.slow
def test_plant_leaf_preset_equals_its_simulated_single_scattering():
    """The preset's three layers (Schlick flakes, HG, RGB albedo) through the preset scene with
    single scattering: every channel agrees with the model."""
    from fitlab.models.presets import preset_scene, rgb_preset

    d = preset_scene("plant_leaf", theta_i=(20.0, 65.0), theta_o=THETA_O)
    d["effects"]["volume_scattering"] = "single"
    res = simulate_as_user(d, samples=200_000, seed=5)
    model, _, params = rgb_preset("plant_leaf")
    m = get_model(model)
    wi = np.stack([_dir(t, f) for t, f in zip(res.theta_i, res.phi_i)])
    wo = np.stack([_dir(t, f) for t, f in zip(res.theta_o, res.phi_o)])
    for j, c in enumerate(("R", "G", "B")):
        f = np.asarray(m.eval({k: jnp.asarray(v) for k, v in params[c].items()}, wi, wo))
        v, s = res.value[:, j], res.sigma[:, j]
        keep = v > 1e-3 * v.max()
        assert np.all(np.abs(f - v)[keep] <= 4.5 * s[keep] + 2e-3 * v[keep]), c
