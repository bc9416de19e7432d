"""Throughput of the GGX rough-dielectric BTDF: fitlab (jitted JAX) against Mitsuba 3 (llvm_ad_rgb).

Pair set: N transmission pairs, float32. ``wi`` is uniform on the upper hemisphere (z > 0, the
outside, where the light is) and ``wo`` uniform on the lower hemisphere (z < 0, inside the
dielectric), both drawn from one seeded NumPy generator. Roughly a fifth of these pairs have a
front-facing generalized half-vector and a nonzero BTDF; the rest evaluate to 0 in both
libraries (both compute every lane anyway).

Both libraries evaluate the same pairs in the same process, on all the CPUs the process may use:

* fitlab: ``fitlab.eval_bsdf("rough_dielectric", {"alpha": a, "eta": eta}, wi, wo)`` on (N, 3)
  float32 device arrays (the public entry point, one jitted XLA computation), forced with
  ``block_until_ready``;
* Mitsuba: ``roughdielectric`` (distribution ggx, sample_visible false, int_ior eta, ext_ior 1)
  ``bsdf.eval(ctx, si, wo)`` on ``mi.Vector3f`` arrays of N (``si.wi`` = wi), forced with
  ``dr.eval`` + ``dr.sync_thread``; each call traces the kernel again and finds it in Dr.Jit's
  kernel cache, which is part of what a Mitsuba caller pays.

The first call of each (tracing + compilation) is timed separately and excluded; Dr.Jit also
keeps compiled kernels on disk (~/.drjit), so its "first call" is a cache hit after the first run
on a machine. Then ``--repeat`` repetitions alternate the two libraries; in each, a library gets
a ``--pause`` of idle time (Dr.Jit's worker threads spin for several ms after each launch, taking
a core from whatever runs next; XLA's park at once), one untimed call (its own workers wake up),
then ``--block`` back-to-back calls timed together. Reported: the median (and the minimum) over the
repetitions of the time per call, pairs/s = N / median, and the ratio of the throughputs.

Conventions mapped before comparing the values: Mitsuba's eval includes |cos θo|, and in radiance
mode its transmitted value carries (η_i/η_o)² = 1/eta² relative to Walter's eq. 21, which fitlab
evaluates; so Mitsuba ≈ fitlab · |cos θo| / eta².

Usage: python benchmarks/bench_btdf_eval.py [--pairs 1000000] [--repeat 21] [--seed 0] [--alpha-y A]
           [--block 5] [--pause 0.05] [--alpha 0.3] [--eta 1.5] [--cores K]
Mitsuba's LLVM backend needs libLLVM (Debian: ``apt-get install libllvm19``); set
DRJIT_LIBLLVM_PATH to use a particular one, otherwise standard library folders are searched.
Exit status: 0 when the two agree, 1 when they do not, 2 when Mitsuba/libLLVM is unavailable.
"""

from __future__ import annotations

import argparse
import glob
import os
import platform
import re
import statistics
import sys
import time

import numpy as np

