"""fitlab command line: thin subcommands over the library, one function each, no physics here."""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

import fitlab
from fitlab.assignments import parse_assignments
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


def _params_from_cli(model, items, base=None):
    raw = parse_assignments(items, "param")
    params = dict(base or {})  # e.g. a preset's values, which --param overrides
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
    if not args.name:
        print("Models add up with '+': e.g. lambertian+rough_conductor is f_lambertian + "
              "f_rough_conductor (`fitlab models lambertian+rough_conductor` lists its "
              "parameters).\n")
        print("Layered models take a model as argument: coated(INNER) puts any model (sums "
              "too) under a smooth dielectric coat, coated(INNER,specular=lobe) adds a narrow "
              "coat lobe; weidlich_wilkie(BASE[,layers=K]) stacks K-1 microfacet interfaces "
              "over a lambertian, oren_nayar or rough_conductor base "
              "(data_formats/layered_models.md).\n")
    for m in models:
        print(f"{m.name}: {m.summary}  [{m.lobes}]")
        for p in m.parameters:
            print(f"  --param {p.name}=VALUE   {p.description}; bounds [{p.lower:g}, {p.upper:g}], "
                  f"unit {p.unit}, typical {p.default:g}")
        for o in m.options:
            print(f"  --option {o.name}={'|'.join(o.choices)}   {o.description} "
                  f"(default {o.default})")
        for pr in _presets_of(m):
            values = ", ".join(f"{k}={'/'.join(f'{x:g}' for x in v) if isinstance(v, tuple) else f'{v:g}'}"
                               for k, v in pr.params.items())
            print(f"  --preset {pr.name} --channel R|G|B   {values} (R/G/B)\n"
                  f"      {pr.description}")
        print(f"  source: {m.reference}\n")
    return 0


def _presets_of(model):
    from fitlab.models.presets import PRESETS

    return [p for p in PRESETS.values() if fitlab.get_model(p.model).name == model.name]


# --------------------------------------------------------------------------------------------
# fitlab eval
# --------------------------------------------------------------------------------------------


def _preset_from_cli(args):
    """(model name, parameters, options) of --preset NAME --channel C (eval), or Nones."""
    if not getattr(args, "preset", None):
        return args.model, {}, {}
    from fitlab.models.presets import get_preset, preset_params

    try:
        preset = get_preset(args.preset)
        if args.model and fitlab.get_model(args.model).name != fitlab.get_model(preset.model).name:
            raise FitlabError(f"--preset {args.preset} is a {preset.model} preset, not "
                              f"{args.model}; leave out the model name")
        if not args.channel:
            raise FitlabError(f"--preset {args.preset} needs --channel R, G or B (its values "
                              "differ per channel; `fitlab models` lists them)")
        return preset.model, preset_params(args.preset, args.channel), dict(preset.options)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None


def _model_from_cli(args):
    """(model, params, options) from --model/model (or --preset/--channel), --param, --option."""
    name, base_params, base_options = _preset_from_cli(args)
    if not name:
        raise FitlabError("give a model name (see `fitlab models`) or --preset NAME")
    try:
        model = fitlab.get_model(name)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    params = _params_from_cli(model, args.param, base_params)
    try:
        options = fitlab.api.resolve_options(
            model, {**base_options, **parse_assignments(args.option, "option")})
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None
    return model, params, options


def cmd_eval(args):
    from fitlab.io.directions import read_directions
    from fitlab.io.values_csv import format_values_csv

    model, params, options = _model_from_cli(args)
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
# fitlab fit
# --------------------------------------------------------------------------------------------


def _fixed_from_cli(model, items):
    fixed = {}
    for name, text in parse_assignments(items, "fix").items():
        if name not in model.parameter_names:
            raise FitlabError(f"--fix {name}: model {model.name!r} has no parameter {name!r} "
                              f"(its parameters: {', '.join(model.parameter_names)})")
        try:
            fixed[name] = float(text)
        except ValueError:
            raise FitlabError(f"--fix {name}={text!r}: the value must be a number") from None
    try:
        fitlab.api.check_params(model, {**{p.name: p.default for p in model.parameters}, **fixed})
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    return fixed


