"""OpenEXR files of fitlab lookup tables (data_formats/lut_exr.md): write, read, describe.

API (also what ``fitlab report`` uses to preview LUTs)::

    write_exr(path, table)        # atomic: a temporary file beside ``path``, then a rename
    table = read_exr(path)        # -> fitlab.lut.Table (values float64 (H, W, C), axes, accuracy…)
    info = describe_exr(path)     # header only -> JSON-ready dict (what `fitlab info` prints)

Channels are stored as HALF or FLOAT (never 8-bit), one EXR channel per table channel, ZIP
compressed. All metadata lives in header attributes named ``fitlab.*`` (strings; structured
values are JSON). :func:`read_exr` validates everything and raises
:class:`fitlab.errors.InputFileError` naming the file and the attribute at fault.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np

from fitlab.version import __version__
from fitlab.errors import FitlabError, InputFileError
from fitlab.io.validate import check_allocation, quote
from fitlab.io.exr_image import write_channels
from fitlab.io.conventions import CONVENTIONS
from fitlab.io.files import path_for_record, read_bytes, sha256_of
from fitlab.lut import (KINDS, MAPPINGS, PHI_D, SCHEMA, SCHEMA_VERSION, SIZE_MAX, SIZE_MIN,
                        TEXEL_CONVENTION, Axis, Table)

#: First four bytes of every OpenEXR file.
MAGIC = b"\x76\x2f\x31\x01"
PREFIX = "fitlab."
#: Attributes every fitlab LUT carries (JSON-encoded unless noted).
REQUIRED = ("schema", "schema_version", "kind", "channels", "dtype", "axes", "quantity", "model",
            "params", "accuracy", "texel_convention", "conventions", "version")


def header_attributes(table: Table, path=None) -> dict:
    """The ``fitlab.*`` header attributes of a table (all strings) to be written to ``path``.
    No clock time: the same table gives the same header. ``source_fit`` is recorded relative to
    ``path``'s folder (as given when there is no ``path``)."""
    attrs = {
        "schema": SCHEMA,
        "schema_version": str(SCHEMA_VERSION),
        "kind": table.kind,
        "channels": json.dumps(list(table.channels)),
        "dtype": table.dtype,
        "axes": json.dumps([a._asdict() for a in table.axes]),
        "quantity": table.quantity,
        "model": json.dumps(table.model),
        "params": json.dumps(table.params),
        "accuracy": json.dumps(table.accuracy, allow_nan=False),
        "texel_convention": TEXEL_CONVENTION,
        "conventions": json.dumps(CONVENTIONS),
        "version": __version__,
        "notes": json.dumps(list(table.notes)),
    }
    for k, a in enumerate(table.axes):  # readable copies for exrheader & co.
        attrs[f"axis{k}"] = (f"{a.name} in [{a.lo!r}, {a.hi!r}], {a.size} samples, mapping "
                             f"{a.mapping} ({MAPPINGS[a.mapping].formula})")
    if table.source_fit:
        attrs["source_fit"] = (path_for_record(table.source_fit, path) if path is not None
                               else str(table.source_fit))
        with contextlib.suppress(OSError):
            attrs["source_fit_sha256"] = sha256_of(table.source_fit)
    return {PREFIX + k: v for k, v in attrs.items()}


def write_exr(path, table: Table) -> None:
    """Write ``table`` to ``path`` atomically (nothing is left behind on failure)."""
    path = Path(path)
    if not path.parent.exists():
        raise FitlabError(f"{path}: the output folder {path.parent} does not exist; create it first")
    np_type = np.float16 if table.dtype == "half" else np.float32
    values = np.asarray(table.values)
    if not np.all(np.isfinite(values)):
        raise FitlabError(f"{path}: refusing to write a table with NaN or Inf values")
    channels = {name: np.ascontiguousarray(values[:, :, k].astype(np_type))
                for k, name in enumerate(table.channels)}
    write_channels(path, channels, header_attributes(table, path))


def _open(path, header_only: bool):
    import OpenEXR

    path = Path(path)
    if read_bytes(path, limit=len(MAGIC)) != MAGIC:
        raise InputFileError(path, "is not an OpenEXR file (wrong magic number)")
    try:
        return OpenEXR.File(str(path), separate_channels=True, header_only=header_only)
    except Exception as exc:  # the binding raises RuntimeError for any damage
        raise InputFileError(path, f"cannot be read as OpenEXR ({quote(str(exc), 120)})",
                             hint="the file is damaged or truncated; write it again with "
                             "`fitlab lut`") from None


