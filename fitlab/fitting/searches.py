"""The global stage of a fit: where Levenberg–Marquardt starts, by name
(``fitlab fit --global-search``, ``fitlab.fit(..., global_search=)``).

- ``scan`` (the default): the cost at 256 Halton points of the unit box of the bounds per free
  parameter (and one more), in one compiled call (fitlab.fitting.least_squares.scan_costs; the
  batched fits, fitlab.fitting.batch, run the same scan vmapped over datasets). Levenberg–
  Marquardt then runs from its ``starts + 1`` best points at once. It costs one model
  evaluation per point and row, on at most SCAN_ROWS rows.
- ``mlsl``: nlopt's multi-level single linkage over a low-discrepancy sequence with L-BFGS
  local searches, one evaluation at a time from Python; Levenberg–Marquardt then runs from its
  best point and ``starts`` Halton points. Many times slower: for a cost whose basins are
  narrower than the scan's points.

Measured on a joint RGB fit (Lambert + rough conductor, α shared: 7 free coordinates, a narrow
specular basin; tests/fitting/test_joint_fit.py): LM from the best points of a 512-point scan
all ended in broad-lobe local minima (cost 18,500 and more against 148 at the truth); from
the best of 1,024 points one of ten starts reached the truth, from 2,048 points two, from
4,096 three. Hence 256 points per coordinate, and the best points rather than the single best
and blind Halton starts.

The names, descriptions and the Halton sequence need neither JAX nor nlopt (``fitlab fit
--help``); nlopt is imported when ``mlsl`` runs.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab.fitting.progress import bar as progress_bar, line as progress_line
from fitlab.registry import Registry

#: The scan's points: SCAN_PER_DIMENSION per free parameter and one more (module text), at most
#: SCAN_MAX_POINTS.
SCAN_PER_DIMENSION = 256
SCAN_MAX_POINTS = 4096
#: The scan evaluates the cost on at most this many rows (evenly spread over the data; a fit of
#: more rows scans a subset: the scan only chooses a start, and LM then fits every row) ...
SCAN_ROWS = 4096
#: The Levenberg–Marquardt starts of a fit of more than START_SUBSET_ABOVE rows run on
#: START_ROWS rows, evenly spread (they find the basins; the best end is refined on every row:
#: fitlab.fitting.least_squares ``_refined``). Below it every start fits every row: on a few
#: thousand rows a subset's basins may differ from the data's (a start that reaches the optimum
#: on every row can stop elsewhere on a third of them), and every row costs little there ...
START_ROWS = 1024
START_SUBSET_ABOVE = 8192
#: ... and the scan on at most this many point-row pairs at once (memory: a block of points at
#: a time).
SCAN_BLOCK = 1 << 20


def scan_size(ndim: int) -> int:
    """How many points the scan evaluates for ``ndim`` free parameters."""
    return int(min(SCAN_PER_DIMENSION * (ndim + 1), SCAN_MAX_POINTS))


def scan_points(n: int, ndim: int, seed: int) -> np.ndarray:
    """The scan's points: n Halton points of the unit box; the seed shifts the sequence (seeds
    scan disjoint stretches of it)."""
    return halton(n, ndim, skip=1 + int(seed) * n)


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


def scan_search(ndim, costs_at, problem, seed: int, n_points: int, rows: int, keep: int = 1):
    """The global stage by default: the cost at ``n_points`` Halton points (:func:`scan_points`)
    in one call of ``costs_at(U, problem)`` (``problem`` has ``rows`` rows); returns its
    ``keep`` best points (keep, ndim), best first (points of non-finite cost last), and the
    record."""
    U = scan_points(n_points, ndim, seed)
    costs = np.asarray(costs_at(U, problem), dtype=float)
    finite = np.isfinite(costs)
    order = np.argsort(np.where(finite, costs, np.inf), kind="stable")[:keep]
    best = int(order[0]) if finite.any() else None
    return (np.full((1, ndim), 0.5) if best is None else U[order]), {
        "algorithm": f"Halton scan of the unit box ({n_points} points, one batched call, "
                     f"{rows} rows)",
        "evaluations": int(n_points), "non_finite": int(np.sum(~finite)),
        "status": "scanned" if best is not None else "no finite cost; the box's centre kept",
        "best_cost": None if best is None else float(costs[best])}


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

    import nlopt  # on first use (the scan, the default, needs no nlopt)

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


class GlobalStage(NamedTuple):
    """One way to choose the Levenberg–Marquardt starts (``--global-search``)."""

    description: str
    #: (kernels, problem, scan_problem, scan_rows, ndim, seed, starts, evaluations or None,
    #: progress) -> (Levenberg–Marquardt starts (starts + 1, ndim) in the unit box, record)
    run: Callable


def _scan_stage(k, problem, scan_problem, scan_rows, ndim, seed, starts, evaluations,
                progress):
    n = evaluations or scan_size(ndim)
    if progress:
        progress_line(f"  global scan: the cost at {n} points in one call...")
    best, record = scan_search(ndim, k["scan"], scan_problem, seed, n, scan_rows, starts + 1)
    if len(best) < starts + 1:  # fewer points than starts, or nothing finite: Halton fills up
        best = np.concatenate([best, halton(starts + 1 - len(best), ndim)])
    return best, record


def _mlsl_stage(k, problem, scan_problem, scan_rows, ndim, seed, starts, evaluations,
                progress):
    maxeval = evaluations or 150 * (ndim + 1)
    bar = progress_bar(progress, maxeval, "  global search", "eval")
    try:
        u, record = global_search(ndim, k["value_and_grad"], problem, seed, maxeval,
                                  value=k["value"], on_eval=None if bar is None else bar.update)
    finally:
        if bar is not None:
            bar.close()
    return np.concatenate([u[None, :], halton(starts, ndim)]), record


#: The global stages by name; the first is the default.
GLOBAL_SEARCHES: Registry[GlobalStage] = Registry("global search", {
    "scan": GlobalStage(f"the cost at {SCAN_PER_DIMENSION} Halton points of the bounds' box per "
                        f"free parameter and one more (at most {SCAN_MAX_POINTS}) in one "
                        f"compiled call, on at most {SCAN_ROWS} rows; Levenberg-Marquardt starts "
                        "from its best points (default)", _scan_stage),
    "mlsl": GlobalStage("nlopt multi-level single linkage (G_MLSL_LDS) with L-BFGS local "
                        "searches, 150 evaluations per free parameter and one more, one at a "
                        "time; Levenberg-Marquardt starts from its best point and Halton "
                        "points: slower, for basins narrower than the scan's points",
                        _mlsl_stage),
})
DEFAULT_GLOBAL_SEARCH = GLOBAL_SEARCHES.names()[0]


def global_start(search, k, problem, scan_problem, scan_rows, ndim, seed, starts,
                 evaluations=None, progress=False):
    """The Levenberg–Marquardt starts, (starts + 1, ndim) in the unit box, and the record of the
    global stage ``search`` (a name of :data:`GLOBAL_SEARCHES`). ``k``: the fit's kernels
    (fitlab.fitting.least_squares.kernels); ``scan_problem``: the kernels' argument with the
    ``scan_rows`` rows the scan evaluates."""
    return GLOBAL_SEARCHES[search].run(k, problem, scan_problem, scan_rows, ndim, seed, starts,
                                       evaluations, progress)


def add_global_search_option(parser) -> None:
    """``--global-search NAME`` on a command that fits (fit, compare)."""
    parser.add_argument("--global-search", choices=GLOBAL_SEARCHES.names(),
                        default=DEFAULT_GLOBAL_SEARCH,
                        help="where Levenberg-Marquardt starts: " + "; ".join(
                            f"{k}: {v.description}" for k, v in GLOBAL_SEARCHES.items()))
