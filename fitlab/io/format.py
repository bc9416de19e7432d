"""What a reader module declares about its file format (``FORMAT = Format(...)``); the registry
of them, detection and reading are fitlab.io.formats."""

from __future__ import annotations

from typing import Callable, NamedTuple


class Format(NamedTuple):
    name: str
    description: str
    #: detect(head: bytes, path: Path) -> bool, from the first HEAD_BYTES bytes
    detect: Callable
    #: read(path, **options) -> Measurement (options: the reader's own, and "angles",
    #: "quantity" and "accept" where ``takes`` names them)
    read: Callable
    #: describe(path, format_name=, accept=, [angles=, quantity=]) -> dict of what the file
    #: holds (format, angles, channels, units, checks, the sanity gates' findings)
    describe: Callable
    spec: str  # the data_formats/ document
    #: file name endings the format's files usually have (lower case, with the dot): when no
    #: format recognizes a file, the one its ending names is tried, to say what is wrong
    suffixes: tuple = ()
    #: whether its files are binary (where two formats share an ending, a file's bytes tell)
    binary: bool = False
    #: the read options (fitlab.io.gates) its ``read`` and ``describe`` take besides ``accept``:
    #: "angles" (the unit of the file's angles), "quantity" (what its values are); a format
    #: whose spec fixes them takes neither, and read_any refuses them for it
    takes: tuple = ()
    #: reader options that read every place of the file, where the defaults read a subsample
    #: (MERL's stride): what ``fitlab convert --complete`` reads, as it fills what the file lacks
    whole: dict | None = None
