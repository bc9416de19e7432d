"""fitlab simulate: Monte Carlo ground truth of a layer stack (scene TOML) as a measurement CSV."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_quiet
from fitlab.errors import FitlabError
from fitlab.simulate.protocol import DEVICES, LAUNCH_PATHS as BATCH_SIZE


def add_parser(sub):
    p = sub.add_parser(
        "simulate", help="Monte Carlo ground truth of a layer stack (scene TOML) as measurement CSV",
        description="Trace a vectorized Monte Carlo random walk (JAX) through the layer stack of "
        "SCENE.toml (data_formats/scene_toml.md): rough or smooth dielectric interfaces (GGX, "
        "Beckmann, vMF with the exact masking of its NDF unless masking = \"approx\" asks for "
        "the extended-NDF paper's eq. 8), absorbing and scattering media (isotropic, Henyey-Greenstein, SGGX "
        "microflakes), Lambertian / conductor / dielectric substrates. Only the effects the scene "
        "asks for are compiled and traced (observed hemispheres, bounce limit, absorption, volume "
        "scattering none/single/multiple, delta transmission, mono/RGB), and fitlab derives more "
        "from the scene itself (no medium: no volume code; sigma_a = 0: no attenuation; grey: one "
        "channel; opaque substrate: no transmitted paths). Writes a measurement CSV "
        "(data_formats/measurement_csv.md): value = BSDF in 1/sr averaged over each bin or "
        "cone, or with the detector's estimator = \"point\" a point estimate at each exact "
        "direction (next-event estimation), sigma = Monte Carlo standard error, metadata with the effects simulated and "
        "skipped (and why), samples and seed (the same scene, samples and seed give "
        "the same bytes on one device; the run time is printed, not stored), so `fitlab fit OUT.csv --model "
        "...` works on it. Progress on stderr; the output is written atomically.",
        epilog="example: fitlab simulate data_formats/examples/scenes/rough_dielectric_interface.toml "
        "--samples 200000 --out sim.csv && fitlab fit sim.csv --model rough_dielectric; "
        "fitlab simulate --sweep data_formats/examples/sweeps/coated_lambertian_grid.toml "
        "--out-dir sweep/ --workers 2",
    )
    p.add_argument("scene", metavar="SCENE.toml", nargs="?",
                   help="scene file (data_formats/scene_toml.md); not with --sweep")
    p.add_argument("--samples", type=int,
                   help="paths traced per incident direction (the standard error falls as "
                   "1/sqrt); required with SCENE.toml (a sweep file states its own)")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed; the same seed gives the same numbers on one device "
                   "(default 0; a sweep file states its own)")
    p.add_argument("--out", metavar="FILE.csv", help="output measurement CSV (default: standard output)")
    p.add_argument("--split-bounces", action="store_true",
                   help="also write FILE.orders.csv with the bounce-order components (order 0 = top "
                   "surface, 1 = one-bounce subsurface, 2, rest) as channels")
    p.add_argument("--batch-size", type=int, default=BATCH_SIZE,
                   help="paths per launch of the compiled walk: bounds the memory (default "
                   f"{BATCH_SIZE}); the numbers do not depend on it")
    p.add_argument("--device", choices=DEVICES, default="auto",
                   help="where the walk runs: auto (Dr.Jit's CUDA backend when a GPU is usable, "
                   "else its LLVM backend on every CPU core), cpu, or gpu (an error when no GPU "
                   "is usable); results are reproducible per device")
    g = p.add_argument_group(
        "parameter sweeps (data_formats/sweep_toml.md; needs pip install 'fitlab[distributed]')")
    g.add_argument("--sweep", metavar="SWEEP.toml",
                   help="simulate every point of a grid of scene parameters into --out-dir "
                   "(DIR/point_NNNNN.csv each, DIR/index.csv); chunks of points run on Dask "
                   "workers, resumable (a rerun skips the chunks done)")
    g.add_argument("--out-dir", metavar="DIR", help="with --sweep: the output folder")
    g.add_argument("--workers", type=int, metavar="N",
                   help="with --sweep: worker processes of an embedded Dask LocalCluster "
                   "(default 2; 1 runs the chunks in this process)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="with --sweep: send the chunks to a running Dask scheduler "
                   "(tcp://HOST:8786; its workers need fitlab and the same --out-dir path)")
    g.add_argument("--points-per-chunk", type=int, metavar="N",
                   help="with --sweep: points per task (default: the sweep file's, else 8)")
    add_quiet(p)
    return p


def _run_sweep(args):
    """fitlab simulate --sweep SWEEP.toml --out-dir DIR: fitlab.simulate.sweep.run_sweep."""
    import time

    from fitlab.simulate.sweep import load_sweep, run_sweep

    used = [flag for flag, v in (("SCENE.toml", args.scene), ("--samples", args.samples),
                                 ("--seed", args.seed), ("--out", args.out),
                                 ("--split-bounces", args.split_bounces)) if v]
    if used:
        raise FitlabError(f"--sweep: the sweep file states the scene, samples and seed, and each "
                          f"point is written to --out-dir; not with {', '.join(used)}")
    if not args.out_dir:
        raise FitlabError("--sweep needs --out-dir DIR (a measurement CSV per point goes there)")
    if args.device != "auto":
        raise FitlabError("--sweep runs on the workers' default device; leave out --device")
    if args.workers is not None and args.scheduler:
        raise FitlabError("give --workers (a local cluster) or --scheduler (a running one), "
                          "not both")
    if args.workers is not None and args.workers < 1:
        raise FitlabError("--workers must be at least 1")
    sweep = load_sweep(args.sweep)
    if not args.quiet:
        print(f"simulate: sweep {sweep.name}: {len(sweep.points)} points of "
              f"{', '.join(sweep.keys)}; {sweep.samples} paths per incidence each", file=sys.stderr)
    t0 = time.perf_counter()
    s = run_sweep(sweep, args.out_dir, workers=args.workers or 2, scheduler=args.scheduler,
                  points_per_chunk=args.points_per_chunk, progress=not args.quiet)
    if not args.quiet:
        print(f"simulate: {s['points']} points in {s['chunks']} chunks: {s['done_now']} chunks "
              f"simulated now, {s['done_before']} done before, in {time.perf_counter() - t0:.1f} s"
              + (f"; {s['truncated']} paths truncated" if s["truncated"] else "")
              + f"; wrote {s['index']}", file=sys.stderr)
    return 0


def run(args):
    from pathlib import Path

    from fitlab.io.atomic import atomic_write_text
    from fitlab.io.files import path_for_record
    from fitlab.simulate import derive_effects, load_scene, simulate

    if args.sweep:
        return _run_sweep(args)
    sweep_only = [flag for flag, v in (("--out-dir", args.out_dir), ("--workers", args.workers),
                                       ("--scheduler", args.scheduler),
                                       ("--points-per-chunk", args.points_per_chunk)) if v]
    if sweep_only:
        raise FitlabError(f"{', '.join(sweep_only)} go with --sweep SWEEP.toml")
    if not args.scene:
        raise FitlabError("give a scene file (SCENE.toml) or --sweep SWEEP.toml")
    if args.samples is None:
        raise FitlabError("--samples is required: paths traced per incident direction")
    args.seed = 0 if args.seed is None else args.seed
    if args.samples < 2:
        raise FitlabError("--samples must be at least 2 (a standard error needs two paths)")
    if args.batch_size < 1:
        raise FitlabError("--batch-size must be a positive number of paths")
    if args.split_bounces and not args.out:
        raise FitlabError("--split-bounces needs --out FILE.csv: the split goes to FILE.orders.csv")
    if args.out and not Path(args.out).parent.exists():
        raise FitlabError(f"--out {args.out}: the folder {Path(args.out).parent} does not exist; "
                          "create it first")
    scene = load_scene(args.scene)
    if not args.quiet:
        plan = derive_effects(scene)
        for line in plan.describe().splitlines():
            print(f"simulate: {line}", file=sys.stderr)
    res = simulate(scene, args.samples, args.seed, batch_size=args.batch_size,
                   progress=not args.quiet, device=args.device)
    m = res.to_measurement()
    # The scene as the output names files: relative to its folder (standard output: the working
    # folder), never an absolute path of this machine.
    scene_record = path_for_record(args.scene, args.out or "stdout")
    text = res.csv_text(scene_record)
    if args.out:
        atomic_write_text(args.out, text)
        written = [args.out]
        if args.split_bounces:
            orders_path = str(Path(args.out).with_suffix("")) + ".orders.csv"
            atomic_write_text(orders_path, res.csv_text(scene_record, orders=True))
            written.append(orders_path)
    else:
        sys.stdout.write(text)
        written = []
    if not args.quiet:
        print(f"simulate: {res.samples} paths per incidence x {len(res.incidences)} incidences in "
              f"{res.time_s:.2f} s ({res.paths_per_s:,.0f} paths/s); {m.n} rows"
              + (f", {m.metadata['empty_bins']} empty bins left out" if m.metadata["empty_bins"] != "0" else "")
              + (f"; {res.truncated} paths truncated" if res.truncated else "")
              + (f"; wrote {' and '.join(written)}" if written else ""), file=sys.stderr)
    return 0