#: Where Debian/Ubuntu packages put libLLVM (libllvmNN, and the llvm-NN toolchain packages).
_LIBLLVM_GLOBS = (
    "/usr/lib/*-linux-gnu/libLLVM-[0-9]*.so*",
    "/usr/lib/*-linux-gnu/libLLVM.so.[0-9]*",
    "/usr/lib/llvm-[0-9]*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


class MitsubaUnavailable(RuntimeError):
    """Mitsuba 3 or its LLVM backend cannot be loaded (exit status 2 of the script)."""


def find_libllvm() -> str | None:
    """DRJIT_LIBLLVM_PATH if set, else the newest libLLVM in the standard library folders."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]

    def version(path):
        return tuple(int(x) for x in re.findall(r"\d+", os.path.basename(path))) or (0,)

    found = [p for pattern in _LIBLLVM_GLOBS for p in glob.glob(pattern) if os.path.isfile(p)]
    return max(found, key=version) if found else None


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def make_pairs(n: int, seed: int):
    """wi uniform on the upper hemisphere, wo uniform on the lower one; (n, 3) float32 each."""
    rng = np.random.default_rng(seed)

    def hemisphere(sign):
        v = rng.standard_normal((n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        v[:, 2] = sign * np.abs(v[:, 2])
        return v.astype(np.float32)

    return hemisphere(+1.0), hemisphere(-1.0)


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def run(pairs=1_000_000, repeat=21, seed=0, alpha=0.3, eta=1.5, block=5, pause=0.05,
        quiet=False, alpha_y=None):
    """Run the benchmark; returns a dict of the figures (also printed unless ``quiet``)."""
    say = (lambda *a, **k: None) if quiet else print
    libllvm = find_libllvm()
    if libllvm and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm

    import jax
    import jax.numpy as jnp

    import fitlab

    cpus = len(os.sched_getaffinity(0))
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise MitsubaUnavailable(
            f"Mitsuba 3 is not importable ({exc}); install the extra: pip install -e \".[bench]\""
        ) from exc
    try:
        mi.set_variant("llvm_ad_rgb")
        if dr.thread_count() > cpus:
            dr.set_thread_count(cpus)  # Dr.Jit sizes its pool by the machine, not the affinity
    except Exception as exc:  # noqa: BLE001 - re-raised with the fix
        raise MitsubaUnavailable(
            f"Mitsuba's llvm_ad_rgb variant is unavailable ({exc}). Install libLLVM "
            "(Debian: apt-get install libllvm19) or point DRJIT_LIBLLVM_PATH at libLLVM-NN.so"
        ) from exc

    wi_np, wo_np = make_pairs(pairs, seed)
    # isotropic: rough_dielectric (alpha); with alpha_y: rough_dielectric_anisotropic against
    # Mitsuba's alpha_u, alpha_v
    if alpha_y is None:
        model, params, mi_alpha = "rough_dielectric", {"alpha": alpha, "eta": eta}, {"alpha": alpha}
    else:
        model = "rough_dielectric_anisotropic"
        params = {"alpha_x": alpha, "alpha_y": alpha_y, "eta": eta}
        mi_alpha = {"alpha_u": alpha, "alpha_v": alpha_y}

    # ---- fitlab: (N, 3) float32 arrays already on the device --------------------------------
    wi_j, wo_j = jax.device_put(wi_np), jax.device_put(wo_np)

    def fitlab_call():
        return fitlab.eval_bsdf(model, params, wi_j, wo_j).block_until_ready()

    t_first_fl, f_fl = timed(fitlab_call)
    if f_fl.dtype != jnp.float32:
        raise SystemExit(f"fitlab returned {f_fl.dtype} for float32 input")

    # ---- Mitsuba: Vector3f arrays of N, evaluated before timing -------------------------------
    bsdf = mi.load_dict({
        "type": "roughdielectric", "distribution": "ggx", **mi_alpha,
        "int_ior": eta, "ext_ior": 1.0, "sample_visible": False,
    })
    si = dr.zeros(mi.SurfaceInteraction3f, pairs)
    si.wi = mi.Vector3f(wi_np[:, 0], wi_np[:, 1], wi_np[:, 2])
    wo_m = mi.Vector3f(wo_np[:, 0], wo_np[:, 1], wo_np[:, 2])
    ctx = mi.BSDFContext()  # TransportMode.Radiance, all lobes
    dr.eval(si, wo_m)
    dr.sync_thread()

    def mitsuba_call():
        value = bsdf.eval(ctx, si, wo_m)
        dr.eval(value)
        dr.sync_thread()
        return value

    t_first_mi, f_mi = timed(mitsuba_call)

    # ---- timing -------------------------------------------------------------------------------
    def blocks(call):
        call()  # untimed: the library's worker threads wake up
        out = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            for _ in range(block):
                call()
            out.append((time.perf_counter() - t0) / block)
        return out

    load_before = load_average()
    # (1) interleaved: each repetition gives each library a pause (Dr.Jit's idle workers spin for
    # ~20 ms after a launch and would take a core from the next library's calls; XLA's do not
    # spin), one untimed call, then `block` back-to-back calls timed together.
    t_fl, t_mi = [], []
    for _ in range(repeat):
        for call, times in ((fitlab_call, t_fl), (mitsuba_call, t_mi)):
            time.sleep(pause)
            call()
            t0 = time.perf_counter()
            for _ in range(block):
                call()
            times.append((time.perf_counter() - t0) / block)
    # (2) separate: each library alone, `repeat` blocks back to back (steady state).
    time.sleep(pause)
    s_mi = blocks(mitsuba_call)
    time.sleep(pause)
    s_fl = blocks(fitlab_call)
    load_after = load_average()
    med_fl, med_mi = statistics.median(t_fl), statistics.median(t_mi)
    paired = statistics.median(m / f for f, m in zip(t_fl, t_mi))
    sep_fl, sep_mi = statistics.median(s_fl), statistics.median(s_mi)

    # ---- agreement: Mitsuba = fitlab |cos θo| / eta² for these transmission pairs -------------
    ref = np.asarray(f_fl, dtype=np.float64) * np.abs(wo_np[:, 2]) / eta**2
    got = np.asarray(f_mi[0], dtype=np.float64)
    scale = float(np.max(np.abs(ref)))
    significant = np.abs(ref) > 1e-6 * scale
    rel = np.abs(got - ref)[significant] / np.abs(ref)[significant]
    zero_mismatch = int(np.sum(((got > 0) != (ref > 0)) & (np.maximum(got, ref) > 1e-6 * scale)))
    rel_p999 = float(np.percentile(rel, 99.9)) if rel.size else 0.0
    agree = zero_mismatch == 0 and rel_p999 < 1e-3

    res = {
        "pairs": pairs, "repeat": repeat, "seed": seed, "block": block, "pause_s": pause,
        "alpha": alpha, "alpha_y": alpha_y, "model": model, "eta": eta,
        "cpu": cpu_model(), "cpus": cpus,
        "python": platform.python_version(), "jax": jax.__version__,
        "mitsuba": mi.__version__, "drjit": dr.__version__, "libllvm": libllvm,
        "fitlab_first_s": t_first_fl, "mitsuba_first_s": t_first_mi,
        "fitlab_median_s": med_fl, "mitsuba_median_s": med_mi,
        "fitlab_min_s": min(t_fl), "mitsuba_min_s": min(t_mi),
        "fitlab_pairs_per_s": pairs / med_fl, "mitsuba_pairs_per_s": pairs / med_mi,
        "ratio": med_mi / med_fl, "ratio_paired": paired,
        "fitlab_separate_median_s": sep_fl, "mitsuba_separate_median_s": sep_mi,
        "fitlab_separate_pairs_per_s": pairs / sep_fl,
        "mitsuba_separate_pairs_per_s": pairs / sep_mi, "ratio_separate": sep_mi / sep_fl,
        "nonzero": int(np.sum(ref > 0)),
        "rel_err_median": float(np.median(rel)) if rel.size else 0.0,
        "rel_err_p999": rel_p999, "rel_err_max": float(rel.max()) if rel.size else 0.0,
        "zero_mismatch": zero_mismatch, "agree": agree,
        "load_before": load_before, "load_after": load_after,
    }

    say(f"machine : {res['cpu']}, {res['cpus']} CPUs usable; "
        f"load avg {load_before} -> {load_after}")
    say(f"versions: python {res['python']}, jax {res['jax']}, mitsuba {res['mitsuba']}, "
        f"drjit {res['drjit']}, libLLVM {libllvm or '(Dr.Jit default search)'}")
    say(f"pairs   : {pairs:,} float32 transmission pairs (wi z>0, wo z<0, uniform), seed {seed}; "
        f"{model} GGX alpha={alpha}" + (f", alpha_y={alpha_y}" if alpha_y is not None else "")
        + f", eta={eta}; {res['nonzero']:,} nonzero")
    say(f"first call (trace + compile): fitlab {t_first_fl * 1e3:.1f} ms, "
        f"Mitsuba {t_first_mi * 1e3:.1f} ms (Dr.Jit disk cache may hit)")
    say(f"time per call, median (min) over {repeat} blocks of {block} calls: interleaved = the two "
        f"alternating, a {pause * 1e3:.0f} ms pause before each block; separate = each alone, "
        f"blocks back to back")
    say(f"{'':9}{'interleaved ms':>17}{'Mpairs/s':>10}{'separate ms':>17}{'Mpairs/s':>10}")
    for name, ti, ts in (("fitlab", t_fl, s_fl), ("Mitsuba", t_mi, s_mi)):
        mi_, ms_ = statistics.median(ti), statistics.median(ts)
        say(f"{name:9}{mi_ * 1e3:9.2f} ({min(ti) * 1e3:5.2f}){pairs / mi_ / 1e6:10.1f}"
            f"{ms_ * 1e3:9.2f} ({min(ts) * 1e3:5.2f}){pairs / ms_ / 1e6:10.1f}")
    say(f"ratio fitlab/Mitsuba throughput: interleaved {res['ratio']:.2f} (median of "
        f"per-repetition ratios {paired:.2f}), separate {res['ratio_separate']:.2f}; "
        f"target >= 0.5")
    say(f"agreement (Mitsuba vs fitlab |cos θo|/eta², values > 1e-6 max): rel err median "
        f"{res['rel_err_median']:.1e}, 99.9% {rel_p999:.1e}, max {res['rel_err_max']:.1e}; "
        f"zero/nonzero mismatches {zero_mismatch} -> {'OK' if agree else 'MISMATCH'}")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=1_000_000, help="number of pairs (1,000,000)")
    ap.add_argument("--repeat", type=int, default=21, help="timed repetitions of each (21)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random pairs (0)")
    ap.add_argument("--alpha", type=float, default=0.3, help="GGX width α (0.3)")
    ap.add_argument("--eta", type=float, default=1.5, help="n_inside/n_outside (1.5)")
    ap.add_argument("--alpha-y", type=float, default=None,
                    help="anisotropic: width along +y (rough_dielectric_anisotropic with "
                    "alpha_x = --alpha, against Mitsuba's alpha_u, alpha_v)")
    ap.add_argument("--block", type=int, default=5,
                    help="back-to-back calls timed together in each repetition (5)")
    ap.add_argument("--pause", type=float, default=0.05,
                    help="seconds of idle time before each library's turn (0.05)")
    ap.add_argument("--cores", type=int, default=0,
                    help="pin the process to its first K CPUs before loading JAX and Mitsuba "
                         "(default: all it may use)")
    args = ap.parse_args(argv)
    if args.pairs < 1 or args.repeat < 1 or args.block < 1:
        ap.error("--pairs, --repeat and --block must be positive")
    if args.cores:
        cpus = sorted(os.sched_getaffinity(0))[: args.cores]
        os.sched_setaffinity(0, cpus)
        if "drjit" in sys.modules or "jax" in sys.modules:
            print("warning: --cores after JAX/Dr.Jit were loaded may not resize their pools")
    try:
        res = run(args.pairs, args.repeat, args.seed, args.alpha, args.eta, args.block, args.pause,
                  alpha_y=args.alpha_y)
    except MitsubaUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0 if res["agree"] else 1


if __name__ == "__main__":
    sys.exit(main())
