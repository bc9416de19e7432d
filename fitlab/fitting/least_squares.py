"""Least squares: jaxopt Levenberg–Marquardt on jitted residuals, global starts with nlopt,
covariance from the Jacobian at the optimum.

Three compiled kernels per fit structure: the cost, and the cost with its gradient (for the
global search), and the local stage (Levenberg–Marquardt from every start at once, batched,
then each end's cost, residuals and Jacobian in native units). They are cached by the fit's
static structure (model, options, free names, transforms, loss): data, bounds and fixed values
are arguments, and the rows are padded to a ladder of sizes (``padded_size``; the extra rows are
masked out), so refitting new data of a similar size reuses the compilation (and ``fitlab fit``
keeps it on disk, see fitlab.fitting.cache).
"""

from __future__ import annotations

import functools
import math
import sys
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jaxopt
import nlopt
import numpy as np

from fitlab._jax import jax, jnp
from fitlab.fitting.exchange import canonical_runs
from fitlab.fitting.losses import has_absolute_noise, residuals
from fitlab.fitting.progress import bars_shown, line as progress_line
from fitlab.fitting.space import FitSpace, StaticSpace, predict, to_native, unit_from_z, z_from_unit
from fitlab.fitting.status import Status

#: jaxopt Levenberg–Marquardt settings: step limit, Madsen–Nielsen tolerances on the step and
#: the gradient, and the initial damping relative to the largest diagonal element of JᵀJ.
LM_MAXITER = 200
#: The largest step limit a user may ask for (each step solves a small linear system per start).
MAX_LM_MAXITER = 100_000
LM_XTOL = 1e-10
LM_GTOL = 1e-10
LM_DAMPING = 1e-6

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
    #: Aperture quadrature (fitlab.aperture): with weights (N, K), wi and wo are nodes
    #: (N, K, 3) and a row's model value is Σ_k weights[:, k] f(wi[:, k], wo[:, k]); None: one
    #: direction pair per row.
    weights: jnp.ndarray | None = None


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
    solver: dict  # why the best start's LM stopped (see lm_record)
    jacobian: np.ndarray | None = None  # ∂r/∂θ (rows, free) at the optimum, native units


#: Why a Levenberg–Marquardt run ended: its stopping rule was met, it ran out of steps, or it
#: ended at a point where the cost is not finite (NaN or inf).
LM_STOPPED = (Status.CONVERGED, Status.MAX_ITERATIONS, Status.NON_FINITE)


def lm_stop_reason(cost: float, iterations: int, rule_unmet: bool,
                   max_iterations: int) -> Status:
    """One of LM_STOPPED. A NaN gradient also ends jaxopt's loop (its stopping test compares
    NaN), so a non-finite end is named before the iteration count is looked at."""
    if not np.isfinite(cost):
        return Status.NON_FINITE
    if rule_unmet and iterations >= max_iterations:
        return Status.MAX_ITERATIONS
    return Status.CONVERGED


def problem_of(space: FitSpace, data: FitData) -> dict:
    """The array arguments of every kernel, on the device once (not copied at every call)."""
    return {**jax.device_put(space.arrays()), "data": jax.device_put(data)}


#: A per-row 0/1 array under this key of ``FitData.consts`` leaves the rows with 0 out of the fit
#: (their residual is 0) while the data keep their shape, so every fold of a cross-validation
#: reuses one compilation (fitlab.fitting.compare). Only the least-squares stage honours it.
ROW_MASK = "row_mask"


#: The smallest padded row count, and the ladder's ratio: 2^(1/4), so at most 19% more rows.
PAD_MIN_ROWS = 64
PAD_STEPS_PER_DOUBLING = 4


def padded_size(n: int) -> int:
    """The row count the least-squares kernels of ``n`` rows are compiled for: the smallest
    size ≥ n on the ladder 64 · 2^(k/4) (rounded up to a multiple of 8). Fits of one structure
    whose row counts fall on the same rung share one compilation, in a process and through the
    on-disk cache: two files of the same instrument rarely keep exactly as many rows."""
    n = int(n)
    if n <= PAD_MIN_ROWS:
        return PAD_MIN_ROWS
    k = max(math.floor(PAD_STEPS_PER_DOUBLING * math.log2(n / PAD_MIN_ROWS)) - 1, 0)
    while True:
        size = 8 * math.ceil(PAD_MIN_ROWS * 2 ** (k / PAD_STEPS_PER_DOUBLING) / 8)
        if size >= n:
            return size
        k += 1


