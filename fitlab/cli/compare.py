"""fitlab compare: fit several candidate models to one measurement and rank them by held-out
error (leave-one-incidence-out cross-validation) and by PSIS-LOO and WAIC from the posterior;
a table (CSV, JSON) and a report page (data_formats/compare.md)."""

from __future__ import annotations

import sys

from fitlab.assignments import parse_assignments
from fitlab.cli.common import (add_channel, add_format, add_option, add_quiet, add_read_options,
                               add_verbose, read_kwargs)
from fitlab.errors import FitlabError
from fitlab.fitting.losses import LOSSES
from fitlab.fitting.searches import add_global_search_option
from fitlab.fitting.solvers import add_local_solver_option


def add_parser(sub):
    p = sub.add_parser(
        "compare", help="rank candidate models on one measurement (cross-validation, PSIS-LOO, "
        "WAIC)",
        description="Fit each candidate model to a measurement file (as `fitlab fit`) and rank "
        "them by held-out error: leave-one-incidence-out cross-validation (each incidence "
        "direction refitted without its rows and predicted) and PSIS-LOO and WAIC from the "
        "MCMC posterior (ArviZ: pip install 'fitlab[compare]'). Says which model wins and by "
        "how much relative to the noise, on the terminal and, with --out, in a table "
        "(compare.csv, compare_incidences.csv, compare.json), a report page (index.html) and "
        "each candidate's parameter file (fits/). Formats: data_formats/compare.md.",
        epilog="example: fitlab compare data_formats/examples/zemax_brown_vinyl.bsdf "
        "--model lambertian+rough_conductor --model 'weidlich_wilkie(lambertian) --fix k1=0 "
        "--fix tau1=0' --fit-subset 'value > 0.01' --out reports/compare_brown_vinyl/",
    )
    p.add_argument("data", help="measurement file (any format `fitlab info` knows)")
    p.add_argument("--model", action="append", metavar="'NAME [--fix P=V] [--option O=V] "
                   "[--free P] [--start P=V] [--label TEXT]'",
                   help="a candidate (give two or more): a model name (see `fitlab models`), "
                   "optionally followed, inside the same quoted argument, by its own --fix, "
                   "--option, --free, --start (one more Levenberg-Marquardt start, as for "
                   "`fitlab fit`) and --label (e.g. --model 'coated(lambertian,"
                   "specular=lobe) --option interreflection=closed_form --fix coat_eta=1.5')")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value in every candidate that has it")
    add_option(p, help="a model option for every candidate that has it, e.g. "
               "distribution=beckmann")
    p.add_argument("--free", action="append", metavar="NAME",
                   help="fit a parameter the data file would fix (eta), in every candidate "
                   "that has it")
    p.add_argument("--loss", choices=list(LOSSES),
                   help="one loss for every candidate (default: chi2 when the data have sigma, "
                   "else relative)")
    p.add_argument("--fit-subset", metavar="EXPR",
                   help="fit and compare only these rows (as `fitlab fit --fit-subset`), e.g. "
                   "'value > 0.01'")
    add_channel(p, "compare on this channel only (default: every channel, each ranked "
                "separately)")
    p.add_argument("--mcmc-steps", type=int, default=3000,
                   help="MCMC steps per walker for PSIS-LOO and WAIC (default 3000)")
    p.add_argument("--walkers", type=int, help="MCMC walkers (default max(32, 4 x dim))")
    p.add_argument("--no-mcmc", action="store_true",
                   help="no posterior sampling: rank by cross-validation alone (no ArviZ "
                   "needed)")
    p.add_argument("--no-cv", action="store_true",
                   help="no cross-validation: rank by PSIS-LOO and WAIC alone")
    p.add_argument("--starts", type=int, default=8,
                   help="Levenberg-Marquardt starts besides the global search's best, in "
                   "every fit and every fold (default 8)")
    add_global_search_option(p)
    add_local_solver_option(p)
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--out", metavar="DIR",
                   help="write the tables, the report page and the candidates' parameter "
                   "files into DIR (created if missing); without it only the terminal summary")
    p.add_argument("--no-report", action="store_true",
                   help="with --out: no report page")
    p.add_argument("--no-fits", action="store_true",
                   help="with --out: no parameter files of the candidates (fits/)")
    add_quiet(p, help="no progress bar or summary on the terminal")
    add_verbose(p, help="every verdict (CV, PSIS-LOO, WAIC), warning and status with its advice "
                "on the terminal (by default the ranking tables, each channel's first verdict and "
                "a count of the warnings; compare.json keeps everything)")
    add_format(p)
    add_read_options(p)
    return p


def run(args):
    from pathlib import Path

    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()  # before any computation; FITLAB_NO_CACHE=1 turns it off
    import fitlab
    from fitlab.fitting.compare import compare, parse_candidate

    if not args.model or len(args.model) < 2:
        raise FitlabError("--model: give two or more candidates to compare, e.g. --model "
                          "lambertian+rough_conductor --model 'weidlich_wilkie(lambertian)'")
    for flag in ("no_report", "no_fits"):
        if getattr(args, flag) and not args.out:
            raise FitlabError(f"--{flag.replace('_', '-')} needs --out DIR: without --out "
                              "nothing is written")
    if args.out and Path(args.out).exists() and not Path(args.out).is_dir():
        raise FitlabError(f"--out {args.out}: is a file, not a folder; give a folder")
    cands = [parse_candidate(text) for text in args.model]
    # the settings are checked once, by the candidates' FitRequests inside compare
    m = fitlab.read(args.data, args.format, **read_kwargs(args))
    result = compare(m, cands, fix=parse_assignments(args.fix, "fix"), options=parse_assignments(args.option, "option"),
                     free=args.free or (), loss=args.loss, subset=args.fit_subset,
                     channels=[args.channel] if args.channel else None, cv=not args.no_cv,
                     mcmc=not args.no_mcmc, mcmc_steps=args.mcmc_steps, walkers=args.walkers,
                     starts=args.starts, seed=args.seed, global_search=args.global_search,
                     local_solver=args.local_solver,
                     progress=not args.quiet)
    if args.out:
        result = result.save(args.out, fits=not args.no_fits)
        if not args.no_report:
            from fitlab.report.api import write_report

            write_report(result, args.out)
    if not args.quiet:
        print(result.summary(verbose=args.verbose), end="", file=sys.stderr)
        if args.out:
            print(f"wrote {args.out}: compare.csv, compare_incidences.csv, compare.json"
                  + ("" if args.no_fits else ", fits/")
                  + ("" if args.no_report else ", index.html"), file=sys.stderr)
    # The verdict on standard output, one line per channel (for scripts and pipes).
    for ch in result.channels:
        print(f"{ch}\t{result.winner(ch)}\t{result.verdict(ch)}")
    return 0
