"""The record of a comparison (what compare.json holds, data_formats/compare.md) and its
verdicts."""

from __future__ import annotations

import math
import re

import numpy as np

from fitlab.fitting.compare.common import SCHEMA, SCHEMA_VERSION
from fitlab.fitting.compare.criteria import _arviz, _compare_ic
from fitlab.fitting.compare.crossval import (_rms, incidence_keys, incidences_of,
                                             jackknife_difference)
from fitlab.metrics import REL_ERR_FLOOR, fit_error_text, relative_errors
from fitlab.fitting.status import Status, channel_statuses

#: A difference is decisive beyond this many standard errors ...
DECISIVE_SE = 2.0
#: ... and, for an ELPD difference, beyond this many nats (below it the normal approximation of
#: its standard error is unreliable: Sivula, Magnusson and Vehtari 2020).
SMALL_ELPD = 4.0


# --------------------------------------------------------------------------------------------
# The record (data_formats/compare.md)
# --------------------------------------------------------------------------------------------


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _fmt(x, digits=3):
    return "n/a" if x is None else f"{x:.{digits}g}"


def _cv_block(entries, labels, noise):
    """CV scores, ranks and differences to the best for one channel's candidates."""
    out = {}
    complete = {}
    for lab, e in zip(labels, entries):
        folds = e["folds"]
        failed = [f for f in folds if f["error"]]
        rel = np.concatenate([f["rel"] for f in folds]) if folds else np.zeros(0)
        out[lab] = {
            "rms_relative_error": None if failed else _rms(rel),
            "per_incidence": [_rms(f["rel"]) for f in folds],
            "failed_folds": [{"theta_i": f["theta_i"], "phi_i": f["phi_i"], "error": f["error"]}
                             for f in failed],
            "fold_parameters": [f["parameters"] for f in folds],
            "fold_warnings": sorted({w for f in folds for w in f["warnings"]}),
        }
        if not failed and rel.size:
            complete[lab] = (np.array([np.sum(f["rel"] ** 2) for f in folds]),
                             np.array([f["rel"].size for f in folds]))
    order = sorted(complete, key=lambda lab: (out[lab]["rms_relative_error"], labels.index(lab)))
    order += [lab for lab in labels if lab not in complete]
    best = order[0] if order and order[0] in complete else None
    for rank, lab in enumerate(order, start=1):
        block = out[lab]
        block["rank"] = rank
        if lab in complete and best is not None:
            d, se = jackknife_difference(complete[lab][0], complete[best][0], complete[lab][1])
            block["delta"] = d
            block["delta_se"] = _num(se)
            block["delta_over_noise"] = _num(d / noise) if noise else None
        else:
            block["delta"] = block["delta_se"] = block["delta_over_noise"] = None
    return out, order


def _pareto_summary(loo, informative_rows, keys) -> dict:
    k = np.asarray(loo["pareto_k"].values, float)
    good_k = float(loo["good_k"])
    bad = k > good_k
    where = {}
    for (ti, pi) in keys[informative_rows][bad]:
        where[(float(ti), float(pi))] = where.get((float(ti), float(pi)), 0) + 1
    worst = sorted(where.items(), key=lambda kv: (-kv[1], kv[0]))[:5]
    return {"good_k": good_k, "good": int(np.sum(~bad)),
            "bad": int(np.sum(bad & (k <= 1.0))), "very_bad": int(np.sum(k > 1.0)),
            "max": _num(np.max(k)) if k.size else None,
            "worst_incidences": [{"theta_i": t, "phi_i": p, "rows": n} for (t, p), n in worst]}


