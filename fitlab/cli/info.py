"""fitlab info: what a data, parameter or lookup-table file holds."""

from __future__ import annotations

import json

from fitlab.errors import FitlabError

from fitlab.cli.common import add_format, add_json, add_read_options, read_kwargs


def add_parser(sub):
    p = sub.add_parser("info", help="show what a data, parameter or table file holds",
                       description="Describe a file fitlab reads: format, angles, channels, units, "
                       "value ranges and format-specific checks. For a measurement it reports "
                       "what every sanity gate finds (sanity_gates) and lists under warnings "
                       "each gate the file trips, which the commands that read it (fit, "
                       "convert, compare, report) refuse unless --accept names it; info itself "
                       "does not refuse a file for a gate.")
    p.add_argument("file")
    add_format(p, help="force a format instead of detecting it")
    add_read_options(p)
    add_json(p)
    return p


def _print_info(info, indent=""):
    for key, value in info.items():
        if isinstance(value, dict):
            print(f"{indent}{key}:")
            _print_info(value, indent + "  ")
        elif key == "warnings" and value:  # one sentence a line
            print(f"{indent}{key}:")
            for w in value:
                print(f"{indent}  - {w}")
        elif isinstance(value, list) and len(value) > 12:
            shown = ", ".join(str(v) for v in value[:12])
            print(f"{indent}{key}: [{shown}, ... ({len(value)} values)]")
        else:
            print(f"{indent}{key}: {value}")


def run(args):
    from fitlab.export.exr import describe_exr, is_exr
    from fitlab.io.fitfile import is_fit_file

    read = read_kwargs(args)
    if read and (is_exr(args.file) or is_fit_file(args.file)) and not args.format:
        raise FitlabError(f"{args.file}: --angles, --accept and --quantity apply to measurement "
                          "files, not to a lookup table or a parameter file")
    if is_exr(args.file) and not args.format:
        info = describe_exr(args.file)  # a fitlab LUT (data_formats/lut_exr.md)
    elif is_fit_file(args.file) and not args.format:
        from fitlab.export.paramfile import read_fit
        from fitlab.io.fitfile import describe_fit

        info = describe_fit(read_fit(args.file))
    else:
        from fitlab.io.formats import describe_any

        info = describe_any(args.file, args.format, **read)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
    else:
        _print_info(info)
    return 0
