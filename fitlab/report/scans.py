"""In-plane scans: data against the fitted model along the plane of incidence, on linear and log
axes, with the posterior band, and the relative residual underneath."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.report.style import new_figure, styled

BAND_COLOR = "#1f77b4"
DATA_FIT = "#d62728"
DATA_PRED = "#ff7f0e"


class ScanSide(NamedTuple):
    side: str  # "reflection" or "transmission"
    x: np.ndarray  # signed in-plane angle of each data row (degrees)
    value: np.ndarray  # data (internal quantity)
    sigma: np.ndarray | None
    fitted: np.ndarray  # bool per row: in the fit subset
    pred: np.ndarray  # model at the data rows
    x_dense: np.ndarray
    model_dense: np.ndarray
    band_dense: np.ndarray | None  # (5, P): 2.5, 16, 50, 84, 97.5 percentiles
    floor: float  # rows below this |value| are left out of relative residuals


def _band(ax, s: ScanSide):
    if s.band_dense is None:
        return
    b = s.band_dense
    ax.fill_between(s.x_dense, b[0], b[4], color=BAND_COLOR, alpha=0.18, lw=0,
                    label="95% posterior band")
    ax.fill_between(s.x_dense, b[1], b[3], color=BAND_COLOR, alpha=0.35, lw=0,
                    label="68% posterior band")


def _data(ax, s: ScanSide, x, y):
    for mask, color, label in ((s.fitted, DATA_FIT, "data (fitted)"),
                               (~s.fitted, DATA_PRED, "data (predicted)")):
        if not mask.any():
            continue
        if s.sigma is not None:
            ax.errorbar(x[mask], y[mask], yerr=s.sigma[mask], fmt="o", ms=2.6, color=color,
                        elinewidth=0.6, capsize=0, label=label, zorder=3)
        else:
            ax.plot(x[mask], y[mask], "o", ms=2.6, color=color, label=label, zorder=3)


@styled
def scan_figure(sides: list, *, title: str, ylabel: str):
    """One incidence: a column per side (reflection / transmission), rows linear, log,
    residual. Returns a matplotlib Figure (no display)."""
    ncol = len(sides)
    fig = new_figure(4.6 * ncol + 0.4, 6.4)
    axes = fig.subplots(3, ncol, squeeze=False, sharex="col",
                        gridspec_kw={"height_ratios": [3, 3, 1.7]})
    for col, s in enumerate(sides):
        lin, log, res = axes[:, col]
        for ax, scale in ((lin, "linear"), (log, "log")):
            _band(ax, s)
            ax.plot(s.x_dense, s.model_dense, "-", color="k", lw=1.0, label="model (best fit)")
            _data(ax, s, s.x, s.value)
            ax.set_yscale(scale)
            ax.set_ylabel(ylabel + (" (log)" if scale == "log" else ""))
        positive = np.concatenate([s.value[s.value > 0], s.model_dense[s.model_dense > 0]])
        if positive.size:
            top = positive.max()
            log.set_ylim(max(positive.min(), top * 1e-4) * 0.7, top * 2.0)
        lin.set_title(f"{s.side}: {title}")
        if s.side == "reflection" or col == 0:
            lin.legend(loc="upper left", frameon=False)
        ok = np.abs(s.value) >= s.floor
        rel = np.full(s.value.shape, np.nan)
        rel[ok] = 100.0 * (s.pred[ok] - s.value[ok]) / s.value[ok]
        res.axhline(0.0, color="k", lw=0.8)
        if s.band_dense is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                m = np.where(s.model_dense > 0, s.model_dense, np.nan)
                res.fill_between(s.x_dense, 100 * (s.band_dense[0] / m - 1),
                                 100 * (s.band_dense[4] / m - 1), color=BAND_COLOR, alpha=0.18,
                                 lw=0)
        for mask, color in ((s.fitted & ok, DATA_FIT), (~s.fitted & ok, DATA_PRED)):
            res.plot(s.x[mask], rel[mask], "o", ms=2.4, color=color)
        finite = np.abs(rel[np.isfinite(rel)])
        lim = max(5.0, float(np.percentile(finite, 99)) * 1.2) if finite.size else 10.0
        res.set_ylim(-lim, lim)
        res.set_ylabel("(model − data)/data (%)")
        res.set_xlabel("in-plane angle θo from the normal (°); + forward, − backward")
        res.set_xlim(-90, 90)
        res.set_xticks(np.arange(-90, 91, 30))
    return fig
