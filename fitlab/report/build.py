"""``build_report``: a fit record, its data and chain in; ``index.html`` and the figures (PNG and
SVG) out. Every file is rendered in memory first and then written atomically, ``index.html``
last, so a failure leaves no partial report. The output depends only on the inputs (no dates,
sorted iteration, deterministic figure bytes)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError
from fitlab.metrics import REL_ERR_FLOOR, fit_error, fit_error_of, fit_error_text
from fitlab.io.atomic import atomic_open
from fitlab.report import geometry as geo
from fitlab.report.html import (document, esc, note_html, paragraph, table_html, warning_html)
from fitlab.report.inputs import (BAND_SAMPLES, data_prediction, load_inputs, model_f,
                                  prediction, predictive_band)
from fitlab.report.style import Figures
from fitlab.report.summary import CSS as SUMMARY_CSS, lead_html
from fitlab.version import __version__

#: At most this many incidence directions get an in-plane scan figure per channel.
MAX_SCANS = 24
#: Hemisphere maps and polar lobes: this many incidence angles.
MAX_MAPS = 4
MAX_LOBES = 4
#: Hemisphere maps: at most this many points per incidence (evenly thinned).
MAX_MAP_POINTS = 20000
#: Hemisphere residual maps leave out rows below this fraction of the incidence's median
#: positive value (not of its maximum, as the error tables do: next to a strong specular peak the
#: diffuse floor would vanish), so near-zero readings do not swamp the map.
MAP_FLOOR = 1e-2


def _fmt(x, digits=5):
    if x is None:
        return "n/a"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    try:
        return f"{float(x):.{digits}g}"
    except (TypeError, ValueError):
        return str(x)


def _angle_tag(x):
    return f"{x:g}".replace(".", "p").replace("-", "m")


class _Report(Figures):
    """Collects figures (rendered at once) and HTML sections."""

    figure = Figures.add

    @property
    def figures(self) -> list:
        return self.entries


# --------------------------------------------------------------------------------------------
# Header, parameters, statistics
# --------------------------------------------------------------------------------------------


def _shown(path, out_dir) -> str:
    """How the page names a file: relative to the report's folder (no absolute path of the
    machine that made it, and the same text wherever the folders are)."""
    from fitlab.io.files import path_for_record

    return path_for_record(path, Path(out_dir) / "index.html")


def _header(inp, out_dir):
    rec, m = inp.record, inp.measurement
    meta = rec["data"].get("metadata", {})
    model = rec["model"]
    rows = [
        ("sample", meta.get("sample", "not stated in the data file")),
        ("instrument", meta.get("instrument", meta.get("source", "not stated in the data file"))),
        ("model", f"{model['name']} ({model.get('lobes', '')}); options "
                  + ", ".join(f"{k}={v}" for k, v in sorted(model.get("options", {}).items()))),
        ("model equations", model.get("reference", "")),
        ("loss", rec.get("loss")),
        ("seed", rec.get("seed")),
        ("parameter file", _shown(inp.fit_path, out_dir)),
    ]
    if rec.get("created_utc"):  # files of older fitlab versions record when the fit finished
        rows.append(("fit made", rec["created_utc"]))
    prov = [
        ("data file", _shown(inp.data_path, out_dir)),
        ("recorded path", rec["data"].get("path")),
        ("SHA-256", rec["data"].get("sha256")),
        ("file quantity", rec["data"].get("file_quantity")),
        ("quantity fitted", "relative (scale · f, unknown overall scale)"
         if m.is_relative else "BSDF f (1/sr)"),
        ("rows", f"{rec['data'].get('rows')} ({rec['data'].get('rows_fitted')} fitted)"),
        ("fit subset", rec["data"].get("fit_subset") or "all rows"),
        ("channels", ", ".join(rec["data"].get("channels", []))),
    ]
    prov += [(f"file metadata: {k}", v) for k, v in sorted(meta.items())
             if k not in ("sample", "instrument")]
    conv = sorted(rec.get("conventions", {}).items())
    soft = sorted((rec.get("software") or {}).items())
    chain = _shown(inp.chain_path, out_dir) if inp.chain_path else inp.chain_note
    body = table_html([], rows)
    body += "<h3>Data provenance</h3>\n" + table_html([], prov)
    body += "<h3>Conventions</h3>\n" + table_html([], conv)
    body += "<h3>Software (of the fit)</h3>\n" + table_html(["package", "version"], soft)
    body += paragraph(f"Report made by fitlab {__version__}. MCMC chain: {chain}.")
    for note in rec.get("notes", []):
        body += note_html(f"fit note: {note}")
    return body


def _warning_items(inp) -> list:
    """Every warning of the fit, one sentence each, channel named (the first screen's verdict
    counts them; the Warnings section lists them)."""
    items = []
    for fit in inp.record["fits"]:
        tag = f"channel {fit['channel']}: "
        mc = fit.get("mcmc")
        if mc and not mc.get("trustworthy", True):
            items.append(tag + "the MCMC chain is NOT trustworthy (" +
                         "; ".join(mc.get("warnings") or ["too short"]) + ")")
        elif mc and mc.get("warnings"):
            items += [tag + w for w in mc["warnings"]]
        for name, p in fit["parameters"].items():
            if p.get("at_bound"):
                items.append(tag + f"{name} ended at a bound of its range "
                             f"{p['bounds']}: its uncertainty is not meaningful")
        if fit.get("starts_disagree"):
            items.append(tag + fit["starts_disagree"].get("message", "starts disagree"))
        from fitlab.report.goodness import misfit_sentence

        if misfit_sentence(fit):  # goodness of fit failed (fitlab.fitting.goodness)
            items.append(tag + misfit_sentence(fit))
    return items


def _warnings(items):
    return warning_html("Read these before trusting the numbers", items)


def _bootstrap_cells(boot):
    if not boot:
        return ["n/a", ""]
    return [_fmt(boot["std"], 3), f"[{_fmt(boot['p16'], 6)}, {_fmt(boot['p84'], 6)}]"]


def _parameter_table(ch):
    from fitlab.report.goodness import conditional_note, has_bootstrap

    boot_cols = has_bootstrap(ch.fit)  # block bootstrap over incidences: two more columns
    rows = []
    for name, p in ch.fit["parameters"].items():
        post = p.get("posterior")
        if p["fixed"]:
            rows.append([name, p.get("unit", ""), _fmt(p["value"], 6), "fixed", "", "", "",
                         f"[{_fmt(p['bounds'][0])}, {_fmt(p['bounds'][1])}]", "fixed"]
                        + (["", ""] if boot_cols else []))
            continue
        flags = [p.get("transform", "")] + (["AT BOUND"] if p.get("at_bound") else [])
        rows.append([
            name, p.get("unit", ""), _fmt(p["value"], 6),
            _fmt(p.get("stderr"), 3),
            _fmt(post["median"], 6) if post else "no MCMC",
            f"[{_fmt(post['p16'], 6)}, {_fmt(post['p84'], 6)}]" if post else "",
            f"[{_fmt(post['p2_5'], 6)}, {_fmt(post['p97_5'], 6)}]" if post else "",
            f"[{_fmt(p['bounds'][0])}, {_fmt(p['bounds'][1])}]", ", ".join(f for f in flags if f),
        ] + (_bootstrap_cells(p.get("bootstrap")) if boot_cols else []))
    table = table_html(["parameter", "unit", "best fit (least squares)", "std. error (LS)",
                        "posterior median", "68% interval", "95% interval", "bounds", "notes"]
                       + (["bootstrap std. error", "bootstrap 68% interval"] if boot_cols
                          else []), rows, numeric=(2, 3, 4) + ((9,) if boot_cols else ()))
    note = conditional_note(ch.fit)
    return table + (note_html(note) if note else "")


def _correlation(rep, ch, tag):
    names = list(ch.free)
    mc = ch.fit.get("mcmc")
    if mc and mc.get("correlation") is not None and len(names) > 1:
        matrix, source = np.asarray(mc["correlation"], float), "MCMC posterior samples"
    else:
        cov = np.asarray([[np.nan if v is None else v for v in row]
                          for row in ch.fit["covariance"]["matrix"]], float)
        sd = np.sqrt(np.diag(cov))
        with np.errstate(divide="ignore", invalid="ignore"):
            matrix = cov / np.outer(sd, sd)
        source = "least-squares covariance"
    if len(names) < 2:
        return paragraph("One free parameter: no correlation matrix.")
    if not np.all(np.isfinite(matrix)):
        return note_html(f"The correlation matrix ({source}) is not finite: a parameter's "
                         "uncertainty is undefined (see the warnings).")
    from fitlab.report.posterior import correlation_figure

    fig = correlation_figure(matrix, names, source=source)
    return rep.figure(f"correlation_{tag}", fig,
                      f"Correlation matrix of the free parameters ({source}); colours from −1 "
                      "(blue) to +1 (red), 0 white.",
                      f"Correlation matrix of {', '.join(names)}, channel {ch.name}")


def _error_tables(inp, ch, preds):
    st = ch.fit["statistics"]
    rows = [[_fmt(r["theta_i"], 4), _fmt(r["phi_i"], 4), r["role"], r["n"], r["n_fitted"],
             _fmt(r["rms_relative_error"], 4), _fmt(r["max_abs_relative_error"], 4)]
            for r in st["per_incidence"]]
    head = []
    if st.get("chi2_per_dof") is not None:
        head.append(f"χ²/dof = {_fmt(st['chi2_per_dof'], 4)} (χ² = {_fmt(st['chi2'], 5)}, "
                    f"dof = {st['dof']}).")
    head.append(f"{fit_error_text(fit_error_of(st))} ({st['n_fit']} of {st['n_total']} rows "
                "fitted). The table's errors leave out the rows below "
                f"{REL_ERR_FLOOR:g} × the maximum of their incidence.")
    from fitlab.fitting.model_check import check_text

    check = check_text(ch.fit.get("model_check"))
    if check:
        head.append(check)
    from fitlab.report.atlas import fit_note

    atlas = fit_note(inp.model, ch.params, inp.options)  # None: a model the atlas does not map
    ap = ch.fit.get("aperture")
    if ap:
        err = ap.get("quadrature_error", {})
        shift = err.get("max_parameter_shift")
        head.append(
            f"{ap.get('rows')} rows average over their aperture (detector cone or bin, source "
            "divergence): the fit and these errors compare them with the model averaged over it "
            f"by a quadrature of order {ap.get('order')} ({ap.get('order_choice')}, "
            f"{ap.get('nodes_per_row')} nodes per row); against order "
            f"{err.get('reference_order')} it moves the parameters by {_fmt(shift, 2)} standard "
            f"errors and the rows by {_fmt(err.get('max_row_error'), 2)} noise at most. The "
            "scans' model curves are f itself, not averaged.")
    body = paragraph(" ".join(head)) + (note_html(atlas) if atlas else "")
    body += table_html(["θi (°)", "φi (°)", "role", "rows", "fitted", "RMS rel. error",
                        "max |rel. error|"], rows, numeric=(0, 1, 3, 4, 5, 6))
    # Walter-style protocol: fit on a subset, predict the rest.
    if inp.record["data"].get("fit_subset") and not ch.fitted.all() and ch.fitted.any():
        errs = [st.get("fit_error"), st.get("prediction_error")]  # the fit's stored figures
        if errs[0] is None:  # a file written before them: the same function (fitlab.metrics)
            m = inp.measurement
            errs = [fit_error(preds[k], m.value[ch.rows][k], m.theta_i[ch.rows][k],
                              m.phi_i[ch.rows][k]) for k in (ch.fitted, ~ch.fitted)]
        srows = []
        for label, e in zip(("fit subset", "predicted (not fitted)"), errs):
            worst = [r["max_abs_relative_error"] for r in e["per_incidence"]
                     if r.get("max_abs_relative_error") is not None]
            srows.append([label, e["rows_scored"], e["rows"], _fmt(e["rms_relative_error"], 4),
                          _fmt(max(worst) if worst else None, 4)])
        body += ("<h3>Fit subset against prediction (Walter 2007 §6.1 protocol)</h3>\n"
                 + paragraph(f"Fitted on {inp.record['data']['fit_subset']!s}; every other row "
                             "is a prediction. Predictions as good as the fit mean the model "
                             "generalizes across incidence angles.")
                 + table_html(["rows", "count", "counted for errors", "RMS rel. error",
                               "max |rel. error|"], srows, numeric=(1, 2, 3, 4)))
    return body


# --------------------------------------------------------------------------------------------
# Scans, maps, lobes
# --------------------------------------------------------------------------------------------


def _value_label(inp):
    return "scale·f (data units)" if inp.measurement.is_relative else "f (1/sr)"


def _scans(rep, inp, ch, preds, tag):
    from fitlab.report.scans import ScanSide, scan_figure

    m = inp.measurement
    incs = geo.incidences(m, ch.rows)
    shown = geo.pick_evenly(incs, MAX_SCANS)
    body = ""
    if len(shown) < len(incs):
        body += note_html(f"{len(incs)} incidence directions: scans of {len(shown)}, evenly "
                          "spread; the error table above covers all.")
    if ch.samples is None:
        body += note_html("No posterior bands: " + (inp.chain_note or "no chain for this "
                                                    "channel") + ".")
    else:
        from fitlab.report.goodness import conditional_note

        if conditional_note(ch.fit):  # the bands assume a model the checks reject
            body += note_html(conditional_note(ch.fit))
    body = paragraph(
        "Each figure: one incidence direction. Top two panels: the data in the plane of "
        f"incidence (points within ±{geo.IN_PLANE_TOL_DEG:g}°; red: fitted rows, orange: "
        "predicted rows) and the best-fit model (black line), on linear and logarithmic axes; "
        "shaded, when the chain is available: the 68% and 95% posterior bands of the model "
        "(scale·f evaluated at posterior samples: parameter uncertainty only); grey dashed and "
        "dotted lines, when the fit sampled a noise scale σ_r (every loss but chi2): the 68% "
        "and 95% posterior predictive bands, where new measurements should fall (the model "
        "at each sample plus the loss's noise model with that sample's σ_r; exact quantiles, "
        "not random draws). Every band is clipped at 0. Bottom "
        "panel: relative residual (model − data)/data in %, for rows above "
        f"{REL_ERR_FLOOR:g} × the incidence's maximum, with the same bands relative to the "
        "best fit. x axis: angle of wo from the normal of its hemisphere, positive on the "
        "forward side (φo = φi + 180°, where the specular or refracted peak lies), negative on "
        "the backward side.") + body
    body_parts = []
    for inc in shown:
        sel = np.isin(ch.rows, inc.rows)
        rows = ch.rows[sel]
        mask, x = geo.in_plane(m, rows)
        sides_data = geo.side_of(m, rows)
        sides = []
        floor = REL_ERR_FLOOR * np.max(np.abs(m.value[rows]))
        for side in (geo.REFLECTION, geo.TRANSMISSION):
            keep = mask & (sides_data == side)
            if not keep.any():
                continue
            xd, wi, wo = geo.dense_scan(inc.theta_i, inc.phi_i, side)
            best = prediction(inp, ch, wi, wo)
            band = predictive_band(inp, ch, wi, wo)
            band_new = predictive_band(inp, ch, wi, wo, with_noise=True)
            order = np.argsort(x[keep], kind="stable")
            r = rows[keep][order]
            sides.append(ScanSide(side, x[keep][order], m.value[r],
                                  None if m.sigma is None else m.sigma[r],
                                  ch.fitted[sel][keep][order], preds[sel][keep][order], xd, best,
                                  band, floor, band_new))
        label = f"θi = {inc.theta_i:.4g}°" + (f", φi = {inc.phi_i:.4g}°" if inc.phi_i else "")
        if not sides:
            body_parts.append(note_html(f"{label}: no measured rows within "
                                        f"±{geo.IN_PLANE_TOL_DEG:g}° of the plane of incidence "
                                        "(see the hemisphere maps)."))
            continue
        fig = scan_figure(sides, title=f"{label} (channel {ch.name})", ylabel=_value_label(inp))
        n_in = int(mask.sum())
        role = "fitted" if ch.fitted[sel].all() else (
            "predicted (not fitted)" if not ch.fitted[sel].any() else "partly fitted")
        band_txt = (f"bands from {ch.samples.shape[0]} posterior samples" if ch.samples
                    is not None else "no posterior band (no chain)")
        cap = (f"In-plane scan at {label}, channel {ch.name}, {role}: {n_in} measured rows within "
               f"±{geo.IN_PLANE_TOL_DEG:g}° of the plane of incidence; {band_txt}.")
        alt = (f"Scan at {label}: data points and model curve for "
               f"{' and '.join(s.side for s in sides)}, linear and log, with residuals")
        body_parts.append(rep.figure(f"scan_{tag}_theta{_angle_tag(inc.theta_i)}_phi"
                                     f"{_angle_tag(inc.phi_i)}", fig, cap, alt,
                                     half=len(sides) == 1))
    return body + "".join(body_parts)


def _maps(rep, inp, ch, preds, tag):
    from fitlab.report.maps import RESIDUAL_MAX, MapRow, hemisphere_figure

    m = inp.measurement
    if not geo.is_out_of_plane(m, ch.rows):
        return None
    incs = geo.pick_evenly(geo.incidences(m, ch.rows), MAX_MAPS)
    rows_fig = []
    for inc in incs:
        sel = np.isin(ch.rows, inc.rows)
        rows = ch.rows[sel]
        p = preds[sel]
        sides = geo.side_of(m, rows)
        for side in (geo.REFLECTION, geo.TRANSMISSION):
            keep = sides == side
            if keep.sum() < 3:
                continue
            idx = np.flatnonzero(keep)
            if idx.size > MAX_MAP_POINTS:
                idx = idx[np.round(np.linspace(0, idx.size - 1, MAX_MAP_POINTS)).astype(int)]
            r = rows[idx]
            x, y = geo.disc_xy(m.theta_o[r], m.phi_o[r])
            vals = m.value[rows]
            floor = MAP_FLOOR * float(np.median(vals[vals > 0])) if (vals > 0).any() else 0.0
            # φi named when the data hold several (an anisotropic sample's rotations)
            phi = f", φi = {inc.phi_i:.4g}°" if inc.phi_i else ""
            rows_fig.append(MapRow(f"θi = {inc.theta_i:.4g}°{phi}, {side}", x, y, m.value[r],
                                   p[idx], floor))
    if not rows_fig:
        return None
    unit = _value_label(inp)
    fig = hemisphere_figure(rows_fig, unit=unit)
    cap = (f"Hemispherical maps, channel {ch.name}, for {len(rows_fig)} incidence(s): measured "
           f"{unit} (left), the model at the same directions (middle), both on one logarithmic, "
           "perceptually uniform colour scale (viridis), and the relative residual "
           "(model − data)/data in % (right) on a diverging map centred on zero, its range the "
           f"95th percentile of |residual| (at most ±{RESIDUAL_MAX:g}%; beyond it the colours "
           f"saturate; grey: rows below {MAP_FLOOR:g} × the incidence's median value, or not "
           "measured). Projection: radius = angle "
           "of wo from the normal (rings at 30°, 60°, 90°), angle = φo; the light comes from "
           "φ = φi, the specular peak lies near φo = φi + 180°.")
    alt = "Hemisphere maps of data, model and relative residual for " + \
        ", ".join(r.label for r in rows_fig)
    return rep.figure(f"hemisphere_{tag}", fig, cap, alt)


def _lobes(rep, inp, ch, tag):
    from fitlab.report.lobes import Lobe, lobe_figure

    m = inp.measurement
    thetas = sorted({float(inc.theta_i) if inc.theta_i <= 90 else 180.0 - inc.theta_i
                     for inc in geo.incidences(m, ch.rows)})
    thetas = [t for t in thetas if t < 90.0] or [0.0]
    thetas = geo.pick_evenly(thetas, MAX_LOBES)
    model_sides = [geo.REFLECTION] + ([geo.TRANSMISSION] if inp.model.capabilities.transmission
                                      else [])
    sides = {}
    for side in model_sides:
        lobes = []
        for t in thetas:
            x, wi, wo = geo.dense_scan(t, 0.0, side, n=721)
            f = model_f(inp, ch.params, wi, wo)
            lobes.append(Lobe(t, x, f * np.abs(wo[:, 2])))
        sides[side] = lobes
    fig = lobe_figure(sides, title=f"{inp.model.name}, channel {ch.name}: best fit"
                      + (", without the scale of relative data" if inp.measurement.is_relative
                         else ""))
    cap = (f"Polar lobes of the fitted BSDF in the plane of incidence, channel {ch.name}: "
           "f·|cos θo| in 1/sr (radius) against the direction of wo, at θi = "
           + ", ".join(f"{t:g}°" for t in thetas)
           + ". Reflection above the surface (0° = normal, dotted: incident directions), "
           + ("transmission below it (0° = −normal). " if len(sides) > 1 else
              "the model has no transmission lobe. ")
           + "The right side is forward scattering. Model values only, without the fit's "
           "relative-data scale.")
    alt = f"Polar plots of the fitted BSDF lobes ({', '.join(sides)}) for " \
          f"{len(thetas)} incidence angles"
    return rep.figure(f"lobes_{tag}", fig, cap, alt)


# --------------------------------------------------------------------------------------------
# Posterior and MCMC
# --------------------------------------------------------------------------------------------


def _posterior(rep, inp, ch, tag):
    from fitlab.report.posterior import corner_figure, trace_figure

    mc = ch.fit.get("mcmc")
    if not mc:
        return note_html("No MCMC run for this fit: the uncertainties are the least-squares "
                         "standard errors (fitlab fit --mcmc samples the posterior).")
    tau = mc.get("autocorrelation_time") or []
    rows = [["walkers", mc["nwalkers"]], ["steps per walker", mc["nsteps"]],
            ["burn-in (steps)", mc["burn_in"]], ["thinning", mc["thin"]],
            ["autocorrelation time τ (steps)",
             ", ".join(f"{c}: {_fmt(t, 4)}" for c, t in zip(mc["coordinates"], tau))],
            ["steps / longest τ (≥ 50 to trust)",
             _fmt(mc["nsteps"] / max(t for t in tau if t) if any(tau) else None, 4)],
            ["acceptance fraction", _fmt(mc["acceptance_fraction"], 3)],
            ["effective sample size", _fmt(mc["effective_sample_size"], 5)],
            ["stored samples", mc["samples"]],
            ["trustworthy", "yes" if mc["trustworthy"] else "NO"],
            ["prior", mc.get("prior", "")]]
    body = ""
    if not mc["trustworthy"]:
        body += warning_html("This chain is not trustworthy: its intervals and bands are not "
                             "reliable", mc.get("warnings") or ["chain shorter than 50 τ"])
    elif mc.get("warnings"):
        body += warning_html("MCMC warnings", mc["warnings"])
    body += table_html(["MCMC diagnostic", "value"], rows)
    if ch.samples is None:
        return body + note_html("No corner or trace plots: " + (inp.chain_note or "no chain")
                                + ".")
    units = [ch.fit["parameters"][n].get("unit", "") for n in ch.free]
    best = np.array([ch.fit["parameters"][n]["value"] for n in ch.free])
    fig = corner_figure(ch.samples_all, list(ch.free), units, best)
    body += rep.figure(
        f"corner_{tag}", fig,
        f"Posterior corner plot, channel {ch.name}: marginal histograms (diagonal; blue lines at "
        f"the median, 68% and 95% interval ends) and pairwise 2-D histograms of the "
        f"{ch.samples_all.shape[0]} stored posterior samples; red: the least-squares best fit.",
        f"Corner plot of the posterior of {', '.join(ch.free)}")
    # Trace plots in native units (free parameters) and log σ_r (noise scale), if sampled.
    nfree = len(ch.free)
    native = ch.space.to_native(ch.chain[:, :, :nfree])
    extra = ch.chain[:, :, nfree:]
    vals = np.concatenate([native, extra], axis=2)
    labels = [f"{n} ({u})" if u not in ("", "1") else n for n, u in zip(ch.free, units)]
    labels += ["log σ_r (noise)" if c == "log_noise" else c for c in ch.chain_coordinates[nfree:]]
    fig = trace_figure(vals, labels, burn=int(mc["burn_in"]),
                       tau=[t or 0.0 for t in tau], log_prob=ch.log_prob)
    body += rep.figure(
        f"trace_{tag}", fig,
        f"MCMC traces, channel {ch.name}, for every sampled coordinate and the log posterior: "
        "per step, the band holding 68% and 95% of the walkers, their median (black) and three "
        "single walkers (every step shown for chains up to 600 steps, else evenly thinned); grey: "
        "the discarded burn-in. A trustworthy chain looks like stationary noise after the "
        "burn-in, with τ much shorter than the chain.",
        f"Trace plots of {len(labels)} MCMC coordinates and the log posterior")
    return body


def _walter(rep, inp, ch, tag):
    from fitlab.report.walter import distribution_curves, empirical_D_figure

    diag = (ch.fit.get("diagnostics") or {}).get("empirical_D")
    if not diag:
        return None
    if "skipped" in diag:
        return note_html(f"Empirical D: {diag['skipped']}.")
    if not diag.get("points"):
        return note_html("Empirical D: no data point qualified (|i·n|, |o·n| > 0.5, ≥ 1% of "
                         "the maximum).")
    th, D = np.asarray(diag["theta_m_deg"]), np.asarray(diag["D_empirical"])
    dist = inp.options.get("distribution", "ggx")
    curves = distribution_curves(th, D, dist, ch.params["alpha"])
    fig = empirical_D_figure(th, D, curves)
    rows = [[label, _fmt(rms, 4)] for label, _, _, rms in curves]
    cap = (f"Walter 2007 §6.1 (Fig. 12): empirical microfacet distribution, channel {ch.name}: "
           f"{diag['points']} points D = f / K with G = 1 (|i·n|, |o·n| > 0.5, values ≥ 1% of "
           "the maximum; eq. 20 or 21 solved for D) against θm, with the BSDF fit's distribution "
           "and every registry distribution matched to the points (α minimizing the RMS log "
           "ratio, each point's |log ratio| capped at ln 100). Points on a curve mean the data "
           "follow that microfacet distribution; a distribution that cannot follow the points' "
           "tails is pushed to a wide α.")
    return (rep.figure(f"empirical_D_{tag}", fig, cap,
                       f"Empirical D points against {len(curves)} microfacet distributions")
            + table_html(["distribution", "RMS log ratio to the points (capped at ln 100)"], rows,
                         numeric=(1,)))


# --------------------------------------------------------------------------------------------


def _previous_files(index: Path) -> set:
    """Figure files an earlier report in this folder listed in its index.html (so that a
    rebuild removes figures that no longer exist, and nothing else)."""
    if not index.is_file():
        return set()
    text = index.read_text(encoding="utf-8", errors="replace")
    found = re.search(r'<meta name="fitlab-report-files" content="([^"]*)">', text)
    if not found:
        return set()
    return {n for n in found.group(1).split() if re.fullmatch(r"[A-Za-z0-9_.-]+\.(png|svg)", n)}


def _lut_tables(fit_path, given, discover):
    """[(path, table, note)] of the --lut files (validated: a table of another fit is an error)
    and, with ``discover``, the EXR tables beside the fit file that name it."""
    from fitlab.report.luts import check_lut, discover_luts as find

    paths = [Path(p) for p in given]
    if discover:
        known = {p.resolve() for p in paths}
        paths += [p for p in find(fit_path) if p.resolve() not in known]
    out = []
    for p in paths:
        table, note = check_lut(p, fit_path)
        out.append((p, table, note))
    return out


def _source_fit(lut_path, source_fit, out_dir) -> str:
    """A table's ``source_fit`` as the page names files."""
    from fitlab.report.luts import source_fit_path

    return _shown(source_fit_path(lut_path, source_fit), out_dir) if source_fit else "none"


