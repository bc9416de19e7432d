"""fitlab simulate: Monte Carlo ground truth of a layer stack (scene TOML) as a measurement CSV."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_quiet
from fitlab.errors import FitlabError
from fitlab.simulate.simulator import DEVICES


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
        "skipped (and why), samples and seed (the same scene, samples, seed and batch size give "
        "the same bytes; the run time is printed, not stored), so `fitlab fit OUT.csv --model "
        "...` works on it. Progress on stderr; the output is written atomically.",
        epilog="example: fitlab simulate data_formats/examples/scenes/rough_dielectric_interface.toml "
        "--samples 200000 --out sim.csv && fitlab fit sim.csv --model rough_dielectric",
    )
    p.add_argument("scene", metavar="SCENE.toml", help="scene file (data_formats/scene_toml.md)")
    p.add_argument("--samples", type=int, required=True,
                   help="paths traced per incident direction (the standard error falls as 1/sqrt)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed; the same seed and --batch-size give the same numbers "
                   "(default 0)")
    p.add_argument("--out", metavar="FILE.csv", help="output measurement CSV (default: standard output)")
    p.add_argument("--split-bounces", action="store_true",
                   help="also write FILE.orders.csv with the bounce-order components (order 0 = top "
                   "surface, 1 = one-bounce subsurface, 2, rest) as channels")
    p.add_argument("--batch-size", type=int, default=1 << 13,
                   help="paths traced in parallel (lanes); with 32 lanes' worth of paths per "
                   "compiled call it bounds the memory (default 8192)")
    p.add_argument("--device", choices=DEVICES, default="auto",
                   help="where the walk runs: auto (JAX's default device: a GPU when JAX has "
                   "one), cpu, or gpu (an error when JAX sees none; install a CUDA build of "
                   "jaxlib, e.g. pip install 'jax[cuda12]'); results are reproducible per device")
    add_quiet(p)
    return p


def run(args):
    from pathlib import Path

    from fitlab.io.atomic import atomic_write_text
    from fitlab.io.files import path_for_record
    from fitlab.io.measurement import format_measurement_csv
    from fitlab.simulate import derive_effects, load_scene, simulate

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
    extra = {"scatter": res.metadata()["scatter"],
             "scene": path_for_record(args.scene, args.out or "stdout")}
    text = format_measurement_csv(m, extra)
    if args.out:
        atomic_write_text(args.out, text)
        written = [args.out]
        if args.split_bounces:
            orders_path = str(Path(args.out).with_suffix("")) + ".orders.csv"
            atomic_write_text(orders_path, format_measurement_csv(res.to_measurement(orders=True),
                                                                  extra))
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
