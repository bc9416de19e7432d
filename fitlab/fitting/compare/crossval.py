"""Incidences, relative errors, the jackknife, and leave-one-incidence-out cross-validation of
one candidate (its in-sample error is its fit's stored ``statistics.fit_error``, the same rule)."""

from __future__ import annotations

import math

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.compare.candidates import Resolved
from fitlab.fitting.status import Status
from fitlab.metrics import relative_errors


# --------------------------------------------------------------------------------------------
# Incidences, relative errors, the jackknife
# --------------------------------------------------------------------------------------------


def incidence_keys(m) -> np.ndarray:
    """(θi, φi mod 360) of every row, degrees (the fit statistics' grouping)."""
    return np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)


def incidences_of(m, rows) -> list[tuple[float, float]]:
    keys = incidence_keys(m)[rows]
    return [(float(t), float(p)) for t, p in np.unique(keys, axis=0)] if keys.size else []


def _rms(x) -> float | None:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def jackknife_difference(sq_a, sq_b, counts) -> tuple[float, float]:
    """(Δ, its standard error) of Δ = RMS_a − RMS_b, where fold k holds ``counts[k]`` rows whose
    squared errors sum to ``sq_a[k]`` and ``sq_b[k]``: the delete-one-fold jackknife."""
    sq_a, sq_b, n = (np.asarray(x, float) for x in (sq_a, sq_b, counts))
    full = math.sqrt(sq_a.sum() / n.sum()) - math.sqrt(sq_b.sum() / n.sum())
    k = n.size
    if k < 2:
        return full, float("nan")
    rest = n.sum() - n
    ok = rest > 0
    d = np.sqrt((sq_a.sum() - sq_a[ok]) / rest[ok]) - np.sqrt((sq_b.sum() - sq_b[ok]) / rest[ok])
    se = math.sqrt((k - 1) / k * float(np.sum((d - d.mean()) ** 2)))
    return full, se


# --------------------------------------------------------------------------------------------
# Cross-validation
# --------------------------------------------------------------------------------------------


def _masked(data_all, data_kept, kept):
    """``data_all`` (every row of the fit) with the loss constants of a fit to the ``kept``
    rows, and the row mask that zeroes the others (their constants are a kept row's: finite)."""
    from fitlab._jax import jax

    from fitlab.fitting.least_squares import ROW_MASK

    consts = {}
    for key, v in data_kept.consts.items():
        v = np.asarray(v)
        full = np.empty(kept.shape + v.shape[1:], v.dtype)
        full[kept] = v
        full[~kept] = v[0]
        consts[key] = full
    consts[ROW_MASK] = kept.astype(np.float64)
    return jax.device_put(data_all._replace(consts=consts))


def aperture_order(result, channel_name):
    """The aperture quadrature order a fit used for a channel (data with an aperture), or None."""
    return (result._fit(channel_name).get("aperture") or {}).get("order")


def _predict(space, native, m, in_chan, order=None):
    """The model at every row of a channel, as the fit predicts them (fitlab.fitting.driver):
    at the rows' directions, or averaged over their apertures."""
    if order is None:
        return space.predict(native, m.wi[in_chan], m.wo[in_chan])
    from fitlab.fitting.aperture import predict_rows

    return predict_rows(space, native, m, in_chan, order)


def _channel_problem(m, base, rows, order):
    from fitlab.fitting.channel import channel_problem

    extra = {} if order is None else {"aperture_order": order}
    return channel_problem(m, base["model"], base["options"], base["fixed"], base["loss"],
                           base["start"], rows, m.channel_names[base["channel"]],
                           base["in_chan"], **extra)


def _problem(m, cand: Resolved, loss, rows, channel, order=None):
    """(model, options, fixed, loss, start, space, data) of a fit of ``rows`` of a channel,
    exactly as fitlab.fit builds it (``order``: its aperture quadrature order, if any)."""
    from fitlab.fitting.channel import resolve_fit

    mdl, options, fixed, _, loss, start = resolve_fit(
        m, cand.request if cand.request.loss == loss else cand.request.replace(loss=loss))
    base = {"model": mdl, "options": options, "fixed": fixed, "loss": loss, "start": start,
            "channel": channel, "in_chan": m.channel == channel, "order": order}
    space, data, start_native = _channel_problem(m, base, rows, order)
    return {**base, "space": space, "data": data, "start_native": start_native}


