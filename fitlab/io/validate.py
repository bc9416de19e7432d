"""The validation layer every reader goes through before it trusts what a file says.

One place per concern, shared by the readers of every format:

* **quoting** — ``quote`` is the only way a message shows text from a file: short, one line, so a
  message never echoes megabytes of input;
* **encoding** — ``decode_text`` turns bytes into text or names the line and byte that are not
  in the expected encoding;
* **numbers** — ``parse_number`` (a token: finite, in range), ``check_finite`` (an array, naming
  the first bad entry), ``check_range``;
* **sizes** — ``check_count`` and ``check_allocation``: what a header declares is checked against
  the bytes actually present and against ``max_values()``, the most one file may make fitlab
  allocate, *before* anything is allocated;
* **structure** — ``load_json`` / ``load_toml`` (parse errors, nesting depth), and
  ``check_schema``: a record checked against one of fitlab's published JSON Schemas
  (``data_formats/schemas/``, packaged in ``fitlab/io/schemas/``) by ``jsonschema``, its first
  error turned into a message that names the field (``fits[0].covariance.matrix[1][0]``), what
  is wrong and what to do;
* **archives** — ``read_npz``: a NumPy ``.npz`` read member by member, each member's header
  (dtype, shape) checked against its declared size and the allocation bound before its data are
  read, object arrays refused, corrupted compression reported.

Every failure is an :class:`~fitlab.errors.InputFileError` naming the file (and the line, field or
member), saying what is wrong and what to do.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from fitlab.errors import QUOTE_CHARS, InputFileError, quote  # noqa: F401 (quote: io's name)

# Quoting: fitlab.errors.quote (messages quote file content the same way everywhere)


# --------------------------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------------------------


def decode_text(path, raw: bytes, *, what: str, encoding: str = "utf-8-sig",
                fallback: str | None = None) -> str:
    """``raw`` decoded as ``encoding`` (``fallback`` if that fails, e.g. latin-1 for formats whose
    comments may be in a legacy code page); a UTF-16/32 file or bytes that are not text are
    refused naming the line and byte offset. NUL bytes are refused: no text format fitlab reads
    holds them."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff") or raw[:4] in (b"\x00\x00\xfe\xff", b"\xff\xfe\x00\x00"):
        raise InputFileError(path, f"is UTF-16 or UTF-32 text; {what} files are "
                             f"{encoding.replace('-sig', '').upper()}",
                             hint="save it as UTF-8 (e.g. `iconv -f UTF-16 -t UTF-8`)")
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise InputFileError(path, f"holds a NUL byte (byte {nul}): not a {what} text file",
                             line=raw.count(b"\n", 0, nul) + 1,
                             hint="give the text file itself, not a binary or corrupted copy")
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        if fallback is not None:
            return raw.decode(fallback)
        raise InputFileError(path, f"byte {exc.start} ({quote(raw[exc.start:exc.start + 4])}) "
                             f"is not {encoding.replace('-sig', '').upper()} text",
                             line=raw.count(b"\n", 0, exc.start) + 1,
                             hint=f"save the {what} file as UTF-8") from None


# --------------------------------------------------------------------------------------------
# Numbers
# --------------------------------------------------------------------------------------------


