"""Many fits at once (``fitlab.fit_many``, ``fitlab fit FILE FILE ...``): N datasets of one
structure fitted in one compiled, vmapped call per chunk.

A *structure* is what the least-squares kernels are compiled for (fitlab/fitting/least_squares):
the model, its options, the free parameters and their transforms, the loss and the padded row
count. Datasets (each channel of each measurement) are grouped by structure; every group is fitted
in chunks of ``chunk`` datasets, each chunk with three batched calls:

1. the global stage, the single fit's default low-discrepancy scan (fitlab.fitting.searches):
   the cost at ``scan`` Halton points of the unit box of every dataset (vmapped over datasets);
   its best point is the first start;
2. Levenberg–Marquardt (jaxopt, the single fit's own solver and kernel) from that point, the
   model's defaults and ``starts`` Halton points, vmapped over starts and datasets;
3. per dataset the best end, its covariance noise² (JᵀJ)⁻¹ from the Jacobian at the optimum
   (native units), the residual noise scale, which parameters sit at a bound, why LM stopped.

Bounds and fixed values (η from each file, the relative scale's reference) are per dataset,
so datasets of one structure may differ in everything but their shapes. The results are plain
arrays (:class:`BatchResult`); fitlab/fitting/many.py turns them into parameter files or a table.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from fitlab._jax import jax
from fitlab.fitting.least_squares import (AT_BOUND_UNIT, LM_MAXITER, FitData, kernels,
                                          lm_stop_reason, pad_to, padded_size, scan_costs)
from fitlab.fitting.losses import has_absolute_noise
from fitlab.fitting.searches import halton, scan_points
from fitlab.fitting.space import FitSpace, z_from_unit

#: Halton points of the global scan, and Levenberg–Marquardt starts besides its best point and
#: the model's defaults.
SCAN = 256
STARTS = 4
#: Datasets per batched call (memory: chunk × (starts + 2) × rows × free Jacobian entries).
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


def structure_of(p: Problem):
    """What must agree for datasets to share one compiled call."""
    w = None if p.data.weights is None else tuple(np.shape(p.data.weights)[1:])
    return (p.space.static, p.loss, padded_size(p.n_rows), w,
            tuple(sorted(np.asarray(v).shape[1:] for v in p.data.consts.values())))


def group(problems: list[Problem]) -> list[list[int]]:
    """Indices of ``problems`` grouped by structure, in first-seen order."""
    out: dict = {}
    for i, p in enumerate(problems):
        if p.space.static.rows_fixed:
            raise ValueError("fit_many: a joint fit over channels (share=) is one problem per "
                             "measurement; fit them with fitlab.fit")
        out.setdefault(structure_of(p), []).append(i)
    return list(out.values())


def _stack(problems: list[Problem], size: int) -> dict:
    """The kernels' ``problem`` argument with a leading dataset axis."""
    per = [{**p.space.arrays(), "data": pad_to(p.data, size)} for p in problems]
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *per)


@functools.lru_cache(maxsize=32)
def _batched(static, loss, maxiter):
    """The single fit's kernels vmapped over datasets: the scan's costs (points shared, problem
    per dataset) and the local stage (starts, weights and problem per dataset)."""
    local = kernels(static, loss, int(maxiter))["local_fn"]
    cost_points = functools.partial(scan_costs, static, loss)  # the single fit's scan
    return {"batch_scan": jax.jit(jax.vmap(cost_points, in_axes=(None, 0))),
            "batch_local": jax.jit(jax.vmap(local, in_axes=(0, 0, 0, 0)))}


