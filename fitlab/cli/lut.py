"""fitlab lut: bake a lookup table (OpenEXR) and the GLSL/HLSL that reads it."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from fitlab import lut
from fitlab.assignments import parse_assignments
from fitlab.cli.common import (add_channel, add_model, add_option, add_param, add_quiet,
                               channel_params, get_model, model_options)
from fitlab.errors import FitlabError


def _kinds_text() -> str:
    return "; ".join(
        f"{k.name} ({k.summary}; {'x'.join(map(str, k.default_size))}, axes "
        f"{', '.join(f'{a} {m}' for a, m in zip(k.axis_names, k.default_mappings))})"
        for k in lut.KINDS.values())


def add_parser(sub):
    from fitlab.export.lut_files import PHI_D_CHOICES
    from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS, CONDUCTOR_PRESETS
    from fitlab.microfacet import DISTRIBUTIONS

    p = sub.add_parser(
        "lut", help="bake a lookup table (OpenEXR) and the GLSL that reads it",
        description="Bake a 1D/2D/3D lookup table for shaders and write it as OpenEXR (half or "
        "float channels; axes, mappings, texel convention, model, parameters and the measured "
        "accuracy in fitlab.* header attributes) plus a GLSL snippet beside it (OUT.glsl) with "
        f"the exact index mapping. KIND (default size, axis mappings): {_kinds_text()}. "
        "Integrals use deterministic quadrature; every table's accuracy against direct "
        "evaluation is measured and stored. Spec: data_formats/lut_exr.md. Nothing is written "
        "on error.",
        epilog="examples: fitlab lut D --option distribution=ggx --out d_ggx.exr; fitlab lut "
        "fresnel --preset copper --out copper_F.exr; fitlab lut fresnel --param eta=1.5 --out "
        "glass_F.exr; fitlab lut albedo_conductor --dtype float --out E_ggx.exr; fitlab lut "
        "model --from-fit fits/walter_rough_glass.json --out glass_brdf.exr; fitlab lut model "
        "--model rough_conductor --param alpha=0.2 --param n=0.2,1.0,1.2 --param k=3.9,2.6,2.4 "
        "--out metal.exr; fitlab lut model --from-fit "
        "fits/brown_vinyl_weidlich_wilkie_lambert.json --out vinyl.exr (256x256x16: the 2D "
        "table misses the target); fitlab lut model --from-fit "
        "fits/brown_vinyl_weidlich_wilkie_lambert.json --phi-d slice --out vinyl2d.exr (the 2D "
        "table, its error printed); fitlab lut model --model oren_nayar --param "
        "albedo=0.5 --param sigma=0.3 --phi-d axis --size 128x128x16 --out on.exr (3D); "
        "fitlab lut thin_layer "
        "--model 'thin_layer(rough_conductor)' --param eta=1.5 --param tau=0.2 --param "
        "n2=0.2,1.0,1.2 --param k2=3.9,2.6,2.4 --out film.exr (the subsurface lobe's mean, "
        "kappa and albedo over (mu, kappa1, kappa2) for a pre-filtered environment map); "
        "fitlab lut thin_layer_compensation --from-fit FIT.json --out comp.exr (fitlab's "
        "energy compensation: D(mu) and Dbar over (mu, kappa1, kappa2); the shader adds "
        "D(mu_i) D(mu_o) / (pi Dbar))",
    )
    p.add_argument("kind", metavar="KIND", help=f"table kind: {', '.join(lut.KINDS)}")
    p.add_argument("--from-fit", metavar="FIT.json",
                   help="take the model, options and parameters from a parameter file "
                   "(data_formats/fit_json.md); its path is recorded in the EXR header")
    add_channel(p, "with --from-fit: only this channel of the fit")
    add_model(p)
    add_param(p, "a parameter; three comma-separated values make R, G, B channels",
              metavar="NAME=VALUE[,G,B]")
    add_option(p, "a model option, e.g. distribution=beckmann (D, albedo and dfg tables read "
               f"distribution={'|'.join(DISTRIBUTIONS)}; fresnel reads "
               f"fresnel={'|'.join(CONDUCTOR_FRESNEL_METHODS)})")
    p.add_argument("--preset", help="fresnel: conductor (n, k) per RGB from Elek 2010 "
                   f"appendix A ({', '.join(CONDUCTOR_PRESETS)}); model: a layered preset "
                   "(`fitlab models` lists them), all three channels")
    p.add_argument("--size", metavar="NxN[xN]",
                   help=f"samples per axis, {lut.SIZE_MIN}..{lut.SIZE_MAX} (one number: every "
                   "axis); default per kind; model: a third number is the phi_d axis's "
                   "(e.g. 256x256x16; see --phi-d)")
    target = lut.PHI_D_TARGET
    p.add_argument("--phi-d", choices=PHI_D_CHOICES,
                   help="model only: auto (the default) = bake the 2D (cos theta_h, "
                   "cos theta_d) table at phi_d = 90 deg, measure its error against the model "
                   "at random direction pairs and, if it misses the target (RMS relative <= "
                   f"{target['rms_rel']:g}, max <= {target['max_rel']:g}), bake the 3D table "
                   "with a phi_d axis (phi_d samples: the third --size number, default "
                   f"{lut.PHI_D_SIZE}); write the table that meets the target, or nothing "
                   "(exit status 2, with both figures and what to try) when neither does; "
                   "slice = the 2D table whatever its error (measured and printed); axis = "
                   "the 3D table whatever its error")
    p.add_argument("--mapping", action="append", metavar="AXIS=MAPPING",
                   help="axis mapping: " + ", ".join(f"{m.name} ({m.formula})"
                                                     for m in lut.MAPPINGS.values())
                   + ", e.g. cos_theta_h=linear or alpha=log")
    p.add_argument("--alpha-range", metavar="LO:HI",
                   help="range of the alpha axis within [1e-4, 1] (default 1e-4:1)")
    p.add_argument("--eta-range", metavar="LO:HI",
                   help="albedo_dielectric: range of eta = n_inside/n_outside within [1.001, 5] "
                   "(default 1.05:3; incidence from inside covers 1/eta)")
    p.add_argument("--kappa-range", metavar="LO:HI",
                   help="thin_layer, thin_layer_compensation: range of the kappa1 and kappa2 "
                   "axes within [0.01, 1e7] (default 1:1e6; thin_layer_compensation 10:1e4, "
                   "its table's range)")
    p.add_argument("--dtype", choices=("half", "float"), default="half",
                   help="EXR channel type (default half; half refuses values above 65504)")
    p.add_argument("--check-points", type=int, metavar="N",
                   help="random points for the accuracy check against direct evaluation "
                   "(default per kind; 0 skips it)")
    p.add_argument("--out", required=True, metavar="FILE.exr", help="output table")
    p.add_argument("--no-shader", action="store_true", help="do not write FILE.glsl")
    p.add_argument("--hlsl", action="store_true", help="also write FILE.hlsl")
    add_quiet(p, help="no progress or summary on stderr")
    return p


def _model_and_options(args):
    """(registry name or None, options): a model's options resolved against it; without a model
    the raw --option values (distribution, fresnel) the table kinds read."""
    if not args.model:
        return None, parse_assignments(args.option, "option")
    model = get_model(args.model)
    return model.name, model_options(model, args.option)


def _print_summary(table, written):
    acc = table.accuracy
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
        how = ("phi_d axis" if any(a.name == lut.PHI_D for a in table.axes)
               else "phi_d = 90 deg assumed")
        miss = "" if p.get("meets_target", True) else (
            f" (misses the target RMS <= {p['target']['rms_rel']:g}, max <= "
            f"{p['target']['max_rel']:g}"
            + (": --phi-d auto, the default, adds a phi_d axis)" if len(table.axes) == 2
               else ": more samples in --size lower it)"))
        print(f"  lookup vs the model at random direction pairs ({how}): max rel "
              f"{p['max_rel']:.3g}, RMS rel {p['rms_rel']:.3g}{miss}", file=sys.stderr)
    if "vmf_lobe" in acc:
        v = acc["vmf_lobe"]
        print(f"  the lobe as one vMF (mean, kappa, E) vs the model's lobe at {v['points']} "
              f"random points, relative L2: median {v['median']:.3g}, 90th percentile "
              f"{v['p90']:.3g}, max {v['max']:.3g}", file=sys.stderr)
    if "auto" in acc:
        print(f"  axes chosen by measurement: {acc['auto']['reason']}", file=sys.stderr)


def run(args) -> int:
    from fitlab.export.lut_files import build_table, write_outputs

    t0 = time.perf_counter()

    def progress(msg):
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr)

    out = Path(args.out)
    if out.suffix.lower() != ".exr":
        raise FitlabError(f"--out {out}: the table file must end in .exr")
    if not out.parent.exists():
        raise FitlabError(f"--out {out}: the folder {out.parent} does not exist; create it first")
    model, options = _model_and_options(args)
    table = build_table(args.kind, fit=args.from_fit, channel=args.channel, model=model,
                        params=channel_params(args.param), options=options, preset=args.preset,
                        size=args.size, mapping_items=args.mapping, alpha_range=args.alpha_range,
                        eta_range=args.eta_range, kappa_range=args.kappa_range,
                        dtype=args.dtype,
                        check_points=args.check_points, progress=progress,
                        phi_d=args.phi_d)
    written = write_outputs(table, out, shader=not args.no_shader, hlsl=args.hlsl)
    if not args.quiet:
        _print_summary(table, written)
    return 0
