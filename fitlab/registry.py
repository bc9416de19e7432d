"""One registry type for every name → behaviour table fitlab keeps (models, distributions,
losses, samplers, file formats, writers, exporters, LUT kinds, presets, knobs, phase functions,
the simulator's boundary kinds): a read-only mapping with ``validate`` (a did-you-mean error),
``names`` for ``--help`` and ``register(replace=)``."""

from __future__ import annotations

import difflib
from collections.abc import Iterator, Mapping
from typing import Generic, TypeVar

T = TypeVar("T")


def _plural(what: str) -> str:
    return what + ("es" if what.endswith(("s", "x", "sh", "ch")) else "s")


class Registry(Mapping[str, T], Generic[T]):
    """Entries by name, in registration order. ``what`` names an entry in messages ("model",
    "loss"); ``listing`` says where a user finds them all (e.g. "`fitlab models`")."""

    def __init__(self, what: str, entries: Mapping[str, T] | None = None, *,
                 listing: str | None = None):
        self.what = what
        self.listing = listing
        self._entries: dict[str, T] = dict(entries or {})

    # ---- the mapping -----------------------------------------------------------------------

    def __getitem__(self, name: str) -> T:
        return self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self._entries)})"

    # ---- what users meet ---------------------------------------------------------------------

    def names(self) -> tuple[str, ...]:
        """Every name, in registration order (for --help and choices)."""
        return tuple(self._entries)

    def unknown(self, name) -> ValueError:
        """The error for a name that is not registered: the closest names, then all of them."""
        close = difflib.get_close_matches(str(name), self._entries, n=3, cutoff=0.6)
        text = f"unknown {self.what} {name!r}"
        if close:
            text += f"; did you mean {' or '.join(repr(c) for c in close)}?"
        text += f" {_plural(self.what).capitalize()}: {', '.join(self._entries)}"
        if self.listing:
            text += f" (see {self.listing})"
        return ValueError(text)

    def validate(self, name) -> str:
        """``name`` if it is registered, else ValueError saying what was meant."""
        if name not in self._entries:
            raise self.unknown(name)
        return name

    def get_entry(self, name) -> T:
        """The entry of ``name`` (ValueError with the did-you-mean message if there is none)."""
        return self._entries[self.validate(name)]

    def register(self, name: str, entry: T, *, replace: bool = False) -> T:
        """Add ``entry`` under ``name``; a name already taken needs ``replace=True``."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"a {self.what} needs a non-empty name, got {name!r}")
        if name in self._entries and not replace:
            raise ValueError(f"a {self.what} named {name!r} is already registered; pass "
                             "replace=True to replace it")
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> T | None:
        """Remove ``name`` (if registered) and return its entry."""
        return self._entries.pop(name, None)
