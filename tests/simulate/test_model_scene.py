"""``Model.scene_of``: the simulator scene of the stack a model approximates
(fitlab/models/base.py; data_formats/layered_models.md, "The simulator's scene of a model").

(a) every registry model that has one gives a scene the simulator accepts, at its defaults, at
its parameter bounds and under each option; (b) coated(lambertian) with every bounce and
coated(rough_conductor) with one agree with a short simulation of their scenes; (c) the
parameters land in the right scene fields (relative indices scaled by the layer above,
absolute ones as given) and the options in the right effects."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.models import CONSTRUCTORS, MODELS, get_model
from fitlab.simulate import scene_from_dict


def _registry_models():
    """Every registry model, every constructor over every plain model it accepts, and the
    variants of the layered families (options in the name) with a scene."""
    plain = [n for n in MODELS if "(" not in n]
    names = list(MODELS)
    for ctor in CONSTRUCTORS:
        for inner in plain:
            try:
                get_model(f"{ctor}({inner})")
            except ValueError:  # refused by the constructor (e.g. a transmitting base)
                continue
            names.append(f"{ctor}({inner})")
    names += ["coated(lambertian,specular=lobe)", "coated(rough_conductor,specular=lobe)",
              "weidlich_wilkie(rough_conductor,layers=3)", "weidlich_wilkie(lambertian,layers=4)",
              "thin_layer(rough_conductor,roughness=alpha)",
              "thin_layer(rough_dielectric,roughness=alpha)",
              "spongecake(hg,substrate=rough_dielectric)",
              "spongecake(fiber,substrate=rough_conductor,multiple=lobe)",
              "coated(spongecake(hg))", "lambertian+rough_conductor"]
    return tuple(dict.fromkeys(names))


NAMES = _registry_models()
WITH_SCENE = tuple(n for n in NAMES if get_model(n).scene_of is not None)


def test_the_layered_families_and_their_parts_have_scenes_and_the_rest_none():
    for name in ("lambertian", "rough_conductor", "rough_dielectric", "coated(lambertian)",
                 "coated(rough_conductor)", "coated(lambertian,specular=lobe)",
                 "weidlich_wilkie(lambertian)", "weidlich_wilkie(rough_conductor)",
                 "weidlich_wilkie(rough_conductor,layers=3)", "thin_layer(rough_conductor)",
                 "thin_layer(rough_dielectric)", "spongecake(surface)", "spongecake(hg)",
                 "spongecake(surface_z,substrate=lambertian)", "spongecake(surface,multiple=lobe)",
                 "spongecake(fiber,multiple=learned)"):
        assert name in WITH_SCENE, name
    # no stack the simulator traces: an Oren–Nayar or glTF base, a sum, a fitted lobe alone
    for name in ("oren_nayar", "gltf_pbr", "coated(oren_nayar)", "weidlich_wilkie(oren_nayar)",
                 "lambertian+rough_conductor", "spongecake(hg,multiple=only)",
                 "spongecake(surface,substrate=oren_nayar)"):
        assert get_model(name).scene_of is None, name


def _parameter_sets(model):
    return {"default": {p.name: p.default for p in model.parameters},
            "lower": {p.name: p.lower for p in model.parameters},
            "upper": {p.name: p.upper for p in model.parameters}}


def _option_sets(model):
    """The defaults, then each option's every choice alone."""
    base = model.default_options()
    out = [base]
    for o in model.options:
        out += [{**base, o.name: c} for c in o.choices if c != o.default]
    return out


def _validate(model, scene):
    """The scene with an in-plane detector on the sides the model scatters to: point estimates
    where the simulator can make them for this stack, cones otherwise."""
    theta_o = [-60.0, -20.0, 10.0, 40.0, 75.0]
    if model.capabilities.transmission:
        theta_o += [120.0, 160.0, -150.0]
    for det in ({"estimator": "point"}, {"acceptance_sr": 0.01}):
        d = {**scene, "illumination": {"theta_i": [30.0]},
             "detector": {"type": "inplane", "theta_o": theta_o, **det}}
        try:
            return scene_from_dict(d)
        except Exception as e:  # point estimates refused for this stack: use cones
            if "detector.estimator" not in str(e):
                raise
    raise AssertionError("unreachable")


def _model_refuses(model, params, options):
    """The model's own evaluation raises ValueError for these options (traced, not run)."""
    wi = jnp.asarray([[0.0, 0.0, 1.0]])
    p = {k: jnp.float64(v) for k, v in params.items()}
    try:
        jax.eval_shape(lambda: model.eval(p, wi, wi, **options))
    except ValueError:
        return True
    return False


