"""fitlab fit-maps: a capture stack of a flat sample fitted texel by texel into texture maps
(fitlab.fit_maps), written with the renderer hand-off."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_model, add_option, add_quiet
from fitlab.errors import FitlabError
from fitlab.fitting.losses import LOSSES


def add_parser(sub):
    p = sub.add_parser(
        "fit-maps", help="fit a model to every texel of a capture stack: texture maps",
        description="Fit a registry model to every texel of a capture stack (a folder with "
        "stack.csv and one OpenEXR image per row, data_formats/stack.md) with batched least "
        "squares (the engine of fitlab fit FILE FILE ...: a Halton scan, then "
        "Levenberg-Marquardt), and write into --out-dir one float32 OpenEXR map per free "
        "parameter (PARAM.exr: R, G, B per channel, Y when shared) and its standard error "
        "(PARAM_std.exr), the fit error (rms.exr), the status code per texel (status.exr: 0 "
        "converged; maps.json lists the codes), maps.json (model, settings, provenance), "
        "where Mitsuba 3 evaluates the model natively, mitsuba.xml with bitmap textures, and "
        "with --gltf a glTF 2.0 material with PNG textures. "
        "A texel with nothing to fit (in a channel: every reading NaN, too few, or only "
        "zeros) is not fitted (status no_data). The folder is written all or nothing; the "
        "same inputs give the same bytes.",
        epilog="example: fitlab fit-maps data_formats/examples/stack --model "
        "lambertian+rough_conductor --fix n=0.2 --fix k=3.9 --share alpha --out-dir maps",
    )
    p.add_argument("stack", metavar="STACK",
                   help="capture stack folder: stack.csv (file, theta_i, phi_i, theta_o, "
                   "phi_o in degrees) and its OpenEXR images (R, G, B or Y; f in 1/sr)")
    add_model(p, help="model name (see `fitlab models`)", required=True)
    add_option(p, help="a model option")
    p.add_argument("--out-dir", metavar="DIR", required=True,
                   help="folder of the maps (created; an earlier fit-maps folder is replaced)")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value in every texel (e.g. --fix k=3.9)")
    p.add_argument("--free", action="append", metavar="NAME",
                   help="fit a parameter the stack table would fix (eta from # eta_inside/"
                   "outside)")
    p.add_argument("--loss", choices=list(LOSSES), help="default: relative")
    p.add_argument("--fit-subset", metavar="EXPR",
                   help="fit only these readings, as fitlab fit's --fit-subset (names: "
                   "theta_i, phi_i, theta_o, phi_o, channel, row = the image's index, "
                   "specular_deg, value: a texel's reading), e.g. 'theta_o < 70'")
    p.add_argument("--share", action="append", metavar="NAME[,NAME...]",
                   help="a parameter shared by the channels of a texel (e.g. --share alpha: "
                   "one geometry, colour per channel): each texel's channels are fitted "
                   "jointly and the parameter's map has one channel, Y")
    p.add_argument("--starts", type=int, default=4, metavar="N",
                   help="Levenberg-Marquardt starts besides the scan's best point and the "
                   "model's defaults, run with them where the first one's end is suspect "
                   "(default 4)")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="seed of the scan (default 0)")
    p.add_argument("--lm-maxiter", type=int, metavar="N",
                   help="step limit of each Levenberg-Marquardt run (default 200)")
    p.add_argument("--chunk", type=int, metavar="N",
                   help="texel fits per compiled batched call (default 1024; memory grows "
                   "with it)")
    p.add_argument("--gltf", action="store_true",
                   help="also write material.gltf: glTF's BRDF fitted to every texel's "
                   "material as fitlab export --to gltf fits it (ior fixed at 1.5: glTF has no "
                   "ior texture), with PNG textures under gltf/ (a second, costlier fit per "
                   "texel)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="fit the stack in tiles of image rows on N local Dask worker "
                   "processes (1: in this process); resumable: the finished tiles wait in "
                   "DIR.tiles beside DIR, and a rerun skips them")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the tiles to a running Dask scheduler (tcp://HOST:8786; its "
                   "workers need fitlab and the same paths)")
    p.add_argument("--tile-rows", type=int, metavar="N",
                   help="with --workers/--scheduler: image rows per tile (default: about "
                   "16384 texels)")
    add_quiet(p)
    return p


def request_of(args):
    """The FitRequest of the options, checked before the stack is read."""
    from fitlab.assignments import parse_assignments
    from fitlab.cli.fit import _share_names
    from fitlab.fitting.maps import MAPS_DEFAULTS
    from fitlab.fitting.request import FitRequest

    return FitRequest(args.model, spelling="cli", fix=parse_assignments(args.fix, "fix"),
                      free=tuple(args.free or ()),
                      options=parse_assignments(args.option, "option"), loss=args.loss,
                      subset=args.fit_subset, share=_share_names(args.share),
                      starts=MAPS_DEFAULTS["starts"] if args.starts is None else args.starts,
                      seed=args.seed, lm_maxiter=args.lm_maxiter, progress=not args.quiet)


def run(args):
    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()
    from fitlab.fitting.batch import CHUNK, SCAN
    from fitlab.fitting.maps import check_maps_request, fit_maps

    if args.tile_rows is not None and not (args.workers or args.scheduler):
        raise FitlabError("--tile-rows needs --workers or --scheduler (tiles are what the "
                          "workers fit)")
    chunk = CHUNK if args.chunk is None else args.chunk
    request = check_maps_request(request_of(args), scan=SCAN, chunk=chunk)
    from fitlab.fitting.progress import brief

    with brief():  # progress: one transient status line and the bar, on a terminal only
        result = fit_maps(args.stack, request, out_dir=args.out_dir, gltf=args.gltf,
                          workers=args.workers,
                          scheduler=args.scheduler, tile_rows=args.tile_rows, chunk=chunk)
    if not args.quiet:
        H, W = result.shape
        counts = result.counts()
        print(f"fitted {H} x {W} texels of {result.stack.n_images} images in "
              f"{result.seconds:.2f} s: " + ", ".join(f"{n} {s}" for s, n in counts.items()),
              file=sys.stderr)
        rms = result.rms[result.status == 0]
        if rms.size:
            import numpy as np

            print(f"fit error (RMS relative) of the converged texels: median "
                  f"{np.nanmedian(rms):.4g}, 95th percentile {np.nanpercentile(rms, 95):.4g}",
                  file=sys.stderr)
        print(f"wrote {args.out_dir} (maps.json lists the files)", file=sys.stderr)
    return 0