def _attrs(path, header) -> dict:
    out = {k[len(PREFIX):]: v for k, v in header.items() if k.startswith(PREFIX)}
    if "schema" not in out:
        raise InputFileError(path, "is an OpenEXR file but not a fitlab lookup table (no "
                             "fitlab.schema attribute)", hint="see data_formats/lut_exr.md")
    if out["schema"] != SCHEMA:
        raise InputFileError(path, f"has schema {quote(out['schema'])}, expected {quote(SCHEMA)}",
                             column="fitlab.schema")
    if out.get("schema_version") != str(SCHEMA_VERSION):
        raise InputFileError(path, f"has schema_version {quote(out.get('schema_version'))}; this "
                             f"fitlab reads version {SCHEMA_VERSION}", column="fitlab.schema_version",
                             hint="write the table again with this fitlab version")
    for key in REQUIRED:
        if key not in out:
            raise InputFileError(path, "lacks a required attribute", column=PREFIX + key,
                                 hint="see data_formats/lut_exr.md for the attributes")
        if not isinstance(out[key], str):
            raise InputFileError(path, f"must be a string attribute, got {type(out[key]).__name__}",
                                 column=PREFIX + key)
    return out


def _json(path, attrs, key, kind):
    from fitlab.io.validate import load_json

    try:
        value = load_json(path, attrs[key].encode("utf-8"), what=f"{PREFIX}{key} attribute")
    except InputFileError as exc:
        raise InputFileError(path, str(exc).split(": ", 1)[-1], column=PREFIX + key) from None
    if not isinstance(value, kind):
        raise InputFileError(path, f"must be a JSON {kind.__name__ if isinstance(kind, type) else 'value'}",
                             column=PREFIX + key)
    return value


def _axes(path, attrs):
    raw = _json(path, attrs, "axes", list)
    axes = []
    for k, a in enumerate(raw):
        col = f"{PREFIX}axes[{k}]"
        if not isinstance(a, dict) or set(a) != set(Axis._fields):
            raise InputFileError(path, f"each axis needs exactly the fields {', '.join(Axis._fields)}",
                                 column=col)
        if not isinstance(a["mapping"], str) or a["mapping"] not in MAPPINGS:
            raise InputFileError(path, f"unknown mapping {quote(a['mapping'])}", column=col,
                                 hint=f"mappings: {', '.join(MAPPINGS)}")
        size = a["size"]
        if isinstance(size, bool) or not isinstance(size, int) or not SIZE_MIN <= size <= SIZE_MAX:
            raise InputFileError(path, f"size must be an integer in [{SIZE_MIN}, {SIZE_MAX}]",
                                 column=col)
        try:
            lo, hi = float(a["lo"]), float(a["hi"])
        except (TypeError, ValueError):
            raise InputFileError(path, "lo and hi must be numbers", column=col) from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi) or (a["mapping"] == "log" and lo <= 0):
            raise InputFileError(path, f"invalid range [{lo}, {hi}] for mapping {a['mapping']}",
                                 column=col)
        axes.append(Axis(str(a["name"]), lo, hi, size, a["mapping"], str(a["description"])))
    return tuple(axes)


