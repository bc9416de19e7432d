"""Monte Carlo ground truth for layer stacks (``fitlab simulate``).

A scene (data_formats/scene_toml.md) → :func:`load_scene` / :func:`scene_from_dict` → a
validated :class:`Scene` → :func:`derive_effects` (what is traced and why) → :func:`simulate`
(a :class:`SimulationResult`: BSDF per bin in 1/sr, standard errors, split by bounce order).

The names below are imported at their first use (PEP 562): a submodule (``engine`` for the
devices, ``walk`` for the launch size) loads without the rest.
"""

from fitlab._lazy import exports

#: Public name -> the module that defines it.
_SOURCES = {"Scene": "scene", "load_scene": "scene", "scene_from_dict": "scene",
            "EffectPlan": "effects", "derive_effects": "effects",
            "SimulationResult": "simulator", "simulate": "simulator", "ORDER_CLASSES": "walk"}

__all__ = ["Scene", "load_scene", "scene_from_dict", "EffectPlan", "derive_effects",
           "SimulationResult", "simulate", "ORDER_CLASSES"]


__getattr__, __dir__ = exports(__name__, _SOURCES)
