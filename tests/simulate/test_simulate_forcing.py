"""What the simulator leaves out when a scene observes only part of the light (issue 15, item 2):
branch forcing at the boundaries that lead to an unobserved side, and one channel of an RGB
scene. Every choice is unbiased: the values agree with a scene that traces everything, and the
effect plan names what was forced or skipped."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.models import rough_dielectric
from fitlab.models.rough_dielectric import CHOOSE, REFLECT, REFRACT, walter_sample
from fitlab.simulate import scene_from_dict, simulate
from fitlab.simulate.effects import derive_effects

UP = [-60.0, -25.0, 0.0, 30.0, 65.0]
DOWN = [115.0, 150.0, 180.0, -140.0]


def _slab(theta_o, top="ggx", estimator="point", color="mono", **over):
    top_if = ({"type": "interface", "distribution": "ggx", "alpha": 0.2} if top == "ggx"
              else {"type": "interface"})
    det = {"type": "inplane", "theta_o": list(theta_o), "estimator": estimator}
    if estimator == "cone":
        det["acceptance_sr"] = 0.05
    d = {"name": "forcing", "stack": [
        top_if,
        {"type": "medium", "index": 1.5, "thickness": 0.5, "sigma_a": 0.1, "sigma_s": 1.2,
         "phase": "hg", "g": 0.4},
        {"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "below": {"index": 2.2},  # a dense substrate: F at the bottom is not small
        "illumination": {"theta_i": [35.0]}, "detector": det,
        "effects": {"color": color}}
    d.update(over)
    return scene_from_dict({k: v for k, v in d.items() if v is not None}, source="<test>")


def test_forced_branches_are_named_in_the_effect_plan():
    only_r = derive_effects(_slab(UP))
    assert only_r.force_bottom and not only_r.force_top
    assert "forced reflection at the bottom" in dict(only_r.simulated)
    assert "forced reflection" in dict(only_r.skipped)["transmission"]
    only_t = derive_effects(_slab(DOWN))
    assert only_t.force_top and not only_t.force_bottom
    assert "forced branches at the top" in dict(only_t.simulated)
    both = derive_effects(_slab(UP + DOWN))
    assert not (both.force_top or both.force_bottom)
    # an opaque substrate transmits nothing: nothing to force
    opaque = derive_effects(_slab(UP, stack=[
        {"type": "interface", "distribution": "ggx", "alpha": 0.2},
        {"type": "medium", "index": 1.5, "thickness": 0.5, "sigma_s": 1.0}],
        substrate={"type": "lambertian", "albedo": 0.5}, below=None))
    assert not opaque.force_bottom


@pytest.mark.slow
@pytest.mark.parametrize("top", ["smooth"])
def test_forced_sides_agree_with_the_walk_that_traces_both(top):
    """Point estimates of each side alone (the other side's branches forced away) against the
    same rows of a scene observing both sides: the same values within the standard errors."""
    both = simulate(_slab(UP + DOWN, top), 6000, seed=3)
    n_up = len(UP)
    for rows, side in ((slice(0, n_up), UP), (slice(n_up, None), DOWN)):
        alone = simulate(_slab(side, top), 6000, seed=4)
        a, sa = both.value[rows, 0], both.sigma[rows, 0]
        b, sb = alone.value[:, 0], alone.sigma[:, 0]
        assert np.all(b > 0) and np.all(sb > 0)
        z = (a - b) / np.sqrt(sa**2 + sb**2)
        assert np.max(np.abs(z)) < 4.5, (side, z)


def test_forced_reflection_of_one_interface_is_every_path_weighted_by_fresnel():
    """One rough interface observed in reflection only: every path reflects, weighted by F, so
    the cone values agree with a walk over both sides, with a smaller error."""
    stack = [{"type": "interface", "distribution": "ggx", "alpha": 0.3}]
    r = simulate(_slab(UP, estimator="cone", stack=stack), 40000, seed=1)
    both = simulate(_slab(UP + DOWN, estimator="cone", stack=stack), 40000, seed=2)
    a, sa = both.value[:len(UP), 0], both.sigma[:len(UP), 0]
    z = (r.value[:, 0] - a) / np.sqrt(r.sigma[:, 0] ** 2 + sa**2)
    assert np.max(np.abs(z)) < 4.5, z
    assert r.plan.force_bottom
    # with η 2.2 about 15% of the light reflects: forced, every path lands in the reflection
    # cones' neighbourhood, and the errors shrink accordingly
    assert np.median(r.sigma[:, 0] / r.value[:, 0]) < 0.6 * np.median(sa / a)


@pytest.mark.parametrize("eta", [1.5, 0.6])
def test_walter_sample_forced_branches_carry_their_probability(eta):
    """walter_sample with force: E[weight | forced reflect] = E[weight · 1{reflect}] of the
    Fresnel choice (and likewise for refraction), the density stays the model's pdf."""
    n = 20000
    key = jax.random.PRNGKey(7)
    u = jax.random.uniform(key, (n, 3), dtype=jnp.float64)
    wi = jnp.broadcast_to(jnp.asarray([np.sin(1.0), 0.0, np.cos(1.0)]), (n, 3))
    params = {"alpha": jnp.float64(0.4), "eta": jnp.float64(eta)}
    dist = rough_dielectric.MODEL.microfacet(params, "ggx")
    wo, w, p = walter_sample(dist, params, wi, u)
    chose_r = wo[:, 2] > 0
    for code, mask in ((REFLECT, chose_r), (REFRACT, ~chose_r)):
        wf, ww, pf = walter_sample(dist, params, wi, u, force=jnp.full((n,), code))
        assert np.all(np.asarray(ww) >= 0)
        lhs, rhs = float(jnp.mean(ww)), float(jnp.mean(jnp.where(mask, w, 0.0)))
        se = float(jnp.std(ww) + jnp.std(jnp.where(mask, w, 0.0))) / np.sqrt(n)
        assert abs(lhs - rhs) < 5 * se + 1e-12, (code, lhs, rhs)
        side = wf[:, 2] > 0 if code == REFLECT else wf[:, 2] < 0
        ok = np.asarray((ww > 0) & side)
        ref = rough_dielectric.MODEL.pdf(params, wi, wf)
        np.testing.assert_allclose(np.asarray(pf)[ok], np.asarray(ref)[ok], rtol=1e-9)
    # CHOOSE is the unforced sampler itself
    w0, ww0, p0 = walter_sample(dist, params, wi, u, force=jnp.full((n,), CHOOSE))
    np.testing.assert_array_equal(np.asarray(w0), np.asarray(wo))
    np.testing.assert_array_equal(np.asarray(ww0), np.asarray(w))


def test_one_channel_of_an_rgb_scene_is_that_channel_of_the_full_walk():
    """color = "G" walks the G values alone: bit for bit the G column of the RGB run (one walk
    per channel there, the same random numbers), named G, the others listed as skipped."""
    over = {"stack": [
        {"type": "interface", "distribution": "ggx", "alpha": 0.2},
        {"type": "medium", "index": 1.5, "thickness": 0.5, "sigma_a": [0.1, 0.2, 0.3],
         "sigma_s": [0.8, 1.0, 1.5], "phase": "hg", "g": 0.5}],
        "substrate": {"type": "lambertian", "albedo": [0.5, 0.6, 0.7]}, "below": None}
    rgb = simulate(_slab(UP, color="rgb", **over), 3000, seed=5)
    g = simulate(_slab(UP, color="g", **over), 3000, seed=5)
    assert g.channel_names == ("G",) and g.value.shape == (len(UP), 1)
    np.testing.assert_array_equal(g.value[:, 0], rgb.value[:, 1])
    np.testing.assert_array_equal(g.sigma[:, 0], rgb.sigma[:, 1])
    assert "other channels" in dict(g.plan.skipped)
    # grey properties: one channel, named as asked
    grey = derive_effects(_slab(UP, color="B"))
    assert grey.channel_names == ("B",) and grey.channel_pick is None


@pytest.mark.parametrize("top", [pytest.param("ggx", marks=pytest.mark.slow), "smooth"])
def test_splitting_the_first_interface_agrees_and_sharpens_the_surface_lobe(top):
    """split_first_interface = true: every path's first crossing gives its reflection (tallied
    at once) and continues refracted. Cone values and the flux per side agree with the plain
    walk; the cones of the surface reflection get errors several times smaller."""
    theta = [-60.0, -35.0, -10.0, 10.0, 35.0, 55.0, 150.0]  # 35°: the mirror direction
    plain = simulate(_slab(theta, top, estimator="cone"), 40000, seed=6)
    split = simulate(_slab(theta, top, estimator="cone",
                           effects={"color": "mono", "split_first_interface": True}),
                     40000, seed=7)
    assert split.plan.split_first and "splitting at the first interface" in dict(
        split.plan.simulated)
    ok = (plain.sigma[:, 0] > 0) & (split.sigma[:, 0] > 0)
    z = (plain.value[:, 0] - split.value[:, 0]) / np.hypot(plain.sigma[:, 0], split.sigma[:, 0])
    assert np.all(np.abs(z[ok]) < 4.5), z
    ez = (plain.energy - split.energy) / np.hypot(plain.energy_sigma, split.energy_sigma)
    assert np.all(np.abs(ez) < 4.5), ez
    mirror = theta.index(35.0)
    assert split.sigma[mirror, 0] < 0.5 * plain.sigma[mirror, 0]
    # all order-0 reflection comes from the split branch
    assert split.by_order[0, mirror, 0] > 0


@pytest.mark.parametrize("detector", ["cone", "bins"])
def test_a_smooth_tops_split_is_counted_once_per_path(detector):
    """A smooth top reflects every path alike (mirror direction, weight F(θi)): the split
    computes its branch once and counts it per path of each block (walk._Split.blocks), the
    same sums as tallying every path's branch, and its order-0 value has no Monte Carlo error."""
    from fitlab.simulate import detectors, simulator, walk

    over = {} if detector == "cone" else {"detector": {"type": "hemisphere", "theta_bins": 3,
                                                       "phi_bins": 4}}
    scene = _slab([-35.0, 10.0, 35.0], "smooth", estimator="cone", **over,
                  effects={"color": "mono", "split_first_interface": True})
    plan = derive_effects(scene)
    stack = walk.Stack(*simulator._walk_setup(scene, plan, plan.channel_pick, 1000))
    ti, pi_, rows, axes = simulator._incidence_rows(scene)[0]
    if axes is None:  # bins: both sides, 3 x 4 each
        det, cones, n_out = walk.Detector(np.zeros((1, 3)), np.full(1, 2.0)), None, 24
    else:
        cos = detectors.cone_half_angle_cos(scene.detector.acceptance_sr)
        det = walk.Detector(np.asarray(axes, float), np.full(len(axes), cos))
        cones, n_out = walk.ConeIndex(det), len(axes)
    n = 3 * walk.TALLY_BLOCK + 123
    with walk._Cores() as cores:
        split = walk._Split(stack, det, detectors.direction(ti, pi_), walk.seed_words(1, 0),
                            n_out, cones, cores)
        once, every = split.blocks(n, 0, cores), split._tally(n, 0, cores)
    assert split.one is not None and once[0].sum() > 0
    for a, b in zip(once, every):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
    res = simulate(scene, 5000, seed=2)
    up = res.theta_o < 90.0  # order 0 there: the split alone (the walk's first crossing refracts)
    assert np.all(res.sigma_by_order[0][up] == 0) and res.by_order[0][up].max() > 0


@pytest.mark.parametrize("change, words", [
    ({"detector": {"type": "inplane", "theta_o": [10.0], "estimator": "point"}}, "exactly"),
    ({"detector": {"type": "inplane", "theta_o": [150.0], "acceptance_sr": 0.01}},
     "reflection is not observed"),
    ({"stack": [{"type": "medium", "index": 1.0, "thickness": 1.0, "sigma_s": 1.0}],
      "below": None}, "not a dielectric interface"),
])
def test_splitting_is_refused_where_it_cannot_apply(change, words):
    from fitlab.errors import InputFileError

    base = {"detector": {"type": "inplane", "theta_o": [10.0], "acceptance_sr": 0.01},
            "effects": {"split_first_interface": True}}
    base.update(change)
    with pytest.raises(InputFileError, match=words):
        _slab([10.0], **base)
