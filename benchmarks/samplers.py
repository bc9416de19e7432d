"""Posterior samplers (issue 19, item 2): effective samples per second of blackjax's NUTS
(``--sampler nuts``) against emcee (the reference) on the same posterior, in one run, for two
posteriors (``--posterior walter|layered|all``, default all).

``walter``: the Walter example's least-squares problem (GGX rough dielectric at normal
incidence, free α and scale, a sampled noise scale: 3 coordinates; 69 rows).

``layered``: an 8-parameter layered fit to real measured data bundled in the repository, the
Radiant Imaging brown vinyl (``data_formats/examples/zemax_brown_vinyl.bsdf``, channel Y, 13
incidences): ``rough_conductor+coated(lambertian+rough_conductor,specular=lobe)`` with the coat
fixed (``coat_eta`` 1.5, ``coat_tau`` 0), i.e. a grazing sheen lobe over a clear coat (its GGX
lobe ``coat_alpha``) over a Lambertian base with a rough inner lobe. Free: the sheen lobe's
α, n, k, ``coat_alpha``, ``albedo``, the inner lobe's α, n, k (8), plus the sampled noise scale
of the relative loss (9 coordinates). Rows: ``--layered-rows``, by default every 8th of the
clean rows of ``fits/brown_vinyl_two_lobe.json`` (``value > 0.01 and theta_o < 83``: 476 of
3809 rows), so that NUTS's warm run stays near three minutes on 2 CPU cores. Least squares
with up to 2000 Levenberg–Marquardt iterations (it needs about 800 here; fitlab's default 200
stops short); the benchmark stops if it does not converge.

emcee: 32 walkers (4 × the coordinates when more: 36 for the layered posterior) × the emcee
steps, ESS = walkers × (steps − burn-in) / the largest integrated autocorrelation time
(fitlab's own figure). NUTS: 4 chains × (N adaptation + N draws) vmapped, ESS = ArviZ's
smallest bulk ESS. Lengths: ``--emcee-steps`` and ``--nuts-steps`` (N) for the Walter posterior,
``--layered-emcee-steps`` and ``--layered-nuts-steps`` for the layered one. Both timed warm (a
first run compiles and is timed apart); both posteriors' means are printed with their Monte
Carlo standard errors (posterior sd / √ESS).

    python benchmarks/samplers.py [--posterior all] [--emcee-steps 3000] [--nuts-steps 1000]
        [--layered-emcee-steps 10000] [--layered-nuts-steps 700] [--layered-rows EXPR]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _walter_fit import ROOT, WALTER_CSV, machine, machine_line

VINYL = ROOT / "data_formats" / "examples" / "zemax_brown_vinyl.bsdf"
LAYERED_MODEL = "rough_conductor+coated(lambertian+rough_conductor,specular=lobe)"
LAYERED_FIXED = {"coat_eta": 1.5, "coat_tau": 0.0}
LAYERED_ROWS = "value > 0.01 and theta_o < 83 and row % 8 == 0"
LAYERED_LM_MAXITER = 2000


def walter(args) -> dict:
    """The Walter example at normal incidence, as ``fitlab fit`` builds it."""
    import fitlab

    m = fitlab.read(WALTER_CSV)
    return {"name": "walter", "measurement": m, "model": "rough_dielectric",
            "rows": m.theta_i == 0, "fixed": None, "lm_maxiter": None,
            "shown": (("alpha", "α", ".6f"), ("scale", "scale", ".5f")),
            "emcee_steps": args.emcee_steps, "nuts_steps": args.nuts_steps}


def layered(args) -> dict:
    """The 8-parameter layered fit to the brown vinyl (module text)."""
    import fitlab
    from fitlab.fitting.subset import subset_mask

    if not VINYL.exists():
        raise SystemExit(f"layered posterior: the brown vinyl data {VINYL.relative_to(ROOT)} is "
                         "missing from this checkout")
    m = fitlab.read(VINYL)
    return {"name": "layered", "measurement": m, "model": LAYERED_MODEL,
            "rows": subset_mask(args.layered_rows, m), "fixed": LAYERED_FIXED,
            "lm_maxiter": LAYERED_LM_MAXITER,
            "shown": (("rough_conductor.alpha", "sheen α", ".5f"),
                      ("coat_alpha", "coat_alpha", ".5f"), ("albedo", "albedo", ".5f")),
            "emcee_steps": args.layered_emcee_steps, "nuts_steps": args.layered_nuts_steps}


def describe(p: dict, prep: dict) -> None:
    """One line: the posterior's rows, free parameters and whether a noise scale is sampled."""
    from fitlab.fitting.losses import has_absolute_noise

    space = prep["space"]
    noise = not has_absolute_noise(prep["loss"])
    fixed = ", ".join(f"{k} {v:g}" for k, v in (prep["fixed"] or {}).items())
    print(f"[{p['name']}] {p['model']} ({int(np.sum(p['rows']))} rows, {prep['loss']} loss"
          f"{'; fixed ' + fixed if fixed else ''}): {space.ndim} free parameters "
          f"({', '.join(space.names)})"
          + (f" + the sampled noise scale log_noise = {space.ndim + 1} sampled coordinates"
             if noise else f", no noise scale sampled = {space.ndim} sampled coordinates"))


