"""The report's goodness-of-fit section: does the model describe the data (fits[k].goodness,
fitlab.fitting.goodness), and the parameter intervals side by side, least squares, MCMC and the
block bootstrap over incidences (the one that accounts for misfit)."""

from __future__ import annotations

from fitlab.fitting.goodness import failure_sentence
from fitlab.report.html import note_html, paragraph, table_html, warning_html
from fitlab.report.style import new_figure, styled


def _p(p):
    return "n/a" if p is None else (f"{p:.2g}" if p >= 1e-300 else "< 1e-300")


def _g(x, digits=4):
    return "n/a" if x is None else f"{x:.{digits}g}"


def has_bootstrap(fit) -> bool:
    return any(p.get("bootstrap") for p in fit["parameters"].values())


def misfit_sentence(fit) -> str | None:
    """The failure sentence of a channel whose goodness checks failed (None otherwise and for
    files without ``goodness``)."""
    g = fit.get("goodness")
    if not g:
        return None
    return failure_sentence(g, has_mcmc=bool(fit.get("mcmc")), bootstrap=has_bootstrap(fit))


def conditional_note(fit) -> str | None:
    """What the posterior bands and intervals mean when the model fails its checks."""
    g = fit.get("goodness")
    if not g or g.get("describes_data", True):
        return None
    return ("The goodness checks reject this model (section 'Goodness of fit'): the posterior "
            "bands and intervals are conditional on the model. They show how well the data pin "
            "the parameters down if the model were right, not how far the model is from the "
            "data" + ("; the bootstrap intervals in the parameter table account for the misfit."
                      if has_bootstrap(fit) else "."))


@styled
def interval_figure(rows: list, title: str):
    """Per free parameter, the 68% intervals side by side (least squares ± 1 s.e., MCMC, block
    bootstrap), relative to the best fit. ``rows``: (name, best, [(label, lo, hi)])."""
    n = len(rows)
    fig = new_figure(6.4, 0.55 * n + 1.3)
    ax = fig.subplots()
    colours = {"least squares": "#7f7f7f", "MCMC": "#1f77b4", "bootstrap": "#d62728"}
    seen = set()
    for i, (name, best, ivals) in enumerate(rows):
        scale = abs(best) if best else 1.0
        for j, (label, lo, hi) in enumerate(ivals):
            y = i + (j - (len(ivals) - 1) / 2) * 0.22
            ax.plot([(lo - best) / scale * 100, (hi - best) / scale * 100], [y, y], lw=3,
                    color=colours[label], solid_capstyle="butt",
                    label=None if label in seen else label)
            seen.add(label)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(range(n))
    ax.set_yticklabels([r[0] for r in rows])
    ax.invert_yaxis()
    ax.set_xlabel("68% interval relative to the best fit (%)")
    ax.set_title(title)
    ax.legend(loc="best")
    return fig


def intervals(fit, free) -> list:
    """The rows of :func:`interval_figure` for a channel."""
    out = []
    for name in free:
        p = fit["parameters"][name]
        ivals = []
        if p.get("stderr") is not None:
            ivals.append(("least squares", p["value"] - p["stderr"], p["value"] + p["stderr"]))
        if p.get("posterior"):
            ivals.append(("MCMC", p["posterior"]["p16"], p["posterior"]["p84"]))
        if p.get("bootstrap"):
            ivals.append(("bootstrap", p["bootstrap"]["p16"], p["bootstrap"]["p84"]))
        if ivals:
            out.append((name, p["value"], ivals))
    return out


