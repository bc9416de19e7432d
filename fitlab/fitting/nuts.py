"""Posterior sampling with blackjax's NUTS (``fitlab fit --mcmc --sampler nuts``): the same
posterior as emcee's (fitlab/fitting/mcmc.py: uniform prior in each parameter's unit-box
coordinate, a Jeffreys-prior noise scale for losses not in units of σ), sampled by the No-U-Turn
sampler in unconstrained coordinates, compiled whole: window adaptation (step size and a
dense mass matrix, Stan's schedule) and the draws are one ``jax.lax.scan`` per chain. emcee stays
the default and the reference.

One chain per core: on the CPU the chains are not vmapped (a vmapped NUTS step waits for the
longest of the chains' trajectories, and a vmapped gradient costs more than the same gradients
one after another) but spread over the host's devices, one XLA CPU device per core
(fitlab/_jax.py sets ``--xla_force_host_platform_device_count``), by ``jax.shard_map``: each
device runs its share of the chains one after another (``jax.lax.map``), the devices at the same
time (:func:`chain_layout`). On an accelerator the chains stay vmapped, where lanes are cheap.
The tree depth is capped at :data:`MAX_TREE_DEPTH` (at most 2^10 − 1 leapfrog steps a draw,
blackjax's and Stan's default), stated in the record's warnings when a draw reaches it.

Coordinates: z = logit(u) for the free parameters' unit-box coordinates u (the prior's density
in z is u(1 − u), added to the log-posterior), and log σ_r as is. Diagnostics by ArviZ: bulk
ESS and split R̂ per coordinate; a chain set is trusted when every R̂ ≤ 1.01 and the smallest
ESS ≥ 100 per chain (Vehtari et al. 2021), with warnings otherwise, and the divergent
transitions are counted and reported.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.fitting.cores import host_devices, over_cores
from fitlab.fitting.mcmc import MCMCResult, log_posterior_fn, unit_stderr
from fitlab.fitting.least_squares import pad_rows, problem_of
from fitlab.fitting.exchange import canonical, order_keys
from fitlab.fitting.losses import has_absolute_noise
from fitlab.fitting.space import FitSpace

#: R̂ above this, or a bulk ESS below ESS_PER_CHAIN × chains, makes the chains untrusted.
RHAT_MAX = 1.01
ESS_PER_CHAIN = 100


def _logdensity(static, loss: str, order: tuple, ndim: int, problem: dict):
    """log p(z) in NUTS's coordinates (module text), for one point z (ndim[+1],)."""
    logp, _ = log_posterior_fn(static, loss, order)

    def one(z):
        u = jax.nn.sigmoid(z[:ndim])
        x = jnp.concatenate([u, z[ndim:]])
        # log |du/dz| = Σ log u(1 − u), computed stably from z
        log_jac = jnp.sum(-jax.nn.softplus(-z[:ndim]) - jax.nn.softplus(z[:ndim]))
        return logp(x[None], problem)[0] + log_jac

    return one


#: The largest NUTS tree: at most 2^MAX_TREE_DEPTH − 1 leapfrog steps a draw (Stan's default).
MAX_TREE_DEPTH = 10


def _chain(static, loss: str, order: tuple, ndim: int, nsteps: int, warmup: int):
    """One chain: (key, start (dim,), initial inverse mass matrix (dim, dim), problem) →
    draws, log-densities, acceptance rates, divergences, tree depths (nsteps,) and the adapted
    step size."""
    import blackjax

    def chain(key, x0, inverse_mass, problem):
        logdensity = _logdensity(static, loss, order, ndim, problem)
        k_adapt, k_draw = jax.random.split(key)
        adapt = blackjax.window_adaptation(blackjax.nuts, logdensity,
                                           is_mass_matrix_diagonal=False,
                                           initial_inverse_mass_matrix=inverse_mass,
                                           max_num_doublings=MAX_TREE_DEPTH)
        (state, params), _ = adapt.run(k_adapt, x0, num_steps=warmup)
        # the adapted parameters carry the cap too (blackjax passes extra parameters on)
        kernel = blackjax.nuts(logdensity, **{"max_num_doublings": MAX_TREE_DEPTH,
                                              **params}).step

        def step(st, k):
            st, info = kernel(k, st)
            return st, (st.position, st.logdensity, info.acceptance_rate, info.is_divergent,
                        info.num_trajectory_expansions)

        _, out = jax.lax.scan(step, state, jax.random.split(k_draw, nsteps))
        return out + (params["step_size"],)

    return chain


