"""fitlab simulate: scene validation, effect derivation, determinism, float32 paths, CLI (and
`fitlab fit` on its output). The statistical validation is in test_simulate_validation.py."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

import fitlab  # noqa: F401  (x64)
from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.io.files import path_for_record
from fitlab.io.measurement import read_measurement
from fitlab.simulate import derive_effects, load_scene, scene_from_dict, simulate
from fitlab.simulate.simulator import _walk_setup

SCENES = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "scenes"

INVALID = {
    "scene_theta_i_out_of_range.toml": "illumination.theta_i: 95 is out of range",
    "scene_two_interfaces.toml": "stack[1]: two interfaces in a row",
    "scene_index_jump_without_interface.toml": "stack[0].index: 1.5 differs from the index above",
    "scene_negative_thickness.toml": "stack[1].thickness: -1 is out of range",
    "scene_coefficient_past_float32.toml": "stack[1].sigma_a: 1e+35 is out of range: it must "
                                           "be >= 0 and <= 1e+30",
    "scene_unknown_key.toml": "stack[0].alhpa: unknown key. did you mean 'alpha'?",
    "scene_bad_hg_g.toml": "stack[0].g: 1.2 is out of range: it must be > -1 and < 1",
    "scene_two_channels.toml": "stack[0].sigma_a: has 2 values",
    "scene_opaque_transmission_only.toml": "detector.sides: only transmission is observed but "
                                           "the substrate is opaque",
    "scene_no_acceptance.toml": "detector.acceptance_sr: is missing",
    "scene_no_detector.toml": "detector: is missing",
    "scene_anisotropic_vmf.toml": "stack[0].alpha_x: the vmf distribution is isotropic",
    "scene_point_with_acceptance.toml": "detector.acceptance_sr: a point estimate has no "
                                        "acceptance solid angle",
    "scene_point_specular_between.toml": "detector.estimator: point estimates of reflection are "
                                         "not possible for this stack: boundary 1 is specular",
    "scene_masking_not_vmf.toml": "stack[0].masking: only a vmf distribution has a masking "
                                  "choice",
    "scene_flake_f0_not_sggx.toml": "stack[0].flake_f0: only SGGX phases have flake_f0",
    "scene_split_with_points.toml": "effects.split_first_interface: point estimates already "
                                    "take the first crossing's reflection exactly",
    "scene_toml_syntax.toml": "is not valid TOML (Expected ']]' at the end of an array "
                              "declaration (at line 2, column 8))",
}


def test_every_invalid_example_is_listed():
    assert sorted(p.name for p in (SCENES / "invalid").glob("*.toml")) == sorted(INVALID)


@pytest.mark.parametrize("name", sorted(INVALID))
def test_invalid_scene_examples_fail_with_the_documented_message(name):
    path = SCENES / "invalid" / name
    before = path.read_bytes()
    with pytest.raises(InputFileError) as exc:
        load_scene(path)
    assert str(path) in str(exc.value) and INVALID[name] in str(exc.value)
    assert path.read_bytes() == before
    doc = (SCENES.parent.parent / "scene_toml.md").read_text()
    assert name in doc


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.toml")), ids=lambda p: p.name)
def test_valid_scene_examples_load(path):
    scene = load_scene(path)
    assert scene.boundaries and scene.detector.sides
    assert path.name in (SCENES.parent.parent / "scene_toml.md").read_text()


def _base(**over):
    d = {"stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.3}],
         "below": {"index": 1.5}, "illumination": {"theta_i": [30.0]},
         "detector": {"type": "hemisphere", "theta_bins": 3, "phi_bins": 4}}
    d.update(over)
    return d


@pytest.mark.parametrize("patch, fragment", [
    (lambda d: d["stack"][0].update(kappa=10.0), "stack[0].kappa: only a vmf distribution"),
    (lambda d: d["stack"][0].update(alpha=0.0), "stack[0].alpha: 0 is out of range"),
    (lambda d: d["stack"][0].update(distribution="cosine"), "stack[0].distribution: 'cosine' is not"),
    (lambda d: d["stack"][0].update(alpha_x=0.1, alpha_y=0.3),
     "stack[0].alpha: give either alpha or alpha_x and alpha_y"),
    (lambda d: d["stack"][0].update(alpha=None) or d["stack"][0].pop("alpha") and None
     or d["stack"][0].update(alpha_x=0.1), "stack[0].alpha_y: is missing"),
    (lambda d: d["stack"].__setitem__(0, {"type": "interface", "distribution": "vmf",
                                          "alpha_x": 0.1, "alpha_y": 0.3}),
     "stack[0].alpha_x: the vmf distribution is isotropic"),
    (lambda d: d.update(effects={"max_bounces": -1}), "effects.max_bounces: -1 is not"),
    (lambda d: d.update(effects={"color": "mono"}, below={"index": 1.0}, stack=[
        {"type": "interface"}, {"type": "medium", "index": 1.5, "thickness": 1.0,
                                "sigma_a": [0.1, 0.2, 0.3]}, {"type": "interface"}]),
     "effects.color: is \"mono\" but some properties have three"),
    (lambda d: d.update(substrate={"type": "conductor", "preset": "copper", "n": 1.0}),
     "below: a scene with a [substrate] has no [below] medium"),
    (lambda d: d.update(below={"index": 1.0}), "stack[0]: both sides have index 1"),
    (lambda d: d["illumination"].update(phi_i=[0.0, 10.0]), "illumination.phi_i: has 2 values"),
    (lambda d: d["detector"].update(sides=["up"]), "detector.sides: ['up'] is not a list"),
    (lambda d: d.update(detector={"type": "inplane", "theta_o": [90.0], "acceptance_sr": 0.01}),
     "detector.theta_o: ±90° lies in the surface plane"),
    (lambda d: d.update(version=2), "version: 2 is not a version"),
])
def test_scene_from_dict_errors(patch, fragment):
    d = copy.deepcopy(_base())
    patch(d)
    with pytest.raises(InputFileError) as exc:
        scene_from_dict(d, source="mine.toml")
    assert str(exc.value).startswith("mine.toml: ") and fragment in str(exc.value)


def test_anisotropic_widths_reach_the_boundary():
    d = _base()
    d["stack"][0] = {"type": "interface", "distribution": "beckmann", "alpha_x": 0.1,
                     "alpha_y": 0.3}
    b = scene_from_dict(d).boundaries[0]
    assert (b.distribution, b.alpha, b.alpha_y) == ("beckmann", 0.1, 0.3)
    assert _base_boundary().alpha_y is None


def _base_boundary():
    return scene_from_dict(_base()).boundaries[0]


def test_vmf_kappa_maps_to_alpha():
    d = _base()
    d["stack"][0] = {"type": "interface", "distribution": "vmf", "kappa": 200.0}
    assert scene_from_dict(d).boundaries[0].alpha == pytest.approx(0.1)
    # down to the thin layer's bound (κ < 2 is wider than α = 1), and no further
    d["stack"][0]["kappa"] = 1.0
    assert scene_from_dict(d).boundaries[0].alpha == pytest.approx(np.sqrt(2.0))
    for bad in (5e-3, 2e7):
        d["stack"][0]["kappa"] = bad
        with pytest.raises(InputFileError, match=r"stack\[0\]\.kappa: .* out of range"):
            scene_from_dict(d)


# --------------------------------------------------------------------------------------------
# Effect derivation
# --------------------------------------------------------------------------------------------


def _skipped(plan):
    return dict(plan.skipped)


def test_no_medium_means_no_volume_or_attenuation_code():
    plan = derive_effects(scene_from_dict(_base()))
    assert not plan.volume and not plan.absorption
    assert "no medium" in _skipped(plan)["volume scattering"]
    cfg, _ = _walk_setup(scene_from_dict(_base()), plan, None, 64)
    assert not cfg.volume and not cfg.absorption and not cfg.extinction_only


def _slab(**medium):
    return _base(stack=[{"type": "interface"},
                        {"type": "medium", "index": 1.5, "thickness": 1.0, **medium},
                        {"type": "interface"}], below={"index": 1.0})


def test_zero_sigma_a_means_no_attenuation():
    plan = derive_effects(scene_from_dict(_slab(sigma_a=0.0, sigma_s=1.0)))
    assert not plan.absorption and plan.volume
    assert "every sigma_a is 0" in _skipped(plan)["absorption"]
    plan = derive_effects(scene_from_dict(_slab(sigma_a=0.5)))
    assert plan.absorption and not plan.volume
    assert "every sigma_s is 0" in _skipped(plan)["volume scattering"]


def test_grey_properties_mean_one_channel():
    plan = derive_effects(scene_from_dict({**_slab(sigma_a=0.5), "effects": {"color": "rgb"}}))
    assert plan.channels == 1 and "every property is grey" in _skipped(plan)["color"]
    plan = derive_effects(scene_from_dict(_slab(sigma_a=[0.1, 0.2, 0.3])))
    assert plan.channels == 3 and not plan.walk_per_channel
    plan = derive_effects(scene_from_dict(_slab(sigma_s=[1.0, 2.0, 3.0])))
    assert plan.channels == 3 and plan.walk_per_channel


def test_opaque_substrate_without_transmission_detector_traces_no_transmitted_paths():
    d = _base(stack=[{"type": "interface"}, {"type": "medium", "index": 1.5, "thickness": 0.0}],
              substrate={"type": "lambertian", "albedo": 0.5})
    d.pop("below")
    plan = derive_effects(scene_from_dict(d))
    assert plan.reflection and not plan.transmission
    assert "opaque" in _skipped(plan)["transmission"]
    d2 = copy.deepcopy(_slab(sigma_a=0.1))
    d2["detector"]["sides"] = ["reflection"]
    d2["effects"] = {"max_bounces": 1}
    plan = derive_effects(scene_from_dict(d2))
    assert not plan.transmission and plan.end_downward_after_last_bounce
    assert "no transmission detector" in _skipped(plan)["transmission"]


def test_volume_scattering_requests():
    assert derive_effects(scene_from_dict({**_slab(sigma_s=1.0), "effects": {
        "volume_scattering": "single"}})).volume_limit == 1
    plan = derive_effects(scene_from_dict({**_slab(sigma_s=1.0), "effects": {
        "volume_scattering": "none"}}))
    assert not plan.volume and plan.extinction_only


def test_dropped_absorption_and_extinction_only_change_what_they_should():
    """absorption = false equals the non-absorbing scene exactly (same seed); volume
    scattering "none" keeps only the unscattered flux: T = (delta transmission) only."""
    a = simulate(scene_from_dict({**_slab(sigma_a=0.7), "effects": {"absorption": False}}),
                 4096, seed=3)
    b = simulate(scene_from_dict(_slab(sigma_a=0.0)), 4096, seed=3)
    np.testing.assert_array_equal(a.value, b.value)
    c = simulate(scene_from_dict({**_slab(sigma_s=0.4), "effects": {
        "volume_scattering": "none"}}), 4096, seed=3)
    d = simulate(scene_from_dict(_slab(sigma_a=0.4)), 4096, seed=3)
    np.testing.assert_allclose(c.value, d.value, rtol=1e-6)


# --------------------------------------------------------------------------------------------
# Determinism, float32, results
# --------------------------------------------------------------------------------------------


def test_same_seed_same_numbers_other_seed_other_numbers():
    scene = scene_from_dict(_base())
    a = simulate(scene, 3000, seed=4, batch_size=1024)
    b = simulate(scene, 3000, seed=4, batch_size=1024)
    c = simulate(scene, 3000, seed=5, batch_size=1024)
    np.testing.assert_array_equal(a.value, b.value)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    assert not np.array_equal(a.value, c.value)
    np.testing.assert_allclose(a.by_order.sum(0), a.value, rtol=1e-12, atol=1e-15)


#: Examples whose float32 walk compiles kernels no other quick test needs: whole suite only.
SLOW_FLOAT32_SCENES = {"sggx_fiber_layer.toml", "measurement_directions.toml",
                       "measurement_points.toml"}


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow)
                                  if p.name in SLOW_FLOAT32_SCENES else p
                                  for p in sorted(SCENES.glob("*.toml"))], ids=lambda p: p.name)
def test_float32_walk_is_finite_on_every_example(path):
    r = simulate(load_scene(path), 2048, seed=0, batch_size=2048)
    assert np.all(np.isfinite(r.value)) and np.all(np.isfinite(r.sigma))
    assert np.all(r.value >= 0) and np.all(r.sigma >= 0) and r.truncated == 0
    assert np.all(r.energy.sum(1) <= 1.0 + 5 * r.energy_sigma.sum(1) + 1e-6)
    assert r.value.shape[1] == len(r.channel_names) and r.time_s > 0


@pytest.mark.parametrize("alpha", [1e-4, 1.0])
def test_hard_cases_finite(alpha):
    """Roughness at both ends, grazing incidence (89.99°), normal incidence, index ratio below
    1 (denser outside) and near 1, a very thick absorbing layer; Mitsuba's and fitlab's own
    interfaces (the paths are float32: Mitsuba's llvm_ad_rgb variant)."""
    cases = [(0.7, 0.0, "ggx"), (1.0001, 50.0, "beckmann"), (1.5, 0.0, "vmf"),
             (0.7, 0.0, "phong")]
    for eta, sa, dist in cases:
        d = _base(stack=[{"type": "interface", "distribution": dist, "alpha": alpha},
                         {"type": "medium", "index": eta, "thickness": 10.0, "sigma_a": sa},
                         {"type": "interface", "distribution": "ggx", "alpha": alpha}],
                  below={"index": 1.0}, illumination={"theta_i": [0.0, 89.99]})
        r = simulate(scene_from_dict(d), 1024, seed=1)
        assert np.all(np.isfinite(r.value)) and np.all(np.isfinite(r.sigma)), (eta, dist)
        # at 89.99° the Walter weights (eq. 41) spread widely: bound by the MC error
        assert np.all(r.energy.sum(1) <= 1.0 + 5 * r.energy_sigma.sum(1) + 1e-6)


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def test_cli_simulate_writes_measurement_csv_that_fitlab_fit_reads(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    scene = SCENES / "rough_dielectric_interface.toml"
    assert main(["simulate", str(scene), "--samples", "20000", "--seed", "3", "--out", str(out),
                 "--split-bounces"]) == 0
    err = capsys.readouterr().err
    assert "simulate: skipped: " in err and "paths/s" in err and "wrote" in err
    m = read_measurement(out)
    assert m.quantity == "bsdf" and m.sigma is not None and m.n > 100
    assert m.eta() == pytest.approx(1.5)
    for key in ("effects_simulated", "effects_skipped", "samples", "seed"):
        assert key in m.metadata
    assert "time_s" not in m.metadata  # printed, not stored: same seed, same bytes
    assert m.metadata["scene"] == path_for_record(scene, out)
    assert m.metadata["samples"] == "20000" and "volume scattering" in m.metadata["effects_skipped"]
    orders = read_measurement(tmp_path / "sim.orders.csv")
    assert set(orders.channel_names) <= {"order0", "order1", "order2", "rest"}
    assert sorted(q.name for q in tmp_path.iterdir()) == ["sim.csv", "sim.orders.csv"]
    # fitlab fit on the simulated file recovers the interface's roughness
    fit_out = tmp_path / "fit.json"
    assert main(["fit", str(out), "--model", "rough_dielectric", "--starts", "2", "--quiet",
                 "--fit-subset", "value > 0.05", "--bootstrap", "0", "--out", str(fit_out)]) == 0
    rec = json.loads(fit_out.read_text())
    alpha = rec["fits"][0]["parameters"]["alpha"]["value"]
    assert alpha == pytest.approx(0.3, rel=0.1)


def test_cli_simulate_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    bad = SCENES / "invalid" / "scene_two_interfaces.toml"
    assert main(["simulate", str(bad), "--samples", "100", "--out", str(out)]) == 2
    assert "two interfaces in a row" in capsys.readouterr().err
    assert main(["simulate", str(SCENES / "hg_medium.toml"), "--samples", "1"]) == 2
    assert "--samples must be at least 2" in capsys.readouterr().err
    assert main(["simulate", str(SCENES / "hg_medium.toml"), "--samples", "10",
                 "--split-bounces"]) == 2
    assert list(tmp_path.iterdir()) == []


def test_cli_simulate_help_explains_itself(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = capsys.readouterr().out
    for word in ("--samples", "--seed", "--split-bounces", "scene_toml.md", "standard error"):
        assert word in text


def test_walk_random_numbers_are_uniform_and_independent():
    """The walk's PCG32 streams (one per path, seeded by walk.seed_words and the path id):
    KS test per draw, no correlation between successive draws, neighbouring paths or seeds,
    float32 in [0, 1)."""
    from scipy import stats

    from fitlab.simulate import engine
    from fitlab.simulate.walk import path_rng, seed_words

    engine.load("cpu")
    rng = path_rng(20000, seed_words(7, 0, 0), 0)
    a = np.stack([np.array(rng.next_float32()) for _ in range(8)], axis=1)
    b = np.stack([np.array(path_rng(20000, seed_words(8, 0, 0), 0).next_float32())], axis=1)
    assert a.dtype == np.float32 and a.min() >= 0 and a.max() < 1
    for k in range(8):
        assert stats.kstest(a[:, k], "uniform").pvalue > 1e-3
    c = np.corrcoef(np.concatenate([a, b, np.roll(a, 1, axis=0)], axis=1).T)
    off = c[~np.eye(17, dtype=bool)]
    assert np.max(np.abs(off)) < 5 / np.sqrt(20000)
    # a path's numbers depend on its id, not on the launch it is traced in
    tail = path_rng(100, seed_words(7, 0, 0), 19900).next_float32()
    np.testing.assert_array_equal(np.array(tail), a[19900:, 0])


@pytest.mark.slow
def test_eta_metadata_only_for_a_single_interface():
    one = simulate(scene_from_dict(_base()), 256, seed=0).to_measurement()
    assert one.eta() == pytest.approx(1.5)
    slab = simulate(scene_from_dict(_slab(sigma_a=0.1)), 256, seed=0).to_measurement()
    assert slab.eta() is None and slab.metadata["region_indices"] == "1, 1.5, 1"


def test_split_by_order_sums_to_the_total_in_the_orders_file(tmp_path):
    out = tmp_path / "s.csv"
    assert main(["simulate", str(SCENES / "coated_lambertian.toml"), "--samples", "4096",
                 "--out", str(out), "--split-bounces", "--quiet"]) == 0
    total = read_measurement(out)
    orders = read_measurement(tmp_path / "s.orders.csv")
    key = lambda m, j: (m.theta_i[j], m.theta_o[j], m.phi_o[j])  # noqa: E731
    summed = {}
    for j in range(orders.n):
        summed[key(orders, j)] = summed.get(key(orders, j), 0.0) + orders.value[j]
    for j in range(total.n):
        assert summed[key(total, j)] == pytest.approx(total.value[j], rel=1e-6)


def test_stack_structure_compiles_once():
    """Stack values are kernel inputs: a second scene of the same structure with other values
    (roughness, index, absorption, albedo) launches only kernels from Dr.Jit's cache."""
    import drjit as dr

    def scene(alpha, index, sigma_a, albedo):
        return scene_from_dict(_base(
            stack=[{"type": "interface", "distribution": "ggx", "alpha": alpha},
                   {"type": "medium", "index": index, "thickness": 1.0, "sigma_a": sigma_a}],
            below=None, substrate={"type": "lambertian", "albedo": albedo}))

    simulate(scene(0.2, 1.5, 0.3, 0.5), 256, seed=0)
    dr.kernel_history_clear()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        r = simulate(scene(0.35, 1.33, 0.7, 0.8), 256, seed=0)
        history = dr.kernel_history()
    launched = [k for k in history if k.get("type") == dr.KernelType.JIT]
    assert launched and all(k["cache_hit"] for k in launched), \
        [k.get("hash") for k in launched if not k["cache_hit"]]
    assert r.value.sum() > 0
