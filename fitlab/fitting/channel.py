"""One channel's fit problem, as an independent fit and a joint fit (fitlab/fitting/joint.py)
both build it: its rows, its parameter space and data, the statistics over its rows and the
warnings its least-squares run gives. fitlab/fitting/driver.py runs the fit end to end."""

from __future__ import annotations

import sys
from typing import NamedTuple

import numpy as np

from fitlab.api import check_params
from fitlab.errors import FitlabError
from fitlab.fitting.least_squares import FitData
from fitlab.fitting import progress
from fitlab.fitting.losses import loss_weights
from fitlab.fitting.space import SCALE, FreeParameter, make_space, model_values
from fitlab.fitting.status import Status
from fitlab.metrics import fit_error, incidence_keys
from fitlab.models import Model

#: The fit error (statistics.fit_error) is fitlab.metrics.fit_error: rows below 1% of their
#: incidence's peak are left out (data_formats/fit_json.md, "The fit error").


class FitWarning(UserWarning):
    """A fit finished but is not to be trusted as it stands (the message says why and what to
    do); the same text is in the channel's ``warnings``."""


def least_squares_warnings(ls) -> list[str]:
    """Sentences for what went wrong in the least-squares stage of one channel."""
    out = []
    sol = ls.solver
    if sol["stopped"] == Status.MAX_ITERATIONS:
        out.append(f"Levenberg-Marquardt stopped at its iteration limit ({sol['max_iterations']} "
                   "iterations) before its stopping rule was met: the optimum may not be "
                   "reached; check the parameters, or refit with more iterations "
                   "(--lm-maxiter, or lm_maxiter in Python) or a better start")
    elif sol["stopped"] == Status.NON_FINITE:
        out.append("Levenberg-Marquardt ended with a non-finite cost (NaN or inf) from every "
                   "start: the model or the loss is not finite for these data; check the data "
                   "(zero or negative values with the log loss, zero sigma) and the fixed "
                   "parameters")
    lost = sum(st["lm_stopped"] == Status.NON_FINITE for st in ls.starts)
    if lost and sol["stopped"] != Status.NON_FINITE:
        out.append(f"{lost} of {len(ls.starts)} Levenberg-Marquardt starts ended at NaN or inf "
                   "(e.g. where the model is exactly 0 at every measured direction, so the cost "
                   "is flat) and were left out; the fit comes from the others")
    g = ls.global_search
    if g.get("non_finite"):
        out.append(f"the global search met a non-finite cost (NaN or inf) at {g['non_finite']} "
                   f"of {g['evaluations']} evaluations: the model or the loss is not finite in "
                   "part of the parameter box (those points were treated as infinitely bad)")
    if ls.disagreement:
        out.append(ls.disagreement["message"])
    for p in ls.at_bound:
        out.append(f"{p} ended at a bound of its range; its uncertainty is not meaningful")
    return out


def least_squares_alerts(ls, names=None) -> list[str]:
    """What to say the moment least squares ends, before the bootstrap and MCMC run: that its
    Levenberg–Marquardt run stopped at its iteration limit, or that parameters ended at a bound
    of their range, each with what to try (the Status's advice). ``names``: the coordinates'
    names (default ``ls``'s start records')."""
    out = []
    if ls.solver["stopped"] == Status.MAX_ITERATIONS:
        out.append(f"least squares stopped at its iteration limit ({ls.solver['max_iterations']} "
                   f"Levenberg-Marquardt steps) before converging: "
                   f"{Status.MAX_ITERATIONS.advice}")
    if ls.at_bound:
        names = list(names if names is not None else ls.starts[0]["start"])
        at = ", ".join(f"{p} = {ls.native[names.index(p)]:.6g}" if p in names else p
                       for p in ls.at_bound)
        out.append(f"least squares ended at a bound of the range: {at}; try: "
                   f"{Status.AT_BOUND.advice}")
    if out:
        out[-1] += " (the bootstrap is skipped for this fit)"
    return out


def log_line(quiet, msg):
    if not quiet:
        progress.line(msg)


