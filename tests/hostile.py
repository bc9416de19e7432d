"""Generators of malformed and hostile input files, and the contract every fitlab command must
keep on them (issue 13).

Each generator takes the bytes of a valid file (real data, the bundled examples, or fitlab's own
outputs) and yields ``Case(name, payload)`` variants: truncations, flipped bytes, wrong
encodings, non-finite / negative / huge / non-numeric values in place of numbers (in the data and
in header fields), deleted and duplicated lines, declared sizes that do not match, deep nesting,
wrong JSON types, a folder in place of the file. They are seeded, so the same cases are made
every run, and they are generic: the positions come from the file's own structure, not from a
list of known bugs.

The contract (``run_contract``) for one command on one case:

* the command returns exit status 0 or 2 and never raises (no traceback);
* with status 2, stderr is one short message (at most ``MAX_MESSAGE`` characters) naming the
  input file, and nothing was written to the output folder;
* with status 0, no output holds a NaN or an infinity where a number belongs;
* the input file is unchanged;
* (cases marked ``allocation``) the command allocates at most ``MAX_ALLOCATION`` bytes.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import random
import re
import shutil
import tracemalloc
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

#: Longest error message a hostile input may produce (the message must not echo the input).
MAX_MESSAGE = 600
#: What a hostile file may make fitlab allocate, in bytes (traced by tracemalloc).
MAX_ALLOCATION = 512 << 20

#: Values put in place of a number.
HOSTILE_NUMBERS = ("nan", "NaN", "inf", "-inf", "-1", "0", "1e308", "-1e308", "1e999", "1e-320",
                   "abc", "", "9" * 400, "0x10", "1,5")
#: Values put in place of a header field's value.
HOSTILE_FIELDS = ("-1.5", "glass", "0", "nan", "", "1e400", "\x00", "é" * 3)
#: JSON values put in place of a field of a JSON record.
HOSTILE_JSON = (None, [], {}, "x", -1, 1e308, True, [[[[[]]]]], 2 ** 70)

NUMBER = re.compile(rb"(?<![\w.+-])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w.])")
FOLDER = object()  # payload: a folder in place of the file


@dataclass(frozen=True)
class Case:
    name: str
    payload: object  # bytes, or FOLDER
    allocation: bool = False  # also check what the command allocates

    def write(self, path: Path) -> Path:
        if self.payload is FOLDER:
            path.mkdir()
            (path / "inside.txt").write_text("a folder, not a file\n")
        else:
            path.write_bytes(self.payload)
        return path


# --------------------------------------------------------------------------------------------
# Generic byte-level mutations: any format
# --------------------------------------------------------------------------------------------


def _rng(data: bytes, salt: str) -> random.Random:
    return random.Random(hashlib.sha256(salt.encode() + data[:4096]).digest())


def byte_cases(data: bytes, *, text: bool = True):
    n = len(data)
    yield Case("empty", b"")
    yield Case("folder", FOLDER)
    for cut in sorted({1, 16, n // 7, n // 2, n - 1}):
        if 0 < cut < n:
            yield Case(f"truncated_at_{cut}", data[:cut])
    rng = _rng(data, "flip")
    for flips in (1, 8, 64):
        b = bytearray(data)
        for _ in range(flips):
            i = rng.randrange(n)
            b[i] ^= 1 << rng.randrange(8)
        yield Case(f"flipped_{flips}", bytes(b))
    b = bytearray(data)
    for _ in range(4):
        b[rng.randrange(n)] = rng.randrange(256)
    yield Case("random_bytes_4", bytes(b))
    mid = data.find(b"\n", n // 2) + 1 if text else n // 2
    yield Case("non_utf8", data[:mid] + b"\xff\xfe\x80\xc3\x28" + data[mid:])
    yield Case("nul_bytes", data[:mid] + b"\x00" * 16 + data[mid:])
    yield Case("garbage_tail", data + bytes(rng.randrange(256) for _ in range(4096)))
    yield Case("doubled", data + data)
    if text:
        yield Case("utf16", data.decode("latin-1").encode("utf-16"))
        yield Case("crlf", data.replace(b"\n", b"\r\n"))
        yield Case("long_line", data[:mid] + b"1," * 600_000 + b"\n" + data[mid:])
        yield Case("binary_garbage", bytes(rng.randrange(256) for _ in range(n if n < 65536 else 65536)))


def text_cases(data: bytes, *, positions: int = 3, header_lines: int = 12):
    """Numbers replaced by hostile values; header ``key: value`` / ``key value`` fields given
    hostile values; lines deleted and duplicated."""
    numbers = list(NUMBER.finditer(data))
    if numbers:
        picks = sorted({0, len(numbers) // 2, len(numbers) - 1}
                       | set(_rng(data, "num").sample(range(len(numbers)),
                                                      min(positions, len(numbers)))))
        for k in picks:
            m = numbers[k]
            for v in HOSTILE_NUMBERS:
                yield Case(f"number{k}_{_tag(v)}", data[:m.start()] + v.encode() + data[m.end():])
    lines = data.split(b"\n")
    fields = 0
    for i, line in enumerate(lines[:200]):
        m = re.match(rb"^(\s*#?\s*[A-Za-z_][\w .-]*?\s*[:=\t ]\s*)(\S.*?)\s*$", line)
        if not m or fields >= header_lines:
            continue
        fields += 1
        for v in HOSTILE_FIELDS:
            new = m.group(1) + v.encode("utf-8")
            yield Case(f"field{i}_{_tag(v)}", b"\n".join(lines[:i] + [new] + lines[i + 1:]))
    rng = _rng(data, "lines")
    idx = sorted(rng.sample(range(len(lines)), min(4, len(lines))))
    for i in idx:
        yield Case(f"line{i}_deleted", b"\n".join(lines[:i] + lines[i + 1:]))
        yield Case(f"line{i}_doubled", b"\n".join(lines[:i + 1] + lines[i:]))
    yield Case("header_only", b"\n".join(lines[:_first_data_line(lines)]) + b"\n")


def _first_data_line(lines) -> int:
    for i, line in enumerate(lines):
        s = line.strip()
        if s and (s[:1].isdigit() or s[:1] in b"-+."):
            return i
    return len(lines)


def _tag(v) -> str:
    text = str(v).replace("-", "neg").replace(".", "p").replace(",", "comma").replace("[", "L")
    s = re.sub(r"[^A-Za-z0-9]+", "", text)[:12]
    return s or f"x{len(str(v))}"


# --------------------------------------------------------------------------------------------
# JSON records (fit parameter files, EXR header values)
# --------------------------------------------------------------------------------------------


def _paths(obj, prefix=(), depth=4):
    if depth == 0:
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,), depth - 1)
    elif isinstance(obj, list) and obj:
        yield prefix + (0,)
        yield from _paths(obj[0], prefix + (0,), depth - 1)


def _replace(obj, path, value, delete=False):
    import copy

    out = copy.deepcopy(obj)
    parent = out
    for k in path[:-1]:
        parent = parent[k]
    if delete:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return out


def json_cases(data: bytes, *, depth: int = 4, values=HOSTILE_JSON):
    """Every field (to ``depth``) deleted or given each hostile value; deep nesting."""
    record = json.loads(data)
    for path in _paths(record, depth=depth):
        tag = ".".join(str(p) for p in path)
        if isinstance(path[-1], str):
            yield Case(f"{tag}:deleted", _dump(_replace(record, path, None, delete=True)))
        for v in values:
            yield Case(f"{tag}:{_tag(json.dumps(v))}", _dump(_replace(record, path, v)))
    yield Case("deep_nesting", b"[" * 100_000 + b"]" * 100_000)
    yield Case("deep_in_field", _dump({**record, "notes": "@DEEP@"}).replace(
        b'"@DEEP@"', b"[" * 50_000 + b"]" * 50_000))
    yield Case("not_an_object", b"[1, 2, 3]")
    yield Case("nan_literal", data.replace(b": 0", b": NaN", 1))


def _dump(obj) -> bytes:
    return json.dumps(obj, indent=1).encode()


# --------------------------------------------------------------------------------------------
# NumPy .npz archives (MCMC chains)
# --------------------------------------------------------------------------------------------


def npz_cases(data: bytes):
    import numpy as np

    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        members = {i.filename: zf.read(i.filename) for i in zf.infolist()}
    first = sorted(members)[0]

    def rebuild(changed, compress=zipfile.ZIP_STORED):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", compress) as zf:
            for k, v in {**members, **changed}.items():
                if v is not None:
                    zf.writestr(zipfile.ZipInfo(k, (1980, 1, 1, 0, 0, 0)), v, compress)
        return buf.getvalue()

    def npy(arr, **kw):
        b = io.BytesIO()
        np.save(b, arr, **kw)
        return b.getvalue()

    for name, blob in members.items():
        arr = np.load(io.BytesIO(blob), allow_pickle=False)
        key = name[:-4]
        header_end = blob.index(b"\n") + 1
        shape = repr(tuple(arr.shape)).encode()
        huge = repr((1 << 40,) + tuple(arr.shape[1:])).encode()
        yield Case(f"{key}:declares_2^40", rebuild({name: blob[:header_end].replace(
            shape, huge.ljust(len(shape)) if len(huge) <= len(shape) else huge) + blob[header_end:]}),
            allocation=True)
        yield Case(f"{key}:object_array", rebuild({name: npy(np.array([{"a": 1}] * 3), allow_pickle=True)}))
        yield Case(f"{key}:deleted", rebuild({name: None}))
        yield Case(f"{key}:truncated", rebuild({name: blob[: len(blob) // 2]}))
        if arr.dtype.kind == "f":
            bad = arr.copy()
            bad.flat[bad.size // 2] = np.nan
            yield Case(f"{key}:nan", rebuild({name: npy(bad)}))
            yield Case(f"{key}:strings", rebuild({name: npy(arr.astype(str)[..., :1])}))
            yield Case(f"{key}:scalar", rebuild({name: npy(np.float64(1.0))}))
            yield Case(f"{key}:empty", rebuild({name: npy(arr[:0])}))
        else:
            yield Case(f"{key}:numbers", rebuild({name: npy(np.arange(arr.size))}))
    deflated = rebuild({}, zipfile.ZIP_DEFLATED)
    b = bytearray(deflated)
    with zipfile.ZipFile(io.BytesIO(deflated)) as zf:
        info = zf.getinfo(first)
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    for k in range(start + 10, start + min(info.compress_size, 400), 37):
        b[k] ^= 0x5A
    yield Case("corrupted_deflate", bytes(b))
    yield Case("not_a_zip", b"PK\x03\x04" + b"\x00" * 100)
    yield Case("plain_npy", npy(np.zeros(3)))


# --------------------------------------------------------------------------------------------
# The contract
# --------------------------------------------------------------------------------------------


@dataclass
class Outcome:
    status: int | None
    err: str
    exception: BaseException | None = None
    peak: int = 0
    problems: list = field(default_factory=list)


NONFINITE = re.compile(r"(?<![A-Za-z_])(nan|inf|infinity)(?![A-Za-z_])", re.IGNORECASE)


def run_contract(argv, case_file: Path, out_dir: Path, *, allocation=False,
                 capsys=None) -> Outcome:
    """Run ``fitlab ARGV`` in-process and check the contract; ``Outcome.problems`` lists each
    breach (empty when the command behaved)."""
    from fitlab.cli import main

    before = _fingerprint(case_file)
    err_buf, out_buf = io.StringIO(), io.StringIO()
    exc = None
    status = None
    if allocation:
        tracemalloc.start()
    try:
        with contextlib.redirect_stderr(err_buf), contextlib.redirect_stdout(out_buf):
            status = main([str(a) for a in argv])
    except SystemExit as e:  # argparse
        status = e.code
    except BaseException as e:  # noqa: BLE001 - the contract forbids any
        exc = e
    finally:
        peak = 0
        if allocation:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    err = err_buf.getvalue()
    o = Outcome(status, err, exc, peak)
    if exc is not None:
        o.problems.append(f"raised {type(exc).__name__}: {str(exc)[:300]}")
    elif status not in (0, 2):
        o.problems.append(f"exit status {status}")
    if "Traceback" in err:
        o.problems.append("traceback on stderr")
    if "root:x:0:0" in err + out_buf.getvalue():
        o.problems.append("shows the content of a system file (external entity or path)")
    if status == 2:
        if len(err) > MAX_MESSAGE:
            o.problems.append(f"message of {len(err)} characters: {err[:200]!r}...")
        if str(case_file) not in err and case_file.name not in err:
            o.problems.append(f"message does not name the file: {err.strip()[:300]!r}")
        written = [p.name for p in out_dir.rglob("*")] if out_dir.exists() else []
        if written:
            o.problems.append(f"wrote {written[:5]} on failure")
    elif status == 0:
        for p in (out_dir.rglob("*") if out_dir.exists() else []):
            if p.is_file() and p.suffix == ".json":  # numbers only: text fields may say "nan"
                def refuse(name):
                    raise ValueError(name)
                try:
                    json.loads(p.read_text(errors="replace"), parse_constant=refuse)
                except ValueError as exc:
                    o.problems.append(f"exit 0 but {p.name} holds {exc}")
            elif p.is_file() and p.suffix in (".csv", ".bsdf", ".txt"):
                text = p.read_text(errors="replace")
                body = "\n".join(l for l in text.splitlines() if not l.lstrip().startswith("#"))
                m = NONFINITE.search(body)
                if m:
                    o.problems.append(f"exit 0 but {p.name} holds {m.group(0)!r}")
    if _fingerprint(case_file) != before:
        o.problems.append("input modified")
    if allocation and peak > MAX_ALLOCATION:
        o.problems.append(f"allocated {peak / 2 ** 20:.0f} MiB")
    return o


def _fingerprint(path: Path):
    if path.is_dir():
        return sorted((p.name, p.read_bytes()) for p in path.iterdir())
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else None


def fresh(tmp: Path, case: Case, suffix: str) -> tuple[Path, Path]:
    """(input file written from ``case``, empty output folder) in a new folder under ``tmp``."""
    d = tmp / f"c{abs(hash(case.name)) % 10 ** 10}"
    if d.exists():
        shutil.rmtree(d)
    d.mkdir()
    src = case.write(d / f"input{suffix}")
    out = d / "out"
    out.mkdir()
    return src, out
