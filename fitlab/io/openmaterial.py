"""ASAM OpenMATERIAL 3D BRDF look-up tables (``*_brdf.xompt``): JSON with a ``metadata`` object
and a ``brdf`` object whose ``lookupTable`` rows are ``[wavelength (m), θi (rad), θo (rad),
φo (rad), BRDF (1/sr)]``. Spec: data_formats/openmaterial_xompt.md.

Every file is validated against the standard's published schema (bundled:
fitlab/io/schemas/openmaterial_brdf_schema.json, MPL-2.0), then by fitlab's own checks (no
null or non-finite number, every row's wavelength listed in ``wavelengths`` and every listed
wavelength used, no two rows at one wavelength and direction pair, receiver solid angles of
listed wavelengths below a hemisphere).

Frame (data_formats/CONVENTIONS.md): the schema states "Exit azimuth angle in rad. The value
is relative to the incident azimuth angle. The incident azimuth angle is set to 0, because the
incident ray is used as the reference." fitlab reads the incident direction as the
radiometric one (toward the source, as in the BRDF definition the schema quotes), so the light
lies at φi = 0 and φo is the file's azimuth: φo = 0 is the light's side (θo = θi is
retro-reflection), φo = 180° the specular side. Angles become degrees, the wavelengths spectral
channels ``<λ>nm``, the values f in 1/sr.
"""

from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path

import numpy as np

from fitlab.errors import InputFileError, quote
from fitlab.io.directions import degrees_to_direction
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.format import Format
from fitlab.io.measurement import MAX_ABS_VALUE, Measurement, describe_loaded
from fitlab.io.validate import (check_count, is_finite_number, json_path, kind_of, load_json,
                                shown_number)

NAME = "openmaterial"
SUFFIX = ".xompt"
SPEC = "data_formats/openmaterial_xompt.md"
SCHEMA_FILE = Path(__file__).resolve().parent / "schemas" / "openmaterial_brdf_schema.json"
#: What the bundled schema is (fitlab/io/schemas/SOURCE-openmaterial.txt).
SCHEMA_SOURCE = ("github.com/asam-ev/OpenMATERIAL-3D schemas/material_brdf_schema.json at "
                 "d8f359a (tag v1.1.0-rc1)")
#: The fields of a lookupTable row, as messages name them.
ROW_FIELDS = ("wavelength, m", "θi, rad", "θo, rad", "φo, rad", "BRDF, 1/sr")
#: The largest zenith and azimuth angles the schema allows (rad).
MAX_ZENITH = 1.570796
MAX_AZIMUTH = 6.283185
#: Degrees are rounded to this many decimals on reading (1e-9° = 1.7e-11 rad, far below any
#: instrument): a grid written in whole degrees reads back in whole degrees.
DEGREE_DECIMALS = 9
#: Wavelengths are compared and named in nm rounded to this many decimals.
NM_DECIMALS = 6
#: The prefix of the metadata keys a Measurement carries from the file's ``metadata``.
META_PREFIX = "openmaterial_"
HINT = f"give an ASAM OpenMATERIAL 3D BRDF look-up table ({SPEC})"
#: The top-level field beside the standard's in which ``fitlab convert DATA --complete FIT.json
#: OUT.xompt`` lists the rows whose value is a fit's, not a reading: {"rows": [[λ (m), θi, θo,
#: φo (rad), reason], ...]} (data_formats/completion_json.md). fitlab reads those rows as no
#: reading (the Measurement's gaps); other readers of the standard ignore the field.
COMPLETION_FIELD = "fitlabCompletion"
DEGREES_HINT = "convert the file's angles to radians (× π/180); fitlab converts them to degrees"


# --------------------------------------------------------------------------------------------
# The schema
# --------------------------------------------------------------------------------------------


@functools.cache
def schema() -> dict:
    """The bundled OpenMATERIAL BRDF schema (parsed once)."""
    return json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))


