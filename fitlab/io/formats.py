"""Registry of the file formats fitlab reads: detection from content, reading to a
Measurement, and a description for ``fitlab info``.

Each reader module defines ``FORMAT = Format(...)`` (fitlab.io.format); ``READER_MODULES``
lists them in detection order (the most specific signatures first, fitlab's own CSV last).
"""

from __future__ import annotations

import functools
import importlib
from pathlib import Path

from fitlab.errors import InputFileError
from fitlab.io.format import Format
from fitlab.registry import Registry
from fitlab.io.files import read_bytes
from fitlab.io.validate import quote

#: Bytes read from the start of a file for detection.
HEAD_BYTES = 4096


READER_MODULES = (
    "fitlab.io.openmaterial",
    "fitlab.io.merl",
    "fitlab.io.klems",
    "fitlab.io.pgii",
    "fitlab.io.zemax",
    "fitlab.io.rgl",
    "fitlab.io.spectral_scan",
    "fitlab.io.measurement",
)


@functools.cache
def formats() -> Registry[Format]:
    """The formats fitlab reads, in detection order (built on first use: it imports every
    reader module)."""
    fmts = [importlib.import_module(mod).FORMAT for mod in READER_MODULES]
    return Registry("format", {f.name: f for f in fmts}, listing="`fitlab info`")


def detect_format(path, name: str | None = None) -> Format:
    """The format of ``path``: ``name`` if given (checked against the registry), else detected."""
    path = Path(path)
    known = formats()
    if name is not None:
        if name not in known:
            raise InputFileError(path, f"unknown format {name!r}",
                                 hint=f"formats: {', '.join(known)}")
        read_bytes(path, limit=HEAD_BYTES)  # a missing or unreadable file says so first
        return known[name]
    head = read_bytes(path, limit=HEAD_BYTES)
    for fmt in known.values():
        if fmt.detect(head, path):
            return fmt
    raise unrecognized(path, head, known)


def closest_format(path, head: bytes, known) -> tuple[Format, str] | None:
    """The format an unrecognized file most likely meant, and why: the one its name's ending
    belongs to (text or binary as the file is, where endings are shared), else fitlab's CSV
    for a text file; None for a binary file with an unknown ending."""
    text = b"\0" not in head
    by_suffix = [f for f in known.values() if Path(path).suffix.lower() in f.suffixes]
    if len(by_suffix) > 1:  # .bsdf: Zemax's text or RGL's binary
        by_suffix = [f for f in by_suffix if f.binary != text] or by_suffix
    if by_suffix:
        return by_suffix[0], f"by its ending {Path(path).suffix}"
    if text and head.strip():
        return known["csv"], "a text file"
    return None


def unrecognized(path, head: bytes, known) -> InputFileError:
    """Why no format recognizes ``path``: an empty file says so; otherwise the closest format
    (:func:`closest_format`) reads it and its first error is named."""
    formats_hint = (f"formats: {', '.join(known)}; see data_formats/ (or force one with "
                    "--format)")
    if not head.strip():
        return InputFileError(path, "is empty" if not head else "holds only white space",
                              hint="give a measurement file; " + formats_hint)
    closest = closest_format(path, head, known)
    if closest is not None:
        fmt, why = closest
        try:
            fmt.read(path)
        except InputFileError as exc:
            where = "".join(
                [f"line {exc.line}: " if exc.line is not None else "",
                 f"column {quote(exc.column)}: " if exc.column is not None else ""])
            return InputFileError(
                path, f"is in no format fitlab recognizes; read as the closest, {fmt.name} "
                f"({why}), it fails at {where}{exc.message}",
                hint=(exc.hint + "; or " if exc.hint else "") + "force a format with --format")
        except (ValueError, OSError):
            pass
    return InputFileError(path, "is in no format fitlab recognizes", hint=formats_hint)


def _read_kwargs(fmt: Format, path, opts) -> dict:
    """The read options (fitlab.io.gates.ReadOptions) ``fmt``'s reader takes; an option it does
    not take (its spec fixes the angles' unit or the quantity) is refused when given."""
    given = {"angles": opts.angles if opts.angles != "degrees" else None,
             "quantity": opts.quantity}
    for name, value in given.items():
        if value is not None and name not in fmt.takes:
            raise InputFileError(path, f"--{name} {value} applies to fitlab's measurement CSV; "
                                 f"the {fmt.name} format states its {name} itself ({fmt.spec})",
                                 hint=f"drop --{name}, or convert the file to a measurement CSV "
                                 "(fitlab convert) and correct it there")
    kw = {name: value for name, value in given.items() if name in fmt.takes and value is not None}
    if fmt.takes:
        kw["accept"] = opts.accept
    return kw


def read_any(path, format: str | None = None, *, angles: str | None = None, accept=(),
             quantity: str | None = None, enforce: bool = True, **options):
    """Read any supported file to a Measurement (format detected from content unless given),
    checked (check_measurement) and passed through the sanity gates (fitlab.io.gates): a gate
    that trips raises its InputFileError unless ``accept`` names it (``enforce=False``: none
    raises). ``angles`` ("degrees", "radians") and ``quantity`` (one of
    fitlab.io.gates.QUANTITIES, replacing the file's) apply to the formats that take them
    (fitlab's CSV); ``options`` are the reader's own."""
    from fitlab.io.gates import apply_gates, read_options
    from fitlab.io.measurement import check_measurement

    opts = read_options(angles, accept, quantity)
    fmt = detect_format(path, format)
    m = check_measurement(fmt.read(path, **_read_kwargs(fmt, path, opts), **options))
    return apply_gates(m, fmt.name, opts, enforce=enforce)


def describe_any(path, format: str | None = None, *, angles: str | None = None, accept=(),
                 quantity: str | None = None) -> dict:
    """What ``path`` holds, for ``fitlab info``: the format's description, with every sanity
    gate's finding reported (``warnings``, ``sanity_gates``) rather than refused."""
    from fitlab.io.gates import read_options

    opts = read_options(angles, accept, quantity)
    fmt = detect_format(path, format)
    kw = _read_kwargs(fmt, path, opts)
    kw["accept"] = opts.accept
    info = {"format": fmt.name, "format_description": fmt.description, "spec": fmt.spec,
            **fmt.describe(path, format_name=fmt.name, **kw)}
    if opts.record():
        info["read_options"] = opts.record()
    return info
