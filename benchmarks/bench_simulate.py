"""``fitlab simulate`` performance against the same random walk in vectorized NumPy
(benchmarks/numpy_walk.py), in one run: CPU and wall time, events per path, time to equal error.

fitlab's walk (fitlab/simulate/walk.py) is Dr.Jit on Mitsuba 3's ``llvm_ad_rgb`` variant (or
``cuda_ad_rgb`` with ``--device gpu``): every path is one lane of a symbolic ``dr.while_loop``
(one scattering event per iteration) compiled into one kernel per walk configuration (the
stack's structure and the effect plan; values, seeds and sizes are kernel inputs), traced on
``walk.LANES`` lanes with path regeneration (a lane whose path ends starts the next one), paths
float32, per-path exits summed on the host in float64 in path order. A configuration's first
call traces and compiles the kernel (or loads it from Dr.Jit's on-disk kernel cache,
``~/.drjit``); every fitlab run below is preceded by a first call of :data:`WARMUP_PATHS` paths
and is warm. CPU time is ``time.process_time`` (all threads of the process, summed over cores);
wall time ``time.perf_counter`` around the call. An event is one iteration of a path's loop (a
free flight and the scattering or boundary crossing that ends it), counted alike by both walks;
events per path = events / (paths x incidences), every channel walk of a scene included. The
NumPy walk (float64, alive paths compacted after every event) runs in the same process.

Time to equal error: the time to a median relative standard error of 1% over the requested
values (the rows holding at least 1% of the largest value; both walks over the same rows),
extrapolated as t (rel / 0.01)^2 from a run whose path count grows x8 until it takes about
``--tte-budget`` / 8 seconds (Monte Carlo error falls as 1 / sqrt(N)), at most ``--max-paths``
paths (fitlab's runs reach about a second at the default), fitlab's final run timed
``--repeat`` times and the least kept; the ratio NumPy / fitlab on wall and on CPU time.
Target >= 10x.

[1] throughput: the throughput scene (HG slab, g 0.5, sigma_a 0.2, sigma_s 0.8, thickness 1,
    n 1.5, between GGX 0.2 / 0.3 interfaces, light at 30 deg, both sides in 9 x 12 bins, every
    order with Russian roulette), ``--paths`` paths each; the two walks must agree (reflected and
    transmitted flux within 4 standard errors, per-bin chi^2 over bins expecting >= 100 paths
    with p > 1e-3), else the exit status is 1.
[2] loop modes: the throughput scene with ``walk.LOOP_MODE`` "symbolic" (one megakernel) and
    "evaluated" (a kernel per iteration, finished lanes compressed away); ``--loop-mode`` sets
    the mode of every other part.
[3] compile time: the throughput scene (bins) and its point-estimate arc, first call in a new
    process whose Dr.Jit kernel cache is an empty temporary folder (``HOME`` redirected), first
    call in a second process with that cache warm, and the warm call in the same process.
[4] time to equal error on every scene of data_formats/examples/scenes (its own estimator, and
    point estimates for cone detectors), the throughput scene on an in-plane arc (point
    estimates, cones of 0.01 sr) and every stack of benchmarks/layered_validation.py, each
    against the NumPy walk where it can simulate the scene (dielectric interfaces smooth or GGX,
    media with isotropic or HG phase, ``pass`` boundaries, one channel, no substrate); else the
    fitlab figures and the reason there is no peer.
[5] effect selection: for each reduced scene, events per path of the full and the reduced
    scene, the ideal saving (events per path full / reduced, times the variance ratio of the
    requested values at equal paths, var_full / var_red = rel_full^2 N_full / (rel_red^2 N_red)
    from the two runs' standard errors) beside the measured saving in time to equal error;
    target: measured >= 80% of ideal, and >= 3x wherever the ideal is >= 3.75x.
[6] standard error against time (the throughput scene, 2^14 .. 2^20 paths); ``--figure PATH``
    draws it (fitlab.report.simulate_figures).

Usage: python benchmarks/bench_simulate.py [--paths 524288] [--seed 0] [--device cpu]
       [--loop-mode symbolic|evaluated] [--only throughput,loops,compile,tte,selection,curve]
       [--tte-budget 8] [--max-paths 8388608] [--repeat 3] [--figure reports/x.png]
Exit status 0 when the two walks agree in [1] (or [1] did not run), 1 when they do not.
"""

from __future__ import annotations

import time

_T_IMPORT0 = time.perf_counter()

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import types  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from fitlab.errors import FitlabError  # noqa: E402
from fitlab.simulate import engine  # noqa: E402

try:  # before drjit / mitsuba are imported (this script reads their versions)
    engine.select_libllvm()
except FitlabError:
    pass

from fitlab.simulate import load_scene, scene_from_dict, simulate  # noqa: E402
from fitlab.simulate import detectors, walk  # noqa: E402
from fitlab.simulate.detectors import hemisphere_rows  # noqa: E402
from fitlab.simulate.simulator import _incidence_rows  # noqa: E402
from numpy_walk import simulate_numpy_points  # noqa: E402
# the NumPy walk with its events counted: walk_engines.py's proxy of numpy (one definition)
from walk_engines import _NumpyProxy  # noqa: E402