@pytest.mark.parametrize("name", WITH_SCENE)
def test_scene_validates_at_defaults_bounds_and_every_option(name):
    model = get_model(name)
    allowed = {"illumination", "detector"}
    for pset, params in _parameter_sets(model).items():
        for options in _option_sets(model) if pset == "default" else [model.default_options()]:
            try:
                scene = model.scene_of(params, options)
            except ValueError as e:
                # parameters the simulator cannot express, said so; or options the model
                # itself refuses
                assert ((pset != "default" and "fitlab simulate" in str(e))
                        or _model_refuses(model, params, options)), (pset, options, e)
                continue
            assert scene is not None
            assert set(scene) <= {"outside", "stack", "substrate", "below", "effects"}, scene
            assert not set(scene) & allowed
            assert scene["effects"]["delta"] is False  # no model's f holds a delta
            sc = _validate(model, scene)
            assert sc.outside_index == 1.0


# ----------------------------------------------------------------------------------------------
# (b) the model against a short simulation of its own scene
# ----------------------------------------------------------------------------------------------

THETA_I = 30.0
THETA_O = [-60.0, -25.0, 0.0, 20.0, 35.0, 55.0, 75.0]


def _dir(theta, phi):
    t, f = np.radians(theta), np.radians(phi)
    return np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1)


def _model_vs_simulation(name, params, options, samples, seed):
    from fitlab.simulate import simulate

    model = get_model(name)
    scene = model.scene_of(params, options)
    res = simulate(scene_from_dict({
        **scene, "illumination": {"theta_i": [THETA_I]},
        "detector": {"type": "inplane", "theta_o": THETA_O, "estimator": "point"}}),
        samples=samples, seed=seed)
    wi = jnp.asarray(_dir(res.theta_i, res.phi_i))
    wo = jnp.asarray(_dir(res.theta_o, res.phi_o))
    p = {k: jnp.float64(v) for k, v in params.items()}
    f = np.asarray(jax.jit(lambda a, b: model.eval(p, a, b, **options))(wi, wo))
    return f, res.value[:, 0], res.sigma[:, 0]


@pytest.mark.parametrize("name, params, options", [
    ("coated(lambertian)", {"coat_eta": 1.5, "coat_tau": 0.3, "albedo": 0.7},
     {"interreflection": "closed_form"}),
    # chromium (Elek 2010 appendix A) under the coat: n, k relative to the coat
    ("coated(rough_conductor)", {"coat_eta": 1.5, "coat_tau": 0.2, "alpha": 0.3,
                                 "n": 3.18 / 1.5, "k": 4.41 / 1.5}, {}),
], ids=["lambertian-closed_form", "rough_conductor-one_bounce"])
def test_coated_agrees_with_its_simulated_scene(name, params, options):
    """The coated model is exact for its stack (smooth coat, single point; one bounce, or every
    bounce in closed form over a Lambertian base): within 4.5 standard errors + 3%."""
    f, v, s = _model_vs_simulation(name, params, options, samples=40_000, seed=3)
    assert np.all(v > 0) and np.all(s > 0)
    assert np.all(np.abs(f - v) <= 4.5 * s + 0.03 * v), np.c_[THETA_O, f, v, s]


# ----------------------------------------------------------------------------------------------
# (c) which parameter moves which scene field
# ----------------------------------------------------------------------------------------------


def _scene(name, options=None, **params):
    m = get_model(name)
    p = {q.name: q.default for q in m.parameters}
    p.update(params)
    return m.scene_of(p, {**m.default_options(), **(options or {})})


def test_coated_inner_indices_are_relative_to_the_coat():
    s = _scene("coated(rough_conductor)", coat_eta=1.5, coat_tau=0.4, alpha=0.2, n=2.0, k=3.0)
    assert s["stack"] == [{"type": "interface", "distribution": "smooth"},
                          {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.4}]
    sub = s["substrate"]
    assert (sub["type"], sub["n"], sub["k"], sub["alpha"]) == ("conductor", 3.0, 4.5, 0.2)
    # the relative n moves only the substrate's n; the coat's index moves the coat and (n, k)
    t = _scene("coated(rough_conductor)", coat_eta=1.5, coat_tau=0.4, alpha=0.2, n=2.5, k=3.0)
    assert t["stack"] == s["stack"] and (t["substrate"]["n"], t["substrate"]["k"]) == (3.75, 4.5)
    u = _scene("coated(rough_conductor)", coat_eta=2.0, coat_tau=0.4, alpha=0.2, n=2.0, k=3.0)
    assert u["stack"][1]["index"] == 2.0
    assert (u["substrate"]["n"], u["substrate"]["k"]) == (4.0, 6.0)
    # a transmitting inner: the medium below has the inner's relative index times the coat's
    d = _scene("coated(rough_dielectric)", coat_eta=1.5, eta=1.2)
    assert d["below"]["index"] == pytest.approx(1.8) and d["stack"][-1]["type"] == "interface"
    # a coat of the outside's index is no interface
    assert _scene("coated(lambertian)", coat_eta=1.0)["stack"][0]["type"] == "medium"


