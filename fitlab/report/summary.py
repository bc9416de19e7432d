"""The report's first screen: the answer before the evidence. The model, the parameters with
their intervals (least squares or block bootstrap, and the MCMC credible interval), the fit
error, a one-sentence verdict read from the fit's statuses (:mod:`fitlab.fitting.status`) and
the key figure, the data against the best fit."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from matplotlib import colormaps

from fitlab.fitting.status import Status, channel_statuses
from fitlab.metrics import fit_error_of, fit_error_text
from fitlab.report.html import esc
from fitlab.report.style import CMAP_VALUES, new_figure, styled

#: The first screen's layout (added to the page's style sheet): the answer on the left, the key
#: figure on the right; one column on a narrow screen.
CSS = """
.lead { display: grid; grid-template-columns: minmax(0, 1fr) 520px; gap: 0 1.2em;
        align-items: start; }
@media (max-width: 1000px) { .lead { grid-template-columns: minmax(0, 1fr); } }
.lead figure { margin: 0; }
.lead figure img { width: 100%; }
.lead table { margin: .3em 0 .5em 0; }
.verdict { font-size: 1.05em; padding: .45em .8em; margin: .2em 0 .7em 0; }
.verdict.ok { background: #e6f4ea; border-left: 6px solid #2e7d32; }
.verdict.bad { background: #fdecea; border-left: 6px solid #c62828; }
.verdict.unknown { background: #eef4fb; border-left: 6px solid #4a7ab5; }
.fit-error { margin: .3em 0; }
.lead .model { margin: .2em 0 .3em 0; }
"""


# --------------------------------------------------------------------------------------------
# The fit error: one function, so that the report reads one figure everywhere
# --------------------------------------------------------------------------------------------


def fit_error(fit: dict) -> dict | None:
    """A channel's fit error as its parameter file holds it (``statistics.fit_error``, or for an
    older file ``rms_relative_error_fit`` with its own floor rule: fitlab.metrics.fit_error_of).
    Every figure of the fit error the first screen shows comes from here."""
    return fit_error_of(fit["statistics"])


# --------------------------------------------------------------------------------------------
# Numbers
# --------------------------------------------------------------------------------------------


def _digits(value, width) -> int:
    """Significant digits of ``value`` whose last digit is at most 2% of ``width`` (an
    interval's), 3 to 7."""
    if not width or not np.isfinite(width) or not value:
        return 5
    last = math.floor(math.log10(abs(width) / 50.0))  # decade of the last digit shown
    return int(min(7, max(3, math.floor(math.log10(abs(value))) - last + 1)))


def _num(x, digits=5) -> str:
    return "n/a" if x is None else f"{float(x):.{digits}g}"


def _interval(lo, hi, value) -> str:
    d = _digits(value, hi - lo)
    return f"[{_num(lo, d)}, {_num(hi, d)}]"


def intervals_68(p: dict) -> dict:
    """The 68% intervals a free parameter has: ``least squares`` (± 1 standard error),
    ``bootstrap`` and ``MCMC`` (16th to 84th percentile), each (lo, hi)."""
    out = {}
    if p.get("stderr") is not None and np.isfinite(p["stderr"]):
        out["least squares"] = (p["value"] - p["stderr"], p["value"] + p["stderr"])
    if p.get("bootstrap"):
        out["bootstrap"] = (p["bootstrap"]["p16"], p["bootstrap"]["p84"])
    if p.get("posterior"):
        out["MCMC"] = (p["posterior"]["p16"], p["posterior"]["p84"])
    return out


#: Two 68% intervals agree when neither is wider than this factor times the other and their
#: centres lie within half the wider one's width.
AGREE_WIDTH_RATIO = 1.5


def disagreement(fits) -> str | None:
    """The worst disagreement between a free parameter's 68% intervals (least squares or
    bootstrap against MCMC, least squares against bootstrap), in words, or None."""
    worst, text = 1.0, None
    for fit in fits:
        for name, p in fit["parameters"].items():
            if p.get("fixed"):
                continue
            iv = intervals_68(p)
            labels = list(iv)
            for i, a in enumerate(labels):
                for b in labels[i + 1:]:
                    (a0, a1), (b0, b1) = iv[a], iv[b]
                    wa, wb = a1 - a0, b1 - b0
                    if wa <= 0 or wb <= 0:
                        continue
                    ratio = max(wa / wb, wb / wa)
                    offset = abs((a0 + a1) - (b0 + b1)) / 2 / max(wa, wb)
                    score = max(ratio / AGREE_WIDTH_RATIO, 2.0 * offset)
                    if score > worst:
                        worst = score
                        wide, narrow = (a, b) if wa >= wb else (b, a)
                        text = (f"the {wide} interval of {name} is {ratio:.2g}× as wide as the "
                                f"{narrow} one" if ratio > AGREE_WIDTH_RATIO else
                                f"the {a} and {b} intervals of {name} are offset by "
                                f"{offset:.2g} of their width")
    return text


# --------------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------------


def _at_bound(fit) -> str:
    names = [f"{n} = {_num(min(p['bounds'], key=lambda b: abs(b - p['value'])), 4)}"
             for n, p in fit["parameters"].items() if p.get("at_bound")]
    return ("least squares ended at the bound " if len(names) == 1 else
            "least squares ended at the bounds ") + ", ".join(names)


#: What each status says went wrong, as a clause of the verdict.
PROBLEMS = {
    Status.MAX_ITERATIONS: lambda fit: "least squares stopped at its iteration limit",
    Status.NON_FINITE: lambda fit: "the cost is not finite where least squares ended",
    Status.STARTS_LOST: lambda fit: "some least-squares starts ended at NaN or inf",
    Status.STARTS_DISAGREE: lambda fit: "starts reached equally good fits at different "
                                        "parameters",
    Status.AT_BOUND: _at_bound,
    Status.CHAIN_UNTRUSTED: lambda fit: "the MCMC chain is too short or fails its diagnostics",
    Status.MISFIT: lambda fit: "the model does not describe the data within their noise",
    Status.BOOTSTRAP_FAILED: lambda fit: "too few bootstrap refits ended at finite values",
    Status.APERTURE_INACCURATE: lambda fit: "the aperture quadrature moves the optimum beyond "
                                            "its tolerance",
    Status.FOLDS_FAILED: lambda fit: "a cross-validation fold could not be fitted",
    Status.NO_DATA: lambda fit: "there was nothing to fit (no readings)",
}


def _try(status: Status) -> str:
    """The status's advice, less a restatement of the problem before its colon."""
    advice = status.advice
    if status in (Status.MISFIT, Status.STARTS_DISAGREE):
        advice = advice.split(": ", 1)[-1]
    return advice


class Verdict(NamedTuple):
    trusted: bool | None  # None: the file records too little to say (an older fitlab's)
    sentence: str  # plain text, one sentence


def verdict(fits) -> Verdict:
    """One sentence from the statuses of every channel (``fits``: the record's ``fits``): what
    limits trust and what to try, or why the fit can be used as it stands."""
    multi = len(fits) > 1
    problems, first = {}, None  # clause -> channels
    for fit in fits:
        for s in channel_statuses(fit):
            if s.ok:
                continue
            first = first or s
            problems.setdefault(PROBLEMS[s](fit), []).append(fit["channel"])
    if problems:
        clauses = [c + (f" (channel{'s' if len(chs) > 1 else ''} {', '.join(chs)})"
                        if multi and len(chs) < len(fits) else "")
                   for c, chs in problems.items()]
        return Verdict(False, f"Not trusted: {'; '.join(clauses)}; try: {_try(first)}.")
    old = not any(fit.get("solver") for fit in fits)
    if old:
        parts = ["this parameter file of an older fitlab records neither the solver's stop nor "
                 "the goodness checks (refit to get them)"]
    else:
        parts = ["converged"]
        if all((fit.get("goodness") or {}).get("describes_data") for fit in fits):
            parts.append("the model describes the data within their noise")
    kinds = sorted({k for fit in fits for p in fit["parameters"].values()
                    if not p.get("fixed") for k in intervals_68(p)},
                   key=["least squares", "bootstrap", "MCMC"].index)
    off = disagreement(fits)
    if off:
        parts.append(f"but {off} (quote the wider)")
    elif len(kinds) > 1:
        parts.append(f"the {' and '.join(k.replace(' ', '-') for k in kinds)} intervals agree")
    elif kinds:
        parts.append(f"{kinds[0]} intervals only")
    text = ", ".join(parts[:-1]) + (", and " if len(parts) > 2 and not off else
                                    ("; " if old else ", ") if len(parts) > 1 else "") + parts[-1]
    return Verdict(None, f"Not checked: {text}.") if old else \
        Verdict(True, f"Trustworthy: {text}.")


# --------------------------------------------------------------------------------------------
# The parameter table of the first screen
# --------------------------------------------------------------------------------------------


def parameter_table(fits) -> tuple[list, list]:
    """(header, rows) of the first screen's parameter table: per parameter its best fit, the
    least-squares 68% interval (the bootstrap's where the fit ran one: it accounts for misfit)
    and the MCMC 68% credible interval."""
    multi = len(fits) > 1
    boot = any(p.get("bootstrap") for f in fits for p in f["parameters"].values())
    mcmc = any(p.get("posterior") for f in fits for p in f["parameters"].values())
    header = (["channel"] if multi else []) + [
        "parameter", "best fit",
        "68% interval (bootstrap)" if boot else "68% interval (least squares)"]
    header += ["68% credible (MCMC)"] if mcmc else []
    header += ["unit"]
    rows = []
    for fit in fits:
        for name, p in fit["parameters"].items():
            row = [fit["channel"]] if multi else []
            iv = intervals_68(p)
            if p.get("fixed"):
                row += [name, _num(p["value"], 6), "fixed"] + (["fixed"] if mcmc else [])
            else:
                first = iv.get("bootstrap") or iv.get("least squares")
                width = (first[1] - first[0]) if first else None
                value = _num(p["value"], _digits(p["value"], width) if width else 6)
                if p.get("at_bound"):
                    value += " (at a bound)"
                cell = "n/a"
                if first:
                    cell = _interval(*first, p["value"]) + (
                        " (least squares)" if boot and "bootstrap" not in iv else "")
                row += [name, value, cell]
                if mcmc:
                    row.append(_interval(*iv["MCMC"], p["value"]) if "MCMC" in iv else
                               "no MCMC")
            unit = p.get("unit", "")
            row.append("" if unit == "1" else unit)
            rows.append(row)
    return header, rows


# --------------------------------------------------------------------------------------------
# The key figure: the data against the best fit
# --------------------------------------------------------------------------------------------


class Curve(NamedTuple):
    label: str  # the incidence, e.g. "θi = 30°"
    x_dense: np.ndarray  # signed in-plane angle (degrees)
    model_dense: np.ndarray  # the best fit along it
    x: np.ndarray  # the in-plane data rows' signed angles
    value: np.ndarray
    fitted: np.ndarray  # bool per data row


class Scatter(NamedTuple):
    label: str
    value: np.ndarray  # data
    pred: np.ndarray  # the best fit at the rows
    fitted: np.ndarray


def _log_limits(values):
    pos = np.concatenate([v[np.isfinite(v) & (v > 0)] for v in values] or [np.ones(1)])
    if not pos.size:
        return None
    top = pos.max()
    return max(pos.min(), top * 1e-4) * 0.7, top * 2.0


@styled
def fit_figure(panels: list, *, ylabel: str, title: str):
    """The data against the best fit at a glance: per panel (``(side, [Curve])``, or
    ``("all rows", [Scatter])`` for data with no row in the plane of incidence) the data (filled
    markers: fitted rows, open: predicted) and the model (lines), on a logarithmic axis, a colour
    per incidence."""
    fig = new_figure(5.6, 0.55 + 2.55 * len(panels))
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    cmap = colormaps[CMAP_VALUES]
    for ax, (side, items) in zip(axes, panels):
        for j, it in enumerate(items):
            color = cmap(0.1 + 0.75 * j / max(len(items) - 1, 1))
            if isinstance(it, Scatter):
                for mask, face in ((it.fitted, color), (~it.fitted, "none")):
                    ax.plot(it.value[mask], it.pred[mask], "o", ms=2.6, mec=color, mfc=face,
                            mew=0.7, label=it.label if face is color else None)
                continue
            ax.plot(it.x_dense, it.model_dense, "-", color=color, lw=1.1, label=it.label)
            for mask, face in ((it.fitted, color), (~it.fitted, "none")):
                ax.plot(it.x[mask], it.value[mask], "o", ms=3.0, mec=color, mfc=face, mew=0.8)
        if side == "all rows":
            lim = _log_limits([i.value for i in items] + [i.pred for i in items])
            ax.set_xscale("log")
            ax.set_yscale("log")
            if lim:
                ax.set_xlim(*lim)
                ax.set_ylim(*lim)
                ax.plot(lim, lim, "-", color="k", lw=0.8, label="model = data")
            ax.set_xlabel(f"data: {ylabel}")
            ax.set_ylabel(f"best fit: {ylabel}")
            ax.set_title(f"best fit against data, every row ({title})")
        else:
            ax.set_yscale("log")
            lim = _log_limits([i.value for i in items] + [i.model_dense for i in items])
            if lim:
                ax.set_ylim(*lim)
            ax.set_xlim(-90, 90)
            ax.set_xticks(np.arange(-90, 91, 30))
            ax.set_xlabel("in-plane angle θo from the normal (°); + forward, − backward")
            ax.set_ylabel(f"{ylabel} (log)")
            ax.set_title(f"{side}: data (points) and best fit (lines), {title}")
        ax.legend(loc="best", fontsize=7, frameon=False,
                  ncol=2 if len(items) > 3 else 1)
    return fig


def verdict_html(v: Verdict, warnings: int) -> str:
    more = (f' <a href="#warnings">{warnings} warning{"s" if warnings > 1 else ""} '
            "below</a>." if warnings else "")
    cls = {True: "ok", False: "bad", None: "unknown"}[v.trusted]
    return f'<p id="verdict" class="verdict {cls}"><strong>{esc(v.sentence)}</strong>{more}</p>\n'


__all__ = ["fit_error", "verdict", "Verdict", "parameter_table",
           "fit_figure", "Curve", "Scatter", "verdict_html", "intervals_68", "disagreement",
           "PROBLEMS", "CSS"]


# --------------------------------------------------------------------------------------------
# The first screen
# --------------------------------------------------------------------------------------------

#: The key figure: at most this many incidences (evenly chosen), one colour each.
KEY_INCIDENCES = 4


def key_panels(inp, ch, preds) -> list:
    """The panels of :func:`fit_figure` for one channel: per side with in-plane data, the
    data and the best fit at up to KEY_INCIDENCES incidences; with no in-plane row at all, the
    best fit against the data at every row."""
    from fitlab.report import geometry as geo
    from fitlab.report.inputs import prediction

    m = inp.measurement
    incs = geo.pick_evenly(geo.incidences(m, ch.rows), KEY_INCIDENCES)
    panels = {}
    for inc in incs:
        sel = np.isin(ch.rows, inc.rows)
        rows = ch.rows[sel]
        mask, x = geo.in_plane(m, rows)
        sides = geo.side_of(m, rows)
        label = f"θi = {inc.theta_i:.4g}°" + (f", φi = {inc.phi_i:.4g}°" if inc.phi_i else "")
        for side in (geo.REFLECTION, geo.TRANSMISSION):
            keep = mask & (sides == side)
            if not keep.any():
                continue
            order = np.argsort(x[keep], kind="stable")
            xd, wi, wo = geo.dense_scan(inc.theta_i, inc.phi_i, side)
            panels.setdefault(side, []).append(Curve(
                label, xd, prediction(inp, ch, wi, wo), x[keep][order],
                m.value[rows[keep][order]], ch.fitted[sel][keep][order]))
    if panels:
        return [(side, panels[side]) for side in (geo.REFLECTION, geo.TRANSMISSION)
                if side in panels]
    out = []
    for inc in incs:
        sel = np.isin(ch.rows, inc.rows)
        out.append(Scatter(f"θi = {inc.theta_i:.4g}°", m.value[ch.rows[sel]], preds[sel],
                           ch.fitted[sel]))
    return [("all rows", out)]


def _percentile_note(fits) -> str:
    """How the percentile intervals the fits hold are made (bootstrap, MCMC): only those."""
    from fitlab.report.goodness import has_bootstrap

    kinds = [k for k, there in (
        ("bootstrap", any(has_bootstrap(f) for f in fits)),
        ("MCMC", any(p.get("posterior") for f in fits for p in f["parameters"].values())))
        if there]
    if not kinds:
        return ""
    what = " or ".join({"bootstrap": "the refits", "MCMC": "the posterior"}[k] for k in kinds)
    return f"; {', '.join(kinds)}: 16th to 84th percentile of {what}"


def lead_html(inp, preds, figure, warnings: int, value_label: str) -> str:
    """The first screen: verdict, model, parameters with their intervals, fit error, and the
    key figure of the first channel (``preds``: its predictions at its rows; ``figure``: the
    report's ``figure(name, fig, caption, alt)``)."""
    from pathlib import Path

    from fitlab.report import geometry as geo
    from fitlab.report.html import table_html

    rec = inp.record
    fits = [ch.fit for ch in inp.channels]
    model = rec["model"]
    opts = ", ".join(f"{k}={v}" for k, v in sorted(model.get("options", {}).items()))
    data = rec["data"]
    subset = f" ({data['fit_subset']})" if data.get("fit_subset") else ""
    out = verdict_html(verdict(fits), warnings)
    out += (f'<p class="model"><strong>Model:</strong> {esc(model["name"])} '
            f"({esc(model.get('lobes', ''))}{'; ' + esc(opts) if opts else ''}), "
            f"{esc(rec.get('loss'))} loss, fitted to {esc(data.get('rows_fitted'))} of "
            f"{esc(data.get('rows'))} rows{esc(subset)} of "
            f"<code>{esc(Path(inp.data_path).name)}</code>.</p>\n")
    header, rows = parameter_table(fits)
    numeric = tuple(range(len(header) - 1))[1 + (len(fits) > 1):]
    out += '<div id="summary-parameters">' + table_html(header, rows, numeric=numeric) \
        + "</div>\n"
    out += ('<p class="small">68% intervals: least squares, the best fit ± 1 standard error'
            + _percentile_note(fits) + '. Every interval, the 95% ones and the bounds: '
            f'<a href="#parameters-{esc(inp.channels[0].name)}">Parameters</a>.</p>\n')
    multi = len(inp.channels) > 1
    errs = "".join((f"<br>channel {esc(ch.name)}: " if multi else " ")
                   + esc(fit_error_text(fit_error(ch.fit)))
                   for ch in inp.channels)
    out += f'<p id="fit-error" class="fit-error"><strong>Fit error:</strong>{errs}.</p>\n'
    ch = inp.channels[0]
    panels = key_panels(inp, ch, preds)
    title = f"channel {ch.name}"
    fig = fit_figure(panels, ylabel=value_label, title=title)
    scatter = panels[0][0] == "all rows"
    n_inc = len(geo.incidences(inp.measurement, ch.rows))
    cap = ("The fit against the data, channel " + ch.name + ": " +
           ("the best fit against the measured value at every row (log–log; on the diagonal "
            "the model equals the data), a colour per incidence" if scatter else
            "the rows in the plane of incidence (points; filled: fitted rows, open: predicted "
            "rows) and the best fit along it (lines), a colour per incidence, on a logarithmic "
            "axis")
           + (f" ({KEY_INCIDENCES} of the {n_inc} incidences, evenly spread)"
              if n_inc > KEY_INCIDENCES else "")
           + ". The scans below show each incidence with its residuals and posterior bands.")
    alt = f"Data and best fit of channel {ch.name} for {len(panels[0][1])} incidences"
    key = figure(f"fit_{ch.name}", fig, cap, alt)
    return (f'<div class="lead">\n<div class="answer">\n{out}</div>\n{key}</div>\n')
