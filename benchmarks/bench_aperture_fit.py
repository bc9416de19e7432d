"""What the aperture quadrature costs a fit: the aperture-averaged fit against the
point-evaluation fit (its peer: the same fitlab fit with each row evaluated at its centre, as
before issue 14 item 2) on the same data, in the same process.

Data, simulated at the start (seed 0, as ``fitlab simulate ... --samples N`` writes them):

- ``bins``: ``data_formats/examples/scenes/rough_dielectric_interface.toml`` (GGX α = 0.3,
  η = 1.5, 5° × 10° hemisphere bins, θi = 0, 30, 60°); about 2,500 rows.
- ``cones``: ``data_formats/examples/scenes/measurement_directions.toml`` (GGX α = 0.2, cones of
  0.003 sr = 1.77° half-angle at the Walter example's directions); about 110 rows.

Each is fitted with ``rough_dielectric`` (η fixed by the file, free α, chi2 loss), two ways:

1. the least-squares stage alone (``fit_least_squares``: nlopt global search, 9-start
   Levenberg–Marquardt, covariance), warm, on the data ``prepare_channel`` builds: with the
   aperture nodes of the order the automatic choice settles on, and without (one node per row);
2. the whole ``fitlab.fit`` call, warm: the aperture fit includes the order check (the rule of
   twice the order evaluated at the optimum, and any refit), the point fit does not.

The first call of each shape compiles; compile times are printed separately and excluded from
the medians. Rounds alternate the two sides (``--repeat`` rounds × ``--inner`` calls each).

Usage: python benchmarks/bench_aperture_fit.py [--samples 200000] [--repeat 5] [--inner 3]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import load_average, machine, machine_line, median, timed  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SCENES = {"bins": ROOT / "data_formats/examples/scenes/rough_dielectric_interface.toml",
          "cones": ROOT / "data_formats/examples/scenes/measurement_directions.toml"}


def simulated(name, samples):
    from fitlab.simulate import load_scene, simulate

    return simulate(load_scene(SCENES[name]), samples, 0).to_measurement()


def point(m):
    return m._replace(aperture_deg=None, bin_o_deg=None, source_divergence_deg=None)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--inner", type=int, default=3)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    import fitlab
    from fitlab.fitting.channel import prepare_channel
    from fitlab.fitting.least_squares import fit_least_squares

    print(f"machine: {machine_line(machine())}; load average {load_average()}")
    rows = []
    for name in SCENES:
        m = simulated(name, args.samples)
        mp = point(m)
        t_first, r = timed(lambda: fitlab.fit(m, "rough_dielectric", bootstrap=0))
        rec = r.record["fits"][0]["aperture"]
        order = rec["order"]
        t_first_p, rp = timed(lambda: fitlab.fit(mp, "rough_dielectric", bootstrap=0))
        print(f"{name}: {m.n} rows; aperture fit alpha = {r.parameters['Y']['alpha']:.5f} "
              f"(order {order}, {rec['nodes_per_row']} nodes per row, chi2/dof "
              f"{r.statistics()['chi2_per_dof']:.3f}); point fit alpha = "
              f"{rp.parameters['Y']['alpha']:.5f} (chi2/dof {rp.statistics()['chi2_per_dof']:.3f})"
              f"; first calls (compilation included): {t_first:.1f} s and {t_first_p:.1f} s")
        all_rows = np.ones(m.n, bool)
        pa = prepare_channel(m, "rough_dielectric", rows=all_rows, aperture_order=order)
        pp = prepare_channel(mp, "rough_dielectric", rows=all_rows)

        def ls(p):
            return fit_least_squares(p["space"], p["data"], p["loss"],
                                     start_native=p["start_native"], seed=0)

        ls(pa), ls(pp)  # compiled above for these shapes; once more to be sure
        cases = {"least squares": (lambda: ls(pa), lambda: ls(pp)),
                 "fitlab.fit": (lambda: fitlab.fit(m, "rough_dielectric", bootstrap=0),
                                lambda: fitlab.fit(mp, "rough_dielectric", bootstrap=0))}
        for case, (fa, fp) in cases.items():
            ta, tp = [], []
            for _ in range(args.repeat):
                for _ in range(args.inner):
                    ta.append(timed(fa)[0])
                for _ in range(args.inner):
                    tp.append(timed(fp)[0])
            a, p = median(ta), median(tp)
            rows.append((name, m.n, rec["nodes_per_row"], case, a, p))
            print(f"  {case:>14}: aperture {a * 1e3:8.1f} ms, point {p * 1e3:8.1f} ms, "
                  f"ratio {a / p:.1f}x", flush=True)
    print("\n| data | rows | nodes per row | what | aperture | point | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, n, k, case, a, p in rows:
        print(f"| {name} | {n} | {k} | {case} | {a * 1e3:.0f} ms | {p * 1e3:.0f} ms | "
              f"**{a / p:.1f}x** |")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
