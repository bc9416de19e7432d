"""Hemispherical maps for out-of-plane data: measured values, the model at the same directions
and their relative residual, on an azimuthal equidistant projection of wo's hemisphere."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib.colors import LogNorm, Normalize
from matplotlib.tri import Triangulation

from fitlab.report.style import CMAP_RESIDUAL, CMAP_VALUES, new_figure, styled


class MapRow(NamedTuple):
    label: str  # e.g. "θi = 45°, reflection"
    x: np.ndarray  # projected coordinates (r = θ'/90°)
    y: np.ndarray
    value: np.ndarray
    pred: np.ndarray
    floor: float  # |value| below this: no relative residual (grey)


def _frame(ax):
    for r in (1 / 3, 2 / 3, 1.0):
        t = np.linspace(0, 2 * np.pi, 181)
        ax.plot(r * np.cos(t), r * np.sin(t), color="0.5", lw=0.5)
    ax.plot([-1, 1], [0, 0], color="0.5", lw=0.5)
    ax.plot([0, 0], [-1, 1], color="0.5", lw=0.5)
    ax.text(1.02, 0.0, "φo=0°", fontsize=7, va="center")
    ax.text(0.0, 1.03, "90°", fontsize=7, ha="center")
    ax.text(2 / 3 * 0.71, 2 / 3 * 0.71, "60°", fontsize=6.5, color="0.35")
    ax.text(1 / 3 * 0.71, 1 / 3 * 0.71, "30°", fontsize=6.5, color="0.35")
    ax.set_xlim(-1.12, 1.22)
    ax.set_ylim(-1.12, 1.12)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.grid(False)


#: Residual colour range: at most this many percent.
RESIDUAL_MAX = 200.0
#: Measured directions are dotted on the maps up to this many points.
MAX_DOTS = 3000
#: Triangles with an edge longer than this angle between directions are not drawn: they would
#: bridge regions the instrument did not measure.
MAX_EDGE_DEG = 35.0


def _triangulation(row: MapRow):
    tri = Triangulation(row.x, row.y)
    theta = np.radians(90.0 * np.hypot(row.x, row.y))
    phi = np.arctan2(row.y, row.x)
    w = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    v = w[tri.triangles]  # (T, 3 corners, 3)
    cos_edge = np.sum(v * np.roll(v, 1, axis=1), axis=2).min(axis=1)
    tri.set_mask(cos_edge < np.cos(np.radians(MAX_EDGE_DEG)))
    return tri


@styled
def hemisphere_figure(rows: list, *, unit: str):
    """Rows of (data, model, relative residual) maps. Data and model share one logarithmic
    colour scale (viridis); the residual uses a diverging map centred on zero. Returns a Figure."""
    n = len(rows)
    fig = new_figure(10.6, 3.2 * n + 0.3)
    axes = fig.subplots(n, 3, squeeze=False)
    for k, row in enumerate(rows):
        tri = _triangulation(row)
        pos = np.concatenate([row.value[row.value > 0], row.pred[row.pred > 0]])
        # Robust top (99.9th percentile): a few outliers at the horizon must not set the scale.
        top = float(np.percentile(pos, 99.9)) if pos.size else 1.0
        norm = LogNorm(vmin=max(pos.min() if pos.size else top * 1e-3, top * 1e-3), vmax=top)
        for ax, vals, what in ((axes[k, 0], row.value, "data"), (axes[k, 1], row.pred, "model")):
            shown = np.clip(vals, norm.vmin, norm.vmax)
            pc = ax.tripcolor(tri, shown, norm=norm, cmap=CMAP_VALUES, shading="gouraud",
                              rasterized=True)
            if row.x.size <= MAX_DOTS:  # where the measurements are (a blur beyond that)
                ax.plot(row.x, row.y, ",", color="w", alpha=0.4, rasterized=True)
            _frame(ax)
            ax.set_title(f"{what}: {row.label}")
            fig.colorbar(pc, ax=ax, shrink=0.85, label=unit, extend="both")
        ok = (row.value > 0) & (np.abs(row.value) >= row.floor)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(ok, 100.0 * (row.pred - row.value) / row.value, 0.0)
        # Robust range: the 95th percentile of |residual|, at most RESIDUAL_MAX (a few grazing
        # points off by 100x must not wash out the rest); beyond it the colours saturate.
        lim = min(RESIDUAL_MAX, max(5.0, float(np.percentile(np.abs(rel[ok]), 95)))) \
            if ok.any() else 10.0
        rt = _triangulation(row)
        bad = ~ok[rt.triangles].all(axis=1)
        rt.set_mask(rt.mask | bad)
        ax = axes[k, 2]
        pc = ax.tripcolor(rt, np.clip(rel, -lim, lim), norm=Normalize(-lim, lim),
                          cmap=CMAP_RESIDUAL, shading="gouraud", rasterized=True)
        ax.set_facecolor("0.85")
        _frame(ax)
        ax.set_title(f"residual: {row.label}")
        fig.colorbar(pc, ax=ax, shrink=0.85, extend="both",
                     label="(model − data)/data (%)")
    return fig