def is_finite_number(value) -> bool:
    """``value`` (from a parsed file) is an int or float, not a bool, that converts to a finite
    float: NaN, infinities and integers with hundreds of digits are not."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer too large for a float
        return False


def parse_number(token, path, *, what: str | None = None, line: int | None = None,
                 column: str | None = None, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, integer: bool = False, hint: str | None = None) -> float:
    """The number ``token`` (a string from a file), finite and within [lo, hi] (``lo_open``:
    > lo), or an InputFileError quoting (briefly) the token, prefixed by ``what`` if given."""
    text = str(token).strip()
    prefix = f"{what}: " if what else ""
    try:
        value = int(text) if integer else float(text)
    except (ValueError, OverflowError):
        kind = "an integer" if integer else "a number"
        raise InputFileError(path, f"{prefix}{quote(text) if text else '(empty)'} is not {kind}",
                             line=line, column=column,
                             hint=hint or f"write {kind}") from None
    if not integer and not math.isfinite(value):
        raise InputFileError(path, f"{prefix}{quote(text)} is not a finite number", line=line,
                             column=column, hint=hint or "replace NaN and infinite values")
    check_range(value, path, what=what or "the value", line=line, column=column, lo=lo, hi=hi,
                lo_open=lo_open, hint=hint)
    return value


def check_range(value, path, *, what: str, line=None, column=None, lo=None, hi=None,
                lo_open: bool = False, hint: str | None = None):
    """``value`` within [lo, hi] (``lo_open``: strictly above lo), else an InputFileError."""
    low_bad = lo is not None and (value <= lo if lo_open else value < lo)
    if low_bad or (hi is not None and value > hi):
        lo_s = "" if lo is None else (f"> {lo:g}" if lo_open else f">= {lo:g}")
        hi_s = "" if hi is None else f"<= {hi:g}"
        rule = " and ".join(s for s in (lo_s, hi_s) if s)
        shown = f"{value:g}" if isinstance(value, (int, float)) and abs(value) < 1e15 else quote(value, 24)
        raise InputFileError(path, f"{what} is {shown}; it must be {rule}", line=line,
                             column=column, hint=hint)
    return value


def check_finite(values, path, *, what: str, line_of=None, column: str | None = None,
                 hint: str | None = None) -> np.ndarray:
    """``values`` as an array, all finite; else an InputFileError naming how many entries are
    not and the first (its line when ``line_of(index)`` is given)."""
    arr = np.asarray(values)
    bad = ~np.isfinite(arr)
    if np.any(bad):
        first = np.argwhere(bad)[0]
        idx = tuple(int(i) for i in first)
        line = line_of(idx[0]) if line_of is not None else None
        where = "" if line_of is not None or arr.ndim == 0 else f" (first at index {list(idx)})"
        raise InputFileError(path, f"{what}: {int(bad.sum())} of {arr.size} values are NaN or "
                             f"infinite{where}", line=line, column=column,
                             hint=hint or "replace or remove NaN and infinite values")
    return arr


# --------------------------------------------------------------------------------------------
# Sizes
# --------------------------------------------------------------------------------------------

#: Default bound on the values (numbers) one input file may make fitlab allocate: 2^28 values,
#: 2 GiB in float64. ``FITLAB_MAX_VALUES`` raises or lowers it.
DEFAULT_MAX_VALUES = 1 << 28
MAX_VALUES_ENV = "FITLAB_MAX_VALUES"


def max_values() -> int:
    """The bound on values per input file (``FITLAB_MAX_VALUES`` or the default)."""
    text = os.environ.get(MAX_VALUES_ENV)
    if text:
        try:
            n = int(float(text))
            if n > 0:
                return n
        except ValueError:
            pass
    return DEFAULT_MAX_VALUES


def check_count(declared, path, *, what: str, present: int | None = None,
                line: int | None = None, column: str | None = None, lo: int = 0,
                hint: str | None = None) -> int:
    """A count a file declares (``declared``: int or numeric text): a whole number >= ``lo``,
    at most ``max_values()``, and (``present``) no more than the items the file actually holds."""
    try:
        n = float(declared)
        ok = math.isfinite(n) and n == int(n)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise InputFileError(path, f"{what}: {quote(declared)} is not a whole number",
                             line=line, column=column, hint=hint)
    n = int(n)
    if n < lo:
        raise InputFileError(path, f"{what} is {n}; it must be at least {lo}", line=line,
                             column=column, hint=hint)
    if present is not None and n > present:
        raise InputFileError(path, f"{what} is {n:,} but the file holds only {present:,}",
                             line=line, column=column,
                             hint=hint or "the file is truncated or the count is wrong")
    limit = max_values()
    if n > limit:
        raise InputFileError(path, f"{what} is {n:,}, more than the {limit:,} values fitlab reads "
                             "from one file", line=line, column=column,
                             hint=hint or f"check the count; for a genuinely larger file set "
                             f"{MAX_VALUES_ENV} higher")
    return n


def check_allocation(shape, path, *, what: str, itemsize: int = 8, present_bytes: int | None = None,
                     column: str | None = None) -> int:
    """The number of values of an array of ``shape`` a file asks for, refused when above
    ``max_values()`` or (``present_bytes``) more than the bytes the file holds."""
    n = 1
    for s in shape:
        if not isinstance(s, (int, np.integer)) or s < 0:
            raise InputFileError(path, f"{what}: shape {quote(shape)} is not a list of sizes",
                                 column=column)
        n *= int(s)
    limit = max_values()
    if n > limit:
        raise InputFileError(path, f"{what} declares {n} values (shape {tuple(int(s) for s in shape)}), "
                             f"more than the {limit} fitlab reads from one file", column=column,
                             hint=f"the file is corrupted, or set {MAX_VALUES_ENV} higher for a "
                             "genuinely larger one")
    if present_bytes is not None and n * itemsize > present_bytes:
        raise InputFileError(path, f"{what} declares {n} values ({n * itemsize} bytes) but "
                             f"{present_bytes} bytes are present", column=column,
                             hint="the file is truncated or corrupted")
    return n


# --------------------------------------------------------------------------------------------
# Structured text: JSON, TOML
# --------------------------------------------------------------------------------------------

#: Deepest nesting a JSON or TOML input may have (fitlab's own files nest at most 6 deep).
MAX_DEPTH = 32


def nesting_depth(obj) -> int:
    """Depth of nested lists/dicts (iterative: no recursion limit)."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        o, d = stack.pop()
        if isinstance(o, dict):
            deepest = max(deepest, d)
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, (list, tuple)):
            deepest = max(deepest, d)
            stack.extend((v, d + 1) for v in o)
    return deepest


