"""How a fit tells its progress on stderr: bars (tqdm, erased when they end) and lines
("fitting M to channel R: ...", "least squares: ...", MCMC's percentages).

A line stays on its own line (``fitlab.fit(..., progress=True)``, ``fitlab fit -v``). Inside
:func:`brief` (``fitlab fit`` without ``-v``) a line is a status that the next one replaces, on
one terminal line cleared at the end, and nothing at all (no bars either) where stderr is not a
terminal: the command's summary says what matters, and the parameter file keeps every warning.
"""

from __future__ import annotations

import contextlib
import shutil
import sys

_brief = False


def line(msg: str) -> None:
    """Show the progress line ``msg`` on stderr (as the module docstring says)."""
    if not _brief:
        print(msg, file=sys.stderr, flush=True)
    elif sys.stderr.isatty():
        width = max(shutil.get_terminal_size().columns - 1, 20)
        sys.stderr.write("\r" + msg.strip()[:width] + "\x1b[K")
        sys.stderr.flush()


def bars_shown() -> bool:
    """Whether progress bars are drawn: always, but inside :func:`brief` only on a terminal."""
    return not _brief or sys.stderr.isatty()


@contextlib.contextmanager
def brief(on: bool = True):
    """Progress lines as one transient status line while inside (``on``), then cleared."""
    global _brief
    before, _brief = _brief, bool(on)
    try:
        yield
    finally:
        _brief = before
        if on and sys.stderr.isatty():
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()



def bar(enabled: bool, total: int, desc: str, unit: str):
    """A tqdm bar on stderr (rate and time left), or None when progress is off (or inside
    :func:`brief` where stderr is no terminal)."""
    if not enabled or not bars_shown():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                mininterval=0.5, dynamic_ncols=True)


__all__ = ["bar", "bars_shown", "brief", "line"]