def _luts(rep, tables, out_dir):
    from fitlab.report.luts import accuracy_rows, lut_figure

    body = paragraph("Tables baked for this fit (fitlab lut, OpenEXR, data_formats/lut_exr.md): "
                     "a preview of the stored values (texture coordinates, the axis values as "
                     "tick labels) and the accuracy figures the baker measured and stored in "
                     "the file's header (relative errors).")
    used = set()
    for path, t, note in tables:
        stem = re.sub(r"[^A-Za-z0-9_-]", "_", path.stem)
        name = f"lut_{stem}"
        k = 2
        while name in used:
            name, k = f"lut_{stem}_{k}", k + 1
        used.add(name)
        size = " × ".join(str(a.size) for a in t.axes)
        body += f"<h3>{esc(path.name)}</h3>\n"
        if note:
            body += note_html(f"{path.name}: {note}.")
        info = [("kind", t.kind), ("size", f"{size} ({t.dtype})"),
                ("channels", ", ".join(t.channels)), ("quantity", t.quantity),
                ("source fit", _source_fit(path, t.source_fit, out_dir))]
        info += [(f"axis {a.name}", f"[{a.lo:g}, {a.hi:g}], {a.size} samples, {a.mapping} "
                  f"mapping: {a.description}") for a in t.axes]
        info += [("note", n) for n in t.notes]
        body += table_html([], info)
        rows = [[m, _fmt(mx, 3), _fmt(rms, 3), what] for m, mx, rms, what in
                accuracy_rows(t.accuracy)]
        body += table_html(["accuracy", "max rel. error", "RMS rel. error", "against"], rows,
                           numeric=(1, 2))
        fig = lut_figure(t.values, t.channels, t.axes, title=f"{path.name}: {t.kind} table")
        shown = min(len(t.channels), 4)
        body += rep.figure(
            name, fig,
            f"Preview of {path.name}: the {t.kind} table ({t.quantity}) as stored, "
            f"{shown} of {len(t.channels)} channel(s); "
            + ("value against the axis." if len(t.axes) == 1 else
               "colour = value (viridis; logarithmic when positive values span over two "
               "decades), x and y in texture coordinates labelled with the axis values"
               + (", at the first, middle and last sample of the third axis." if len(t.axes) == 3
                  else ".")),
            f"Preview of the {t.kind} lookup table {path.name}")
    return body


