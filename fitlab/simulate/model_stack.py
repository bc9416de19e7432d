"""A model's own layer stack, simulated: the pieces that compare a model with the Monte Carlo
simulation of the stack it approximates (``Model.scene_of``; data_formats/layered_models.md).

``fitlab tradeoffs`` (its "layered physics" knob) and the fit's model check
(:mod:`fitlab.fitting.model_check`) both use them: the scene with every effect a model may
approximate traced (:func:`stack_scene`), the simulation at given rows or on an arc
(:func:`rows_scene`, :func:`with_detector`), and the model at the simulation's rows as the
simulator tallies them (:func:`model_at_rows`).
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import numpy as np

#: The cone of the simulator's detectors where point estimates are impossible (smooth
#: interfaces between the top and the first rough boundary).
ACCEPTANCE_SR = 0.005


def full_physics(scene: dict) -> dict:
    """The stack with every effect a model may approximate traced: all bounces and every
    order of volume scattering (the delta components stay as the model declares them)."""
    return {**scene, "effects": {**scene.get("effects", {}), "max_bounces": "all",
                                 "volume_scattering": "multiple"}}


def stack_scene(model, params: dict, options: dict) -> dict:
    """The scene dict (no illumination, no detector) of ``model``'s stack at ``params`` (one
    channel's, {name: float}) and ``options``, every effect traced (:func:`full_physics`).
    Raises ValueError saying why where the model names no stack the simulator traces."""
    scene_of = getattr(model, "scene_of", None)
    if scene_of is None:
        raise ValueError(f"{model.name} names no layer stack for the simulator "
                         "(Model.scene_of; data_formats/layered_models.md)")
    s = scene_of(params, options)  # ValueError: values the simulator cannot express
    if s is None:
        raise ValueError(f"{model.name} with these options has no stack the simulator traces")
    return full_physics(s)


def is_layered(scene: dict) -> bool:
    """Whether a model's scene is a layered stack: a medium of some thickness, or two or more
    boundaries (interfaces, a substrate). A single interface, a bare substrate behind the clear
    film an opaque substrate needs, is not."""
    items = scene.get("stack", [])
    if any(i.get("type") == "medium" and float(i.get("thickness", 0.0)) > 0 for i in items):
        return True
    boundaries = sum(i.get("type") == "interface" for i in items) + ("substrate" in scene)
    return boundaries >= 2


def with_detector(scene: dict, detector: dict):
    """The validated Scene of ``scene`` with ``detector`` (its ``estimator`` point), or, where
    the stack allows no point estimates, with cones of :data:`ACCEPTANCE_SR`."""
    from fitlab.errors import InputFileError
    from fitlab.simulate import scene_from_dict

    try:
        return scene_from_dict({**scene, "detector": {**detector, "estimator": "point"}})
    except InputFileError:
        return scene_from_dict({**scene, "detector": {**detector,
                                                      "acceptance_sr": ACCEPTANCE_SR}})


@contextlib.contextmanager
def rows_scene(scene: dict, rows):
    """The validated Scene of ``scene`` at the directions of Measurement ``rows`` (a
    measurement detector, :func:`with_detector`), for as many ``simulate`` runs as the context
    lasts: the rows travel to the simulator as a temporary measurement CSV, written once and
    removed when the context ends."""
    from fitlab.io.measurement import format_measurement_csv

    with tempfile.TemporaryDirectory(prefix="fitlab-stack-") as tmp:
        path = Path(tmp) / "rows.csv"
        path.write_text(format_measurement_csv(rows), encoding="utf-8")
        yield with_detector(scene, {"type": "measurement", "file": str(path)})


def model_at_rows(evaluate, m) -> np.ndarray:
    """The model at a simulation's rows (Measurement ``m``), averaged over each row's cone
    (cos-weighted) as the simulator tallies, or at the points (fitlab.aperture's rules);
    ``evaluate(wi, wo)`` gives (N, channels)."""
    from fitlab.aperture import row_rule

    if m.aperture_deg is None or not np.any(m.aperture_deg > 0):
        return evaluate(m.wi, m.wo)
    nodes_i, nodes_o, w = row_rule(m.wi, m.wo, 6, aperture_deg=m.aperture_deg)
    R, K = w.shape
    v = evaluate(nodes_i.reshape(-1, 3), nodes_o.reshape(-1, 3)).reshape(R, K, -1)
    return np.einsum("rk,rkc->rc", w, v)


__all__ = ["ACCEPTANCE_SR", "full_physics", "is_layered", "model_at_rows", "rows_scene",
           "stack_scene", "with_detector"]
