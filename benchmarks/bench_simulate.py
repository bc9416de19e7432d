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

4. Time to equal error (``--only tte``): every example scene of data_formats/examples/scenes,
   with the estimator it asks for (bins or cones) and, for in-plane and measurement detectors,
   with point estimates at the same directions; and the throughput scene of [1] on an in-plane
   arc, fitlab's point estimates against the NumPy walk's (numpy_walk.simulate_numpy_points,
   when present) and the NumPy walk's cones. Each run is warm (a first run of the same size
   compiles); the time to a median relative standard error of 1% over the rows holding at
   least 1% of the largest value is extrapolated as t · (rel / 0.01)² (Monte Carlo error
   falls as 1/√N). Target: >= 10x the NumPy walk.
5. Effect selection in time to equal error (``--only tte``): the same requested values (the
   one-bounce reflection of the absorbing slab at 30°, point estimates on an in-plane arc)
   from a scene that asks only for them against one that simulates everything and reads them
   from its bounce-order split. Target: >= 3x.

Usage: python benchmarks/bench_simulate.py [--paths 524288] [--seed 0] [--figure reports/x.png]
       [--only throughput|tte]
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


SCENES = os.path.join(HERE, "..", "data_formats", "examples", "scenes")
TARGET_REL = 0.01


def _median_rel(values, sigma):
    v, s = np.asarray(values, float), np.asarray(sigma, float)
    big = v >= 0.01 * v.max()
    return float(np.median(s[big] / v[big]))


def _tte_run(scene, n, seed, pick=None):
    """Warm run of n paths: (result, wall s, CPU s, median relative SE of the picked values)."""
    _, res = warm(scene, n, seed)
    v, sg = (res.value, res.sigma) if pick is None else pick(res)
    return res, res.time_s, warm.cpu_s, _median_rel(v.ravel(), sg.ravel())


def _tte(scene, seed, pick=None, budget_s=8.0, start=1 << 12):
    """Grow the path count (x8) until a warm run takes about ``budget_s`` / 8 or more, then
    extrapolate the time to a 1% median relative standard error."""
    n = start
    while True:
        res, wall, cpu, rel = _tte_run(scene, n, seed, pick)
        if wall * 8 > budget_s or n >= 1 << 21:
            break
        n *= 8
    scale = (rel / TARGET_REL) ** 2
    return {"paths": n, "wall_s": wall, "cpu_s": cpu, "rel": rel, "events": res.events / n /
            max(len(res.incidences), 1), "tte_s": wall * scale, "tte_cpu_s": cpu * scale,
            "rows": int(np.asarray(res.value).shape[0]), "result": res}


def _as_points(scene):
    return scene._replace(detector=scene.detector._replace(estimator="point", acceptance_sr=0.0))


def time_to_error(seed):
    print("[4] time to a 1% median relative standard error at the requested values (warm; "
          "extrapolated t * (rel/0.01)^2)")
    print("    scene                          estimator  rows   paths    wall_s   CPU_s  "
          "events/path  rel_SE   t_1%_s  CPU_1%_s")
    out = []
    for name in sorted(os.listdir(SCENES)):
        if not name.endswith(".toml"):
            continue
        scene = load_scene(os.path.join(SCENES, name))
        runs = [(scene.detector.estimator if scene.detector.type != "hemisphere"
                 or scene.detector.estimator == "point" else "bin", scene)]
        if scene.detector.type != "hemisphere" and scene.detector.estimator == "cone":
            runs.append(("point", _as_points(scene)))
        for est, sc in runs:
            r = _tte(sc, seed)
            out.append((name, est, r))
            print(f"    {name[:-5]:<30} {est:<9} {r['rows']:5d} {r['paths']:8d} "
                  f"{r['wall_s']:8.2f} {r['cpu_s']:7.2f} {r['events']:9.2f}  {r['rel']:.4f} "
                  f"{r['tte_s']:9.2f} {r['tte_cpu_s']:9.2f}", flush=True)
    return out


def arc_scene(estimator, sr=0.01):
    """The throughput scene on an in-plane arc (5° steps, both sides)."""
    sc = throughput_scene()
    arc = tuple(float(t) for t in np.arange(-80.0, 81.0, 5.0)) + \
        tuple(float(t) for t in np.arange(100.0, 180.0, 10.0))
    det = sc.detector._replace(type="inplane", sides=("reflection", "transmission"),
                               theta_o=arc, acceptance_sr=0.0 if estimator == "point" else sr,
                               estimator=estimator, theta_bins=0, phi_bins=0)
    return sc._replace(detector=det)


