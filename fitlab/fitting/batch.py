"""Many fits at once (``fitlab.fit_many``, ``fitlab fit FILE FILE ...``): N datasets of one
structure fitted in one compiled, vmapped call per chunk.

A *structure* is what the least-squares kernels are compiled for (fitlab/fitting/least_squares):
the model, its options, the free parameters and their transforms, the loss and the padded row
count. Datasets (each channel of each measurement) are grouped by structure; every group is fitted
in chunks of ``chunk`` datasets, each chunk with a few batched calls:

1. the global stage, the single fit's default low-discrepancy scan (fitlab.fitting.searches):
   the cost at ``scan`` Halton points of the unit box of every dataset (vmapped over datasets);
2. Levenberg–Marquardt from the scan's ``starts`` + 1 best points (the single fit's rule) and
   the model's defaults, vmapped over starts and datasets, with the fixed-budget solver of
   fitlab.fitting.lm_fixed (the single fit's damping and stopping rule; jaxopt's ``while_loop``
   made every lane wait for the chunk's slowest, and evaluated the model three times a step):
   ``STEPS`` steps a call, and the datasets whose best run has not met its stopping rule go on
   from where it ended in further calls of the same compiled kernel, up to ``lm_maxiter``
   steps; on the Walter benchmark (2,048 datasets, 2 vCPUs) 4.7x the jaxopt batch's fits/s
   with the same optima;
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

from fitlab._jax import jax, jnp
from fitlab.fitting.least_squares import (AT_BOUND_UNIT, LM_DAMPING, LM_GTOL, LM_MAXITER,
                                          LM_XTOL, ROW_WEIGHT, FitData,
                                          lm_stop_reason, pad_to, padded_size, residuals_native,
                                          residuals_unit, scan_costs)
from fitlab.fitting.lm_fixed import lm_fixed, value_and_jacobian
from fitlab.fitting.losses import has_absolute_noise
from fitlab.fitting.searches import scan_points
from fitlab.fitting.space import FitSpace, to_native, unit_from_z, z_from_unit

#: Halton points of the global scan, and Levenberg–Marquardt starts besides its best point and
#: the model's defaults.
SCAN = 256
STARTS = 4
#: Levenberg–Marquardt steps per batched call (fitlab.fitting.lm_fixed): every lane runs this
#: many (a lane that met its stopping rule stays put); a dataset whose best run has not met it
#: goes on in further calls, up to lm_maxiter steps in all.
STEPS = 30
#: The ``solver.algorithm`` of a batched fit's parameter file.
BATCH_LM_ALGORITHM = (f"fitlab fixed-budget Levenberg-Marquardt (Madsen-Nielsen stopping rule, "
                      f"{STEPS} steps a call)")
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


def fixed_local(static, loss, steps):
    """The local stage of one dataset with the fixed-budget solver (fitlab.fitting.lm_fixed):
    ``(Z0, U0, W, problem)`` -> the same record per start as the single fit's ``local``."""
    r_and_jac_native = value_and_jacobian(functools.partial(residuals_native, static, loss))

    def r_z(z, problem):
        return residuals_unit(static, loss, unit_from_z(z), problem) * problem[ROW_WEIGHT]

    def one(z0, u0, w, problem):
        problem = {**problem, ROW_WEIGHT: w}
        sol = lm_fixed(r_z, z0, problem, steps=steps, xtol=LM_XTOL, gtol=LM_GTOL,
                       tau=LM_DAMPING)
        z = jnp.where(sol["finite"], sol["z"], z0)
        theta = to_native(static, unit_from_z(z), problem["lo"], problem["hi"])
        r, J = r_and_jac_native(theta, problem)
        r, J = r * w, J * w[:, None]
        return {"z": z, "iters": sol["iters"], "rule_unmet": ~sol["rule_met"],
                "end_finite": sol["finite"], "u": unit_from_z(z), "native": theta,
                "cost": 0.5 * jnp.sum(r * r), "residuals": r, "jacobian": J,
                "start_native": to_native(static, u0, problem["lo"], problem["hi"])}

    def local(Z0, U0, W, problem):
        return jax.vmap(one, in_axes=(0, 0, 0, None))(Z0, U0, W, problem)

    return local


@functools.lru_cache(maxsize=32)
def _batched(static, loss, steps):
    """The kernels vmapped over datasets: the single fit's scan (points shared, problem per
    dataset) and the local stage with the fixed-budget solver, ``steps`` steps a call (starts,
    weights and problem per dataset)."""
    local = fixed_local(static, loss, int(steps))
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
    steps = min(int(lm_maxiter), STEPS)
    k = _batched(static, loss, steps)
    problem = _stack(problems, size)
    B = len(problems)
    # 1. global scan (the same low-discrepancy points in every dataset's unit box; the seed
    #    shifts the sequence, as the single fit's seed does its search)
    U_scan = scan_points(scan, d, seed)
    costs = np.asarray(k["batch_scan"](U_scan, problem))
    costs = np.where(np.isfinite(costs), costs, np.inf)
    # 2. LM from the scan's `starts` + 1 best points (the single fit's rule) and the defaults
    order = np.argsort(costs, axis=1, kind="stable")[:, :starts + 1]
    u_default = np.stack([p.space.to_unit(p.start_native) for p in problems])
    U0 = np.clip(np.concatenate([U_scan[order], u_default[:, None]], axis=1), 1e-6, 1 - 1e-6)
    S = U0.shape[1]
    W = np.ones((B, S, size))
    out = {key: np.array(v) for key, v in k["batch_local"](z_from_unit(U0), U0, W,
                                                          problem).items()}  # writable
    cost = np.where(np.isfinite(out["cost"]) & out["end_finite"], out["cost"], np.inf)
    ib = np.argmin(cost, axis=1)
    # 3. the datasets whose best run has not met its stopping rule go on from where it ended,
    #    `steps` more at a time, until it does or at least lm_maxiter steps are spent (the same
    #    compiled call: those datasets packed into a chunk of the same size)
    while True:
        at = np.arange(B), ib
        todo = np.flatnonzero(out["rule_unmet"][at] & out["end_finite"][at]
                              & (out["iters"][at] < lm_maxiter))
        if todo.size == 0:
            break
        for part in (todo[a:a + B] for a in range(0, todo.size, B)):
            fill = np.concatenate([part, np.full(B - part.size, part[0])])
            z = np.broadcast_to(out["z"][fill, ib[fill]][:, None], (B, S, d))
            more = {key: np.asarray(v) for key, v in k["batch_local"](
                z, out["u"][fill, ib[fill]][:, None].repeat(S, 1), W,
                _stack([problems[i] for i in fill], size)).items()}
            more["iters"] = more["iters"] + out["iters"][fill, ib[fill]][:, None]
            more["start_native"] = np.broadcast_to(
                out["start_native"][fill, ib[fill]][:, None], more["start_native"].shape)
            for key in out:
                out[key][part, ib[part]] = more[key][:part.size, 0]
    cost = np.where(np.isfinite(out["cost"]) & out["end_finite"], out["cost"], np.inf)
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


__all__ = ["SCAN", "STARTS", "STEPS", "BATCH_LM_ALGORITHM", "CHUNK", "Problem", "BatchResult", "structure_of",
           "group", "fit_chunk", "chunks", "n_chunks"]
