"""Least squares: a global stage that picks the starts, Levenberg–Marquardt (fitlab.fitting.
solvers: fitlab's own by default, jaxopt's as the reference) on jitted residuals from every
start at once, covariance from the Jacobian at the optimum.

The global stage (fitlab.fitting.searches) is by default a *scan*: the cost at a few hundred
Halton points of the unit box, all in one compiled call (:func:`scan_costs`; the batched fits,
fitlab.fitting.batch, run the same scan vmapped over datasets); Levenberg–Marquardt starts from
its best points. ``mlsl`` is nlopt's multi-level single linkage, one evaluation at a time, then
its best point and Halton points.

The compiled kernels per fit structure: the scan's costs, the cost and the cost with its
gradient (for nlopt), and the local stage (Levenberg–Marquardt from every start at once,
batched, then each end's cost, residuals and Jacobian in native units). They are cached by the fit's
static structure (model, options, free names, transforms, loss): data, bounds and fixed values
are arguments, and the rows are padded to a ladder of sizes (``padded_size``; the extra rows are
masked out), so refitting new data of a similar size reuses the compilation (and ``fitlab fit``
keeps it on disk, see fitlab.fitting.cache).
"""

from __future__ import annotations

import functools
import math
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.fitting.exchange import canonical_runs
from fitlab.fitting.lm import value_and_jacobian
from fitlab.fitting.losses import has_absolute_noise, residuals
from fitlab.fitting.progress import line as progress_line
from fitlab.fitting.searches import (DEFAULT_GLOBAL_SEARCH, SCAN_BLOCK, SCAN_ROWS, START_ROWS,
                                     START_SUBSET_ABOVE, global_start)
from fitlab.fitting.solvers import DEFAULT_LOCAL_SOLVER, LOCAL_SOLVERS, algorithm
from fitlab.fitting.space import FitSpace, StaticSpace, predict, to_native, unit_from_z, z_from_unit
from fitlab.fitting.status import Status
from fitlab.models.base import call_work

#: Levenberg–Marquardt settings (both solvers): step limit, Madsen–Nielsen tolerances on the step and
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


def lm_stop_reasons(cost, iterations, rule_unmet, max_iterations: int) -> list[Status]:
    """One of LM_STOPPED per fit (arrays of the fits' costs, iteration counts and whether
    their stopping rule was unmet). A NaN gradient also ends the solvers' loops (their
    stopping tests compare NaN), so a non-finite end is named before the iteration count is
    looked at."""
    cost = np.asarray(cost, dtype=float).ravel()
    out_of_steps = np.asarray(rule_unmet, dtype=bool).ravel() & (
        np.asarray(iterations).ravel() >= max_iterations)
    which = np.where(~np.isfinite(cost), LM_STOPPED.index(Status.NON_FINITE),
                     np.where(out_of_steps, LM_STOPPED.index(Status.MAX_ITERATIONS),
                              LM_STOPPED.index(Status.CONVERGED)))
    return [LM_STOPPED[k] for k in which]


def lm_stop_reason(cost: float, iterations: int, rule_unmet: bool,
                   max_iterations: int) -> Status:
    """One fit's :func:`lm_stop_reasons`."""
    return lm_stop_reasons([cost], [iterations], [rule_unmet], max_iterations)[0]


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


def pad_to(data: FitData, size: int, axis: int = 0) -> FitData:
    """``data`` padded to ``size`` rows as :func:`pad_rows` pads: copies of its last row that
    the row mask leaves out. ``axis``: the rows' axis (1 for datasets stacked on axis 0, as the
    batched fits stack them, fitlab.fitting.batch); fields that are None stay None."""
    host = jax.tree.map(np.asarray, data)
    n = int(host.value.shape[axis])
    extra = size - n

    def grow(x):
        if not extra:
            return x
        return np.concatenate([x, np.repeat(np.take(x, [-1], axis=axis), extra, axis=axis)],
                              axis=axis)

    mask = np.asarray(host.consts.get(ROW_MASK, np.ones(host.value.shape[:axis + 1])),
                      dtype=np.float64)
    grown = jax.tree.map(grow, host._replace(
        consts={k: v for k, v in host.consts.items() if k != ROW_MASK}))
    mask = np.concatenate([mask, np.zeros(mask.shape[:axis] + (extra,))], axis=axis)
    return grown._replace(consts={**grown.consts, ROW_MASK: mask})


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


