"""The pointwise log-likelihood of an MCMC posterior, PSIS-LOO and WAIC (ArviZ), and the
stacking weights of ArviZ's ``compare``."""

from __future__ import annotations

import functools
import math
import warnings as _warnings

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.compare.candidates import Resolved
from fitlab.fitting.compare.crossval import _problem, aperture_order

#: Posterior samples per call of the log-likelihood kernel (one compile per model).
LOGLIK_CHUNK = 256


# --------------------------------------------------------------------------------------------
# Pointwise log-likelihood, PSIS-LOO and WAIC
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def _loglik_kernel(static, loss: str):
    """Jitted (samples (S, P), problem) → (pointwise log-likelihood (S, n), the chain's
    log-posterior recomputed (S,)). P: the unit-box coordinates, then log σ_r if sampled."""
    from fitlab._jax import jax, jnp

    from fitlab.fitting.least_squares import residuals_native
    from fitlab.fitting.losses import has_absolute_noise
    from fitlab.fitting.space import to_native

    nuisance = not has_absolute_noise(loss)
    ndim = len(static.names)
    half_log_2pi = 0.5 * math.log(2.0 * math.pi)

    def one(x, problem):
        theta = to_native(static, x[:ndim], problem["lo"], problem["hi"])
        d = problem["data"]

        def r_of(v):  # the residual as a function of the measured values, constants held
            return residuals_native(static, loss, theta, {**problem, "data": d._replace(value=v)})

        r, dr_dv = jax.jvp(r_of, (d.value,), (jnp.ones_like(d.value),))  # elementwise loss
        log_s = x[ndim] if nuisance else jnp.zeros(())
        z = r * jnp.exp(-log_s)
        core = -0.5 * z * z - log_s
        return core - half_log_2pi + jnp.log(jnp.abs(dr_dv)), jnp.sum(core)

    return jax.jit(jax.vmap(one, in_axes=(0, None)))


def pointwise_log_likelihood(m, cand: Resolved, result, loss, rows, channel) -> dict:
    """The log-likelihood of every fitted row at every stored posterior sample of a fit made by
    ``fitlab.fit(..., mcmc=True)``: ``loglik`` (walkers, draws, rows), ``reff`` (effective over
    stored samples), ``samples``, ``informative`` (rows whose residual depends on the value:
    the others carry no likelihood and are left out)."""
    from fitlab._jax import jax

    from fitlab.fitting.least_squares import problem_of

    name = m.channel_names[channel]
    base = _problem(m, cand, loss, rows, channel, aperture_order(result, name))
    fit = result._fit(name)
    mc = fit.get("mcmc")
    chain = result.chains.get(f"chain_{name}")
    if not mc or chain is None:
        raise FitlabError(f"{cand.label}: channel {name} has no MCMC chain to compute PSIS-LOO "
                          "and WAIC from")
    lp_stored = np.asarray(result.chains[f"log_prob_{name}"])[mc["burn_in"]::mc["thin"]]
    x = np.asarray(chain)[mc["burn_in"]::mc["thin"]]  # (draws, walkers, P)
    draws, walkers, ncoord = x.shape
    flat = x.reshape(-1, ncoord)
    kernel = _loglik_kernel(base["space"].static, base["loss"])
    problem = problem_of(base["space"], base["data"])
    lls, lps = [], []
    for i in range(0, flat.shape[0], LOGLIK_CHUNK):
        part = flat[i:i + LOGLIK_CHUNK]
        pad = LOGLIK_CHUNK - part.shape[0]
        if pad:  # every call the same shape: one compile
            part = np.concatenate([part, np.repeat(part[:1], pad, axis=0)])
        ll, lp = jax.device_get(kernel(part, problem))
        lls.append(np.asarray(ll)[:LOGLIK_CHUNK - pad])
        lps.append(np.asarray(lp)[:LOGLIK_CHUNK - pad])
    ll, lp = np.concatenate(lls), np.concatenate(lps)
    want = lp_stored.reshape(-1)
    if not np.allclose(lp, want, rtol=1e-8, atol=1e-8 * max(1.0, float(np.max(np.abs(want))))):
        raise FitlabError(
            f"internal error: {cand.label}, channel {name}: the pointwise log-likelihood does not "
            f"sum to the chain's log-posterior (largest difference "
            f"{float(np.max(np.abs(lp - want))):.3g}); the fit's likelihood has changed without "
            "fitlab.fitting.compare; please report this")
    informative = np.all(np.isfinite(ll), axis=0)
    ess = float(mc.get("effective_sample_size") or 0.0)
    reff = min(1.0, ess / flat.shape[0]) if ess > 0 else 1.0
    ll = ll[:, informative]
    above = int(np.sum(np.var(ll, axis=0) > 0.4))  # ArviZ's WAIC criterion, per row
    ll = ll.reshape(draws, walkers, -1).transpose(1, 0, 2)
    return {"loglik": ll, "reff": reff, "samples": int(flat.shape[0]), "informative": informative,
            "rows_variance_above_0_4": above,
            "trustworthy": bool(mc.get("trustworthy")), "mcmc_warnings": list(mc.get("warnings")
                                                                              or [])}


def _arviz():
    try:
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore")  # ArviZ announces its refactor on import
            import arviz
    except ImportError:
        raise FitlabError("PSIS-LOO and WAIC need ArviZ, which is not installed: pip install "
                          "'fitlab[compare]' (or 'arviz>=0.23,<0.24'), or rank by "
                          "cross-validation alone with --no-mcmc (mcmc=False)") from None
    return arviz


def information_criteria(loglik, reff):
    """(PSIS-LOO, WAIC) ArviZ ELPDData (pointwise) of a (chains, draws, rows) log-likelihood."""
    az = _arviz()
    with _warnings.catch_warnings():
        # Their content is in warning / pareto_k, worded by compare; an emcee ensemble may have
        # more walkers (ArviZ's chains) than stored draws, which ArviZ warns about.
        _warnings.simplefilter("ignore")
        idata = az.from_dict(log_likelihood={"value": loglik})
        loo = az.loo(idata, pointwise=True, reff=reff)
        waic = az.waic(idata, pointwise=True)
    return loo, waic


WEIGHT_DECIMALS = 6


def _compare_ic(elpds: dict, ic: str) -> dict:
    """{label: {rank, elpd_diff, dse, weight}} from ArviZ's compare (stacking weights).

    The weights come from SciPy's SLSQP (tolerance 1e-6 on the log score) and are written to
    WEIGHT_DECIMALS places: their last binary digits follow BLAS's rounding, which depends on
    how the process's memory happens to be aligned, and would make the record differ between two
    runs of the same command."""
    az = _arviz()
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        table = az.compare(elpds, ic=ic, method="stacking")
    return {str(label): {"rank": int(row["rank"]) + 1, "elpd_diff": float(row["elpd_diff"]),
                         "dse": float(row["dse"]),
                         "weight": round(float(row["weight"]), WEIGHT_DECIMALS)}
            for label, row in table.iterrows()}