def alert_line(quiet, msg):
    """A warning said the moment it is known (least_squares_alerts): its own line on stderr,
    also where progress lines are brief (a status line on the terminal is cleared first)."""
    if quiet:
        return
    if sys.stderr.isatty():
        sys.stderr.write("\r\x1b[K")
    print(msg, file=sys.stderr, flush=True)


def _scale_reference(model, options, start, m, rows, in_chan, memo=None):
    """Least-squares scale of the model at ``start`` to the fitted rows' values
    (:func:`scale_of`). The model is evaluated on every row of the channel (the shape the final
    prediction uses too, so both are one compiled kernel). ``memo``: a dict kept by the caller
    across datasets of one request, where the model's values on the same directions are looked
    up instead of evaluated."""
    f_all = _start_values(model, options, start, m, in_chan, memo)
    return scale_of(f_all[rows[in_chan]], m.value[rows])


def _start_values(model, options, start, m, in_chan, memo=None):
    """The model's values at ``start`` on the channel's rows (looked up in ``memo`` by the
    start and the directions, else evaluated and kept there)."""
    wi, wo = m.wi[in_chan], m.wo[in_chan]
    key = None if memo is None else (tuple(sorted(start.items())), wi.tobytes(), wo.tobytes())
    f_all = None if memo is None else memo.get(key)
    if f_all is None:
        f_all = model_values(model, tuple(sorted(options.items())), start, wi, wo)
        if memo is not None:
            memo[key] = f_all
    return f_all


def scale_of(f, v) -> float:
    """The least-squares scale s of model values ``f`` to data ``v`` (min |s f - v|²); where
    that is not finite or not positive, the median of |v| over the median of f on the rows
    where f > 0 (1 if none); at least 1e-300."""
    den = float(f @ f)
    s = float(v @ f) / den if den > 0 else 0.0
    if not np.isfinite(s) or s <= 0:
        pos = f > 0
        s = float(np.median(np.abs(v[pos])) / np.median(f[pos])) if pos.any() else 1.0
    return max(s, 1e-300)


def statistics(m, rows_fit, pred, ls, data_sigma, loss):
    """Fit statistics of one channel: the fit error over the fitted rows (``fit_error``, the one
    definition: fitlab.metrics.fit_error), the same over the rows not fitted
    (``prediction_error``, None when every row was fitted) and per incidence direction over all
    rows (``per_incidence``, each incidence's floor from its own rows)."""
    fit_err = fit_error(pred[rows_fit], m.value[rows_fit], m.theta_i[rows_fit],
                        m.phi_i[rows_fit])
    rest = ~rows_fit
    stats = {
        "loss": loss,
        "n_fit": int(rows_fit.sum()),
        "n_total": int(rows_fit.size),
        "cost": ls.cost,
        "dof": ls.dof,
        "residual_noise_scale": ls.noise_scale,
        "fit_error": fit_err,
        "prediction_error": (fit_error(pred[rest], m.value[rest], m.theta_i[rest], m.phi_i[rest])
                             if rest.any() else None),
    }
    if data_sigma is not None:
        chi2 = float(np.sum(((pred[rows_fit] - m.value[rows_fit]) / data_sigma[rows_fit]) ** 2))
        stats["chi2"] = chi2
        stats["chi2_per_dof"] = chi2 / ls.dof
    every = fit_error(pred, m.value, m.theta_i, m.phi_i)["per_incidence"]
    keys = incidence_keys(m.theta_i, m.phi_i)
    per = []
    for row in every:
        sel = (keys[:, 0] == row["theta_i"]) & (keys[:, 1] == row["phi_i"])
        in_fit = rows_fit[sel]
        per.append({
            "theta_i": row["theta_i"], "phi_i": row["phi_i"], "n": row["rows"],
            "n_fitted": int(in_fit.sum()),
            "role": "fit" if in_fit.all() else ("prediction" if not in_fit.any() else "partly fit"),
            "rms_relative_error": row["rms_relative_error"],
            "max_abs_relative_error": row["max_abs_relative_error"],
        })
    stats["per_incidence"] = per
    return stats


