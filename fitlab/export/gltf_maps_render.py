"""A map fit's glTF hand-off rendered by three.js under the capture's own geometry, texel for
texel against the input images (data_formats/stack.md, "The glTF hand-off in three.js";
``fitlab report DIR`` of a ``fitlab fit-maps --gltf`` folder; :func:`render_maps_gltf`).

For a stack row (wi, wo), three.js (headless Chromium, fitlab/export/threejs.py,
``web/gltf_views.html``) renders the file's own scene, the textured quad, under one directional
light of irradiance 1 from wi, seen by an orthographic camera from wo, into a float target
with no tone mapping: each pixel is f(wi, wo)·cos θi of the texel it shows, as three.js
computes it. The render is resampled to the texel grid: each texel's centre, placed on the quad
by the hand-off's texture coordinates (fitlab/export/gltf_maps.py, :func:`texel_centres`), is
projected by the camera's world-to-clip matrix (orthographic: affine) and the pixel under it is
that texel's value (the textures are sampled nearest, so a texel's pixels are equal); then it
is divided by cos θi, so render and input are both f in 1/sr.

Frames: fitlab's is normal +z, tangent +x; the glTF file's quad lies in glTF's x-z plane with
normal +y, u along +x and v along +z. The rotation that takes one to the other
(:data:`GLTF_FROM_FITLAB`: x -> x, z -> y, y -> -z) puts texture u along fitlab's +x and v along
fitlab's -y: image row 0 (the stack's first row, the texture's top) is the sample's +y edge, the
image as seen from above (+z) with +x to the right and +y up. A v along +y would be a mirror
(det -1), which turns every anisotropic rotation the wrong way.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.export.maps import read_maps_record

#: fitlab's frame in the glTF file's world frame: a rotation (rows: glTF x, y, z).
GLTF_FROM_FITLAB = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Stack rows rendered by default: the nearest to normal, the middle, the most grazing.
ROWS = 3
#: Render size: this many pixels across a texel (before foreshortening), within the bounds.
PIXELS_PER_TEXEL = 8
MIN_SIZE, MAX_SIZE = 64, 512
#: Rows with cos θi or cos θo below this are not rendered (a quad seen or lit edge-on).
COS_MIN = 0.1


class RowRenders(NamedTuple):
    """Stack rows rendered by three.js and resampled to the texel grid."""

    rows: np.ndarray  # (n,) the stack's row (image) indices
    angles: np.ndarray  # (n, 4) θi, φi, θo, φo in degrees
    channels: tuple[str, ...]  # the stack's
    input: np.ndarray  # (H, W, n, C) f of the input images, 1/sr (NaN: no reading)
    render: np.ndarray  # (H, W, n, C) three.js's pixel / cos θi, 1/sr
    three: str  # three.js's revision
    size: int  # pixels across each render

    def relative_difference(self) -> np.ndarray:
        """(render - input) / input per texel, row and channel (NaN where input <= 0)."""
        ok = np.isfinite(self.input) & (self.input > 0)
        return np.where(ok, (self.render - self.input) / np.where(ok, self.input, 1.0), np.nan)

    def median_relative_difference(self, mask=None) -> np.ndarray:
        """(n,) per row: the median over texels (``mask`` (H, W): those only) and channels of
        |render - input| / input."""
        d = np.abs(self.relative_difference())
        if mask is not None:
            d = np.where(np.asarray(mask, bool)[:, :, None, None], d, np.nan)
        flat = np.moveaxis(d, 2, 0).reshape(d.shape[2], -1)
        return np.array([np.median(r[np.isfinite(r)]) if np.isfinite(r).any() else np.nan
                         for r in flat])


def pick_rows(theta_i, theta_o, n: int = ROWS) -> np.ndarray:
    """``n`` rows spread from the nearest to normal to the most grazing, by max(θi, θo), then
    θi + θo, then the row's order; rows lit or seen within acos(COS_MIN) of the plane are left
    out."""
    ti, to = np.asarray(theta_i, float), np.asarray(theta_o, float)
    ok = np.flatnonzero((np.cos(np.radians(ti)) >= COS_MIN) & (np.cos(np.radians(to)) >= COS_MIN))
    if ok.size == 0:
        return ok
    order = ok[np.lexsort((ok, ti[ok] + to[ok], np.maximum(ti[ok], to[ok])))]
    picks = np.unique(np.round(np.linspace(0, len(order) - 1, min(n, len(order)))).astype(int))
    return order[picks]


def render_size(h: int, w: int) -> int:
    """Pixels across a render of an h × w texel quad."""
    return int(np.clip(PIXELS_PER_TEXEL * max(h, w), MIN_SIZE, MAX_SIZE))


def view_extent(h: int, w: int) -> float:
    """Half-width of an orthographic view that holds the quad (width 1, height h/w) from any
    direction: its half diagonal, and a margin."""
    return 0.51 * float(np.hypot(1.0, h / w))


def resample(image: np.ndarray, view_projection: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(H, W, C) values of the render ``image`` (size, size, C; row 0 at the bottom) at the
    texel centres ``centres`` (H, W, 3, world frame) projected by ``view_projection`` (4 × 4,
    world to clip); NaN where a centre falls outside the image."""
    size = image.shape[0]
    p = np.concatenate([centres, np.ones(centres.shape[:2] + (1,))], axis=-1)
    clip = p @ view_projection.T
    ndc = clip[..., :2] / clip[..., 3:4]
    col = np.floor((ndc[..., 0] + 1.0) * 0.5 * size).astype(int)
    row = np.floor((ndc[..., 1] + 1.0) * 0.5 * size).astype(int)
    inside = (col >= 0) & (col < size) & (row >= 0) & (row < size)
    out = image[np.clip(row, 0, size - 1), np.clip(col, 0, size - 1)]
    return np.where(inside[..., None], out, np.nan)


