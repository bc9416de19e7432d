"""Errors fitlab reports to its users: each names the file, the position and what to do."""

from __future__ import annotations

#: Characters of file content a message may show.
QUOTE_CHARS = 40


def quote(text, limit: int = QUOTE_CHARS) -> str:
    """``repr`` of a short, one-line excerpt of ``text`` (bytes are shown as text with escapes)."""
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text[: 4 * limit]).decode("utf-8", errors="backslashreplace")
    if not isinstance(text, str):  # a number, list... from a parsed file: shown as Python shows it
        shown = repr(text)
        return shown if len(shown) <= limit else shown[:limit] + f"... ({len(shown)} characters)"
    if len(text) > limit:
        return repr(text[:limit]) + f"... ({len(text)} characters)"
    return repr(text)


class FitlabError(Exception):
    """Base class of errors the CLI reports as a one-line message with a non-zero exit status."""


class InputFileError(FitlabError, ValueError):
    """A malformed or inconsistent input file.

    The message reads ``FILE:LINE: column NAME: what is wrong. What to do.`` with the parts that
    apply."""

    def __init__(self, path, message: str, *, line: int | None = None,
                 column: str | None = None, hint: str | None = None):
        self.path, self.line, self.column, self.hint = str(path), line, column, hint
        self.message = message
        where = self.path if line is None else f"{self.path}:{line}"
        text = f"{where}: "
        if column is not None:  # column names may come from the file
            text += f"column {quote(column)}: "
        text += message
        if hint:
            text += f". {hint}"
        super().__init__(text)