def pad_rows(static, data: FitData) -> FitData:
    """``data`` padded to ``padded_size`` rows with copies of its last row that the row mask
    (``ROW_MASK``, added when absent) leaves out: their residuals and Jacobian rows are exactly
    0, so the cost, the gradient and JᵀJ are those of the rows given. A structure whose kernels
    depend on the row count itself (``static.rows_fixed``: a joint fit's rows per channel) is
    returned unpadded."""
    if static.rows_fixed:
        return data
    return pad_to(data, padded_size(int(np.shape(data.value)[0])))


def pad_to(data: FitData, size: int) -> FitData:
    """``data`` padded to ``size`` rows as :func:`pad_rows` pads (the batched fits pad a group
    of datasets to the size they share)."""
    host = jax.tree.map(np.asarray, data)
    n = int(host.value.shape[0])
    extra = size - n

    def grow(x):
        return np.concatenate([x, np.repeat(x[-1:], extra, axis=0)]) if extra else x

    mask = np.asarray(host.consts.get(ROW_MASK, np.ones(n)), dtype=np.float64)
    consts = {k: grow(v) for k, v in host.consts.items() if k != ROW_MASK}
    consts[ROW_MASK] = np.concatenate([mask, np.zeros(extra)])
    return FitData(grow(host.wi), grow(host.wo), grow(host.value), consts,
                   None if host.weights is None else grow(host.weights))


def predict_data(static: StaticSpace, theta, fixed: dict, d: FitData):
    """The model value of every row of ``d``: at its direction pair, or averaged over its
    aperture's nodes when ``d.weights`` is given."""
    m = predict(static, theta, fixed, d.wi, d.wo)
    return m if d.weights is None else jnp.sum(d.weights * m, axis=-1)


#: Key of the per-start row weights inside the local stage (see ``kernels``).
ROW_WEIGHT = "row_weight"


def residuals_native(static: StaticSpace, loss: str, theta, problem):
    d = problem["data"]
    m = predict_data(static, theta, problem["fixed"], d)
    r = residuals(loss, m, d.value, d.consts)
    return r * d.consts[ROW_MASK] if ROW_MASK in d.consts else r


def residuals_unit(static, loss, u, problem):
    return residuals_native(static, loss, to_native(static, u, problem["lo"], problem["hi"]),
                            problem)


def cost_unit(static, loss, u, problem):
    r = residuals_unit(static, loss, u, problem)
    return 0.5 * jnp.sum(r * r)


def _value_and_jacobian(f):
    """x -> (f(x), ∂f/∂x) in one forward-mode pass."""

    def both(x, *args):
        def f2(y):
            v = f(y, *args)
            return v, v

        J, v = jax.jacfwd(f2, has_aux=True)(x)
        return v, J

    return both