@functools.cache
def _validator():
    import jsonschema

    s = schema()
    return jsonschema.validators.validator_for(s)(s)


def metadata_fields() -> tuple[str, ...]:
    """The header fields the schema defines, in its order."""
    return tuple(schema()["properties"]["metadata"]["properties"])


def meta_key(field: str) -> str:
    """The Measurement metadata key of a file's metadata field: ``materialVersion`` ->
    ``openmaterial_material_version`` (lower case: CSV metadata keys are read lower-cased)."""
    return META_PREFIX + re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", field).lower()


def _field_name(items) -> str:
    """The field's JSON path, with what a lookupTable entry holds."""
    where = json_path(items) or "the top level"
    if len(items) == 4 and tuple(items[:2]) == ("brdf", "lookupTable") \
            and isinstance(items[3], int) and 0 <= items[3] < len(ROW_FIELDS):
        where += f" ({ROW_FIELDS[items[3]]})"
    return where


def _schema_problem(error) -> tuple[str, str, str]:
    """(where, what is wrong, what to do) of a jsonschema error, short, quoting file content
    briefly."""
    path, inst, v, rule = list(error.absolute_path), error.instance, error.validator, \
        error.validator_value
    if v == "required":
        missing = next((k for k in rule if isinstance(inst, dict) and k not in inst), rule[0])
        return (json_path(path + [missing]), "is missing (the schema requires it)",
                f"add it ({SPEC} says what each field holds)")
    where = _field_name(path)
    in_table = path[:2] == ["brdf", "lookupTable"] and len(path) == 4
    if v == "type":
        kinds = rule if isinstance(rule, list) else [rule]
        return (where, f"is {kind_of(inst)}; the schema expects {' or '.join(kinds)}",
                f"give {' or '.join(kinds)} there ({SPEC})")
    bounds = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">",
              "exclusiveMaximum": "<"}
    if v in bounds:
        hint = {1: "a zenith angle is measured from the normal, 0 to π/2 rad (the file holds "
                   "reflection only)", 2: "a zenith angle is measured from the normal, 0 to "
                   "π/2 rad (the file holds reflection only)", 3: "an azimuth is 0 to 2π rad",
                0: "a wavelength is in metres (550 nm is 5.5e-07)", 4: "a BRDF is >= 0 (1/sr)"}
        return (where, f"is {shown_number(inst)}; the schema requires {bounds[v]} {rule:.10g}",
                hint.get(path[3], f"give a value within the schema's range ({SPEC})")
                if in_table else f"give a value within the schema's range ({SPEC})")
    if v == "pattern":
        return (where, f"is {quote(inst)}; the schema requires the pattern {quote(rule, 80)}",
                "write it in that form (a uuid as 8-4-4-4-12 hexadecimal digits, a version as "
                "1.0.0, a date as 20240703T101728Z)")
    if v in ("minItems", "maxItems"):
        most = "at least" if v == "minItems" else "at most"
        return (where, f"has {len(inst)} entries; the schema requires {most} {rule}",
                "a table row is [wavelength (m), θi, θo, φo (rad), BRDF (1/sr)]" if
                path[:2] == ["brdf", "lookupTable"] else f"see {SPEC}")
    return where, f"does not match the schema ({quote(error.message, 120)})", HINT


def _angle_maximum(doc) -> float:
    """The largest angle (θi, θo, φo) of the lookupTable rows that are lists of numbers."""
    rows = doc.get("brdf", {}).get("lookupTable") if isinstance(doc.get("brdf"), dict) else None
    top = 0.0
    for row in rows if isinstance(rows, list) else ():
        if isinstance(row, list):
            for v in row[1:4]:
                if isinstance(v, (int, float)) and not isinstance(v, bool) and v > top:
                    top = float(v)
    return top


def schema_errors(doc):
    """The schema's errors of a parsed document, in the schema's order (lazily)."""
    return _validator().iter_errors(doc)