def least_squares(p: dict, prep: dict):
    """The least-squares fit the samplers start from; stops the benchmark unless it converged."""
    from fitlab.fitting.least_squares import LM_MAXITER, fit_least_squares

    t0 = time.perf_counter()
    ls = fit_least_squares(prep["space"], prep["data"], prep["loss"],
                           start_native=prep["start_native"],
                           lm_maxiter=p["lm_maxiter"] or LM_MAXITER)
    sol = ls.solver
    values = ", ".join(f"{n} {v:.4g}" for n, v in zip(prep["space"].names, ls.native))
    n = sol["iterations"]
    print(f"  least squares: cost {ls.cost:.6g}, {sol['stopped']} after {n} "
          f"Levenberg-Marquardt iteration{'s' * (n != 1)}, noise scale {ls.noise_scale:.4g}, "
          f"{time.perf_counter() - t0:.1f} s; {values}"
          + (f"; AT A BOUND: {', '.join(ls.at_bound)}" if ls.at_bound else ""))
    if sol["stopped"] != "converged":
        raise SystemExit(f"[{p['name']}] the least-squares fit did not converge "
                         f"({sol['stopped']}): no posterior to benchmark")
    return ls


def timed_runs(run):
    """(first run's seconds (with compilation), warm seconds, the warm run's result)."""
    t0 = time.perf_counter()
    run(0)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = run(1)
    return first, time.perf_counter() - t0, r


def compare(p: dict, prep: dict, ls) -> float:
    """Both samplers on one posterior: a line each, then NUTS's ESS/s over emcee's."""
    from fitlab.fitting.mcmc import run_mcmc
    from fitlab.fitting.nuts import run_nuts

    space, data, loss = prep["space"], prep["data"], prep["loss"]
    cols = [space.names.index(name) for name, _, _ in p["shown"]]
    rates = []
    for name, run in (("emcee", lambda seed: run_mcmc(space, data, loss, ls, seed=seed,
                                                      nsteps=p["emcee_steps"],
                                                      progress=False)),
                      ("NUTS", lambda seed: run_nuts(space, data, loss, ls, seed=seed,
                                                     nsteps=p["nuts_steps"]))):
        first, warm, r = timed_runs(run)
        s = r.samples_native
        mcse = s.std(0) / np.sqrt(r.ess)
        means = ", ".join(f"{label} {s[:, c].mean():{fmt}} ± {mcse[c]:{fmt}}"
                          for (_, label, fmt), c in zip(p["shown"], cols))
        rates.append(r.ess / warm)
        print(f"{name:>7}: first run {first:6.2f} s, warm {warm:6.2f} s, ESS {r.ess:7.0f} -> "
              f"{r.ess / warm:8.1f} ESS/s; {means}; trustworthy {r.trustworthy}")
        for w in r.warnings:
            print(f"         warning: {w}")
    print(f"  NUTS / emcee: {rates[1] / rates[0]:.3g}x ESS/s")
    return rates[1] / rates[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--posterior", choices=("walter", "layered", "all"), default="all")
    ap.add_argument("--emcee-steps", type=int, default=3000, help="walter posterior")
    ap.add_argument("--nuts-steps", type=int, default=1000, help="walter posterior")
    ap.add_argument("--layered-emcee-steps", type=int, default=10000)
    ap.add_argument("--layered-nuts-steps", type=int, default=700)
    ap.add_argument("--layered-rows", default=LAYERED_ROWS,
                    help="--fit-subset expression of the layered posterior (default "
                    f"{LAYERED_ROWS!r})".replace("%", "%%"))
    args = ap.parse_args(argv)

    from fitlab.fitting import channel

    print(machine_line(machine()))
    for build in {"walter": (walter,), "layered": (layered,),
                  "all": (walter, layered)}[args.posterior]:
        p = build(args)
        prep = channel.prepare_channel(p["measurement"], p["model"], rows=p["rows"],
                                      fix=p["fixed"])
        describe(p, prep)
        ls = least_squares(p, prep)
        compare(p, prep, ls)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
