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
* **structure** — ``load_json`` / ``load_toml`` (parse errors, nesting depth), and ``check``:
  a small declarative schema (``Num``, ``Int``, ``Str``, ``Bool``, ``Null``, ``Any``, ``List``,
  ``Map``, ``Record``, ``Either``) that names the field (``fits[0].covariance.matrix[1][0]``)
  whose type or value is wrong;
* **archives** — ``read_npz``: a NumPy ``.npz`` read member by member, each member's header
  (dtype, shape) checked against its declared size and the allocation bound before its data are
  read, object arrays refused, corrupted compression reported.

Every failure is an :class:`~fitlab.errors.InputFileError` naming the file (and the line, field or
member), saying what is wrong and what to do.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field

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
# Schemas for JSON / TOML records
# --------------------------------------------------------------------------------------------


class Spec:
    """What a field must be. ``errors(value, where)`` yields (where, problem) pairs."""

    description = "a value"

    def errors(self, value, where):  # pragma: no cover - abstract
        raise NotImplementedError

    def matches(self, value) -> bool:
        """Whether ``value`` is of this spec's type (its content may still be wrong)."""
        return True


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


@dataclass(frozen=True)
class Num(Spec):
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False

    @property
    def description(self):
        return "a finite number"

    def matches(self, value) -> bool:
        return isinstance(value, (int, float)) and not isinstance(value, bool)

    def errors(self, value, where):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            yield where, f"is {kind_of(value)}; expected {self.description}"
            return
        if not is_finite_number(value) or abs(value) > 1.7e308:
            yield where, "is not a finite number"
            return
        low = self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo)
        if low or (self.hi is not None and value > self.hi):
            lo = "" if self.lo is None else (f"> {self.lo:g}" if self.lo_open else f">= {self.lo:g}")
            hi = "" if self.hi is None else f"<= {self.hi:g}"
            shown = f"{value:g}" if abs(value) < 1e15 else quote(value, 24)
            yield where, f"is {shown}; it must be {' and '.join(s for s in (lo, hi) if s)}"


@dataclass(frozen=True)
class Int(Spec):
    lo: int | None = None
    hi: int | None = None
    description = "a whole number"

    def matches(self, value) -> bool:
        return isinstance(value, int) and not isinstance(value, bool)

    def errors(self, value, where):
        if isinstance(value, bool) or not isinstance(value, int):
            yield where, f"is {kind_of(value)}; expected {self.description}"
        elif (self.lo is not None and value < self.lo) or (self.hi is not None and value > self.hi):
            rule = " and ".join(s for s in (f">= {self.lo}" if self.lo is not None else "",
                                            f"<= {self.hi}" if self.hi is not None else "") if s)
            shown = value if abs(value) < 10 ** 15 else quote(value, 24)
            yield where, f"is {shown}; it must be {rule}"


@dataclass(frozen=True)
class Str(Spec):
    choices: tuple = ()
    max_len: int = 100_000
    description = "a string"

    def matches(self, value) -> bool:
        return isinstance(value, str)

    def errors(self, value, where):
        if not isinstance(value, str):
            yield where, f"is {kind_of(value)}; expected a string"
        elif self.choices and value not in self.choices:
            yield where, f"is {quote(value)}; expected one of {', '.join(self.choices)}"
        elif len(value) > self.max_len:
            yield where, f"is a string of {len(value)} characters; at most {self.max_len} expected"


@dataclass(frozen=True)
class Bool(Spec):
    description = "true or false"

    def matches(self, value) -> bool:
        return isinstance(value, bool)

    def errors(self, value, where):
        if not isinstance(value, bool):
            yield where, f"is {kind_of(value)}; expected true or false"


@dataclass(frozen=True)
class Null(Spec):
    description = "null"

    def matches(self, value) -> bool:
        return value is None

    def errors(self, value, where):
        if value is not None:
            yield where, f"is {kind_of(value)}; expected null"


@dataclass(frozen=True)
class Any(Spec):
    description = "any value"

    def errors(self, value, where):
        return iter(())