def check_schema(path, doc) -> None:
    """``doc`` valid against the bundled schema, else an InputFileError naming the first field
    that is not (a file in degrees is called so)."""
    error = next(iter(schema_errors(doc)), None)
    if error is None:
        return
    where, problem, hint = _schema_problem(error)
    items = list(error.absolute_path)
    if error.validator == "maximum" and items[:2] == ["brdf", "lookupTable"] \
            and len(items) == 4 and items[3] in (1, 2, 3):
        top = _angle_maximum(doc)
        if 2 * math.pi < top <= 360.0:
            raise InputFileError(path, f"field {where} is {shown_number(error.instance)}: the "
                                 f"largest angle in the table is {top:g}, so the angles look "
                                 "like degrees, but the standard states radians (θ up to π/2, "
                                 "φ up to 2π)", hint=DEGREES_HINT)
    raise InputFileError(path, f"field {where} {problem}", hint=hint)


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def load_document(path) -> dict:
    """The parsed file, valid against the schema (InputFileError otherwise)."""
    raw = read_bytes(path)
    doc = load_json(path, raw, what="OpenMATERIAL BRDF", hint=HINT)
    if not isinstance(doc, dict):
        raise InputFileError(path, f"is not an OpenMATERIAL BRDF look-up table: its top level "
                             f"is {kind_of(doc)}, not an object", hint=HINT)
    brdf = doc.get("brdf")
    table = brdf.get("lookupTable") if isinstance(brdf, dict) else None
    if isinstance(table, list):  # the arrays fitlab will make of it, before the schema's walk
        check_count(len(table) * len(ROW_FIELDS), path, what="field brdf.lookupTable: values")
    check_schema(path, doc)
    return doc


def _fail(path, items, problem, hint) -> InputFileError:
    return InputFileError(path, f"field {_field_name(items)} {problem}", hint=hint)


