"""Layered models vs the Monte Carlo simulator (`fitlab simulate`) on the same stacks.

Writes reports/layered_validation/README.md (tables + the command) and results.json:

* A. coated(INNER) vs the simulator's one-bounce component (max_bounces = 1, the smooth coat's
  delta dropped): smooth coat η = 1.5 over a rough conductor (α2 = 0.05, 0.2, 0.5) or a
  Lambertian base, optical depth τ = 0 or 1. The coated model is the exact single-bounce,
  single-point solution for a smooth coat, so it should agree within the Monte Carlo noise.
  coated(lambertian) with interreflection=closed_form vs the full simulation (every bounce).
* B. weidlich_wilkie(BASE) vs the full simulation: GGX top interface α1 = 0.05, 0.2, 0.4 over a
  rough conductor (α2 = 0.05, 0.3), τ = 0 or 1, and over a Lambertian base. The subsurface lobe
  (simulated bounce orders >= 1 vs the model minus its top-interface term) shows where the
  collimated single-point assumption (refraction through the macro normal, no blur by the rough
  interface) makes it too glossy; the same stacks with roughness_clamp=clamp (Elek section 3).

Metrics along an in-plane arc at θi = 30° (point estimates every 2.5°, the model evaluated at the
same directions; ``--estimator cone``: cones of 0.01 sr, the model averaged over each cone with
cos θo weights like the simulator): RMS relative error over the directions above 1% of
the maximum, the Monte Carlo noise of the simulation there, the lobe peak position and FWHM
(specular half-plane). Timing: model evaluation per direction pair (jitted, float64, about 10^5
pairs, best of 3, once per model and options) and the simulation's paths per second (warm);
"sim. time for the model's accuracy" is the time the simulator needs until its own RMS relative
noise equals the model's RMS relative error (N* = N (noise / error)²).

Run time (issue: at most 15 s, cold and warm): the simulator's walk is Dr.Jit (one kernel per
walk configuration, kept in Dr.Jit's on-disk kernel cache ``~/.drjit``); the first call of each
configuration (:data:`WARMUP_PATHS` paths, tracing and compiling included) is timed apart from
the warm runs. Every model evaluation is padded to whole chunks of :data:`CHUNK` pairs, so each
model and option set compiles once (arc points, cone points and the timing share it), and JAX's
compiled models are kept in fitlab's persistent compilation cache
(:func:`fitlab.fitting.cache.enable_compilation_cache`). The script prints its run time by phase;
``--cold-warm`` runs it twice in child processes whose Dr.Jit kernel cache and JAX compilation
cache start empty (a fresh temporary ``HOME`` and ``FITLAB_CACHE_DIR``): the first run is cold,
the second warm, and both wall times (spawn to exit) are printed against the 15 s target.
The errors are set against the ``results.json`` already in the output folder, if any, before it
is replaced.

    .venv/bin/python benchmarks/layered_validation.py [--samples 2000000] [--quick] [--cold-warm]
        [--out DIR]
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_T_START = time.perf_counter()

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from fitlab.io.atomic import atomic_write_text  # noqa: E402
from fitlab.models import get_model  # noqa: E402
from fitlab.simulate import scene_from_dict, simulate  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "reports" / "layered_validation"
THETA_I = 30.0
ARC = [float(t) for t in np.arange(-85.0, 85.01, 2.5)]
ACCEPTANCE_SR = 0.01
ETA = 1.5
#: chromium at 550 nm (Elek 2010 appendix A), relative to vacuum
N_CR, K_CR = 3.18, 4.41
FLOOR = 0.01
#: paths per stack by estimator: about the same noise (point estimates need ~100x fewer paths)
DEFAULT_SAMPLES = {"point": 1 << 14, "cone": 2_000_000}
#: Paths of the first simulation of each walk configuration (tracing and compiling the kernel).
WARMUP_PATHS = 1024
#: Direction pairs per model evaluation call: every evaluation is padded to whole chunks, so a
#: model and option set compiles once whatever the number of directions.
CHUNK = 16384
#: The timing of a model evaluation: this many chunks (about 10^5 pairs), best of this many.
TIMING_CHUNKS, TIMING_REPEATS = 6, 3
#: Run time by phase (wall seconds), printed at the end and kept in results.json.
TIMES = collections.defaultdict(float)


def log(msg):
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------------------------
# Scenes and the matching model parameters
# ----------------------------------------------------------------------------------------------


def scene(top_alpha, base, tau, max_bounces, estimator="cone"):
    top = ({"type": "interface", "distribution": "smooth"} if top_alpha is None else
           {"type": "interface", "distribution": "ggx", "alpha": top_alpha})
    if isinstance(base, tuple):  # ("conductor", alpha)
        sub = {"type": "conductor", "n": N_CR, "k": K_CR, "distribution": "ggx", "alpha": base[1]}
    else:  # Lambertian albedo
        sub = {"type": "lambertian", "albedo": base}
    return scene_from_dict({
        "name": "layered validation",
        "stack": [top, {"type": "medium", "index": ETA, "thickness": 1.0, "sigma_a": tau}],
        "substrate": sub,
        "illumination": {"theta_i": [THETA_I]},
        "detector": ({"type": "inplane", "theta_o": ARC, "acceptance_sr": ACCEPTANCE_SR}
                     if estimator == "cone" else
                     {"type": "inplane", "theta_o": ARC, "estimator": "point"}),
        "effects": {"max_bounces": max_bounces, "delta": False, "color": "mono"},
    })


def cone_points(theta_o, phi_o, k=12):
    """Points (uniform in solid angle, k² per cone) of each detector cone around (θo, φo), and
    their cos θo weights: the model is averaged over the cone as the simulator tallies it."""
    beta = np.arccos(1.0 - ACCEPTANCE_SR / (2.0 * np.pi))
    u = (np.arange(k) + 0.5) / k
    cb = 1.0 - u * (1.0 - np.cos(beta))
    ph = 2.0 * np.pi * u
    CB, PH = np.meshgrid(cb, ph, indexing="ij")
    sb = np.sqrt(1.0 - CB**2)
    local = np.stack([sb * np.cos(PH), sb * np.sin(PH), CB], -1).reshape(-1, 3)
    t, p = np.radians(theta_o), np.radians(phi_o)
    c = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    # orthonormal frame around each cone axis c
    a = np.where(np.abs(c[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(a, c)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(c, e1)
    pts = (local[None, :, 0:1] * e1[:, None] + local[None, :, 1:2] * e2[:, None]
           + local[None, :, 2:3] * c[:, None])
    w = np.maximum(pts[..., 2], 0.0)
    return pts, w


def cone_average(model_name, params, options, theta_o, phi_o, theta_i=THETA_I):
    pts, w = cone_points(theta_o, phi_o)
    ti = np.radians(theta_i)
    wi = np.broadcast_to([np.sin(ti), 0.0, np.cos(ti)], pts.shape)
    f = np.asarray(_eval(model_name, params, options, wi, pts))
    return np.sum(f * w, -1) / np.maximum(np.sum(w, -1), 1e-300)


@functools.lru_cache(maxsize=None)
def _jitted_eval(model_name, options):
    """One compiled evaluation per model and options (``options``: sorted (key, value) pairs),
    shared by every stack and direction set of the run (inputs are always :data:`CHUNK` pairs)."""
    m = get_model(model_name)
    return jax.jit(lambda p, a, b: m.eval(p, a, b, **dict(options)))


_COMPILED = set()


def _chunks(a):
    """Direction array (..., 3) as float64 (n_chunks, CHUNK, 3), padded with the normal."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    pad = -len(a) % CHUNK
    if pad:
        a = np.concatenate([a, np.broadcast_to([0.0, 0.0, 1.0], (pad, 3))])
    return a.reshape(-1, CHUNK, 3)


