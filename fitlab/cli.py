"""fitlab command line: thin subcommands over the library, one function each, no physics here."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

import fitlab
from fitlab.errors import FitlabError

CONVENTIONS = (
    "frame: normal = +z; directions point away from the surface (wi toward the light, wo toward "
    "the detector); theta from +z (theta > 90 deg = transmission side), phi from +x; values are the "
    "BSDF f in 1/sr without the cosine; angles in degrees in files, radians in code; "
    "alpha = microfacet width (Walter alpha_b / alpha_g); separable Smith G = G1(i)G1(o); "
    "eta = n_inside/n_outside (inside = -z side); BTDF for radiance transport (Walter eq. 21). "
    "Full text: data_formats/CONVENTIONS.md"
)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own usage errors keep exit status 2
        self.print_usage(sys.stderr)
        self.exit(2, f"fitlab: error: {message}\n")


def _parse_assignments(items, what):
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise FitlabError(f"--{what} {item!r} must look like NAME=VALUE")
        if name in out:
            raise FitlabError(f"--{what} {name} is given twice")
        out[name.strip()] = value.strip()
    return out


def _params_from_cli(model, items):
    raw = _parse_assignments(items, "param")
    params = {}
    for name, text in raw.items():
        try:
            params[name] = float(text)
        except ValueError:
            raise FitlabError(f"--param {name}={text!r}: the value must be a number") from None
    try:
        fitlab.api.check_params(model, params)
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None
    return params


# --------------------------------------------------------------------------------------------
# fitlab models
# --------------------------------------------------------------------------------------------


def _model_record(model):
    return {
        "name": model.name,
        "summary": model.summary,
        "lobes": model.lobes,
        "parameters": [p._asdict() for p in model.parameters],
        "options": [{"name": o.name, "choices": list(o.choices), "default": o.default,
                     "description": o.description} for o in model.options],
        "reference": model.reference,
    }


def cmd_models(args):
    names = [args.name] if args.name else list(fitlab.MODELS)
    try:
        models = [fitlab.get_model(n) for n in names]
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if args.json:
        print(json.dumps({"conventions": CONVENTIONS,
                          "models": [_model_record(m) for m in models]}, indent=2))
        return 0
    print(f"Conventions: {CONVENTIONS}\n")
    for m in models:
        print(f"{m.name}: {m.summary}  [{m.lobes}]")
        for p in m.parameters:
            print(f"  --param {p.name}=VALUE   {p.description}; bounds [{p.lower:g}, {p.upper:g}], "
                  f"unit {p.unit}, typical {p.default:g}")
        for o in m.options:
            print(f"  --option {o.name}={'|'.join(o.choices)}   {o.description} "
                  f"(default {o.default})")
        print(f"  source: {m.reference}\n")
    return 0


# --------------------------------------------------------------------------------------------
# fitlab eval
# --------------------------------------------------------------------------------------------


def cmd_eval(args):
    from fitlab.io.directions import read_directions
    from fitlab.io.values_csv import format_values_csv

    try:
        model = fitlab.get_model(args.model)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    params = _params_from_cli(model, args.param)
    try:
        options = fitlab.api.resolve_options(model, _parse_assignments(args.option, "option"))
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None
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


# --------------------------------------------------------------------------------------------


def build_parser():
    parser = _Parser(
        prog="fitlab",
        description="Fit, evaluate and tabulate physically based BSDF models (Walter 2007 "
        "microfacet models and more). Conventions: data_formats/CONVENTIONS.md.",
    )
    parser.add_argument("--version", action="version", version=f"fitlab {fitlab.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("models", help="list the models with their parameters, bounds and conventions",
                       description="List every registry model: parameters (bounds, units), "
                       "options, source equations, and the conventions all models share.")
    p.add_argument("name", nargs="?", help="show only this model")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser(
        "eval", help="evaluate a model's BSDF on a file of direction pairs",
        description="Evaluate a registry model's BSDF f (1/sr, without cosine) at the direction "
        "pairs of a CSV file with columns theta_i, phi_i, theta_o, phi_o in degrees "
        "(data_formats/directions_csv.md). Output: the same rows with a 'value' column "
        "(data_formats/values_csv.md).",
        epilog="example: fitlab eval rough_dielectric --param alpha=0.3 --param eta=1.5 "
        "--directions data_formats/examples/directions_inplane.csv --out f.csv",
    )
    p.add_argument("model", help="model name (see `fitlab models`)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a model parameter; give every parameter of the model")
    p.add_argument("--option", action="append", metavar="NAME=VALUE",
                   help="a model option, e.g. distribution=beckmann")
    p.add_argument("--directions", required=True, metavar="FILE.csv", help="direction pairs")
    p.add_argument("--out", metavar="FILE.csv", help="output file (default: standard output)")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                   help="evaluation precision (default float64)")
    p.set_defaults(func=cmd_eval)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except FitlabError as exc:
        print(f"fitlab {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