def fit_chunk(problems: list[Problem], *, starts: int = STARTS, scan: int = SCAN,
              seed: int = 0, lm_maxiter: int = LM_MAXITER,
              batch: int | None = None) -> BatchResult:
    """Fit ``problems`` (one structure) in three batched calls (module text). ``batch``: pad
    the call to this many datasets (copies of the last, whose results are dropped), so that
    every chunk of a run, the last one too, uses one compilation."""
    n_real = len(problems)
    if batch is not None and batch > n_real:
        problems = list(problems) + [problems[-1]] * (batch - n_real)
    p0 = problems[0]
    static, loss, d = p0.space.static, p0.loss, p0.space.ndim
    size = padded_size(max(p.n_rows for p in problems))
    k = _batched(static, loss, lm_maxiter)
    problem = _stack(problems, size)
    B = len(problems)
    with jax.numpy_dtype_promotion("standard"):  # jaxopt multiplies bool masks with floats
        # 1. global scan (the same low-discrepancy points in every dataset's unit box; the seed
        #    shifts the sequence, as the single fit's seed does its search)
        U_scan = scan_points(scan, d, seed)
        costs = np.asarray(k["batch_scan"](U_scan, problem))
        costs = np.where(np.isfinite(costs), costs, np.inf)
        best = np.argmin(costs, axis=1)
        u_best = U_scan[best]
        # 2. LM from the scan's best, the defaults and `starts` Halton points
        u_default = np.stack([p.space.to_unit(p.start_native) for p in problems])
        extra = np.broadcast_to(halton(starts, d, skip=1 + (int(seed) + 1) * 97), (B, starts, d))
        U0 = np.concatenate([u_best[:, None], u_default[:, None], extra], axis=1)
        U0 = np.clip(U0, 1e-6, 1 - 1e-6)
        Z0 = z_from_unit(U0)
        S = U0.shape[1]
        W = np.ones((B, S, size))
        out = k["batch_local"](Z0, U0, W, problem)
    out = {key: np.asarray(v) for key, v in out.items()}
    cost = np.where(np.isfinite(out["cost"]) & out["end_finite"], out["cost"], np.inf)
    ib = np.argmin(cost, axis=1)
    pick = lambda a: a[np.arange(B), ib]  # noqa: E731
    theta, J, r = pick(out["native"]), pick(out["jacobian"]), pick(out["residuals"])
    n_rows = np.array([p.n_rows for p in problems])
    dof = np.maximum(n_rows - d, 1)
    cost_b = 0.5 * np.einsum("bn,bn->b", r, r)
    noise = np.ones(B) if has_absolute_noise(loss) else np.sqrt(2 * cost_b / dof)
    cov = noise[:, None, None] ** 2 * np.linalg.pinv(np.einsum("bni,bnj->bij", J, J))
    stderr = np.sqrt(np.clip(np.einsum("bii->bi", cov), 0, None))
    u_end = pick(out["u"])
    names = p0.space.names
    at_bound = [tuple(n for n, u in zip(names, row) if u < AT_BOUND_UNIT or u > 1 - AT_BOUND_UNIT)
                for row in u_end]
    iters = pick(out["iters"])
    stopped = [lm_stop_reason(float(c), int(it), bool(ru), int(lm_maxiter))
               for c, it, ru in zip(np.where(np.isfinite(pick(cost)), pick(cost), np.nan),
                                    iters, pick(out["rule_unmet"]))]
    keep = slice(0, n_real)
    return BatchResult([p.key for p in problems[keep]], names, theta[keep], stderr[keep],
                       cov[keep], cost_b[keep], dof[keep], noise[keep], iters[keep],
                       stopped[keep], at_bound[keep],
                       [r[i, :n] for i, n in enumerate(n_rows[keep])], costs.min(axis=1)[keep])


def chunks(n: int, chunk: int) -> list[range]:
    """Consecutive ranges of at most ``chunk`` indices covering range(n)."""
    chunk = max(1, int(chunk))
    return [range(a, min(a + chunk, n)) for a in range(0, n, chunk)]


def n_chunks(sizes: list[int], chunk: int) -> int:
    return sum(math.ceil(s / max(1, int(chunk))) for s in sizes)


__all__ = ["SCAN", "STARTS", "CHUNK", "Problem", "BatchResult", "structure_of",
           "group", "fit_chunk", "chunks", "n_chunks"]