def residuals_z(static: StaticSpace, loss: str, z, problem):
    """The residuals at logit coordinates ``z`` of the unit box, times the start's row weights
    (``problem[ROW_WEIGHT]``): what Levenberg–Marquardt minimises."""
    return residuals_unit(static, loss, unit_from_z(z), problem) * problem[ROW_WEIGHT]


def lm_end(static: StaticSpace, loss: str):
    """``(z_end, iters, rule_unmet, z0, u0, w, problem)`` -> the record of one
    Levenberg–Marquardt run's end (row weights ``w``): where it ended, how, and its cost,
    residuals and Jacobian in native units. :func:`local_stage` and the batched fits
    (fitlab.fitting.batch) share it."""
    r_and_jac_native = value_and_jacobian(functools.partial(residuals_native, static, loss))

    def end(z_end, iters, rule_unmet, z0, u0, w, problem):
        # A flat cost (every residual's Jacobian exactly 0, e.g. a lobe so narrow that the
        # model is 0 at every measured direction: Beckmann's D underflows to 0 there) makes the
        # damping μ = τ max diag(JᵀJ) zero and the first step 0/0 = NaN. Such a run ends where
        # it started, marked by end_finite = False (lm_stopped "non_finite").
        end_finite = jnp.all(jnp.isfinite(z_end))
        z = jnp.where(end_finite, z_end, z0)
        theta = to_native(static, unit_from_z(z), problem["lo"], problem["hi"])
        r, J = r_and_jac_native(theta, problem)
        r, J = r * w, J * w[:, None]
        return {"z": z, "iters": iters, "rule_unmet": rule_unmet, "end_finite": end_finite,
                "u": unit_from_z(z), "native": theta, "cost": 0.5 * jnp.sum(r * r),
                "residuals": r, "jacobian": J,
                "start_native": to_native(static, u0, problem["lo"], problem["hi"])}

    return end


def local_stage(static: StaticSpace, loss: str, run_lm, sequential: bool = False):
    """``(Z0, U0, W, problem)`` -> per start (vmapped, or one after another with
    ``sequential``): Levenberg–Marquardt by ``run_lm(z0, problem)`` -> (end, steps,
    rule_unmet), then the end's record (:func:`lm_end`)."""
    end = lm_end(static, loss)

    def one(z0, u0, w, problem):
        problem = {**problem, ROW_WEIGHT: w}
        z_end, iters, rule_unmet = run_lm(z0, problem)
        return end(z_end, iters, rule_unmet, z0, u0, w, problem)

    def local(Z0, U0, W, problem):
        if sequential:
            return jax.lax.map(lambda a: one(*a, problem), (Z0, U0, W))
        return jax.vmap(one, in_axes=(0, 0, 0, None))(Z0, U0, W, problem)

    return local


def at_bound_mask(u) -> np.ndarray:
    """Which unit-box coordinates of ``u`` (any shape) lie within AT_BOUND_UNIT of a bound."""
    u = np.asarray(u)
    return (u < AT_BOUND_UNIT) | (u > 1 - AT_BOUND_UNIT)


def names_at_bound(names, u) -> tuple[str, ...]:
    """The names whose unit-box coordinate in ``u`` lies within AT_BOUND_UNIT of a bound."""
    return tuple(n for n, b in zip(names, at_bound_mask(u)) if b)


def names_at_bound_many(names, U) -> list[tuple[str, ...]]:
    """:func:`names_at_bound` of every row of ``U`` (fits, coordinates): each distinct pattern
    named once."""
    patterns, which = np.unique(at_bound_mask(U), axis=0, return_inverse=True)
    named = [tuple(n for n, b in zip(names, row) if b) for row in patterns]
    return [named[k] for k in np.ravel(which)]


