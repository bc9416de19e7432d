"""Posterior figures: corner plot of the samples, correlation matrix, MCMC trace plots."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import Normalize

from fitlab.report.style import CMAP_RESIDUAL, new_figure, styled


def _label(name, unit):
    return name if unit in ("", "1", None) else f"{name} ({unit})"


@styled
def corner_figure(samples: np.ndarray, names: list, units: list, best: np.ndarray):
    """Marginal histograms (diagonal, with the 2.5/16/50/84/97.5 percentiles) and pairwise 2-D
    histograms of posterior ``samples`` (n, d); the least-squares ``best`` fit in red."""
    d = samples.shape[1]
    size = min(2.2 * d + 0.6, 9.0)
    fig = new_figure(size, size)
    axes = fig.subplots(d, d, squeeze=False)
    q = np.percentile(samples, [2.5, 16, 50, 84, 97.5], axis=0)
    for i in range(d):
        for j in range(d):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(samples[:, i], bins=30, color="0.45", histtype="stepfilled")
                for k, ls in zip(range(5), (":", "--", "-", "--", ":")):
                    ax.axvline(q[k, i], color="#1f77b4", ls=ls, lw=0.9)
                ax.axvline(best[i], color="#d62728", lw=0.9)
                ax.set_yticks([])
                ax.set_title(f"{names[i]} = {q[2, i]:.5g} (+{q[3, i] - q[2, i]:.2g} / "
                             f"−{q[2, i] - q[1, i]:.2g})", fontsize=8)
            else:
                ax.hist2d(samples[:, j], samples[:, i], bins=30, cmap="Greys", rasterized=True)
                ax.plot(best[j], best[i], "+", color="#d62728", ms=9, mew=1.4)
            if i == d - 1:
                ax.set_xlabel(_label(names[j], units[j]))
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(_label(names[i], units[i]))
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=7)
            for lab in ax.get_xticklabels():
                lab.set_rotation(35)
    return fig


@styled
def correlation_figure(matrix, names: list, *, source: str):
    """The correlation matrix on a diverging map fixed to [−1, 1], each cell annotated."""
    c = np.asarray(matrix, dtype=float)
    d = c.shape[0]
    fig = new_figure(1.1 * d + 2.4, 0.9 * d + 1.2)
    ax = fig.add_subplot()
    im = ax.imshow(c, cmap=CMAP_RESIDUAL, norm=Normalize(-1, 1))
    for i in range(d):
        for j in range(d):
            ax.text(j, i, f"{c[i, j]:+.2f}", ha="center", va="center", fontsize=8,
                    color="w" if abs(c[i, j]) > 0.6 else "k")
    ax.set_xticks(range(d), names, rotation=30)
    ax.set_yticks(range(d), names)
    ax.grid(False)
    ax.set_title(f"correlation ({source})")
    fig.colorbar(im, ax=ax, label="correlation coefficient")
    return fig


@styled
def trace_figure(chain: np.ndarray, labels: list, *, burn: int, tau: list, log_prob=None):
    """Walker traces (steps × walkers) per coordinate, native units; burn-in shaded; the
    autocorrelation time in each panel's title."""
    steps, walkers, d = chain.shape
    rows = d + (log_prob is not None)
    fig = new_figure(8.4, 1.45 * rows + 0.6)
    axes = fig.subplots(rows, 1, squeeze=False, sharex=True)[:, 0]
    t = np.arange(steps)
    step = max(1, steps // 600)  # at most ~600 points per drawn line
    show = np.unique(np.round(np.linspace(0, walkers - 1, min(walkers, 3))).astype(int))
    series = [(chain[:, :, k], labels[k], tau[k] if k < len(tau) else None) for k in range(d)]
    if log_prob is not None:
        series.append((log_prob, "log posterior", None))
    ts = t[::step]
    for ax, (vals, label, tk) in zip(axes, series):
        finite = np.where(np.isfinite(vals), vals, np.nan)
        q = np.nanpercentile(finite[::step], [2.5, 16, 50, 84, 97.5], axis=1)
        ax.fill_between(ts, q[0], q[4], color="#1f77b4", alpha=0.2, lw=0,
                        label="95% of walkers")
        ax.fill_between(ts, q[1], q[3], color="#1f77b4", alpha=0.35, lw=0,
                        label="68% of walkers")
        ax.plot(ts, vals[::step, show], lw=0.5, alpha=0.8)
        ax.plot(ts, q[2], color="k", lw=0.8, label="walker median")
        ax.axvspan(0, burn, color="0.85", zorder=0)
        ax.set_ylabel(label, fontsize=8)
        if tk is not None:
            ax.set_title(f"{label}: autocorrelation time τ = {tk:.1f} steps "
                         f"({steps / tk:.0f} τ in the chain)" if tk else label, fontsize=8,
                         loc="left")
        lo, hi = np.nanpercentile(finite[burn:] if burn < steps else finite, [0.5, 99.5])
        pad = (hi - lo) * 0.3 or abs(hi) * 0.01 or 1.0
        ax.set_ylim(lo - pad, hi + pad)
    axes[-1].set_xlabel(f"step (grey: burn-in, first {burn} steps; blue: spread of the "
                        f"{walkers} walkers; coloured lines: {len(show)} single walkers)")
    axes[0].legend(loc="upper right", ncol=3, frameon=False, fontsize=7)
    return fig
