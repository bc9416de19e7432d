"""Polar lobe plots of the fitted BSDF in the plane of incidence: f·|cos θo| against the
direction of wo, one half-disc for reflection (above the surface) and one for transmission
(below it), a curve per incidence angle."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib import colormaps
from matplotlib.ticker import MaxNLocator

from fitlab.report.style import CMAP_VALUES, new_figure, styled


class Lobe(NamedTuple):
    theta_i: float  # degrees
    x: np.ndarray  # signed in-plane angle (degrees), + forward
    value: np.ndarray  # f·|cos θo| (1/sr)


@styled
def lobe_figure(sides: dict, *, title: str):
    """``sides`` maps "reflection"/"transmission" to a list of Lobe. Returns a Figure."""
    names = [s for s in ("reflection", "transmission") if s in sides]
    fig = new_figure(4.4 * len(names) + 0.4, 3.5)
    cmap = colormaps[CMAP_VALUES]
    for k, side in enumerate(names):
        ax = fig.add_subplot(1, len(names), k + 1, projection="polar")
        lobes = sides[side]
        # Reflection: 0° at the top (the normal +z), forward to the right. Transmission: 0° at
        # the bottom (−z), forward to the right.
        ax.set_theta_zero_location("N" if side == "reflection" else "S")
        ax.set_theta_direction(-1 if side == "reflection" else 1)
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        top = max((float(np.max(lb.value)) for lb in lobes), default=1.0) or 1.0
        for j, lb in enumerate(lobes):
            color = cmap(0.1 + 0.8 * j / max(len(lobes) - 1, 1))
            ax.plot(np.radians(lb.x), lb.value, color=color, lw=1.4,
                    label=f"θi = {lb.theta_i:g}°")
            if side == "reflection":  # the incident direction, on the backward side
                ax.plot([np.radians(-lb.theta_i)] * 2, [0, top * 1.05], ls=":", color=color,
                        lw=1.0)
        ax.set_ylim(0, top * 1.08)
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.set_rlabel_position(-45 if side == "reflection" else 45)
        ax.set_title(f"{side}: f·|cos θo| (1/sr)")
        ax.tick_params(labelsize=7)
        handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), frameon=False)
    fig.suptitle(title, fontsize=9.5)
    return fig
