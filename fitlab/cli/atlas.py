"""fitlab atlas: the layered-model validation atlas (each layered model against the simulation of
its own stack over a grid of its parameters; maps, the 5% region, a page and package data)."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_quiet
from fitlab.errors import FitlabError


def add_parser(sub):
    from fitlab.atlas.grids import GRIDS, THETA_I_DEG

    grids = "; ".join(f"{s.model}: {' x '.join(a.name for a in s.axes)}" for s in GRIDS.values())
    p = sub.add_parser(
        "atlas", help="the layered models against the simulator over a grid of their "
        "parameters: maps, the region within 5%%, a page (reports/layered_atlas/)",
        description="For each layered model (or --model), simulate its own stack (every bounce "
        "and scattering order) at every point of a grid of two of its parameters and incidences "
        f"{', '.join(f'{t:g}' for t in THETA_I_DEG)} degrees, and score the model against it: "
        "albedo error and relative RMS error of f*cos over the hemisphere, the simulation's "
        "noise beside them and taken out. Writes DIR/README.md (per model its maps, the region "
        "where it is within 5% named, how it was made), DIR/atlas.json "
        "(data_formats/layered_atlas.md) and DIR/NAME.png/.svg, atomically; entries already in "
        "DIR/atlas.json that this run does not redo are kept. --write-package-data also "
        "updates fitlab/models/data/layered_atlas.json, which `fitlab models` and fit reports "
        "read. The same arguments give the same bytes on one simulator backend; the run time "
        f"is printed, not stored. Grids: {grids}.",
        epilog="examples: fitlab atlas --write-package-data (the whole atlas, from the source "
        "tree's root; it prints its estimated time first); fitlab atlas --model "
        "'coated(rough_conductor)' --quick --out /tmp/atlas; fitlab atlas --model "
        "'thin_layer(rough_conductor)' --values kappa1=100,300,1000 --out /tmp/atlas",
    )
    p.add_argument("--model", action="append", metavar="NAME",
                   help="only this model (repeatable; default: every one): "
                   + ", ".join(GRIDS.names()))
    p.add_argument("--out", metavar="DIR", default="reports/layered_atlas",
                   help="output folder (default reports/layered_atlas, relative to the current "
                   "folder: run from fitlab's source tree's root)")
    p.add_argument("--samples", type=int, metavar="N",
                   help="paths per incidence at every grid point (default: a pilot run sets "
                   "them for a noise of about 1.7%% in the RMS error and 0.5%% in the albedo, at most 2,000,000)")
    p.add_argument("--seed", type=int, default=0, help="the simulator's seed (default 0)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke run: every third grid value, at most 100,000 paths, fewer "
                   "model points (minutes for all models)")
    p.add_argument("--values", action="append", metavar="AXIS=V1,V2,...",
                   help="replace an axis's values of the one --model (at least two, "
                   "ascending; repeatable)")
    p.add_argument("--theta-i", metavar="DEG,DEG,...",
                   help="incidences in degrees instead of the grids' own")
    p.add_argument("--write-package-data", action="store_true",
                   help="also write fitlab/models/data/layered_atlas.json (the shipped grids "
                   "only; --out must be the source tree's reports/layered_atlas)")
    add_quiet(p)
    return p


def _numbers(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise FitlabError(f"{what}: {text!r} is not a list of numbers separated by commas") \
            from None


def run(args):
    from fitlab.atlas.run import atlas
    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()  # before any computation; FITLAB_NO_CACHE=1 turns it off
    values = {}
    for item in args.values or ():
        name, sep, rest = item.partition("=")
        if not sep or not name:
            raise FitlabError(f"--values {item!r}: write AXIS=V1,V2,... (e.g. alpha=0.05,0.1)")
        values[name.strip()] = _numbers(rest, f"--values {name}")
    theta = _numbers(args.theta_i, "--theta-i") if args.theta_i is not None else None
    if args.samples is not None and args.samples < 2:
        raise FitlabError("--samples must be at least 2 paths per incidence")
    try:
        res = atlas(args.model, out=args.out, samples=args.samples, seed=args.seed,
                    quick=args.quick, write_package_data=args.write_package_data,
                    values=values or None, theta_i=theta, progress=not args.quiet)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if not args.quiet:
        mine = {e["model"] for e in res.record["entries"]} & set(
            args.model or [e["model"] for e in res.record["entries"]])
        for e in res.record["entries"]:
            if e["model"] in mine:
                print(f"{e['model']}: within 5%: {e['region']}", file=sys.stderr)
    return 0
