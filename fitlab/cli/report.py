"""fitlab report: a self-contained HTML report of a fit, its data and its MCMC chain."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_quiet, add_read_options, read_kwargs


def add_parser(sub):
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
    p.add_argument("fit", metavar="FIT.json",
                   help="parameter file written by `fitlab fit --out`, or a folder written by "
                   "`fitlab fit-maps` (its maps with colour bars, the fit error and status maps, "
                   "histograms, a few texels against their readings and, with --gltf, its glTF "
                   "rendered by three.js beside the input images where Chromium and three are "
                   "installed)")
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
    p.add_argument("--renderers", action="store_true",
                   help="add the hand-off section: each `fitlab export` format's conversion "
                   "error (Mitsuba exports rendered on a virtual goniometer) and a Mitsuba 3 "
                   "render of the material on a sphere (needs Mitsuba 3: pip install "
                   "'fitlab[mitsuba]')")
    add_read_options(p)  # for the data file; default: as the fit read it (data.read_options)
    add_quiet(p, help="no progress on the terminal")
    return p


def run(args):
    from fitlab.report import build_report
    from fitlab.report.texture_maps import build_maps_report, is_maps_folder

    if is_maps_folder(args.fit):
        summary = build_maps_report(args.fit, args.out, progress=not args.quiet)
        if not args.quiet:
            print(f"open {summary['index']} in a browser", file=sys.stderr)
        return 0

    summary = build_report(args.fit, args.out, data_path=args.data, chain_path=args.chain,
                           luts=args.lut or (), discover_luts=not args.no_lut_discovery,
                           renderers=args.renderers,
                           progress=not args.quiet, read_options=read_kwargs(args) or None)
    if not args.quiet:
        print(f"open {summary['index']} in a browser (self-contained; "
              f"{len(summary['figures'])} figures also as PNG and SVG beside it)", file=sys.stderr)
    return 0
