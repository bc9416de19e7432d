"""SpongeCake's multiple-scattering lobe (§5): the model's multiple=lobe|only forms, the lobe fit
of fitlab.learn.lobe and `fitlab multiple-lobe`."""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import user_environment

import fitlab  # noqa: F401  (x64)
from fitlab.cli import main
from fitlab.io.directions import degrees_to_direction
from fitlab.models import get_model
from fitlab.learn.lobe import (fit_lobe, held_parameters, lobe_model_name, lobe_parameters,
                                    stack_call)

STACK = {"alpha1": 0.3, "albedo1": 0.9, "f0_1": 1.0, "tau1": 2.0}
LOBE = {"alpha1_ms": 0.6, "albedo1_ms": 1.0, "f0_1_ms": 0.4, "tau1_ms": 1.5,
        "W1": 0.7, "W2": 0.06, "W2T": 0.03}


def _pairs(n=400, seed=0):
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 88, n), rng.uniform(0, 179, n)
    to = np.where(np.abs(to - 90) < 1, 91.0, to)
    pi_, po = rng.uniform(-180, 180, n), rng.uniform(-180, 180, n)
    return (jnp.asarray(degrees_to_direction(ti, pi_)), jnp.asarray(degrees_to_direction(to, po)))


def _j(d):
    return {k: jnp.asarray(v) for k, v in d.items()}


def test_lobe_is_single_scattering_plus_modified_lobe_plus_lambertian():
    """f(multiple=lobe) = f_ss(p) + W1 f_ss(p') + W2/π (same side) + W2T/π (other side), and
    f(multiple=only) is the same without f_ss(p): the §5 sum, term by term (a lobe within the
    energy that arrives, which the energy budget leaves as it is)."""
    wi, wo = _pairs()
    single = get_model("spongecake(surface_z)")
    lobe = get_model("spongecake(surface_z,multiple=lobe)")
    only = get_model("spongecake(surface_z,multiple=only)")
    p_ms = {k.removesuffix("_ms"): v for k, v in LOBE.items() if k.endswith("_ms")}
    same = np.asarray(wi[:, 2] * wo[:, 2] > 0)
    lam = np.where(same, LOBE["W2"], LOBE["W2T"]) / np.pi
    f_ss = np.asarray(single.eval(_j(STACK), wi, wo))
    f_ms = np.asarray(single.eval(_j(p_ms), wi, wo))
    expect_only = LOBE["W1"] * f_ms + lam
    np.testing.assert_allclose(np.asarray(only.eval(_j(LOBE), wi, wo)), expect_only, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(lobe.eval(_j({**STACK, **LOBE}), wi, wo)),
                               f_ss + expect_only, rtol=1e-12)
    assert lobe.capabilities.delta and not only.capabilities.delta
    assert lobe.capabilities.energy_conserving and only.capabilities.energy_conserving


def test_a_substrate_keeps_the_lobes_above_the_stack():
    """Over an opaque substrate the lobes scatter light from above to above only, and there is
    no W2T."""
    m = get_model("spongecake(surface_z,substrate=lambertian,multiple=only)")
    assert "W2T" not in m.parameter_names and not m.capabilities.transmission
    wi, wo = _pairs()
    f = np.asarray(m.eval(_j({k: v for k, v in LOBE.items() if k != "W2T"}), wi, wo))
    above = np.asarray((wi[:, 2] > 0) & (wo[:, 2] > 0))
    assert np.all(f[~above] == 0) and np.all(f[above] > 0)


@pytest.mark.parametrize("name, fragment", [
    ("spongecake(surface,multiple=two)", "multiple must be none"),
    ("spongecake(surface,multiple=only,delta=true)", "drop delta=true"),
    ("spongecake(surface,multi=lobe)", "unknown keyword"),
])
def test_bad_multiple_names(name, fragment):
    with pytest.raises(ValueError, match=fragment):
        get_model(name)


