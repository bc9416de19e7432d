"""``fitlab simulate`` performance (issue 7): paths/s of the JAX walk against the same random walk in
vectorized NumPy (benchmarks/numpy_walk.py), the saving from effect selection, and the standard
error against time.

1. Throughput. Scene: a slab between two GGX interfaces (α 0.2 on top, 0.3 below, n = 1.5,
   thickness 1, σa = 0.2, σs = 0.8, Henyey–Greenstein g = 0.5, air on both sides), light at 30°,
   both hemispheres in 9 × 12 (θ, φ) bins, every bounce order with Russian roulette. fitlab's
   walk (float32 paths, float64 tallies, 32768 paths per batch) runs warm (its compilation is
   timed separately and excluded); the NumPy walk (float64, alive paths compacted after each
   event) runs the same number of paths in the same process. The two must agree statistically
   (reflected and transmitted flux within 4 standard errors; per-bin χ² over bins expecting
   >= 100 paths with p > 1e-3) before the ratio is printed. Target: fitlab >= 20x NumPy.
2. Effect selection. Scene: the two-interface absorbing slab of
   data_formats/examples/scenes/absorbing_slab.toml (GGX 0.2 / Beckmann 0.4, RGB σa). Warm time of
   "reflection only, max_bounces = 1" against "both hemispheres, all bounces" for the same
   paths. Target: >= 3x less time.
3. Standard error against time (the first scene, warm): sample counts 2^14 .. 2^20, median
   relative standard error over the bins holding at least 1% of the largest value, and the
   standard error of the reflected flux. ``--figure PATH`` also draws it
   (fitlab.report.simulate_figures).

Usage: python benchmarks/bench_simulate.py [--paths 524288] [--seed 0] [--figure reports/x.png]
Exit status 0 when the two walks agree, 1 when they do not.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
from scipy import stats

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import fitlab  # noqa: E402,F401
from fitlab.simulate import load_scene, scene_from_dict, simulate  # noqa: E402
from fitlab.simulate.detectors import hemisphere_rows  # noqa: E402
from numpy_walk import simulate_numpy  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
T, P, THETA_I = 9, 12, 30.0


def throughput_scene():
    return scene_from_dict({
        "name": "HG slab between GGX interfaces",
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                  {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2,
                   "sigma_s": 0.8, "phase": "hg", "g": 0.5},
                  {"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "illumination": {"theta_i": [THETA_I]},
        "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P}})


def run_numpy(n, seed):
    regions = [{"index": 1.0}, {"index": 1.5, "thickness": 1.0, "sigma_a": 0.2, "sigma_s": 0.8,
                                "g": 0.5}, {"index": 1.0}]
    boundaries = [{"kind": "ggx", "alpha": 0.2}, {"kind": "ggx", "alpha": 0.3}]
    wi = [np.sin(np.radians(THETA_I)), 0.0, np.cos(np.radians(THETA_I))]
    t0, c0 = time.perf_counter(), time.process_time()
    S1, S2, flux = simulate_numpy(regions, boundaries, wi, n, T, P, seed=seed)
    return time.perf_counter() - t0, time.process_time() - c0, S1, S2, flux


def warm(scene, n, seed, **kw):
    """A first run of the same size compiles the kernels (its time less the warm run's is the
    compile time); the second, timed run is warm. Returns (compile_s, result)."""
    cold = simulate(scene, n, seed=seed + 1000, **kw)
    c0 = time.process_time()
    res = simulate(scene, n, seed=seed, **kw)
    warm.cpu_s = time.process_time() - c0
    return cold.time_s - res.time_s, res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=int, default=1 << 19)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figure", help="write the standard error vs time figure here (PNG)")
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"python {platform.python_version()}", flush=True)

    # 1. throughput ------------------------------------------------------------------------
    scene = throughput_scene()
    n = args.paths
    compile_s, res = warm(scene, n, args.seed)
    fl_cpu = warm.cpu_s
    t_np, np_cpu, S1, S2, flux = run_numpy(n, args.seed)
    fl_pps, np_pps = n / res.time_s, n / t_np
    print(f"[1] {n} paths, light at {THETA_I:g} deg, both sides, all bounces")
    print(f"    fitlab JAX walk: {res.time_s:.3f} s warm, {fl_cpu:.3f} CPU-s ({fl_pps:,.0f} "
          f"paths/s; compile {compile_s:.2f} s excluded), {res.events / n:.2f} events/path")
    print(f"    NumPy walk:      {t_np:.3f} s, {np_cpu:.3f} CPU-s ({np_pps:,.0f} paths/s)")
    print(f"    ratio fitlab / NumPy: {fl_pps / np_pps:.1f}x in wall time, "
          f"{np_cpu / fl_cpu:.1f}x in CPU time (target >= 20x)")
    # agreement
    N = float(n)
    np_flux = flux / N
    np_flux_sig = np.sqrt(np.maximum(S2.sum((0, 1)) / N - (S1.sum((0, 1)) / N) ** 2, 0) / N)
    ok = True
    for k, name in enumerate(("reflected", "transmitted")):
        a, sa = res.energy[0, k, 0], res.energy_sigma[0, k, 0]
        z = (a - np_flux[k]) / np.hypot(sa, np_flux_sig)
        print(f"    {name} flux: fitlab {a:.5f} ± {sa:.5f}, NumPy {np_flux[k]:.5f}  (z = {z:+.2f})")
        ok &= abs(z) < 4
    rows = hemisphere_rows(T, P, ("reflection", "transmission"))
    mean = S1.sum(0) / N
    var = np.maximum(S2.sum(0) / N - mean**2, 0) / (N - 1)
    v_np = mean[rows.tally] / rows.cos_solid_angle
    s_np = np.sqrt(var[rows.tally]) / rows.cos_solid_angle
    counts = v_np * rows.cos_solid_angle * N
    m = (counts > 100) & (s_np > 0) & (res.sigma[:, 0] > 0)
    chi2 = float(np.sum(((res.value[m, 0] - v_np[m]) / np.hypot(res.sigma[m, 0], s_np[m])) ** 2))
    p = stats.chi2.sf(chi2, m.sum())
    print(f"    per-bin agreement: chi2 = {chi2:.1f} over {m.sum()} bins, p = {p:.3f}")
    ok &= p > 1e-3

    # 2. effect selection ------------------------------------------------------------------
    slab = load_scene(os.path.join(HERE, "..", "data_formats", "examples", "scenes",
                                   "absorbing_slab.toml"))
    d_one = slab._replace(detector=slab.detector._replace(sides=("reflection",)),
                          effects=slab.effects._replace(max_bounces=1),
                          theta_i=(THETA_I,), phi_i=(0.0,))
    d_all = slab._replace(detector=slab.detector._replace(sides=("reflection", "transmission")),
                          effects=slab.effects._replace(max_bounces=None),
                          theta_i=(THETA_I,), phi_i=(0.0,))
    _, r_one = warm(d_one, n, args.seed)
    one_cpu = warm.cpu_s
    _, r_all = warm(d_all, n, args.seed)
    all_cpu = warm.cpu_s
    print(f"[2] two-interface absorbing slab (RGB), {n} paths at {THETA_I:g} deg")
    print(f"    everything (both sides, all bounces): {r_all.time_s:.3f} s, {all_cpu:.3f} CPU-s, "
          f"{r_all.events / n:.2f} events/path")
    print(f"    reflection only, max_bounces = 1:     {r_one.time_s:.3f} s, {one_cpu:.3f} CPU-s, "
          f"{r_one.events / n:.2f} events/path")
    print(f"    saving: {r_all.time_s / r_one.time_s:.1f}x less wall time, "
          f"{all_cpu / one_cpu:.1f}x less CPU time (target >= 3x)")

    # 3. standard error vs time -------------------------------------------------------------
    print("[3] standard error vs time (scene of [1], warm)")
    print("    paths     time_s   median_rel_se   se_reflected_flux")
    curve = []
    for e in range(14, 21):
        _, r = warm(scene, 1 << e, args.seed + e)
        v, s = r.value[:, 0], r.sigma[:, 0]
        big = v >= 0.01 * v.max()
        rel = float(np.median(s[big] / v[big]))
        curve.append((1 << e, r.time_s, rel, float(r.energy_sigma[0, 0, 0])))
        print(f"    {1 << e:8d}  {r.time_s:7.3f}   {rel:.4f}          {r.energy_sigma[0, 0, 0]:.2e}")
    if args.figure:
        from fitlab.report.simulate_figures import se_time_figure

        fig = se_time_figure(np.array(curve), title="fitlab simulate: standard error vs time "
                             "(HG slab between GGX interfaces, 30°)")
        fig.savefig(args.figure, dpi=120)
        print(f"    wrote {args.figure}")
    print("agreement:", "OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
