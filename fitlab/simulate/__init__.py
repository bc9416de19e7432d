"""Monte Carlo ground truth for layer stacks (``fitlab simulate``).

A scene (data_formats/scene_toml.md) → :func:`load_scene` / :func:`scene_from_dict` → a
validated :class:`Scene`; the simulator itself follows in ``simulate()``.
"""

from fitlab.simulate.scene import Scene, load_scene, scene_from_dict

__all__ = ["Scene", "load_scene", "scene_from_dict"]