def build_report(fit_path, out_dir, *, data_path=None, chain_path=None, luts=(),
                 discover_luts=True, renderers=False, progress=True,
                 read_options: dict | None = None) -> dict:
    """Write ``out_dir/index.html`` and the figures; returns a summary dict (``files``,
    ``figures``, ``index``, ``has_chain``). ``luts``: EXR tables to preview (each must have been
    baked from this fit, or from a model without a fit); ``discover_luts``: also preview the
    tables beside the fit file whose header names it; ``renderers``: add the hand-off section
    (fitlab/report/renderers.py: every renderer export's conversion error and a Mitsuba 3
    preview render). ``read_options``: how to read the data file (fitlab.read's ``angles``,
    ``accept``, ``quantity``; default: as the fit recorded, ``data.read_options``)."""
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    inp = load_inputs(fit_path, data_path, chain_path, progress=say, read_options=read_options)
    tables = _lut_tables(fit_path, luts, discover_luts)
    rep = _Report(say)
    meta = inp.record["data"].get("metadata", {})
    title = f"Fit report: {inp.model.name} on {meta.get('sample') or Path(inp.data_path).name}"
    warnings = _warning_items(inp)
    # The answer first (fitlab/report/summary.py); the full warnings next; provenance last.
    lead = lead_html(inp, data_prediction(inp, inp.channels[0]), rep.figure, len(warnings),
                     _value_label(inp))
    sections = [("warnings", "Warnings", _warnings(warnings))] if warnings else []
    for ch in inp.channels:
        tag = ch.name
        ctitle = f" (channel {ch.name})" if len(inp.channels) > 1 else ""
        say(f"report: channel {ch.name}: predictions and bands ({BAND_SAMPLES} samples at most)")
        preds = data_prediction(inp, ch)  # aperture-averaged where the fit averaged
        body = _parameter_table(ch) + _correlation(rep, ch, tag)
        sections.append((f"parameters-{tag}", "Parameters" + ctitle, body))
        sections.append((f"errors-{tag}", "Errors per incidence" + ctitle,
                         _error_tables(inp, ch, preds)))
        from fitlab.report.goodness import goodness_section

        good = goodness_section(rep, ch, tag)  # None for files written before the checks
        if good:
            sections.append((f"goodness-{tag}", "Goodness of fit" + ctitle, good))
        sections.append((f"scans-{tag}", "In-plane scans" + ctitle, _scans(rep, inp, ch, preds,
                                                                          tag)))
        maps = _maps(rep, inp, ch, preds, tag)
        if maps:
            sections.append((f"maps-{tag}", "Hemispherical maps" + ctitle, maps))
        sections.append((f"lobes-{tag}", "Polar lobes of the fitted BSDF" + ctitle,
                         _lobes(rep, inp, ch, tag)))
        sections.append((f"posterior-{tag}", "Posterior and MCMC diagnostics" + ctitle,
                         _posterior(rep, inp, ch, tag)))
        walter = _walter(rep, inp, ch, tag)
        if walter:
            sections.append((f"walter-{tag}", "Walter diagnostics: empirical D" + ctitle, walter))
    if tables:
        sections.append(("luts", "Lookup tables", _luts(rep, tables, out_dir)))
    if renderers:
        from fitlab.report.renderers import renderers_section

        sections.append(("renderers", "Hand-off to renderers", renderers_section(rep, fit_path)))
    sections.append(("header", "Fit, data and provenance", _header(inp, out_dir)))
    names = [f"{f.name}.{ext}" for f in rep.figures for ext in ("png", "svg")]
    page = document(title, sections, files=sorted(names), lead=lead, css=SUMMARY_CSS)
    files = {}
    for f in rep.figures:
        files[f"{f.name}.png"] = f.png
        files[f"{f.name}.svg"] = f.svg
    if len(files) != 2 * len(rep.figures):
        raise FitlabError("internal error: two report figures share a name")
    files["index.html"] = page.encode("utf-8")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FitlabError(f"--out {out}: is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    previous = _previous_files(out / "index.html")
    for name in sorted(files, key=lambda n: (n == "index.html", n)):  # index.html last
        with atomic_open(out / name, "wb") as fh:  # mode from the umask
            fh.write(files[name])
    for name in sorted(previous - set(files)):  # figures of an earlier report of this folder
        (out / name).unlink(missing_ok=True)
    say(f"report: wrote {out / 'index.html'} and {len(rep.figures)} figures (PNG + SVG)")
    return {"files": sorted(files), "figures": [f.name for f in rep.figures],
            "index": str(out / "index.html"), "has_chain": any(c.samples is not None
                                                                for c in inp.channels)}
