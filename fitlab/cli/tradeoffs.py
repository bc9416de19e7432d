"""fitlab tradeoffs: what each accuracy knob costs in time, measured for one material."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_model, add_option, add_quiet, material_arguments
from fitlab.errors import FitlabError


def add_parser(sub):
    from fitlab.tradeoffs.knobs import KNOBS

    knobs = "; ".join(f"{k.name} ({k.group})" for k in KNOBS.values())
    p = sub.add_parser(
        "tradeoffs", help="measure what each accuracy knob costs in time for one material "
        "(HTML + JSON report)",
        description="For a fit (FIT.json) or a registry model with parameters, measure every "
        "knob's error against a stated reference and its time, on this machine in one run: "
        "evaluation (float32 vs float64, Fresnel and masking approximations the model offers), "
        "layered physics against the simulator of the same stack, lookup tables (size, half or "
        "float, axis mapping) and the albedo's quadrature order, Monte Carlo (sampled albedo, "
        "simulator paths, MCMC length on the fit's data). Errors: relative error of f·cos over "
        "the measured directions (else a standard hemisphere grid), albedo error, PSNR/SSIM of "
        "lobe images (scikit-image). Writes DIR/index.html (Pareto plot of error vs time, the "
        "table, a recommendation per use case), DIR/tradeoffs.json "
        "(data_formats/tradeoffs_json.md) and DIR/pareto.png/.svg, atomically. Progress on "
        f"stderr. Knobs: {knobs}.",
        epilog="examples: fitlab tradeoffs fits/walter_rough_glass.json --out "
        "reports/accuracy_cost/walter_rough_glass/; fitlab tradeoffs --model rough_conductor "
        "--param alpha=0.2 --param n=0.2 --param k=3.9 --knob tables --knob Fresnel --out tr/; "
        "fitlab tradeoffs --preset fabric --out tr-fabric/",
    )
    p.add_argument("fit", nargs="?", metavar="FIT.json",
                   help="parameter file written by `fitlab fit --out` (or give --model)")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder (created)")
    add_model(p, help="measure this registry model instead of a fit (see `fitlab models`)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a parameter of --model: NAME=V, or NAME=R,G,B; give every parameter")
    add_option(p, "an option of --model, e.g. fresnel=schlick")
    p.add_argument("--preset", metavar="NAME",
                   help="a SpongeCake preset (fabric, plant_leaf, ...: `fitlab models` lists "
                   "them) with its R, G, B parameters, instead of FIT.json or --model")
    p.add_argument("--data", metavar="FILE",
                   help="the measurement whose directions the errors are measured on (default: "
                   "the fit's data file when found; else a standard hemisphere grid)")
    p.add_argument("--knob", action="append", metavar="NAME",
                   help="measure only this knob (repeatable; default: every knob)")
    p.add_argument("--quick", action="store_true",
                   help="fewer table sizes, samples and MCMC lengths (a few minutes at most)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    add_quiet(p, help="no progress or summary on the terminal")
    return p


def run(args):
    from fitlab.export.material import ExportError
    from fitlab.tradeoffs import tradeoffs

    params, options = material_arguments(args, ("fit", "model", "preset"))
    try:
        res = tradeoffs(args.fit, model=args.model, params=params, options=options,
                        preset=args.preset, data=args.data, knobs=args.knob,
                        quick=args.quick, seed=args.seed, progress=not args.quiet,
                        out=args.out)
    except ExportError as exc:
        raise FitlabError(str(exc)) from None
    if not args.quiet:
        for ch, fe in (res.material.get("fit_error") or {}).items():
            print(f"the fit's own error, channel {ch}: {fe['text']}", file=sys.stderr)
        for use, line in res.recommendations.items():
            print(f"{use}: {line}", file=sys.stderr)
        print(f"wrote {args.out}/index.html and tradeoffs.json", file=sys.stderr)
    return 0
