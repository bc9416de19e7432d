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
    band_dense: np.ndarray | None  # (5, P): 2.5, 16, 50, 84, 97.5 percentiles of the model
    floor: float  # rows below this |value| are left out of relative residuals
    predictive_dense: np.ndarray | None = None  # (5, P) of replicated data (model + noise)


def _band(ax, s: ScanSide, rel_to=None):
    """Model bands (filled) and posterior predictive bands (grey lines), clipped at 0 (a BSDF
    is not negative; the relative loss's Gaussian noise would reach below it at low values);
    ``rel_to``: draw them as % deviations from this curve (the residual panel)."""
    def tr(y):
        y = np.maximum(y, 0.0)
        if rel_to is None:
            return y
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * (y / np.where(rel_to > 0, rel_to, np.nan) - 1.0)

    if s.band_dense is not None:
        b = s.band_dense
        ax.fill_between(s.x_dense, tr(b[0]), tr(b[4]), color=BAND_COLOR, alpha=0.18, lw=0,
                        label="model: 95% posterior band")
        ax.fill_between(s.x_dense, tr(b[1]), tr(b[3]), color=BAND_COLOR, alpha=0.35, lw=0,
                        label="model: 68% posterior band")
    if s.predictive_dense is not None:
        # Where the model is below the floor the noise model is the loss's floor, not a
        # property of the sample: not drawn.
        p = np.where(s.model_dense >= s.floor, s.predictive_dense, np.nan)
        for k, ls, label in ((0, ":", "new data: 95% predictive"), (1, "--", "new data: 68% "
                                                                           "predictive")):
            ax.plot(s.x_dense, tr(p[k]), ls, color="0.35", lw=0.8, label=label)
            ax.plot(s.x_dense, tr(p[4 - k]), ls, color="0.35", lw=0.8)


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
    fig = new_figure(4.6 * ncol + 0.4, 7.0)
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
        if col == 0:
            handles, labels = lin.get_legend_handles_labels()
        ok = np.abs(s.value) >= s.floor
        rel = np.full(s.value.shape, np.nan)
        rel[ok] = 100.0 * (s.pred[ok] - s.value[ok]) / s.value[ok]
        res.axhline(0.0, color="k", lw=0.8)
        _band(res, s, rel_to=s.model_dense)
        for mask, color in ((s.fitted & ok, DATA_FIT), (~s.fitted & ok, DATA_PRED)):
            if s.sigma is not None:  # the data's own 1σ, relative
                res.errorbar(s.x[mask], rel[mask], yerr=100.0 * s.sigma[mask] / np.abs(
                    s.value[mask]), fmt="o", ms=2.4, color=color, elinewidth=0.6, capsize=0)
            else:
                res.plot(s.x[mask], rel[mask], "o", ms=2.4, color=color)
        finite = np.abs(rel[np.isfinite(rel)])
        lim = max(5.0, float(np.percentile(finite, 99)) * 1.2) if finite.size else 10.0
        res.set_ylim(-lim, lim)
        res.set_ylabel("(model − data)/data (%)")
        res.set_xlabel("in-plane angle θo from the normal (°); + forward, − backward")
        res.set_xlim(-90, 90)
        res.set_xticks(np.arange(-90, 91, 30))
    fig.legend(handles, labels, loc="outside lower center", ncol=2 if ncol == 1 else 4,
               frameon=False, fontsize=7.5)
    return fig