@functools.lru_cache(maxsize=64)
def kernels(static: StaticSpace, loss: str, maxiter: int = LM_MAXITER,
            solver: str = DEFAULT_LOCAL_SOLVER):
    """Jitted kernels for one static structure: ``scan`` (the cost at a batch of unit-box
    points, :func:`scan_costs`), ``value`` and ``value_and_grad`` (the cost, and the cost and
    its gradient as one array [cost, gradient...], in the unit box, for nlopt's search) and
    ``local`` (LM by ``solver``, a name of fitlab.fitting.solvers.LOCAL_SOLVERS, from a batch of
    starts, then each end's cost, residuals and Jacobian in native units). ``local`` takes one
    row weight vector per start (the residuals are multiplied by it; ones for a fit): the block
    bootstrap (fitlab.fitting.resampling) refits a batch of resampled datasets, one per start,
    with the fit's own compilation."""
    run_lm = LOCAL_SOLVERS[solver].make(functools.partial(residuals_z, static, loss),
                                        int(maxiter), LM_XTOL, LM_GTOL, LM_DAMPING)
    # the starts one after another (lax.map): each start's loop ends with its own rule, so the
    # stage costs the sum of the starts' steps, not their number times the slowest one's (a
    # vmapped while_loop runs every lane until the last stops). Each step is vectorised over
    # the rows already. Measured (benchmarks/bench_global_stage.py, 9,904 rows, 10 starts):
    # 0.36 s against 0.88 s vmapped.
    local = local_stage(static, loss, run_lm, sequential=True)

    cost = functools.partial(cost_unit, static, loss)

    def value_and_grad(u, problem):
        v, g = jax.value_and_grad(cost)(u, problem)
        return jnp.concatenate([v[None], g])

    return {
        "scan": jax.jit(functools.partial(scan_costs, static, loss)),
        "value": jax.jit(cost),
        "value_and_grad": jax.jit(value_and_grad),
        "local": jax.jit(local),
        "local_fn": local,  # not compiled: fitlab.fitting.batch vmaps it over datasets
    }


def scan_costs(static: StaticSpace, loss: str, U, problem):
    """The cost at every point of ``U`` (P, d) of the unit box: one compiled call, a block of
    points at a time (at most SCAN_BLOCK point-row pairs, a model's per-call samples counted
    as rows: :func:`fitlab.models.base.call_work`; all at once for small data)."""
    block = scan_block(int(U.shape[0]), int(problem["data"].value.shape[0]), static.model)
    return jax.lax.map(lambda u: cost_unit(static, loss, u, problem), U, batch_size=block)