def against_numpy(seed):
    print("[4b] the throughput scene on an in-plane arc (41 directions, both sides): fitlab "
          "against the NumPy walk")
    rows = []
    for est in ("point", "cone"):
        r = _tte(arc_scene(est), seed)
        rows.append((f"fitlab {est}", r))
    try:
        from numpy_walk import simulate_numpy_points
    except ImportError:
        simulate_numpy_points = None
    if simulate_numpy_points is not None:
        sc = arc_scene("point")
        from fitlab.simulate.detectors import inplane_rows

        _, axes = inplane_rows(sc.detector.theta_o, 0.0, 1e-3)
        regions = [{"index": 1.0}, {"index": 1.5, "thickness": 1.0, "sigma_a": 0.2,
                                    "sigma_s": 0.8, "g": 0.5}, {"index": 1.0}]
        boundaries = [{"kind": "ggx", "alpha": 0.2}, {"kind": "ggx", "alpha": 0.3}]
        wi = [np.sin(np.radians(THETA_I)), 0.0, np.cos(np.radians(THETA_I))]
        n = 1 << 12
        while True:
            t0, c0 = time.perf_counter(), time.process_time()
            out = simulate_numpy_points(regions, boundaries, wi, n, axes, seed=seed)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            if wall * 8 > 8.0 or n >= 1 << 21:
                break
            n *= 8
        value, sigma = out[0], out[1]
        rel = _median_rel(value, sigma)
        scale = (rel / TARGET_REL) ** 2
        rows.append(("NumPy point", {"paths": n, "wall_s": wall, "cpu_s": cpu, "rel": rel,
                                     "tte_s": wall * scale, "tte_cpu_s": cpu * scale}))
    print("    walk            paths    wall_s   CPU_s   rel_SE   t_1%_s   CPU_1%_s")
    for name, r in rows:
        print(f"    {name:<14} {r['paths']:8d} {r['wall_s']:8.2f} {r['cpu_s']:7.2f}  "
              f"{r['rel']:.4f} {r['tte_s']:9.2f} {r['tte_cpu_s']:9.2f}")
    best = {name: r for name, r in rows}
    if "NumPy point" in best:
        f, n_ = best["fitlab point"], best["NumPy point"]
        print(f"    ratio NumPy / fitlab, time to 1%: {n_['tte_s'] / f['tte_s']:.1f}x wall, "
              f"{n_['tte_cpu_s'] / f['tte_cpu_s']:.1f}x CPU (target >= 10x)")
    return rows


def _arc_points(scene, sides=("reflection",), extra=()):
    """``scene`` at θi = THETA_I with point estimates on the in-plane arc (33 directions, 5°
    steps) and ``extra`` directions (transmission rows) after them."""
    arc = tuple(float(t) for t in np.arange(-80.0, 81.0, 5.0))
    det = scene.detector._replace(type="inplane", sides=sides, theta_o=arc + tuple(extra),
                                  estimator="point", acceptance_sr=0.0, theta_bins=0,
                                  phi_bins=0)
    return scene._replace(detector=det, theta_i=(THETA_I,), phi_i=(0.0,)), len(arc)


