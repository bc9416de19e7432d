"""One fit, end to end: a Measurement and a model in, a FitResult (plain data) out.

Channels are fitted independently (every model parameter per channel), unless parameters are
shared across channels (``share``: one joint problem, fitlab/fitting/joint.py); the result holds
one entry per channel. Rows outside ``--fit-subset`` are not fitted but are predicted, and the
statistics report both (Walter's protocol: fit at normal incidence, predict the others).

A fit that did not go as planned says so: each channel's ``warnings`` (a list of sentences)
names a Levenberg–Marquardt run stopped by its step limit, non-finite costs met by the global
search, starts that disagree, parameters at a bound and an MCMC chain too short to trust. The
parameter file keeps the list (``fits[k].warnings``), the CLI prints it, and
``fit_measurement`` also issues each as a :class:`FitWarning` for Python callers.
"""

from __future__ import annotations

import time
import warnings as _warnings

import numpy as np

from fitlab.fitting.channel import (FitWarning, channel_problem, fitted_rows,
                                    alert_line, least_squares_alerts, least_squares_warnings,
                                    log_line,
                                    non_finite_fit, resolve_fit, statistics)
from fitlab.fitting.least_squares import fit_least_squares
from fitlab.fitting.request import FitRequest
from fitlab.fitting.status import Status
from fitlab.fitting.subset import channel_ids, rows_of


