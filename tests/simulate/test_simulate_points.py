"""Point estimates of the simulator (``estimator = "point"``, walk.py "Point estimates"): the
values at exact directions agree with the models where those are exact (one Walter interface,
a smooth coat over a Lambertian base), with fine cone averages where no closed form exists, and
the stacks where a connection would miss light are refused by name."""

from __future__ import annotations

import copy
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.errors import InputFileError
from fitlab.io.measurement import read_measurement
from fitlab.models import get_model, rough_dielectric
from fitlab.simulate import scene_from_dict, simulate
from fitlab.simulate.detectors import PASS, ROUGH, SMOOTH, direction, point_connections

ARC = [-70.0, -45.0, -20.0, 0.0, 10.0, 25.0, 40.0, 55.0, 70.0, 85.0]


def _scene(stack, det, **over):
    d = {"name": "points", "stack": stack, "illumination": {"theta_i": [0.0, 35.0, 70.0]},
         "detector": det, "effects": {"delta": False, "color": "mono"}}
    d.update(over)
    return scene_from_dict(d, source="<test>")


def _point(theta_o=ARC):
    return {"type": "inplane", "theta_o": list(theta_o), "estimator": "point"}


def _cone(theta_o=ARC, sr=0.004):
    return {"type": "inplane", "theta_o": list(theta_o), "acceptance_sr": sr}


def _dirs(res):
    return direction(res.theta_i, res.phi_i), direction(res.theta_o, res.phi_o)


def test_one_rough_interface_gives_the_walter_bsdf_exactly():
    """The first event is the only connection: reflection and transmission values are the
    model's own (float32 rounding), at grazing incidence and exit too."""
    theta_o = [-89.0, -30.0, 0.0, 20.0, 45.0, 70.0, 89.0, 95.0, 120.0, 150.0, 179.0]
    sc = _scene([{"type": "interface", "distribution": "ggx", "alpha": 0.25}], _point(theta_o),
                below={"index": 1.5})
    res = simulate(sc, 512, seed=1)
    wi, wo = _dirs(res)
    f = np.asarray(rough_dielectric.MODEL.eval({"alpha": jnp.float64(0.25),
                                                "eta": jnp.float64(1.5)},
                                               jnp.asarray(wi), jnp.asarray(wo)))
    assert np.count_nonzero(f) > 20
    np.testing.assert_allclose(res.value[:, 0], f, rtol=2e-5, atol=1e-12)
    assert np.all(res.sigma[:, 0] <= 2e-7 * np.abs(res.value[:, 0]) + 1e-30)
    assert np.allclose(res.by_order[0, :, 0], res.value[:, 0])  # all of it is order 0
    assert res.scene.detector.estimator == "point"


