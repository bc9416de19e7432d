"""The extended-NDF thin layer (fitlab/models/thin_layer.py) and the vMF algebra under it
(fitlab/vmf.py): A3 and its inverse over κ from 1e-3 to 1e8 in both precisions, the
convolution's large-κ asymptotics, the exact masking integral against brute force; the model's
components, options and closed-form limits; and (slow) its orders against the simulator."""

from __future__ import annotations

from decimal import Decimal, getcontext

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab import vmf
from fitlab.fresnel import fresnel_conductor_exact, fresnel_dielectric_Walter2007
from fitlab.models import get_model

KAPPAS = np.logspace(-3, 8, 23)


def _A3_reference(k):
    getcontext().prec = 60
    x = Decimal(float(k))
    e = (-2 * x).exp()
    return float((1 + e) / (1 - e) - 1 / x)


def test_A3_matches_high_precision_over_the_whole_range():
    got = np.asarray(vmf.A3(jnp.asarray(KAPPAS)))
    ref = np.array([_A3_reference(k) for k in KAPPAS])
    np.testing.assert_allclose(got, ref, rtol=1e-13)
    got32 = np.asarray(vmf.A3(jnp.asarray(KAPPAS, jnp.float32)))
    np.testing.assert_allclose(got32, ref, rtol=1e-6)


@pytest.mark.parametrize("dtype, rtol", [("float64", 1e-11), ("float32", 2e-6)])
def test_A3_inverse_round_trip_and_gradient(dtype, rtol):
    nu = jnp.asarray(1.0 / KAPPAS, dtype)
    back = vmf.nu_of_log_A3(vmf.log_A3_of_nu(nu))
    np.testing.assert_allclose(np.asarray(back), np.asarray(nu), rtol=rtol)
    ident = jax.vmap(jax.grad(lambda n: vmf.nu_of_log_A3(vmf.log_A3_of_nu(n))))(nu)
    np.testing.assert_allclose(np.asarray(ident), 1.0, rtol=50 * rtol)


def test_convolution_of_sharp_lobes_adds_dispersions():
    """1/κ̂ = 1/κ1 + 1/κ2 for large κ (where Mitsuba 0.6's solve returned its start)."""
    for k1, k2 in [(1e5, 1e5), (1e6, 3e7), (1e8, 1e8)]:
        for dtype in ("float64", "float32"):
            nu = vmf.convolve_nu(jnp.asarray(1 / k1, dtype), jnp.asarray(1 / k2, dtype))
            assert float(nu) == pytest.approx(1 / k1 + 1 / k2, rel=1e-5)
    # a moderate case against the moment condition A3(κ̂) = A3(κ1) A3(κ2) (eq. 18)
    nu = float(vmf.convolve_nu(jnp.asarray(1 / 3.0), jnp.asarray(1 / 7.0)))
    assert _A3_reference(1 / nu) == pytest.approx(_A3_reference(3.0) * _A3_reference(7.0),
                                                  rel=1e-12)


def test_exact_masking_integral_against_brute_force():
    rng = np.random.default_rng(3)
    n = 400_000
    m = rng.normal(size=(n, 3))
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    m[:, 2] = np.abs(m[:, 2])
    for kappa in (0.5, 5.0, 50.0):
        d = np.asarray(vmf.D(jnp.asarray(m), kappa))
        for theta in (0.0, 40.0, 75.0, 88.0):
            t = np.radians(theta)
            v = np.array([np.sin(t), 0.0, np.cos(t)])
            mc = np.mean(np.maximum(m @ v, 0.0) * d) * 2.0 * np.pi
            got = float(vmf.projected_area(jnp.asarray(v), kappa))
            assert got == pytest.approx(mc, rel=0.02), (kappa, theta)
    # the quadrature's own error is stated as at most 5e-4 (fitlab/vmf.py, _GL_NODES)
    assert float(vmf.G1_exact(jnp.asarray([0.0, 0.0, 1.0]), 100.0)) == pytest.approx(1.0, abs=5e-4)


# ----------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------

MODEL = "thin_layer(rough_conductor)"
P = {"kappa1": 1000.0, "eta": 1.5, "tau": 0.2, "kappa2": 100.0, "n2": 3.18, "k2": 4.41}


def _dir(theta, phi=0.0):
    t, f = np.radians(theta), np.radians(phi)
    return np.array([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)])