def read_exr(path) -> Table:
    """Read and validate a fitlab LUT → :class:`fitlab.lut.Table` (values as float64)."""
    path = Path(path)
    header = _open(path, header_only=True).header()
    attrs = _attrs(path, header)
    kind = attrs["kind"]
    if kind not in KINDS:
        raise InputFileError(path, f"unknown table kind {quote(kind)}", column=PREFIX + "kind",
                             hint=f"kinds: {', '.join(KINDS)}")
    channels = _json(path, attrs, "channels", list)
    axes = _axes(path, attrs)
    k = KINDS[kind]
    if len(axes) not in k.axis_counts:
        counts = " or ".join(str(c) for c in k.axis_counts)
        raise InputFileError(path, f"a {kind} table has {counts} axes, the header "
                             f"declares {len(axes)}", column=PREFIX + "axes")
    names = tuple(a.name for a in axes)
    if names != k.all_axis_names[: len(axes)]:
        raise InputFileError(path, f"a {len(axes)}-axis {kind} table has the axes "
                             f"{', '.join(k.all_axis_names[: len(axes)])}, the header declares "
                             f"{', '.join(names)}", column=PREFIX + "axes")
    for a in axes:  # the model table's φd: [0°, 90°] (reciprocity fold) or [0°, 180°]
        if a.name == PHI_D and (a.lo != 0.0 or a.hi not in (90.0, 180.0)):
            raise InputFileError(path, f"axis phi_d must span [0, 90] or [0, 180] degrees, got "
                                 f"[{a.lo}, {a.hi}]", column=PREFIX + "axes",
                                 hint="see data_formats/lut_exr.md, the model table")
    dtype = attrs["dtype"]
    if dtype not in ("half", "float"):
        raise InputFileError(path, f"dtype must be half or float, got {quote(dtype)}",
                             column=PREFIX + "dtype")
    if len(axes) == 1:
        shape = (1, axes[0].size)
    else:
        shape = (axes[1].size * (axes[2].size if len(axes) == 3 else 1), axes[0].size)
    try:
        (x0, y0), (x1, y1) = (tuple(int(v) for v in w) for w in header["dataWindow"])
    except (KeyError, TypeError, ValueError):
        raise InputFileError(path, "has no valid data window", column="dataWindow") from None
    if (y1 - y0 + 1, x1 - x0 + 1) != shape:
        raise InputFileError(path, f"the image is {x1 - x0 + 1} x {y1 - y0 + 1} pixels; the axes "
                             f"need {shape[1]} x {shape[0]}", column="dataWindow",
                             hint="write the table again with `fitlab lut`")
    check_allocation((len(channels),) + shape, path, what="the table", column="dataWindow")
    try:
        pixels = {name: c.pixels for name, c in _open(path, header_only=False).channels().items()}
    except InputFileError:
        raise
    except Exception as exc:  # the binding raises RuntimeError/ValueError for any damage
        raise InputFileError(path, f"its pixels cannot be read ({quote(str(exc), 120)})",
                             hint="the file is damaged or truncated; write it again with "
                             "`fitlab lut`") from None
    if sorted(pixels) != sorted(channels):
        raise InputFileError(path, f"the file holds channels {sorted(pixels)} but the header "
                             f"declares {channels}", column=PREFIX + "channels")
    want = np.float16 if dtype == "half" else np.float32
    cols = []
    for name in channels:
        p = pixels[name]
        if p.dtype != want:
            raise InputFileError(path, f"channel is {p.dtype}, the header says {dtype}",
                                 column=name, hint="only HALF or FLOAT channels are valid")
        if p.shape != shape:
            raise InputFileError(path, f"channel has {p.shape[1]} x {p.shape[0]} pixels; the "
                                 f"axes need {shape[1]} x {shape[0]}", column=name)
        if not np.all(np.isfinite(p)):
            raise InputFileError(path, f"channel holds {int(np.sum(~np.isfinite(p)))} NaN or Inf "
                                 "values", column=name)
        cols.append(p.astype(np.float64))
    model = _json(path, attrs, "model", (dict, type(None)))
    params = _json(path, attrs, "params", dict)
    accuracy = _json(path, attrs, "accuracy", dict)
    notes = tuple(_json(path, attrs, "notes", list)) if "notes" in attrs else ()
    return Table(kind, np.stack(cols, axis=-1), tuple(channels), axes, dtype, attrs["quantity"],
                 model, params, accuracy, attrs.get("source_fit"), notes)


def describe_exr(path) -> dict:
    """What ``fitlab info`` shows: every fitlab attribute, decoded, the image layout and each
    channel's value range. The whole file is validated first (as :func:`read_exr` does)."""
    path = Path(path)
    table = read_exr(path)
    f = _open(path, header_only=True)
    header = f.header()
    attrs = _attrs(path, header)
    (x0, y0), (x1, y1) = (tuple(int(v) for v in w) for w in header["dataWindow"])
    info = {"format": "fitlab-lut-exr", "format_description": "fitlab lookup table (OpenEXR)",
            "spec": "data_formats/lut_exr.md", "width": x1 - x0 + 1, "height": y1 - y0 + 1,
            "exr_channels": [c.name for c in header["channels"]]}
    for key, value in attrs.items():
        try:
            decoded = json.loads(value) if key in ("channels", "axes", "model", "params",
                                                   "accuracy", "conventions", "notes") else value
        except json.JSONDecodeError:
            decoded = value
        info[key] = decoded
    info["value_range"] = {ch: [float(table.values[..., k].min()), float(table.values[..., k].max())]
                           for k, ch in enumerate(table.channels)}
    if isinstance(info.get("axes"), list):
        info["axes"] = {f"axis{k}": a for k, a in enumerate(info["axes"])}
    return info


def is_exr(path) -> bool:
    p = Path(path)
    return p.is_file() and read_bytes(p, limit=len(MAGIC)) == MAGIC


__all__ = ["write_exr", "read_exr", "describe_exr", "header_attributes", "is_exr"]