def test_every_sample_has_positive_pdf_where_f_is_positive():
    """The mixture samples the Lambertian lobes too: pdf > 0 wherever f > 0, also where the
    single-scattering lobes are sharp (α 1e-3)."""
    m = get_model("spongecake(surface_z,multiple=lobe)")
    p = _j({**STACK, "alpha1": 1e-3, **LOBE, "alpha1_ms": 1e-3})
    wi, wo = _pairs(2000, seed=3)
    f = np.asarray(m.eval(p, wi, wo))
    pdf = np.asarray(m.pdf(p, wi, wo))
    assert np.all(f > 0) and np.all(pdf[f > 0] > 0)


def test_lobe_fit_recovers_a_known_lobe():
    """A multiple-scattering part made by the multiple=only model itself (known parameters, 3%
    noise): the lobe fit returns them within its uncertainties (χ² at the noise)."""
    from fitlab.io.measurement import Measurement

    only = get_model("spongecake(surface_z,multiple=only)")
    ti = np.repeat([0.0, 30.0, 60.0, 75.0], 72)
    to = np.tile(np.repeat(np.linspace(7.5, 172.5, 12), 6), 4)
    po = np.tile(np.linspace(-150, 150, 6), 48)
    to = np.where(np.abs(to - 90) < 1, 91.0, to)
    wi, wo = degrees_to_direction(ti, 0 * ti), degrees_to_direction(to, po)
    f = np.asarray(only.eval(_j(LOBE), jnp.asarray(wi), jnp.asarray(wo)))
    sigma = 0.03 * f
    value = f + sigma * np.random.default_rng(5).standard_normal(f.shape)
    m = Measurement(path="<synthetic>", sha256="", theta_i=ti, phi_i=0 * ti, theta_o=to, phi_o=po,
                    wi=wi, wo=wo, value=value, sigma=sigma, channel=np.zeros(len(ti), int),
                    channel_names=("Y",), wavelength_nm=None, quantity="bsdf",
                    file_quantity="bsdf", metadata={}, lines=np.zeros(len(ti), int))
    fit, _ = fit_lobe("spongecake(surface_z)", {"Y": STACK}, measurement=m, seed=1)
    got, err = fit.parameters["Y"], fit.stderr["Y"]
    assert fit.fixed["Y"]["albedo1_ms"] == 1.0
    for k in ("alpha1_ms", "tau1_ms", "f0_1_ms", "W1", "W2", "W2T"):
        assert abs(got[k] - LOBE[k]) <= 4 * err[k] + 1e-6, (k, got[k], LOBE[k], err[k])
    assert 0.7 < fit.statistics("Y")["chi2_per_dof"] < 1.4
    merged = lobe_parameters(fit, {"Y": STACK})["Y"]
    assert set(merged) == set(get_model(lobe_model_name("spongecake(surface_z)",
                                                        "lobe")).parameter_names)


def test_what_the_lobe_fit_holds_and_refuses():
    assert held_parameters("spongecake(fiber,surface_z)",
                           {"Y": {"theta_p1": 90.0, "phi_p1": 10.0, "alpha1": 0.2}}) == \
        {"theta_p1": 90.0, "phi_p1": 10.0, "albedo1_ms": 1.0}
    assert stack_call("spongecake(fiber,hg)") == ("fiber", "hg")
    for bad, fragment in (("spongecake(surface,substrate=lambertian)", "no substrate"),
                          ("spongecake(surface,multiple=lobe)", "without multiple"),
                          ("lambertian", "not a SpongeCake model")):
        with pytest.raises(ValueError, match=fragment):
            stack_call(bad)