def _eval(model_name, params, options, wi, wo):
    """The model at direction pairs (wi, wo) of any shape (..., 3), in chunks of :data:`CHUNK`
    pairs (one compilation per model and options). Returns a NumPy array of shape (...)."""
    key = (model_name, tuple(sorted(options.items())))
    fn = _jitted_eval(*key)
    wi, wo = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
    shape, n = wi.shape[:-1], int(np.prod(wi.shape[:-1], dtype=np.int64))
    p = {k: jnp.float64(v) for k, v in params.items()}
    out = []
    for a, b in zip(_chunks(wi), _chunks(wo)):
        t0 = time.perf_counter()
        out.append(np.asarray(fn(p, jnp.asarray(a), jnp.asarray(b))))
        TIMES["model compile" if key not in _COMPILED else "model eval"] += \
            time.perf_counter() - t0
        _COMPILED.add(key)
    return np.concatenate(out)[:n].reshape(shape)


def point_values(model_name, params, options, theta_o, phi_o, theta_i=THETA_I):
    """The model at the exact directions (what the simulator's point estimates estimate)."""
    t, p = np.radians(theta_o), np.radians(phi_o)
    wo = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    ti = np.radians(theta_i)
    wi = np.broadcast_to([np.sin(ti), 0.0, np.cos(ti)], wo.shape)
    return np.asarray(_eval(model_name, params, options, wi, wo))


