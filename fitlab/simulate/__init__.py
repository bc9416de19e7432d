"""Monte Carlo ground truth for layer stacks (``fitlab simulate``).

A scene (data_formats/scene_toml.md) → :func:`load_scene` / :func:`scene_from_dict` → a
validated :class:`Scene` → :func:`derive_effects` (what is traced and why) → :func:`simulate`
(a :class:`SimulationResult`: BSDF per bin in 1/sr, standard errors, split by bounce order).
"""

from fitlab.simulate.effects import EffectPlan, derive_effects
from fitlab.simulate.scene import Scene, load_scene, scene_from_dict
from fitlab.simulate.simulator import SimulationResult, simulate
from fitlab.simulate.walk import ORDER_CLASSES

__all__ = ["Scene", "load_scene", "scene_from_dict", "EffectPlan", "derive_effects",
           "SimulationResult", "simulate", "ORDER_CLASSES"]
