"""OpenEXR files of fitlab lookup tables (data_formats/lut_exr.md): write, read, describe.

API (also what ``fitlab report`` uses to preview LUTs)::

    write_exr(path, table)        # atomic: a temporary file beside ``path``, then a rename
    table = read_exr(path)        # -> fitlab.lut.Table (values float64 (H, W, C), axes, accuracy…)
    info = describe_exr(path)     # header only -> JSON-ready dict (what `fitlab info` prints)

Channels are stored as HALF or FLOAT (never 8-bit), one EXR channel per table channel, ZIP
compressed. All metadata lives in header attributes named ``fitlab.*`` (strings; structured
values are JSON). :func:`read_exr` validates everything (the header record against its JSON
Schema, data_formats/schemas/lut.schema.json, then what a schema cannot say) and raises
:class:`fitlab.errors.InputFileError` naming the file and the attribute at fault.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np

from fitlab.version import __version__
from fitlab.errors import FitlabError, InputFileError
from fitlab.io.validate import check_allocation, check_schema, load_json, quote
from fitlab.io.exr_image import write_channels
from fitlab.io.conventions import CONVENTIONS
from fitlab.io.files import path_for_record, read_bytes, sha256_of
from fitlab.lut import KINDS, MAPPINGS, PHI_D, SCHEMA, SCHEMA_VERSION, TEXEL_CONVENTION, Axis, Table

#: First four bytes of every OpenEXR file.
MAGIC = b"\x76\x2f\x31\x01"
PREFIX = "fitlab."
#: The attributes whose strings are JSON (data_formats/lut_exr.md, "Header attributes"); the
#: header record (:func:`header_record`) holds them parsed.
JSON_ATTRIBUTES = ("channels", "axes", "model", "params", "accuracy", "conventions", "notes")
#: What a message about the header record says to do.
HEADER_HINT = ("write the table again with `fitlab lut` (data_formats/lut_exr.md lists the "
               "attributes)")


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


def header_record(path, header) -> dict:
    """The ``fitlab.*`` attributes of an OpenEXR ``header`` as one record under their own names,
    the JSON ones (:data:`JSON_ATTRIBUTES`) parsed: what data_formats/schemas/lut.schema.json
    describes (not yet validated against it). Every such attribute must be a string; JSON is
    parsed strictly and at most ``MAX_DEPTH`` deep."""
    record = {}
    for name, value in header.items():
        if not name.startswith(PREFIX):
            continue
        if not isinstance(value, str):
            raise InputFileError(path, f"must be a string attribute, got {type(value).__name__}",
                                 column=name, hint=HEADER_HINT)
        if name[len(PREFIX):] in JSON_ATTRIBUTES:
            try:
                value = load_json(path, value.encode("utf-8"), what=f"{name} attribute")
            except InputFileError as exc:
                raise InputFileError(path, str(exc).split(": ", 1)[-1], column=name,
                                     hint=HEADER_HINT) from None
        record[name] = value
    return record


def _attrs(path, header) -> dict:
    """The header record (:func:`header_record`), validated against its JSON Schema, keyed by
    the attribute names without ``fitlab.``."""
    schema = header.get(PREFIX + "schema")
    if schema is None:
        raise InputFileError(path, "is an OpenEXR file but not a fitlab lookup table (no "
                             "fitlab.schema attribute)", hint="see data_formats/lut_exr.md")
    if schema != SCHEMA:
        raise InputFileError(path, f"has schema {quote(schema)}, expected {quote(SCHEMA)}",
                             column="fitlab.schema")
    version = header.get(PREFIX + "schema_version")
    if version != str(SCHEMA_VERSION):
        raise InputFileError(path, f"has schema_version {quote(version)}; this "
                             f"fitlab reads version {SCHEMA_VERSION}", column="fitlab.schema_version",
                             hint="write the table again with this fitlab version")
    record = check_schema(header_record(path, header), "lut", path, hint=HEADER_HINT)
    return {k[len(PREFIX):]: v for k, v in record.items()}


def _axes(path, raw) -> tuple:
    """The axes of the header's (schema-valid) ``fitlab.axes``, each range checked."""
    axes = []
    for k, a in enumerate(raw):
        lo, hi = float(a["lo"]), float(a["hi"])
        if not lo < hi or (a["mapping"] == "log" and lo <= 0):
            raise InputFileError(path, f"invalid range [{lo}, {hi}] for mapping {a['mapping']}",
                                 column=f"{PREFIX}axes[{k}]",
                                 hint="lo must be below hi, and above 0 for a log mapping")
        axes.append(Axis(a["name"], lo, hi, a["size"], a["mapping"], a["description"]))
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
    channels = attrs["channels"]
    axes = _axes(path, attrs["axes"])
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
    notes = tuple(attrs.get("notes", ()))
    return Table(kind, np.stack(cols, axis=-1), tuple(channels), axes, dtype, attrs["quantity"],
                 attrs["model"], attrs["params"], attrs["accuracy"], attrs.get("source_fit"),
                 notes)


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
    info.update(attrs)  # the header record, its JSON attributes parsed
    info["value_range"] = {ch: [float(table.values[..., k].min()), float(table.values[..., k].max())]
                           for k, ch in enumerate(table.channels)}
    if isinstance(info.get("axes"), list):
        info["axes"] = {f"axis{k}": a for k, a in enumerate(info["axes"])}
    return info


def is_exr(path) -> bool:
    p = Path(path)
    return p.is_file() and read_bytes(p, limit=len(MAGIC)) == MAGIC


__all__ = ["write_exr", "read_exr", "describe_exr", "header_attributes", "header_record",
           "is_exr", "JSON_ATTRIBUTES"]