def selection_cases():
    """[5]'s cases: (effect dropped, scene, scene asking for it alone, the same scene asking for
    everything, how the compared values are read from each)."""
    both = (("reflection", "transmission"), (120.0, 150.0, 180.0))
    cases = []
    # one bounce: the absorbing slab (its own example) and a scattering slab
    for name in ("absorbing_slab", "hg_medium"):
        sc = load_scene(os.path.join(SCENES, name + ".toml"))
        one, n = _arc_points(sc._replace(effects=sc.effects._replace(max_bounces=1)))
        every, _ = _arc_points(sc._replace(effects=sc.effects._replace(max_bounces=None)), *both)
        cases.append(("one bounce", name, one, every,
                      lambda r, n=n: (r.by_order[1, :n], r.sigma_by_order[1, :n])))
    # reflection only: a slab over a dense dielectric (the bottom's refracted branch forced away)
    dense = scene_from_dict({
        "name": "HG slab over a dense dielectric",
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                  {"type": "medium", "index": 1.5, "thickness": 0.5, "sigma_a": 0.05,
                   "sigma_s": 1.0, "phase": "hg", "g": 0.5},
                  {"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "below": {"index": 2.4}, "illumination": {"theta_i": [THETA_I]},
        "detector": {"type": "hemisphere"}})
    one, n = _arc_points(dense)
    every, _ = _arc_points(dense, *both)
    cases.append(("transmission", "slab over η 2.4", one, every,
                  lambda r, n=n: (r.value[:n], r.sigma[:n])))
    # one channel of an RGB scene whose σs differs by channel (one walk per channel)
    def rgb(color):
        return scene_from_dict({
            "name": "HG slab in RGB",
            "stack": [{"type": "medium", "index": 1.0, "thickness": 1.0, "sigma_a": 0.2,
                       "sigma_s": [1.8, 1.2, 0.6], "phase": "hg", "g": 0.6}],
            "illumination": {"theta_i": [THETA_I]}, "detector": {"type": "hemisphere"},
            "effects": {"delta": False, "color": color}})

    g_only, n = _arc_points(rgb("g"))
    every, _ = _arc_points(rgb("rgb"))
    cases.append(("channels R, B", "hg_medium in RGB", g_only, every,
                  lambda r, n=n: ((r.value[:n, 1], r.sigma[:n, 1]) if r.value.shape[1] == 3
                                  else (r.value[:n, 0], r.sigma[:n, 0]))))
    return cases


def selection_tte(seed):
    """[5]: effect selection in time to equal error: each case's values from a scene asking for
    them alone against the same values read from a scene simulating everything."""
    print(f"[5] effect selection, time to 1% (point estimates on a 33-direction arc at "
          f"{THETA_I:g} deg)")
    print("    dropped          scene                         alone: paths  t_1%_s CPU_1%_s |"
          " everything: paths  t_1%_s CPU_1%_s | saving wall, CPU")
    out = []
    for dropped, name, alone, every, pick in selection_cases():
        r_one = _tte(alone, seed, pick=pick)
        r_all = _tte(every, seed, pick=pick)
        out.append((dropped, name, r_one, r_all))
        print(f"    {dropped:<16} {name:<30} {r_one['paths']:9d} {r_one['tte_s']:7.2f} "
              f"{r_one['tte_cpu_s']:8.2f} | {r_all['paths']:16d} {r_all['tte_s']:7.2f} "
              f"{r_all['tte_cpu_s']:8.2f} | {r_all['tte_s'] / r_one['tte_s']:5.1f}x "
              f"{r_all['tte_cpu_s'] / r_one['tte_cpu_s']:5.1f}x (target >= 3x)", flush=True)
    return out


def splitting_tte(seed):
    """[5b]: splitting at the first interface (``split_first_interface``) against the plain
    walk, time to 1% on the cones of the throughput scene's arc and of the coated Lambertian
    example: the surface reflection's cones gain most."""
    print("[5b] splitting at the first interface, time to 1% (cones)")
    coated = load_scene(os.path.join(SCENES, "coated_lambertian.toml"))
    out = []
    for name, sc in (("throughput arc, cones 0.01 sr", arc_scene("cone")),
                     ("coated_lambertian, its cones", coated)):
        split = sc._replace(effects=sc.effects._replace(split_first_interface=True))
        r_plain, r_split = _tte(sc, seed), _tte(split, seed)
        out.append((name, r_plain, r_split))
        # the rows of the surface reflection gain most: the largest variance reduction per
        # path among the rows (error ratio squared, scaled to equal path counts)
        a, b = r_plain["result"], r_split["result"]
        ok = (a.sigma[:, 0] > 0) & (b.sigma[:, 0] > 0)
        gain = (a.sigma[:, 0] / np.where(ok, b.sigma[:, 0], 1.0)) ** 2 * (
            r_plain["paths"] / r_split["paths"])
        best = int(np.argmax(np.where(ok, gain, 0.0)))
        print(f"    {name:<32} plain {r_plain['paths']:8d} paths t_1% {r_plain['tte_s']:7.2f} s "
              f"(CPU {r_plain['tte_cpu_s']:7.2f}) | split {r_split['paths']:8d} paths t_1% "
              f"{r_split['tte_s']:7.2f} s (CPU {r_split['tte_cpu_s']:7.2f}) | "
              f"{r_plain['tte_s'] / r_split['tte_s']:.1f}x wall, "
              f"{r_plain['tte_cpu_s'] / r_split['tte_cpu_s']:.1f}x CPU (median row); largest "
              f"variance reduction per path {gain[best]:.1f}x at theta_i {a.theta_i[best]:g}, "
              f"theta_o {a.theta_o[best]:g}, phi_o {a.phi_o[best]:g}", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=int, default=1 << 19)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figure", help="write the standard error vs time figure here (PNG)")
    ap.add_argument("--only", choices=("throughput", "tte", "selection"),
                    help="run only [1]-[3] (throughput), [4]-[5b] (time to equal error) or [5]-[5b] "
                    "(effect selection, splitting)")
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"python {platform.python_version()}", flush=True)
    if args.only == "selection":
        selection_tte(args.seed)
        splitting_tte(args.seed)
        return 0
    if args.only != "throughput":
        time_to_error(args.seed)
        against_numpy(args.seed)
        selection_tte(args.seed)
        splitting_tte(args.seed)
        if args.only == "tte":
            return 0

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