def non_finite_fit(where: str, n_starts: int) -> FitlabError:
    """The error of a fit whose every Levenberg-Marquardt start ended at NaN or inf."""
    return FitlabError(
        f"{where}: the fit did not reach finite values from any of its {n_starts} starts "
        "(every Levenberg-Marquardt run ended at NaN or inf); nothing was written. Check the "
        "data (zero or negative values with the log loss, zero sigma), the fixed parameters "
        "and the model's options")


def fitted_rows(m, c, rows_fit):
    """(name, rows of channel ``c``, its rows to fit) — rows None when none is to be fitted; a
    channel whose fitted values are all 0 is an error naming the file."""
    name = m.channel_names[c]
    in_chan = m.channel == c
    rows = in_chan & rows_fit
    if rows.sum() == 0:
        return name, in_chan, None
    if not np.any(m.value[rows] != 0):
        raise FitlabError(f"{m.path}: every value of channel {name} that would be fitted is "
                          "0: there is nothing to fit; check the value column (and "
                          "--fit-subset)")
    wo = m.wo[rows]
    if rows.sum() > 1 and np.all(np.abs(wo - wo[0]) <= VIEW_TOLERANCE):
        j = int(np.flatnonzero(rows)[0])
        raise FitlabError(
            f"{m.path}: the {int(rows.sum())} rows of channel {name} to fit share one view "
            f"direction (θo = {m.theta_o[j]:g}°, φo = {m.phi_o[j]:g}°): they vary the incidence "
            "only, and one view direction cannot constrain a BRDF model's lobe (fitlab fits "
            "rows that vary the view direction); give a measurement with several view "
            "directions (e.g. a scan of θo at each incidence), or a --fit-subset that keeps "
            "rows of several")
    return name, in_chan, rows


#: Two view directions closer than this (unit-vector components) are one (fitted_rows).
VIEW_TOLERANCE = 1e-9


class FitSetup(NamedTuple):
    """What every channel of one measurement's fit shares: the model, its options, the fixed
    parameters, notes for the user, the loss and the extra start point (:func:`resolve_fit`)."""

    model: Model
    options: dict
    fixed: dict
    notes: list
    loss: str
    start: dict


def resolve_fit(m, request) -> FitSetup:
    """``request`` (a checked :class:`fitlab.fitting.request.FitRequest`) resolved against
    measurement ``m``: eta fixed from the data file unless freed or fixed, the loss by the data
    (chi2 with sigma, else relative) unless given, the extra start (the model's defaults
    overridden by ``request.start``, fixed values where fixed)."""
    model, fixed, notes = request.model, dict(request.fix), []
    eta_file = m.eta()
    if eta_file is not None and "eta" in model.parameter_names and "eta" not in fixed \
            and "eta" not in request.free:
        fixed["eta"] = eta_file
        notes.append(f"eta fixed to {eta_file:.6g} = eta_inside/eta_outside from the data file "
                     "(use --free eta to fit it)")
        if "eta" in request.start:
            raise ValueError("--start eta: eta is fixed from the data file (--free eta to fit "
                             "it); a start is for a parameter the fit moves")
        check_params(model, {**{p.name: p.default for p in model.parameters}, **fixed})
    loss = request.loss or ("chi2" if m.sigma is not None else "relative")
    start = {p.name: fixed.get(p.name, request.start.get(p.name, p.default))
             for p in model.parameters}
    return FitSetup(model, dict(request.options), fixed, notes, loss, start)