def _pairs(n=400, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return jnp.asarray(v[0]), jnp.asarray(v[1])


def test_components_add_up_and_orders_follow_the_bounces_option():
    m = get_model(MODEL)
    wi, wo = _pairs()

    @jax.jit
    def parts(wi, wo):
        return {c: m.eval(P, wi, wo, bounces="3", component=c, compensation="none")
                for c in ("all", "surface", "subsurface", "1", "2", "3")}

    f = {k: np.asarray(v) for k, v in parts(wi, wo).items()}
    np.testing.assert_allclose(f["all"], f["surface"] + f["1"] + f["2"] + f["3"], rtol=1e-12)
    np.testing.assert_allclose(f["all"], f["surface"] + f["subsurface"], rtol=1e-12)
    assert f["2"].max() > 0 and f["3"].max() > 0


def test_width_parameterization_is_the_stated_mapping():
    a = get_model("thin_layer(rough_conductor,roughness=alpha)")
    assert [p.name for p in a.parameters][:4] == ["alpha1", "eta", "tau", "alpha2"]
    wi, wo = _pairs()
    pa = {**{k: v for k, v in P.items() if not k.startswith("kappa")},
          "alpha1": np.sqrt(2.0 / P["kappa1"]), "alpha2": np.sqrt(2.0 / P["kappa2"])}
    both = jax.jit(lambda wi, wo: (a.eval(pa, wi, wo), get_model(MODEL).eval(P, wi, wo)))
    fa, fk = both(wi, wo)
    np.testing.assert_allclose(np.asarray(fa), np.asarray(fk), rtol=1e-10)


def _albedo(model, params, wi, n=200_000, **opts):
    """∫ f cos θo dωo as the mean sample weight (the contract tests that ``sample``'s weight is
    f cos θo / pdf with the pdf ``pdf`` returns)."""
    u = jnp.asarray(np.random.default_rng(5).random((n, 3)))
    w = jnp.broadcast_to(jnp.asarray(wi), (n, 3))
    _, weight, _ = jax.jit(lambda a, b: model.sample(params, a, b, **opts))(w, u)
    return float(jnp.mean(weight))


@pytest.mark.parametrize("component", [pytest.param("surface", marks=pytest.mark.slow), "1",
                                       pytest.param("2", marks=pytest.mark.slow)])
def test_narrow_lobes_carry_the_closed_form_energies(component):
    """With sharp boundaries the orders' albedos at normal incidence are the smooth layer's
    closed forms: F(0) for the surface, T² R_b e^{-2τ} for order 1, T² R_b² R_top e^{-4τ} for
    order 2 (T = 1 - F the top's transmittance, R_top = F its internal reflectance)."""
    m = get_model(MODEL)
    p = {**P, "kappa1": 3e4, "kappa2": 3e4}
    F = float(fresnel_dielectric_Walter2007(1.0, 1.5))
    Rb = float(fresnel_conductor_exact(1.0, 3.18 / 1.5, 4.41 / 1.5))
    a = np.exp(-2 * P["tau"])
    expected = {"surface": F, "1": (1 - F) ** 2 * Rb * a,
                "2": (1 - F) ** 2 * Rb**2 * F * a**2}[component]
    got = _albedo(m, p, np.array([0.0, 0.0, 1.0]), component=component)
    assert got == pytest.approx(expected, rel=0.01 if component != "2" else 0.02)


def test_index_matched_top_does_not_blur_the_subsurface_lobe():
    """η = 1: refraction through the top does not deviate light (eq. 13's Jacobian diverges,
    ν → 0), so order 1's ENDF is the bottom's alone whatever κ1 is."""
    from fitlab.models import thin_layer

    c = jnp.asarray(np.cos(np.radians([0.0, 30.0, 60.0, 85.0])))
    inc = thin_layer._Incidence(c, 1.0)
    nus = [np.asarray(thin_layer._lobe_nu(inc, 1.0, k1, 100.0, 1)) for k1 in (10.0, 1e6)]
    np.testing.assert_allclose(nus[0], nus[1], rtol=1e-12)
    # and it is the bottom's reflection lobe: κ_m = 4 cos θ · κ2/(4 cos θ) = κ2 (eqs 12, 19)
    np.testing.assert_allclose(1.0 / nus[0], 100.0, rtol=1e-9)


def test_absorption_follows_eq_27_on_the_specular_path():
    m = get_model(MODEL)
    wi = jnp.asarray(_dir(40.0))
    wo = jnp.asarray(_dir(40.0, 180.0))
    f = jax.jit(lambda tau: m.eval({**P, "tau": tau}, wi, wo, component="1"))
    f0, f1 = float(f(0.0)), float(f(0.7))
    ct = np.sqrt(1 - np.sin(np.radians(40.0)) ** 2 / 1.5**2)
    assert f1 / f0 == pytest.approx(np.exp(-0.7 * 2 / ct), rel=1e-10)


@pytest.mark.parametrize("name, message", [
    ("thin_layer(lambertian)", "bottom boundary must be an isotropic rough conductor"),
    ("thin_layer(rough_conductor_anisotropic)", "bottom boundary must be an isotropic"),
    ("thin_layer(rough_conductor,roughness=beta)", "roughness=beta"),
    ("thin_layer(rough_conductor,layers=2)", "unknown keyword"),
])
def test_refused_stacks_say_why(name, message):
    with pytest.raises(ValueError, match=message):
        get_model(name)


def test_cli_lists_and_evaluates_it(capsys):
    from fitlab.cli import main

    assert main(["models"]) == 0
    assert "thin_layer(rough_conductor)" in capsys.readouterr().out
    argv = ["eval", MODEL, "--directions", "data_formats/examples/directions_inplane.csv"]
    for k, v in P.items():
        argv += ["--param", f"{k}={v}"]
    assert main(argv + ["--option", "bounces=2"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r and not r.startswith("#")]
    values = np.array([float(r.split(",")[-1]) for r in rows[1:]])
    assert len(values) > 5 and np.all(np.isfinite(values)) and values.max() > 0


# ----------------------------------------------------------------------------------------------
# Against the simulator, order by order (its vMF interfaces and conductor are independent code)
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("k1, k2, tol1", [(1e4, 1e3, 0.10), (100.0, 1000.0, 0.10)])
def test_orders_agree_with_the_simulator(k1, k2, tol1):
    from fitlab.simulate import scene_from_dict, simulate

    arc = np.arange(-80.0, 80.01, 2.5)
    acceptance = 0.01
    r = simulate(scene_from_dict({
        "name": "thin layer",
        "stack": [{"type": "interface", "distribution": "vmf", "kappa": k1},
                  {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.0}],
        "substrate": {"type": "conductor", "n": 3.18, "k": 4.41, "distribution": "vmf",
                      "kappa": k2},
        "illumination": {"theta_i": [30.0]},
        "detector": {"type": "inplane", "theta_o": [float(t) for t in arc],
                     "acceptance_sr": acceptance},
        "effects": {"max_bounces": "all", "delta": False, "color": "mono"},
    }), 200_000, seed=1)
    m = get_model(MODEL)
    p = {"kappa1": k1, "eta": 1.5, "tau": 0.0, "kappa2": k2, "n2": 3.18, "k2": 4.41}
    # the model averaged over each detector cone with cos θo weights, as the simulator tallies
    # (fitlab.aperture's cone rule, the one the aperture-averaged fits use)
    from fitlab.aperture import cone_rule

    t = np.radians(np.abs(arc))
    f = np.where(arc < 0, 0.0, np.pi)
    axis = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1)
    gamma = np.degrees(np.arccos(1.0 - acceptance / (2 * np.pi)))
    pts, w = cone_rule(axis, np.full(len(arc), gamma), 6)
    wi = jnp.asarray(np.broadcast_to(_dir(30.0), pts.shape))
    for order, comp, tol in ((0, "surface", 0.10), (1, "1", tol1)):
        sim, sig = r.by_order[order][:, 0], r.sigma_by_order[order][:, 0]
        mod = np.asarray(m.eval(p, wi, jnp.asarray(pts), component=comp))
        mod = (mod * w).sum(-1) / w.sum(-1)
        sel = sim > 0.05 * sim.max()
        rms = np.sqrt(np.mean(((mod - sim) / sim)[sel] ** 2))
        noise = np.sqrt(np.mean((sig / sim)[sel] ** 2))
        assert rms < tol + 2 * noise, (comp, rms, noise)
        assert mod.max() == pytest.approx(sim.max(), rel=0.1), comp


@pytest.mark.slow
def test_paper_figures_benchmark_writes_its_tables(tmp_path):
    """benchmarks/thin_layer_figures.py end to end at a small sample count: the three tables,
    and numbers that follow from the paper's statements (eq. 8 close for sharp lobes away from
    the horizon; joint warping exact in moments for aligned lobes)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "thin_layer_figures.py"
    spec = importlib.util.spec_from_file_location("thin_layer_figures", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--samples", "50000", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "README.md").read_text()
    for title in ("Fig. 2", "Fig. 5", "Figs 6-8"):
        assert title in text
    res = json.loads((tmp_path / "results.json").read_text())
    k1000 = next(r for r in res["fig2"] if r["kappa"] == 1000)
    assert abs(k1000["eq8"][1] - k1000["exact"][1]) < 1e-3  # 30°
    aligned = [r for r in res["figs678"] if r["mu_o_dot_mu_m"] == 1.0]
    for r in aligned:
        assert r["kappa_hat_eq"] == pytest.approx(r["kappa_moment_mc"], rel=0.03)
    assert all(r["tv_distance"] < 0.01 for r in res["fig5"] if r["theta_o_deg"] == 0)


@pytest.mark.slow
def test_validation_benchmark_writes_its_report(tmp_path):
    """benchmarks/thin_layer_validation.py end to end on its base stack at a small path count:
    the tables, the error map and results whose figures follow from the model's accuracy where
    it is best (the surface term, and order 1 at this stack within its measured 0.3)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "thin_layer_validation.py"
    spec = importlib.util.spec_from_file_location("thin_layer_validation", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--quick", "--samples", "40000", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "README.md").read_text()
    assert "error_map.png" in text and "WW subsurface" in text
    assert (tmp_path / "error_map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (row,) = json.loads((tmp_path / "results.json").read_text())["rows"]
    c = row["components"]
    assert c["order 0"]["rms_rel_error"] < 0.15 + 2 * c["order 0"]["rms_rel_noise"]
    assert c["order 1"]["rms_rel_error"] < 0.35 + 2 * c["order 1"]["rms_rel_noise"]
    assert row["albedo_thin_layer"] == pytest.approx(row["albedo_sim"], rel=0.1)
