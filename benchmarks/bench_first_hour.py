"""The first hour on real data (issue 34, item 3d): two long commands, this fitlab against the
commit before the work (the named peer: a git worktree of that commit, run by the same Python in
the same run, interleaved), wall time from spawning each process to its exit.

* **film**: the RGL film's joint fit, ``fitlab fit ../shared/data/rgl_epfl_via_fzy28/
  aurora_white_rgb.bsdf --model lambertian+rough_conductor --share alpha`` (fits/README.md,
  "Film: RGL Aurora White"; target ≥ 3× faster at the same intervals within 5%). Its k ends at
  its bound 0 in every channel, so this fitlab skips the bootstrap there (fit_json.md); the same
  fit with ``--fix k=0`` runs the bootstrap on both sides (this fitlab: as many refits as its
  intervals need), and its 68% bootstrap bounds are compared (largest |Δ bound| / the before
  side's width), as are the least-squares values and standard errors of both commands.
* **compare**: three candidates on brown vinyl, the first three of fits/README.md's
  ``compare_brown_vinyl_refit`` command (``lambertian+rough_conductor``, the coated Lambertian,
  Weidlich–Wilkie; ``--fit-subset 'value > 0.01 and theta_o < 83' --no-mcmc``; target ≥ 3×),
  first with an empty compilation cache per side, then again with the cache it filled.

Usage: python benchmarks/bench_first_hour.py --before /tmp/before [--only film|compare]
        [--film ../shared/data/rgl_epfl_via_fzy28/aurora_white_rgb.bsdf]
(make the worktree with ``git worktree add /tmp/before <commit>``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import ROOT, load_average, machine, machine_line  # noqa: E402

FILM = ROOT.parent / "shared" / "data" / "rgl_epfl_via_fzy28" / "aurora_white_rgb.bsdf"
VINYL = ROOT / "data_formats" / "examples" / "zemax_brown_vinyl.bsdf"
FILM_ARGS = ["--model", "lambertian+rough_conductor", "--share", "alpha"]
COMPARE_ARGS = [
    "--model", "lambertian+rough_conductor",
    "--model", "coated(lambertian,specular=lobe) --option interreflection=closed_form "
               "--fix coat_eta=1.5 --fix coat_tau=0",
    "--model", "weidlich_wilkie(lambertian) --fix k1=0 --fix tau1=0",
    "--fit-subset", "value > 0.01 and theta_o < 83", "--no-mcmc", "--no-report", "--no-fits"]


def run(root: Path, argv, cache: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds: user + system) of ``python -m fitlab.cli ARGV`` with fitlab
    taken from ``root``. On a shared machine the CPU time is the steadier figure."""
    env = {**os.environ, "PYTHONPATH": str(root), "FITLAB_CACHE_DIR": str(cache)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "fitlab.cli", *map(str, argv), "--quiet"],
                          env=env, cwd=root, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{root}: {' '.join(map(str, argv))} failed:\n{proc.stderr[-3000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def intervals(path: Path) -> dict:
    """{(channel, parameter): (value, stderr, bootstrap p16, p84 or None)} of a fit file."""
    rec = json.loads(path.read_text(encoding="utf-8"))
    out = {}
    for f in rec["fits"]:
        for name, p in f["parameters"].items():
            if not p["fixed"]:
                b = p.get("bootstrap") or {}
                out[f["channel"], name] = (p["value"], p.get("stderr"), b.get("p16"),
                                           b.get("p84"))
    return out, rec


def compare_fits(before: Path, after: Path) -> str:
    a, _ = intervals(before)
    b, rec = intervals(after)
    dv = max(abs(b[k][0] - a[k][0]) / max(abs(a[k][0]), 1e-300) for k in a)
    ds = max(abs(b[k][1] - a[k][1]) / a[k][1] for k in a if a[k][1])
    text = f"LS values within {dv:.1e} (relative), standard errors within {ds:.1e}"
    boots = [k for k in a if a[k][2] is not None and b[k][2] is not None]
    if boots:
        worst = max(max(abs(b[k][2] - a[k][2]), abs(b[k][3] - a[k][3]))
                    / max(a[k][3] - a[k][2], 1e-300) for k in boots)
        text += (f"; bootstrap 68% bounds: largest |Δ| = {100 * worst:.1f}% of the interval's "
                 f"width over {len(boots)} parameters")
    elif any(a[k][2] is not None for k in a):
        text += "; bootstrap intervals: before only (this fitlab skipped the bootstrap)"
    boot = rec["fits"][0].get("bootstrap") or {}
    text += (f"; this fitlab's bootstrap: {boot.get('refits')} refits, {boot.get('stop_reason')}"
             if boot.get("stop_reason") else
             f"; this fitlab's bootstrap: skipped ({boot.get('skipped_status')})"
             if boot.get("skipped") else "")
    return text


def compare_rankings(before: Path, after: Path) -> str:
    """The two comparisons' rankings and their largest differences of held-out and in-sample
    error."""
    a, b = (json.loads(p.read_text(encoding="utf-8"))["channels"][0] for p in (before, after))
    dcv = max(abs(x["cv"]["rms_relative_error"] - y["cv"]["rms_relative_error"])
              for x, y in zip(a["models"], b["models"]))
    dfold = max(abs(p - q) for x, y in zip(a["models"], b["models"])
                for p, q in zip(x["cv"]["per_incidence"], y["cv"]["per_incidence"]))
    dins = max(abs(x["in_sample"]["rms_relative_error"] - y["in_sample"]["rms_relative_error"])
               for x, y in zip(a["models"], b["models"]))
    return (f"CV ranking before {a['ranking']['cv']}, after {b['ranking']['cv']}; held-out RMS "
            f"relative error differs by {dcv:.2g} at most (per incidence {dfold:.2g}), "
            f"in-sample by {dins:.2g} (the in-sample rule is now the fit file's)")


def case(name, argv_of, before: Path, work: Path, runs=("cold",)) -> list:
    out = []
    for kind in runs:
        times = {}
        for side, root in (("before", before), ("after", ROOT)):
            cache = work / f"cache_{name}_{side}"  # empty at the first run, then filled
            times[side] = run(root, argv_of(work / f"{name}_{side}"), cache)
            print(f"  {name} ({kind}), {side}: wall {times[side][0]:.1f} s, CPU "
                  f"{times[side][1]:.1f} s   [load {load_average()}]", flush=True)
        for k, what in enumerate(("wall", "CPU")):
            ratio = times["before"][k] / times["after"][k]
            print(f"{name} ({kind}, {what}): before {times['before'][k]:.1f} s, this fitlab "
                  f"{times['after'][k]:.1f} s: {ratio:.2f}x (target >= 3x: "
                  f"{'met' if ratio >= 3 else 'NOT met'})", flush=True)
        out.append((kind, times))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, type=Path, help="worktree of the commit before")
    ap.add_argument("--film", type=Path, default=FILM)
    ap.add_argument("--only", choices=("film", "compare"))
    args = ap.parse_args()
    print(machine_line(machine()))
    print(f"load average at the start: {load_average()}; before = {args.before}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.only in (None, "film"):
            for label, extra in (("film", []), ("film_fix_k", ["--fix", "k=0"])):
                case(label, lambda out, extra=extra: ["fit", args.film, *FILM_ARGS, *extra,
                                                      "--out", f"{out}.json"],
                     args.before, work)
                print(f"{label}: " + compare_fits(work / f"{label}_before.json",
                                                  work / f"{label}_after.json"), flush=True)
        if args.only in (None, "compare"):
            case("compare", lambda out: ["compare", VINYL, *COMPARE_ARGS, "--out", out],
                 args.before, work, runs=("cold", "cached"))
            print("compare: " + compare_rankings(work / "compare_before" / "compare.json",
                                                 work / "compare_after" / "compare.json"))
    print(f"load average at the end: {load_average()}")


if __name__ == "__main__":
    main()
