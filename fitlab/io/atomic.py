"""Atomic output: write to a temporary file beside the target, then rename over it, so a
failure never leaves a partial file behind. The file gets the mode a plain ``open`` would give it
(0666 less the umask), not the private 0600 of a temporary file."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def current_umask() -> int:
    """The process umask (read without changing it where /proc tells it)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temporary_beside(path, suffix: str = ".tmp") -> tuple[int, str]:
    """(fd, name) of a new temporary file in ``path``'s folder with the mode a plain ``open``
    would create (0666 & ~umask); the caller renames it over ``path`` or removes it."""
    path = Path(path)
    if not path.parent.exists():
        from fitlab.errors import FitlabError

        raise FitlabError(f"{path}: the output folder {path.parent} does not exist; create it first")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.fchmod(fd, 0o666 & ~current_umask())
    return fd, tmp


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open a temporary file in ``path``'s directory; on success it replaces ``path``."""
    path = Path(path)
    fd, tmp = temporary_beside(path)
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path, text: str) -> None:
    with atomic_open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(text)
