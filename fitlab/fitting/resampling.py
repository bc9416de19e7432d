"""What goodness of fit and a misfit-aware uncertainty need from the fit's kernels: the block
bootstrap over incidence directions, and the residuals at posterior draws for the posterior
predictive check. The statistics themselves are pure functions in fitlab.fitting.goodness.

**Block bootstrap** (data_formats/fit_json.md, *Uncertainty that accounts for misfit*): each
replicate resamples the fitted incidence directions with replacement (whole incidences, so that
the residuals' structure within a scan, which a misfit makes strongly correlated, travels with
its block) and refits from the least-squares optimum. A resample is a row weight, √(times the
incidence was drawn), on the same rows: every replicate has the fit's shape, and a batch of
them (as many as the fit had starts) runs as one call of the fit's own compiled
Levenberg–Marquardt stage (``kernels(...)["local"]``, one row-weight vector per start), so
nothing is compiled for the bootstrap. Replicates are drawn from a generator seeded with the
fit's seed: the same fit gives the same intervals, byte for byte.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from fitlab._jax import jax
from fitlab.fitting import goodness as gof
from fitlab.fitting.least_squares import (LM_MAXITER, kernels, local_fits, lm_stop_reason,
                                          pad_rows, problem_of, residuals_native)
from fitlab.fitting.losses import has_absolute_noise
from fitlab.fitting.progress import bar as progress_bar
from fitlab.fitting.solvers import DEFAULT_LOCAL_SOLVER
from fitlab.fitting.status import Status

#: The bootstrap needs at least this many fitted incidence directions (blocks).
MIN_BLOCKS = 3
#: The most refits when the bootstrap is not asked for explicitly (``bootstrap=None``), on
#: channels with at least MIN_BLOCKS fitted incidences; the refits stop earlier when the
#: intervals have settled (:data:`SETTLE_REFITS`, :data:`SETTLE_FRACTION`). At 100 the Monte
#: Carlo error of a standard error is about 1/√(2B) = 7%, below the bootstrap's own roughness
#: with ~10 blocks (about 1/√(2K) = 22%).
DEFAULT_BOOTSTRAP = 100
#: The stopping rule (data_formats/fit_json.md, *the number of refits*): the refits stop when
#: each 68% bound (p16, p84) of every free parameter has moved by less than SETTLE_FRACTION of
#: the interval's width over the last SETTLE_REFITS refits (bounds and widths in the parameter's
#: unit-box coordinate, where percentiles are those of the native values); checked after each
#: batch of refits once 2 × SETTLE_REFITS have run.
SETTLE_REFITS = 20
SETTLE_FRACTION = 0.05
#: Widths below this (unit box) count as this: a parameter pinned to one value has settled.
SETTLE_MIN_WIDTH = 1e-6
#: Fewest refits one may ask for (a 68% interval from fewer is mostly noise).
MIN_REFITS = 10
#: Fewer blocks than this: the bootstrap's spread is itself rough (``note`` in the record).
FEW_BLOCKS = 8
#: Stream tags mixed with the fit's seed (distinct from the MCMC's own use of the seed).
_BOOTSTRAP_STREAM = 0xB0075
_PPC_STREAM = 0x99C


def _canonical(space, loc):
    """One labelling of interchangeable lobes, where the fitter has that notion."""
    try:
        from fitlab.fitting.exchange import canonical_runs
    except ImportError:
        return loc
    return canonical_runs(space, loc)


def resample_counts(n_blocks: int, n_replicates: int, seed: int) -> np.ndarray:
    """(replicates, blocks): how often each block is drawn in each replicate (n_blocks draws
    with replacement, seeded by the fit's seed)."""
    rng = np.random.default_rng([int(seed), _BOOTSTRAP_STREAM])
    draws = rng.integers(0, n_blocks, size=(n_replicates, n_blocks))
    return np.stack([np.bincount(d, minlength=n_blocks) for d in draws])


def bootstrap_caveats(blocks, replicates, requested, non_finite, at_bound):
    """(note or None, warnings) of a bootstrap run: too few incidences to resample is a caveat
    kept with the record; a failed bootstrap, refits at a bound and non-finite refits are
    warnings."""
    warnings = []
    if replicates < 2:
        warnings.append("the bootstrap failed: fewer than 2 of its refits ended at finite values")
    note = (f"only {blocks} incidence directions to resample: the bootstrap intervals are "
            "rough and tend to be too narrow") if blocks < FEW_BLOCKS else None
    if at_bound:
        warnings.append("bootstrap refits ended at a bound of " + ", ".join(
            f"{k} ({v} of {replicates})" for k, v in at_bound.items())
            + ": the data without some incidences do not hold these parameters inside "
            "their range; their bootstrap intervals reach the bound")
    if non_finite:
        warnings.append(f"{non_finite} of {requested} bootstrap refits ended at NaN or inf and "
                        "were left out")
    return note, warnings


def settled(u, n_back: int = SETTLE_REFITS, fraction: float = SETTLE_FRACTION) -> bool:
    """Whether the 68% intervals of the refits ``u`` (finite refits in drawing order, unit-box
    coordinates, (refits, ndim)) have settled: each bound of every coordinate moved by less
    than ``fraction`` of the interval's width between the first len(u) − ``n_back`` refits
    and all of them. Needs 2 × ``n_back`` refits."""
    u = np.asarray(u, float)
    if u.shape[0] < 2 * n_back:
        return False
    now = np.percentile(u, [16, 84], axis=0)
    before = np.percentile(u[:-n_back], [16, 84], axis=0)
    width = np.maximum(now[1] - now[0], SETTLE_MIN_WIDTH)
    return bool(np.all(np.abs(now - before) < fraction * width))


def skip_reason(ls) -> tuple[Status, str] | None:
    """(status, sentence) when the bootstrap is not to run on this least-squares result: its
    Levenberg–Marquardt run stopped at its iteration limit or at a non-finite cost, or a
    parameter ended at a bound of its range (refits from a point that is not an interior
    optimum measure the solver, not the data; at a bound they creep along it for hundreds of
    iterations). None: run it."""
    stopped = (getattr(ls, "solver", None) or {}).get("stopped")
    if stopped in (Status.MAX_ITERATIONS, Status.NON_FINITE):
        return Status(stopped), (f"least squares did not converge ({stopped}): refits from its "
                                 f"end would measure the solver, not the data; "
                                 f"{Status(stopped).advice}")
    at = tuple(getattr(ls, "at_bound", ()) or ())
    if at:
        return Status.AT_BOUND, (f"least squares ended with {', '.join(at)} at a bound of its "
                                 "range: the resampled fits would pile up at the bound. Fix it "
                                 "there (--fix NAME=BOUND, fix= in Python) and refit to get "
                                 "bootstrap intervals of the others, or widen its range if the "
                                 "model allows it")
    return None


def block_bootstrap(space, data, loss, ls, block, *, replicates: int, seed: int, batch: int,
                    lm_maxiter: int = LM_MAXITER, solver: str = DEFAULT_LOCAL_SOLVER,
                    progress: bool = False, adaptive: bool = True) -> dict:
    """At most ``replicates`` refits of the channel on incidence-resampled data (``block``: the
    block index of each fitted row), ``batch`` at a time (the fit's number of
    Levenberg–Marquardt starts, so that the fit's compiled stage is reused); with ``adaptive``
    they stop once the 68% intervals have :func:`settled` (checked after each batch). Returns
    {samples (ok, ndim) native, requested, refits (run), replicates (finite), non_finite,
    max_iterations, blocks, at_bound ({name: refits that ended at a bound}), stopped
    (Status.CONVERGED: the intervals settled; Status.MAX_ITERATIONS: the cap came first; None
    without ``adaptive``), stop_reason (a sentence), seconds}."""
    t0 = time.perf_counter()
    k = kernels(space.static, loss, int(lm_maxiter), solver)
    padded = pad_rows(space.static, data)  # the fit's own padded rows (and compilation)
    problem = problem_of(space, padded)
    block = np.asarray(block)
    n_blocks = int(block.max()) + 1
    counts = resample_counts(n_blocks, replicates, seed)
    weights = np.sqrt(counts[:, block].astype(float))  # (replicates, rows)
    weights = np.pad(weights, ((0, 0), (0, padded.value.shape[0] - weights.shape[1])))
    u0 = space.to_unit(np.asarray(ls.native, float))
    bar = progress_bar(progress, replicates, "  bootstrap" + (" (stops when its intervals "
                       "settle)" if adaptive else ""), "refit")
    natives, stops = [], []
    stopped = Status.MAX_ITERATIONS if adaptive else None
    try:
        for start in range(0, replicates, batch):
            w = weights[start:start + batch]
            n = w.shape[0]
            if n < batch:  # pad to the compiled batch with the fit itself (discarded)
                w = np.concatenate([w, np.ones((batch - n, w.shape[1]))])
            loc = _canonical(space, local_fits(k, problem, [u0] * batch, weights=w))
            for i in range(n):
                cost = float(loc["cost"][i]) if loc["end_finite"][i] else np.nan
                stops.append(lm_stop_reason(cost, int(loc["iters"][i]),
                                            bool(loc["rule_unmet"][i]), int(lm_maxiter)))
                natives.append(loc["native"][i])
            if bar is not None:
                bar.update(n)
            if adaptive and start + n < replicates:
                ok = np.asarray(stops) != Status.NON_FINITE
                if settled(space.to_unit(np.asarray(natives, float)[ok]) if ok.any()
                           else np.zeros((0, space.ndim))):
                    stopped = Status.CONVERGED
                    break
    finally:
        if bar is not None:
            bar.close()
    run = len(stops)
    if stopped == Status.CONVERGED:
        reason = (f"the 68% intervals settled after {run} refits (every bound moved by less "
                  f"than {SETTLE_FRACTION:.0%} of its interval's width over the last "
                  f"{SETTLE_REFITS})")
    elif adaptive and run >= 2 * SETTLE_REFITS:
        reason = (f"the cap of {replicates} refits came before the 68% intervals settled (a "
                  f"bound still moved by {SETTLE_FRACTION:.0%} of its interval's width or more "
                  f"over the last {SETTLE_REFITS}): their Monte Carlo error is larger than that")
    else:
        reason = (f"{replicates} refits, as asked (a number given: no stopping rule)"
                  if not adaptive else
                  f"{replicates} refits, the cap, too few to check the stopping rule (it needs "
                  f"{2 * SETTLE_REFITS})")
    stops = np.asarray(stops)
    ok = stops != Status.NON_FINITE
    samples = np.asarray(natives, float)[ok]
    u = space.to_unit(samples) if samples.size else np.zeros((0, space.ndim))
    edge = (u < 1e-6) | (u > 1 - 1e-6)  # as the fit's at_bound
    at_bound = {name: int(c) for name, c in zip(space.names, edge.sum(axis=0)) if c}
    return {"samples": samples, "requested": int(replicates), "refits": int(run),
            "stopped": stopped, "stop_reason": reason,
            "replicates": int(ok.sum()), "non_finite": int((~ok).sum()),
            "max_iterations": int(np.sum(stops == Status.MAX_ITERATIONS)), "blocks": n_blocks,
            "at_bound": at_bound, "seconds": time.perf_counter() - t0}


@functools.lru_cache(maxsize=64)
def _residuals_at(static, loss):
    """Residuals (loss units) at a batch of native parameter vectors (S, ndim) → (S, rows)."""
    return jax.jit(jax.vmap(functools.partial(residuals_native, static, loss),
                            in_axes=(0, None)))


def posterior_draws(chain, n: int, seed: int):
    """Indices of ``n`` of the chain's stored samples (all if fewer), chosen with a generator
    seeded by the fit's seed, and each sample's noise scale σ_r (ones without one)."""
    samples = chain.samples_native
    rng = np.random.default_rng([int(seed), _PPC_STREAM])
    idx = np.sort(rng.choice(samples.shape[0], size=min(n, samples.shape[0]), replace=False))
    nd = len(chain.names)
    if chain.names[-1] == "log_noise":
        # the stored samples are emcee's get_chain(discard=burn, thin=thin, flat=True)
        flat = chain.chain_unit[chain.burn + chain.thin - 1::chain.thin].reshape(-1, nd)
        sigma = np.exp(flat[idx, -1])
    else:
        sigma = np.ones(idx.size)
    return idx, sigma


def predictive_check(space, data, loss, chain, block, *, seed: int,
                     draws: int = gof.PPC_DRAWS) -> dict:
    """Posterior predictive p-values (fitlab.fitting.goodness.posterior_predictive) from
    ``draws`` posterior samples of ``chain`` (an MCMCResult)."""
    idx, sigma = posterior_draws(chain, draws, seed)
    theta = np.asarray(chain.samples_native[idx], float)
    problem = problem_of(space, data)
    R = np.asarray(_residuals_at(space.static, loss)(theta, problem))
    return gof.posterior_predictive(R, sigma, block)


def skipped_record(skip, requested: int, blocks: int) -> dict:
    """The bootstrap record of a run not made because least squares failed or ended at a bound
    (:func:`skip_reason`): ``skipped`` (the sentence) and ``skipped_status`` (the Status)."""
    status, sentence = skip
    return {"method": "block bootstrap over incidence directions", "requested": int(requested),
            "replicates": 0, "refits": 0, "blocks": int(blocks), "skipped": sentence,
            "skipped_status": status.value}


def run_record(res) -> dict:
    """The fields of a bootstrap record that describe its run (data_formats/fit_json.md)."""
    return {"requested": res["requested"], "refits": res["refits"],
            "replicates": res["replicates"],
            **({} if res["stopped"] is None else {"stopped": Status(res["stopped"]).value}),
            "stop_reason": res["stop_reason"], "blocks": res["blocks"],
            "non_finite": res["non_finite"], "max_iterations": res["max_iterations"]}


def channel_misfit(m, rows, space, data, loss, ls, chain, request, *,
                   log=lambda msg: None) -> dict:
    """Goodness of fit and the block bootstrap of one channel (``rows``: the boolean mask of its
    fitted rows in ``m``; ``request``: the fit's FitRequest, whose ``bootstrap`` is the refits,
    None for :data:`DEFAULT_BOOTSTRAP` where there are enough incidences and none otherwise, 0
    for none; its seed and step limit are the refits'). Returns {goodness, bootstrap (or None),
    warnings}: the records of data_formats/fit_json.md and the sentences for the channel's
    warnings."""
    seed, bootstrap = request.seed, request.bootstrap
    keys, block = gof.incidence_blocks(m.theta_i[rows], m.phi_i[rows])
    absolute = has_absolute_noise(loss)
    predictive = None
    if chain is not None:
        predictive = predictive_check(space, data, loss, chain, block, seed=seed)
    good = gof.assess(ls.residuals, block=block, keys=keys, theta_o=m.theta_o[rows],
                      phi_o=m.phi_o[rows], wo=m.wo[rows], n_params=space.ndim,
                      absolute_noise=absolute, predictive=predictive)
    warnings, boot, seconds = [], None, 0.0
    if bootstrap is None:
        bootstrap = DEFAULT_BOOTSTRAP if len(keys) >= MIN_BLOCKS else 0
    skip = skip_reason(ls) if bootstrap and len(keys) >= MIN_BLOCKS else None
    if bootstrap:
        if len(keys) < MIN_BLOCKS:
            boot = {"method": "block bootstrap over incidence directions", "requested":
                    int(bootstrap), "replicates": 0, "blocks": len(keys),
                    "skipped": f"{len(keys)} fitted incidence direction(s): the bootstrap "
                               f"resamples whole incidences and needs at least {MIN_BLOCKS}"}
            warnings.append("no bootstrap: " + boot["skipped"])
        elif skip is not None:
            boot = skipped_record(skip, int(bootstrap), len(keys))
            log(f"  bootstrap skipped: {skip[1]}")
            warnings.append("no bootstrap: " + boot["skipped"])
        else:
            adaptive = request.bootstrap is None
            log("  bootstrap: refitting " + (f"up to {bootstrap}" if adaptive else
                                              f"{bootstrap}")
                + f" resamples of {len(keys)} incidences")
            res = block_bootstrap(space, data, loss, ls, block, replicates=int(bootstrap),
                                  seed=seed, batch=len(ls.starts),
                                  lm_maxiter=request.lm_maxiter, solver=request.local_solver,
                                  progress=request.progress,
                                  adaptive=adaptive)
            seconds = res["seconds"]
            log(f"  bootstrap: {res['stop_reason']}")
            boot = {"method": "block bootstrap over incidence directions (whole incidences "
                              "resampled with replacement, each replicate refitted from the "
                              "least-squares optimum)",
                    **run_record(res), "at_bound": res["at_bound"], "seed": int(seed)}
            if res["replicates"] >= 2:
                boot["parameters"] = dict(zip(space.names, gof.bootstrap_summary(res["samples"])))
            note, more = bootstrap_caveats(res["blocks"], res["replicates"], res["requested"],
                                           res["non_finite"], res["at_bound"])
            if note:
                boot["note"] = note
            warnings += more
    sentence = gof.failure_sentence(good, has_mcmc=chain is not None,
                                    bootstrap=bool(boot and boot.get("parameters")))
    if sentence:
        warnings.insert(0, sentence)
    return {"goodness": good, "bootstrap": boot, "warnings": warnings, "seconds": seconds}
