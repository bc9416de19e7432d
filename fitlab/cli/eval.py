"""fitlab eval: a model's BSDF at the direction pairs of a file."""

from __future__ import annotations

import sys

import numpy as np

import fitlab
from fitlab.cli.common import RGB, add_channel, add_option, add_param, model_from_args


def add_parser(sub):
    from fitlab.models.presets import PRESETS

    p = sub.add_parser(
        "eval", help="evaluate a model's BSDF on a file of direction pairs",
        description="Evaluate a registry model's BSDF f (1/sr, without cosine) at the direction "
        "pairs of a CSV file with columns theta_i, phi_i, theta_o, phi_o in degrees "
        "(data_formats/directions_csv.md). Output: the same rows with a 'value' column "
        "(data_formats/values_csv.md).",
        epilog="examples: fitlab eval rough_dielectric --param alpha=0.3 --param eta=1.5 "
        "--directions data_formats/examples/directions_inplane.csv --out f.csv; "
        "fitlab eval --preset copper_patina --channel G --directions "
        "data_formats/examples/directions_inplane.csv",
    )
    p.add_argument("model", nargs="?", help="model name (see `fitlab models`); layered models "
                   "as coated(INNER), weidlich_wilkie(BASE[,layers=K]) or thin_layer(BOTTOM); "
                   "optional with --preset")
    add_param(p, "a model parameter; give every parameter of the model (with --preset: "
              "overrides the preset's value)")
    p.add_argument("--preset", metavar="NAME",
                   help=f"parameters and model of a named material ({', '.join(PRESETS)}; "
                   "listed with their sources by `fitlab models`); needs --channel")
    add_channel(p, "with --preset: the colour channel whose values to use", choices=RGB)
    add_option(p)
    p.add_argument("--directions", required=True, metavar="FILE.csv", help="direction pairs")
    p.add_argument("--out", metavar="FILE.csv", help="output file (default: standard output)")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                   help="evaluation precision (default float64)")
    return p


def run(args):
    from fitlab.io.directions import read_directions
    from fitlab.io.values_csv import format_values_csv

    model, params, options = model_from_args(args)
    pairs = read_directions(args.directions)
    wi, wo = pairs.cartesian()
    dtype = np.float32 if args.dtype == "float32" else np.float64
    f = np.asarray(fitlab.eval_bsdf(model.name, params, wi.astype(dtype), wo.astype(dtype), options))
    text = format_values_csv(pairs, f, model=model.name, params=params, options=options,
                             source=args.directions, dtype=args.dtype)
    if args.out:
        from fitlab.io.atomic import atomic_write_text

        atomic_write_text(args.out, text)
        print(f"wrote {len(f)} values of {model.name} to {args.out} "
              f"(f in 1/sr; min {f.min():.6g}, max {f.max():.6g})", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0