def _print_summary(record):
    for fit in record["fits"]:
        print(f"channel {fit['channel']}:", file=sys.stderr)
        for name, p in fit["parameters"].items():
            if p["fixed"]:
                print(f"  {name:>8} = {p['value']:.6g} (fixed)", file=sys.stderr)
                continue
            line = f"  {name:>8} = {p['value']:.6g} ± {p['stderr'] or float('nan'):.2g} (LS)"
            post = p.get("posterior")
            if post:
                line += (f";  posterior median {post['median']:.6g}, 68% "
                         f"[{post['p16']:.6g}, {post['p84']:.6g}]")
            print(line, file=sys.stderr)
        st = fit["statistics"]
        if st.get("chi2_per_dof") is not None:
            print(f"  chi2/dof = {st['chi2_per_dof']:.3f}", file=sys.stderr)
        print(f"  RMS relative error (fitted rows) = {st['rms_relative_error_fit']:.4f}",
              file=sys.stderr)
        for row in st["per_incidence"]:
            err = row["rms_relative_error"]
            line = (f"    theta_i = {row['theta_i']:6.2f}  phi_i = {row['phi_i']:6.2f}  "
                    f"{row['role']:>10}  n = {row['n']:4d}  RMS rel. error = "
                    f"{'n/a' if err is None else f'{err:.4f}'}")
            if row["role"] == "partly fit" and row["rms_relative_error_fitted_rows"] is not None:
                line += f" (fitted rows {row['rms_relative_error_fitted_rows']:.4f})"
            print(line, file=sys.stderr)


def cmd_fit(args):
    import time

    from fitlab.fit.cache import enable_compilation_cache

    enable_compilation_cache()  # before any computation; FITLAB_NO_CACHE=1 turns it off
    from fitlab.export.paramfile import build_record, chains_payload, write_fit
    from fitlab.fit.driver import fit_measurement
    from fitlab.fit.subset import subset_mask
    from fitlab.io.formats import read_any

    t0 = time.perf_counter()
    try:
        model = fitlab.get_model(args.model)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    try:
        options = fitlab.api.resolve_options(model, parse_assignments(args.option, "option"))
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None
    fixed = _fixed_from_cli(model, args.fix)
    for name in args.free or []:
        if name not in model.parameter_names:
            raise FitlabError(f"--free {name}: model {model.name!r} has no parameter {name!r}")
    if args.chain and not args.mcmc:
        raise FitlabError("--chain needs --mcmc: there is no chain to write")
    if args.report and not args.out:
        raise FitlabError("--report needs --out FILE.json: the report is built from the "
                          "parameter file")
    if args.mcmc and args.mcmc_steps < 100:
        raise FitlabError("--mcmc-steps must be at least 100")
    m = read_any(args.data, args.format)
    t_read = time.perf_counter() - t0
    subset = subset_mask(args.fit_subset, m) if args.fit_subset else None
    channels = None
    if args.channel:
        if args.channel not in m.channel_names:
            raise FitlabError(f"--channel {args.channel}: {args.data} has channels "
                              f"{', '.join(m.channel_names)}")
        channels = [m.channel_names.index(args.channel)]
    try:
        result = fit_measurement(m, model.name, options=options, fixed=fixed, free=args.free or (),
                                 loss=args.loss, subset=subset, mcmc=args.mcmc,
                                 mcmc_steps=args.mcmc_steps, mcmc_walkers=args.walkers,
                                 seed=args.seed, n_starts=args.starts, quiet=args.quiet,
                                 channels=channels)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    for note in result["notes"]:
        if not args.quiet:
            print(f"note: {note}", file=sys.stderr)
    timings = {"read": t_read, "total": time.perf_counter() - t0}
    record = build_record(result, m, subset_expr=args.fit_subset, timings=timings)
    if args.walter_diagnostics:
        from fitlab.fit.walter import add_empirical_D

        add_empirical_D(record, result, m)
    chains = chains_payload(result) if args.chain else None
    if args.out:
        write_fit(args.out, record, chains, args.chain)
        if not args.quiet:
            _print_summary(record)
            print(f"wrote {args.out}" + (f" and {args.chain}" if args.chain else ""),
                  file=sys.stderr)
        if args.report:
            from fitlab.report import build_report

            summary = build_report(args.out, args.report, data_path=args.data,
                                   chain_path=args.chain, progress=not args.quiet)
            if not args.quiet:
                print(f"wrote the report {summary['index']}", file=sys.stderr)
    else:
        if chains:
            from fitlab.io.atomic import atomic_open
            import io as _io

            buf = _io.BytesIO()
            np.savez_compressed(buf, **chains)
            with atomic_open(args.chain, "wb") as fh:
                fh.write(buf.getvalue())
        if not args.quiet:
            _print_summary(record)
        print(json.dumps(record, indent=2, allow_nan=False))
    return 0