@functools.lru_cache(maxsize=64)
def kernels(static: StaticSpace, loss: str, maxiter: int = LM_MAXITER):
    """Jitted kernels for one static structure: ``value`` and ``value_and_grad`` (the cost, and
    the cost and its gradient as one array [cost, gradient...], in the unit box, for the global
    search) and ``local`` (LM from a batch of starts, then each end's cost, residuals and
    Jacobian in native units). ``local`` takes one row weight vector per start (the residuals
    are multiplied by it; ones for a fit): the block bootstrap (fitlab.fitting.resampling)
    refits a batch of resampled datasets, one per start, with the fit's own compilation."""

    r_and_jac_native = _value_and_jacobian(functools.partial(residuals_native, static, loss))

    def r_z(z, problem):
        return residuals_unit(static, loss, unit_from_z(z), problem) * problem[ROW_WEIGHT]

    # jaxopt's Levenberg–Marquardt (Madsen–Nielsen stopping rule, Cholesky on the materialized
    # JᵀJ), vmapped over the starts.
    solver = jaxopt.LevenbergMarquardt(residual_fun=r_z, maxiter=maxiter,
                                       damping_parameter=LM_DAMPING,
                                       stop_criterion="madsen-nielsen", xtol=LM_XTOL, gtol=LM_GTOL,
                                       solver="cholesky", materialize_jac=True,
                                       implicit_diff=False, jit=True)

    def one(z0, u0, w, problem):
        problem = {**problem, ROW_WEIGHT: w}
        sol = solver.run(z0, problem)
        # jaxopt's own stopping test (its loop's condition): still true after the loop means
        # the step limit, not the Madsen–Nielsen rule, ended the run.
        rule_unmet = solver._cond_fun(((sol.params, sol.state), ((problem,), {})))
        # A flat cost (every residual's Jacobian exactly 0, e.g. a lobe so narrow that the
        # model is 0 at every measured direction: Beckmann's D underflows to 0 there) makes
        # jaxopt's damping μ = τ max diag(JᵀJ) zero and its first step 0/0 = NaN. Such a run
        # ends where it started, marked by end_finite = False (lm_stopped "non_finite").
        end_finite = jnp.all(jnp.isfinite(sol.params))
        z = jnp.where(end_finite, sol.params, z0)
        theta = to_native(static, unit_from_z(z), problem["lo"], problem["hi"])
        r, J = r_and_jac_native(theta, problem)
        r, J = r * w, J * w[:, None]
        return {"z": z, "iters": sol.state.iter_num, "rule_unmet": rule_unmet,
                "end_finite": end_finite, "u": unit_from_z(z),
                "native": theta, "cost": 0.5 * jnp.sum(r * r), "residuals": r, "jacobian": J,
                "start_native": to_native(static, u0, problem["lo"], problem["hi"])}

    def local(Z0, U0, W, problem):
        return jax.vmap(one, in_axes=(0, 0, 0, None))(Z0, U0, W, problem)

    cost = functools.partial(cost_unit, static, loss)

    def value_and_grad(u, problem):
        v, g = jax.value_and_grad(cost)(u, problem)
        return jnp.concatenate([v[None], g])

    return {
        "value": jax.jit(cost),
        "value_and_grad": jax.jit(value_and_grad),
        "local": jax.jit(local),
        "local_fn": local,  # not compiled: fitlab.fitting.batch vmaps it over datasets
    }


def _primes(d):
    """The first d primes (one Halton base per dimension; a joint fit over channels has many)."""
    out, k = [], 2
    while len(out) < d:
        if all(k % p for p in out if p * p <= k):
            out.append(k)
        k += 1
    return out


def halton(n, d, skip=1):
    """First n points of the d-dimensional Halton sequence (a low-discrepancy start set)."""
    primes = _primes(d)
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


def progress_bar(enabled: bool, total: int, desc: str, unit: str):
    """A tqdm bar on stderr (rate and time left), or None when progress is off (or brief and
    stderr is no terminal: fitlab.fitting.progress)."""
    if not enabled or not bars_shown():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                mininterval=0.5, dynamic_ncols=True)


