"""Posterior samplers (issue 19, item 2): effective samples per second of blackjax's NUTS
(``--sampler nuts``) against emcee (the reference) on the same posterior, in one run.

Posterior: the Walter example's least-squares problem (GGX rough dielectric at normal incidence,
free α and scale, a sampled noise scale: 3 coordinates). emcee: 32 walkers × ``--emcee-steps``,
ESS = walkers × (steps − burn-in) / the largest integrated autocorrelation time (fitlab's own
figure). NUTS: 4 chains × (``--nuts-steps`` adaptation + ``--nuts-steps`` draws) vmapped, ESS =
ArviZ's smallest bulk ESS. Both timed warm (a first run compiles and is timed apart); both
posteriors' means are printed with their Monte Carlo standard errors.

    python benchmarks/samplers.py [--emcee-steps 3000] [--nuts-steps 1000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _walter_fit import machine, machine_line


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--emcee-steps", type=int, default=3000)
    ap.add_argument("--nuts-steps", type=int, default=1000)
    args = ap.parse_args(argv)

    import fitlab
    from fitlab.fitting import driver
    from fitlab.fitting.least_squares import fit_least_squares
    from fitlab.fitting.mcmc import run_mcmc
    from fitlab.fitting.nuts import run_nuts

    m = fitlab.read("../data_formats/examples/walter_rough_glass.csv")
    prep = driver.prepare_channel(m, "rough_dielectric", rows=m.theta_i == 0)
    space, data, loss = prep["space"], prep["data"], prep["loss"]
    ls = fit_least_squares(space, data, loss, start_native=prep["start_native"])
    print(machine_line(machine()))
    rows = []
    for name, run in (("emcee", lambda seed: run_mcmc(space, data, loss, ls, seed=seed,
                                                      nsteps=args.emcee_steps,
                                                      progress=False)),
                      ("NUTS", lambda seed: run_nuts(space, data, loss, ls, seed=seed,
                                                     nsteps=args.nuts_steps))):
        t0 = time.perf_counter()
        run(0)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = run(1)
        warm = time.perf_counter() - t0
        s = r.samples_native
        mcse = s.std(0) / np.sqrt(r.ess)
        rows.append((name, r.ess / warm))
        print(f"{name:>5}: first run {first:6.2f} s, warm {warm:6.2f} s, ESS {r.ess:7.0f} -> "
              f"{r.ess / warm:8.0f} ESS/s; α {s[:, 0].mean():.6f} ± {mcse[0]:.6f}, scale "
              f"{s[:, 1].mean():.5f} ± {mcse[1]:.5f}; trusted {r.trustworthy}")
    print(f"NUTS / emcee: {rows[1][1] / rows[0][1]:.1f}x ESS/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