def fit_measurement(m, request: FitRequest, *, warn: bool = True):
    """Fit Measurement ``m`` as ``request`` asks (a checked :class:`FitRequest`; its
    ``subset`` and ``channels`` are checked against ``m`` here); returns a dict (see data_formats/fit_json.md).

    Each channel's entry has ``warnings``, the sentences of what did not go as planned (see the
    module text); with ``warn`` (the default) each is also issued as a :class:`FitWarning`
    (the CLI, which prints the list itself, turns this off). ``request.bootstrap``: refits of
    the block bootstrap over incidences (None: until its intervals settle, at most
    :data:`fitlab.fitting.resampling.DEFAULT_BOOTSTRAP`, where a channel has at least 3 fitted
    incidences, else none; 0: none; skipped where least squares ended at a bound or its
    iteration limit). Rows with an aperture
    (``m.has_aperture``) are fitted by the aperture-averaged model, of quadrature order
    ``request.aperture_order`` (None: chosen automatically, fitlab.fitting.aperture)."""
    t_start = time.perf_counter()
    setup = resolve_fit(m, request)
    model, options, fixed, notes, loss, start = setup
    quiet, seed, n_starts = not request.progress, request.seed, request.starts
    _, rows_fit = rows_of(request.subset, m)
    channels = channel_ids(request.channels, m)
    chan_ids = range(len(m.channel_names)) if channels is None else channels
    fitted = [c for c in chan_ids if np.any((m.channel == c) & rows_fit)]
    share = request.share
    if share and len(fitted) > 1:  # one problem over the channels (fitlab/fitting/joint.py)
        from fitlab.fitting.joint import fit_joint

        results, joint = fit_joint(m, request, setup, rows_fit, fitted)
        _check_models(m, request, results, rows_fit, t_start, quiet)
        for ch in results if warn else ():
            for w in ch["warnings"]:
                _warnings.warn(f"channel {ch['channel']}: {w}", FitWarning, stacklevel=2)
        return {"model": model, "options": options, "fixed": fixed, "loss": loss,
                "notes": notes, "seed": seed, "subset_rows": rows_fit, "channels": results,
                "joint": joint}
    if share:
        notes.append(f"share {', '.join(share)}: only one channel is fitted, so there is "
                     "nothing to share across channels (an independent fit)")
    results = []
    for c in chan_ids:
        name, in_chan, rows = fitted_rows(m, c, rows_fit)
        if rows is None:
            continue
        t0 = time.perf_counter()
        order = auto_order = None
        if m.has_aperture:
            from fitlab.fitting import aperture as _aperture

            order, auto_order = _aperture.start_order(request.aperture_order)
        space, data, start_native = channel_problem(m, model, options, fixed, loss, start, rows,
                                                    name, in_chan, order)
        log_line(quiet, f"fitting {model.name} to channel {name}: {int(rows.sum())} rows, free "
                    f"{', '.join(space.names)}; loss {loss}; global {request.global_search} + {n_starts} starts")
        ls = fit_least_squares(space, data, loss, start_native=start_native, n_starts=n_starts,
                               seed=seed, lm_maxiter=request.lm_maxiter, progress=not quiet,
                               search=request.global_search, solver=request.local_solver)
        t_ls = time.perf_counter() - t0
        if ls.solver["stopped"] == Status.NON_FINITE:
            raise non_finite_fit(f"{m.path}: channel {name}", len(ls.starts))
        channel_warnings = least_squares_warnings(ls)
        log_line(quiet, "  least squares: " + ", ".join(
            f"{k} = {v:.6g} ± {s:.2g}" for k, v, s in zip(space.names, ls.native, ls.stderr))
            + f"  ({t_ls:.2f} s)")
        aperture = None
        if order is not None:
            def refit(d, start_at):
                return fit_least_squares(space, d, loss, start_native=start_at,
                                         n_starts=n_starts, seed=seed,
                                         lm_maxiter=request.lm_maxiter, progress=not quiet,
                                         search=request.global_search,
                                         solver=request.local_solver)

            ls, data, aperture, more = _aperture.settle_order(
                space, ls, data, m, rows, loss, order, auto=auto_order, refit=refit,
                log=lambda msg: log_line(quiet, msg))
            order = aperture["order"]
            channel_warnings = least_squares_warnings(ls) + more
            t_ls = time.perf_counter() - t0
        for alert in least_squares_alerts(ls, space.names):  # now, before MCMC and bootstrap
            alert_line(quiet, f"warning: channel {name}: {alert}")
        chain = None
        if request.mcmc:
            from fitlab.fitting.samplers import sample_posterior  # the samplers load only here

            log_line(quiet, f"  MCMC ({request.sampler}): {request.mcmc_steps} steps")
            chain = sample_posterior(request.sampler, space, data, loss, ls, seed=seed,
                                     nsteps=request.mcmc_steps, walkers=request.walkers,
                                     progress=not quiet)
            channel_warnings += chain.warnings
        # Predictions for every row of this channel (fitted or not).
        if order is None:
            full = space.predict(ls.native, m.wi[in_chan], m.wo[in_chan])
        else:
            full = _aperture.predict_rows(space, ls.native, m, in_chan, order)
        sub = m.select(in_chan)
        stats = statistics(sub, rows_fit[in_chan], full, ls,
                           None if m.sigma is None else m.sigma[in_chan], loss)
        # Goodness of fit and the block bootstrap (fitlab.fitting.goodness, .resampling).
        from fitlab.fitting.resampling import channel_misfit

        misfit = channel_misfit(m, rows, space, data, loss, ls, chain, request,
                                log=lambda msg: log_line(quiet, msg))
        channel_warnings += misfit["warnings"]
        results.append({"channel": name, "space": space, "ls": ls, "mcmc": chain,
                        "statistics": stats, "seconds_least_squares": t_ls,
                        "goodness": misfit["goodness"], "bootstrap": misfit["bootstrap"],
                        "seconds_bootstrap": misfit["seconds"],
                        "prediction": full, "rows": np.flatnonzero(in_chan),
                        "warnings": channel_warnings,
                        **({"aperture": aperture} if aperture is not None else {})})
        _check_models(m, request, results[-1:], rows_fit, t_start, quiet)
        if warn:
            for w in channel_warnings:
                _warnings.warn(f"channel {name}: {w}", FitWarning, stacklevel=2)
    return {"model": model, "options": options, "fixed": fixed, "loss": loss,
            "notes": notes, "seed": seed, "subset_rows": rows_fit, "channels": results}


def _check_models(m, request, results, rows_fit, t_start, quiet) -> None:
    """The model check of each channel in ``results`` (fitlab.fitting.model_check), its budget
    from the fit's time since ``t_start``."""
    from fitlab.fitting.model_check import check_fit

    check_fit(m, results, rows_fit, mode=request.check_model,
              fit_seconds=time.perf_counter() - t_start, seed=request.seed,
              log=lambda msg: log_line(quiet, msg))
