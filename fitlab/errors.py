"""Errors fitlab reports to its users: each names the file, the position and what to do."""

from __future__ import annotations


class FitlabError(Exception):
    """Base class of errors the CLI reports as a one-line message with a non-zero exit status."""


class InputFileError(FitlabError, ValueError):
    """A malformed or inconsistent input file.

    The message reads ``FILE:LINE: column NAME: what is wrong. What to do.`` with the parts that
    apply."""

    def __init__(self, path, message: str, *, line: int | None = None,
                 column: str | None = None, hint: str | None = None):
        self.path, self.line, self.column, self.hint = str(path), line, column, hint
        where = self.path if line is None else f"{self.path}:{line}"
        text = f"{where}: "
        if column is not None:
            from fitlab.io.validate import quote  # column names may come from the file

            text += f"column {quote(column)}: "
        text += message
        if hint:
            text += f". {hint}"
        super().__init__(text)