# --------------------------------------------------------------------------------------------
# fitlab report
# --------------------------------------------------------------------------------------------


def cmd_report(args):
    from fitlab.report import build_report

    summary = build_report(args.fit, args.out, data_path=args.data, chain_path=args.chain,
                           luts=args.lut or (), discover_luts=not args.no_lut_discovery,
                           progress=not args.quiet)
    if not args.quiet:
        print(f"open {summary['index']} in a browser (self-contained; "
              f"{len(summary['figures'])} figures also as PNG and SVG beside it)", file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------------------
# fitlab simulate
# --------------------------------------------------------------------------------------------


def cmd_simulate(args):
    from pathlib import Path

    from fitlab.io.atomic import atomic_write_text
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
                   progress=not args.quiet)
    m = res.to_measurement()
    scatter = {"scatter": res.metadata()["scatter"]}
    text = format_measurement_csv(m, scatter)
    if args.out:
        atomic_write_text(args.out, text)
        written = [args.out]
        if args.split_bounces:
            orders_path = str(Path(args.out).with_suffix("")) + ".orders.csv"
            atomic_write_text(orders_path, format_measurement_csv(res.to_measurement(orders=True),
                                                                  scatter))
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


# --------------------------------------------------------------------------------------------
# fitlab info / convert
# --------------------------------------------------------------------------------------------


def _is_fit_json(path):
    from pathlib import Path

    p = Path(path)
    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    with open(p, "rb") as fh:
        return b'"fitlab-fit"' in fh.read(256)


def _describe_fit(path):
    from fitlab.export.paramfile import read_fit

    rec = read_fit(path)
    return {"format": "fit-json", "format_description": "fitlab parameter file",
            "spec": "data_formats/fit_json.md", "schema_version": rec["schema_version"],
            "model": rec["model"], "loss": rec["loss"], "data": rec["data"]["path"],
            "channels": [f["channel"] for f in rec["fits"]],
            "parameters": {f["channel"]: {k: v["value"] for k, v in f["parameters"].items()}
                           for f in rec["fits"]},
            "mcmc": [bool(f["mcmc"]) for f in rec["fits"]]}


def _print_info(info, indent=""):
    for key, value in info.items():
        if isinstance(value, dict):
            print(f"{indent}{key}:")
            _print_info(value, indent + "  ")
        elif isinstance(value, list) and len(value) > 12:
            shown = ", ".join(str(v) for v in value[:12])
            print(f"{indent}{key}: [{shown}, ... ({len(value)} values)]")
        else:
            print(f"{indent}{key}: {value}")


def cmd_info(args):
    from fitlab.export.exr import describe_exr, is_exr
    from fitlab.io.formats import describe_any

    if is_exr(args.file) and not args.format:
        info = describe_exr(args.file)  # a fitlab LUT (data_formats/lut_exr.md)
    else:
        info = _describe_fit(args.file) if _is_fit_json(args.file) and not args.format \
            else describe_any(args.file, args.format)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
    else:
        _print_info(info)
    return 0


def cmd_lut(args):
    from fitlab.export.lut_files import run

    return run(args)


_ZEMAX_ONLY = ("model", "param", "option", "grid", "aoi", "azimuth", "radial", "scatter", "channel")