def channel_problem(m, model, options, fixed, loss, start, rows, name, in_chan,
                    aperture_order=None, memo=None):
    """The fit space, the data of the fitted ``rows`` (within the channel's rows ``in_chan``) and
    the extra start (native units). With ``aperture_order``, the data carry the aperture
    quadrature of that order (fitlab.fitting.aperture). ``memo``: see
    :func:`_scale_reference` (the batched fits pass one)."""
    scale_bounds = None
    if m.is_relative:
        s_ref = _scale_reference(model, options, start, m, rows, in_chan, memo)
        scale_bounds = (s_ref * 1e-4, s_ref * 1e4)
    space = make_space(model, options, fixed, m.is_relative, scale_bounds)
    if rows.sum() <= space.ndim:
        raise ValueError(f"channel {name}: {int(rows.sum())} rows cannot constrain "
                         f"{space.ndim} free parameters ({', '.join(space.names)})")
    sigma = None if m.sigma is None else m.sigma[rows]
    consts = loss_weights(loss, m.value[rows], sigma, m.wo[rows, 2])
    # host arrays: the kernels' arguments go to the device once per fit (least_squares.problem_of),
    # and a batched fit stacks thousands of these on the host first
    data = FitData(np.asarray(m.wi[rows], float), np.asarray(m.wo[rows], float),
                   np.asarray(m.value[rows], float),
                   {k: np.asarray(v, float) for k, v in consts.items()})
    if aperture_order is not None:
        from fitlab.fitting.aperture import with_nodes

        data = with_nodes(data, m, rows, aperture_order)
    start_native = [start[p.name] if p.name != SCALE else np.sqrt(np.prod(scale_bounds))
                    for p in space.free]
    return space, data, start_native


def channel_problems_like(space, data, start_native, loss, values, sigma=None, f_start=None):
    """The problems of datasets measured on the rows of one channel problem (``space``,
    ``data``, ``start_native``: what :func:`channel_problem` made for the first of them) with
    values of their own (``values``, and ``sigma`` or None: one dataset per row, the rows on the
    last axis): per dataset (space, data, start_native) as channel_problem makes them from its
    measurement (the same numbers: tested), the loss's constants of all at once, sharing the
    first's direction arrays and, but for a relative fit, its space. ``f_start``: a relative
    fit's model values at the start on the rows, each dataset's scale reference
    (:func:`scale_of`) from them. The batched fits (fitlab.fitting.many) build thousands of
    datasets of one instrument this way."""
    values = np.asarray(values, float)
    sigma = None if sigma is None else np.asarray(sigma, float)
    consts = loss_weights(loss, values, sigma, data.wo[:, 2])
    keys = list(consts)  # a constant per dataset (rows on the last axis) or one for all
    per = [list(x) if np.ndim(x) == 2 else [x] * len(values) for x in consts.values()]
    datas = [FitData(data.wi, data.wo, v, dict(zip(keys, own)), data.weights)
             for v, *own in zip(values, *per)]
    start = np.asarray(start_native, float)
    if not space.relative:
        return [space] * len(values), datas, [start] * len(values)
    s = np.array([scale_of(f_start, np.array(v)) for v in values])  # a fresh array, as
    # channel_problem's (BLAS's dot may round by the alignment of its operands)
    lo, hi = s * 1e-4, s * 1e4  # channel_problem's scale bounds
    k, unit = space.names.index(SCALE), space.free[-1].unit
    spaces = [space._replace(free=space.free[:-1] + (FreeParameter(SCALE, a, b, True, unit),))
              for a, b in zip(lo.tolist(), hi.tolist())]
    starts = np.repeat(start[None], len(values), axis=0)
    starts[:, k] = np.sqrt(lo * hi)
    return spaces, datas, list(starts)


def prepare_channel(m, model, *, rows, channel=0, aperture_order=None, **settings):
    """What ``fit_measurement`` hands the least-squares stage for one channel (benchmarks and
    tests use it to reproduce a fit exactly): a dict with space, data, loss, start_native.
    ``model`` and ``settings`` make a :class:`fitlab.fitting.request.FitRequest` (``fix``,
    ``free``, ``options``, ``loss``, …)."""
    from fitlab.fitting.request import as_request

    model, options, fixed, notes, loss, start = resolve_fit(m, as_request(model, settings))
    in_chan = m.channel == channel
    rows = np.asarray(rows, dtype=bool) & in_chan
    space, data, start_native = channel_problem(m, model, options, fixed, loss, start, rows,
                                                m.channel_names[channel], in_chan,
                                                aperture_order)
    return {"space": space, "data": data, "loss": loss, "start_native": start_native,
            "fixed": fixed, "options": options, "notes": notes}