def _nesting_too_deep(path, what, hint):
    return InputFileError(path, f"nests too deeply to be a {what} (more than {MAX_DEPTH} levels)",
                          hint=hint)


def load_json(path, raw: bytes, *, what: str, hint: str | None = None):
    """``raw`` parsed as JSON (UTF-8, strict: no NaN/Infinity literals), nested at most
    ``MAX_DEPTH`` deep."""
    text = decode_text(path, raw, what=what)

    def no_constants(name):
        raise ValueError(f"{name} is not a JSON number")

    try:
        obj = json.loads(text, parse_constant=no_constants)
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"is not valid JSON ({exc.msg}, column {exc.colno})",
                             line=exc.lineno, hint=hint) from None
    except ValueError as exc:
        raise InputFileError(path, f"is not valid JSON ({exc})", hint=hint) from None
    except RecursionError:
        raise _nesting_too_deep(path, what, hint) from None
    if nesting_depth(obj) > MAX_DEPTH:
        raise _nesting_too_deep(path, what, hint)
    return obj


def load_toml(path, raw: bytes, *, what: str, hint: str | None = None) -> dict:
    """``raw`` parsed as TOML, nested at most ``MAX_DEPTH`` deep."""
    import tomllib

    text = decode_text(path, raw, what=what)
    try:
        obj = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputFileError(path, f"is not valid TOML ({str(exc)[:200]})", hint=hint) from None
    except RecursionError:
        raise _nesting_too_deep(path, what, hint) from None
    if nesting_depth(obj) > MAX_DEPTH:
        raise _nesting_too_deep(path, what, hint)
    return obj


# --------------------------------------------------------------------------------------------
# fitlab's own JSON formats: published JSON Schemas (data_formats/schemas/)
# --------------------------------------------------------------------------------------------

#: Where the package's copies of fitlab's JSON Schemas live (package data; the published copies
#: in data_formats/schemas/ are the same bytes, tests/io/test_schemas.py).
SCHEMA_DIR = Path(__file__).resolve().parent / "schemas"


def kind_of(value) -> str:
    """What a parsed JSON or TOML value is, in words (for messages)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def schema_file(name: str) -> Path:
    """The package's copy of fitlab's JSON Schema ``name`` (``fit``: fit.schema.json)."""
    return SCHEMA_DIR / f"{name}.schema.json"


@functools.cache
def load_schema(name: str) -> dict:
    """fitlab's JSON Schema ``name``, parsed once."""
    return json.loads(schema_file(name).read_text(encoding="utf-8"))