def _ic_block(entries, labels, m, rows, kind):
    elpds = {lab: e["ic"][kind] for lab, e in zip(labels, entries)}
    ranks = _compare_ic(elpds, kind)
    keys = incidence_keys(m)[rows]
    out = {}
    for lab, e in zip(labels, entries):
        d = e["ic"][kind]
        block = {"elpd": float(d[f"elpd_{kind}"]), "se": float(d["se"]), "p": float(d[f"p_{kind}"]),
                 **ranks[lab], "warning": bool(d["warning"])}
        inf = e["ic"]["informative"]
        block["rows"] = int(inf.sum())
        block["trustworthy"] = e["ic"]["trustworthy"]
        if kind == "loo":
            block["pareto_k"] = _pareto_summary(d, inf, keys)
            k = np.asarray(d["pareto_k"].values, float)
            block["pareto_k_per_incidence"] = [
                _num(np.max(k[sel])) if sel.any() else None
                for sel in ((keys[inf][:, 0] == t) & (keys[inf][:, 1] == p)
                            for t, p in incidences_of(m, rows))]
        else:  # ArviZ's criterion: the posterior variance of log p above 0.4 at a row
            block["rows_variance_above_0_4"] = e["ic"]["rows_variance_above_0_4"]
        block["elpd_per_row"] = block["elpd"] / max(block["rows"], 1)
        out[lab] = block
    order = sorted(labels, key=lambda lab: out[lab]["rank"])
    return out, order


def _verdict_cv(cv, order, noise, noise_source):
    best = order[0]
    b = cv[best]
    if b["rms_relative_error"] is None:
        return {"winner": None, "text": "Cross-validation: no candidate completed every fold."}
    text = (f"{best} wins by leave-one-incidence-out cross-validation: held-out RMS relative "
            f"error {b['rms_relative_error']:.4f}")
    v = {"winner": best, "runner_up": None, "delta": None, "delta_se": None,
         "standard_errors": None, "delta_over_noise": None, "decisive": None}
    if len(order) > 1 and cv[order[1]]["rms_relative_error"] is not None:
        second = order[1]
        s = cv[second]
        z = s["delta"] / s["delta_se"] if s["delta_se"] else None
        decisive = bool(z is not None and z > DECISIVE_SE)
        v.update(runner_up=second, delta=s["delta"], delta_se=s["delta_se"],
                 standard_errors=_num(z), delta_over_noise=s["delta_over_noise"],
                 decisive=decisive)
        text += (f" against {s['rms_relative_error']:.4f} for {second}: Δ = {s['delta']:.4f} ± "
                 f"{_fmt(s['delta_se'], 2)} (jackknife over incidences"
                 + (f", {z:.1f} standard errors" if z is not None else "") + ")"
                 + (f", {s['delta_over_noise']:.2f} × the per-row noise scale {noise:.3g}"
                    if s["delta_over_noise"] is not None else "")
                 + (". Decisive." if decisive else
                    f". Not decisive (within {DECISIVE_SE:g} standard errors)."))
    else:
        text += "."
    v["text"] = text
    return v


def _verdict_ic(block, order, kind):
    name = {"loo": "PSIS-LOO", "waic": "WAIC"}[kind]
    best = order[0]
    b = block[best]
    v = {"winner": best, "runner_up": None, "elpd_diff": None, "dse": None,
         "standard_errors": None, "decisive": None}
    text = f"{best} wins by {name}: ELPD {b['elpd']:.1f} ± {b['se']:.1f}"
    if len(order) > 1:
        second = order[1]
        s = block[second]
        z = s["elpd_diff"] / s["dse"] if s["dse"] > 0 else None
        decisive = bool(s["elpd_diff"] > SMALL_ELPD and z is not None and z > DECISIVE_SE)
        v.update(runner_up=second, elpd_diff=s["elpd_diff"], dse=s["dse"],
                 standard_errors=_num(z), decisive=decisive)
        text += (f", ΔELPD = {s['elpd_diff']:.1f} ± {s['dse']:.1f} over {second}"
                 + (f" ({z:.1f} standard errors, {s['elpd_diff'] / max(b['rows'], 1):.3g} per "
                    "row)" if z is not None else "")
                 + (". Decisive." if decisive else
                    f". Not decisive (ΔELPD within {SMALL_ELPD:g} or {DECISIVE_SE:g} standard "
                    "errors)."))
    else:
        text += "."
    short = [lab for lab in order if not block[lab]["trustworthy"]]
    if short:
        text += (f" The MCMC chain of {', '.join(short)} is too short to trust (see the "
                 "warnings): rerun with more --mcmc-steps.")
    if any(block[lab]["warning"] for lab in order):
        text += (" Some of these estimates are flagged unreliable (see the warnings)."
                 if kind == "loo" else " ArviZ flags WAIC as possibly failing (see the "
                 "warnings); prefer PSIS-LOO.")
    v["text"] = text
    return v