def global_search(ndim, value_and_grad, problem, seed: int, maxeval: int, value=None,
                  on_eval=None):
    """nlopt multi-level single linkage over a low-discrepancy sequence (G_MLSL_LDS) with
    gradient-based local searches (LD_LBFGS), over the unit box of the bounds.
    ``value_and_grad(u, problem)`` returns one array, [cost, gradient...] (one transfer);
    ``value(u, problem)``, if given, the cost alone, for the points where nlopt needs no
    gradient (most of the low-discrepancy samples). ``on_eval()``, if given, is called after
    every evaluation (progress)."""
    evals, non_finite = [0], [0]
    best = {"u": np.full(ndim, 0.5), "v": np.inf}

    def objective(u, grad):
        evals[0] += 1
        if on_eval is not None:
            on_eval()
        if grad.size or value is None:
            vg = np.asarray(value_and_grad(u, problem))
            if grad.size:
                grad[:] = np.nan_to_num(vg[1:], nan=0.0, posinf=0.0, neginf=0.0)
            v = float(vg[0])
        else:
            v = float(np.asarray(value(u, problem)))
        if not np.isfinite(v):
            non_finite[0] += 1  # nlopt sees a huge cost instead (it cannot handle NaN)
            return 1e300
        if v < best["v"]:
            best["u"], best["v"] = np.array(u, dtype=float), v
        return v

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
        opt.optimize(x0)
        status = str(opt.last_optimize_result())
    except Exception as exc:  # nlopt stops a local search it cannot continue (roundoff, a
        # failed line search); the best point evaluated so far is still a valid start.
        status = f"stopped early ({type(exc).__name__}: {exc}); best evaluated point kept"
    return np.clip(best["u"], 0, 1), {"algorithm": "nlopt G_MLSL_LDS + LD_LBFGS",
                                      "evaluations": evals[0], "non_finite": non_finite[0],
                                      "status": status,
                                      "best_cost": best["v"] if np.isfinite(best["v"]) else None}


#: (static, loss, starts, rows) of the local stages compiled in this process.
_compiled_local = set()


def _compile_local(k, problem, n_local, d):
    """Compile (and run once, on placeholder starts) the local stage for this shape."""
    with jax.numpy_dtype_promotion("standard"):  # jaxopt multiplies bool masks with floats
        n_rows = problem["data"].value.shape[0]
        jax.block_until_ready(k["local"](np.zeros((n_local, d)), np.full((n_local, d), 0.5),
                                         np.ones((n_local, n_rows)), problem))


def local_fits(k, problem, starts_u, weights=None):
    """Levenberg–Marquardt from each start (unit-box points) in one batched call; per start (as
    NumPy arrays): z (logit coordinates), iters, rule_unmet (LM's stopping rule not met at
    the end), u, native, cost, residuals, jacobian (native
    units), start_native. ``weights`` (starts, rows), if given, multiplies each start's
    residuals (default ones: every start fits the same data)."""
    U0 = np.stack([np.asarray(u0, dtype=float) for u0 in starts_u])
    Z0 = np.stack([z_from_unit(u0) for u0 in U0])
    W = (np.ones((U0.shape[0], problem["data"].value.shape[0])) if weights is None
         else np.asarray(weights, dtype=float))
    with jax.numpy_dtype_promotion("standard"):  # jaxopt multiplies bool masks with floats
        out = k["local"](Z0, U0, W, problem)
    return {key: np.asarray(v) for key, v in out.items()}


