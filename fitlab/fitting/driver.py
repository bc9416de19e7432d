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

import sys
import time
import warnings as _warnings

import jax
import numpy as np

from fitlab.api import check_params, resolve_options
from fitlab.errors import FitlabError
from fitlab.fitting.least_squares import LM_MAXITER, FitData, fit_least_squares
from fitlab.fitting.losses import loss_weights
from fitlab.fitting.space import SCALE, make_space, model_values
from fitlab.models import get_model

#: Rows whose |value| is below this fraction of the channel's maximum are left out of relative
#: error statistics (relative errors of near-zero data are meaningless).
REL_ERR_FLOOR = 0.01


class FitWarning(UserWarning):
    """A fit finished but is not to be trusted as it stands (the message says why and what to
    do); the same text is in the channel's ``warnings``."""


def least_squares_warnings(ls) -> list[str]:
    """Sentences for what went wrong in the least-squares stage of one channel."""
    out = []
    sol = ls.solver
    if sol["stopped"] == "max_iterations":
        out.append(f"Levenberg-Marquardt stopped at its iteration limit ({sol['max_iterations']} "
                   "iterations) before its stopping rule was met: the optimum may not be "
                   "reached; check the parameters, or refit with more iterations "
                   "(--lm-maxiter, or lm_maxiter in Python) or a better start")
    elif sol["stopped"] == "non_finite":
        out.append("Levenberg-Marquardt ended with a non-finite cost (NaN or inf) from every "
                   "start: the model or the loss is not finite for these data; check the data "
                   "(zero or negative values with the log loss, zero sigma) and the fixed "
                   "parameters")
    lost = sum(st["lm_stopped"] == "non_finite" for st in ls.starts)
    if lost and sol["stopped"] != "non_finite":
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


def _log(quiet, msg):
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def _scale_reference(model, options, start, m, rows, in_chan):
    """Least-squares scale of the model at ``start`` to the fitted rows' values. The model is
    evaluated on every row of the channel (the shape the final prediction uses too, so both are
    one compiled kernel)."""
    f = model_values(model, tuple(sorted(options.items())), start, m.wi[in_chan],
                     m.wo[in_chan])[rows[in_chan]]
    v = m.value[rows]
    den = float(f @ f)
    s = float(v @ f) / den if den > 0 else 0.0
    if not np.isfinite(s) or s <= 0:
        pos = f > 0
        s = float(np.median(np.abs(v[pos])) / np.median(f[pos])) if pos.any() else 1.0
    return max(s, 1e-300)


def relative_errors(pred, value):
    floor = REL_ERR_FLOOR * np.max(np.abs(value)) if value.size else 0.0
    keep = np.abs(value) >= floor
    return (pred[keep] - value[keep]) / value[keep], keep


def _rms(x):
    return float(np.sqrt(np.mean(x**2))) if x.size else None


