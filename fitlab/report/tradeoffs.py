"""The tradeoffs report: ``tradeoffs.json`` (every number), ``pareto.png``/``.svg`` (error
against time per knob group, the Pareto front drawn) and ``index.html`` in the style of
``fitlab report``, written atomically into one folder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.ticker import NullFormatter

from fitlab.report.html import FigureEntry, document, esc, figure_html, note_html, paragraph, table_html
from fitlab.report.style import new_figure, render, styled

#: The error each group's Pareto plot shows (the first the variants have).
ERROR_AXES = ("f_rel_rms", "albedo_abs_max", "interval_width_rel_dev")
ERROR_LABELS = {"f_rel_rms": "relative RMS error of f·cos θo",
                "albedo_abs_max": "largest albedo error (absolute)",
                "interval_width_rel_dev": "interval width deviation (relative)"}


def _error_of(v) -> tuple[str, float] | None:
    for k in ERROR_AXES:
        x = v.errors.get(k)
        if x is not None and np.isfinite(x):
            return k, float(x)
    return None


def pareto_front(points):
    """Indices of the points (time, error) no other point beats in both."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


@styled
def pareto_figure(res):
    """One panel per knob: its settings' error against their time (log–log), the Pareto front
    joined and labelled; settings with no error (the reference itself) are left out."""
    knobs = []
    for v in res.variants:
        e = _error_of(v)
        if e is not None and e[1] > 0 and np.isfinite(v.seconds) and v.knob not in knobs:
            knobs.append(v.knob)
    cols = 3
    rows = max(1, -(-len(knobs) // cols))
    fig = new_figure(10.5, 2.9 * rows)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, k in zip(axes, knobs):
        kv = [v for v in res.variants if v.knob == k and _error_of(v) is not None
              and _error_of(v)[1] > 0 and np.isfinite(v.seconds)]
        metric = _error_of(kv[0])[0]
        kv = [v for v in kv if _error_of(v)[0] == metric]
        t = np.array([v.seconds for v in kv])
        e = np.array([_error_of(v)[1] for v in kv])
        ax.scatter(t, e, s=16, color="#4a7ab5", zorder=3)
        front = pareto_front(list(zip(t, e)))
        ax.plot(t[front], e[front], lw=0.9, color="#c9302c", zorder=2)
        for i in front:
            ax.annotate(kv[i].setting, (t[i], e[i]), fontsize=6, xytext=(3, 2),
                        textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        # at least a decade in error and half a decade in time, so narrow ranges stay legible
        lo, hi = e.min(), e.max()
        if hi / lo < 10:
            mid = np.sqrt(lo * hi)
            ax.set_ylim(mid / np.sqrt(10) / 1.3, mid * np.sqrt(10) * 1.3)
        lo, hi = t.min(), t.max()
        if hi / lo < 3:
            mid = np.sqrt(lo * hi)
            ax.set_xlim(mid / np.sqrt(3) / 1.2, mid * np.sqrt(3) * 1.2)
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(f"time (s {kv[0].time_unit})")
        ax.set_ylabel(ERROR_LABELS[metric])
        ax.set_title(f"{k} ({kv[0].group})")
    for ax in axes[len(knobs):]:
        ax.set_visible(False)
    return fig


def _fmt(x) -> str:
    if x is None:
        return "—"
    if isinstance(x, float):
        if not np.isfinite(x):
            return "—"
        return f"{x:.3g}"
    return str(x)


def _rows(res):
    rows = []
    for v in res.variants:
        e = v.errors
        rows.append([v.group, v.knob, v.setting + (" (current)" if v.current else ""),
                     _fmt(e.get("f_rel_rms")), _fmt(e.get("f_rel_max")),
                     _fmt(e.get("albedo_abs_max")), _fmt(e.get("psnr_db")),
                     _fmt(e.get("ssim")), _fmt(v.seconds), v.time_unit,
                     ", ".join(f"{k} {_fmt(x)}" for k, x in v.cost.items() if x is not None),
                     v.reference])
    return rows


def page(res, figure: FigureEntry) -> str:
    m = res.material
    params = "; ".join(f"{c}: " + ", ".join(f"{k} = {x:.6g}" for k, x in p.items())
                       for c, p in m["parameters"].items())
    head = (paragraph(f"Material: {m['model']} ({', '.join(f'{k}={v}' for k, v in m['options'].items()) or 'no options'}); {params}."
                      + (f" From the fit {m['fit']}." if m.get("fit") else "")
                      + "".join(f" The fit's own error, channel {c}: {e['text']}."
                                for c, e in (m.get("fit_error") or {}).items()))
            + paragraph(f"Errors are measured on {res.directions}; albedos at θi = 0, 30, 60, "
                        "80° by quadrature; lobe images (64², f·cos θo over the projected "
                        "hemisphere) at θi = 0, 30, 60° compared by PSNR and SSIM "
                        "(scikit-image), the smallest shown. Times measured in this run on "
                        f"{res.machine['cpu']} ({res.machine['cores']} cores, JAX "
                        f"{res.machine['jax']} on {res.machine['device']}); the run took "
                        f"{res.seconds:.0f} s" + (" (--quick)" if res.quick else "") + "."))
    thresholds = res.as_dict()["thresholds"]  # what the record says each use case accepts
    rec = table_html(["use case", "recommendation", "accepts"],
                     [[k, v, ", ".join(f"{a} {'≥' if a == 'ssim' else '≤'} {b:g}"
                                       for a, b in thresholds[k].items())]
                      for k, v in res.recommendations.items()])
    table = table_html(["group", "knob", "setting", "f rel. RMS", "f rel. max", "albedo err.",
                        "PSNR dB", "SSIM", "time s", "time per", "cost", "reference"],
                       _rows(res), numeric=(3, 4, 5, 6, 7, 8))
    skipped = "".join(f"<li><strong>{esc(k)}</strong>: {esc(v)}</li>"
                      for k, v in res.skipped.items())
    sections = [
        ("material", "Material and method", head),
        ("recommendations", "Recommendations", rec),
        ("pareto", "Error against time", figure_html(figure)
         + note_html("Times of different units (per evaluation, per bake, per fit) are not "
                     "comparable across panels; every number is in the table below and in "
                     "tradeoffs.json.")),
        ("table", "Every measured setting", table),
        ("skipped", "Knobs that do not apply", f"<ul>{skipped}</ul>\n" if skipped
         else paragraph("Every knob applied.")),
    ]
    return document(f"Accuracy against cost: {m['model']}", sections,
                    files=[f"{figure.name}.png", f"{figure.name}.svg", "tradeoffs.json"])


def write_report(res, out) -> None:
    """``out``/index.html, tradeoffs.json and pareto.png/.svg, each written atomically."""
    from fitlab.io.atomic import atomic_open, atomic_write_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    png, svg = render(pareto_figure(res))
    fig = FigureEntry("pareto", "Error against time, one panel per knob (log–log); the red "
                      "line joins the Pareto front (settings no other beats in both), whose "
                      "settings are labelled; the reference setting (no error) is not drawn.",
                      "Scatter plots of error against time for each knob setting", png, svg)
    atomic_write_text(out / "tradeoffs.json", json.dumps(res.as_dict(), indent=1,
                                                         default=_json) + "\n")
    for name, blob in (("pareto.png", png), ("pareto.svg", svg)):
        with atomic_open(out / name, "wb") as fh:
            fh.write(blob)
    atomic_write_text(out / "index.html", page(res, fig))


def _json(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(f"not JSON: {type(x).__name__}")


__all__ = ["pareto_front", "pareto_figure", "write_report"]
