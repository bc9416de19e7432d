"""Least squares: jaxopt Levenberg–Marquardt on jitted residuals, global starts with nlopt,
covariance from the Jacobian at the optimum.

The compiled kernels (residuals, cost and gradient, the vmapped LM) are cached by the fit's
static structure (model, options, free names, transforms, loss): data, bounds and fixed values
are arguments, so refitting new data of the same size reuses the compilation.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxopt
import nlopt
import numpy as np

from fitlab.fit.losses import has_absolute_noise, residuals
from fitlab.fit.space import FitSpace, StaticSpace, predict, to_native, unit_from_z, z_from_unit

#: Two optima count as "equally good" when their costs differ by less than this fraction ...
EQUAL_COST_RTOL = 0.01
#: ... and as "different" when some parameter differs by more than this in the unit box.
DISTINCT_UNIT = 0.05


class FitData(NamedTuple):
    """The rows a fit uses and the per-row loss constants (a pytree of arrays)."""

    wi: jnp.ndarray
    wo: jnp.ndarray
    value: jnp.ndarray
    consts: dict


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


def problem_of(space: FitSpace, data: FitData) -> dict:
    """The array arguments of every kernel."""
    return {**space.arrays(), "data": data}


def residuals_native(static: StaticSpace, loss: str, theta, problem):
    d = problem["data"]
    m = predict(static, theta, problem["fixed"], d.wi, d.wo)
    return residuals(loss, m, d.value, d.consts)


def residuals_unit(static, loss, u, problem):
    return residuals_native(static, loss, to_native(static, u, problem["lo"], problem["hi"]),
                            problem)


def cost_unit(static, loss, u, problem):
    r = residuals_unit(static, loss, u, problem)
    return 0.5 * jnp.sum(r * r)


@functools.lru_cache(maxsize=64)
def kernels(static: StaticSpace, loss: str, maxiter: int = 200):
    """Jitted kernels for one static structure: cost + gradient, batched LM, batched cost,
    residuals and their Jacobian in native units."""

    def r_z(z, problem):
        return residuals_unit(static, loss, unit_from_z(z), problem)

    solver = jaxopt.LevenbergMarquardt(residual_fun=r_z, maxiter=maxiter,
                                       stop_criterion="madsen-nielsen", xtol=1e-10, gtol=1e-10,
                                       solver="cholesky", materialize_jac=True,
                                       implicit_diff=False, jit=True)

    def lm_one(z0, problem):
        sol = solver.run(z0, problem)
        return sol.params, sol.state.iter_num

    cost = functools.partial(cost_unit, static, loss)
    r_nat = functools.partial(residuals_native, static, loss)
    return {
        "value_and_grad": jax.jit(jax.value_and_grad(cost)),
        "lm": jax.jit(jax.vmap(lm_one, in_axes=(0, None))),
        "cost_batch": jax.jit(jax.vmap(cost, in_axes=(0, None))),
        "residuals": jax.jit(r_nat),
        "jacobian": jax.jit(jax.jacfwd(r_nat)),
    }


def halton(n, d, skip=1):
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


def global_search(ndim, value_and_grad, problem, seed: int, maxeval: int):
    """nlopt multi-level single linkage over a low-discrepancy sequence (G_MLSL_LDS) with
    gradient-based local searches (LD_LBFGS), over the unit box of the bounds."""
    evals = [0]

    def objective(u, grad):
        evals[0] += 1
        v, g = value_and_grad(jnp.asarray(u), problem)
        if grad.size:
            grad[:] = np.nan_to_num(np.asarray(g), nan=0.0, posinf=0.0, neginf=0.0)
        v = float(v)
        return v if np.isfinite(v) else 1e300

    nlopt.srand(int(seed))
    opt = nlopt.opt(nlopt.G_MLSL_LDS, ndim)
    local = nlopt.opt(nlopt.LD_LBFGS, ndim)
    local.set_ftol_rel(1e-10)
    local.set_maxeval(200)
    opt.set_local_optimizer(local)
    opt.set_lower_bounds(np.zeros(ndim))
    opt.set_upper_bounds(np.ones(ndim))
    opt.set_min_objective(objective)
    opt.set_maxeval(int(maxeval))
    x0 = np.full(ndim, 0.5)
    try:
        u_best = opt.optimize(x0)
        status = opt.last_optimize_result()
    except (nlopt.RoundoffLimited, RuntimeError) as exc:  # keep the start point
        u_best, status = np.asarray(x0), f"stopped: {exc}"
    return np.clip(u_best, 0, 1), {"algorithm": "nlopt G_MLSL_LDS + LD_LBFGS",
                                   "evaluations": evals[0], "status": str(status),
                                   "best_cost": float(opt.last_optimum_value())}


def fit_least_squares(space: FitSpace, data: FitData, loss: str, *, start_native=None,
                      n_starts: int = 8, seed: int = 0,
                      global_maxeval: int | None = None) -> LeastSquaresResult:
    """Global search + multi-start LM + covariance. ``start_native`` (optional) is one more start."""
    k = kernels(space.static, loss)
    problem = problem_of(space, data)
    d = space.ndim
    u_glob, glob_info = global_search(d, k["value_and_grad"], problem, seed,
                                      global_maxeval or 150 * (d + 1))
    starts_u = [u_glob] + list(halton(n_starts, d))
    if start_native is not None:
        starts_u.append(space.to_unit(np.asarray(start_native, dtype=float)))
    # jaxopt's LM multiplies bool masks with floats; allow that even under strict promotion.
    with jax.numpy_dtype_promotion("standard"):
        Z, iters = k["lm"](jnp.asarray(np.stack([z_from_unit(u0) for u0 in starts_u])), problem)
    U = np.asarray(unit_from_z(Z))
    costs = np.asarray(k["cost_batch"](jnp.asarray(U), problem))
    runs = [{"u0": np.asarray(u0), "u": u, "cost": float(c) if np.isfinite(c) else np.inf,
             "iters": int(it)} for u0, u, c, it in zip(starts_u, U, costs, np.asarray(iters))]
    best = min(runs, key=lambda r: r["cost"])
    theta = np.asarray(space.to_native(best["u"]))
    r = np.asarray(k["residuals"](jnp.asarray(theta), problem))
    cost = 0.5 * float(r @ r)
    dof = max(r.size - d, 1)
    noise = 1.0 if has_absolute_noise(loss) else float(np.sqrt(2 * cost / dof))
    J = np.asarray(k["jacobian"](jnp.asarray(theta), problem))
    cov = noise**2 * np.linalg.pinv(J.T @ J)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    at_bound = tuple(p.name for p, u in zip(space.free, best["u"]) if u < 1e-6 or u > 1 - 1e-6)

    def named(u):
        return {n: float(v) for n, v in zip(space.names, np.asarray(space.to_native(u)))}

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
