"""`fitlab lut`: from command-line values or a fit file to a baked table, its EXR and its shader
snippets. The CLI parses arguments; everything that decides something lives here (testable
without argparse). Output is written only after every input has been validated and the table
baked: nothing is written on error, and the EXR is removed again if a snippet cannot be written.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import fitlab
from fitlab import lut
from fitlab.assignments import parse_assignments
from fitlab.errors import FitlabError


def parse_size(text: str, kind: lut.Kind) -> tuple:
    """'512x512', '32x32x16' or one number for every axis."""
    parts = text.lower().split("x")
    try:
        sizes = tuple(int(p) for p in parts)
    except ValueError:
        raise FitlabError(f"--size {text!r}: give integers like "
                          f"{'x'.join(map(str, kind.default_size))}") from None
    if len(sizes) == 1:
        sizes = sizes * kind.n_axes
    if len(sizes) != kind.n_axes:
        raise FitlabError(f"--size {text!r}: a {kind.name} table has {kind.n_axes} axes "
                          f"({', '.join(kind.axis_names)}); give {kind.n_axes} sizes")
    for s in sizes:
        if not lut.SIZE_MIN <= s <= lut.SIZE_MAX:
            raise FitlabError(f"--size {text!r}: every axis needs {lut.SIZE_MIN} to {lut.SIZE_MAX} "
                              "samples")
    return sizes


def parse_mappings(items, kind: lut.Kind) -> tuple:
    mappings = list(kind.default_mappings)
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise FitlabError(f"--mapping {item!r} must look like AXIS=MAPPING, e.g. "
                              f"{kind.axis_names[0]}=linear")
        if name not in kind.axis_names:
            raise FitlabError(f"--mapping {item!r}: a {kind.name} table has the axes "
                              f"{', '.join(kind.axis_names)}")
        if value not in lut.MAPPINGS:
            raise FitlabError(f"--mapping {item!r}: mappings are {', '.join(lut.MAPPINGS)}")
        mappings[kind.axis_names.index(name)] = value
    return tuple(mappings)


def parse_range(text, what):
    if text is None:
        return None
    lo, sep, hi = text.partition(":")
    try:
        r = (float(lo), float(hi))
    except ValueError:
        raise FitlabError(f"--{what}-range {text!r} must look like LO:HI") from None
    if not sep or not r[0] < r[1]:
        raise FitlabError(f"--{what}-range {text!r} must look like LO:HI with LO < HI")
    return r


def parse_options(items) -> dict:
    """--option NAME=VALUE items → {name: value} (each name once)."""
    return parse_assignments(items, "option")


def params_from_cli(items) -> dict:
    """--param NAME=V or NAME=R,G,B → {channel: {name: value}} (channels Y, or R G B)."""
    raw = {}
    for name, value in parse_assignments(items, "param").items():
        try:
            raw[name] = [float(v) for v in value.split(",")]
        except ValueError:
            raise FitlabError(f"--param {name}={value}: values must be numbers "
                              "(one value, or three as R,G,B)") from None
    lengths = {len(v) for v in raw.values()}
    if lengths - {1, 3}:
        raise FitlabError("--param takes one value or three (R,G,B) per parameter")
    if 3 in lengths:
        return {ch: {n: (v[i] if len(v) == 3 else v[0]) for n, v in raw.items()}
                for i, ch in enumerate("RGB")}
    return {"Y": {n: v[0] for n, v in raw.items()}} if raw else {}


def from_fit(path, channel=None):
    """(model name, options, {channel: {name: value}}) of a parameter file; ``scale`` (the
    unknown factor of relative data) is not part of the model and is left out."""
    from fitlab.export.paramfile import read_fit

    rec = read_fit(path)
    fits = rec["fits"]
    names = [f["channel"] for f in fits]
    if channel is not None:
        if channel not in names:
            raise FitlabError(f"--channel {channel}: {path} has channels {', '.join(names)}")
        fits = [f for f in fits if f["channel"] == channel]
    model = fitlab.get_model(rec["model"]["name"])
    params = {f["channel"]: {k: v["value"] for k, v in f["parameters"].items()
                             if k in model.parameter_names} for f in fits}
    return model.name, dict(rec["model"].get("options") or {}), params


def build_table(kind_name, *, fit=None, channel=None, model=None, param_items=None,
                option_items=None, preset=None, size=None, mapping_items=None, alpha_range=None,
                eta_range=None, dtype="half", check_points=None, progress=None):
    """Validate the inputs of `fitlab lut` and bake the table (nothing written)."""
    try:
        kind = lut.get_kind(kind_name)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if fit and (model or param_items or preset):
        raise FitlabError("give either --from-fit or --model/--param/--preset, not both")
    sizes = parse_size(size, kind) if size else None
    mappings = parse_mappings(mapping_items, kind)
    options = {}
    if fit:
        model, options, params = from_fit(fit, channel)
    else:
        if channel:
            raise FitlabError("--channel applies to --from-fit only")
        params = params_from_cli(param_items)
        if model:
            try:
                m = fitlab.get_model(model)
            except ValueError as exc:
                raise FitlabError(str(exc)) from None
            try:
                options = fitlab.api.resolve_options(m, parse_options(option_items))
            except ValueError as exc:
                raise FitlabError(f"{exc} (see `fitlab models {m.name}`)") from None
            model = m.name
        elif option_items:
            options = parse_options(option_items)
    try:
        if preset:
            if kind.preset is None:
                with_presets = [k.name for k in lut.KINDS.values() if k.preset is not None]
                raise ValueError(f"--preset applies to {' and '.join(with_presets)} tables only")
            params = kind.preset(preset)
        # what the kind needs from the model's or fit's parameters and options
        options, params = kind.prepare(model, options, params)
        spec = lut.make_spec(kind.name, size=sizes, mappings=mappings, model=model, params=params,
                             options=options,
                             alpha_range=parse_range(alpha_range, "alpha"),
                             eta_range=parse_range(eta_range, "eta"))
        return lut.bake(spec, dtype, check_points=check_points,
                        source_fit=str(fit) if fit else None, progress=progress)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None


def write_outputs(table, out, *, shader=True, hlsl=False):
    """Write OUT.exr and (beside it) OUT.glsl / OUT.hlsl; on any failure nothing is left."""
    from fitlab.export import exr, shader as sh
    from fitlab.io.atomic import atomic_write_text

    out = Path(out)
    if out.suffix.lower() != ".exr":
        raise FitlabError(f"--out {out}: the table file must end in .exr")
    texts = {}
    if shader:
        texts[out.with_suffix(".glsl")] = sh.glsl(table, source=out.name)
    if hlsl:
        texts[out.with_suffix(".hlsl")] = sh.hlsl(table, source=out.name)
    exr.write_exr(out, table)
    written = [out]
    try:
        for path, text in texts.items():
            atomic_write_text(path, text)
            written.append(path)
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return written


def run(args) -> int:
    t0 = time.perf_counter()

    def progress(msg):
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr)

    out = Path(args.out)
    if out.suffix.lower() != ".exr":
        raise FitlabError(f"--out {out}: the table file must end in .exr")
    if not out.parent.exists():
        raise FitlabError(f"--out {out}: the folder {out.parent} does not exist; create it first")
    table = build_table(args.kind, fit=args.from_fit, channel=args.channel, model=args.model,
                        param_items=args.param, option_items=args.option, preset=args.preset,
                        size=args.size, mapping_items=args.mapping, alpha_range=args.alpha_range,
                        eta_range=args.eta_range, dtype=args.dtype,
                        check_points=args.check_points, progress=progress)
    written = write_outputs(table, out, shader=not args.no_shader, hlsl=args.hlsl)
    acc = table.accuracy
    if not args.quiet:
        h, w, c = table.values.shape
        print(f"wrote {', '.join(map(str, written))}: {table.kind}, {w} x {h} texels, {c} "
              f"channel(s) ({', '.join(table.channels)}), {table.dtype}", file=sys.stderr)
        print(f"  storage rounding: max rel {acc['storage']['max_rel']:.3g}", file=sys.stderr)
        if "quadrature" in acc:
            q = acc["quadrature"]
            print(f"  quadrature error estimate: max abs {q['max_abs_error_estimate']:.3g}",
                  file=sys.stderr)
        if "interpolation" in acc:
            i = acc["interpolation"]
            print(f"  lookup vs direct evaluation at {i['points']} random points: max rel "
                  f"{i['max_rel']:.3g}, RMS rel {i['rms_rel']:.3g}", file=sys.stderr)
        if "parameterization" in acc:
            p = acc["parameterization"]
            print(f"  lookup vs the model at random direction pairs (phi_d = 90 deg assumed): "
                  f"max rel {p['max_rel']:.3g}, RMS rel {p['rms_rel']:.3g}", file=sys.stderr)
    return 0


__all__ = ["build_table", "write_outputs", "run", "parse_size", "params_from_cli", "from_fit"]