def cmd_convert(args):
    from fitlab.io import zemax

    if args.model:
        if len(args.paths) != 1:
            raise FitlabError("with --model give only the output file: fitlab convert --model "
                              "NAME --param NAME=VALUE ... OUT.bsdf")
        source, output = None, args.paths[0]
    elif len(args.paths) != 2:
        raise FitlabError("give INPUT OUTPUT (or --model NAME --param ... OUT.bsdf)")
    else:
        source, output = args.paths
    to = args.to or ("zemax" if output.lower().endswith(".bsdf") else "csv")
    if to == "csv":
        given = [f"--{k}" for k in _ZEMAX_ONLY if getattr(args, k)]
        if given or _is_fit_json(source):
            raise FitlabError(f"{' '.join(given) or source}: applies to Zemax output only; "
                              "name the output *.bsdf (or give --to zemax)")
        return _convert_to_csv(source, output, args.format)
    grid = dict(grid=args.grid or "standard", aoi=args.aoi, azimuth=args.azimuth,
                radial=args.radial, scatter=args.scatter or "BRDF")
    if args.model:
        model, params, options = _model_from_cli(args)
        summary = zemax.write_zemax(output, model.name, params, options, **grid)
    elif _is_fit_json(source):
        summary = zemax.write_zemax_from_fit(output, source, channel=args.channel, **grid)
    else:
        raise FitlabError(f"{source}: only a parameter file (fit JSON) or --model NAME can be "
                          "written as a Zemax .bsdf; measured data would need resampling onto "
                          "its grid (fit a model, then convert the fit)")
    g = summary["grid"]
    print(f"wrote {output}: Zemax {summary['scatter']} of {summary['model']} "
          f"({summary['symmetry']}, {'/'.join(summary['channels'])}), {g['aoi']} AOI x "
          f"{g['azimuth']} azimuth x {g['radial']} radial angles; TIS "
          f"{summary['tis_range'][0]:.4g} .. {summary['tis_range'][1]:.4g}", file=sys.stderr)
    for note in summary.get("notes", []):
        print(f"note: {note}", file=sys.stderr)
    return 0


