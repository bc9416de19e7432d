"""Named parameter sets of the layered models (Elek 2010 section 4; SpongeCake Table 2), per
colour channel.

``fitlab eval --preset NAME --channel R`` and ``fitlab models`` use them; in Python,
``preset_params(name, channel)`` gives the parameter dict of one channel.

The (n, k) values are Elek 2010 appendix A (690, 550, 450 nm for R, G, B;
:data:`fitlab.fresnel.CONDUCTOR_PRESETS`). The paper gives no numbers for the roughnesses, the
coat's tint or the patina's "empirically matched light-green absorption spectrum": those below
are fitlab's choices, stated as such. The car paint's flake sparkle (a normal map) and the
patina layer's extra diffuse term are out of scope; the layering is what the presets carry.

The SpongeCake presets are the four stacks of the paper's Table 2 (Wang et al. 2022). Where the
table says "map" (a texture in the paper's scenes) fitlab puts one constant and says so in the
description: fibers in the plane (θp = 90°), flake normals along the macro normal, a thickness
of 1. The text and the table disagree on two values (window shade: the text calls the rough
layer the outside one; fabric: the text gives the fibers α 0.5, the table 0.1); the presets
follow the table. ``fitlab lut model --preset NAME`` bakes all three channels;
:func:`preset_scene` gives a preset as a simulator scene (``fitlab simulate``).
"""

from __future__ import annotations

from typing import NamedTuple

from fitlab.fresnel import CONDUCTOR_PRESETS
from fitlab.registry import Registry

CHANNELS = ("R", "G", "B")


class Preset(NamedTuple):
    name: str
    model: str
    options: dict
    #: parameter -> one value (all channels) or (R, G, B)
    params: dict
    description: str


_CR, _CU, _CU2O = (CONDUCTOR_PRESETS[k] for k in ("chromium", "copper", "cuprite"))

PRESETS: Registry[Preset] = Registry("preset", {
    p.name: p
    for p in (
        Preset(
            "metallic_car_paint", "weidlich_wilkie(rough_conductor)", {},
            {"alpha1": 0.02, "n1": 1.5, "k1": 0.0, "tau1": (0.05, 0.9, 1.2),
             "alpha2": 0.3, "n2": _CR["n"], "k2": _CR["k"]},
            "Elek 2010 section 4.1: chromium substrate (appendix A n, k; alpha2 = 0.3 stands in "
            "for the flakes' spread) under a smooth red-tinted clear coat (n1 = 1.5, alpha1 = "
            "0.02, optical depth tau1 = 0.05/0.9/1.2 for R/G/B: fitlab's choice)"),
        Preset(
            "copper_patina", "weidlich_wilkie(rough_conductor)", {},
            {"alpha1": 0.3, "n1": _CU2O["n"], "k1": _CU2O["k"], "tau1": (1.2, 0.25, 0.8),
             "alpha2": 0.15, "n2": _CU["n"], "k2": _CU["k"]},
            "Elek 2010 section 4.2: cuprite (Cu2O) layer with the appendix A (n, k) over copper "
            "(appendix A); light-green absorption tau1 = 1.2/0.25/0.8 for R/G/B and the "
            "roughnesses alpha1 = 0.3, alpha2 = 0.15 are fitlab's choices"),
        Preset(
            "window_shade", "spongecake(fiber,fiber)", {},
            {"alpha1": 0.1, "theta_p1": 90.0, "phi_p1": 0.0, "albedo1": (0.9, 0.9, 0.7),
             "f0_1": 1.0, "tau1": 1.0,
             "alpha2": 1.0, "theta_p2": 90.0, "phi_p2": 90.0, "albedo2": (0.9, 0.9, 0.7),
             "f0_2": 1.0, "tau2": 1.0},
            "SpongeCake Table 2, window shade: two fiber layers of Tρ 1, α 0.1 over α 1.0, "
            "γ (0.9, 0.9, 0.7), no Fresnel; the orientation maps become fibers in the plane "
            "along x (layer 1) and y (layer 2): fitlab's choice"),
        Preset(
            "fabric", "spongecake(fiber,surface_z)", {},
            {"alpha1": 0.1, "theta_p1": 90.0, "phi_p1": 0.0, "albedo1": (0.7, 0.1, 0.1),
             "f0_1": 1.0, "tau1": 1.0,
             "alpha2": 0.8, "albedo2": (0.7, 0.1, 0.1),
             "f0_2": 1.0, "tau2": 5.0},
            "SpongeCake Table 2, fabric: fibers (α 0.1, Tρ 1) over surface flakes (α 0.8, "
            "Tρ 5, normal along z), γ (0.7, 0.1, 0.1), no Fresnel; the fibers' orientation map "
            "becomes fibers along x: fitlab's choice"),
        Preset(
            "plant_leaf", "spongecake(surface_z,hg,surface_z)", {},
            {"alpha1": 0.05, "albedo1": 1.0, "f0_1": 0.1, "tau1": 0.05,
             "g2": 0.7, "albedo2": (0.7, 0.1, 0.1), "tau2": 1.0,
             "alpha3": 0.05, "albedo3": 1.0, "f0_3": 1.0,
             "tau3": 0.002},
            "SpongeCake Table 2, plant: a thin specular surface layer (α 0.05, f0 0.1, Tρ 0.05), "
            "a forward-scattering HG layer (g 0.7, γ (0.7, 0.1, 0.1) as printed), a very thin "
            "specular surface layer (α 0.05, Tρ 0.002); the orientation maps become normals "
            "along z and the HG layer's thickness map Tρ 1: fitlab's choices"),
        Preset(
            "varnished_wood", "spongecake(surface_z,fiber,surface_z)", {},
            {"alpha1": 0.05, "albedo1": 1.0, "f0_1": 0.1, "tau1": 0.1,
             "alpha2": 0.2, "theta_p2": 90.0, "phi_p2": 0.0, "albedo2": (0.6, 0.35, 0.2),
             "f0_2": 1.0, "tau2": 1.0,
             "alpha3": 0.8, "albedo3": 1.0, "f0_3": 1.0, "tau3": 5.0},
            "SpongeCake Table 2, wood: a varnish of surface flakes (α 0.05, f0 0.1, Tρ 0.1), "
            "fibers (α 0.2, Tρ 1), a diffuse layer of surface flakes (α 0.8, Tρ 5); the "
            "fibers' albedo and orientation maps become γ (0.6, 0.35, 0.2) and fibers along x: "
            "fitlab's choices"),
    )
}, listing="`fitlab models`")