def render_stack_rows(gltf_path, stack, rows=None, *, timeout: float = 180.0) -> RowRenders:
    """Render the glTF hand-off ``gltf_path`` of a map fit of ``stack`` (fitlab.io.stack.Stack)
    at its rows ``rows`` (default :func:`pick_rows`) and resample it to the texel grid."""
    from fitlab.export import threejs
    from fitlab.export.gltf_maps import texel_centres

    rows = pick_rows(stack.theta_i, stack.theta_o) if rows is None else np.asarray(rows, int)
    if rows.size == 0:
        raise FitlabError(f"{stack.path}: no row of the stack is lit and seen within "
                          f"{np.degrees(np.arccos(COS_MIN)):.0f}° of the normal")
    wi, wo = stack.directions()
    wi, wo = wi[rows], wo[rows]
    H, W = stack.shape
    size = render_size(H, W)
    images, vp, report = threejs.render_views(
        gltf_path, wi @ GLTF_FROM_FITLAB.T, wo @ GLTF_FROM_FITLAB.T, size=size,
        extent=view_extent(H, W), timeout=timeout)
    centres = texel_centres(H, W)
    C = len(stack.channel_names)
    render = np.stack([resample(images[k], vp[k], centres) / wi[k, 2]
                       for k in range(len(rows))], axis=2)[..., :C]  # Y: the grey R
    angles = np.stack([stack.theta_i, stack.phi_i, stack.theta_o, stack.phi_o], axis=1)[rows]
    return RowRenders(rows, angles, tuple(stack.channel_names),
                      stack.values[:, :, rows, :].astype(float), render,
                      str(report.get("three", "?")), size)


def gltf_handoff(folder, record: dict | None = None) -> tuple[Path | None, str]:
    """(the folder's glTF document, "") or (None, why there is none)."""
    from fitlab.export.gltf_maps import DOCUMENT

    folder = Path(folder)
    rec = read_maps_record(folder) if record is None else record
    handoff = rec.get("handoff")
    g = handoff.get("gltf") if isinstance(handoff, dict) else None
    if not isinstance(g, dict) or g.get("written") is not True:
        why = g.get("reason") if isinstance(g, dict) else None
        return None, f"the fit has no glTF hand-off ({why or 'fitlab fit-maps --gltf writes it'})"
    if g.get("document") != DOCUMENT:
        raise InputFileError(folder / "maps.json", f"names the glTF document "
                             f"{g.get('document')!r}; fitlab fit-maps writes {DOCUMENT}",
                             column="handoff.gltf.document",
                             hint="give a folder written by fitlab fit-maps")
    path = folder / DOCUMENT
    if not path.is_file():
        raise InputFileError(path, "is missing (maps.json lists it)",
                             hint="write the folder again with fitlab fit-maps --gltf")
    return path, ""


def render_maps_gltf(folder, rows=None, *, record: dict | None = None,
                     timeout: float = 180.0) -> RowRenders:
    """The glTF hand-off of the ``fitlab fit-maps --gltf`` folder ``folder`` rendered by
    three.js at rows ``rows`` of its stack (default: near normal, middle, grazing), resampled to
    the texel grid, beside the stack's images (:class:`RowRenders`); raises
    :class:`fitlab.export.threejs.RenderError` where three.js or Chromium is missing."""
    from fitlab.io.stack import read_stack

    folder = Path(folder)
    rec = read_maps_record(folder) if record is None else record
    gltf, why = gltf_handoff(folder, rec)
    if gltf is None:
        raise FitlabError(f"{folder}: {why}")
    where = rec.get("stack")
    if not (isinstance(where, dict) and isinstance(where.get("folder"), str)
            and isinstance(where.get("sha256"), str)):
        raise InputFileError(folder / "maps.json", "lacks the stack's folder and SHA-256",
                             column="stack", hint="give a folder written by fitlab fit-maps")
    stack = read_stack((folder / where["folder"]).resolve())
    if stack.sha256 != where["sha256"]:
        raise FitlabError(f"{folder}: the stack at {where['folder']} is not the one fitted "
                          "(its SHA-256 differs)")
    if rows is not None:
        rows = np.asarray(rows, int)
        if rows.size == 0 or rows.min() < 0 or rows.max() >= stack.n_images:
            raise FitlabError(f"rows: give indices of the stack's images, 0 to "
                              f"{stack.n_images - 1}")
    return render_stack_rows(gltf, stack, rows, timeout=timeout)


__all__ = ["GLTF_FROM_FITLAB", "RowRenders", "pick_rows", "render_size", "view_extent",
           "resample", "render_stack_rows", "gltf_handoff", "render_maps_gltf"]
