"""The batched Levenberg–Marquardt step alone (issue 35 item 1: "Optimistix's
LevenbergMarquardt under vmap with throw=False, or a short own one where it measures faster;
say which and why"): fitlab's batched solver (fitlab/fitting/lm.py ``lm_queue``: lanes
refilled as runs end, fitlab.fitting.batch's ``queue`` kernel) against
``optimistix.least_squares`` with ``optimistix.LevenbergMarquardt`` (rtol = atol = 1e-10,
max_steps 200, throw=False) vmapped over the 2,048 datasets, from the same starts (each dataset's best point of fitlab's 256-point scan), on the same residuals
(fitlab's, in logit coordinates of the unit box), in one run. Datasets: benchmarks/fit_many.py's
(``--kind walter|conductor``). Printed: compile + first run, warm (best of 3), lanes per second,
steps taken (median, max), and the largest difference between the two optima.

    pip install -e '.[bench]'   # optimistix
    python benchmarks/batched_lm.py [--kind walter|conductor] [--n 2048]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import fit_many as FM  # noqa: E402
from _walter_fit import machine, machine_line  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kind", choices=("walter", "conductor"), default="walter")
    ap.add_argument("--n", type=int, default=2048)
    args = ap.parse_args(argv)
    try:
        import optimistix as optx
    except ImportError:
        raise SystemExit("this benchmark compares with Optimistix: pip install -e '.[bench]'")
    import jax

    from fitlab.fitting import batch, many
    from fitlab.fitting.least_squares import (LM_DAMPING, LM_GTOL, LM_XTOL, ROW_WEIGHT,
                                              padded_size, residuals_unit)
    from fitlab.fitting.request import FitRequest
    from fitlab.fitting.searches import scan_points
    from fitlab.fitting.space import unit_from_z, z_from_unit

    if args.kind == "walter":
        ms, _, _ = FM.datasets(args.n)
        req = FitRequest("rough_dielectric")
    else:
        ms, _ = FM.conductor_datasets(args.n)
        req = FitRequest(FM.CONDUCTOR, fix=FM.CONDUCTOR_FIXED)
    problems = many._problems(ms, req)[0]
    p0 = problems[0]
    static, loss, d = p0.space.static, p0.loss, p0.space.ndim
    size = padded_size(max(p.n_rows for p in problems))
    stacked = batch._stack(problems, size)
    k = batch._batched(static, loss, batch.LM_MAXITER)
    U = scan_points(batch.SCAN, d, 0)
    costs = np.asarray(k["batch_scan"](U, stacked))
    Z0 = z_from_unit(np.clip(U[np.argmin(costs, axis=1)], 1e-6, 1 - 1e-6))
    W = np.ones((len(problems), size))

    def r_z(z, args):
        return residuals_unit(static, loss, unit_from_z(z), args) * args[ROW_WEIGHT]

    which = np.arange(len(problems))
    dd = stacked["data"]
    directions = None  # as fitlab.fitting.batch._run_starts passes them: once when shared
    if batch._alike(dd.wi) and batch._alike(dd.wo) and dd.weights is None:
        directions = (dd.wi[0], dd.wo[0], None)

    def own(z0, w, args):  # the batched fits' kernel (it gives every dataset weights of 1)
        if directions is not None:
            args = {**args, "data": args["data"]._replace(wi=None, wo=None, weights=None)}
        out = k["queue"](z0, which, len(problems), args, directions)
        return out["z"], out["iters"]

    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10)

    def optimistix(z0, w, args):
        sol = optx.least_squares(r_z, solver, z0, args={**args, ROW_WEIGHT: w}, max_steps=200,
                                 throw=False)
        return sol.value, sol.stats["num_steps"]

    print(machine_line(machine()))
    print(f"{len(problems)} datasets ({args.kind}, {p0.n_rows} rows, {d} free), one start each")
    ends = {}
    for name, g in (("fitlab lm_queue", own),
                    ("optimistix LevenbergMarquardt", jax.jit(jax.vmap(optimistix)))):
        t0 = time.perf_counter()
        jax.block_until_ready(g(Z0, W, stacked))
        t_first = time.perf_counter() - t0
        warm = []
        for _ in range(3):
            t0 = time.perf_counter()
            z, steps = jax.block_until_ready(g(Z0, W, stacked))
            warm.append(time.perf_counter() - t0)
        ends[name] = np.asarray(z)
        steps = np.asarray(steps)
        print(f"{name:30s} first call {t_first:5.2f} s, warm {min(warm):.3f} s = "
              f"{len(problems) / min(warm):7.0f} datasets/s; steps median {np.median(steps):g}, "
              f"max {steps.max()}")
    a, b = ends.values()
    print(f"largest |Δz| between the optima: {np.max(np.abs(a - b)):.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