T, P, THETA_I = 9, 12, 30.0
SCENES = os.path.join(HERE, "..", "data_formats", "examples", "scenes")
TARGET_REL = 0.01
TARGET_TTE = 10.0
#: Below this median relative standard error the values are exact (float rounding only).
EXACT_REL = 1e-5
#: Paths of the first call of each walk configuration (tracing and compiling; not timed).
WARMUP_PATHS = 1024
#: Where fitlab's walk runs (--device).
DEVICE = "cpu"


# --------------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------------


def throughput_scene():
    return scene_from_dict({
        "name": "HG slab between GGX interfaces",
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                  {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2,
                   "sigma_s": 0.8, "phase": "hg", "g": 0.5},
                  {"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "illumination": {"theta_i": [THETA_I]},
        "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P}})


def arc_scene(estimator, sr=0.01):
    """The throughput scene on an in-plane arc (5° steps on the reflection side, 10° on the
    transmission side: 41 directions)."""
    sc = throughput_scene()
    arc = tuple(float(t) for t in np.arange(-80.0, 81.0, 5.0)) + \
        tuple(float(t) for t in np.arange(100.0, 180.0, 10.0))
    det = sc.detector._replace(type="inplane", sides=("reflection", "transmission"),
                               theta_o=arc, acceptance_sr=0.0 if estimator == "point" else sr,
                               estimator=estimator, theta_bins=0, phi_bins=0)
    return sc._replace(detector=det)


def _as_points(scene):
    return scene._replace(detector=scene.detector._replace(estimator="point", acceptance_sr=0.0))


def _layered_stacks():
    """The stacks benchmarks/layered_validation.py simulates: [(name, scene)]."""
    spec = importlib.util.spec_from_file_location("layered_validation",
                                                  os.path.join(HERE, "layered_validation.py"))
    mod = sys.modules.get("layered_validation")
    if mod is None:
        mod = importlib.util.module_from_spec(spec)
        sys.modules["layered_validation"] = mod
        spec.loader.exec_module(mod)
    return mod.stacks()


# --------------------------------------------------------------------------------------------
# Running the two walks
# --------------------------------------------------------------------------------------------

_WARM = set()


def fl_run(scene, n, seed):
    """One fitlab run of n paths per incidence, warm: (result, wall s, CPU s)."""
    key = repr(scene)
    if key not in _WARM:
        simulate(scene, WARMUP_PATHS, seed=seed + 7919, device=DEVICE)
        _WARM.add(key)
    t0, c0 = time.perf_counter(), time.process_time()
    res = simulate(scene, n, seed=seed, device=DEVICE)
    return res, time.perf_counter() - t0, time.process_time() - c0


def _fl_events(res):
    return res.events / (res.samples * max(len(res.incidences), 1))



_COUNTED = {}


def numpy_bins_counted(*args, **kw):
    """``numpy_walk.simulate_numpy`` (same random numbers, same result) and its event count."""
    if "mod" not in _COUNTED:
        spec = importlib.util.spec_from_file_location("_numpy_walk_counted",
                                                      os.path.join(HERE, "numpy_walk.py"))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.np = _COUNTED["proxy"] = _NumpyProxy()
        _COUNTED["mod"] = mod
    out = _COUNTED["mod"].simulate_numpy(*args, **kw)
    return out, _COUNTED["proxy"].last.events


def numpy_peer(scene):
    """How the NumPy walk simulates ``scene``: a dict (regions, boundaries, estimator) or the
    reason it cannot (a string). numpy_walk supports dielectric interfaces (smooth or GGX,
    isotropic), media with isotropic or HG phase, ``pass`` boundaries, one channel, no
    substrate, every bounce order, multiple volume scattering."""
    det, eff = scene.detector, scene.effects
    if scene.opaque_substrate or any(b.kind in ("lambertian", "conductor")
                                     for b in scene.boundaries):
        kinds = sorted({b.kind for b in scene.boundaries if b.kind in ("lambertian",
                                                                       "conductor")})
        return f"{'/'.join(kinds)} substrate: numpy_walk has no substrate"
    for b in scene.boundaries:
        if b.kind == "pass":
            continue
        if b.kind != "dielectric" or b.distribution not in ("smooth", "ggx"):
            return f"{b.distribution} {b.kind} boundary: numpy_walk has smooth and GGX ones"
        if b.alpha_y is not None:
            return "anisotropic interface: numpy_walk's GGX is isotropic"
    for m in scene.media:
        if m.phase.type not in ("isotropic", "hg"):
            return f"{m.phase.type} phase function: numpy_walk has isotropic and HG"
    if scene.channels != 1:
        return "RGB properties: numpy_walk traces one channel"
    if eff.volume_scattering != "multiple" and any(max(m.sigma_s) > 0 for m in scene.media):
        return f"volume_scattering = {eff.volume_scattering}: numpy_walk scatters every order"
    if not eff.absorption and any(max(m.sigma_a) > 0 for m in scene.media):
        return "absorption = false: numpy_walk always attenuates"
    bins = det.type == "hemisphere" and det.estimator != "point"
    if eff.max_bounces is not None and not bins:
        return "max_bounces with cones or points: numpy_walk splits only its bins by order"
    if not eff.delta and det.estimator != "point" and any(
            b.kind == "dielectric" and b.distribution == "smooth" for b in scene.boundaries):
        return "delta = false over a smooth interface: numpy_walk tallies the delta paths"
    regions = [{"index": scene.outside_index}]
    for m in scene.media:
        regions.append({"index": m.index, "thickness": m.thickness,
                        "sigma_a": float(m.sigma_a[0]), "sigma_s": float(m.sigma_s[0]),
                        "g": float(m.phase.g) if m.phase.type == "hg" else 0.0})
    regions.append({"index": scene.below_index})
    bounds = [{"kind": "pass"} if b.kind == "pass" else
              {"kind": "smooth"} if b.distribution == "smooth" else
              {"kind": "ggx", "alpha": float(b.alpha)} for b in scene.boundaries]
    est = "point" if det.estimator == "point" else "bins" if bins else "cones"
    return {"regions": regions, "boundaries": bounds, "estimator": est}


def np_run(scene, peer, n, seed):
    """The NumPy walk on every incidence of ``scene``, n paths each: (value, sigma, keep, wall
    s, CPU s, events per path) with value and sigma in the rows of fitlab's result and
    ``keep`` False on rows that hold a delta the NumPy walk tallies and fitlab does not."""
    det, eff = scene.detector, scene.effects
    vals, sigs, keeps = [], [], []
    events = 0
    t0, c0 = time.perf_counter(), time.process_time()
    incid = _incidence_rows(scene)
    for ii, (ti, pi_, rows, axes) in enumerate(incid):
        wi = detectors.direction(ti, pi_)
        keep = np.ones(len(rows.tally), dtype=bool)
        if peer["estimator"] == "point":
            v, s, ev = simulate_numpy_points(peer["regions"], peer["boundaries"], wi, n, axes,
                                             seed=seed + ii)
            v, s = v[rows.tally], s[rows.tally]
        elif peer["estimator"] == "bins":
            (S1, S2, _), ev = numpy_bins_counted(peer["regions"], peer["boundaries"], wi, n,
                                                 det.theta_bins, det.phi_bins, seed=seed + ii)
            k = None if eff.max_bounces is None else eff.max_bounces + 1
            S1, S2 = S1[:k].sum(0), S2[:k].sum(0)  # each path exits in one order class
            mean = S1 / n
            var = np.maximum(S2 / n - mean * mean, 0.0) / (n - 1.0)
            cw = rows.cos_solid_angle
            v, s = mean[rows.tally] / cw, np.sqrt(var[rows.tally]) / cw
            if not eff.delta:  # the unscattered direction's bin holds the delta
                d = -np.asarray(wi, float)[None]
                cfg = types.SimpleNamespace(theta_bins=det.theta_bins, phi_bins=det.phi_bins)
                keep &= rows.tally != walk.bin_index(cfg, d)[0]
        else:
            cos_half = detectors.cone_half_angle_cos(det.acceptance_sr)
            (_, _, _, mc, sc), ev = numpy_bins_counted(
                peer["regions"], peer["boundaries"], wi, n, 1, 1, seed=seed + ii,
                cones=(axes, cos_half))
            v, s = mc[rows.tally], sc[rows.tally]
            if not eff.delta:
                keep &= axes[rows.tally] @ -np.asarray(wi, float) < cos_half
        vals.append(v)
        sigs.append(s)
        keeps.append(keep)
        events += ev
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return (np.concatenate(vals), np.concatenate(sigs), np.concatenate(keeps), wall, cpu,
            events / (n * len(incid)))


def _big(v):
    v = np.asarray(v, float)
    return v >= 0.01 * v.max() if v.size and v.max() > 0 else np.zeros(v.shape, bool)


def _median_rel(v, s, mask):
    v, s = np.asarray(v, float).ravel(), np.asarray(s, float).ravel()
    m = mask.ravel() & (s > 0) & (v > 0)
    return float(np.median(s[m] / v[m])) if m.any() else float("nan")


def _grow(run, budget_s, max_paths, start=4096):
    """Run with a path count growing x8 from ``start`` until a run takes about budget_s / 8 or
    ``max_paths`` is reached: the last run's (n, output)."""
    n = min(start, max_paths)
    while True:
        out = run(n)
        if out["wall"] * 8 > budget_s or n >= max_paths:
            return n, out
        n = min(n * 8, max_paths)


def _tte_fields(rec, rel):
    scale = (rel / TARGET_REL) ** 2
    rec.update(rel=rel, tte_s=rec["wall"] * scale, tte_cpu_s=rec["cpu"] * scale)
    return rec


#: fitlab's final run of a measurement is repeated (same paths and seed, same result) and the
#: least wall and CPU times kept: its runs last about a second, where the machine's noise moved
#: single runs by ±15% (``--repeat``).
FL_REPEAT = 3


def fl_measure(scene, seed, budget_s, max_paths, pick=None):
    """fitlab's run for time to equal error: {paths, wall, cpu, events, result, v, s}; the
    times the least of :data:`FL_REPEAT` runs of the final path count."""
    def run(n):
        res, wall, cpu = fl_run(scene, n, seed)
        v, s = (res.value, res.sigma) if pick is None else pick(res)
        return {"paths": n, "wall": wall, "cpu": cpu, "events": _fl_events(res), "result": res,
                "v": np.asarray(v, float), "s": np.asarray(s, float)}

    n, out = _grow(run, budget_s, max_paths)
    for _ in range(FL_REPEAT - 1):
        _, wall, cpu = fl_run(scene, n, seed)
        out["wall"], out["cpu"] = min(out["wall"], wall), min(out["cpu"], cpu)
    return out


def np_measure(scene, peer, seed, budget_s, max_paths):
    def run(n):
        v, s, keep, wall, cpu, ev = np_run(scene, peer, n, seed)
        return {"paths": n, "wall": wall, "cpu": cpu, "events": ev, "v": v, "s": s,
                "keep": keep}

    return _grow(run, budget_s, max_paths)[1]


def _verdict(ratio, target):
    return "PASS" if ratio >= target else "MISS"


def _fmt_run(name, r):
    return (f"      {name:<7} paths {r['paths']:8d}  wall {r['wall']:8.3f} s  CPU {r['cpu']:8.3f} s"
            f"  events/path {r['events']:7.2f}  median rel SE {r['rel']:.4f}  t_1% "
            f"{r['tte_s']:9.3f} s (CPU {r['tte_cpu_s']:9.3f} s)")


def compare_case(label, scene, seed, budget_s, max_paths, peer=None):
    """[4]'s one case: fitlab's time to equal error and, where possible, NumPy's. Returns a
    summary dict."""
    fl = fl_measure(scene, seed, budget_s, max_paths)
    peer = numpy_peer(scene) if peer is None else peer
    out = {"label": label, "fitlab": fl, "numpy": None, "reason": None}
    if isinstance(peer, str):
        mask = _big(fl["v"].ravel()).reshape(fl["v"].shape)
        _tte_fields(fl, _median_rel(fl["v"], fl["s"], mask))
        print(f"    {label}: {fl['v'].shape[0]} rows")
        print(_fmt_run("fitlab", fl))
        print(f"      no NumPy peer for this scene ({peer})", flush=True)
        out["reason"] = peer
        return out
    try:
        nw = np_measure(scene, peer, seed, budget_s, max_paths)
    except Exception as exc:  # a scene the NumPy walk's checks refuse
        reason = f"numpy_walk refused it: {type(exc).__name__}: {exc}"
        return compare_case(label, scene, seed, budget_s, max_paths, peer=reason)
    fv, fs = fl["v"][:, 0], fl["s"][:, 0]
    mask = _big(fv) & (fs > 0) & nw["keep"] & (nw["s"] > 0) & (nw["v"] > 0)
    _tte_fields(fl, _median_rel(fv, fs, mask))
    _tte_fields(nw, _median_rel(nw["v"], nw["s"], mask))
    # agreement of the two walks on those rows (a sanity check, not the benchmark's target)
    chi2 = float(np.sum((fv[mask] - nw["v"][mask]) ** 2 / (fs[mask] ** 2 + nw["s"][mask] ** 2)))
    dof = int(mask.sum())
    p = float(stats.chi2.sf(chi2, dof)) if dof else float("nan")
    print(f"    {label}: {fl['v'].shape[0]} rows, {dof} compared (>= 1% of the maximum)")
    print(_fmt_run("fitlab", fl))
    print(_fmt_run("NumPy", nw))
    if max(fl["rel"], nw["rel"]) < EXACT_REL:
        # every path gives the same value (a point estimate through one rough interface is
        # its BSDF): any path count reaches any error; compare the time per path instead
        rw = (nw["wall"] / nw["paths"]) / (fl["wall"] / fl["paths"])
        rc = (nw["cpu"] / nw["paths"]) / (fl["cpu"] / fl["paths"])
        diff = float(np.max(np.abs(fv[mask] - nw["v"][mask]) / nw["v"][mask])) if dof else 0.0
        out.update(numpy=nw, ratio_wall=rw, ratio_cpu=rc, chi2=chi2, dof=dof, p=p, exact=True)
        print(f"      exact values in both walks (median rel SE < {EXACT_REL:g}: no Monte Carlo "
              f"spread), so the time to equal error is undefined; time per path NumPy / fitlab: "
              f"wall {rw:.1f}x {_verdict(rw, TARGET_TTE)}, CPU {rc:.1f}x "
              f"{_verdict(rc, TARGET_TTE)}; largest relative difference {diff:.1e}", flush=True)
        return out
    rw, rc = nw["tte_s"] / fl["tte_s"], nw["tte_cpu_s"] / fl["tte_cpu_s"]
    out.update(numpy=nw, ratio_wall=rw, ratio_cpu=rc, chi2=chi2, dof=dof, p=p)
    print(f"      time to equal error NumPy / fitlab: wall {rw:.1f}x {_verdict(rw, TARGET_TTE)}, "
          f"CPU {rc:.1f}x {_verdict(rc, TARGET_TTE)} (target >= {TARGET_TTE:g}x); events/path "
          f"NumPy / fitlab {nw['events'] / fl['events']:.2f}; agreement chi2 {chi2:.1f} over "
          f"{dof} rows, p = {p:.3g}{'' if p > 1e-3 else '  <- DISAGREE'}", flush=True)
    return out


# --------------------------------------------------------------------------------------------
# [1] throughput
# --------------------------------------------------------------------------------------------


def throughput(n, seed):
    scene = throughput_scene()
    peer = numpy_peer(scene)
    res, wall, cpu = fl_run(scene, n, seed)
    t0 = time.perf_counter()
    c0 = time.process_time()
    (S1, S2, flux), np_events = numpy_bins_counted(peer["regions"], peer["boundaries"],
                                                   detectors.direction(THETA_I, 0.0), n, T, P,
                                                   seed=seed)
    np_wall, np_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"[1] throughput: {scene.name}, light at {THETA_I:g} deg, both sides in {T} x {P} bins, "
          f"all orders, {n} paths (device {DEVICE}, loop mode {walk.LOOP_MODE})")
    N = float(n)
    rows = hemisphere_rows(T, P, ("reflection", "transmission"))
    mean = S1.sum(0) / N
    var = np.maximum(S2.sum(0) / N - mean**2, 0) / (N - 1)
    v_np = mean[rows.tally] / rows.cos_solid_angle
    s_np = np.sqrt(var[rows.tally]) / rows.cos_solid_angle
    fv, fs = res.value[:, 0], res.sigma[:, 0]
    mask = _big(fv) & (fs > 0) & (s_np > 0)
    fl = _tte_fields({"paths": n, "wall": wall, "cpu": cpu, "events": _fl_events(res)},
                     _median_rel(fv, fs, mask))
    nw = _tte_fields({"paths": n, "wall": np_wall, "cpu": np_cpu, "events": np_events / N},
                     _median_rel(v_np, s_np, mask))
    print(_fmt_run("fitlab", fl))
    print(_fmt_run("NumPy", nw))
    rw, rc = nw["tte_s"] / fl["tte_s"], nw["tte_cpu_s"] / fl["tte_cpu_s"]
    print(f"      paths/s fitlab {n / wall:,.0f} (CPU {n / cpu:,.0f} per CPU-s), NumPy "
          f"{n / np_wall:,.0f} (CPU {n / np_cpu:,.0f}); ns of CPU per event: fitlab "
          f"{cpu / res.events * 1e9:.1f}, NumPy {np_cpu / np_events * 1e9:.1f}")
    print(f"      time to equal error NumPy / fitlab: wall {rw:.1f}x {_verdict(rw, TARGET_TTE)}, "
          f"CPU {rc:.1f}x {_verdict(rc, TARGET_TTE)} (target >= {TARGET_TTE:g}x)")
    # agreement
    np_flux = flux / N
    ok = True
    half = T * P
    for k, name in enumerate(("reflected", "transmitted")):
        s2 = S2.sum(0)[k * half:(k + 1) * half].sum() / N
        s1 = S1.sum(0)[k * half:(k + 1) * half].sum() / N
        sig = np.sqrt(max(s2 - s1 * s1, 0.0) / (N - 1))
        a, sa = res.energy[0, k, 0], res.energy_sigma[0, k, 0]
        z = (a - np_flux[k]) / np.hypot(sa, sig)
        print(f"      {name} flux: fitlab {a:.5f} ± {sa:.5f}, NumPy {np_flux[k]:.5f} ± {sig:.5f}"
              f"  (z = {z:+.2f})")
        ok &= abs(z) < 4
    counts = v_np * rows.cos_solid_angle * N
    m = (counts > 100) & (s_np > 0) & (fs > 0)
    chi2 = float(np.sum(((fv[m] - v_np[m]) / np.hypot(fs[m], s_np[m])) ** 2))
    p = stats.chi2.sf(chi2, m.sum())
    print(f"      per-bin agreement: chi2 = {chi2:.1f} over {m.sum()} bins, p = {p:.3f}",
          flush=True)
    ok &= p > 1e-3
    return bool(ok)


# --------------------------------------------------------------------------------------------
# [2] loop modes
# --------------------------------------------------------------------------------------------


def loop_modes(n, seed):
    print(f"[2] loop modes: the throughput scene, {n} paths (device {DEVICE}; warm)")
    print("      mode        wall_s    CPU_s   events/path   ns CPU/event   paths/s")
    keep = walk.LOOP_MODE
    scene = throughput_scene()
    out = {}
    try:
        for mode in ("symbolic", "evaluated"):
            walk.LOOP_MODE = mode
            _WARM.discard(repr(scene))
            res, wall, cpu = fl_run(scene, n, seed)
            out[mode] = (wall, cpu)
            print(f"      {mode:<10} {wall:8.3f} {cpu:8.3f} {_fl_events(res):11.3f} "
                  f"{cpu / res.events * 1e9:14.1f} {n / wall:11,.0f}", flush=True)
    finally:
        walk.LOOP_MODE = keep
        _WARM.clear()
    s, e = out["symbolic"], out["evaluated"]
    print(f"      evaluated / symbolic: wall {e[0] / s[0]:.2f}x, CPU {e[1] / s[1]:.2f}x")
    return out


# --------------------------------------------------------------------------------------------
# [3] compile time
# --------------------------------------------------------------------------------------------

COMPILE_PATHS = 4096


def _compile_child(device, loop_mode):
    """In a new process: the imports (this script's, fitlab.simulate's), engine.load, and per
    scene the first and a second (warm) call."""
    t_import = time.perf_counter() - _T_IMPORT0
    walk.LOOP_MODE = loop_mode
    t0 = time.perf_counter()
    engine.load(device)
    t_engine = time.perf_counter() - t0
    out = {"import_s": t_import, "engine_s": t_engine, "scenes": {}}
    for name, sc in (("throughput scene, bins", throughput_scene()),
                     ("throughput arc, point estimates", arc_scene("point"))):
        t0 = time.perf_counter()
        simulate(sc, COMPILE_PATHS, seed=0, device=device)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        simulate(sc, COMPILE_PATHS, seed=1, device=device)
        out["scenes"][name] = {"first_s": first, "warm_s": time.perf_counter() - t0}
    print("COMPILE_JSON " + json.dumps(out), flush=True)


def compile_times():
    print(f"[3] compile time: first call of a scene ({COMPILE_PATHS} paths) in a new process "
          f"(device {DEVICE}, loop mode {walk.LOOP_MODE})")
    tmp = tempfile.mkdtemp(prefix="bench_simulate_drjit_")
    env = dict(os.environ, HOME=tmp)  # Dr.Jit's kernel cache is $HOME/.drjit
    runs = []
    try:
        for _ in range(2):
            p = subprocess.run([sys.executable, os.path.abspath(__file__), "--compile-child",
                                "--device", DEVICE, "--loop-mode", walk.LOOP_MODE],
                               env=env, capture_output=True, text=True, timeout=600)
            line = [ln for ln in p.stdout.splitlines() if ln.startswith("COMPILE_JSON ")]
            if p.returncode != 0 or not line:
                print(f"      the child process failed ({p.returncode}): {p.stderr[-2000:]}")
                return None
            runs.append(json.loads(line[-1][len("COMPILE_JSON "):]))
        n_kernels = len(os.listdir(os.path.join(tmp, ".drjit"))) \
            if os.path.isdir(os.path.join(tmp, ".drjit")) else 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    cold, warm = runs
    print(f"      imports (this script: fitlab.simulate, scipy) {cold['import_s']:.2f} s, "
          f"engine.load (drjit, mitsuba, variant) {cold['engine_s']:.2f} s in the first "
          f"process; {n_kernels} files in the fresh Dr.Jit kernel cache afterwards")
    print("      scene                              first call, empty cache   first call, "
          "cache warm (new process)   warm call, same process   compile ~ first - warm")
    for name in cold["scenes"]:
        c, w = cold["scenes"][name], warm["scenes"][name]
        print(f"      {name:<34} {c['first_s']:14.3f} s {w['first_s']:26.3f} s "
              f"{c['warm_s']:22.3f} s {c['first_s'] - c['warm_s']:16.3f} s / "
              f"{w['first_s'] - w['warm_s']:.3f} s (cache warm)", flush=True)
    return runs


# --------------------------------------------------------------------------------------------
# [4] time to equal error
# --------------------------------------------------------------------------------------------


def time_to_error(seed, budget_s, max_paths):
    print(f"[4] time to a 1% median relative standard error over the requested values (warm; "
          f"t (rel/0.01)^2; runs grow x8 to ~{budget_s:g}/8 s, at most {max_paths} paths)")
    cases = []
    for name in sorted(os.listdir(SCENES)):
        if not name.endswith(".toml"):
            continue
        scene = load_scene(os.path.join(SCENES, name))
        det = scene.detector
        est = ("point" if det.estimator == "point" else
               "bins" if det.type == "hemisphere" else "cones")
        cases.append((f"{name[:-5]} [{est}]", scene))
        if det.type != "hemisphere" and det.estimator == "cone":
            cases.append((f"{name[:-5]} [point]", _as_points(scene)))
    cases += [("throughput arc [point]", arc_scene("point")),
              ("throughput arc [cones 0.01 sr]", arc_scene("cone"))]
    cases += [(f"layered: {label} [point]", sc) for label, sc in _layered_stacks()]
    out = []
    for label, sc in cases:
        out.append(compare_case(label, sc, seed, budget_s, max_paths))
    print("\n    summary: time to 1% median relative SE (s), wall (CPU); * exact values: the "
          "ratio of the times per path")
    print(f"    {'case':<70} {'fitlab':>18} {'NumPy':>18}  {'NumPy / fitlab':>22}  target >= 10x")
    for r in out:
        f = r["fitlab"]
        fs = f"{f['tte_s']:.3g} ({f['tte_cpu_s']:.3g})"
        if r["numpy"] is None:
            print(f"    {r['label'][:70]:<70} {fs:>18} {'-':>18}  {'-':>22}  no NumPy peer "
                  f"({r['reason']})")
            continue
        nw = r["numpy"]
        ns = f"{nw['tte_s']:.3g} ({nw['tte_cpu_s']:.3g})"
        rs = f"{r['ratio_wall']:.1f}x ({r['ratio_cpu']:.1f}x)" + ("*" if r.get("exact") else "")
        print(f"    {r['label'][:70]:<70} {fs:>18} {ns:>18}  {rs:>22}  wall "
              f"{_verdict(r['ratio_wall'], TARGET_TTE)}, CPU {_verdict(r['ratio_cpu'], TARGET_TTE)}")
    return out


# --------------------------------------------------------------------------------------------
# [5] effect selection
# --------------------------------------------------------------------------------------------


def _keys(res):
    return [(round(float(a), 6), round(float(b), 6), round(float(c), 6), round(float(d), 6))
            for a, b, c, d in zip(res.theta_i, res.phi_i, res.theta_o, res.phi_o)]


def _rows_of(full, reduced):
    """Indices of the rows of ``full`` at the directions of ``reduced``'s rows."""
    pos = {k: i for i, k in enumerate(_keys(full))}
    return np.array([pos[k] for k in _keys(reduced)], dtype=int)


def _orders_upto(res, k):
    """Value and standard error of bounce orders 0..k of a bin or cone result: each path exits
    once, in one order class, so the classes' covariance is -m_i m_j / (N - 1)."""
    v = res.by_order[:k + 1].sum(0)
    var = (res.sigma_by_order[:k + 1] ** 2).sum(0)
    for i in range(k + 1):
        for j in range(i + 1, k + 1):
            var = var - 2.0 * res.by_order[i] * res.by_order[j] / (res.samples - 1.0)
    return v, np.sqrt(np.maximum(var, 0.0))


def selection_cases():
    """(what is reduced, full scene, reduced scene, pick_full(full, reduced_result),
    pick_reduced(result)) for [5]."""
    cases = []
    slab = load_scene(os.path.join(SCENES, "absorbing_slab.toml"))
    full = slab._replace(detector=slab.detector._replace(sides=("reflection", "transmission")),
                         effects=slab.effects._replace(max_bounces=None))

    def pick_slab(r, red):
        v, s = _orders_upto(r, 1)
        i = _rows_of(r, red)
        return v[i], s[i]

    cases.append(("absorbing_slab: reflection only, max_bounces = 1 (its own scene) vs both "
                  "sides, all bounces", full, slab, pick_slab, None))

    def rgb(color):
        return scene_from_dict({
            "name": "HG slab in RGB",
            "stack": [{"type": "medium", "index": 1.0, "thickness": 1.0, "sigma_a": 0.2,
                       "sigma_s": [1.8, 1.2, 0.6], "phase": "hg", "g": 0.6}],
            "illumination": {"theta_i": [THETA_I]},
            "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P},
            "effects": {"delta": False, "color": color}})

    cases.append(("one channel: color = \"G\" vs RGB (HG slab, sigma_s 1.8/1.2/0.6: one walk "
                  "per channel)", rgb("rgb"), rgb("G"),
                  lambda r, red: (r.value[_rows_of(r, red), 1], r.sigma[_rows_of(r, red), 1]),
                  None))
    dense = scene_from_dict({
        "name": "HG slab over a dense dielectric",
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                  {"type": "medium", "index": 1.5, "thickness": 0.5, "sigma_a": 0.05,
                   "sigma_s": 1.0, "phase": "hg", "g": 0.5},
                  {"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "below": {"index": 2.4}, "illumination": {"theta_i": [THETA_I]},
        "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P}})
    refl = dense._replace(detector=dense.detector._replace(sides=("reflection",)))
    pick_rows = lambda r, red: (r.value[_rows_of(r, red)], r.sigma[_rows_of(r, red)])  # noqa
    cases.append(("forced branches: reflection only (the bottom reflects every path) vs both "
                  "sides (HG slab over n 2.4)", dense, refl, pick_rows, None))
    tp = throughput_scene()
    trans = tp._replace(detector=tp.detector._replace(sides=("transmission",)))
    cases.append(("forced branches: transmission only (the top keeps paths inside) vs both "
                  "sides (throughput scene)", tp, trans, pick_rows, None))
    for name, sc in (("coated_lambertian, its cones", load_scene(
            os.path.join(SCENES, "coated_lambertian.toml"))),
            ("throughput arc, cones 0.01 sr", arc_scene("cone"))):
        split = sc._replace(effects=sc.effects._replace(split_first_interface=True))
        cases.append((f"split_first_interface vs the plain walk ({name})", sc, split,
                      pick_rows, None))
    return cases


def selection(seed, budget_s, max_paths):
    print("[5] effect selection: ideal saving = (events/path full / reduced) x (variance of "
          "the requested values at equal paths, full / reduced); measured = time to 1% full / "
          "reduced; target measured >= 80% of ideal, and >= 3x where ideal >= 3.75x")
    out = []
    for what, full, red, pick_full, pick_red in selection_cases():
        r_red = fl_measure(red, seed, budget_s, max_paths, pick=pick_red)
        res_red = r_red["result"]
        r_full = fl_measure(full, seed, budget_s, max_paths,
                            pick=lambda r, red=res_red: pick_full(r, red))
        vr, sr = r_red["v"].ravel(), r_red["s"].ravel()
        vf, sf = r_full["v"].ravel(), r_full["s"].ravel()
        mask = _big(vr) & (sr > 0) & (sf > 0) & (vf > 0)
        rel_r, rel_f = _median_rel(vr, sr, mask), _median_rel(vf, sf, mask)
        _tte_fields(r_red, rel_r)
        _tte_fields(r_full, rel_f)
        ev_ratio = r_full["events"] / r_red["events"]
        var_ratio = (rel_f ** 2 * r_full["paths"]) / (rel_r ** 2 * r_red["paths"])
        ideal = ev_ratio * var_ratio
        mw, mc = r_full["tte_s"] / r_red["tte_s"], r_full["tte_cpu_s"] / r_red["tte_cpu_s"]

        def verdict(m):
            ok = m >= 0.8 * ideal and (ideal < 3.75 or m >= 3.0)
            return "PASS" if ok else "MISS"

        print(f"    {what}")
        print(_fmt_run("full", r_full))
        print(_fmt_run("reduced", r_red))
        print(f"      events/path full {r_full['events']:.3f}, reduced {r_red['events']:.3f} "
              f"({ev_ratio:.2f}x); variance at equal paths full / reduced {var_ratio:.2f}; "
              f"ideal saving {ideal:.2f}x")
        print(f"      measured saving: wall {mw:.2f}x ({mw / ideal:.0%} of ideal) {verdict(mw)}, "
              f"CPU {mc:.2f}x ({mc / ideal:.0%} of ideal) {verdict(mc)}", flush=True)
        out.append({"what": what, "ideal": ideal, "wall": mw, "cpu": mc})
    return out


# --------------------------------------------------------------------------------------------
# [6] standard error against time
# --------------------------------------------------------------------------------------------


def se_curve(seed, max_paths, figure=None):
    print("[6] standard error vs time (the throughput scene, warm)")
    print("      paths     time_s   median_rel_se   se_reflected_flux")
    scene = throughput_scene()
    curve = []
    for e in range(14, 21):
        if (1 << e) > max_paths:
            break
        r, wall, _ = fl_run(scene, 1 << e, seed + e)
        v, s = r.value[:, 0], r.sigma[:, 0]
        rel = _median_rel(v, s, _big(v))
        curve.append((1 << e, wall, rel, float(r.energy_sigma[0, 0, 0])))
        print(f"      {1 << e:8d}  {wall:7.3f}   {rel:.4f}          "
              f"{r.energy_sigma[0, 0, 0]:.2e}", flush=True)
    if figure and curve:
        from fitlab.report.simulate_figures import se_time_figure

        fig = se_time_figure(np.array(curve), title="fitlab simulate: standard error vs time "
                             "(HG slab between GGX interfaces, 30°)")
        fig.savefig(figure, dpi=120)
        print(f"      wrote {figure}")
    return curve


# --------------------------------------------------------------------------------------------


def _machine_lines():
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    name = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    eng = engine.load(DEVICE)
    import drjit
    import mitsuba

    return [f"machine: {name}, {os.cpu_count()} CPUs ({usable} usable), {platform.system()} "
            f"{platform.release()}, python {platform.python_version()}, numpy {np.__version__}",
            f"walk: drjit {drjit.__version__}, mitsuba {mitsuba.__version__} ({eng.variant}, "
            f"libLLVM {eng.libllvm} from {eng.libllvm_source}), loop mode {walk.LOOP_MODE}, "
            f"boundary dispatch {getattr(walk, 'DISPATCH', '-')}, "
            f"{walk.LANES} lanes per launch, tally block {walk.TALLY_BLOCK} paths"]


PARTS = ("throughput", "loops", "compile", "tte", "selection", "curve")


def main(argv=None):
    global DEVICE, FL_REPEAT
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=int, default=1 << 19,
                    help="paths of the fixed-size runs ([1], [2])")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", choices=("cpu", "gpu", "auto"), default="cpu",
                    help="where fitlab's walk runs (the NumPy walk runs on the CPU)")
    ap.add_argument("--loop-mode", choices=("symbolic", "evaluated"), default=walk.LOOP_MODE,
                    help="fitlab.simulate.walk.LOOP_MODE for every part ([2] runs both)")
    ap.add_argument("--only", default=",".join(PARTS),
                    help="comma-separated parts: " + ", ".join(PARTS))
    ap.add_argument("--tte-budget", type=float, default=8.0,
                    help="seconds a time-to-error run grows to (about budget/8 .. budget)")
    ap.add_argument("--max-paths", type=int, default=1 << 23,
                    help="most paths per incidence of a time-to-error run ([4]-[6])")
    ap.add_argument("--repeat", type=int, default=FL_REPEAT,
                    help="fitlab's final run of each measurement is timed this many times, the "
                         "least kept (default %(default)s)")
    ap.add_argument("--figure", help="write the standard error vs time figure here (PNG)")
    ap.add_argument("--compile-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    DEVICE = args.device
    FL_REPEAT = max(1, args.repeat)
    walk.LOOP_MODE = args.loop_mode
    if args.compile_child:
        _compile_child(args.device, args.loop_mode)
        return 0
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad:
        ap.error(f"unknown part(s) {', '.join(bad)}; choose from {', '.join(PARTS)}")
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    for line in _machine_lines():
        print(line)
    print(f"load average at start: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}", flush=True)
    ok = True
    if "throughput" in parts:
        ok = throughput(args.paths, args.seed)
    if "loops" in parts:
        loop_modes(args.paths, args.seed)
    if "compile" in parts:
        compile_times()
    if "tte" in parts:
        time_to_error(args.seed, args.tte_budget, args.max_paths)
    if "selection" in parts:
        selection(args.seed, args.tte_budget, args.max_paths)
    if "curve" in parts:
        se_curve(args.seed, args.max_paths, args.figure)
    load1 = os.getloadavg()
    print(f"load average at end: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; run time "
          f"{time.perf_counter() - t_start:.0f} s")
    if "throughput" in parts:
        print("agreement:", "OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