def model_values(estimator, *args, **kw):
    """The model as the simulator's rows estimate it: cone averages or point values."""
    return (cone_average if estimator == "cone" else point_values)(*args, **kw)


def eval_time_us(model_name, params, options, n=TIMING_CHUNKS * CHUNK, repeats=TIMING_REPEATS):
    """µs per direction pair of the model's compiled evaluation: about ``n`` random pairs
    (whole chunks of :data:`CHUNK`), the best of ``repeats`` runs."""
    t_start = time.perf_counter()
    key = (model_name, tuple(sorted(options.items())))
    fn = _jitted_eval(*key)
    rng = np.random.default_rng(0)
    k = max(1, -(-int(n) // CHUNK))
    mu = rng.uniform(0.05, 1, (2, k * CHUNK))
    ph = rng.uniform(0, 2 * np.pi, (2, k * CHUNK))
    d = np.stack([np.sqrt(1 - mu**2) * np.cos(ph), np.sqrt(1 - mu**2) * np.sin(ph), mu], -1)
    a = [jnp.asarray(c) for c in d[0].reshape(k, CHUNK, 3)]
    b = [jnp.asarray(c) for c in d[1].reshape(k, CHUNK, 3)]
    p = {kk: jnp.float64(v) for kk, v in params.items()}
    t0 = time.perf_counter()
    fn(p, a[0], b[0]).block_until_ready()  # compiles if no evaluation did yet
    compile_s = 0.0
    if key not in _COMPILED:
        compile_s = time.perf_counter() - t0
        TIMES["model compile"] += compile_s
        _COMPILED.add(key)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for x, y in zip(a, b):
            r = fn(p, x, y)
        r.block_until_ready()
        best = min(best, time.perf_counter() - t0)
    TIMES["model timing"] += time.perf_counter() - t_start - compile_s
    return 1e6 * best / (k * CHUNK)


# ----------------------------------------------------------------------------------------------
# Lobe metrics
# ----------------------------------------------------------------------------------------------


def lobe(theta_o, values):
    """Peak θo (parabolic refinement) and FWHM (linear interpolation) on the specular half-plane
    θo >= 0 of the arc; None where the profile has no interior maximum."""
    sel = theta_o >= 0
    t, v = theta_o[sel], values[sel]
    i = int(np.argmax(v))
    if v[i] <= 0:
        return None, None
    peak = t[i]
    if 0 < i < len(v) - 1:
        den = v[i - 1] - 2 * v[i] + v[i + 1]
        if den < 0:
            peak = t[i] + 0.5 * (v[i - 1] - v[i + 1]) / den * (t[1] - t[0])
    half = 0.5 * v[i]

    def cross(idx):
        step = -1 if idx == "left" else 1
        j = i
        while 0 <= j + step < len(v) and v[j + step] > half:
            j += step
        if not 0 <= j + step < len(v):
            return None
        a, b = v[j], v[j + step]
        return t[j] + (a - half) / (a - b) * (t[j + step] - t[j])

    lo, hi = cross("left"), cross("right")
    if lo is None or hi is None:  # no lobe (e.g. a diffuse profile): neither peak nor width
        return None, None
    return float(peak), float(hi - lo)


def compare(sim_value, sim_sigma, model_value, theta_o):
    keep = (sim_value > FLOOR * sim_value.max()) & (sim_sigma > 0)
    rel = (model_value[keep] - sim_value[keep]) / sim_value[keep]
    noise = sim_sigma[keep] / sim_value[keep]
    ps, ws = lobe(theta_o, sim_value)
    pm, wm = lobe(theta_o, model_value)
    return {"rms_rel_error": float(np.sqrt(np.mean(rel**2))),
            "rms_rel_noise": float(np.sqrt(np.mean(noise**2))),
            "n_cones": int(keep.sum()),
            "peak_sim": ps, "peak_model": pm, "fwhm_sim": ws, "fwhm_model": wm}


# ----------------------------------------------------------------------------------------------


def cases(quick=False, estimator="point"):
    """The comparisons of the table, in order: dicts with ``part``, ``label``, ``scene``,
    ``compared`` ("one", "all" or "subsurface") and ``models`` [(model, params, options, the top
    interface's (model, params, options) to subtract or None)]."""
    out = []
    stack = functools.partial(scene, estimator=estimator)

    def do(part, label, sc, compared, models):
        out.append({"part": part, "label": label, "scene": sc, "compared": compared,
                    "models": models})

    a2s = (0.05, 0.2, 0.5) if not quick else (0.2,)
    taus = (0.0, 1.0) if not quick else (0.0,)
    # A: coated vs one bounce
    for tau in taus:
        for a2 in a2s:
            p = {"coat_eta": ETA, "coat_tau": tau, "alpha": a2, "n": N_CR / ETA, "k": K_CR / ETA}
            do("A", f"smooth coat / conductor a2={a2} tau={tau}", stack(None, ("conductor", a2), tau, 1),
               "one", [("coated(rough_conductor)", p, {}, None)])
        p = {"coat_eta": ETA, "coat_tau": tau, "albedo": 0.7}
        do("A", f"smooth coat / lambertian 0.7 tau={tau}", stack(None, 0.7, tau, 1), "one",
           [("coated(lambertian)", p, {"interreflection": "single"}, None)])
        do("A", f"smooth coat / lambertian 0.7 tau={tau}", stack(None, 0.7, tau, "all"), "all",
           [("coated(lambertian)", p, {"interreflection": "closed_form"}, None),
            ("coated(lambertian)", p, {"interreflection": "single"}, None)])
    # B: Weidlich–Wilkie vs full simulation
    a1s = (0.05, 0.2, 0.4) if not quick else (0.2,)
    a2b = (0.05, 0.3) if not quick else (0.05,)
    for tau in taus:
        for a1 in a1s:
            for a2 in a2b:
                p = {"alpha1": a1, "n1": ETA, "k1": 0.0, "tau1": tau, "alpha2": a2, "n2": N_CR,
                     "k2": K_CR}
                top = ("rough_conductor", {"alpha": a1, "n": ETA, "k": 0.0}, {})
                sc = stack(a1, ("conductor", a2), tau, "all")
                label = f"GGX a1={a1} / conductor a2={a2} tau={tau}"
                do("B", label, sc, "all",
                   [("weidlich_wilkie(rough_conductor)", p, {}, None),
                    ("weidlich_wilkie(rough_conductor)", p, {"roughness_clamp": "clamp"}, None)])
                do("B", label, sc, "subsurface",
                   [("weidlich_wilkie(rough_conductor)", p, {}, top),
                    ("weidlich_wilkie(rough_conductor)", p, {"roughness_clamp": "clamp"}, top)])
    for a1 in ((0.05, 0.3) if not quick else (0.3,)):
        p = {"alpha1": a1, "n1": ETA, "k1": 0.0, "tau1": 0.0, "albedo2": 0.7}
        do("B", f"GGX a1={a1} / lambertian 0.7 tau=0", stack(a1, 0.7, 0.0, "all"), "all",
           [("weidlich_wilkie(lambertian)", p, {}, None)])
    return out


def _stack_key(case):
    mb = case["scene"].effects.max_bounces
    return case["label"] + (", all bounces" if mb is None else f", max_bounces {mb}")


def stacks(quick=False, estimator="point"):
    """The distinct stacks the run simulates, in order: [(name, scene)] (benchmarks/
    bench_simulate.py times them against the NumPy walk)."""
    seen = {}
    for c in cases(quick, estimator):
        seen.setdefault(_stack_key(c), c["scene"])
    return list(seen.items())


def _config(sc):
    """What the simulator compiles into a walk kernel, as far as these stacks differ: the
    boundary kinds, absorption, the bounce limit (the values are kernel inputs)."""
    return (tuple((b.kind, b.distribution) for b in sc.boundaries),
            any(max(m.sigma_a) > 0 for m in sc.media), sc.effects.max_bounces)


def run(samples, quick, estimator="point"):
    rows = []
    compiled, done, eval_us = set(), {}, {}
    for case in cases(quick, estimator):
        part, label, sc, bounce_sel = case["part"], case["label"], case["scene"], case["compared"]
        # the first call of each walk configuration traces and compiles its kernel (timed
        # apart, on a few paths); each stack is then simulated once, warm
        config = _config(sc)
        if config not in compiled:
            t0 = time.perf_counter()
            simulate(sc, samples=WARMUP_PATHS, seed=0)
            TIMES["sim first calls"] += time.perf_counter() - t0
            TIMES["sim configurations"] += 1
            compiled.add(config)
        key = _stack_key(case)
        if key not in done:
            t0 = time.perf_counter()
            done[key] = (simulate(sc, samples=samples, seed=1), time.perf_counter() - t0)
            TIMES["sim warm runs"] += done[key][1]
        res, wall = done[key]
        th = res.theta_o * np.where(np.abs(res.phi_o - 180.0) < 1e-6, 1.0, -1.0)
        if bounce_sel == "one":
            v, s = res.by_order[1, :, 0], res.sigma_by_order[1, :, 0]
        elif bounce_sel == "subsurface":
            v = res.by_order[1:, :, 0].sum(0)
            s = np.sqrt((res.sigma_by_order[1:, :, 0] ** 2).sum(0))
        else:
            v, s = res.value[:, 0], res.sigma[:, 0]
        order = np.argsort(th)
        th, v, s = th[order], v[order], s[order]
        pps = res.samples / max(wall, 1e-12)
        for mname, params, opts, sub in case["models"]:
            mv = model_values(estimator, mname, params, opts, res.theta_o[order],
                              res.phi_o[order])
            if sub is not None:  # subtract the top interface's own lobe
                mv = mv - model_values(estimator, *sub, res.theta_o[order], res.phi_o[order])
            c = compare(v, s, mv, th)
            # one timing per model and options (the cost does not depend on the values)
            ek = (mname, json.dumps(opts, sort_keys=True))
            if ek not in eval_us:
                eval_us[ek] = eval_time_us(mname, params, opts)
            t_eval = eval_us[ek]
            n_star = samples * (c["rms_rel_noise"] / max(c["rms_rel_error"], 1e-12)) ** 2
            rows.append({"part": part, "stack": label, "compared": bounce_sel, "model": mname,
                         "options": opts, "params": params, **c, "eval_us_per_pair": t_eval,
                         "sim_paths": samples, "sim_wall_s": wall, "sim_paths_per_s": pps,
                         "sim_s_for_model_accuracy": n_star / pps})
            log(f"{part} {label:<38} {mname:<34} {json.dumps(opts):<28} err "
                f"{c['rms_rel_error']:.3f} noise {c['rms_rel_noise']:.3f} peak "
                f"{c['peak_sim']}/{c['peak_model']} fwhm {c['fwhm_sim']}/{c['fwhm_model']}")
    return rows


def _f(x, fmt="{:.3f}"):
    return "–" if x is None else fmt.format(x)


def markdown(rows, samples, machine, command, estimator="point"):
    where = ("point estimates (next-event estimation) every 2.5° (θo < 0: the incidence side), "
             "the model evaluated at the same directions" if estimator == "point" else
             f"cones of {ACCEPTANCE_SR} sr every 2.5° (θo < 0: the incidence side), the model "
             "averaged over each cone with cos θo weights as the simulator tallies")
    lines = [
        "# Layered models vs `fitlab simulate`",
        "",
        f"Generated by `{command}` (`benchmarks/layered_validation.py`; machine: {machine}).",
        "",
        f"In-plane arc at θi = {THETA_I:g}°, {where}; "
        f"{samples:,} paths per stack. Coat / layer index 1.5, thickness 1, "
        "σa = τ (so the optical depth is τ); conductor = chromium at 550 nm (n 3.18, k 4.41). "
        "*error*: RMS relative error of the model over the directions above 1% of the "
        "simulated maximum; *noise*: the simulation's own RMS relative standard error there; peak and FWHM "
        "of the lobe on the specular half-plane (degrees; simulated / model). *eval*: model "
        "evaluation per direction pair (jitted, float64, 10^5 pairs); *sim. for same accuracy*: "
        "seconds the simulator needs until its RMS noise equals the model's error.",
        "",
    ]
    for part, title, text in (
        ("A", "A. coated model vs the simulator's one-bounce component (and closed form vs all "
              "bounces)",
         "The coated model is the exact single-bounce solution under a smooth coat: its errors "
         "are the Monte Carlo noise. `compared = all` rows are the full simulation (every "
         "bounce): the closed-form inter-reflection sum matches it, the single-bounce default "
         "misses the inter-reflections."),
        ("B", "B. Weidlich–Wilkie vs the full simulation",
         "`subsurface` rows compare the light that went below the top interface (simulated "
         "bounce orders ≥ 1 vs the model minus its top-interface lobe). Refraction through the "
         "macro normal (the collimated single-point assumption) does not blur the base lobe "
         "by the rough top interface: where α1 is comparable to or larger than α2 the model's "
         "subsurface lobe is narrower (FWHM) and higher than simulated, i.e. too glossy; "
         "the peak positions agree. The section 3 clamp (α2 ≥ α1) widens it too far: the "
         "clamped α acts in the refracted frame and the refraction out widens the lobe once "
         "more. With α1 much smaller than α2 (or both small) the model is close to the "
         "simulation; absorption (τ = 1) does not change the picture.")):
        lines += [f"## {title}", "", text, "",
                  "| stack | compared | model, options | error | noise | peak sim/model | "
                  "FWHM sim/model | eval µs/pair | sim. s (paths/s) | sim. s for same accuracy |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            if r["part"] != part:
                continue
            opts = ", ".join(f"{k}={v}" for k, v in r["options"].items()) or "defaults"
            lines.append(
                f"| {r['stack']} | {r['compared']} | `{r['model']}` {opts} | "
                f"{r['rms_rel_error']:.3f} | {r['rms_rel_noise']:.3f} | "
                f"{_f(r['peak_sim'], '{:.1f}')} / {_f(r['peak_model'], '{:.1f}')} | "
                f"{_f(r['fwhm_sim'], '{:.1f}')} / {_f(r['fwhm_model'], '{:.1f}')} | "
                f"{r['eval_us_per_pair']:.3f} | {r['sim_wall_s']:.1f} "
                f"({r['sim_paths_per_s']:.3g}) | {r['sim_s_for_model_accuracy']:.3g} |")
        lines.append("")
    lines += ["## Summary (computed from the rows above)", ""] + summary(rows) + [""]
    return "\n".join(lines) + "\n"


def summary(rows):
    out = []
    a1 = [r for r in rows if r["part"] == "A" and r["compared"] == "one"]
    if a1:
        ratio = [r["rms_rel_error"] / r["rms_rel_noise"] for r in a1]
        out.append(f"- coated vs one bounce: model error / simulation noise = "
                   f"{min(ratio):.2f} .. {max(ratio):.2f} over {len(a1)} stacks (≈ 1: agreement "
                   "within the Monte Carlo noise).")
    cf = [r for r in rows if r["part"] == "A" and r["compared"] == "all"]
    for r in cf:
        out.append(f"- {r['stack']}, all bounces: interreflection={r['options']['interreflection']}"
                   f" error {r['rms_rel_error']:.3f} (noise {r['rms_rel_noise']:.3f}).")
    sub = [r for r in rows if r["part"] == "B" and r["compared"] == "subsurface"
           and r["fwhm_sim"] and r["fwhm_model"]]
    for r in sub:
        clamp = r["options"].get("roughness_clamp", "none")
        out.append(f"- {r['stack']}, subsurface lobe, clamp={clamp}: FWHM model/sim = "
                   f"{r['fwhm_model'] / r['fwhm_sim']:.2f} ({r['fwhm_model']:.1f}° vs "
                   f"{r['fwhm_sim']:.1f}°), error {r['rms_rel_error']:.3f}.")
    t = [r["eval_us_per_pair"] for r in rows]
    pps = [r["sim_paths_per_s"] for r in rows]
    out.append(f"- model evaluation {min(t):.3f} .. {max(t):.3f} µs per direction pair; the "
               f"simulator traces {min(pps):.3g} .. {max(pps):.3g} paths/s.")
    return out


def _machine():
    import os

    name = platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} CPUs, JAX {jax.__version__} on {jax.devices()[0].platform}"


def _compare_previous(prev, rows):
    """Lines setting this run's errors against ``prev`` (the rows of the results.json this run
    replaces), matched by part, stack, compared values, model and options."""
    key = lambda r: (r["part"], r["stack"], r["compared"], r["model"],  # noqa: E731
                     json.dumps(r["options"], sort_keys=True))
    before = {key(r): r for r in prev}
    pairs = [(r, before[key(r)]) for r in rows if key(r) in before]
    if not pairs:
        return ["errors: no row of the previous results.json matches this run"]
    lower = sum(r["rms_rel_error"] <= b["rms_rel_error"] for r, b in pairs)
    # a rise counts against the noise of the two runs (the agreeing rows are noise-limited)
    rise = [((r["rms_rel_error"] - b["rms_rel_error"])
             / max(np.hypot(r["rms_rel_noise"], b["rms_rel_noise"]), 1e-12), r, b)
            for r, b in pairs]
    worst = max(rise, key=lambda t: t[0])
    beyond = sum(z > 2.0 for z, _, _ in rise)
    z, r, b = worst
    return [f"errors vs the previous results.json: {lower} of {len(pairs)} rows lower or equal; "
            f"{beyond} higher by more than 2x their combined noise; largest rise "
            f"{r['rms_rel_error'] - b['rms_rel_error']:+.4f} ({z:+.1f} noise) at {r['stack']} / "
            f"{r['compared']} / {r['model']} {json.dumps(r['options'])} "
            f"({b['rms_rel_error']:.4f} -> {r['rms_rel_error']:.4f})"]


def _timing_lines(total):
    other = total - sum(v for k, v in TIMES.items() if k != "sim configurations")
    return [f"run time {total:.1f} s (wall, from the imports): imports {TIMES['imports']:.1f} s; "
            f"simulator first calls {TIMES['sim first calls']:.1f} s "
            f"({int(TIMES['sim configurations'])} walk configurations, {WARMUP_PATHS} paths each, "
            f"kernel tracing and compilation or kernel-cache loading included); simulator warm "
            f"runs {TIMES['sim warm runs']:.1f} s; model compilation {TIMES['model compile']:.1f} "
            f"s; model evaluation {TIMES['model eval']:.1f} s; model timing "
            f"{TIMES['model timing']:.1f} s; the rest {other:.1f} s"]


def cold_warm(argv):
    """Run this script twice in child processes whose Dr.Jit kernel cache (``$HOME/.drjit``)
    and JAX compilation cache (``FITLAB_CACHE_DIR``) start in a fresh temporary folder: cold,
    then warm. Prints both wall times (spawn to exit) against the 15 s target."""
    tmp = tempfile.mkdtemp(prefix="layered_validation_")
    env = dict(os.environ, HOME=tmp, FITLAB_CACHE_DIR=os.path.join(tmp, "xla"))
    env.pop("XDG_CACHE_HOME", None)
    walls = []
    try:
        for what in ("cold", "warm"):
            log(f"--- {what} run (Dr.Jit kernel cache and JAX compilation cache in {tmp})")
            t0 = time.perf_counter()
            rc = subprocess.call([sys.executable, os.path.abspath(__file__), *argv], env=env)
            walls.append(time.perf_counter() - t0)
            if rc != 0:
                log(f"{what} run failed (exit status {rc})")
                return rc
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for what, w in zip(("cold", "warm"), walls):
        log(f"{what}: {w:.1f} s wall, process spawn to exit (target <= 15 s: "
            f"{'PASS' if w <= 15.0 else 'MISS'})")
    return 0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--estimator", choices=("point", "cone"), default="point",
                    help="point estimates at the arc's directions, the model evaluated there "
                         "(default), or cones of 0.01 sr with the model averaged over them")
    ap.add_argument("--samples", type=int, default=None,
                    help="paths per stack (default 16384 for point estimates, 2,000,000 for "
                         "cones: about the same noise)")
    ap.add_argument("--quick", action="store_true", help="one stack per group (smoke run)")
    ap.add_argument("--out", default=str(OUT), help="output folder")
    ap.add_argument("--render-only", action="store_true",
                    help="rewrite README.md from the folder's results.json without simulating")
    ap.add_argument("--cold-warm", action="store_true",
                    help="run twice in child processes with empty kernel caches: cold, then "
                         "warm; print both wall times")
    args = ap.parse_args(argv)
    if args.cold_warm:
        return cold_warm([a for a in argv if a != "--cold-warm"])
    if args.samples is None:
        args.samples = DEFAULT_SAMPLES[args.estimator]
    TIMES["imports"] = time.perf_counter() - _T_START
    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()  # the models' compiled evaluations, kept for the next run
    out = Path(args.out)
    machine = _machine()
    timing = None
    if args.render_only:
        data = json.loads((out / "results.json").read_text())
        rows, args.samples, machine = data["rows"], data["samples"], data.get("machine", machine)
        args.estimator = data.get("estimator", "cone")
        timing = data.get("timing")
    else:
        rows = run(args.samples, args.quick, args.estimator)
    command = "python benchmarks/layered_validation.py" + (
        f" --estimator {args.estimator}" if args.estimator != "point" else "") + (
        f" --samples {args.samples}" if args.samples != DEFAULT_SAMPLES[args.estimator]
        else "") + (" --quick" if args.quick else "")
    out.mkdir(parents=True, exist_ok=True)
    if not args.render_only:
        try:
            prev = json.loads((out / "results.json").read_text())["rows"]
        except (OSError, ValueError, KeyError):
            prev = None
        if prev is not None:
            for line in _compare_previous(prev, rows):
                log(line)
        timing = {k: round(v, 3) for k, v in TIMES.items()}
        timing["total"] = round(time.perf_counter() - _T_START, 3)
        atomic_write_text(out / "results.json", json.dumps(
            {"samples": args.samples, "theta_i": THETA_I, "estimator": args.estimator,
             "acceptance_sr": ACCEPTANCE_SR if args.estimator == "cone" else None,
             "machine": machine, "timing": timing, "rows": rows}, indent=1))
    atomic_write_text(out / "README.md", markdown(rows, args.samples, machine, command,
                                                  args.estimator))
    if not args.render_only:
        for line in _timing_lines(time.perf_counter() - _T_START):
            log(line)
    log(f"wrote {out / 'README.md'} and results.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
