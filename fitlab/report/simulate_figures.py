"""Figures of ``fitlab simulate`` studies (matplotlib stays inside fitlab.report)."""

from __future__ import annotations

import numpy as np

from fitlab.report.style import new_figure, styled


@styled
def se_time_figure(curve, title="fitlab simulate: standard error vs time"):
    """Standard error against wall time, log-log, with the 1/sqrt(time) slope for reference.

    ``curve``: rows (paths, time_s, median relative standard error of the bins, standard error of
    the reflected flux). Returns a Figure."""
    curve = np.asarray(curve, dtype=float)
    paths, t, rel, se_flux = curve.T
    fig = new_figure(6.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    ax.loglog(t, rel, "o-", label="median relative standard error of the bins")
    ax.loglog(t, se_flux, "s-", label="standard error of the reflected flux")
    ref = rel[-1] * np.sqrt(t[-1] / t)
    ax.loglog(t, ref, "k:", linewidth=0.8, label="∝ 1/√time")
    for x, y, n in zip(t, rel, paths):
        ax.annotate(f"{int(n):,}", (x, y), textcoords="offset points", xytext=(3, 4), fontsize=7)
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("wall time of the warm run (s)")
    ax.set_ylabel("standard error (bins: relative; flux: absolute)")
    ax.set_title(title)
    ax.legend(loc="lower left")
    return fig