def scan_block(points: int, rows: int, model) -> int:
    """Points evaluated together by a scan over ``rows`` rows: at most SCAN_BLOCK point-row
    pairs, each point's per-call samples (:func:`fitlab.models.base.call_work`: SpongeCake's
    energy budget tabulates 45,056 to 90,112 per parameter set) counted as rows (without them
    a two-layer lobe fit's scan of 4,096 points asked for 40 GB at once)."""
    return max(1, min(points, SCAN_BLOCK // max(rows + call_work(model), 1)))


def scan_rows(static: StaticSpace, data: FitData, limit: int = SCAN_ROWS) -> FitData:
    """The rows the scan evaluates (``limit`` SCAN_ROWS; the starts, START_ROWS): all of them
    up to ``limit``, else ``limit`` rows evenly spread over the data (in their order). A
    structure whose kernels depend on its row counts (``static.rows_fixed``: a joint fit)
    keeps every row."""
    n = int(np.shape(data.value)[0])
    if static.rows_fixed or n <= limit:
        return data
    keep = np.unique(np.round(np.linspace(0, n - 1, limit)).astype(int))
    return jax.tree.map(lambda x: np.asarray(x)[keep], data)


#: (static, loss, starts, rows) of the local stages compiled in this process.
_compiled_local = set()


def _compile_local(k, problem, n_local, d, all_rows=None):
    """Compile (and run once, on placeholder starts) the local stage for this shape, and with
    ``all_rows`` (the problem of every row of a fit whose starts run on START_ROWS of them) what
    :func:`_refined` runs on every row: one start's local stage and the cost."""
    with jax.numpy_dtype_promotion("standard"):  # jaxopt multiplies bool masks with floats
        for p, n in ((problem, n_local),) + (() if all_rows is None else ((all_rows, 1),)):
            n_rows = p["data"].value.shape[0]
            jax.block_until_ready(k["local"](np.zeros((n, d)), np.full((n, d), 0.5),
                                             np.ones((n, n_rows)), p))
        if all_rows is not None:
            jax.block_until_ready(k["value"](np.full(d, 0.5), all_rows))


def _refined(k, space, problem, loc: dict, lm_maxiter: int) -> dict:
    """The starts' Levenberg–Marquardt ends on START_ROWS rows (``loc``, :func:`local_fits`)
    carried to every row of ``problem``: each end's cost on every row, then the best end, and
    each end as good (cost within EQUAL_COST_RTOL) at other parameters (more than DISTINCT_UNIT
    apart: one per such basin), refined by Levenberg–Marquardt on every row (its steps added to
    the start's), until the best end is a refined one. The starts find the basins on a thousand
    rows, and only the runs the fit reports pay for every row (benchmarks/README.md, "The
    single fit at scale"). Returns ``loc`` so changed (its residuals and Jacobians those of
    every row, NaN for ends not refined)."""
    n = len(loc["cost"])
    n_rows = int(problem["data"].value.shape[0])
    out = {key: v.copy() for key, v in loc.items() if key not in ("residuals", "jacobian")}
    out["residuals"] = np.full((n, n_rows), np.nan)
    out["jacobian"] = np.full((n, n_rows, space.ndim), np.nan)
    for i in range(n):
        if loc["end_finite"][i]:
            out["cost"][i] = float(k["value"](loc["u"][i], problem))
    refined: list[int] = []

    def refine(i):
        again = canonical_runs(space, local_fits(k, problem, [loc["u"][i]]))
        for key in out:
            out[key][i] = again[key][0]
        out["iters"][i] = loc["iters"][i] + again["iters"][0]
        out["start_native"][i] = loc["start_native"][i]
        refined.append(i)

    def costs():
        return np.array([r["cost"] for r in lm_runs(out, lm_maxiter)])

    c = costs()
    for i in np.argsort(c, kind="stable"):
        if not np.isfinite(c[i]) or (refined and c[i] > c[refined[0]] * (1 + EQUAL_COST_RTOL)
                                     + 1e-300):
            break
        if all(np.max(np.abs(loc["u"][i] - loc["u"][j])) > DISTINCT_UNIT for j in refined):
            refine(i)
    while True:  # an end not refined that is now the best: refined too
        c = costs()
        i = int(np.argmin(c))
        if i in refined or not np.isfinite(c[i]):
            return out
        refine(i)


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


def lm_runs(loc: dict, lm_maxiter: int) -> list[dict]:
    """Per start of the local stage's output ``loc``: its end ``u``, ``cost`` (inf where not
    finite), ``iters``, ``stopped`` (one of LM_STOPPED) and ``index``."""
    return [{"u": loc["u"][i],
             "cost": (float(loc["cost"][i]) if np.isfinite(loc["cost"][i])
                      and loc["end_finite"][i] else np.inf),
             "iters": int(loc["iters"][i]),
             "stopped": lm_stop_reason(float(loc["cost"][i]) if loc["end_finite"][i] else np.nan,
                                       int(loc["iters"][i]), bool(loc["rule_unmet"][i]),
                                       int(lm_maxiter)),
             "index": i} for i in range(len(loc["cost"]))]


#: A parameter this close to a bound (unit box) at the optimum is reported at the bound.
AT_BOUND_UNIT = 1e-6
#: A Levenberg–Marquardt end this close to a bound (unit box), but not at it, is refitted from
#: the bound itself: LM moves in logit coordinates, where a cost that keeps falling towards a bound
#: flattens out before it (Oren–Nayar's σ on Lambertian data, bound 0, ended at u ≈ 3e-6 from
#: interior starts, with a meaningless standard error and no warning). From the bound it stays
#: there when that is lower, and the fit says so (``at_bound``).
NEAR_BOUND_UNIT = 1e-3


def near_bounds(u) -> np.ndarray | None:
    """``u`` with every coordinate within NEAR_BOUND_UNIT of a bound moved onto it; None when
    none is, or each that is lies within AT_BOUND_UNIT already."""
    u = np.asarray(u, dtype=float)
    lo, hi = u < NEAR_BOUND_UNIT, u > 1.0 - NEAR_BOUND_UNIT
    if not ((lo & (u >= AT_BOUND_UNIT)) | (hi & (u <= 1.0 - AT_BOUND_UNIT))).any():
        return None
    return np.where(lo, 0.0, np.where(hi, 1.0, u))


def fit_least_squares(space: FitSpace, data: FitData, loss: str, *, start_native=None,
                      n_starts: int = 8, seed: int = 0,
                      global_maxeval: int | None = None,
                      lm_maxiter: int = LM_MAXITER, progress: bool = False,
                      search: str = DEFAULT_GLOBAL_SEARCH,
                      solver: str = DEFAULT_LOCAL_SOLVER) -> LeastSquaresResult:
    """Global stage (``search``, one of GLOBAL_SEARCHES; ``global_maxeval`` its evaluations,
    None: its default) + multi-start LM + covariance. ``start_native`` (optional) is one more
    start; ``lm_maxiter`` is each LM run's step limit, ``solver`` its implementation (a name
    of fitlab.fitting.solvers.LOCAL_SOLVERS); ``progress`` says what runs (nlopt's
    search with a bar and an estimate of the time left), on stderr."""
    k = kernels(space.static, loss, int(lm_maxiter), solver)
    n_rows = int(data.value.shape[0])
    scan_data = scan_rows(space.static, data)
    scanned_all = scan_data is data
    data = pad_rows(space.static, data)
    problem = problem_of(space, data)
    scan_problem = problem if scanned_all else problem_of(space, pad_rows(space.static,
                                                                          scan_data))
    d = space.ndim
    n_local = 1 + n_starts + (start_native is not None)
    # more rows than START_SUBSET_ABOVE: the starts run on START_ROWS of them, and the best of
    # their ends (with any as good at other parameters) is refined on every row (:func:`_refined`)
    start_data = (scan_rows(space.static, scan_data, START_ROWS)
                  if n_rows > START_SUBSET_ABOVE else scan_data)
    every_row = start_data is scan_data and (scanned_all or n_rows <= START_SUBSET_ABOVE)
    start_problem = problem if every_row else problem_of(space, pad_rows(space.static,
                                                                         start_data))
    with ThreadPoolExecutor(max_workers=1) as pool:
        # The first fit of this shape in the process compiles the local stage meanwhile (XLA
        # compiles outside the GIL, so with two cores the two compilations overlap).
        key = (space.static, loss, int(lm_maxiter), solver, n_local, int(data.value.shape[0]),
               every_row, None if data.weights is None else tuple(data.weights.shape))
        warm = None if key in _compiled_local else pool.submit(
            _compile_local, k, start_problem, n_local, d,
            None if every_row else problem)
        U_glob, glob_info = global_start(search, k, problem, scan_problem,
                                         int(scan_data.value.shape[0]), d, seed, n_starts,
                                         global_maxeval, progress)
        if warm is not None:
            if progress and not warm.done():
                progress_line("  compiling the Levenberg-Marquardt stage for this data shape "
                              "(once per shape; cached on disk)...")
            warm.result()
            _compiled_local.add(key)
    starts_u = list(U_glob)
    if start_native is not None:
        starts_u.append(space.to_unit(np.asarray(start_native, dtype=float)))
    if progress:
        progress_line(f"  Levenberg-Marquardt from {len(starts_u)} starts at once...")
    loc = canonical_runs(space, local_fits(k, start_problem, starts_u))  # one labelling of
    # interchangeable lobes (a sum that repeats a component: fitlab/fitting/exchange.py)
    if not every_row:
        loc = _refined(k, space, problem, loc, lm_maxiter)
        glob_info = dict(glob_info, lm_rows=int(start_data.value.shape[0]))
    runs = lm_runs(loc, lm_maxiter)
    best = min(runs, key=lambda r: r["cost"])
    u_bound = near_bounds(best["u"]) if np.isfinite(best["cost"]) else None
    if u_bound is not None:  # one more start: the best end moved onto the bounds it nears
        again = canonical_runs(space, local_fits(
            k, problem, [u_bound] * (len(starts_u) if every_row else 1)))
        loc = {key: np.concatenate([v, again[key][:1]]) for key, v in loc.items()}
        starts_u.append(u_bound)
        runs = lm_runs(loc, lm_maxiter)
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
    at_bound = names_at_bound(space.names, best["u"])

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
    solver = lm_record(best["stopped"], best["iters"], int(lm_maxiter), algorithm(solver))
    return LeastSquaresResult(theta, cost, r, cov, stderr, noise, dof, at_bound,
                              best["iters"], starts, disagreement, glob_info, solver, J)


def lm_record(stopped: str, iterations: int, max_iterations: int,
              algorithm: str = algorithm(DEFAULT_LOCAL_SOLVER)) -> dict:
    """The parameter file's ``solver`` entry: how the best start's Levenberg–Marquardt run
    ended (data_formats/fit_json.md)."""
    return {"algorithm": algorithm,
            "stopped": stopped, "iterations": int(iterations),
            "max_iterations": int(max_iterations), "xtol": LM_XTOL, "gtol": LM_GTOL}