def _convert_to_csv(source, output, format_name):
    from fitlab.io.atomic import atomic_write_text
    from fitlab.io.formats import read_any
    from fitlab.io.measurement import format_measurement_csv

    m = read_any(source, format_name)
    text = format_measurement_csv(m, {"converted_from": f"{source} ({m.file_quantity})"})
    atomic_write_text(output, text)
    print(f"wrote {m.n} rows ({', '.join(m.channel_names)}) to {output}", file=sys.stderr)
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
        epilog="examples: fitlab eval rough_dielectric --param alpha=0.3 --param eta=1.5 "
        "--directions data_formats/examples/directions_inplane.csv --out f.csv; "
        "fitlab eval --preset copper_patina --channel G --directions "
        "data_formats/examples/directions_inplane.csv",
    )
    p.add_argument("model", nargs="?", help="model name (see `fitlab models`); layered models "
                   "as coated(INNER) or weidlich_wilkie(BASE[,layers=K]); optional with --preset")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a model parameter; give every parameter of the model (with --preset: "
                   "overrides the preset's value)")
    p.add_argument("--preset", metavar="NAME",
                   help="parameters and model of a named material (metallic_car_paint, "
                   "copper_patina: Elek 2010 section 4; listed by `fitlab models`); needs "
                   "--channel")
    p.add_argument("--channel", choices=("R", "G", "B"),
                   help="with --preset: the colour channel whose values to use")
    p.add_argument("--option", action="append", metavar="NAME=VALUE",
                   help="a model option, e.g. distribution=beckmann")
    p.add_argument("--directions", required=True, metavar="FILE.csv", help="direction pairs")
    p.add_argument("--out", metavar="FILE.csv", help="output file (default: standard output)")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                   help="evaluation precision (default float64)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser(
        "fit", help="fit a model to measurements (least squares, global starts, optional MCMC)",
        description="Fit a registry model to a measurement file (data_formats/measurement_csv.md): "
        "global search (nlopt MLSL) and multi-start Levenberg-Marquardt (jaxopt, vmapped over the starts), "
        "covariance from the Jacobian, optional posterior sampling with emcee. Writes a parameter "
        "file (data_formats/fit_json.md). Compiled kernels are kept on disk for later runs, in "
        "$FITLAB_CACHE_DIR or else $XDG_CACHE_HOME/fitlab/xla or ~/.cache/fitlab/xla "
        "(FITLAB_NO_CACHE=1: no cache).",
        epilog="example: fitlab fit data_formats/examples/walter_rough_glass.csv --model "
        "rough_dielectric --fit-subset 'theta_i == 0' --mcmc --out fits/walter_rough_glass.json",
    )
    p.add_argument("data", help="measurement CSV")
    p.add_argument("--model", required=True, help="model name (see `fitlab models`)")
    p.add_argument("--option", action="append", metavar="NAME=VALUE", help="a model option")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value (e.g. --fix eta=1.51)")
    p.add_argument("--free", action="append", metavar="NAME",
                   help="fit a parameter the data file would fix (eta from # eta_inside/outside)")
    p.add_argument("--loss", choices=("chi2", "relative", "log", "cos_l2"),
                   help="default: chi2 when the data have sigma, else relative")
    p.add_argument("--fit-subset", metavar="EXPR",
                   help="fit only these rows, predict the rest, e.g. 'theta_i == 0', "
                   "'value > 0.01 and theta_o < 80', 'row %% 8 == 0', 'specular_deg > 3' (names: "
                   "theta_i, phi_i, theta_o, phi_o, value, channel, row, specular_deg = angle "
                   "to the mirror direction, to leave out a smooth coat's delta peak; + - * / %%, "
                   "comparisons, and/or/not, abs)")
    p.add_argument("--channel", help="fit only this channel (default: every channel separately)")
    p.add_argument("--mcmc", action="store_true", help="sample the posterior with emcee")
    p.add_argument("--mcmc-steps", type=int, default=3000, help="steps per walker (default 3000)")
    p.add_argument("--walkers", type=int, help="number of walkers (default max(32, 4 x dim))")
    p.add_argument("--starts", type=int, default=8,
                   help="low-discrepancy Levenberg-Marquardt starts besides the global search "
                   "(default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--walter-diagnostics", action="store_true",
                   help="add Walter 2007 section 6.1's empirical D points to the parameter file")
    p.add_argument("--out", metavar="FILE.json", help="parameter file (default: standard output)")
    p.add_argument("--chain", metavar="FILE.npz", help="also write the MCMC chain")
    p.add_argument("--report", metavar="DIR",
                   help="then write an HTML report of the fit into DIR (as `fitlab report`; "
                   "needs --out; with --chain it shows posterior bands and MCMC plots)")
    p.add_argument("--quiet", action="store_true", help="no progress or summary on the terminal")
    p.add_argument("--format", help="input format (default: detected from the content)")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser(
        "report", help="write a self-contained HTML report of a fit (figures as PNG and SVG)",
        description="Turn a parameter file (data_formats/fit_json.md), its data file and its "
        "MCMC chain into OUT/index.html: header and provenance, parameter table (best fit, "
        "posterior median, 68% and 95% intervals) and correlations, errors per incidence "
        "(fit subset against prediction), in-plane scans of data against the model with "
        "posterior bands and residuals, hemispherical maps for out-of-plane data, polar lobes, "
        "corner plot, MCMC diagnostics and traces, Walter's empirical D, and previews with "
        "accuracy figures of the lookup tables baked for the fit. The page embeds every "
        "figure (no network needed); each figure is also written beside it as NAME.png and "
        "NAME.svg. Same inputs, same bytes. Layout: data_formats/report_html.md.",
        epilog="example: fitlab report fits/walter_rough_glass.json --chain "
        "fits/walter_rough_glass_chain.npz --out reports/walter_rough_glass/",
    )
    p.add_argument("fit", metavar="FIT.json", help="parameter file written by `fitlab fit --out`")
    p.add_argument("--data", metavar="FILE",
                   help="the data file (default: the path recorded in FIT.json; its SHA-256 "
                   "must match the recorded one)")
    p.add_argument("--chain", metavar="FILE.npz",
                   help="the MCMC chain written by `fitlab fit --chain` (default: the path "
                   "recorded in FIT.json, if that file exists); without one the report has no "
                   "posterior bands, corner or trace plots and says so")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (created if missing; files of the same names replaced)")
    p.add_argument("--lut", action="append", metavar="FILE.exr",
                   help="a lookup table baked for this fit (`fitlab lut KIND --from-fit "
                   "FIT.json`) to preview with its accuracy figures; repeatable. Tables beside "
                   "FIT.json whose header names it are added unless --no-lut-discovery")
    p.add_argument("--no-lut-discovery", action="store_true",
                   help="preview only the --lut tables, not those found beside FIT.json")
    p.add_argument("--quiet", action="store_true", help="no progress on the terminal")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("info", help="show what a data, parameter or table file holds",
                       description="Describe a file fitlab reads: format, angles, channels, units, "
                       "value ranges and format-specific checks.")
    p.add_argument("file")
    p.add_argument("--format", help="force a format instead of detecting it")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser(
        "convert", help="convert data to measurement CSV; tabulate a fit or model as Zemax .bsdf",
        description="Three forms, each writing atomically (nothing is left on failure). "
        "(1) INPUT OUTPUT.csv: read any supported measurement format (e.g. a Zemax .bsdf) and "
        "write a fitlab measurement CSV (data_formats/measurement_csv.md). "
        "(2) FIT.json OUTPUT.bsdf: tabulate a fitted model (parameter file) as a Zemax / "
        "Radiant IS-BSDF text file (data_formats/zemax_bsdf.md); channels X, Y, Z become "
        "tristimulus data, other multi-channel fits need --channel; a relative fit's 'scale' is "
        "not applied (the file holds the absolute model f). "
        "(3) --model NAME --param NAME=VALUE ... OUTPUT.bsdf: the same for any registry model. "
        "The Zemax grid is --grid standard (light at 0..80 deg in 5 deg steps, azimuth 0..180 "
        "in 10 deg steps, plane-symmetric, radial 0..180 deg, fine near the specular ray) or "
        "the angles of an existing .bsdf file, with --aoi/--azimuth/--radial replacing lists. "
        "The output type follows the suffix (.bsdf = Zemax) unless --to is given.",
        epilog="examples: fitlab convert data_formats/examples/zemax_brown_vinyl.bsdf vinyl.csv; "
        "fitlab convert fits/vinyl.json vinyl_fit.bsdf --grid data_formats/examples/"
        "zemax_brown_vinyl.bsdf; fitlab convert --model rough_dielectric --param alpha=0.3 "
        "--param eta=1.5 --scatter BTDF --aoi 0:40:5 glass_btdf.bsdf",
    )
    p.add_argument("paths", nargs="+", metavar="FILE",
                   help="INPUT OUTPUT, or only OUTPUT with --model")
    p.add_argument("--format", help="input format (default: detected from the content)")
    p.add_argument("--to", choices=("csv", "zemax"),
                   help="output type (default: zemax for *.bsdf, else csv)")
    p.add_argument("--model", help="tabulate this registry model (see `fitlab models`)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a parameter of --model; give every parameter")
    p.add_argument("--option", action="append", metavar="NAME=VALUE",
                   help="an option of --model, e.g. distribution=beckmann")
    p.add_argument("--scatter", type=str.upper, choices=("BRDF", "BTDF"),
                   help="Zemax ScatterType (default BRDF); for BTDF the angles are about the "
                   "refracted ray and --aoi lists refraction angles")
    p.add_argument("--grid", metavar="standard|FILE.bsdf",
                   help="'standard' (default) or a Zemax file whose angles to reuse")
    p.add_argument("--aoi", metavar="ANGLES", help="AngleOfIncidence list in degrees, "
                   "'0,15,30' or START:STOP:STEP (e.g. 0:80:5)")
    p.add_argument("--azimuth", metavar="ANGLES", help="ScatterAzimuth list; all within "
                   "0..180 writes PlaneSymmetrical data, beyond 180 Asymmetrical")
    p.add_argument("--radial", metavar="ANGLES", help="ScatterRadial list, 0..180")
    p.add_argument("--channel", help="the channel of a multi-channel fit to write")
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser(
        "lut", help="bake a lookup table (OpenEXR) and the GLSL that reads it",
        description="Bake a 1D/2D/3D lookup table for shaders and write it as OpenEXR (half or "
        "float channels; axes, mappings, texel convention, model, parameters and the measured "
        "accuracy in fitlab.* header attributes) plus a GLSL snippet beside it (OUT.glsl) with "
        "the exact index mapping. KIND: D (pi alpha^2 D(cos theta_h; alpha), 512x512, u8 cos axis as "
        "in Elek 2010, log alpha axis), fresnel (F(cos theta) per channel: conductor n,k, --preset or dielectric "
        "eta; 128), albedo_conductor (E(mu, alpha) with F = 1 and E_avg; 32x32), "
        "albedo_dielectric (R and T from outside and inside over mu x alpha x eta; 32x32x16), "
        "dfg (split-sum scale and bias; 64x64), model (a model's or fit's BRDF over "
        "(cos theta_h, cos theta_d) at phi_d = 90 deg; 256x256). Integrals use deterministic "
        "quadrature; every table's accuracy against direct evaluation is measured and stored. "
        "Spec: data_formats/lut_exr.md. Nothing is written on error.",
        epilog="examples: fitlab lut D --option distribution=ggx --out d_ggx.exr; fitlab lut "
        "fresnel --preset copper --out copper_F.exr; fitlab lut fresnel --param eta=1.5 --out "
        "glass_F.exr; fitlab lut albedo_conductor --dtype float --out E_ggx.exr; fitlab lut "
        "model --from-fit fits/walter_rough_glass.json --out glass_brdf.exr; fitlab lut model "
        "--model rough_conductor --param alpha=0.2 --param n=0.2,1.0,1.2 --param k=3.9,2.6,2.4 "
        "--out metal.exr",
    )
    p.add_argument("kind", metavar="KIND",
                   help="D, fresnel, albedo_conductor, albedo_dielectric, dfg or model")
    p.add_argument("--from-fit", metavar="FIT.json",
                   help="take the model, options and parameters from a parameter file "
                   "(data_formats/fit_json.md); its path is recorded in the EXR header")
    p.add_argument("--channel", help="with --from-fit: only this channel of the fit")
    p.add_argument("--model", help="registry model (see `fitlab models`)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE[,G,B]",
                   help="a parameter; three comma-separated values make R, G, B channels")
    p.add_argument("--option", action="append", metavar="NAME=VALUE",
                   help="a model option, e.g. distribution=beckmann (D, albedo and dfg tables "
                   "read distribution; fresnel reads fresnel=exact|schlick|lazanyi)")
    p.add_argument("--preset", help="fresnel only: conductor (n, k) per RGB from Elek 2010 "
                   "appendix A: copper, chromium or cuprite")
    p.add_argument("--size", metavar="NxN[xN]",
                   help="samples per axis, 2..4096 (one number: every axis); default per kind")
    p.add_argument("--mapping", action="append", metavar="AXIS=MAPPING",
                   help="axis mapping: linear, u8 (x = hi - (hi-lo) t^8), sqrt (x = lo + "
                   "(hi-lo) t^2) or log, e.g. cos_theta_h=linear or alpha=log")
    p.add_argument("--alpha-range", metavar="LO:HI",
                   help="range of the alpha axis within [1e-4, 1] (default 1e-4:1)")
    p.add_argument("--eta-range", metavar="LO:HI",
                   help="albedo_dielectric: range of eta = n_inside/n_outside within [1.001, 5] "
                   "(default 1.05:3; incidence from inside covers 1/eta)")
    p.add_argument("--dtype", choices=("half", "float"), default="half",
                   help="EXR channel type (default half; half refuses values above 65504)")
    p.add_argument("--check-points", type=int, metavar="N",
                   help="random points for the accuracy check against direct evaluation "
                   "(default per kind; 0 skips it)")
    p.add_argument("--out", required=True, metavar="FILE.exr", help="output table")
    p.add_argument("--no-shader", action="store_true", help="do not write FILE.glsl")
    p.add_argument("--hlsl", action="store_true", help="also write FILE.hlsl")
    p.add_argument("--quiet", action="store_true", help="no progress or summary on stderr")
    p.set_defaults(func=cmd_lut)

    p = sub.add_parser(
        "simulate", help="Monte Carlo ground truth of a layer stack (scene TOML) as measurement CSV",
        description="Trace a vectorized Monte Carlo random walk (JAX) through the layer stack of "
        "SCENE.toml (data_formats/scene_toml.md): rough or smooth dielectric interfaces (GGX, "
        "Beckmann, vMF), absorbing and scattering media (isotropic, Henyey-Greenstein, SGGX "
        "microflakes), Lambertian / conductor / dielectric substrates. Only the effects the scene "
        "asks for are compiled and traced (observed hemispheres, bounce limit, absorption, volume "
        "scattering none/single/multiple, delta transmission, mono/RGB), and fitlab derives more "
        "from the scene itself (no medium: no volume code; sigma_a = 0: no attenuation; grey: one "
        "channel; opaque substrate: no transmitted paths). Writes a measurement CSV "
        "(data_formats/measurement_csv.md): value = BSDF in 1/sr averaged over each bin or "
        "cone, sigma = Monte Carlo standard error, metadata with the effects simulated and "
        "skipped (and why), samples, seed and time, so `fitlab fit OUT.csv --model ...` works "
        "on it. Progress on stderr; the output is written atomically.",
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
    p.add_argument("--quiet", action="store_true", help="no progress or summary on the terminal")
    p.set_defaults(func=cmd_simulate)
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
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early: not an error
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 0


if __name__ == "__main__":
    sys.exit(main())