@dataclass(frozen=True)
class Either(Spec):
    options: tuple

    @property
    def description(self):
        return " or ".join(o.description for o in self.options)

    def matches(self, value) -> bool:
        return any(o.matches(value) for o in self.options)

    def errors(self, value, where):
        typed = [o for o in self.options if o.matches(value)]
        if not typed:
            yield where, f"is {kind_of(value)}; expected {self.description}"
            return
        found = []
        for o in typed:
            errs = list(o.errors(value, where))
            if not errs:
                return
            found.append(errs)
        yield from found[0]


def Optional(spec: Spec) -> Either:  # noqa: N802 - reads like the types above
    """``spec`` or null."""
    return Either((spec, Null()))


def _length_problem(n: int, min_len: int, max_len: int | None, length: int | None = None):
    """What is wrong with a list or object of ``n`` entries, or None."""
    if length is not None and n != length:
        return f"has {n} entries; expected {length}"
    if n < min_len:
        return f"has {n} entries; expected at least {min_len}"
    if max_len is not None and n > max_len:
        return f"has {n} entries; expected at most {max_len}"
    return None


@dataclass(frozen=True)
class List(Spec):
    item: Spec = field(default_factory=Any)
    min_len: int = 0
    max_len: int | None = None
    length: int | None = None

    @property
    def description(self):
        return "a list"

    def matches(self, value) -> bool:
        return isinstance(value, list)

    def errors(self, value, where):
        if not isinstance(value, list):
            yield where, f"is {kind_of(value)}; expected a list"
            return
        problem = _length_problem(len(value), self.min_len, self.max_len, self.length)
        if problem:
            yield where, problem
            return
        for i, v in enumerate(value):
            yield from self.item.errors(v, f"{where}[{i}]")


@dataclass(frozen=True)
class Map(Spec):
    """An object whose keys are names (strings) and values all ``value``."""

    value: Spec = field(default_factory=Any)
    min_len: int = 0
    max_len: int | None = 4096

    @property
    def description(self):
        return "an object"

    def matches(self, value) -> bool:
        return isinstance(value, dict)

    def errors(self, value, where):
        if not isinstance(value, dict):
            yield where, f"is {kind_of(value)}; expected an object"
            return
        problem = _length_problem(len(value), self.min_len, self.max_len)
        if problem:
            yield where, problem
            return
        for k, v in value.items():
            yield from self.value.errors(v, _join(where, k))


@dataclass(frozen=True)
class Record(Spec):
    """An object with named fields: ``required`` and ``optional`` {name: Spec}; other fields are
    allowed (files from newer versions may add some)."""

    required: dict = field(default_factory=dict)
    optional: dict = field(default_factory=dict)

    @property
    def description(self):
        return "an object"

    def matches(self, value) -> bool:
        return isinstance(value, dict)

    def errors(self, value, where):
        if not isinstance(value, dict):
            yield where, f"is {kind_of(value)}; expected an object"
            return
        for k, spec in self.required.items():
            if k not in value:
                yield _join(where, k), "is missing"
                return
            yield from spec.errors(value[k], _join(where, k))
        for k, spec in self.optional.items():
            if k in value:
                yield from spec.errors(value[k], _join(where, k))


def _join(where: str, key) -> str:
    return f"{where}.{key}" if where else str(key)


def check(value, spec: Spec, path, *, where: str = "", hint: str | None = None):
    """``value`` if it matches ``spec``; else an InputFileError naming the first field that does
    not (``field fits[0].parameters.alpha.value: is a string; expected a finite number``)."""
    for at, problem in spec.errors(value, where):
        raise InputFileError(path, f"field {at or 'at the top level'} {problem}", hint=hint)
    return value


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
           "load_json", "load_toml", "Spec", "Num", "Int", "Str", "Bool", "Null", "Any", "Either",
           "Optional", "List", "Map", "Record", "check", "read_npz", "QUOTE_CHARS",
           "DEFAULT_MAX_VALUES", "MAX_VALUES_ENV"]