def table_arrays(path, doc) -> dict:
    """The lookupTable of a schema-valid document as checked arrays: ``rows`` (N, 5) in the
    file's units, ``channel`` (N,) index into ``wavelength_nm`` (sorted, nm), the receiver
    solid angles per channel (sr, NaN where not given) and whether the rows are sorted as the
    standard requires."""
    brdf = doc["brdf"]
    table = brdf["lookupTable"]
    if not table:
        raise _fail(path, ["brdf", "lookupTable"], "holds no row", "give at least one row")
    for k, row in enumerate(table):
        for j, v in enumerate(row):
            if v is None:  # the schema allows null without saying what it means
                raise _fail(path, ["brdf", "lookupTable", k, j], "is null: fitlab needs a "
                            "number (the standard allows null but does not say what it means)",
                            "give the value, or remove the row if it holds no reading")
            if not is_finite_number(v):
                raise _fail(path, ["brdf", "lookupTable", k, j], "is not a finite number",
                            "replace the value by a finite number")
    rows = np.asarray(table, dtype=np.float64)
    big = np.flatnonzero(rows[:, 4] > MAX_ABS_VALUE)
    if big.size:
        raise _fail(path, ["brdf", "lookupTable", int(big[0]), 4], f"is {rows[big[0], 4]:.3g}, "
                    f"beyond {MAX_ABS_VALUE:g}", "check the units (1/sr); no surface reflects so")
    listed = np.asarray(brdf["wavelengths"], dtype=np.float64)  # the schema bounds them
    nm_listed = np.round(listed * 1e9, NM_DECIMALS)
    for j in range(len(nm_listed)):
        if nm_listed[j] in nm_listed[:j]:
            raise _fail(path, ["brdf", "wavelengths", j], f"lists {nm_listed[j]:g} nm again",
                        "list each wavelength once")
    nm = np.unique(nm_listed)
    nm_rows = np.round(rows[:, 0] * 1e9, NM_DECIMALS)
    unlisted = np.flatnonzero(~np.isin(nm_rows, nm))
    if unlisted.size:
        k = int(unlisted[0])
        raise _fail(path, ["brdf", "lookupTable", k, 0], f"is {nm_rows[k]:g} nm, which "
                    "brdf.wavelengths does not list", "list every wavelength of the table in "
                    "brdf.wavelengths")
    unused = [w for w in nm if w not in nm_rows]
    if unused:
        j = int(np.flatnonzero(nm_listed == unused[0])[0])
        raise _fail(path, ["brdf", "wavelengths", j], f"lists {unused[0]:g} nm, which no row "
                    "of brdf.lookupTable holds", "list only the wavelengths the table holds")
    names = [f"{w:g}nm" for w in nm]
    if len(set(names)) != len(names):
        raise _fail(path, ["brdf", "wavelengths"], "lists wavelengths closer than fitlab's "
                    "channel names tell apart (6 significant digits)",
                    "merge wavelengths that differ by less than a millionth")
    channel = np.searchsorted(nm, nm_rows)
    # one direction pair per row and wavelength: at θo = 0 the azimuth means nothing
    phi = np.where(rows[:, 2] == 0.0, 0.0, rows[:, 3])
    key = np.column_stack([channel, rows[:, 1], rows[:, 2], phi])
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    repeated = np.flatnonzero(first[inverse] != np.arange(len(rows)))
    if repeated.size:
        k = int(repeated[0])
        j = int(first[inverse[k]])
        raise _fail(path, ["brdf", "lookupTable", k], f"repeats the wavelength and direction "
                    f"pair of brdf.lookupTable[{j}]" + (" (at θo = 0 every φo is the normal)"
                                                       if rows[k, 2] == 0 else ""),
                    "merge repeated readings into one row or remove one")
    solid = np.full(len(nm), np.nan)
    for k, entry in enumerate(brdf.get("receiverSolidAngles") or ()):
        w = round(float(entry["wavelength"]) * 1e9, NM_DECIMALS)
        where = ["brdf", "receiverSolidAngles", k]
        if w not in nm:
            raise _fail(path, where + ["wavelength"], f"is {w:g} nm, which brdf.wavelengths "
                        "does not list", "give a solid angle per wavelength of the table")
        c = int(np.searchsorted(nm, w))
        if not np.isnan(solid[c]):
            raise _fail(path, where + ["wavelength"], f"gives {w:g} nm a second solid angle",
                        "give one solid angle per wavelength")
        omega = entry["solidAngle"]
        if not (is_finite_number(omega) and omega < 2 * math.pi):
            raise _fail(path, where + ["solidAngle"], f"is {shown_number(omega)} sr; a receiver "
                        "sees less than a hemisphere (2π sr)", "give the receiver's solid "
                        "angle in steradians")
        solid[c] = float(omega)
    order = np.lexsort(rows[:, 3::-1].T)
    return {"rows": rows, "channel": channel, "wavelength_nm": nm, "channel_names": names,
            "solid_angle_sr": solid, "sorted": bool(np.all(order == np.arange(len(rows))))}


def cone_half_angle_deg(omega_sr):
    """The half-angle (degrees) of the circular cone of solid angle ``omega_sr``:
    Ω = 2π(1 − cos α)."""
    return np.degrees(np.arccos(1.0 - np.asarray(omega_sr, dtype=np.float64) / (2 * np.pi)))


#: Control characters (line breaks, tabs, NUL): a metadata value is one line of text.
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def file_metadata(doc) -> dict:
    """The file's metadata as a Measurement carries it: ``openmaterial_<field>`` for each field
    the schema defines (lists as JSON text, control characters such as line breaks as spaces:
    each value is one ``# key: value`` line of fitlab's CSV), plus the source format."""
    meta = {"source_format": "ASAM OpenMATERIAL 3D BRDF look-up table (.xompt)"}
    given = doc["metadata"]
    for name in metadata_fields():
        if name in given:
            v = given[name]
            meta[meta_key(name)] = _CONTROL.sub(" ", v) if isinstance(v, str) else \
                json.dumps(v, ensure_ascii=False)
    return meta


