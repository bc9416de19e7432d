"""Many fits at once (``fitlab.fit_many``, ``fitlab fit FILE FILE ...``): N datasets of one
structure fitted in one compiled, vmapped call per chunk.

A *structure* is what the least-squares kernels are compiled for (fitlab/fitting/least_squares):
the model, its options, the free parameters and their transforms, the loss and the padded row
count. Datasets (each channel of each measurement) are grouped by structure; every group is fitted
in chunks of ``chunk`` datasets, each chunk with a few batched calls:

1. the global stage, the single fit's default low-discrepancy scan (fitlab.fitting.searches):
   the cost at ``scan`` Halton points of the unit box of every dataset (vmapped over datasets;
   where every dataset of the chunk has the same directions, bounds and fixed values and no
   free scale, as the texels of a map fit, the model's values at the points once per chunk
   and each dataset's cost from them: :func:`shared_scan_costs`, the same costs);
2. Levenberg–Marquardt from the scan's best point, and only where that end is suspect
   (:func:`_suspect`: not finite, at a bound, out of steps, or disagreeing with the data) from
   the model's defaults and the scan's next ``starts`` best points too; the best end is kept.
   The solver is fitlab.fitting.lm's ``lm_queue`` (the single fit's damping and
   stopping rule, one forward-mode pass a step, each run step for step the single fit's) on
   ``LANES`` *lanes* at once: a lane whose run meets its stopping rule or spends
   ``lm_maxiter`` steps writes its end and takes the next start (as the simulator's walk
   regenerates paths), so a chunk costs the sum of its runs' steps, not a fixed budget per
   run or the slowest run's count. Measured (benchmarks/fit_many.py, 10,000 datasets, 2
   vCPUs): benchmarks/README.md, "Batched fits";
3. per dataset the best end, its covariance noise² (JᵀJ)⁻¹ from the Jacobian at the optimum
   (native units), the residual noise scale, which parameters sit at a bound, why LM stopped.

Bounds and fixed values (η from each file, the relative scale's reference) are per dataset,
so datasets of one structure may differ in everything but their shapes. The results are plain
arrays (:class:`BatchResult`); fitlab/fitting/many.py turns them into parameter files or a table.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import math
from typing import NamedTuple

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.fitting.least_squares import (LM_DAMPING, LM_GTOL, LM_MAXITER, LM_XTOL, ROW_MASK,
                                          ROW_WEIGHT, FitData, at_bound_mask, lm_end,
                                          lm_stop_reasons, names_at_bound_many, pad_to, padded_size,
                                          predict_data, residuals_z, scan_block, scan_costs)
from fitlab.fitting.lm import lm_queue
from fitlab.fitting.losses import has_absolute_noise, is_weighted, residuals
from fitlab.fitting.searches import scan_points
from fitlab.fitting.space import SCALE, FitSpace, to_native, to_unit, z_from_unit

#: Halton points of the global scan, and Levenberg–Marquardt starts besides its best point and
#: the model's defaults.
SCAN = 256
STARTS = 4
#: Lanes of the batched Levenberg–Marquardt call (fitlab.fitting.lm ``lm_queue``): a
#: lane whose run ends takes the next start.
LANES = 256
#: A first run's end is suspect (more starts are run) above this reduced chi-square (a noise
#: model: chi2 loss) ...
SUSPECT_REDUCED_CHI2 = 2.0
#: ... or, with no noise model, above this multiple of the chunk's median reduced cost.
SUSPECT_COST_RATIO = 4.0
#: The ``solver.algorithm`` of a batched fit's parameter file.
BATCH_LM_ALGORITHM = (f"fitlab batched Levenberg-Marquardt (Madsen-Nielsen stopping rule, "
                      f"{LANES} lanes refilled as runs end)")
#: Datasets per batched call (memory: chunk × 2 starts × rows × free Jacobian entries).
CHUNK = 1024


class Problem(NamedTuple):
    """One dataset's least-squares problem: its structure, data (padded), the model's default
    start (native units) and where it came from."""

    space: FitSpace
    data: FitData
    start_native: np.ndarray
    loss: str
    n_rows: int
    key: object  # the caller's label of the dataset (index, channel)


class BatchResult(NamedTuple):
    """Per dataset of a group: best-fit values and uncertainties (native units), how LM ended."""

    keys: list
    names: tuple[str, ...]
    native: np.ndarray  # (N, d)
    stderr: np.ndarray  # (N, d)
    covariance: np.ndarray  # (N, d, d)
    cost: np.ndarray  # (N,) ½ Σ r² of the fitted rows
    dof: np.ndarray  # (N,)
    noise_scale: np.ndarray  # (N,)
    iterations: np.ndarray  # (N,)
    stopped: list  # per dataset, one of least_squares.LM_STOPPED
    at_bound: list  # per dataset, the names of the parameters at a bound
    residuals: list  # per dataset, the residuals of its rows
    scan_cost: np.ndarray  # (N,) best cost of the global scan
    lm_starts: np.ndarray  # (N,) Levenberg–Marquardt starts run


def structure_of(p: Problem):
    """What must agree for datasets to share one compiled call."""
    w = None if p.data.weights is None else tuple(np.shape(p.data.weights)[1:])
    return (p.space.static, p.loss, padded_size(p.n_rows), w,
            tuple(sorted(np.asarray(v).shape[1:] for v in p.data.consts.values())))


def group(problems: list[Problem], *, joint: bool = False) -> list[list[int]]:
    """Indices of ``problems`` grouped by structure, in first-seen order. ``joint``: joint
    problems over channels (fitlab.fitting.joint, ``static.rows_fixed``) are accepted; their
    structure holds their rows per channel, so a group's are the same and are not padded
    (``fitlab fit-maps --share``: every texel on the same images, a missing reading a row of
    ROW_MASK 0)."""
    out: dict = {}
    for i, p in enumerate(problems):
        if p.space.static.rows_fixed and not joint:
            raise ValueError("fit_many: a joint fit over channels (share=) is one problem per "
                             "measurement; fit them with fitlab.fit")
        out.setdefault(structure_of(p), []).append(i)
    return list(out.values())


def _stack(problems: list[Problem], size: int) -> dict:
    """The kernels' ``problem`` argument with a leading dataset axis, the rows padded to
    ``size`` (least_squares.pad_to). Problems that share their direction arrays (datasets of
    one instrument, the texels of a map: fitlab.fitting.many and maps) keep one copy of those,
    broadcast; problems that share their space, one copy of its bounds and fixed values."""
    p0 = problems[0]
    d0 = p0.data
    every = lambda x: np.broadcast_to(np.asarray(x), (len(problems),) + np.shape(x))  # noqa: E731
    datas = [p.data for p in problems]
    if all(p.space is p0.space for p in problems):
        arrays = jax.tree.map(every, p0.space.arrays())
    else:
        arrays = {"lo": np.array([[q.lower for q in p.space.free] for p in problems]),
                  "hi": np.array([[q.upper for q in p.space.free] for p in problems]),
                  "fixed": {k: np.array([np.float64(p.space.fixed[k]) for p in problems])
                            for k in p0.space.fixed}}
    if all(d.wi is d0.wi and d.wo is d0.wo and d.weights is d0.weights for d in datas):
        first = pad_to(d0, size)
        own = _stacked_rows(datas, size, directions=False)
        data = own._replace(wi=every(first.wi), wo=every(first.wo),
                            weights=None if first.weights is None else every(first.weights))
        return {**arrays, "data": data}
    return {**arrays, "data": _stacked_rows(datas, size)}


def _stacked_rows(datas: list[FitData], size: int, directions: bool = True) -> FitData:
    """``datas`` stacked on a new axis 0 and padded to ``size`` rows (a row mask of ones for
    those without one); of different row counts, each padded first. ``directions``: stack
    ``wi``, ``wo`` and ``weights`` too (else None)."""
    if len({int(np.shape(d.value)[0]) for d in datas}) > 1:
        datas = [pad_to(d, size) for d in datas]

    def stack(get):
        return np.stack([np.asarray(get(d)) for d in datas])

    keys = set().union(*(d.consts.keys() for d in datas))
    consts = {k: stack(lambda d, k=k: d.consts[k]) for k in keys if k != ROW_MASK}
    if ROW_MASK in keys:
        consts[ROW_MASK] = stack(lambda d: d.consts.get(ROW_MASK, np.ones(np.shape(d.value)[0])))
    d0 = datas[0]
    stacked = FitData(stack(lambda d: d.wi) if directions else None,
                      stack(lambda d: d.wo) if directions else None,
                      stack(lambda d: d.value), consts,
                      stack(lambda d: d.weights) if directions and d0.weights is not None
                      else None)
    return pad_to(stacked, size, axis=1)


def shared_scan_costs(static, loss: str, U, problem):
    """The scan's costs (datasets, points) of a chunk whose datasets share their directions,
    aperture weights, bounds and fixed values (:func:`shares_scan`), so that the model's
    predictions at the points are the same in every dataset: computed once per point, then each
    dataset's cost there from its own values and loss constants (fitlab.fitting.losses
    ``residuals``, times its ROW_MASK), as the single fit's scan (least_squares.scan_costs)
    computes it. A free ``scale`` (relative data) has bounds of its own per dataset: the
    predictions are computed with scale 1 and multiplied by each dataset's scale at the point
    (the product the single fit's prediction forms). A loss whose residual is (m - v) w
    (``Loss.weighted``) gives every cost at once as a quadratic form in the predictions m,
    ½ (s² Σ w² m² - 2 s Σ w² v m + Σ w² v²), by matrix products over the rows (the same costs
    to rounding: tested); another, a block of points at a time (at most SCAN_BLOCK point-row
    pairs of residuals over the chunk)."""
    d = problem["data"]
    B, rows = (int(n) for n in d.value.shape[:2])
    first = FitData(d.wi[0], d.wo[0], d.value[0], {},
                    None if d.weights is None else d.weights[0])
    lo, hi = problem["lo"], problem["hi"]
    fixed = jax.tree.map(lambda x: x[0], problem["fixed"])
    k = static.names.index(SCALE) if SCALE in static.names else None

    def unscaled(u):  # the prediction at u, with scale 1 if the scale is free
        theta = to_native(static, u, lo[0], hi[0])
        return predict_data(static, theta if k is None else theta.at[k].set(1.0), fixed, first)

    def scales(u):  # (B,) each dataset's scale at u
        return to_native(static, jnp.broadcast_to(u, lo.shape), lo, hi)[:, k]

    if is_weighted(loss):
        w = d.consts["w"] * d.consts.get(ROW_MASK, 1.0)
        w2 = w * w
        M = jax.lax.map(unscaled, U, batch_size=scan_block(int(U.shape[0]), rows, static.model))
        quad = w2 @ (M * M).T  # (B, P)
        cross = (w2 * d.value) @ M.T
        const = jnp.sum(w2 * d.value * d.value, axis=1)[:, None]
        if k is not None:
            s = jax.vmap(scales, out_axes=1)(U)  # (B, P)
            quad, cross = s * s * quad, s * cross
        return jnp.maximum(0.5 * (quad - 2.0 * cross + const), 0.0)

    def at(u):
        f = unscaled(u)
        m = jnp.broadcast_to(f, (B, rows)) if k is None else scales(u)[:, None] * f[None, :]
        r = jax.vmap(lambda mb, v, c: residuals(loss, mb, v, c))(m, d.value, d.consts)
        if ROW_MASK in d.consts:
            r = r * d.consts[ROW_MASK]
        return 0.5 * jnp.sum(r * r, axis=-1)

    return jax.lax.map(at, U, batch_size=scan_block(int(U.shape[0]), B * rows, static.model)).T


def shares_scan(static, stacked: dict) -> bool:
    """Whether every dataset of a chunk's stacked problems has the first one's directions,
    aperture weights, bounds (but a free ``scale``'s) and fixed values: its predictions at the
    scan's points are the first's (times its own scale)."""
    d = stacked["data"]
    keep = np.array([n != SCALE for n in static.names])
    same = lambda x: x is None or bool(np.all(np.asarray(x) == np.asarray(x)[:1]))  # noqa: E731
    return all(same(x) for x in (d.wi, d.wo, d.weights, stacked["lo"][:, keep],
                                 stacked["hi"][:, keep], *stacked["fixed"].values()))


@functools.lru_cache(maxsize=32)
def _batched(static, loss, maxiter):
    """The kernels: the single fit's scan vmapped over datasets (points shared, problem per
    dataset), the shared scan (:func:`shared_scan_costs`), Levenberg–Marquardt from a chunk's
    starts on ``LANES`` lanes refilled as runs end (fitlab.fitting.lm ``lm_queue``,
    ``maxiter`` steps a run at most), and the runs' ends (least_squares ``lm_end``), ``LANES``
    at a time."""
    residual = functools.partial(residuals_z, static, loss)
    end = lm_end(static, loss)
    cost_points = functools.partial(scan_costs, static, loss)  # the single fit's scan

    def queue(Z0, which, n, problems, directions):
        # directions: (wi, wo, weights) of every dataset alike, passed once (a lane then
        # gathers its own values and constants only), or None (each dataset's in problems)
        problems = {**problems, ROW_WEIGHT: jnp.ones(problems["data"].value.shape[:2])}
        own = residual
        if directions is not None:
            def own(z, args):
                d = args["data"]._replace(wi=directions[0], wo=directions[1],
                                          weights=directions[2])
                return residual(z, {**args, "data": d})
        return lm_queue(own, Z0, problems, which, n, lanes=LANES, maxiter=int(maxiter),
                        xtol=LM_XTOL, gtol=LM_GTOL, tau=LM_DAMPING)

    def ends(z, iters, rule_unmet, z0, u0, problem):
        w = jnp.ones(problem["data"].value.shape[:1])
        return end(z, iters, rule_unmet, z0, u0, w, {**problem, ROW_WEIGHT: w})

    # (shared out over the CPU's cores with fitting/cores.py, the lanes gave no measurable
    # gain: fit-maps' 256 x 256 benchmark warm 6.87 s against 6.91 s on one device)
    return {"batch_scan": jax.jit(jax.vmap(cost_points, in_axes=(None, 0))),
            "shared_scan": jax.jit(functools.partial(shared_scan_costs, static, loss)),
            "queue": jax.jit(queue), "ends": jax.jit(jax.vmap(ends))}


def _run_starts(k, stacked, which, u0) -> dict:
    """Levenberg–Marquardt from ``u0`` ((len(which), d) in the unit box) on the datasets
    ``which`` of the chunk's stacked problems ``stacked``: the runs in calls of as many starts as the chunk has datasets (one
    compiled kernel, whatever the count: the unused slots are not run), their ends in calls of
    ``LANES``."""
    B = int(np.shape(stacked["data"].value)[0])
    z0 = z_from_unit(u0)
    d = stacked["data"]
    directions, per = None, stacked
    if all(x is None or _alike(x) for x in (d.wi, d.wo, d.weights)):  # one copy, not B
        directions = tuple(None if x is None else x[0] for x in (d.wi, d.wo, d.weights))
        per = {**stacked, "data": d._replace(wi=None, wo=None, weights=None)}
    parts = []
    for a in range(0, len(which), B):
        part = np.arange(a, min(a + B, len(which)))
        fill = np.concatenate([part, np.full(B - part.size, part[0])])
        sol = k["queue"](z0[fill], which[fill], part.size, per, directions)
        sol = {key: np.asarray(v)[:part.size] for key, v in sol.items()}
        for c in range(0, part.size, LANES):
            lane = np.arange(c, min(c + LANES, part.size))
            pad = np.concatenate([lane, np.full(LANES - lane.size, lane[0])])
            got = k["ends"](sol["z"][pad], sol["iters"][pad], ~sol["rule_met"][pad],
                            z0[part[pad]], u0[part[pad]],
                            jax.tree.map(lambda x: x[which[part[pad]]], stacked))
            parts.append({key: np.asarray(v)[:lane.size] for key, v in got.items()})
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def _alike(x) -> bool:
    """Whether a stacked array holds one array for every dataset (a broadcast view of it:
    :func:`_stack` makes these of the directions the datasets share)."""
    return isinstance(x, np.ndarray) and x.ndim > 0 and x.strides[0] == 0


def _suspect(run: dict, n_rows: np.ndarray, d: int, loss: str) -> np.ndarray:
    """Per dataset: its first run's end is not trusted alone, so more starts are run: it is not
    finite, sits at a bound, ran out of steps, or disagrees with the data: with a noise model
    (chi2) a reduced cost above :data:`SUSPECT_REDUCED_CHI2`, else a reduced cost above
    :data:`SUSPECT_COST_RATIO` × the chunk's median (the noise is unknown, but datasets of one
    structure fitted by the model share its typical misfit)."""
    cost = np.where(np.isfinite(run["cost"]) & run["end_finite"], run["cost"], np.inf)
    reduced = 2.0 * cost / np.maximum(n_rows - d, 1)
    if has_absolute_noise(loss):
        poor = reduced > SUSPECT_REDUCED_CHI2
    else:
        finite = reduced[np.isfinite(reduced)]
        typical = np.median(finite) if finite.size else np.inf
        poor = reduced > SUSPECT_COST_RATIO * typical
    return ~np.isfinite(cost) | poor | np.any(at_bound_mask(run["u"]), axis=1) \
        | run["rule_unmet"]


def smallest(costs: np.ndarray, k: int) -> np.ndarray:
    """Per row of ``costs`` (datasets, points), the indices of its ``k`` smallest in ascending
    order, ties in index order: ``np.argsort(costs, axis=1, kind="stable")[:, :k]``, without
    sorting whole rows (a row whose k-th smallest value is tied with a value left out is
    sorted whole, so the ties fall as the stable sort has them)."""
    n = costs.shape[1]
    if k >= n:
        return np.argsort(costs, axis=1, kind="stable")[:, :k]
    part = np.argpartition(costs, k - 1, axis=1)[:, :k]
    vals = np.take_along_axis(costs, part, axis=1)
    out = np.take_along_axis(part, np.lexsort((part, vals), axis=1), axis=1)
    tied = np.sum(costs <= vals.max(axis=1, keepdims=True), axis=1) > k
    if tied.any():
        out[tied] = np.argsort(costs[tied], axis=1, kind="stable")[:, :k]
    return out


def fit_chunk(problems: list[Problem], *, starts: int = STARTS, scan: int = SCAN,
              seed: int = 0, lm_maxiter: int = LM_MAXITER,
              batch: int | None = None) -> BatchResult:
    """Fit ``problems`` (one structure) in a few batched calls (module text). ``batch``: pad
    the call to this many datasets (copies of the last, whose results are dropped), so that
    every chunk of a run, the last one too, uses one compilation."""
    n_real = len(problems)
    if batch is not None and batch > n_real:
        problems = list(problems) + [problems[-1]] * (batch - n_real)
    p0 = problems[0]
    static, loss, d = p0.space.static, p0.loss, p0.space.ndim
    # a joint group (rows_fixed): the rows as given, the same in every problem of the group
    # (rows left out carry ROW_MASK 0; n_rows counts the others, for the degrees of freedom)
    size = (int(np.shape(p0.data.value)[0]) if static.rows_fixed
            else padded_size(max(p.n_rows for p in problems)))
    k = _batched(static, loss, int(lm_maxiter))
    problem = _stack(problems, size)
    B = len(problems)
    n_rows = np.array([p.n_rows for p in problems])
    # 1. global scan (the same low-discrepancy points in every dataset's unit box; the seed
    #    shifts the sequence, as the single fit's seed does its search)
    #    (a chunk on one set of directions: the model's predictions once per point)
    U_scan = scan_points(scan, d, seed)
    scan_kernel = k["shared_scan"] if shares_scan(static, problem) else k["batch_scan"]
    costs = np.asarray(scan_kernel(U_scan, problem))
    costs = np.where(np.isfinite(costs), costs, np.inf)
    # 2. LM from the scan's best point; where that end is suspect (:func:`_suspect`), from the
    #    model's defaults and the scan's next `starts` best points too
    order = smallest(costs, starts + 1)
    u_default = to_unit(static, np.stack([p.start_native for p in problems]), problem["lo"],
                        problem["hi"])
    lanes = np.concatenate([U_scan[order[:, :1]], u_default[:, None],
                            U_scan[order[:, 1:]]], axis=1)
    lanes = np.clip(lanes, 1e-6, 1 - 1e-6)
    run = functools.partial(_run_starts, k, problem)
    every = np.arange(B)
    first = run(every, lanes[:, 0])
    # every run's results by (lane, dataset): lane 0 written now, a later lane only where it
    # runs (its cost is inf until then, so it is never picked), so that the Jacobians and
    # residuals of lanes that never run are never written (np.empty: their pages stay
    # untouched)
    out = {}
    for key, v in first.items():
        out[key] = np.empty((lanes.shape[1],) + v.shape, v.dtype)
        out[key][0] = v
    out["cost"][1:] = np.inf
    out["end_finite"][1:] = False
    n_lanes = np.ones(B, dtype=int)
    todo = np.flatnonzero(_suspect({key: v[0] for key, v in out.items()}, n_rows, d, loss))
    if todo.size and lanes.shape[1] > 1:
        more_idx = np.repeat(todo, lanes.shape[1] - 1)
        more_lane = np.tile(np.arange(1, lanes.shape[1]), todo.size)
        more = run(more_idx, lanes[more_idx, more_lane])
        for key in out:
            out[key][more_lane, more_idx] = more[key]
        n_lanes[todo] = lanes.shape[1]
    cost = np.where(np.isfinite(out["cost"]) & out["end_finite"], out["cost"], np.inf)
    ib = np.argmin(cost, axis=0)
    # 3. per dataset its best run's end: covariance, noise scale, bounds, why it stopped
    pick = lambda a: a[ib, np.arange(B)]  # noqa: E731
    theta, J, r = pick(out["native"]), pick(out["jacobian"]), pick(out["residuals"])
    dof = np.maximum(n_rows - d, 1)
    cost_b = 0.5 * np.einsum("bn,bn->b", r, r)
    noise = np.ones(B) if has_absolute_noise(loss) else np.sqrt(2 * cost_b / dof)
    cov = noise[:, None, None] ** 2 * np.linalg.pinv(np.einsum("bni,bnj->bij", J, J))
    stderr = np.sqrt(np.clip(np.einsum("bii->bi", cov), 0, None))
    u_end = pick(out["u"])
    names = p0.space.names
    at_bound = names_at_bound_many(names, u_end)
    iters = pick(out["iters"])
    stopped = lm_stop_reasons(pick(cost), iters, pick(out["rule_unmet"]), int(lm_maxiter))
    keep = slice(0, n_real)
    return BatchResult([p.key for p in problems[keep]], names, theta[keep], stderr[keep],
                       cov[keep], cost_b[keep], dof[keep], noise[keep], iters[keep],
                       stopped[keep], at_bound[keep],
                       [r[i, :n] for i, n in enumerate(n_rows[keep])], costs.min(axis=1)[keep],
                       n_lanes[keep])


@contextlib.contextmanager
def paused_gc():
    """Python's cyclic garbage collector paused while a batched fit makes its per-dataset
    records (a Problem, its data and constants, a result row: tens of thousands of small
    objects, none in a cycle), as it was before on leaving. Each collection walks every live
    object; measured on 10,000 datasets (benchmarks/fit_many.py, conductor) they cost 0.13 s
    of 0.67 s."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def chunks(n: int, chunk: int) -> list[range]:
    """Consecutive ranges of at most ``chunk`` indices covering range(n)."""
    chunk = max(1, int(chunk))
    return [range(a, min(a + chunk, n)) for a in range(0, n, chunk)]


def n_chunks(sizes: list[int], chunk: int) -> int:
    return sum(math.ceil(s / max(1, int(chunk))) for s in sizes)


__all__ = ["SCAN", "STARTS", "LANES", "BATCH_LM_ALGORITHM", "CHUNK", "Problem", "BatchResult", "structure_of",
           "group", "fit_chunk", "chunks", "n_chunks", "shared_scan_costs", "shares_scan"]