def fit_least_squares(space: FitSpace, data: FitData, loss: str, *, start_native=None,
                      n_starts: int = 8, seed: int = 0,
                      global_maxeval: int | None = None,
                      lm_maxiter: int = LM_MAXITER, progress: bool = False) -> LeastSquaresResult:
    """Global search + multi-start LM + covariance. ``start_native`` (optional) is one more start;
    ``lm_maxiter`` is each LM run's step limit; ``progress`` shows a bar with an estimate of the
    time left for the global search, then the Levenberg–Marquardt stage, on stderr."""
    k = kernels(space.static, loss, int(lm_maxiter))
    n_rows = int(data.value.shape[0])
    data = pad_rows(space.static, data)
    problem = problem_of(space, data)
    d = space.ndim
    n_local = 1 + n_starts + (start_native is not None)
    with ThreadPoolExecutor(max_workers=1) as pool:
        # The first fit of this shape in the process compiles the local stage meanwhile (XLA
        # compiles outside the GIL, so with two cores the two compilations overlap).
        key = (space.static, loss, int(lm_maxiter), n_local, int(data.value.shape[0]),
               None if data.weights is None else tuple(data.weights.shape))
        warm = None if key in _compiled_local else pool.submit(
            _compile_local, k, problem, n_local, d)
        maxeval = global_maxeval or 150 * (d + 1)
        bar = progress_bar(progress, maxeval, "  global search", "eval")
        try:
            u_glob, glob_info = global_search(d, k["value_and_grad"], problem, seed, maxeval,
                                              value=k["value"],
                                              on_eval=None if bar is None else bar.update)
        finally:
            if bar is not None:
                bar.close()
        if warm is not None:
            if progress and not warm.done():
                progress_line("  compiling the Levenberg-Marquardt stage for this data shape "
                              "(once per shape; cached on disk)...")
            warm.result()
            _compiled_local.add(key)
    starts_u = [u_glob] + list(halton(n_starts, d))
    if start_native is not None:
        starts_u.append(space.to_unit(np.asarray(start_native, dtype=float)))
    if progress:
        progress_line(f"  Levenberg-Marquardt from {len(starts_u)} starts at once...")
    loc = canonical_runs(space, local_fits(k, problem, starts_u))  # one labelling of
    # interchangeable lobes (a sum that repeats a component: fitlab/fitting/exchange.py)
    runs = [{"u0": np.asarray(u0), "u": loc["u"][i],
             "cost": (float(loc["cost"][i]) if np.isfinite(loc["cost"][i])
                      and loc["end_finite"][i] else np.inf),
             "iters": int(loc["iters"][i]),
             "stopped": lm_stop_reason(float(loc["cost"][i]) if loc["end_finite"][i] else np.nan,
                                       int(loc["iters"][i]), bool(loc["rule_unmet"][i]),
                                       int(lm_maxiter)),
             "index": i} for i, u0 in enumerate(starts_u)]
    best = min(runs, key=lambda r: r["cost"])
    ib = best["index"]
    theta = loc["native"][ib]
    r = loc["residuals"][ib][:n_rows]  # the padding's rows are 0 (pad_rows)
    cost = 0.5 * float(r @ r)
    dof = max(r.size - d, 1)
    noise = 1.0 if has_absolute_noise(loss) else float(np.sqrt(2 * cost / dof))
    J = loc["jacobian"][ib][:n_rows]
    cov = noise**2 * np.linalg.pinv(J.T @ J)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    at_bound = tuple(p.name for p, u in zip(space.free, best["u"]) if u < 1e-6 or u > 1 - 1e-6)

    def named(native):
        return {n: float(v) for n, v in zip(space.names, native)}

    starts = [{"start": named(loc["start_native"][rr["index"]]),
               "end": named(loc["native"][rr["index"]]) if np.isfinite(rr["cost"]) else None,
               "cost": rr["cost"] if np.isfinite(rr["cost"]) else None,
               "lm_iterations": rr["iters"], "lm_stopped": rr["stopped"]} for rr in runs]
    equal = [rr for rr in runs if rr["cost"] <= best["cost"] * (1 + EQUAL_COST_RTOL) + 1e-300]
    distinct = [rr for rr in equal if np.max(np.abs(rr["u"] - best["u"])) > DISTINCT_UNIT]
    worse = [rr for rr in runs if rr["cost"] > best["cost"] * (1 + EQUAL_COST_RTOL)]
    disagreement = None
    if distinct:
        disagreement = {
            "message": f"{len(distinct)} of {len(runs)} starts reached fits as good as the best "
                       "(cost within 1%) at different parameters: the data do not pin the "
                       "parameters down uniquely",
            "optima": [named(loc["native"][rr["index"]]) for rr in distinct],
        }
    glob_info = dict(glob_info, lm_starts=len(runs), local_minima_worse=len(worse))
    solver = lm_record(best["stopped"], best["iters"], int(lm_maxiter))
    return LeastSquaresResult(theta, cost, r, cov, stderr, noise, dof, at_bound,
                              best["iters"], starts, disagreement, glob_info, solver, J)


def lm_record(stopped: str, iterations: int, max_iterations: int) -> dict:
    """The parameter file's ``solver`` entry: how the best start's Levenberg–Marquardt run
    ended (data_formats/fit_json.md)."""
    return {"algorithm": "jaxopt LevenbergMarquardt (Madsen-Nielsen stopping rule)",
            "stopped": stopped, "iterations": int(iterations),
            "max_iterations": int(max_iterations), "xtol": LM_XTOL, "gtol": LM_GTOL}
