"""fitlab command line: thin subcommands over the library, one module each (its ``add_parser``
and ``run``), no physics here. Choices and help come from the registries (models, file formats,
writers, LUT kinds)."""

from __future__ import annotations

import gc
import importlib
import os
import sys

import fitlab
from fitlab.cli.common import Parser
from fitlab.errors import FitlabError

#: The subcommands, in the order ``fitlab --help`` lists them: fitlab.cli.<name>.
COMMANDS = ("models", "eval", "fit", "fit-maps", "compare", "report", "info", "convert", "export", "lut", "simulate",
            "tradeoffs", "atlas", "multiple-lobe", "learn-lobe")


def build_parser():
    parser = Parser(
        prog="fitlab",
        description="Fit, evaluate and tabulate physically based BSDF models (Walter 2007 "
        "microfacet models and more). Conventions: data_formats/CONVENTIONS.md.",
    )
    parser.add_argument("--version", action="version", version=f"fitlab {fitlab.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in COMMANDS:
        module = importlib.import_module(f"fitlab.cli.{name.replace('-', '_')}")
        module.add_parser(sub).set_defaults(func=module.run)
    return parser


#: Python's cyclic collector in a ``fitlab`` process: 20,000 new objects before a young
#: collection (700 by default), older generations collected half as often. Tracing and compiling
#: JAX code allocates millions of short-lived objects, and the default thresholds walked the
#: whole heap again and again: a cold ``fitlab fit`` of the quick start takes 15% less CPU
#: (2.94 -> 2.45 s). The test suite's processes use the same setting (tests/conftest.py).
GC_THRESHOLDS = (20_000, 20, 20)


def tune_collector() -> None:
    """Set this process's collector thresholds to :data:`GC_THRESHOLDS`."""
    gc.set_threshold(*GC_THRESHOLDS)


def main(argv=None) -> int:
    tune_collector()
    parser = build_parser()
    args, extras = parser.parse_known_args(argv)
    trailing = getattr(args, "trailing_positionals", None)
    if extras and trailing and not any(e.startswith("-") for e in extras):
        # files after an option (fitlab convert IN --complete FIT.json OUT): the subcommand's
        setattr(args, trailing, list(getattr(args, trailing)) + extras)
        extras = []
    if extras:  # answered by the subcommand that was given them, with its usage
        parser.subcommand(getattr(args, "command", None)).unrecognized(extras)
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


__all__ = ["COMMANDS", "GC_THRESHOLDS", "build_parser", "main", "tune_collector"]