def metadata_from(meta: dict) -> dict:
    """The file metadata a Measurement's metadata (or a fit's ``data.metadata``) carries, the
    inverse of :func:`file_metadata`: {field: value} typed as the schema types it; {} when it
    carries none (the data did not come from an OpenMATERIAL file)."""
    out = {}
    for name, spec in schema()["properties"]["metadata"]["properties"].items():
        key = meta_key(name)
        if key not in meta:
            continue
        v = meta[key]
        if spec.get("type") == "array":
            try:
                v = json.loads(v) if isinstance(v, str) else v
            except ValueError:
                v = [v]
            if not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
                v = [str(v)]
        out[name] = v if isinstance(v, (str, list)) else str(v)
    return out


def to_degrees(radians) -> np.ndarray:
    return np.round(np.degrees(np.asarray(radians, dtype=np.float64)), DEGREE_DECIMALS) + 0.0


def _measurement(path, doc, arrays) -> Measurement:
    rows, channel = arrays["rows"], arrays["channel"]
    theta_i, theta_o, phi_o = (to_degrees(rows[:, j]) for j in (1, 2, 3))
    phi_i = np.zeros_like(theta_i)
    solid = arrays["solid_angle_sr"]
    aperture = None
    if np.any(np.isfinite(solid)):  # a receiver cone where the file gives one, else a point
        aperture = np.where(np.isfinite(solid), cone_half_angle_deg(np.nan_to_num(solid)),
                            0.0)[channel]
    return Measurement(
        path=str(path), sha256=sha256_of(Path(path)), theta_i=theta_i, phi_i=phi_i,
        theta_o=theta_o, phi_o=phi_o, wi=degrees_to_direction(theta_i, phi_i),
        wo=degrees_to_direction(theta_o, phi_o), value=rows[:, 4].copy(), sigma=None,
        channel=channel, channel_names=tuple(arrays["channel_names"]),
        wavelength_nm=arrays["wavelength_nm"], quantity="bsdf", file_quantity="bsdf",
        metadata=file_metadata(doc), lines=np.arange(1, len(rows) + 1), aperture_deg=aperture)


def completion_labels(path, doc, rows) -> np.ndarray:
    """Per table row MEASURED, or the reason the file's :data:`COMPLETION_FIELD` gives for a
    row whose value a completion filled in; an InputFileError for a field that is not a list
    of [wavelength, θi, θo, φo, reason] naming rows of the table."""
    from fitlab.io.measurement import GAP_REASONS, MEASURED

    labels = np.full(len(rows), MEASURED, dtype=object)
    marks = doc.get(COMPLETION_FIELD)
    if marks is None:
        return labels
    hint = ("list the completed rows as [wavelength, θi, θo, φo, reason] with a reason among "
            f"{', '.join(GAP_REASONS)} (data_formats/completion_json.md), or remove the field")
    listed = marks.get("rows") if isinstance(marks, dict) else None
    if not isinstance(listed, list):
        raise _fail(path, [COMPLETION_FIELD], "is not an object with a list rows", hint)
    check_count(len(listed), path, what=f"field {COMPLETION_FIELD}.rows")
    index = {tuple(r[:4]): k for k, r in enumerate(rows.tolist())}
    for k, r in enumerate(listed):
        where = [COMPLETION_FIELD, "rows", k]
        if not (isinstance(r, list) and len(r) == 5 and all(map(is_finite_number, r[:4]))
                and r[4] in GAP_REASONS):
            raise _fail(path, where, "is not [wavelength, θi, θo, φo, reason]", hint)
        j = index.get(tuple(float(x) for x in r[:4]))
        if j is None:
            raise _fail(path, where, "names no row of brdf.lookupTable", hint)
        labels[j] = r[4]
    return labels