def test_smooth_coat_over_lambertian_equals_the_closed_form():
    """Connections through the smooth coat (reverse refraction, (1 - F) and the solid-angle
    compression) and the absorbing layer, summed over every bounce."""
    tau, albedo = 0.3, 0.7
    sc = _scene([{"type": "interface", "distribution": "smooth"},
                 {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": tau}],
                _point(), substrate={"type": "lambertian", "albedo": albedo})
    res = simulate(sc, 40_000, seed=2)
    wi, wo = _dirs(res)
    m = get_model("coated(lambertian)")
    f = np.asarray(m.eval({"coat_eta": jnp.float64(1.5), "coat_tau": jnp.float64(tau),
                           "albedo": jnp.float64(albedo)}, jnp.asarray(wi), jnp.asarray(wo),
                          interreflection="closed_form"))
    v, s = res.value[:, 0], res.sigma[:, 0]
    assert np.all(s > 0) and np.median(s / v) < 0.01  # a 1% estimate from 40,000 paths
    assert np.all(np.abs(v - f) <= 4.0 * s + 1e-3 * f), np.c_[res.theta_i, res.theta_o, v, f, s]
    assert "point estimates" in dict(res.plan.simulated)
    # with delta paths requested, the plan says the point values leave the delta lobes out
    from fitlab.simulate import derive_effects

    with_delta = _scene([{"type": "interface", "distribution": "smooth"},
                                {"type": "medium", "index": 1.5, "thickness": 1.0}],
                        _point(), substrate={"type": "lambertian", "albedo": albedo},
                        effects={"color": "mono"})
    assert "delta lobes in the values" in dict(derive_effects(with_delta).skipped)


@pytest.mark.slow
@pytest.mark.parametrize("top", ["ggx", "smooth"])
def test_point_values_agree_with_fine_cones_on_an_hg_slab(top):
    """An HG slab (index 1.5) between a rough or smooth top and a rough bottom interface, every
    order: point estimates against cone averages over 0.004 sr (half-angle 2°) of broad lobes."""
    first = ({"type": "interface", "distribution": "ggx", "alpha": 0.4} if top == "ggx"
             else {"type": "interface", "distribution": "smooth"})
    stack = [first, {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.1,
                     "sigma_s": 1.5, "phase": "hg", "g": 0.5},
             {"type": "interface", "distribution": "ggx", "alpha": 0.5}]
    theta_o = [-60.0, -30.0, 0.0, 30.0, 60.0, 120.0, 150.0, 180.0 - 10.0]
    kw = dict(below={"index": 1.2}, illumination={"theta_i": [20.0]},
              effects={"color": "mono", "delta": False})
    n_cones = 500_000 if top == "ggx" else 200_000  # (the rough top: the slow tier)
    pts = simulate(_scene(stack, _point(theta_o), **kw), 8_000, seed=3)
    cones = simulate(_scene(stack, _cone(theta_o), **kw), n_cones, seed=4)
    v, s = pts.value[:, 0], pts.sigma[:, 0]
    c, cs = cones.value[:, 0], cones.sigma[:, 0]
    keep = (cs > 0) & (cs < 0.25 * c)  # cones that caught enough paths to compare
    assert keep.sum() >= 6
    z = (v - c) / np.hypot(s, cs)
    assert np.all(np.abs(z[keep]) < 4.0), np.c_[pts.theta_o, v, s, c, cs][keep]
    # the point estimate reaches a given error with far fewer paths
    assert np.median((s / v)[keep]) * np.sqrt(8_000) < \
        0.2 * np.median((cs / c)[keep]) * np.sqrt(n_cones)


def test_next_event_kernel_agrees_with_the_walks_own_connections(monkeypatch):
    """Point estimates through the next-event kernel (records of each path's connecting events,
    walk.RECORDS_PER_PATH slots), with most events past the slots (one slot: they connect in the
    walk's kernel), and all in the walk's kernel (0): the same values within their errors, by
    bounce order too, on a slab whose sides mix strategies."""
    import fitlab.simulate.walk as walk

    stack = [{"type": "interface", "distribution": "ggx", "alpha": 0.3},
             {"type": "medium", "index": 1.5, "thickness": 0.8, "sigma_a": 0.1,
              "sigma_s": 1.0, "phase": "hg", "g": 0.3},
             {"type": "interface", "distribution": "ggx", "alpha": 0.4}]
    sc = _scene(stack, _point([-50.0, -10.0, 20.0, 60.0, 130.0, 160.0]), below={"index": 1.2},
                illumination={"theta_i": [25.0]})
    calls = []
    kernel = walk._Walk.nee_from_records
    monkeypatch.setattr(walk._Walk, "nee_from_records",
                        lambda self, *a: calls.append(1) or kernel(self, *a))
    runs = {}
    for slots in (walk.RECORDS_PER_PATH, 1, 0):
        monkeypatch.setattr(walk, "RECORDS_PER_PATH", slots)
        runs[slots] = simulate(sc, 6_000, seed=11)
        assert bool(calls) == (slots > 0)  # the next-event kernel ran, or did not
        calls.clear()
    ref = runs[0]
    assert np.all(ref.value > 0)
    for slots, res in runs.items():
        z = (res.value - ref.value) / np.hypot(res.sigma, ref.sigma)
        assert np.all(np.abs(z) < 4.5), (slots, z)
        zo = (res.by_order - ref.by_order) / np.maximum(
            np.hypot(res.sigma_by_order, ref.sigma_by_order), 1e-30)
        assert np.all(np.abs(zo) < 4.5), (slots, zo)


def test_bounce_orders_sum_and_max_bounces_keeps_the_low_orders():
    stack = [{"type": "interface", "distribution": "ggx", "alpha": 0.3},
             {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2}]
    sub = {"type": "lambertian", "albedo": 0.8}
    full = simulate(_scene(stack, _point(), substrate=sub), 4_000, seed=5)
    assert np.allclose(full.by_order.sum(0), full.value, rtol=1e-9, atol=1e-15)
    assert np.all(full.by_order[1] > 0) and np.all(full.by_order[2] > 0)
    one = simulate(_scene(stack, _point(), substrate=sub,
                          effects={"max_bounces": 1, "delta": False, "color": "mono"}),
                   4_000, seed=5)
    assert np.all(one.by_order[2:] == 0)
    # order 0 (the top's reflection) is the model's exactly, in both runs
    np.testing.assert_allclose(one.by_order[0], full.by_order[0], rtol=1e-6)
    z = (one.by_order[1] - full.by_order[1]) / np.hypot(one.sigma_by_order[1],
                                                         full.sigma_by_order[1])
    assert np.all(np.abs(z) < 4.5)


def test_point_connections_refuse_what_they_would_miss():
    assert point_connections((ROUGH,)) == ((0, None), (0, None))
    assert point_connections((SMOOTH, PASS, ROUGH))[0] == (2, None)
    (k, why), _ = point_connections((SMOOTH, SMOOTH, ROUGH))
    assert k == 2 and "boundary 1 is specular" in why
    # a volume between a smooth top and a mirror: light bounced by the mirror would be missed
    (k, why), _ = point_connections((SMOOTH, SMOOTH))
    assert k == 2 and why is not None
    # ... but a rough top connects every path on its way out, and a rough boundary right
    # above the bottom every path on its way down
    assert point_connections((ROUGH, SMOOTH)) == ((0, None), (0, None))
    (_, why_u), (kd, why_d) = point_connections((SMOOTH, ROUGH, SMOOTH, SMOOTH))
    assert why_u is None and kd == 1 and "boundary 2 is specular" in why_d
    assert point_connections((PASS, PASS)) == ((2, None), (-1, None))  # a bare volume


_BASE = {"name": "p", "stack": [{"type": "interface", "distribution": "smooth"},
                                {"type": "medium", "index": 1.5, "thickness": 1.0,
                                 "sigma_s": 1.0},
                                {"type": "interface", "distribution": "smooth"}],
         "below": {"index": 1.3}, "illumination": {"theta_i": [10.0]},
         "detector": {"type": "inplane", "theta_o": [0.0, 30.0], "estimator": "point"}}


@pytest.mark.parametrize("patch, fragment", [
    (lambda d: None, "detector.estimator: point estimates of reflection are not possible for "
                     "this stack: boundary 1 is specular"),
    (lambda d: d["detector"].update(acceptance_sr=0.01),
     "detector.acceptance_sr: a point estimate has no acceptance solid angle"),
    (lambda d: d["detector"].update(estimator="bin"), "detector.estimator: 'bin' is not"),
])
def test_point_estimator_scene_errors(patch, fragment):
    d = copy.deepcopy(_BASE)
    patch(d)
    with pytest.raises(InputFileError) as exc:
        scene_from_dict(d, source="mine.toml")
    assert fragment in str(exc.value)


def test_cli_writes_point_estimates_with_their_provenance(tmp_path):
    from fitlab.cli import main

    scene = tmp_path / "s.toml"
    scene.write_text('format = "fitlab-scene"\nversion = 1\nname = "p"\n'
                     '[[stack]]\ntype = "interface"\ndistribution = "ggx"\nalpha = 0.3\n'
                     '[[stack]]\ntype = "medium"\nindex = 1.5\nthickness = 1.0\nsigma_a = 0.2\n'
                     '[substrate]\ntype = "lambertian"\nalbedo = 0.5\n'
                     '[illumination]\ntheta_i = [30]\n'
                     '[detector]\ntype = "hemisphere"\ntheta_bins = 3\nphi_bins = 4\n'
                     'sides = ["reflection"]\nestimator = "point"\n')
    out = tmp_path / "p.csv"
    assert main(["simulate", str(scene), "--samples", "2000", "--seed", "1", "--quiet",
                 "--out", str(out)]) == 0
    m = read_measurement(out)
    assert m.metadata["estimator"] == "point" and "next-event" in m.metadata["value"]
    assert "point estimates" in m.metadata["effects_simulated"]
    assert m.aperture_deg is not None and np.all(m.aperture_deg == 0) and not m.has_aperture
    assert m.n == 12 and np.all(m.sigma > 0)
    # bin centres: θo 15, 45, 75 at φo 45, 135, ...
    assert sorted(set(np.round(m.theta_o, 6))) == [15.0, 45.0, 75.0]
    again = tmp_path / "q.csv"
    assert main(["simulate", str(scene), "--samples", "2000", "--seed", "1", "--quiet",
                 "--out", str(again)]) == 0
    assert again.read_bytes() == out.read_bytes()


@pytest.mark.parametrize("top", [{"type": "interface", "distribution": "ggx", "alpha": 0.3},
                                 {"type": "interface", "distribution": "smooth"}])
def test_point_estimates_are_reciprocal_on_a_layered_brdf(top):
    """f(wi, wo) = f(wo, wi): every connecting strategy (direct, crossing, vertex with its
    multiple-importance weights) meets its mirror image when the roles are swapped."""
    stack = [top, {"type": "medium", "index": 1.4, "thickness": 0.5, "sigma_a": 0.2,
                   "sigma_s": 1.0, "phase": "hg", "g": 0.3}]
    angles = [10.0, 35.0, 60.0]
    sc = _scene(stack, _point(angles), substrate={"type": "lambertian", "albedo": 0.6},
                illumination={"theta_i": angles})
    res = simulate(sc, 12_000, seed=11)
    val = {(ti, to): (v, s) for ti, to, v, s in zip(res.theta_i, res.theta_o, res.value[:, 0],
                                                     res.sigma[:, 0])}
    for a in angles:
        for b in angles:
            if a < b:
                (v1, s1), (v2, s2) = val[(a, b)], val[(b, a)]
                assert abs(v1 - v2) < 4.0 * np.hypot(s1, s2), (a, b, v1, v2, s1, s2)
                assert s1 < 0.03 * v1


def test_device_selection(tmp_path, capsys):
    """--device cpu runs on the CPU (the same numbers as JAX's default device here when that
    is the CPU); --device gpu without a GPU is an input error (exit 2) saying what to install."""
    import jax

    from fitlab.cli import main

    scene = str(Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "scenes"
                / "coated_lambertian.toml")
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert main(["simulate", scene, "--samples", "256", "--quiet", "--device", "cpu",
                 "--out", str(a)]) == 0
    from fitlab.simulate import engine

    if not engine.gpu_available():
        assert main(["simulate", scene, "--samples", "256", "--quiet", "--out", str(b)]) == 0
        assert a.read_bytes() == b.read_bytes()
        capsys.readouterr()
        assert main(["simulate", scene, "--samples", "256", "--quiet", "--device", "gpu",
                     "--out", str(tmp_path / "c.csv")]) == 2
        err = capsys.readouterr().err
        assert "no GPU" in err and "--device cpu" in err and len(err.splitlines()) == 1
        assert not (tmp_path / "c.csv").exists()


def test_single_scattering_slab_equals_the_closed_form():
    """An index-matched HG slab (no interfaces), one volume scattering event: f_r = ω p
    (1 − e^{−τ(1/μi + 1/μo)}) / (μi + μo) and f_t = ω p (e^{−τ/μo} − e^{−τ/μi}) / (μo − μi)
    (p the phase function between the propagation directions, ∫p dω = 1)."""
    from fitlab.phase import eval_hg

    sa, ss, h, g = 0.3, 1.2, 0.8, 0.4
    stack = [{"type": "medium", "index": 1.0, "thickness": h, "sigma_a": sa, "sigma_s": ss,
              "phase": "hg", "g": g}]
    theta_o = [-70.0, -35.0, 0.0, 25.0, 55.0, 80.0, 110.0, 140.0, 175.0]
    sc = _scene(stack, _point(theta_o), illumination={"theta_i": [0.0, 50.0]},
                effects={"volume_scattering": "single", "delta": False, "color": "mono"})
    res = simulate(sc, 20_000, seed=13)
    wi, wo = _dirs(res)
    p = np.asarray(eval_hg({"g": jnp.float64(g)}, jnp.asarray(wi), jnp.asarray(wo)))
    mi, mo = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    tau, omega = (sa + ss) * h, ss / (sa + ss)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(wo[:, 2] > 0,
                     omega * p * -np.expm1(-tau * (1 / mi + 1 / mo)) / (mi + mo),
                     omega * p * (np.exp(-tau / mo) - np.exp(-tau / mi)) / (mo - mi))
    v, s = res.value[:, 0], res.sigma[:, 0]
    assert np.all(np.isfinite(f)) and np.all(v > 0)
    assert np.all(np.abs(v - f) <= 4.0 * s + 1e-4 * f), np.c_[res.theta_i, res.theta_o, v, f, s]
    assert np.median(s / v) < 0.02


@pytest.mark.slow
def test_point_values_integrate_to_the_flux_that_leaves():
    """Points at hemisphere bin centres, integrated with the bins' cosine-weighted solid angles,
    give the reflected and transmitted flux the same walk tallies from its escaping paths, to
    the midpoint rule's accuracy."""
    stack = [{"type": "interface", "distribution": "ggx", "alpha": 0.5},
             {"type": "medium", "index": 1.2, "thickness": 0.5, "sigma_s": 1.0,
              "phase": "isotropic"},
             {"type": "interface", "distribution": "ggx", "alpha": 0.6}]
    det = {"type": "hemisphere", "theta_bins": 12, "phi_bins": 24, "estimator": "point"}
    sc = _scene(stack, det, illumination={"theta_i": [20.0]}, below={"index": 1.0})
    res = simulate(sc, 6_000, seed=17)
    from fitlab.simulate.detectors import hemisphere_rows

    cw = hemisphere_rows(12, 24, ("reflection", "transmission")).cos_solid_angle
    up = res.theta_o < 90
    R, T = (float(np.sum(res.value[m, 0] * cw[m])) for m in (up, ~up))
    (Rw, Tw), (sR, sT) = res.energy[0, :, 0], res.energy_sigma[0, :, 0]
    assert res.truncated == 0
    # (rough interfaces' single-scattering microfacet BSDFs lose energy at α 0.5–0.6, so the
    # flux leaving is below 1 here: the check is that both estimates see the same flux)
    assert 0.5 < Rw + Tw < 1.0
    # the walk's own flux is the noisier side; the midpoint rule (7.5° x 15°) adds about 2%
    assert abs(R - Rw) < 4 * sR + 0.02 * Rw and abs(T - Tw) < 4 * sT + 0.02 * Tw, (R, Rw, T, Tw)
