"""The model-comparison page (``fitlab compare --out DIR``): ``index.html`` and its figures (PNG
and SVG) beside the tables that ``CompareResult.save`` writes, built from the comparison's
record alone (data_formats/compare.md), in the fit report's style and with its building
blocks. Figures first, then ``index.html`` last, each written atomically."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError
from fitlab.io.atomic import atomic_open
from fitlab.report.html import (document, note_html, paragraph, table_html, warning_html)
from fitlab.report.style import Figures, new_figure, styled
from fitlab.version import __version__

#: Colours of the candidates, in the candidates' order (matplotlib's tab10).
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf")


def _fmt(x, digits=4):
    if x is None:
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    return f"{float(x):.{digits}g}"


def _pm(x, se, digits=1):
    return "n/a" if x is None else f"{x:.{digits}f} ± {se:.{digits}f}"


def _inc_axis(incs):
    """x positions and labels of the incidences: θi where φi is the same for all, else 1..K."""
    phis = {round(i["phi_i"], 9) for i in incs}
    if len(phis) == 1:
        return np.array([i["theta_i"] for i in incs]), "θi (°)" + (
            f", φi = {incs[0]['phi_i']:g}°" if incs[0]["phi_i"] else ""), None
    labels = [f"{i['theta_i']:g}/{i['phi_i']:g}" for i in incs]
    return np.arange(len(incs), dtype=float), "incidence θi/φi (°)", labels


def _color(labels, lab):
    return COLORS[labels.index(lab) % len(COLORS)]


@styled
def heldout_figure(ch, labels, title):
    """Held-out (solid) and in-sample (dashed) RMS relative error per incidence and model, the
    per-row noise scale dotted."""
    incs = ch["incidences"]
    x, xlabel, ticks = _inc_axis(incs)
    fig = new_figure(7.2, 4.2 + 0.16 * ((len(ch["models"]) + 3) // 2))
    ax = fig.subplots()
    for mod in ch["models"]:
        c = _color(labels, mod["label"])
        cv = [np.nan if v is None else v for v in mod["cv"]["per_incidence"]]
        ins = [np.nan if v is None else v for v in mod["in_sample"]["per_incidence"]]
        ax.plot(x, cv, "o-", color=c, lw=1.4, ms=4, label=f"{mod['label']} (held out)")
        ax.plot(x, ins, "--", color=c, lw=0.9, alpha=0.8)
    noise = ch["noise_scale"]["relative"]
    if noise:
        ax.axhline(noise, color="0.3", ls=":", lw=1.0, label=f"per-row noise scale {noise:.3g}")
    ax.plot([], [], "--", color="0.4", lw=0.9, label="in-sample (fitted to every incidence)")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("RMS relative error (model − data)/data")
    ax.set_ylim(bottom=0)
    if ticks:
        ax.set_xticks(x, ticks, rotation=45, ha="right")
    ax.set_title(title)
    fig.legend(loc="outside lower center", ncols=2, fontsize=7)
    return fig


@styled
def elpd_figure(ch, labels, order):
    """ELPD difference to the best model (PSIS-LOO and WAIC) with its standard error."""
    fig = new_figure(7.2, 1.5 + 0.4 * len(order))
    ax = fig.subplots()
    y = np.arange(len(order))[::-1]
    mods = {mod["label"]: mod for mod in ch["models"]}
    for k, kind, marker, dy in ((0, "loo", "o", 0.12), (1, "waic", "s", -0.12)):
        d = np.array([-mods[lab][kind]["elpd_diff"] for lab in order])
        se = np.array([mods[lab][kind]["dse"] for lab in order])
        ax.errorbar(d, y + dy, xerr=se, fmt=marker, color="0.15" if k == 0 else "0.55",
                    ms=4.5, capsize=3, lw=1.0,
                    label={"loo": "PSIS-LOO", "waic": "WAIC"}[kind] + " (± SE of the difference)")
    ax.axvline(0.0, color="0.3", lw=0.8)
    ax.set_yticks(y, order)
    for tick, lab in zip(ax.get_yticklabels(), order):
        tick.set_color(_color(labels, lab))
    ax.set_ylim(-0.6, len(order) - 0.4)
    ax.set_xlabel("ELPD − ELPD of the best model (nats; 0 = best, more negative = worse)")
    fig.legend(loc="outside lower center", ncols=2, fontsize=7)
    return fig


@styled
def pareto_figure(ch, labels, good_k):
    """The largest Pareto k at each incidence's rows, per model, with ArviZ's thresholds."""
    incs = ch["incidences"]
    x, xlabel, ticks = _inc_axis(incs)
    fig = new_figure(7.2, 3.2 + 0.16 * ((len(ch["models"]) + 3) // 2))
    ax = fig.subplots()
    for mod in ch["models"]:
        k = [np.nan if v is None else v for v in mod["loo"]["pareto_k_per_incidence"]]
        ax.plot(x, k, "o-", color=_color(labels, mod["label"]), lw=1.0, ms=3.5,
                label=mod["label"])
    ax.axhline(good_k, color="#c9302c", ls="--", lw=0.9,
               label=f"k = {good_k:.2f}: PSIS-LOO unreliable above")
    ax.axhline(1.0, color="#c9302c", ls=":", lw=0.9, label="k = 1")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("largest Pareto k at the rows")
    if ticks:
        ax.set_xticks(x, ticks, rotation=45, ha="right")
    fig.legend(loc="outside lower center", ncols=2, fontsize=7)
    return fig


def _ranking_table(ch, cands):
    """The verdict's table: the CV columns and the PSIS-LOO difference (the rest of PSIS-LOO
    and WAIC in their own section)."""
    mods = {mod["label"]: mod for mod in ch["models"]}
    rk = ch["ranking"]
    order = rk.get("cv") or rk.get("loo")
    head = ["model", "free parameters", "in-sample RMS rel. error"]
    if "cv" in rk:
        head += ["CV rank", "held-out RMS rel. error", "Δ to best ± SE", "Δ / noise scale"]
    if "loo" in rk:
        head += ["LOO rank", "ΔELPD_loo ± SE (nats)"]
    rows = []
    for lab in order:
        mod = mods[lab]
        row = [lab, mod["n_free"], _fmt(mod["in_sample"]["rms_relative_error"])]
        if "cv" in rk:
            cv = mod["cv"]
            row += [cv["rank"], _fmt(cv["rms_relative_error"]),
                    "best" if cv["rank"] == 1 else
                    f"{_fmt(cv['delta'], 3)} ± {_fmt(cv['delta_se'], 2)}",
                    "" if cv["rank"] == 1 else _fmt(cv["delta_over_noise"], 3)]
        if "loo" in rk:
            lo = mod["loo"]
            row += [lo["rank"], "best" if lo["rank"] == 1 else _pm(-lo["elpd_diff"], lo["dse"])]
        rows.append(row)
    return table_html(head, rows, numeric=tuple(range(1, len(head))))


def _incidence_table(ch, order, key):
    """RMS relative error per incidence (rows) and model (columns): held out or in-sample."""
    mods = {mod["label"]: mod for mod in ch["models"]}
    head = ["θi (°)", "φi (°)", "rows", "counted"] + list(order)
    rows = []
    for k, inc in enumerate(ch["incidences"]):
        row = [_fmt(inc["theta_i"]), _fmt(inc["phi_i"]), inc["rows"], inc["rows_counted"]]
        for lab in order:
            block = mods[lab].get(key)
            row.append(_fmt(block["per_incidence"][k], 3) if block else "n/a")
        rows.append(row)
    return table_html(head, rows, numeric=tuple(range(len(head))))


def _ic_table(ch, order):
    mods = {mod["label"]: mod for mod in ch["models"]}
    head = ["model", "ELPD_loo ± SE", "p_loo", "ΔELPD_loo ± SE", "stacking weight",
            "rows with Pareto k ≤ good / bad / > 1 (largest k)", "ELPD_waic ± SE", "p_waic",
            "ΔELPD_waic ± SE", "rows with var(log p) > 0.4", "posterior samples (rel. eff.)"]
    rows = []
    for lab in order:
        lo, wa, mc = mods[lab]["loo"], mods[lab]["waic"], mods[lab]["mcmc"]
        pk = lo["pareto_k"]
        rows.append([lab, _pm(lo["elpd"], lo["se"]), _fmt(lo["p"], 3),
                     "best" if lo["rank"] == 1 else _pm(-lo["elpd_diff"], lo["dse"]),
                     _fmt(lo["weight"], 3),
                     f"{pk['good']} / {pk['bad']} / {pk['very_bad']} ({_fmt(pk['max'], 3)})",
                     _pm(wa["elpd"], wa["se"]), _fmt(wa["p"], 3),
                     "best" if wa["rank"] == 1 else _pm(-wa["elpd_diff"], wa["dse"]),
                     wa["rows_variance_above_0_4"],
                     f"{mc['samples']} ({_fmt(mc['relative_efficiency'], 2)})"
                     + ("" if mc["trustworthy"] else ", chain NOT trustworthy")])
    return table_html(head, rows, numeric=tuple(range(1, len(head))))


def _candidates(rec):
    rows = []
    for c in rec["candidates"]:
        rows.append([c["label"], c["model"],
                     ", ".join(f"{k}={v}" for k, v in sorted(c["options"].items())) or "none",
                     ", ".join(f"{k}={v:g}" for k, v in c["fixed"].items()) or "none",
                     ", ".join(c["free_parameters"]), c.get("parameter_file") or "not saved"])
    body = table_html(["label", "model", "options", "fixed", "free", "parameter file"], rows)
    for ch in rec["channels"]:
        prow = []
        for mod in ch["models"]:
            vals = ", ".join(
                f"{k} = {v:.5g}" + (f" ± {mod['stderr'][k]:.2g}" if mod["stderr"].get(k)
                                    else "")
                for k, v in mod["parameters"].items() if k in mod["stderr"])
            prow.append([mod["label"], vals, "; ".join(mod["fit_warnings"]) or "none"])
        title = "Best fits to every fitted row" + (f" (channel {ch['channel']})"
                                                   if len(rec["channels"]) > 1 else "")
        body += f"<h3>{title}</h3>\n" + table_html(
            ["model", "free parameters (least squares ± std. error)", "fit warnings"], prow)
    return body


def _method(rec):
    st = rec["settings"]
    parts = [paragraph(
        "Every candidate is fitted to the same rows with the same loss "
        f"({st['loss']}), starts ({st['starts']}) and seed ({st['seed']}) as `fitlab fit`.")]
    if st["cross_validation"]:
        parts.append(paragraph(
            "Leave-one-incidence-out cross-validation: for each incidence direction (θi, φi) "
            "the model is refitted by Levenberg–Marquardt from the full fit's optimum "
            "without that incidence's rows, and the refitted model predicts them. Held-out "
            "error: the RMS relative error (model − data)/data of those rows (rows below "
            f"{st['relative_error_floor']:g} × the incidence's maximum are not counted), per "
            "incidence and pooled over every held-out row. Δ to the best: the difference of "
            "the pooled held-out errors; its standard error is a delete-one-incidence "
            "jackknife (incidences are the independent units: rows of one incidence share "
            "its misfit). Δ / noise scale: Δ over the per-row noise scale (RMS σ/|value| "
            "where the data give σ; otherwise the smallest in-sample RMS relative error of the "
            "candidates, which includes that model's misfit and so bounds the noise from "
            "above)."))
    if st["mcmc"]:
        parts.append(paragraph(
            "PSIS-LOO and WAIC (ArviZ) use the fit's own likelihood, row by row, at every "
            "stored posterior sample (emcee, "
            f"{st['mcmc']['steps']} steps): a Gaussian in the loss's residual with the sampled "
            "noise scale (1 with the chi2 loss), written as a density of the measured value "
            "(log p = −½(r/σ_r)² − log σ_r − ½ log 2π + log|∂r/∂v|); summed over the rows it "
            "reproduces the chain's log-posterior, which is checked. ELPD: expected log "
            "predictive density of a new row, in nats (higher is better); ΔELPD and its "
            "standard error from the pointwise differences; stacking weights from ArviZ. "
            "Pareto k above the threshold marks rows whose leave-one-out posterior importance "
            "sampling cannot follow: the ELPD of that model is then uncertain beyond its "
            "standard error."))
        parts.append(note_html(
            "PSIS-LOO leaves out one row at a time and assumes the fit's noise model "
            "(independent residuals of one scale). When a model misses whole incidences, "
            "neighbouring rows are not independent and the ELPD standard errors are too small; "
            "the cross-validation over incidences is then the more honest measure of how the "
            "model predicts a new measurement."))
    parts.append(paragraph(
        f"A difference is called decisive beyond {st['decisive_standard_errors']:g} standard "
        f"errors (and, for ELPD, beyond {st['small_elpd']:g} nats: Sivula, Magnusson and "
        "Vehtari 2020)."))
    return "".join(parts)


def _settings(rec, out_dir):
    d, st = rec["data"], rec["settings"]
    rows = [("data file", d["path"]), ("SHA-256", d["sha256"]),
            ("sample", d.get("sample") or "not stated in the data file"),
            ("rows", f"{d['rows']} ({d['rows_fitted']} fitted)"),
            ("fit subset", d.get("fit_subset") or "all rows"),
            ("quantity", d["quantity"]), ("channels", ", ".join(d["channels"])),
            ("loss", st["loss"]), ("seed", st["seed"]), ("Levenberg–Marquardt starts",
                                                         st["starts"]),
            ("cross-validation", st["cross_validation"] or "not run"),
            ("MCMC", "not run (no PSIS-LOO, WAIC)" if not st["mcmc"] else
             f"{st['mcmc']['steps']} steps, "
             f"{st['mcmc']['walkers'] or 'default'} walkers"),
            ("applied to every candidate",
             "; ".join([f"--fix {k}={v:g}" for k, v in st["fix"].items()]
                       + [f"--option {k}={v}" for k, v in st["options"].items()]
                       + [f"--free {k}" for k in st["free"]]) or "nothing"),
            ("tables", "compare.json, compare.csv, compare_incidences.csv "
                       "(data_formats/compare.md)")]
    soft = sorted((k, v) for k, v in rec["software"].items())
    return (table_html([], rows) + "<h3>Software</h3>\n" + table_html(["package", "version"],
                                                                      soft)
            + paragraph(f"Page made by fitlab {__version__}."))


def build_compare_report(result, out_dir, *, progress: bool = False) -> dict:
    """Write ``out_dir/index.html`` and its figures for a :class:`CompareResult` saved in
    ``out_dir``; returns {index, figures, files}."""
    from fitlab.report.build import _previous_files

    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    rec = result.record
    labels = [c["label"] for c in rec["candidates"]]
    figs = Figures(say)
    multi = len(rec["channels"]) > 1
    sample = rec["data"].get("sample") or Path(rec["data"]["path"]).name
    title = f"Model comparison: {len(labels)} models on {sample}"
    warn = (warning_html("Warnings: read these before trusting the ranking",
                         list(rec["warnings"])) if rec["warnings"] else "")
    sections = [("warnings", None, warn)]
    verdict = ""
    for ch in rec["channels"]:
        tag = ch["channel"]
        ctitle = f" (channel {tag})" if multi else ""
        if multi:
            verdict += f"<h3>Channel {tag}</h3>\n"
        v = ch["verdict"]
        for key in ("cv", "loo", "waic"):
            if key in v:
                verdict += paragraph(v[key]["text"])
        if v.get("agree") is False:
            verdict += note_html("Cross-validation and PSIS-LOO pick different winners: see "
                                 "the method section on what each measures.")
        verdict += paragraph(
            f"{ch['rows_fitted']} rows fitted at {len(ch['incidences'])} incidences; per-row "
            f"noise scale {_fmt(ch['noise_scale']['relative'], 3)} "
            f"({ch['noise_scale']['source']}).")
        verdict += _ranking_table(ch, rec["candidates"])
        rk = ch["ranking"]
        order = list(rk.get("cv") or rk.get("loo"))
        if "cv" in rk:
            fig = heldout_figure(ch, labels, f"held-out error per incidence{ctitle}")
            body = figs.add(
                f"heldout_{tag}", fig,
                "Leave-one-incidence-out cross-validation"
                + (f", channel {tag}" if multi else "")
                + ": RMS relative error (model − data)/data of each incidence's rows when the "
                "model is fitted to every other incidence (solid, circles), and of the fit to "
                "every incidence (dashed, in-sample); dotted: the per-row noise scale. A model "
                "that generalizes across incidence angles keeps its solid line near its dashed "
                "one and near the noise scale.",
                "Held-out and in-sample RMS relative error against incidence angle for "
                + ", ".join(labels))
            body += ("<h3>Held out (fitted to every other incidence)</h3>\n"
                     + _incidence_table(ch, order, "cv")
                     + "<h3>In-sample (fitted to every incidence)</h3>\n"
                     + _incidence_table(ch, order, "in_sample"))
            sections.append((f"heldout-{tag}", "Held-out error per incidence" + ctitle, body))
        if "loo" in rk:
            fig = elpd_figure(ch, labels, list(rk["loo"]))
            body = figs.add(
                f"elpd_{tag}", fig,
                "ELPD of each model relative to the best, by PSIS-LOO (circles) and WAIC "
                "(squares), with the standard error of the difference"
                + (f"; channel {tag}" if multi else "") + ". In nats summed over the "
                f"{ch['models'][0]['loo']['rows']} fitted rows; 0 is the best model.",
                "ELPD differences with error bars for " + ", ".join(rk["loo"]))
            body += _ic_table(ch, list(rk["loo"]))
            good_k = ch["models"][0]["loo"]["pareto_k"]["good_k"]
            fig = pareto_figure(ch, labels, good_k)
            body += figs.add(
                f"pareto_k_{tag}", fig,
                "PSIS-LOO diagnostics: the largest Pareto shape k among each incidence's rows, "
                f"per model; above k = {good_k:.2f} (dashed, ArviZ's threshold for this many "
                "samples) the leave-one-out estimate of a row is unreliable.",
                "Largest Pareto k per incidence for " + ", ".join(labels))
            sections.append((f"ic-{tag}", "PSIS-LOO and WAIC" + ctitle, body))
    sections.insert(1, ("verdict", "Which model wins, and by how much", verdict))
    sections.append(("candidates", "Candidates and their fits", _candidates(rec)))
    sections.append(("method", "How the models are compared", _method(rec)))
    sections.append(("settings", "Data and settings", _settings(rec, out_dir)))
    names = [f"{f.name}.{ext}" for f in figs.entries for ext in ("png", "svg")]
    page = document(title, sections, files=sorted(names))
    files = {}
    for f in figs.entries:
        files[f"{f.name}.png"] = f.png
        files[f"{f.name}.svg"] = f.svg
    if len(files) != 2 * len(figs.entries):
        raise FitlabError("internal error: two comparison figures share a name")
    files["index.html"] = page.encode("utf-8")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    previous = _previous_files(out / "index.html")
    for name in sorted(files, key=lambda n: (n == "index.html", n)):  # index.html last
        with atomic_open(out / name, "wb") as fh:
            fh.write(files[name])
    for name in sorted(previous - set(files)):
        (out / name).unlink(missing_ok=True)
    return {"index": str(out / "index.html"), "figures": [f.name for f in figs.entries],
            "files": sorted(files)}


__all__ = ["build_compare_report", "heldout_figure", "elpd_figure", "pareto_figure"]
