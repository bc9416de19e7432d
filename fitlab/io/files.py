"""Reading an input file's bytes and fingerprinting them: the one place that turns a missing,
unreadable or folder path into an :class:`~fitlab.errors.InputFileError` naming the file, and
the one SHA-256 every record of provenance uses."""

from __future__ import annotations

import hashlib
from pathlib import Path

from fitlab.errors import InputFileError

#: Bytes hashed per read when fingerprinting a file.
HASH_BLOCK = 1 << 20


def read_bytes(path, *, limit: int | None = None, folder_hint: str | None = None) -> bytes:
    """The bytes of an input file, or its first ``limit`` bytes. A missing file, a folder and a
    file that cannot be read raise InputFileError naming ``path`` (``folder_hint`` says what to
    give instead of a folder)."""
    path = Path(path)
    try:
        if limit is None:
            return path.read_bytes()
        with open(path, "rb") as fh:
            return fh.read(limit)
    except FileNotFoundError:
        raise InputFileError(path, "no such file", hint="check the path") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a folder, not a file", hint=folder_hint) from None
    except OSError as exc:
        raise InputFileError(path, f"cannot be read ({exc.strerror})") from None


def sha256_of(source) -> str:
    """Hex SHA-256 of ``source``: bytes as they are, or the contents of the file at a path
    (read block by block)."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        return hashlib.sha256(source).hexdigest()
    h = hashlib.sha256()
    with open(source, "rb") as fh:
        for block in iter(lambda: fh.read(HASH_BLOCK), b""):
            h.update(block)
    return h.hexdigest()


def path_for_record(path, output) -> str:
    """How an output file names another file (its data, its chain, its source): relative to the
    output's folder, with '/' separators, so that no absolute path of the machine that made it
    is stored and the pair can be moved together; the base name where no relative path exists
    (another drive)."""
    import os

    target = os.path.abspath(os.fspath(path))
    base = os.path.dirname(os.path.abspath(os.fspath(output)))
    try:
        return Path(os.path.relpath(target, base)).as_posix()
    except ValueError:
        return Path(target).name


__all__ = ["read_bytes", "sha256_of", "path_for_record"]