def test_coated_options_choose_the_bounces_and_the_top():
    assert _scene("coated(lambertian)")["effects"] == {"max_bounces": 1, "delta": False}
    closed = _scene("coated(lambertian)", {"interreflection": "closed_form"})
    assert closed["effects"] == {"max_bounces": "all", "delta": False}
    assert closed["substrate"] == {"type": "lambertian", "albedo": 0.5}
    lobe = _scene("coated(lambertian,specular=lobe)", coat_alpha=0.03)
    assert lobe["stack"][0] == {"type": "interface", "distribution": "ggx", "alpha": 0.03}


def test_weidlich_wilkie_indices_are_absolute():
    s = _scene("weidlich_wilkie(rough_conductor)", {"distribution": "beckmann"}, alpha1=0.1,
               n1=1.4, tau1=0.5, alpha2=0.3, n2=3.18, k2=4.41)
    assert s["stack"] == [
        {"type": "interface", "distribution": "beckmann", "alpha": 0.1},
        {"type": "medium", "index": 1.4, "thickness": 1.0, "sigma_a": 0.5}]
    sub = s["substrate"]
    assert sub["n"] == pytest.approx(3.18) and sub["k"] == pytest.approx(4.41)
    assert (sub["distribution"], sub["alpha"]) == ("beckmann", 0.3)
    assert s["effects"] == {"max_bounces": "all", "delta": False}
    # n1 moves the layer only; the clamp is the model's, not the stack's
    t = _scene("weidlich_wilkie(rough_conductor)", {"roughness_clamp": "clamp"}, alpha1=0.1,
               n1=1.7, tau1=0.5, alpha2=0.05, n2=3.18, k2=4.41)
    assert t["stack"][1]["index"] == 1.7 and t["substrate"]["n"] == pytest.approx(3.18)
    assert t["substrate"]["alpha"] == 0.05
    three = _scene("weidlich_wilkie(lambertian,layers=3)", n1=1.3, n2=1.6, tau2=0.2, albedo3=0.4)
    assert [i.get("index") for i in three["stack"]] == [None, 1.3, None, 1.6]
    assert three["stack"][3]["sigma_a"] == 0.2 and three["substrate"]["albedo"] == 0.4


def test_weidlich_wilkie_absorbing_interface_has_no_scene():
    with pytest.raises(ValueError, match="k1 = 0.2 > 0.*dielectric"):
        _scene("weidlich_wilkie(rough_conductor)", k1=0.2)


def test_thin_layer_maps_vmf_boundaries_and_absolute_bottom_indices():
    s = _scene("thin_layer(rough_conductor)", {"masking": "approx", "bounces": "3",
                                               "compensation": "none"},
               kappa1=500.0, eta=1.4, tau=0.3, kappa2=80.0, n2=3.18, k2=4.41)
    assert s["stack"] == [
        {"type": "interface", "distribution": "vmf", "kappa": 500.0, "masking": "approx"},
        {"type": "medium", "index": 1.4, "thickness": 1.0, "sigma_a": 0.3}]
    assert s["substrate"] == {"type": "conductor", "n": 3.18, "k": 4.41, "distribution": "vmf",
                              "kappa": 80.0, "masking": "approx"}
    assert s["effects"] == {"max_bounces": 3, "delta": False}
    # the compensation (the default) stands for every order the stack scatters
    assert _scene("thin_layer(rough_conductor)", {"bounces": "3"})["effects"][
        "max_bounces"] == "all"
    assert _scene("thin_layer(rough_conductor)", {"component": "surface"})["effects"][
        "max_bounces"] == 0
    d = _scene("thin_layer(rough_dielectric,roughness=alpha)", alpha1=0.05, eta=1.3, alpha2=0.2,
               eta2=1.8)
    assert d["stack"][0]["alpha"] == 0.05
    assert d["substrate"] == {"type": "dielectric", "index": 1.8, "distribution": "vmf",
                              "alpha": 0.2, "masking": "exact"}
    # a bottom of the layer's own index is no boundary
    assert _scene("thin_layer(rough_dielectric)", eta=1.5, eta2=1.5)["below"] == {"index": 1.5}


def test_spongecake_single_and_multiple_scattering_share_the_stack():
    from fitlab.models import spongecake

    p = {"alpha1": 0.3, "theta_p1": 20.0, "phi_p1": 10.0, "albedo1": 0.8, "f0_1": 0.5,
         "tau1": 2.0}
    single = _scene("spongecake(surface)", **p)
    assert single["stack"] == spongecake.simulator_stack(("surface",), {"": p})
    assert "substrate" not in single and "below" not in single
    assert single["effects"] == {"volume_scattering": "single", "delta": False}
    lobe = _scene("spongecake(surface,multiple=lobe)", **p)
    assert lobe["stack"] == single["stack"]
    assert lobe["effects"] == {"volume_scattering": "multiple", "delta": False}
    sub = _scene("spongecake(surface_z,substrate=lambertian)", albedo=0.6, tau1=0.5)
    assert sub["stack"][-1]["thickness"] == 0.5
    assert sub["substrate"] == {"type": "lambertian", "albedo": 0.6}