@pytest.mark.parametrize("argv, fragment", [
    (["lambertian"], "not a SpongeCake model"),
    (["spongecake(surface_z,substrate=lambertian)"], "no substrate"),
    (["spongecake(surface_z)", "--param", "beta1=2"], "no parameter"),
    (["spongecake(surface_z)", "--param", "tau1=1000"], "tau1"),
    (["spongecake(surface_z)", "--grid", "6by12"], "THETAxPHI"),
    (["spongecake(surface_z)", "--theta-i", "0,95"], "[0, 90)"),
    ([], "give a SpongeCake model"),
])
def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, argv, fragment):
    out = tmp_path / "lobe.json"
    assert main(["multiple-lobe", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err and not out.exists()


@pytest.mark.slow
def test_cli_fits_the_simulated_multiple_scattering_of_a_thick_bright_layer(tmp_path):
    """`fitlab multiple-lobe` end to end on a layer where multiple scattering is large (γ 0.95,
    Tρ 3): the lobe describes the simulated multiple-scattering part to a few per cent, and
    single scattering + lobe has the simulator's albedo where single scattering alone misses
    a large part of it."""
    out, data = tmp_path / "lobe.json", tmp_path / "ms.csv"
    r = subprocess.run([sys.executable, "-m", "fitlab.cli", "multiple-lobe", "spongecake(surface_z)",
                        "--param", "alpha1=0.3", "--param", "albedo1=0.95", "--param", "tau1=3",
                        "--samples", "20000", "--theta-i", "0,40,70", "--grid", "5x8",
                        "--out", str(out), "--data-out", str(data)],
                       capture_output=True, text=True, env=user_environment(), timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "multiple scattering" in r.stderr and out.exists() and data.exists()
    fit = fitlab.load_fit(out)
    assert fit.model == "spongecake(surface_z,multiple=only)"
    st = fit.statistics("Y")
    assert st["fit_error"]["rms_relative_error"] < 0.1, st
    stack = {"alpha1": 0.3, "albedo1": 0.95, "f0_1": 1.0, "tau1": 3.0}
    params = lobe_parameters(fit, {"Y": stack})["Y"]
    # albedo at θi = 40°: single scattering, single + lobe, and the simulation's (the measured
    # CSV's values integrated over its cells would be coarse: use the model's own samples)
    wi = jnp.tile(jnp.asarray(degrees_to_direction(np.array([40.0]), np.array([0.0]))), (200_000, 1))
    u = jax.random.uniform(jax.random.PRNGKey(2), (200_000, 3), jnp.float64)
    a_ss = float(jnp.mean(get_model("spongecake(surface_z)").sample(_j(stack), wi, u)[1]))
    a_lobe = float(jnp.mean(get_model("spongecake(surface_z,multiple=lobe)").sample(
        _j(params), wi, u)[1]))
    from fitlab.models.spongecake import Layer, delta_transmittance
    delta = float(delta_transmittance((Layer("surface_z", 1),), stack, wi[0]))
    ms = fitlab.read(data)
    assert json.loads(json.dumps(ms.metadata)).get("component", "").startswith("multiple")
    # the simulator's albedo of this stack (every order, no delta): 1 − absorbed; measured by
    # the furnace benchmark's method at a small scale
    from fitlab.simulate import scene_from_dict, simulate
    from fitlab.learn.lobe import stack_scene
    d = stack_scene(("surface_z",), {"Y": stack}, theta_i=(40.0,), theta_bins=3, phi_bins=4)
    d["detector"].pop("estimator")
    res = simulate(scene_from_dict(d), 100_000, seed=3)
    a_sim = float(res.energy[0, :, 0].sum())
    s_sim = float(np.sqrt((res.energy_sigma[0, :, 0] ** 2).sum()))
    assert a_sim - (a_ss + delta) > 0.1  # single scattering misses a large part
    # the lobe's own approximation: its albedo was 3.5 % above the simulator's with the JAX
    # walk's data and 4.3 % with the Dr.Jit walk's (the two walks' data for this fit agree
    # statistically: 240 rows, z rms 1.00); issue 36 takes up the lobe's energy
    assert abs(a_lobe + delta - a_sim) < 0.05 + 4 * s_sim, (a_lobe + delta, a_sim)
