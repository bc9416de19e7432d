"""fitlab info: what a data, parameter or lookup-table file holds."""

from __future__ import annotations

import json

from fitlab.cli.common import add_format, add_json


def add_parser(sub):
    p = sub.add_parser("info", help="show what a data, parameter or table file holds",
                       description="Describe a file fitlab reads: format, angles, channels, units, "
                       "value ranges and format-specific checks.")
    p.add_argument("file")
    add_format(p, help="force a format instead of detecting it")
    add_json(p)
    return p


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


def run(args):
    from fitlab.export.exr import describe_exr, is_exr
    from fitlab.io.fitfile import is_fit_file

    if is_exr(args.file) and not args.format:
        info = describe_exr(args.file)  # a fitlab LUT (data_formats/lut_exr.md)
    elif is_fit_file(args.file) and not args.format:
        from fitlab.export.paramfile import read_fit
        from fitlab.io.fitfile import describe_fit

        info = describe_fit(read_fit(args.file))
    else:
        from fitlab.io.formats import describe_any

        info = describe_any(args.file, args.format)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
    else:
        _print_info(info)
    return 0
