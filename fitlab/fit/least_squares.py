"""Least squares: jaxopt Levenberg–Marquardt on jitted residuals, global starts with nlopt,
covariance from the Jacobian at the optimum."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxopt
import nlopt
import numpy as np

from fitlab.fit.losses import has_absolute_noise, residuals
from fitlab.fit.space import FitSpace, unit_from_z, z_from_unit

#: Two optima count as "equally good" when their costs differ by less than this fraction ...
EQUAL_COST_RTOL = 0.01
#: ... and as "different" when some parameter differs by more than this in the unit box.
DISTINCT_UNIT = 0.05


class FitData(NamedTuple):
    """The rows a fit uses, as device arrays, and the per-row loss constants."""

    wi: jnp.ndarray
    wo: jnp.ndarray
    value: jnp.ndarray
    consts: dict
    loss: str


class LeastSquaresResult(NamedTuple):
    native: np.ndarray
    cost: float  # ½ Σ r²
    residuals: np.ndarray
    covariance: np.ndarray
    stderr: np.ndarray
    noise_scale: float  # σ̂ of one residual (1 for chi2)
    dof: int
    at_bound: tuple[str, ...]
    lm_iterations: int
    starts: list  # [{"start": {...}, "end": {...}, "cost": ...}]
    disagreement: dict | None
    global_search: dict


def residual_fn(space: FitSpace, data: FitData):
    """r(θ_native) for one native parameter vector."""

    def r(theta):
        m = space.predict(theta, data.wi, data.wo)
        return residuals(data.loss, m, data.value, data.consts)

    return r


def lm_batch(r_z, maxiter: int = 200):
    """One jitted, vmapped jaxopt Levenberg–Marquardt over a batch of starts z0 (k, ndim).

    Stops by Madsen–Nielsen's criteria (step and gradient below 1e-10): the grad-norm criterion
    never triggers on residuals that do not vanish at the optimum."""
    solver = jaxopt.LevenbergMarquardt(residual_fun=r_z, maxiter=maxiter,
                                       stop_criterion="madsen-nielsen", xtol=1e-10, gtol=1e-10,
                                       solver="cholesky", materialize_jac=True,
                                       implicit_diff=False, jit=True)

    def one(z0):
        sol = solver.run(z0)
        return sol.params, sol.state.iter_num

    return jax.jit(jax.vmap(one))


def _halton(n, d, skip=1):
    """First n points of the d-dimensional Halton sequence (a low-discrepancy start set)."""
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47][:d]
    out = np.empty((n, d))
    for j, b in enumerate(primes):
        for i in range(n):
            k, f, x = i + skip, 1.0, 0.0
            while k > 0:
                f /= b
                x += f * (k % b)
                k //= b
            out[i, j] = x
    return out


def global_search(space: FitSpace, cost_u, seed: int, maxeval: int):
    """nlopt multi-level single linkage over a low-discrepancy sequence (G_MLSL_LDS) with
    gradient-based local searches (LD_LBFGS), over the unit box of the bounds."""
    value_and_grad = jax.jit(jax.value_and_grad(cost_u))
    evals = [0]

    def objective(u, grad):
        evals[0] += 1
        v, g = value_and_grad(jnp.asarray(u))
        if grad.size:
            grad[:] = np.nan_to_num(np.asarray(g), nan=0.0, posinf=0.0, neginf=0.0)
        v = float(v)
        return v if np.isfinite(v) else 1e300

    nlopt.srand(int(seed))
    opt = nlopt.opt(nlopt.G_MLSL_LDS, space.ndim)
    local = nlopt.opt(nlopt.LD_LBFGS, space.ndim)
    local.set_ftol_rel(1e-10)
    local.set_maxeval(200)
    opt.set_local_optimizer(local)
    opt.set_lower_bounds(np.zeros(space.ndim))
    opt.set_upper_bounds(np.ones(space.ndim))
    opt.set_min_objective(objective)
    opt.set_maxeval(int(maxeval))
    x0 = np.full(space.ndim, 0.5)
    try:
        u_best = opt.optimize(x0)
        status = opt.last_optimize_result()
    except (nlopt.RoundoffLimited, RuntimeError) as exc:  # keep the best point found
        u_best, status = np.asarray(x0), f"stopped: {exc}"
    return np.clip(u_best, 0, 1), {"algorithm": "nlopt G_MLSL_LDS + LD_LBFGS",
                                   "evaluations": evals[0], "status": str(status),
                                   "best_cost": float(opt.last_optimum_value())}


def fit_least_squares(space: FitSpace, data: FitData, *, start_native=None, n_starts: int = 8,
                      seed: int = 0, global_maxeval: int | None = None) -> LeastSquaresResult:
    """Global search + multi-start LM + covariance. ``start_native`` (optional) is one more start."""
    r_native = residual_fn(space, data)
    r_z = lambda z: r_native(space.to_native(unit_from_z(z)))  # noqa: E731
    cost_u = lambda u: 0.5 * jnp.sum(r_native(space.to_native(u)) ** 2)  # noqa: E731

    u_glob, glob_info = global_search(space, cost_u, seed,
                                      global_maxeval or 150 * (space.ndim + 1))
    starts_u = [u_glob] + list(_halton(n_starts, space.ndim))
    if start_native is not None:
        starts_u.append(space.to_unit(np.asarray(start_native, dtype=float)))
    Z, iters = lm_batch(r_z)(jnp.asarray(np.stack([z_from_unit(u0) for u0 in starts_u])))
    U = np.asarray(unit_from_z(Z))
    costs = np.asarray(jax.vmap(cost_u)(jnp.asarray(U)))
    runs = [{"u0": np.asarray(u0), "u": u, "cost": float(c) if np.isfinite(c) else np.inf,
             "iters": int(it)} for u0, u, c, it in zip(starts_u, U, costs, np.asarray(iters))]
    best = min(runs, key=lambda r: r["cost"])
    theta = np.asarray(space.to_native(jnp.asarray(best["u"])))
    r = np.asarray(r_native(jnp.asarray(theta)))
    cost = 0.5 * float(r @ r)
    n, d = r.size, space.ndim
    dof = max(n - d, 1)
    noise = 1.0 if has_absolute_noise(data.loss) else float(np.sqrt(2 * cost / dof))
    J = np.asarray(jax.jacfwd(r_native)(jnp.asarray(theta)))
    cov = noise**2 * np.linalg.pinv(J.T @ J)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    at_bound = tuple(p.name for p, u in zip(space.free, best["u"]) if u < 1e-6 or u > 1 - 1e-6)

    def named(u):
        return {k: float(v) for k, v in zip(space.names, np.asarray(space.to_native(jnp.asarray(u))))}

    starts = [{"start": named(rr["u0"]), "end": named(rr["u"]), "cost": rr["cost"],
               "lm_iterations": rr["iters"]} for rr in runs]
    equal = [rr for rr in runs if rr["cost"] <= best["cost"] * (1 + EQUAL_COST_RTOL) + 1e-300]
    distinct = [rr for rr in equal if np.max(np.abs(rr["u"] - best["u"])) > DISTINCT_UNIT]
    worse = [rr for rr in runs if rr["cost"] > best["cost"] * (1 + EQUAL_COST_RTOL)]
    disagreement = None
    if distinct:
        disagreement = {
            "message": f"{len(distinct)} of {len(runs)} starts reached fits as good as the best "
                       "(cost within 1%) at different parameters: the data do not pin the "
                       "parameters down uniquely",
            "optima": [named(rr["u"]) for rr in distinct],
        }
    glob_info = dict(glob_info, lm_starts=len(runs), local_minima_worse=len(worse))
    return LeastSquaresResult(theta, cost, r, cov, stderr, noise, dof, at_bound,
                              best["iters"], starts, disagreement, glob_info)