def chain_layout(nchains: int, ndevices: int) -> tuple[int, int]:
    """(devices used, chains per device) for ``nchains`` chains on ``ndevices`` host devices:
    as many devices as the chains can fill evenly, each running its chains one after another;
    the last device's spare slots (when the chains do not divide evenly) run copies whose draws
    are dropped, in time the other devices need anyway."""
    per_device = -(-nchains // max(ndevices, 1))
    return -(-nchains // per_device), per_device


@functools.lru_cache(maxsize=32)
def _sampler(static, loss: str, order: tuple, ndim: int, nsteps: int, warmup: int,
             ndevices: int = 0):
    """The compiled sampler of one structure: (keys (chains,), starts (chains, dim), initial
    inverse mass matrix (dim, dim), problem) → per chain: draws, log-densities, acceptance
    rates, divergences, tree depths, step sizes; the data are an argument, so a new dataset of
    the same structure reuses the compilation. ``ndevices`` > 0: the chains (a multiple of
    it) spread over that many host devices, one after another on each (module text); 0: vmapped."""
    chain = _chain(static, loss, order, ndim, nsteps, warmup)
    if not ndevices:
        return jax.jit(jax.vmap(chain, in_axes=(0, 0, None, None)))

    def local(keys, starts, inverse_mass, problem):
        return jax.lax.map(lambda a: chain(a[0], a[1], inverse_mass, problem), (keys, starts))

    return over_cores(local, ndevices, (True, True, False, False))


def _run_chains(static, loss, order, ndim, nsteps, warmup, keys, starts, inverse_mass,
                problem):
    """Every chain of one dataset, one chain per core on the CPU (:func:`_sampler`)."""
    nchains = int(starts.shape[0])
    devices = host_devices()
    if not devices:
        run = _sampler(static, loss, order, ndim, nsteps, warmup, 0)
        return run(keys, starts, inverse_mass, problem)
    used, per_device = chain_layout(nchains, len(devices))
    spare = used * per_device - nchains
    if spare:  # copies of the last chain fill the last device's slots; dropped below
        keys = jnp.concatenate([keys, jnp.repeat(keys[-1:], spare, axis=0)])
        starts = jnp.concatenate([starts, jnp.repeat(starts[-1:], spare, axis=0)])
    run = _sampler(static, loss, order, ndim, nsteps, warmup, used)
    return tuple(o[:nchains] for o in run(keys, starts, inverse_mass, problem))


def run_nuts(space: FitSpace, data, loss: str, ls, *, seed: int, nsteps: int = 1000,
             nchains: int = 4, warmup: int | None = None, progress: bool = False) -> MCMCResult:
    """NUTS from the least-squares optimum: ``warmup`` adaptation steps (default ``nsteps``),
    then ``nsteps`` draws per chain, ``nchains`` chains, one per core on the CPU."""
    t0 = time.perf_counter()
    problem = problem_of(space, pad_rows(space.static, data))
    nuisance = not has_absolute_noise(loss)
    names = space.names + (("log_noise",) if nuisance else ())
    warmup = nsteps if warmup is None else warmup
    starts = _starts(space, ls, nuisance, nchains, np.random.default_rng(seed))
    keys = jax.random.split(jax.random.PRNGKey(int(seed)), nchains)
    if progress:
        from fitlab.fitting.progress import line

        line(f"  NUTS: {nchains} chains × ({warmup} adaptation + {nsteps} draws) in one "
             "compiled call...")
    imm = jnp.asarray(_inverse_mass(space, ls, nuisance))
    with jax.numpy_dtype_promotion("standard"):  # blackjax mixes bool and int internally
        pos, logd, acc, div, depth, _ = _run_chains(
            space.static, loss, order_keys(space), space.ndim, int(nsteps), int(warmup), keys,
            jnp.asarray(starts), imm, problem)
    return assemble(space, names, np.asarray(pos), np.asarray(logd), np.asarray(acc),
                    np.asarray(div), nsteps, time.perf_counter() - t0, np.asarray(depth))


def assemble(space: FitSpace, names, pos, logd, acc, div, nsteps: int,
             seconds: float, depth=None) -> MCMCResult:
    """One dataset's MCMCResult from NUTS's draws (chains, draws, dim) in z coordinates;
    ``depth``: each draw's tree depth (chains, draws), checked against :data:`MAX_TREE_DEPTH`."""
    nchains = pos.shape[0]
    u = 1.0 / (1.0 + np.exp(-pos[..., : space.ndim]))
    chain_unit = np.concatenate([u, pos[..., space.ndim:]], axis=-1)
    ess, rhat = diagnostics(chain_unit, names)
    warnings = []
    n_div = int(np.sum(div))
    if n_div:
        warnings.append(f"{n_div} divergent NUTS transitions of {nchains * nsteps}: the "
                        "posterior has regions the sampler could not follow (a funnel or a "
                        "bound); check the intervals with emcee (--sampler emcee)")
    n_cap = 0 if depth is None else int(np.sum(np.asarray(depth) >= MAX_TREE_DEPTH))
    if n_cap:
        warnings.append(f"{n_cap} NUTS draws of {nchains * nsteps} reached the tree-depth cap "
                        f"{MAX_TREE_DEPTH} (2^{MAX_TREE_DEPTH} - 1 leapfrog steps): the chains "
                        "explore slowly there; check the intervals with emcee (--sampler emcee)")
    bad = [n for n, r in zip(names, rhat) if not r <= RHAT_MAX]
    if bad:
        warnings.append(f"THE CHAINS DISAGREE: split R-hat above {RHAT_MAX} for "
                        f"{', '.join(bad)}; rerun with more --mcmc-steps")
    low = float(np.min(ess))
    if not low >= ESS_PER_CHAIN * nchains:
        warnings.append(f"effective sample size {low:.0f} < {ESS_PER_CHAIN} × {nchains} chains: "
                        "rerun with more --mcmc-steps")
    trustworthy = not (bad or not low >= ESS_PER_CHAIN * nchains)
    flat = chain_unit.reshape(-1, chain_unit.shape[-1])
    samples_native = space.to_native(flat[:, : space.ndim])
    tau = (nchains * nsteps) / np.maximum(ess, 1e-12)  # integrated autocorrelation per draw
    return MCMCResult(samples_native, np.swapaxes(chain_unit, 0, 1), np.swapaxes(logd, 0, 1),
                      names, nchains, nsteps, 0, 1, tau, float(np.mean(acc)), low,
                      trustworthy, warnings, seconds, "nuts")


def _inverse_mass(space: FitSpace, ls, nuisance: bool) -> np.ndarray:
    """The adaptation's initial inverse mass matrix (dense, dim × dim): the least-squares
    covariance mapped to NUTS's coordinates (z = logit u, u = the unit box; the Jacobian
    dz/dθ by central differences of the elementwise map), and 1 / (2 dof) for log_noise, so the
    adaptation starts near the posterior's scales and correlations instead of at the identity
    (which sent early trajectories of a layered posterior to the tree-depth limit). Where the
    covariance is unusable, or exchangeable lobes are relabelled into canonical order, the
    diagonal of :func:`unit_stderr`'s variances is used."""
    native = np.asarray(ls.native, float)
    u_raw = space.to_unit(native)
    u = np.clip(canonical(space, u_raw[None])[0], 1e-6, 1 - 1e-6)
    var = np.clip(unit_stderr(space, ls) / (u * (1 - u)), 1e-4, 10.0) ** 2
    cov = np.diag(var)
    c = getattr(ls, "covariance", None)
    if c is not None and np.allclose(u, np.clip(u_raw, 1e-6, 1 - 1e-6)):
        c = np.asarray(c, float)
        if c.shape == (len(native),) * 2 and np.all(np.isfinite(c)):
            h = np.maximum(1e-6 * np.abs(native), 1e-9)

            def z(x):
                uu = np.clip(space.to_unit(x), 1e-12, 1 - 1e-12)
                return np.log(uu) - np.log1p(-uu)
            jac = (z(native + h) - z(native - h)) / (2 * h)  # the map is elementwise
            dense = jac[:, None] * c * jac[None, :]
            d = np.sqrt(np.clip(np.diag(dense), 1e-8, 100.0))
            corr = dense / np.sqrt(np.outer(np.diag(dense), np.diag(dense)).clip(1e-300))
            corr = 0.99 * np.nan_to_num(corr) + 0.01 * np.eye(len(d))  # keep it positive
            cand = d[:, None] * corr * d[None, :]
            if np.all(np.isfinite(cand)) and np.all(np.linalg.eigvalsh(cand) > 0):
                cov = cand
    if nuisance:
        k = cov.shape[0]
        cov = np.pad(cov, ((0, 1), (0, 1)))
        cov[k, k] = 1.0 / (2.0 * max(int(ls.dof), 1))
    return cov


def _starts(space: FitSpace, ls, nuisance: bool, nchains: int, rng) -> np.ndarray:
    """Chain starts in z coordinates around the least-squares optimum."""
    u0 = np.clip(canonical(space, space.to_unit(np.asarray(ls.native))[None])[0], 1e-6,
                 1 - 1e-6)
    z0 = np.log(u0) - np.log1p(-u0)
    if nuisance:
        z0 = np.concatenate([z0, [np.log(max(float(ls.noise_scale), 1e-300))]])
    return z0 + 1e-2 * rng.standard_normal((nchains, z0.size))


def run_nuts_many(items, *, seed: int, nsteps: int = 1000, nchains: int = 4,
                  warmup: int | None = None) -> list[MCMCResult]:
    """NUTS for many datasets of one structure at once: ``items`` = [(space, data (padded to
    one size), loss, ls)]. Throughput first: a dataset's chains and the datasets are vmapped,
    and on the CPU the datasets are shared out over the host devices, one share per core
    (:func:`_sampler_many`)."""
    t0 = time.perf_counter()
    space0, _, loss, _ = items[0]
    nuisance = not has_absolute_noise(loss)
    names = space0.names + (("log_noise",) if nuisance else ())
    warmup = nsteps if warmup is None else warmup
    n_real = len(items)
    ndevices = min(len(host_devices()), n_real)
    if ndevices > 1:  # every device the same share: copies of the last dataset, dropped below
        items = list(items) + [items[-1]] * (-n_real % ndevices)
    rng = np.random.default_rng(seed)
    starts = np.stack([_starts(sp, ls, nuisance, nchains, rng) for sp, _, _, ls in items])
    keys = jax.random.split(jax.random.PRNGKey(int(seed)), len(items) * nchains).reshape(
        len(items), nchains, -1)
    problems = [problem_of(sp, d) for sp, d, _, _ in items]
    problem = jax.tree.map(lambda *xs: jnp.stack(xs), *problems)
    run = _sampler_many(space0.static, loss, order_keys(space0), space0.ndim, int(nsteps),
                        int(warmup), ndevices if ndevices > 1 else 0)
    imm = jnp.asarray(np.stack([_inverse_mass(sp, ls, nuisance) for sp, _, _, ls in items]))
    with jax.numpy_dtype_promotion("standard"):
        pos, logd, acc, div, depth, _ = run(keys, jnp.asarray(starts), imm, problem)
    seconds = (time.perf_counter() - t0) / n_real
    return [assemble(sp, names, np.asarray(pos[i]), np.asarray(logd[i]), np.asarray(acc[i]),
                     np.asarray(div[i]), nsteps, seconds, np.asarray(depth[i]))
            for i, (sp, _, _, _) in enumerate(items[:n_real])]


@functools.lru_cache(maxsize=32)
def _sampler_many(static, loss: str, order: tuple, ndim: int, nsteps: int, warmup: int,
                  ndevices: int = 0):
    """The sampler of :func:`run_nuts_many`: chains and datasets vmapped (keys, starts, mass
    matrices and problems per dataset); ``ndevices`` > 1: the datasets (a multiple of it)
    shared out over that many host devices."""
    chain = _chain(static, loss, order, ndim, nsteps, warmup)
    local = jax.vmap(jax.vmap(chain, in_axes=(0, 0, None, None)), in_axes=(0, 0, 0, 0))
    if not ndevices:
        return jax.jit(local)
    return over_cores(local, ndevices, (True, True, True, True))


def diagnostics(chain_unit: np.ndarray, names) -> tuple[np.ndarray, np.ndarray]:
    """ArviZ's bulk ESS and split R̂ per coordinate of draws (chains, draws, dim)."""
    import arviz as az

    data = az.convert_to_dataset({n: chain_unit[..., k] for k, n in enumerate(names)})
    ess = az.ess(data, method="bulk")
    rhat = az.rhat(data)
    return (np.array([float(ess[n]) for n in names]), np.array([float(rhat[n]) for n in names]))


__all__ = ["run_nuts", "run_nuts_many", "assemble", "chain_layout", "diagnostics", "RHAT_MAX",
           "ESS_PER_CHAIN", "MAX_TREE_DEPTH"]