def get_preset(name: str) -> Preset:
    return PRESETS.get_entry(name)


def check_preset_model(name: str, model: str | None) -> Preset:
    """Preset ``name``, checked to be a preset of ``model`` when one is given (the same model
    however its name is written: ValueError saying to leave the model out otherwise)."""
    from fitlab.models import get_model

    preset = get_preset(name)
    if model and get_model(model).name != get_model(preset.model).name:
        raise ValueError(f"--preset {name} is a {preset.model} preset, not {model}; leave out "
                         "the model name")
    return preset


def presets_of(model) -> list[Preset]:
    """The presets of a registry model (a :class:`~fitlab.models.base.Model`)."""
    from fitlab.models import get_model

    return [p for p in PRESETS.values() if get_model(p.model).name == model.name]


def spongecake_presets() -> tuple[str, ...]:
    """The names of the SpongeCake presets (flake stacks: simulator scenes, ``fitlab
    multiple-lobe --preset``), known without building the model registry."""
    from fitlab.models import spongecake
    from fitlab.models.syntax import parse_call

    calls = {name: parse_call(p.model) for name, p in PRESETS.items()}
    return tuple(name for name, call in calls.items()
                 if call is not None and call.func == spongecake.NAME)


def preset_params(name: str, channel: str) -> dict:
    """The parameters of preset ``name`` for colour channel R, G or B."""
    if channel not in CHANNELS:
        raise ValueError(f"preset channel must be one of {', '.join(CHANNELS)}, got {channel!r}")
    j = CHANNELS.index(channel)
    return {k: float(v[j] if isinstance(v, tuple) else v)
            for k, v in get_preset(name).params.items()}


def rgb_preset(name: str) -> tuple[str, dict, dict]:
    """(model name, options, {channel: parameters}) of preset ``name`` for R, G and B."""
    preset = get_preset(name)
    return preset.model, dict(preset.options), {c: preset_params(name, c) for c in CHANNELS}


def preset_scene(name: str, theta_i=(0.0, 30.0, 60.0), theta_o=None) -> dict:
    """A SpongeCake preset as a simulator scene (a dict for fitlab.simulate.scene_from_dict;
    data_formats/scene_toml.md): its layers over the outside index (no interfaces), lit from
    ``theta_i`` and observed by point estimates on the in-plane arc ``theta_o`` (signed
    degrees; default both sides every 10°), delta transmission dropped (the model declares it
    apart)."""
    from fitlab.models import spongecake
    from fitlab.models.syntax import parse_call

    model, _, params = rgb_preset(name)
    if name not in spongecake_presets():
        raise ValueError(f"preset {name!r} is a {model} preset; only SpongeCake presets are "
                         "simulator scenes")
    if theta_o is None:
        theta_o = [t for t in range(-170, 180, 10) if abs(t) != 90]
    return {"format": "fitlab-scene", "version": 1, "name": f"SpongeCake preset {name}",
            **spongecake.stack_scene(parse_call(model).args, params),
            "illumination": {"theta_i": list(theta_i)},
            "detector": {"type": "inplane", "theta_o": list(theta_o), "estimator": "point"},
            "effects": {"delta": False}}