def _read(path, doc, arrays) -> Measurement:
    """The Measurement of a checked document: the rows a completion filled in are its gaps."""
    from fitlab.io.measurement import MEASURED, split_gaps

    m = _measurement(path, doc, arrays)
    labels = completion_labels(path, doc, arrays["rows"])
    if np.all(labels != MEASURED):
        raise _fail(path, [COMPLETION_FIELD], "marks every row as filled in: the file holds "
                    "no reading", "give a file with measured rows")
    return split_gaps(m, labels != MEASURED, labels)


def read_openmaterial(path, accept=()) -> Measurement:
    """Read an OpenMATERIAL BRDF look-up table (validated) to a Measurement: one row per table
    row, the wavelengths as spectral channels, angles in degrees, f in 1/sr. ``lines`` holds
    each row's 1-based index in ``brdf.lookupTable``; rows a completion filled in
    (:data:`COMPLETION_FIELD`) are its gaps. ``accept``: sanity gates accepted (they run in
    read_any)."""
    path = Path(path)
    doc = load_document(path)
    return _read(path, doc, table_arrays(path, doc))


def view_directions(m, rows=None) -> int:
    """How many distinct view directions ``m``'s rows (all, or ``rows``) have."""
    wo = m.wo if rows is None else m.wo[rows]
    return len(np.unique(np.round(wo, 9) + 0.0, axis=0))


def describe_openmaterial(path, format_name: str = NAME, accept=()) -> dict:
    path = Path(path)
    doc = load_document(path)
    arrays = table_arrays(path, doc)
    m = _read(path, doc, arrays)
    info = describe_loaded(m, format_name, accept)
    views = view_directions(m)
    if views == 1:
        info["warnings"] = info["warnings"] + [
            f"every row has one view direction (θo = {m.theta_o[0]:g}°, φo = "
            f"{m.phi_o[0]:g}°): fitlab fit refuses it, as one view direction cannot constrain "
            "a BRDF model"]
    if not arrays["sorted"]:
        info["warnings"] = info["warnings"] + [
            "the rows are not sorted by wavelength, θi, θo, φo as the standard requires "
            "(checker rule asam.net:xom:1.0.0:xompt.tables_sorted_correctly); fitlab reads "
            "them in any order"]
    solid = arrays["solid_angle_sr"]
    info.update({
        "rows_in_file": int(len(arrays["rows"])),
        "wavelength_nm": [float(w) for w in arrays["wavelength_nm"]],
        "view_directions": views,
        "receiver_solid_angle_sr": {n: (None if np.isnan(s) else float(s))
                                    for n, s in zip(arrays["channel_names"], solid)}
        if np.any(np.isfinite(solid)) else "not given (read as a point detector)",
        "schema": f"valid ({SCHEMA_SOURCE})",
        "units_in_file": "wavelength m, angles rad, BRDF 1/sr (read as nm, degrees, 1/sr)",
        "azimuth_convention": "phi_o relative to the incidence: light at phi_i = 0, phi_o = 0 "
                              "its side (retro-reflection at theta_o = theta_i), phi_o = 180° "
                              "the specular side",
        "sorted_as_the_standard_requires": arrays["sorted"],
    })
    return info


#: The top-level ``"brdf": {`` of an OpenMATERIAL BRDF file (or the schema's name).
_SIGNATURE = re.compile(rb'"brdf"\s*:\s*\{|material_brdf_schema')


def _detect(head: bytes, path) -> bool:
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    return text[:1] == b"{" and _SIGNATURE.search(head) is not None


FORMAT = Format(NAME, "ASAM OpenMATERIAL 3D BRDF look-up table (JSON, *_brdf.xompt; "
                "validated against the standard's schema)", _detect, read_openmaterial,
                describe_openmaterial, SPEC, suffixes=(SUFFIX,))