def statistics(m, rows_fit, pred, ls, data_sigma, loss):
    """Fit statistics over the fitted rows and per incidence direction over all rows."""
    rel_fit, _ = relative_errors(pred[rows_fit], m.value[rows_fit])
    stats = {
        "loss": loss,
        "n_fit": int(rows_fit.sum()),
        "n_total": int(rows_fit.size),
        "cost": ls.cost,
        "dof": ls.dof,
        "residual_noise_scale": ls.noise_scale,
        "rms_relative_error_fit": float(np.sqrt(np.mean(rel_fit**2))) if rel_fit.size else None,
        "relative_error_floor": REL_ERR_FLOOR,
    }
    if data_sigma is not None:
        chi2 = float(np.sum(((pred[rows_fit] - m.value[rows_fit]) / data_sigma[rows_fit]) ** 2))
        stats["chi2"] = chi2
        stats["chi2_per_dof"] = chi2 / ls.dof
    per = []
    keys = np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)
    for ti, pi in np.unique(keys, axis=0):
        sel = (keys[:, 0] == ti) & (keys[:, 1] == pi)
        rel, keep = relative_errors(pred[sel], m.value[sel])
        in_fit = rows_fit[sel]
        per.append({
            "theta_i": float(ti), "phi_i": float(pi), "n": int(sel.sum()),
            "n_fitted": int(in_fit.sum()),
            "role": "fit" if in_fit.all() else ("prediction" if not in_fit.any() else "partly fit"),
            "rms_relative_error": float(np.sqrt(np.mean(rel**2))) if rel.size else None,
            "max_abs_relative_error": float(np.max(np.abs(rel))) if rel.size else None,
            "rms_relative_error_fitted_rows": _rms(rel[in_fit[keep]]),
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
    return name, in_chan, rows


def resolve_fit(m, model_name, *, options=None, fixed=None, free=(), loss=None, start=None):
    """The model, its options, the fixed parameters (eta from the data file unless freed), notes
    for the user, the loss and the extra start point (the model's defaults, overridden by
    ``start``): everything channels share."""
    model = get_model(model_name)
    options = resolve_options(model, options)
    fixed = dict(fixed or {})
    notes = []
    eta_file = m.eta()
    if eta_file is not None and "eta" in model.parameter_names and "eta" not in fixed \
            and "eta" not in free:
        fixed["eta"] = eta_file
        notes.append(f"eta fixed to {eta_file:.6g} = eta_inside/eta_outside from the data file "
                     "(use --free eta to fit it)")
    for name in fixed:
        if name not in model.parameter_names:
            raise ValueError(f"--fix {name}: model {model.name!r} has no parameter {name!r} "
                             f"(its parameters: {', '.join(model.parameter_names)})")
    check_params(model, {**{p.name: p.default for p in model.parameters}, **fixed})
    loss = loss or ("chi2" if m.sigma is not None else "relative")
    start = dict(start or {})
    for name in start:
        if name in fixed:
            raise ValueError(f"--start {name}: {name} is fixed"
                             + (" from the data file (--free eta to fit it)"
                                if name == "eta" and eta_file is not None else "")
                             + "; a start is for a parameter the fit moves")
    check_params(model, {**{p.name: p.default for p in model.parameters}, **start, **fixed})
    start = {p.name: fixed.get(p.name, start.get(p.name, p.default)) for p in model.parameters}
    return model, options, fixed, notes, loss, start


def channel_problem(m, model, options, fixed, loss, start, rows, name, in_chan,
                    aperture_order=None):
    """The fit space, the data of the fitted ``rows`` (within the channel's rows ``in_chan``) and
    the extra start (native units). With ``aperture_order``, the data carry the aperture
    quadrature of that order (fitlab.fitting.aperture)."""
    scale_bounds = None
    if m.is_relative:
        s_ref = _scale_reference(model, options, start, m, rows, in_chan)
        scale_bounds = (s_ref * 1e-4, s_ref * 1e4)
    space = make_space(model, options, fixed, m.is_relative, scale_bounds)
    if rows.sum() <= space.ndim:
        raise ValueError(f"channel {name}: {int(rows.sum())} rows cannot constrain "
                         f"{space.ndim} free parameters ({', '.join(space.names)})")
    sigma = None if m.sigma is None else m.sigma[rows]
    consts = loss_weights(loss, m.value[rows], sigma, m.wo[rows, 2])
    data = jax.device_put(FitData(np.asarray(m.wi[rows], float), np.asarray(m.wo[rows], float),
                                  np.asarray(m.value[rows], float),
                                  {k: np.asarray(v, float) for k, v in consts.items()}))
    if aperture_order is not None:
        from fitlab.fitting.aperture import with_nodes

        data = with_nodes(data, m, rows, aperture_order)
    start_native = [start[p.name] if p.name != SCALE else np.sqrt(np.prod(scale_bounds))
                    for p in space.free]
    return space, data, start_native


def prepare_channel(m, model_name, *, rows, channel=0, options=None, fixed=None, free=(),
                    loss=None, aperture_order=None):
    """What ``fit_measurement`` hands the least-squares stage for one channel (benchmarks and
    tests use it to reproduce a fit exactly): a dict with space, data, loss, start_native."""
    model, options, fixed, notes, loss, start = resolve_fit(m, model_name, options=options,
                                                            fixed=fixed, free=free, loss=loss)
    in_chan = m.channel == channel
    rows = np.asarray(rows, dtype=bool) & in_chan
    space, data, start_native = channel_problem(m, model, options, fixed, loss, start, rows,
                                                m.channel_names[channel], in_chan,
                                                aperture_order)
    return {"space": space, "data": data, "loss": loss, "start_native": start_native,
            "fixed": fixed, "options": options, "notes": notes}


def fit_measurement(m, model_name, *, options=None, fixed=None, free=(), loss=None,
                    subset=None, mcmc=False, mcmc_steps=3000, mcmc_walkers=None, seed=0,
                    n_starts=8, quiet=False, channels=None, lm_maxiter=LM_MAXITER, warn=True,
                    aperture_order=None, bootstrap=None, share=(), start=None,
                    sampler="emcee"):
    """Fit ``model_name`` to Measurement ``m``; returns a dict (see data_formats/fit_json.md).

    Each channel's entry has ``warnings``, the sentences of what did not go as planned (see the
    module text); with ``warn`` (the default) each is also issued as a :class:`FitWarning`
    (the CLI, which prints the list itself, turns this off). ``lm_maxiter`` is the step limit
    of every Levenberg–Marquardt run. ``bootstrap``: refits of the block bootstrap over
    incidences (None: :data:`fitlab.fitting.resampling.DEFAULT_BOOTSTRAP` where a channel has
    at least 3 fitted incidences, else none; 0: none). Rows with an aperture (``m.has_aperture``) are fitted
    by the aperture-averaged model, of quadrature order ``aperture_order`` (None: chosen
    automatically, fitlab.fitting.aperture). ``start``: values for the extra
    Levenberg–Marquardt start (the model's defaults elsewhere)."""
    model, options, fixed, notes, loss, start = resolve_fit(m, model_name, options=options,
                                                            fixed=fixed, free=free, loss=loss,
                                                            start=start)
    rows_fit = np.ones(m.n, dtype=bool) if subset is None else np.asarray(subset, dtype=bool)
    chan_ids = range(len(m.channel_names)) if channels is None else channels
    fitted = [c for c in chan_ids if np.any((m.channel == c) & rows_fit)]
    if share and len(fitted) > 1:  # one problem over the channels (fitlab/fitting/joint.py)
        from fitlab.fitting.joint import fit_joint

        results, joint = fit_joint(
            m, model, options, fixed, loss, start, rows_fit, fitted, share,
            channel_problem=channel_problem, statistics=statistics,
            least_squares_warnings=least_squares_warnings, mcmc=mcmc, mcmc_steps=mcmc_steps,
            mcmc_walkers=mcmc_walkers, seed=seed, n_starts=n_starts, quiet=quiet,
            sampler=sampler,
            lm_maxiter=lm_maxiter, aperture_order=aperture_order, bootstrap=bootstrap)
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

            order, auto_order = _aperture.start_order(aperture_order)
        space, data, start_native = channel_problem(m, model, options, fixed, loss, start, rows,
                                                    name, in_chan, order)
        _log(quiet, f"fitting {model.name} to channel {name}: {int(rows.sum())} rows, free "
                    f"{', '.join(space.names)}; loss {loss}; global search + {n_starts} starts")
        ls = fit_least_squares(space, data, loss, start_native=start_native, n_starts=n_starts,
                               seed=seed, lm_maxiter=lm_maxiter, progress=not quiet)
        t_ls = time.perf_counter() - t0
        if ls.solver["stopped"] == "non_finite":
            raise non_finite_fit(f"{m.path}: channel {name}", len(ls.starts))
        channel_warnings = least_squares_warnings(ls)
        _log(quiet, "  least squares: " + ", ".join(
            f"{k} = {v:.6g} ± {s:.2g}" for k, v, s in zip(space.names, ls.native, ls.stderr))
            + f"  ({t_ls:.2f} s)")
        aperture = None
        if order is not None:
            def refit(d, start_at):
                return fit_least_squares(space, d, loss, start_native=start_at,
                                         n_starts=n_starts, seed=seed, lm_maxiter=lm_maxiter,
                                         progress=not quiet)

            ls, data, aperture, more = _aperture.settle_order(
                space, ls, data, m, rows, loss, order, auto=auto_order, refit=refit,
                log=lambda msg: _log(quiet, msg))
            order = aperture["order"]
            channel_warnings = least_squares_warnings(ls) + more
            t_ls = time.perf_counter() - t0
        chain = None
        if mcmc:
            from fitlab.fitting.mcmc import sample_posterior  # the samplers load only here

            _log(quiet, f"  MCMC ({sampler}): {mcmc_steps} steps")
            chain = sample_posterior(sampler, space, data, loss, ls, seed=seed,
                                     nsteps=mcmc_steps, walkers=mcmc_walkers,
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

        misfit = channel_misfit(m, rows, space, data, loss, ls, chain, bootstrap=bootstrap,
                                seed=seed, lm_maxiter=lm_maxiter, progress=not quiet,
                                log=lambda msg: _log(quiet, msg))
        channel_warnings += misfit["warnings"]
        results.append({"channel": name, "space": space, "ls": ls, "mcmc": chain,
                        "statistics": stats, "seconds_least_squares": t_ls,
                        "goodness": misfit["goodness"], "bootstrap": misfit["bootstrap"],
                        "seconds_bootstrap": misfit["seconds"],
                        "prediction": full, "rows": np.flatnonzero(in_chan),
                        "warnings": channel_warnings,
                        **({"aperture": aperture} if aperture is not None else {})})
        if warn:
            for w in channel_warnings:
                _warnings.warn(f"channel {name}: {w}", FitWarning, stacklevel=2)
    return {"model": model, "options": options, "fixed": fixed, "loss": loss,
            "notes": notes, "seed": seed, "subset_rows": rows_fit, "channels": results}
