"""The strict comma-separated table reader behind every fitlab CSV format.

Format: UTF-8 (no byte-order mark), ``#`` comment lines anywhere (``# key: value`` comments with
an identifier-like key are metadata), one header line naming the columns, then rows of numbers separated by commas.
Everything that is not exactly that is an error naming file, line and column.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import InputFileError
from fitlab.io.validate import decode_text, parse_number
from fitlab.io.files import read_bytes


#: A metadata comment: ``# key: value`` with an identifier-like key (other comments are prose).
_METADATA = re.compile(r"#\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(.*)$")


def text_lines(text: str):
    """(line number, stripped line, metadata) of every non-blank line; metadata is (key
    lower-cased, value) for a ``# key: value`` comment, else None. Shared by the text readers."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped:
            meta = _METADATA.match(stripped) if stripped.startswith("#") else None
            yield lineno, stripped, (meta.group(1).lower(), meta.group(2).strip()) if meta else None


class Table(NamedTuple):
    path: str
    columns: dict[str, np.ndarray]
    #: ``# key: value`` comment lines, keys lower-cased
    metadata: dict[str, str]
    #: the 1-based file line of each row
    lines: np.ndarray
    #: the file line of each metadata key
    metadata_lines: dict


def _read_text(path: Path) -> str:
    raw = read_bytes(path, folder_hint="give the path of a CSV file")
    if raw.startswith(b"\xef\xbb\xbf"):
        raise InputFileError(
            path, "starts with a UTF-8 byte-order mark", line=1,
            hint="save the file as plain UTF-8 without BOM (e.g. 'UTF-8' rather than 'UTF-8 with BOM')",
        )
    return decode_text(path, raw, what="CSV", encoding="utf-8")


def _check_delimiters(path, lineno: int, text: str) -> None:
    for bad, name in (("\t", "a tab"), (";", "a semicolon")):
        if bad in text:
            raise InputFileError(
                path, f"uses {name} as a separator", line=lineno,
                hint="fitlab CSV files separate fields with commas only",
            )


def read_table(path, required: tuple[str, ...], optional: tuple[str, ...] = (),
               what: str = "CSV file", text_columns: tuple[str, ...] = (),
               column_pattern: str | None = None, nan_pattern: str | None = None) -> Table:
    """Read and validate a numeric table with the ``required`` and ``optional`` columns.

    Columns named in ``text_columns`` keep their cells as strings; any other column must hold
    finite numbers, except that a cell of a column whose name matches ``nan_pattern`` may read
    ``NaN`` (any case: no reading). Columns whose name matches the regular expression
    ``column_pattern`` are accepted besides the named ones (e.g. per-channel ``value_R``)."""
    path = Path(path)
    text = _read_text(path)
    metadata: dict[str, str] = {}
    metadata_lines: dict[str, int] = {}
    header = None
    rows: list[list[str]] = []
    lines: list[int] = []
    for lineno, stripped, meta in text_lines(text):
        if stripped.startswith("#"):
            if meta:
                metadata[meta[0]], metadata_lines[meta[0]] = meta[1], lineno
            continue
        try:
            _check_delimiters(path, lineno, stripped)
        except InputFileError:
            _check_cells(path, header, rows, lines, text_columns, nan_pattern)  # an earlier one
            raise
        fields = [f.strip() for f in stripped.split(",")]
        if header is None:
            header = _parse_header(path, lineno, fields, required, optional, what, column_pattern)
            continue
        if len(fields) != len(header):
            _check_cells(path, header, rows, lines, text_columns, nan_pattern)  # an earlier one
            raise InputFileError(
                path, f"has {len(fields)} fields but the header names {len(header)}", line=lineno,
                hint=f"every row needs exactly the columns {', '.join(header)}",
            )
        rows.append(fields)
        lines.append(lineno)
    if header is None:
        raise InputFileError(path, f"is empty: a {what} needs a header line and at least one row",
                             hint=f"the header must name the columns {', '.join(required)}")
    if not rows:
        raise InputFileError(path, "has a header but no data rows",
                             hint="add at least one row of numbers")
    columns = _columns(path, header, rows, lines, text_columns, nan_pattern)
    return Table(str(path), columns, metadata, np.asarray(lines), metadata_lines)


def _nan_cell(name, cell, nan_pattern) -> bool:
    """Whether ``cell`` is a ``NaN`` (no reading) its column ``name`` may hold."""
    return bool(nan_pattern) and cell.lower() == "nan" and re.fullmatch(nan_pattern, name)


def _columns(path, header, rows, lines, text_columns, nan_pattern=None) -> dict:
    """The cells of ``rows`` as one array per column: a numeric column converted at once (the
    same rules as Python's ``float``); where a cell is empty, not a number or not finite (and
    not a ``NaN`` its column may hold), the cells are checked one by one in file order, so the
    error names the first bad cell's line and column."""
    columns = {}
    for j, name in enumerate(header):
        cells = [r[j] for r in rows]
        if name in text_columns:
            if not all(cells):
                _check_cells(path, header, rows, lines, text_columns, nan_pattern)
            columns[name] = np.asarray(cells, dtype=object)
            continue
        try:
            values = np.asarray(cells, dtype=np.float64)
            finite = np.isfinite(values)
            ok = bool(np.all(finite)) or all(
                f or _nan_cell(name, c, nan_pattern) for f, c in zip(finite, cells))
        except (ValueError, OverflowError):
            ok = False
        if not ok:
            _check_cells(path, header, rows, lines, text_columns, nan_pattern)
        columns[name] = values
    return columns


def _check_cells(path, header, rows, lines, text_columns, nan_pattern=None) -> None:
    """Every cell of ``rows``, in file order: the first bad one raises its InputFileError."""
    for fields, lineno in zip(rows, lines):
        for name, cell in zip(header, fields):
            if name in text_columns:
                if not cell:
                    raise InputFileError(path, "is empty", line=lineno, column=name)
            elif not _nan_cell(name, cell, nan_pattern):
                _parse_number(path, lineno, name, cell)


def _parse_header(path, lineno, fields, required, optional, what, column_pattern=None):
    known = set(required) | set(optional)
    seen = set()
    for name in fields:
        if name == "":
            raise InputFileError(path, "the header has an empty column name", line=lineno)
        try:
            float(name)
        except ValueError:
            pass
        else:
            raise InputFileError(
                path, f"the first non-comment line should be the header, found a number {name!r}",
                line=lineno, hint=f"add a header line naming the columns {', '.join(required)}",
            )
        if name not in known and not (column_pattern and re.fullmatch(column_pattern, name)):
            raise InputFileError(
                path, "unknown column", line=lineno, column=name,
                hint=f"a {what} has the columns {', '.join(required + tuple(optional))}",
            )
        if name in seen:
            raise InputFileError(path, "appears twice in the header", line=lineno, column=name)
        seen.add(name)
    missing = [c for c in required if c not in seen]
    if missing:
        raise InputFileError(
            path, f"the header lacks the column(s) {', '.join(missing)}", line=lineno,
            hint=f"a {what} needs the columns {', '.join(required)}",
        )
    return fields


def _parse_number(path, lineno, column, cell) -> float:
    return parse_number(cell, path, line=lineno, column=column,
                        hint="every cell must be a finite decimal number; remove or fix rows "
                        "with NaN or infinite values")
