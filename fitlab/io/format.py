"""What a reader module declares about its file format (``FORMAT = Format(...)``); the registry
of them, detection and reading are fitlab.io.formats."""

from __future__ import annotations

from typing import Callable, NamedTuple


class Format(NamedTuple):
    name: str
    description: str
    #: detect(head: bytes, path: Path) -> bool, from the first HEAD_BYTES bytes
    detect: Callable
    #: read(path, **options) -> Measurement
    read: Callable
    #: describe(path) -> dict of what the file holds (format, angles, channels, units, checks)
    describe: Callable
    spec: str  # the data_formats/ document