def _is_number(checker, value) -> bool:
    return is_finite_number(value) and abs(float(value)) <= 1.7e308


def _is_integer(checker, value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@functools.cache
def _validator_class():
    """Draft 2020-12 whose ``number`` is a finite number (a JSON number beyond the float range,
    which Python reads as infinity or as a huge integer, is not) and whose ``integer`` is a
    number written without a fraction (1.0 is not)."""
    import jsonschema

    base = jsonschema.Draft202012Validator
    checker = base.TYPE_CHECKER.redefine_many({"number": _is_number, "integer": _is_integer})
    return jsonschema.validators.extend(base, type_checker=checker)


@functools.cache
def schema_validator(name: str):
    """A validator of fitlab's JSON Schema ``name`` (built once)."""
    return _validator_class()(load_schema(name))


#: How a JSON Schema type reads in a message.
TYPE_WORDS = {"number": "a finite number", "integer": "a whole number", "string": "a string",
              "boolean": "true or false", "null": "null", "array": "a list",
              "object": "an object"}


def json_path(items) -> str:
    """A field in fitlab's spelling, ``fits[0].covariance.matrix[1][0]``, of a path of keys
    and indices."""
    out = ""
    for p in items:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def shown_number(value) -> str:
    """A number as a message shows it (``1e+20``; an integer of many digits quoted short)."""
    return f"{value:g}" if isinstance(value, (int, float)) and abs(value) < 1e15 \
        else quote(value, 24)


def _entries(n: int, node: dict, low: str, high: str) -> str:
    lo, hi = node.get(low), node.get(high)
    if lo is not None and lo == hi:
        return f"has {n} entries; expected {lo}"
    if lo is not None and n < lo:
        return f"has {n} entries; expected at least {lo}"
    return f"has {n} entries; expected at most {hi}"


def schema_problem(error) -> tuple[list, str]:
    """(the field's path, what is wrong) of a jsonschema error, in fitlab's words, quoting file
    content briefly."""
    items, inst, kw, rule, node = (list(error.absolute_path), error.instance, error.validator,
                                   error.validator_value, error.schema)
    if kw == "required":
        missing = next((k for k in rule if isinstance(inst, dict) and k not in inst), rule[0])
        return items + [missing], "is missing"
    if kw == "type":
        kinds = rule if isinstance(rule, list) else [rule]
        if isinstance(inst, (int, float)) and not isinstance(inst, bool) \
                and not _is_number(None, inst) and {"number", "integer"} & set(kinds):
            return items, "is not a finite number"
        return items, f"is {kind_of(inst)}; expected {' or '.join(TYPE_WORDS[k] for k in kinds)}"
    if kw in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        rules = [f"{op} {node[k]:g}" for k, op in (("minimum", ">="), ("exclusiveMinimum", ">"),
                                                     ("maximum", "<="), ("exclusiveMaximum", "<"))
                 if k in node]
        return items, f"is {shown_number(inst)}; it must be {' and '.join(rules)}"
    if kw == "enum":
        return items, f"is {quote(inst)}; expected one of " \
                      f"{', '.join(str(c) for c in rule if c is not None)}"
    if kw == "const":
        return items, f"is {quote(inst)}; expected {quote(rule)}"
    if kw in ("minItems", "maxItems"):
        return items, _entries(len(inst), node, "minItems", "maxItems")
    if kw in ("minProperties", "maxProperties"):
        return items, _entries(len(inst), node, "minProperties", "maxProperties")
    if kw == "maxLength":
        return items, f"is a string of {len(inst)} characters; at most {rule} expected"
    return items, f"does not match the schema ({quote(error.message, 120)})"


def _description(name: str, items) -> str | None:
    """The ``description`` of the schema's property at ``items`` (what the field holds), if
    the schema gives one."""
    node = load_schema(name)
    for p in items:
        if not isinstance(node, dict):
            return None
        if isinstance(p, int):
            node = node.get("items")
        else:
            props = node.get("properties") or {}
            node = props.get(p, node.get("additionalProperties"))
    return node.get("description") if isinstance(node, dict) else None


def check_schema(value, name: str, path, *, hint: str | None = None):
    """``value`` (a parsed file) if it is valid against fitlab's JSON Schema ``name``; else an
    InputFileError naming the first field that is not, in fitlab's spelling (``field
    fits[0].covariance.matrix[1][0] is a string; expected a finite number or null``), with the
    field's ``description`` from the schema ahead of ``hint`` (what to do)."""
    error = next(iter(schema_validator(name).iter_errors(value)), None)
    if error is None:
        return value
    items, problem = schema_problem(error)
    about = _description(name, items)
    advice = "; ".join(s for s in (about and f"{json_path(items) or 'the file'}: {about}", hint)
                       if s)
    raise InputFileError(path, f"field {json_path(items) or 'at the top level'} {problem}",
                         hint=advice or None)


# --------------------------------------------------------------------------------------------
# NumPy .npz archives
# --------------------------------------------------------------------------------------------

#: dtype kinds an .npz input may hold: bool, integers, floats, complex, strings.
NPZ_KINDS = "biufcU"


def read_npz(path, *, what: str, hint: str | None = None) -> dict[str, np.ndarray]:
    """Every member of the ``.npz`` file at ``path`` as an array, read member by member: each
    member's .npy header is parsed first, its dtype must be a plain numeric or string kind (no
    objects, no pickles), its shape within ``max_values()`` and within the member's stored size;
    a corrupted archive or compressed stream is reported naming the member."""
    from numpy.lib import format as npy_format

    from fitlab.io.files import read_bytes

    raw = read_bytes(path)
    try:
        zf = zipfile.ZipFile(io.BytesIO(raw))
        infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise InputFileError(path, f"is not a NumPy .npz archive ({quote(str(exc), 80)})",
                             hint=hint) from None
    if len(infos) > 4096:
        raise InputFileError(path, f"holds {len(infos)} members; not a {what}", hint=hint)
    out = {}
    for info in infos:
        name = info.filename
        member = name[:-4] if name.endswith(".npy") else name
        try:
            with zf.open(info) as fh:
                version = npy_format.read_magic(fh)
                if version == (1, 0):
                    shape, fortran, dtype = npy_format.read_array_header_1_0(fh, max_header_size=10000)
                else:
                    shape, fortran, dtype = npy_format.read_array_header_2_0(fh, max_header_size=10000)
                if dtype.hasobject or dtype.kind not in NPZ_KINDS:
                    raise InputFileError(path, f"member {member!r} holds {dtype} values; a {what} "
                                         "holds numbers and strings only", column=member, hint=hint)
                n = check_allocation(shape, path, what=f"member {member!r}",
                                     itemsize=max(dtype.itemsize, 1),
                                     present_bytes=info.file_size, column=member)
                data = fh.read(n * dtype.itemsize)
                if len(data) != n * dtype.itemsize:
                    raise InputFileError(path, f"member {member!r} is truncated ({len(data)} of "
                                         f"{n * dtype.itemsize} bytes)", column=member, hint=hint)
                arr = np.frombuffer(data, dtype=dtype).copy()
                out[member] = arr.reshape(shape, order="F" if fortran else "C")
        except InputFileError:
            raise
        except (zipfile.BadZipFile, OSError, ValueError, EOFError, zlib.error) as exc:
            raise InputFileError(path, f"member {member!r} cannot be read "
                                 f"({type(exc).__name__}: {quote(str(exc), 80)})", column=member,
                                 hint=hint or "the file is corrupted; write it again") from None
    return out


__all__ = ["quote", "kind_of", "decode_text", "parse_number", "check_range", "check_finite",
           "max_values", "check_count", "check_allocation", "MAX_DEPTH", "nesting_depth",
           "load_json", "load_toml", "SCHEMA_DIR", "schema_file", "load_schema",
           "schema_validator", "json_path", "shown_number", "schema_problem", "check_schema", "read_npz",
           "QUOTE_CHARS", "DEFAULT_MAX_VALUES", "MAX_VALUES_ENV"]