def batched_folds(m, base, rows, incs, fit: dict, lm_maxiter, order=None, solver=None):
    """Every leave-one-incidence-out fold of one candidate refitted at once: each fold is one
    lane of the full fit's compiled Levenberg–Marquardt stage (as many lanes per call as the
    full fit had starts), started at the full fit's optimum, its data the full fit's rows with
    the held-out incidence's rows weighted 0 and every other row's loss constant that of a fit
    to the kept rows (the relative loss's 1% floor of the kept rows: the weight is the ratio of
    the two constants, so a lane's residuals are exactly the fold's). Returns one dict per fold
    (as :func:`cross_validate`)."""
    from types import SimpleNamespace

    from fitlab.fitting.channel import least_squares_warnings
    from fitlab.fitting.exchange import canonical_runs
    from fitlab.fitting.least_squares import (kernels, local_fits, lm_stop_reason, pad_rows,
                                              problem_of)
    from fitlab.fitting.losses import loss_weights
    from fitlab.fitting.solvers import DEFAULT_LOCAL_SOLVER

    space, data, loss = base["space"], base["data"], base["loss"]
    k = kernels(space.static, loss, int(lm_maxiter), solver or DEFAULT_LOCAL_SOLVER)
    padded = pad_rows(space.static, data)
    problem = problem_of(space, padded)
    n_pad, n = int(padded.value.shape[0]), int(rows.sum())
    batch = len(fit["starts"])
    u0 = space.to_unit(np.array([fit["parameters"][p]["value"] for p in space.names], float))
    keys = incidence_keys(m)
    w_full = np.asarray(data.consts["w"], float) if "w" in data.consts else None
    plan = []
    for ti, pi in incs:
        held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        kept = rows & ~held
        w = np.zeros(n_pad)
        w[:n][kept[rows]] = 1.0
        if w_full is not None:
            sigma = None if m.sigma is None else m.sigma[kept]
            w[:n][kept[rows]] = (loss_weights(loss, m.value[kept], sigma, m.wo[kept, 2])["w"]
                                 / w_full[kept[rows]])
        plan.append((ti, pi, held, w))
    folds = []
    for start in range(0, len(plan), batch):
        part = plan[start:start + batch]
        W = np.stack([w for *_, w in part] + [part[0][3]] * (batch - len(part)))
        loc = canonical_runs(space, local_fits(k, problem, [u0] * batch, weights=W))
        for i, (ti, pi, held, _) in enumerate(part):
            fold = {"theta_i": ti, "phi_i": pi, "rel": np.zeros(0), "parameters": None,
                    "warnings": [], "error": None}
            cost = float(loc["cost"][i]) if loc["end_finite"][i] else np.nan
            stopped = lm_stop_reason(cost, int(loc["iters"][i]), bool(loc["rule_unmet"][i]),
                                     int(lm_maxiter))
            if stopped == Status.NON_FINITE:
                fold["error"] = "no start reached a finite cost"
            else:
                native = loc["native"][i]
                pred = _predict(space, native, m, base["in_chan"], order)[held[base["in_chan"]]]
                fold["rel"], _ = relative_errors(pred, m.value[held])
                fold["parameters"] = {p: float(v) for p, v in zip(space.names, native)}
                u = loc["u"][i]
                ls = SimpleNamespace(
                    solver={"stopped": stopped, "max_iterations": int(lm_maxiter)},
                    starts=[{"lm_stopped": stopped}], global_search={}, disagreement=None,
                    at_bound=tuple(p for p, x in zip(space.names, u)
                                   if x < 1e-6 or x > 1 - 1e-6))
                fold["warnings"] = least_squares_warnings(ls)
            folds.append(fold)
    return folds


def cross_validate(m, cand: Resolved, loss, rows, channel, *, seed=0, starts=8, order=None,
                   on_fold=None, fit=None):
    """Leave-one-incidence-out CV of one candidate on one channel's ``rows`` (bool, all rows of
    the measurement; ``order``: the fit's aperture quadrature order, if any). Returns one dict
    per incidence: theta_i, phi_i, rel (held-out relative errors of the counted rows),
    parameters (the fold's fit), warnings, error (a fold that could not be fitted).

    With ``fit`` (the channel's entry of the candidate's full fit) the folds are refitted
    together by Levenberg–Marquardt from the full fit's optimum (:func:`batched_folds`), without
    a global search of their own; without it, by the whole procedure
    (global search and multi-start Levenberg–Marquardt with ``starts`` and ``seed``)."""
    from fitlab.fitting.channel import least_squares_warnings
    from fitlab.fitting.least_squares import fit_least_squares

    base = _problem(m, cand, loss, rows, channel, order)
    if fit is not None:
        folds = batched_folds(m, base, rows, incidences_of(m, rows), fit,
                              cand.request.lm_maxiter, order, cand.request.local_solver)
        for fold in folds if on_fold is not None else ():
            on_fold(fold)
        return folds
    in_chan = base["in_chan"]
    keys = incidence_keys(m)
    folds = []
    for ti, pi in incidences_of(m, rows):
        held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        kept = rows & ~held
        fold = {"theta_i": ti, "phi_i": pi, "rel": np.zeros(0), "parameters": None,
                "warnings": [], "error": None}
        try:
            space, data_k, start_native = _channel_problem(m, base, kept, order)
            data = _masked(base["data"], data_k, kept[rows])
            ls = fit_least_squares(space, data, base["loss"], start_native=start_native,
                                   n_starts=starts, seed=seed,
                                   lm_maxiter=cand.request.lm_maxiter,
                                   search=cand.request.global_search,
                                   solver=cand.request.local_solver)
            if ls.solver["stopped"] == Status.NON_FINITE:
                raise ValueError("no start reached a finite cost")
            pred = _predict(space, ls.native, m, in_chan, order)[held[in_chan]]
            fold["rel"], _ = relative_errors(pred, m.value[held])
            fold["parameters"] = {n: float(v) for n, v in zip(space.names, ls.native)}
            fold["warnings"] = least_squares_warnings(ls)
        except (ValueError, FitlabError) as exc:
            fold["error"] = str(exc)
        folds.append(fold)
        if on_fold is not None:
            on_fold(fold)
    return folds