def _in_sample(fe, incs) -> dict:
    """A candidate's in-sample error: its fit's stored ``statistics.fit_error`` (the one
    definition, fitlab.metrics.fit_error), per incidence in the order of ``incs``."""
    per = {(r["theta_i"], r["phi_i"]): r["rms_relative_error"] for r in fe["per_incidence"]}
    return {"rms_relative_error": fe["rms_relative_error"], "rows": fe["rows"],
            "per_incidence": [per.get((t, p)) for t, p in incs], "text": fit_error_text(fe)}


def _record(m, cands, fits, per, chan_ids, incs, rows_fit, expr, loss, cv, mcmc, mcmc_steps,
            walkers, starts, seed, fix, options, free, run_warnings) -> dict:
    from fitlab.export.paramfile import software_versions

    labels = [c.label for c in cands]
    warnings = list(run_warnings)
    pareto_flagged = False
    channels = []
    for c in chan_ids:
        name = m.channel_names[c]
        rows = rows_fit & (m.channel == c)
        entries = per[c]
        keys = incidence_keys(m)
        counted = []
        for ti, pi in incs[c]:
            held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
            counted.append(relative_errors(m.value[held], m.value[held])[1])
        in_sample = {lab: e["in_sample"]["rms_relative_error"] for lab, e in zip(labels, entries)}
        if m.sigma is not None:
            sig = np.concatenate([m.sigma[rows & (keys[:, 0] == t) & (keys[:, 1] == p)][k]
                                  / np.abs(m.value[rows & (keys[:, 0] == t) & (keys[:, 1] == p)]
                                           [k]) for (t, p), k in zip(incs[c], counted)])
            noise, source = _rms(sig), "RMS of sigma/|value| over the counted rows"
        else:
            best_in = min((v for v in in_sample.values() if v is not None), default=None)
            noise = best_in
            source = ("no sigma in the data: the smallest in-sample RMS relative error of the "
                      "candidates, an upper bound of the noise")
        models = []
        for cand, e in zip(cands, entries):
            fit = e["fit"]
            free_names = [k for k, p in fit["parameters"].items() if not p["fixed"]]
            models.append({
                "label": cand.label,
                "n_free": len(free_names),
                "free_parameters": free_names,
                "parameters": {k: p["value"] for k, p in fit["parameters"].items()},
                "stderr": {k: p.get("stderr") for k, p in fit["parameters"].items()
                           if not p["fixed"]},
                "in_sample": _in_sample(e["in_sample"], incs[c]),
                "fit_warnings": list(fit.get("warnings") or []),
                "statuses": [str(st) for st in channel_statuses(fit)],
            })
        ch = {"channel": name, "rows_fitted": int(rows.sum()),
              "noise_scale": {"relative": noise, "source": source},
              "incidences": [{"theta_i": t, "phi_i": p,
                              "rows": int(np.sum(rows & (keys[:, 0] == t) & (keys[:, 1] == p))),
                              "rows_counted": int(k.sum())}
                             for (t, p), k in zip(incs[c], counted)],
              "models": models, "ranking": {}, "verdict": {}}
        if cv:
            block, order = _cv_block(entries, labels, noise)
            for mod in models:
                mod["cv"] = block[mod["label"]]
                if mod["cv"]["failed_folds"]:
                    mod["statuses"] = [st for st in mod["statuses"] if st != Status.CONVERGED] \
                        + [str(Status.FOLDS_FAILED)]
                for f in block[mod["label"]]["failed_folds"]:
                    warnings.append(f"channel {name}: {mod['label']}: the cross-validation "
                                    f"fold without θi = {f['theta_i']:g}°, φi = "
                                    f"{f['phi_i']:g}° could not be fitted ({f['error']}); this "
                                    "model is ranked last by CV")
            ch["ranking"]["cv"] = order
            ch["verdict"]["cv"] = _verdict_cv(block, order, noise, source)
        if mcmc:
            for kind in ("loo", "waic"):
                block, order = _ic_block(entries, labels, m, rows, kind)
                for mod in models:
                    mod[kind] = block[mod["label"]]
                ch["ranking"][kind] = order
                ch["verdict"][kind] = _verdict_ic(block, order, kind)
            for mod, e in zip(models, entries):
                ic = e["ic"]
                mod["mcmc"] = {"samples": ic["samples"], "relative_efficiency": ic["reff"],
                               "trustworthy": ic["trustworthy"], "warnings": ic["mcmc_warnings"]}
                loo = mod["loo"]
                pk = loo["pareto_k"]
                if pk["bad"] + pk["very_bad"]:
                    at = ", ".join(f"θi = {w['theta_i']:g}° ({w['rows']})"
                                   for w in pk["worst_incidences"])
                    warnings.append(
                        f"channel {name}: {mod['label']}: PSIS-LOO is unreliable at "
                        f"{pk['bad'] + pk['very_bad']} of {loo['rows']} rows (Pareto k > "
                        f"{pk['good_k']:.2f}, up to {pk['max']:.2f}; most at {at})")
                    pareto_flagged = True
                if mod["waic"]["warning"]:
                    warnings.append(f"channel {name}: {mod['label']}: WAIC may be failing (the "
                                    "posterior variance of the log predictive density exceeds "
                                    f"0.4 at {mod['waic']['rows_variance_above_0_4']} of "
                                    f"{mod['waic']['rows']} rows, ArviZ's criterion): prefer "
                                    "PSIS-LOO")
        for mod in models:  # the full sentences are in the candidates' fit warnings
            heads = [re.split(r" \(|: ", w, maxsplit=1)[0].rstrip(".")
                     for w in mod["fit_warnings"]]
            if heads:
                warnings.append(f"channel {name}: {mod['label']}: its fit warns: "
                                + "; ".join(dict.fromkeys(heads))
                                + " (in full with the candidates' fits)")
        ch["verdict"]["text"] = " ".join(ch["verdict"][k]["text"] for k in ("cv", "loo")
                                         if k in ch["verdict"])
        if cv and mcmc:
            a, b = ch["verdict"]["cv"]["winner"], ch["verdict"]["loo"]["winner"]
            ch["verdict"]["agree"] = a == b
            if a != b:
                ch["verdict"]["text"] += (
                    " The two measures disagree: PSIS-LOO scores single rows under the fit's "
                    "noise model (independent residuals of one scale), the cross-validation "
                    "whole incidences the model was not fitted to; where the residuals are "
                    "structured by incidence (see the goodness warnings) the cross-validation is "
                    "the more honest measure of how a model predicts a new incidence angle.")
        channels.append(ch)
    software = software_versions()
    if mcmc:
        software["arviz"] = _arviz().__version__
    if pareto_flagged:
        warnings.append("Rows with Pareto k above the threshold: leaving one of them out moves the "
                        "posterior more than importance sampling can follow, so the ELPD of "
                        "that model is uncertain beyond its standard error; trust the "
                        "cross-validation for it, or use a model that describes those rows")
    fixed_rec = []
    for cand, res in zip(cands, fits):
        fixed = {}
        for f in res.record["fits"]:
            fixed.update({k: p["value"] for k, p in f["parameters"].items() if p["fixed"]})
        fixed_rec.append(fixed)
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "data": {"path": m.path, "sha256": m.sha256, "rows": m.n,
                 "rows_fitted": int(rows_fit.sum()), "fit_subset": expr,
                 "quantity": m.quantity, "channels": [m.channel_names[c] for c in chan_ids],
                 "sample": m.metadata.get("sample")},
        "settings": {"loss": loss, "seed": seed, "starts": starts,
                     "cross_validation": "leave-one-incidence-out" if cv else None,
                     "mcmc": {"steps": mcmc_steps, "walkers": walkers} if mcmc else None,
                     "relative_error_floor": REL_ERR_FLOOR, "decisive_standard_errors":
                     DECISIVE_SE, "small_elpd": SMALL_ELPD,
                     "fix": dict(fix or {}), "options": dict(options or {}),
                     "free": list(free or ())},
        "candidates": [{"label": c.label, "spec": c.spec, "model": c.model.name,
                        "options": dict(c.options), "fixed": fx,
                        "free_parameters": list(res.record["fits"][0]["covariance"]
                                                ["parameters"]),
                        "parameter_file": None}
                       for c, res, fx in zip(cands, fits, fixed_rec)],
        "channels": channels,
        "warnings": warnings,
        "software": software,
    }
