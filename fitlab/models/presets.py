"""Named parameter sets of the layered models (Elek 2010 section 4), per colour channel.

``fitlab eval --preset NAME --channel R`` and ``fitlab models`` use them; in Python,
``preset_params(name, channel)`` gives the parameter dict of one channel.

The (n, k) values are Elek 2010 appendix A (690, 550, 450 nm for R, G, B;
:data:`fitlab.fresnel.CONDUCTOR_PRESETS`). The paper gives no numbers for the roughnesses, the
coat's tint or the patina's "empirically matched light-green absorption spectrum": those below
are fitlab's choices, stated as such. The car paint's flake sparkle (a normal map) and the
patina layer's extra diffuse term are out of scope; the layering is what the presets carry.
"""

from __future__ import annotations

from typing import NamedTuple

from fitlab.fresnel import CONDUCTOR_PRESETS

CHANNELS = ("R", "G", "B")


class Preset(NamedTuple):
    name: str
    model: str
    options: dict
    #: parameter -> one value (all channels) or (R, G, B)
    params: dict
    description: str


_CR, _CU, _CU2O = (CONDUCTOR_PRESETS[k] for k in ("chromium", "copper", "cuprite"))

PRESETS = {
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
    )
}


def get_preset(name: str) -> Preset:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; presets: {', '.join(PRESETS)}") from None


def preset_params(name: str, channel: str) -> dict:
    """The parameters of preset ``name`` for colour channel R, G or B."""
    if channel not in CHANNELS:
        raise ValueError(f"preset channel must be one of {', '.join(CHANNELS)}, got {channel!r}")
    j = CHANNELS.index(channel)
    return {k: float(v[j] if isinstance(v, tuple) else v)
            for k, v in get_preset(name).params.items()}
