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

#: Bytes read from the start of a file for detection.
HEAD_BYTES = 4096


READER_MODULES = (
    "fitlab.io.merl",
    "fitlab.io.klems",
    "fitlab.io.pgii",
    "fitlab.io.zemax",
    "fitlab.io.rgl",
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
    raise InputFileError(
        path, "is in no format fitlab recognizes",
        hint=f"formats: {', '.join(known)}; see data_formats/ (or force one with --format)",
    )


def read_any(path, format: str | None = None, **options):
    """Read any supported file to a Measurement (format detected from content unless given)."""
    from fitlab.io.measurement import check_measurement

    return check_measurement(detect_format(path, format).read(path, **options))


def describe_any(path, format: str | None = None) -> dict:
    fmt = detect_format(path, format)
    return {"format": fmt.name, "format_description": fmt.description, "spec": fmt.spec,
            **fmt.describe(path)}
