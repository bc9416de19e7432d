"""Warm least-squares fit of the Walter example: fitlab (jitted JAX, jaxopt's
Levenberg–Marquardt vmapped over the starts) against SciPy (``scipy.optimize.least_squares`` on a plain-NumPy implementation of the same GGX
rough-dielectric model, transforms and residuals, written in ``_walter_fit.py``).

The problem is exactly what ``fitlab fit data_formats/examples/walter_rough_glass.csv --model
rough_dielectric --fit-subset 'theta_i == 0'`` solves at the least-squares level: 69 rows at
θi = 0, eta fixed to 1.51, free alpha and the relative scale, relative loss (fitlab's own
``prepare_channel`` builds it). Three meanings of "one fit", each timed warm (fitlab's
compilation is timed once, separately, and excluded):

1. one LM solve from one start (fitlab's start point: the model defaults and the reference
   scale). fitlab: its LM kernel on a batch of one start. SciPy: ``least_squares`` with
   ``method="lm"`` (MINPACK) in the same logit-unit coordinates, and ``method="trf"`` with
   the bounds in native units (the idiomatic SciPy call); the ratio is taken against the
   faster of the two. Both use 2-point finite-difference Jacobians (the NumPy model has no
   derivatives) and tolerances 1e-10.
2. the LM stage of a fitlab fit: 9 starts (the global-search optimum, 8 Halton points and
   the start above; here the Halton points and the start). fitlab: one vmapped call. SciPy:
   9 ``method="lm"`` solves in turn.
3. the whole least-squares pipeline: nlopt G_MLSL_LDS + LD_LBFGS global search (450
   evaluations), the 9-start LM stage, covariance from the Jacobian. fitlab:
   ``fit_least_squares``. Peer: the same nlopt search on the NumPy cost with a forward-difference
   gradient, 9 SciPy LM solves, a central-difference Jacobian at the best.

Both sides run in one process on the same data, in rounds: each round times ``--inner``
consecutive calls of every case in turn (so each side runs with its own code and data warm in
the CPU caches, as in a fitting session); medians over all ``--repeat`` x ``--inner`` calls.
Both must reach the same optimum (parameters within 1e-6 relative, costs within 1e-9).

Usage: python benchmarks/bench_fit_least_squares.py [--repeat 7] [--inner 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import (  # noqa: E402
    SUBSET, Problem, load_average, machine, machine_line, median, np_cost_unit, np_native_from_unit,
    np_residuals_native, np_residuals_z, np_unit_from_native, timed,
)

TOL = 1e-10


def scipy_lm_z(p, z0):
    from scipy.optimize import least_squares

    return least_squares(np_residuals_z, z0, args=(p,), method="lm", xtol=TOL, ftol=TOL,
                         gtol=TOL)


def scipy_trf_native(p, x0):
    from scipy.optimize import least_squares

    return least_squares(np_residuals_native, x0, args=(p,), method="trf", bounds=(p.lo, p.hi),
                         x_scale="jac", xtol=TOL, ftol=TOL, gtol=TOL)


def numpy_pipeline(p, starts_u, seed=0, maxeval=None):
    """The fitlab least-squares pipeline, written with NumPy + nlopt + SciPy."""
    import nlopt

    d = len(p.lo)
    h = 1e-7

    seen = {"f": np.inf, "u": np.full(d, 0.5)}

    def objective(u, grad):
        f0 = np_cost_unit(u, p)
        if f0 < seen["f"]:
            seen["f"], seen["u"] = f0, np.array(u, dtype=float)
        if grad.size:
            for j in range(d):
                du = np.array(u, dtype=float)
                step = h if du[j] + h <= 1 else -h
                du[j] += step
                grad[j] = (np_cost_unit(du, p) - f0) / step
        return f0 if np.isfinite(f0) else 1e300

    nlopt.srand(int(seed))
    opt = nlopt.opt(nlopt.G_MLSL_LDS, d)
    local = nlopt.opt(nlopt.LD_LBFGS, d)
    local.set_ftol_rel(1e-10)
    local.set_maxeval(200)
    opt.set_local_optimizer(local)
    opt.set_lower_bounds(np.zeros(d))
    opt.set_upper_bounds(np.ones(d))
    opt.set_min_objective(objective)
    opt.set_maxeval(int(maxeval or 150 * (d + 1)))
    try:
        u_glob = np.clip(opt.optimize(np.full(d, 0.5)), 0, 1)
    except Exception:  # noqa: BLE001 - nlopt's LBFGS may give up on a finite-difference gradient
        u_glob = np.clip(seen["u"], 0, 1)  # the best point evaluated
    best = None
    for u0 in [u_glob] + list(starts_u):
        u0 = np.clip(u0, 1e-9, 1 - 1e-9)
        sol = scipy_lm_z(p, np.log(u0) - np.log1p(-u0))
        if best is None or sol.cost < best.cost:
            best = sol
    theta = np_native_from_unit(1.0 / (1.0 + np.exp(-best.x)), p.lo, p.hi)
    r = np_residuals_native(theta, p)
    J = np.empty((r.size, d))
    for j in range(d):
        e = np.zeros(d)
        e[j] = 1e-6 * abs(theta[j])
        J[:, j] = ((np_residuals_native(theta + e, p) - np_residuals_native(theta - e, p))
                   / (2 * e[j]))
    cost = 0.5 * float(r @ r)
    noise2 = 2 * cost / max(r.size - d, 1)
    cov = noise2 * np.linalg.pinv(J.T @ J)
    return theta, cost, np.sqrt(np.diag(cov))


def run(repeat=7, inner=5, subset=SUBSET, quiet=False):
    say = (lambda *a, **k: None) if quiet else print
    import jax
    import jax.numpy as jnp

    from fitlab.fitting import least_squares as fls, searches
    from fitlab.fitting.space import z_from_unit

    info = machine()
    p = Problem(subset)
    space, data, loss = p.space, p.data, p.loss
    k = fls.kernels(space.static, loss)
    problem = fls.problem_of(space, data)
    u_start = space.to_unit(p.start_native)
    starts_u = [np.asarray(u) for u in searches.halton(8, space.ndim)] + [u_start]

    def fitlab_lm(us):
        out = fls.local_fits(k, problem, us)  # LM + each end's cost, residuals, Jacobian
        return out["z"], out["iters"]

    def native_of_z(z):
        return np_native_from_unit(1.0 / (1.0 + np.exp(-np.asarray(z))), p.lo, p.hi)

    # ---- first calls (fitlab: tracing + compilation) ---------------------------------------
    t_c1, (z1, it1) = timed(lambda: fitlab_lm([u_start]))
    t_c9, (z9, it9) = timed(lambda: fitlab_lm(starts_u))
    t_cp, ls = timed(lambda: fls.fit_least_squares(space, data, loss, start_native=p.start_native,
                                                   n_starts=8, seed=0))
    z0 = z_from_unit(u_start)
    x0 = np.asarray(p.start_native)
    sol_lm, sol_trf = scipy_lm_z(p, z0), scipy_trf_native(p, x0)
    theta_pipe_np, cost_pipe_np, stderr_np = numpy_pipeline(p, starts_u[:-1] + [u_start])

    # ---- same optimum ----------------------------------------------------------------------
    theta_fl = native_of_z(z1[0])
    theta_lm, theta_trf = native_of_z(sol_lm.x), sol_trf.x
    cost_fl = np_cost_unit(np_unit_from_native(theta_fl, p.lo, p.hi), p)
    checks = {
        "one_start_lm": (theta_lm, sol_lm.cost), "one_start_trf": (theta_trf, sol_trf.cost),
        "pipeline": (theta_pipe_np, cost_pipe_np),
    }
    agree = True
    for name, (th, c) in checks.items():
        ok = np.allclose(th, theta_fl, rtol=1e-6, atol=0) and abs(c - cost_fl) <= 1e-9 * cost_fl
        agree &= bool(ok)
        say(f"check {name:>14}: SciPy/NumPy {th} cost {c:.12g}  vs fitlab {theta_fl} "
            f"cost {cost_fl:.12g}  {'same' if ok else 'DIFFERENT'}")
    ok = (np.allclose(ls.native, theta_fl, rtol=1e-6, atol=0)
          and np.allclose(ls.stderr, stderr_np, rtol=1e-3))
    agree &= bool(ok)
    say(f"check pipeline stderr: fitlab {ls.stderr} NumPy {stderr_np} "
        f"{'same' if ok else 'DIFFERENT'}")
    z9n = np.asarray(z9)
    for j, u0 in enumerate(starts_u):
        zz = z_from_unit(u0)
        s = scipy_lm_z(p, zz)
        if np.isfinite(s.cost) and s.cost < 1.01 * cost_fl:
            th = native_of_z(z9n[j])
            if not np.allclose(th, native_of_z(s.x), rtol=1e-5):
                agree = False
                say(f"check 9-start LM start {j}: DIFFERENT {th} vs {native_of_z(s.x)}")

    # ---- warm timings: blocks of `inner` calls of each case in turn, `repeat` rounds -------
    cases = {
        "fl1": lambda: fitlab_lm([u_start]),
        "lm1": lambda: scipy_lm_z(p, z0),
        "trf1": lambda: scipy_trf_native(p, x0),
        "fl9": lambda: fitlab_lm(starts_u),
        "lm9": lambda: [scipy_lm_z(p, z_from_unit(u)) for u in starts_u],
        "flp": lambda: fls.fit_least_squares(space, data, loss, start_native=p.start_native,
                                             n_starts=8, seed=0),
        "npp": lambda: numpy_pipeline(p, starts_u[:-1] + [u_start]),
    }
    load_before = load_average()
    T = {key: [] for key in cases}
    for _ in range(repeat):
        for key, fn in cases.items():
            T[key].extend(timed(fn)[0] for _ in range(inner))
    load_after = load_average()
    med = {key: median(v) for key, v in T.items()}
    scipy1 = min(med["lm1"], med["trf1"])
    res = {
        **info, "repeat": repeat, "inner": inner, "subset": subset, "rows": int(p.value.size),
        "agree": agree,
        "load_before": load_before, "load_after": load_after,
        "fitlab_first_one_start_s": t_c1, "fitlab_first_nine_starts_s": t_c9,
        "fitlab_first_pipeline_s": t_cp,
        "fitlab_lm_iterations": int(it1[0]), "scipy_lm_nfev": int(sol_lm.nfev),
        "scipy_trf_nfev": int(sol_trf.nfev), "scipy_trf_njev": int(sol_trf.njev),
        **{f"median_{key}_s": v for key, v in med.items()},
        "ratio_one_start": scipy1 / med["fl1"],
        "ratio_nine_starts": med["lm9"] / med["fl9"],
        "ratio_pipeline": med["npp"] / med["flp"],
        "alpha": float(theta_fl[0]), "scale": float(theta_fl[1]),
    }
    ms = 1e3
    say(f"machine : {machine_line(info)}; load avg {load_before} -> {load_after}")
    say(f"problem : Walter example, {subset or 'all rows'}: {res['rows']} rows, free alpha, scale "
        f"(eta fixed 1.51), relative loss; optimum alpha = {res['alpha']:.6g}, "
        f"scale = {res['scale']:.6g}; both sides agree: {agree}")
    say(f"fitlab first calls (trace + compile + run): one-start LM {t_c1:.2f} s, "
        f"9-start LM {t_c9:.2f} s, pipeline {t_cp:.2f} s (excluded below)")
    say(f"1. one LM solve, one start : fitlab {med['fl1'] * ms:8.3f} ms "
        f"({res['fitlab_lm_iterations']} LM iterations) | SciPy lm {med['lm1'] * ms:8.3f} ms "
        f"({res['scipy_lm_nfev']} evaluations), trf {med['trf1'] * ms:8.3f} ms "
        f"({res['scipy_trf_nfev']} + {res['scipy_trf_njev']} Jacobians) "
        f"-> fitlab {res['ratio_one_start']:.1f}x faster than the faster SciPy")
    say(f"2. LM stage, 9 starts      : fitlab {med['fl9'] * ms:8.3f} ms | SciPy lm "
        f"{med['lm9'] * ms:8.3f} ms -> {res['ratio_nine_starts']:.1f}x")
    say(f"3. least-squares pipeline  : fitlab {med['flp'] * ms:8.3f} ms | NumPy+nlopt+SciPy "
        f"{med['npp'] * ms:8.3f} ms -> {res['ratio_pipeline']:.1f}x")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7, help="rounds over the cases")
    ap.add_argument("--inner", type=int, default=5, help="consecutive calls per case and round")
    ap.add_argument("--subset", default=SUBSET,
                    help=f"rows to fit (default {SUBSET!r}, Walter's protocol; '' = all 276 rows)")
    args = ap.parse_args(argv)
    res = run(repeat=args.repeat, inner=args.inner, subset=args.subset or None)
    return 0 if res["agree"] else 1


if __name__ == "__main__":
    sys.exit(main())
