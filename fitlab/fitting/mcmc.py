"""Posterior sampling with emcee: a jitted, vectorized log-posterior over all walkers at once.

Prior: uniform over the bounds in each parameter's unit-box coordinate (linear, or logarithmic
for parameters spanning decades); for a sum that repeats a component, restricted to the lobes'
ordered labelling (fitlab/fitting/exchange.py). Likelihood: Gaussian residuals of the fit's loss; for losses
whose residuals are not in units of the data's σ (everything but chi2) a noise scale σ_r is
sampled too, with a Jeffreys prior p(σ_r) ∝ 1/σ_r (its log is the last chain coordinate).

Outside the prior the log-posterior is −inf (emcee rejects the move), and so it is where the
cost overflows to +inf. A NaN log-probability inside the prior is a bug in the model or a
problem of the data, never a rejected move: like emcee, fitlab stops there, and its error
(:class:`NaNLogProbabilityError`) names the parameter values where it happened.
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import emcee
import numpy as np

import functools

from fitlab._jax import jax, jnp
from fitlab.errors import FitlabError
from fitlab.fitting.exchange import canonical, order_keys, ordered
from fitlab.fitting.least_squares import ROW_MASK, FitData, pad_rows, problem_of, residuals_unit
from fitlab.fitting.losses import has_absolute_noise
from fitlab.fitting.progress import line as progress_line
from fitlab.fitting.space import FitSpace, StaticSpace

#: emcee's rule: a chain shorter than this many autocorrelation times is not trusted.
MIN_TAU_MULTIPLE = 50


class NaNLogProbabilityError(FitlabError):
    """The log-posterior is NaN (or +inf) at a point inside the prior; ``params`` holds that
    point (native units of the free parameters, then ``log_noise`` if sampled)."""

    def __init__(self, params: dict, value: float):
        self.params, self.value = params, value
        where = ", ".join(f"{k}={v:.6g}" for k, v in params.items())
        super().__init__(
            f"log-probability is {'NaN' if np.isnan(value) else value} at {where}, inside the "
            "prior bounds: the model or the loss is not finite there. Check the data (zero or "
            "negative values with the log loss, zero sigma), fix or narrow the parameter that "
            "makes it (--fix NAME=VALUE), or report the model's values there as a bug")


class MCMCResult(NamedTuple):
    samples_native: np.ndarray  # (n_samples, ndim) flattened after burn-in, native units
    chain_unit: np.ndarray  # (nsteps, nwalkers, ndim_total) full chain in sampler coordinates
    log_prob: np.ndarray  # (nsteps, nwalkers)
    names: tuple[str, ...]  # coordinates of chain_unit
    nwalkers: int
    nsteps: int
    burn: int
    thin: int
    tau: np.ndarray
    acceptance: float
    ess: float
    trustworthy: bool
    warnings: list
    seconds: float
    #: which sampler drew the chain (SAMPLERS); emcee's files do not name it (the default)
    sampler: str = "emcee"


@functools.lru_cache(maxsize=64)
def log_posterior_fn(static: StaticSpace, loss: str, order: tuple = ()):
    """Jitted, vectorized log-posterior over walker positions x (nwalkers, ndim[+1]); ``order``:
    the ordered labelling of interchangeable lobes (``exchange.order_keys``)."""
    nuisance = not has_absolute_noise(loss)
    ndim = len(static.names)

    def one(x, problem):
        u = x[:ndim]
        d = problem["data"]  # rows left out by the row mask (least_squares.pad_rows) do not count
        n = jnp.sum(d.consts[ROW_MASK]) if ROW_MASK in d.consts else d.value.shape[0]
        # the prior's support: the unit box, lobes of a repeated component in order (exchange.py)
        inside = jnp.all((u >= 0) & (u <= 1)) & ordered(order, u)
        u_safe = jnp.where(inside, u, 0.5)
        r = residuals_unit(static, loss, u_safe, problem)
        chi2 = jnp.sum(r * r)
        if nuisance:
            log_s = x[ndim]
            lp = -0.5 * chi2 * jnp.exp(-2 * log_s) - n * log_s
        else:
            lp = -0.5 * chi2
        # An overflowing cost gives −inf (a rejected move); NaN is kept, for log_prob to report.
        return jnp.where(inside, lp, -jnp.inf)

    return jax.jit(jax.vmap(one, in_axes=(0, None))), nuisance


def mcmc_setup(space: FitSpace, data: FitData, loss: str, ls, *, seed: int,
               nwalkers: int | None = None) -> dict:
    """What ``run_mcmc`` hands emcee: the vectorized ``log_prob`` (walker positions (n, ndim) →
    log-posteriors (n,)), the start positions ``p0`` (nwalkers, ndim), the coordinate ``names``
    and whether a noise scale is sampled (``nuisance``). Walkers start in a small ball around
    the least-squares optimum."""
    logp, nuisance = log_posterior_fn(space.static, loss, order_keys(space))
    problem = problem_of(space, pad_rows(space.static, data))  # least squares' row ladder
    names = space.names + (("log_noise",) if nuisance else ())
    ndim = len(names)
    nwalkers = nwalkers or max(32, 4 * ndim)
    rng = np.random.default_rng(seed)
    u_best = space.to_unit(ls.native)
    # Spread: the least-squares standard error mapped to the unit box, kept in a sane range.
    eps = 1e-4
    du = np.clip(unit_stderr(space, ls), 1e-5, 0.05)
    centre = np.clip(u_best, eps, 1 - eps)
    p0 = centre + du * rng.standard_normal((nwalkers, space.ndim)) * 0.5
    p0 = canonical(space, np.clip(p0, eps, 1 - eps))  # into the ordered labelling
    if nuisance:
        log_s = np.log(max(ls.noise_scale, 1e-300))
        p0 = np.column_stack([p0, log_s + 0.01 * rng.standard_normal(nwalkers)])

    chunk = (nwalkers + 1) // 2  # emcee asks for half the ensemble at a time (all at the start)

    def log_prob(x):  # the walkers of one half-step in one call, always `chunk` rows (one compile)
        n = x.shape[0]
        pad = -n % chunk
        if pad:
            x = np.concatenate([x, np.repeat(x[:1], pad, axis=0)])
        out = np.concatenate([np.asarray(logp(x[i:i + chunk], problem), dtype=np.float64)
                              for i in range(0, x.shape[0], chunk)])[:n]
        bad = np.isnan(out) | (out == np.inf)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            native = space.to_native(x[i, : space.ndim])
            params = {name: float(v) for name, v in zip(space.names, native)}
            if nuisance:
                params["log_noise"] = float(x[i, space.ndim])
            raise NaNLogProbabilityError(params, float(out[i]))
        return out

    return {"log_prob": log_prob, "p0": p0, "names": names, "nuisance": nuisance}


def unit_stderr(space: FitSpace, ls) -> np.ndarray:
    """The least-squares standard errors mapped to the unit box (half the width of ±1σ there;
    1e-2 where a standard error is undefined): the spread of emcee's walkers and of NUTS's
    initial mass matrix."""
    du = np.abs(space.to_unit(ls.native + ls.stderr) - space.to_unit(ls.native - ls.stderr)) / 2
    return np.nan_to_num(du, nan=1e-2)


def run_mcmc(space: FitSpace, data: FitData, loss: str, ls, *, seed: int, nsteps: int = 3000,
             nwalkers: int | None = None, progress: bool = True) -> MCMCResult:
    """Start walkers in a small ball around the least-squares optimum and run emcee."""
    t0 = time.perf_counter()
    setup = mcmc_setup(space, data, loss, ls, seed=seed, nwalkers=nwalkers)
    log_prob, p0, names = setup["log_prob"], setup["p0"], setup["names"]
    nwalkers, ndim = p0.shape
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True)
    sampler.random_state = np.random.RandomState(seed).get_state()
    report_every = max(nsteps // 10, 1)
    for i, _ in enumerate(sampler.sample(p0, iterations=nsteps), start=1):
        if progress and (i % report_every == 0 or i == nsteps):
            frac = sampler.acceptance_fraction.mean()
            progress_line(f"  MCMC {100 * i // nsteps:3d}%  step {i}/{nsteps}  "
                          f"acceptance {frac:.2f}")
    chain = sampler.get_chain()
    warnings = []
    logging.getLogger("emcee").setLevel(logging.ERROR)  # fitlab words its own warning below
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    tau = np.asarray(tau, dtype=float)
    tau_max = float(np.nanmax(tau))
    trustworthy = bool(np.isfinite(tau_max) and nsteps >= MIN_TAU_MULTIPLE * tau_max)
    if not trustworthy:
        warnings.append(
            f"THE CHAIN IS TOO SHORT TO TRUST: {nsteps} steps < {MIN_TAU_MULTIPLE} × the "
            f"autocorrelation time ({tau_max:.1f} steps). Rerun with --mcmc-steps "
            f"{int(np.ceil(MIN_TAU_MULTIPLE * tau_max / 500) * 500)} or more."
        )
    acceptance = float(sampler.acceptance_fraction.mean())
    if not 0.15 <= acceptance <= 0.7:
        warnings.append(f"acceptance fraction {acceptance:.2f} is outside [0.15, 0.7]: the "
                        "posterior may be multimodal or badly scaled")
    burn = int(min(nsteps // 2, np.ceil(3 * tau_max))) if np.isfinite(tau_max) else nsteps // 2
    thin = max(1, int(tau_max // 2)) if np.isfinite(tau_max) else 1
    flat = sampler.get_chain(discard=burn, thin=thin, flat=True)
    samples_native = space.to_native(flat[:, : space.ndim])
    ess = float(nwalkers * (nsteps - burn) / tau_max) if np.isfinite(tau_max) else 0.0
    return MCMCResult(samples_native, chain, sampler.get_log_prob(), names, nwalkers, nsteps,
                      burn, thin, tau, acceptance, ess, trustworthy, warnings,
                      time.perf_counter() - t0)