def goodness_section(rep, ch, tag) -> str | None:
    """HTML of the 'Goodness of fit' section of one channel (None for files without it)."""
    fit = ch.fit
    g = fit.get("goodness")
    if not g:
        return None
    body = ""
    sentence = misfit_sentence(fit)
    if sentence:
        body += warning_html("The model does not describe the data", [sentence])
    else:
        body += paragraph(f"Every check passes at p ≥ {g['p_fail']:g}: the residuals look like "
                          "the noise the loss assumes, so the model describes these data within "
                          "their noise and the intervals can be read as they stand.")
    lv, rt, pp = g["incidence_level"], g["runs_test"], g.get("posterior_predictive")
    stat = lv["statistic"]
    rows = []
    if g.get("chi2"):  # with the chi2 loss
        c = g["chi2"]
        rows.append(["χ² (all fitted rows)", f"χ²/dof = {_g(c['chi2_per_dof'])} (dof "
                     f"{c['dof']})", _p(c["p_value"]), "fails" if "chi2" in g["failed"]
                     else "passes"])
    vals = [x[stat] for x in g["per_incidence"] if x.get(stat) is not None]
    label = "χ²/dof per incidence" if stat == "chi2_per_dof" else \
        "residual variance per incidence / overall noise scale"
    rows.append([label, f"{_g(min(vals) if vals else None)} to {_g(max(vals) if vals else None)}",
                 _p(lv["min_p_value_sidak"]) + " (Šidák, smallest)",
                 "fails" if "incidence_level" in g["failed"] else "passes"])
    rows.append([f"runs test of residual signs ({rt['ordering']} order)",
                 f"{rt['runs']} runs, {_g(rt['expected_runs'], 5)} expected",
                 f"{_p(rt['p_value'])} (pooled); {_p(rt.get('min_p_value_sidak'))} (Šidák, "
                 "worst incidence)", "fails" if "runs_test" in g["failed"] else "passes"])
    if pp:
        rows.append([f"posterior predictive, worst incidence ({pp['draws']} draws)",
                     f"observed {_g(pp['worst_incidence']['observed_mean'])}, replicated "
                     f"{_g(pp['worst_incidence']['replicated_mean'])}",
                     _p(pp["worst_incidence"]["p_value"]),
                     "fails" if "posterior_predictive" in g["failed"] else "passes"])
        rows.append(["posterior predictive, χ²", f"observed {_g(pp['chi2']['observed_mean'])}, "
                     f"replicated {_g(pp['chi2']['replicated_mean'])}",
                     _p(pp["chi2"]["p_value"]), ""])
    else:
        rows.append(["posterior predictive", "no MCMC run", "", ""])
    body += table_html(["check", "value", "p-value", f"at p < {g['p_fail']:g}"], rows,
                       numeric=(2,))
    body += paragraph(
        f"Noise: {g['noise']}. A check fails below p = {g['p_fail']:g} (at most 0.1% false "
        "alarms for a model that describes the data). The runs test counts sign changes of the "
        "residuals along each scan (rows of one incidence sharing φo, by θo; other rows along "
        "a Hilbert curve over the projected outgoing direction): too few runs means stretches "
        "where the model stays above or below the data, i.e. structure the noise cannot make. "
        "The posterior predictive p-values compare the data with data replicated from the "
        "likelihood the sampler used, at posterior draws; with a fitted noise scale the χ² one "
        "cannot fail, the worst-incidence one can. Formulas: data_formats/fit_json.md.")
    per = [[_g(x["theta_i"]), _g(x["phi_i"]), x["n"], _g(x.get(stat)), _p(x["level_p_value"]),
            x["runs"], _g(x["expected_runs"], 4), _p(x["runs_p_value"])]
           for x in g["per_incidence"]]
    body += table_html(["θi (°)", "φi (°)", "rows fitted",
                        "χ²/dof" if stat == "chi2_per_dof" else "variance ratio", "p-value",
                        "runs", "expected runs", "runs p-value"], per,
                       numeric=(0, 1, 2, 3, 4, 5, 6, 7))
    boot = fit.get("bootstrap")
    if boot and boot.get("skipped"):
        body += note_html(f"No bootstrap: {boot['skipped']}.")
    elif boot and boot.get("replicates"):
        body += paragraph(
            f"Block bootstrap: {boot['replicates']} refits (of {boot['requested']}), each on the "
            f"{boot['blocks']} fitted incidence directions resampled with replacement (whole "
            "incidences, so a misfit's correlated residuals stay together) and refitted from "
            "the least-squares optimum. Its spread is the parameters' sensitivity to which "
            "incidences were measured: it accounts for misfit, where the least-squares errors "
            "and the MCMC posterior assume the model is right."
            + (f" Note: {boot['note']}." if boot.get("note") else ""))
    ivals = intervals(fit, ch.free)
    if any(len(iv) > 1 for _, _, iv in ivals):
        fig = interval_figure(ivals, f"channel {ch.name}: 68% intervals")
        body += rep.figure(
            f"intervals_{tag}", fig,
            f"68% intervals of the free parameters, channel {ch.name}, relative to the best fit "
            "(%): least squares (± 1 standard error; grey), MCMC posterior (16th to 84th "
            "percentile; blue) and block bootstrap over incidences (16th to 84th percentile; "
            "red). Only the bootstrap accounts for misfit.",
            f"Interval comparison for {', '.join(n for n, _, _ in ivals)}")
    return body


__all__ = ["goodness_section", "misfit_sentence", "conditional_note", "has_bootstrap",
           "interval_figure", "intervals"]
