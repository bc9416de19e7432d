"""``NAME=VALUE`` assignments as given on the command line (--param, --option, --fix ...)."""

from __future__ import annotations

from fitlab.errors import FitlabError


def parse_assignments(items, what: str) -> dict[str, str]:
    """``["a=1", "b = x"]`` → ``{"a": "1", "b": "x"}``; each name once. ``what`` names the flag."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise FitlabError(f"--{what} {item!r} must look like NAME=VALUE")
        if name in out:
            raise FitlabError(f"--{what} {name} is given twice")
        out[name] = value.strip()
    return out
