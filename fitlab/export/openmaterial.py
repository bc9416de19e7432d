"""ASAM OpenMATERIAL 3D BRDF look-up tables (``.xompt``) written from a fit, a registry model or
measured data: ``fitlab convert`` (the ``openmaterial`` writer of fitlab.export.writers) and
``fitlab export --to openmaterial`` (fitlab.export.renderers) both end in
:func:`material_table`, or :func:`data_table` for measured data. Spec and the rules below:
data_formats/openmaterial_xompt.md; the reader is fitlab.io.openmaterial.

A model is sampled at the rows of a grid: the standard grid (θi 0–85° step 5°, θo 0–85°
step 5°, φo 0–345° step 15° relative to the incidence, one row at θo = 0) or the rows of a given
OpenMATERIAL file (``grid_from``), at the wavelengths of the fit's channels (``<λ>nm``), or at
``wavelength_nm`` for a single channel that names none. Values are f in 1/sr with 9 significant
digits, angles in radians (each the shortest decimal that reads back as the same degrees),
wavelengths in metres, rows sorted as the standard requires. The
file is checked against the standard's schema and fitlab's reader before it is written
(atomically); its uuid is a UUID 5 of its content, so the same inputs give the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io import openmaterial as om
from fitlab.io.atomic import atomic_write_text
from fitlab.version import __version__


class Grid(NamedTuple):
    """Angles in degrees of a tabulation grid (φo relative to the incidence)."""

    theta_i: tuple
    theta_o: tuple
    phi_o: tuple


#: The standard grid (data_formats/openmaterial_xompt.md, "Writing"): 18 × (17 × 24 + 1) =
#: 7,362 rows per wavelength. Zenith angles stop at 85°: the schema's largest, 1.570796 rad,
#: is just below 90°.
STANDARD_GRID = Grid(tuple(range(0, 90, 5)), tuple(range(0, 90, 5)), tuple(range(0, 360, 15)))
STANDARD_TEXT = ("the standard grid (θi 0–85° step 5°, θo 0–85° step 5°, φo 0–345° step 15° "
                 "relative to the incidence)")
#: What the writer states when it does not know (SPDX's word for "not asserted").
NOASSERTION = "NOASSERTION"
#: The versions the files fitlab writes declare: v1.0.0's structure (the optional
#: receiverSolidAngles of the bundled schema is written only for data that give a cone).
OPENMATERIAL_VERSION = "1.0.0"
SCHEMA_URL = ("https://raw.githubusercontent.com/asam-ev/OpenMATERIAL-3D/refs/tags/v1.0.0/"
              "schemas/material_brdf_schema.json")
MATERIAL_VERSION = "1.0.0"
#: Significant digits of the written values (a float32 reads back exactly).
VALUE_DIGITS = 9
#: The writer's settings (each a ``fitlab convert`` flag: --grid-from, --wavelength-nm, ...).
SETTINGS = ("grid_from", "wavelength_nm", "name", "description", "author", "copyright",
            "license", "sensor")
#: The top-level field of a completed measurement that lists the rows whose value is a fit's
#: (fitlab.io.openmaterial.COMPLETION_FIELD).
COMPLETION_FIELD = om.COMPLETION_FIELD
#: The name space of the files' UUID 5.
UUID_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_URL, "fitlab:openmaterial")


# --------------------------------------------------------------------------------------------
# Grids and wavelengths
# --------------------------------------------------------------------------------------------


def grid_rows(grid: Grid) -> np.ndarray:
    """(K, 3) rows θi, θo, φo in radians of a grid, sorted, one row (φo = 0) at θo = 0."""
    rows = [(ti, to, po) for ti in sorted(grid.theta_i) for to in sorted(grid.theta_o)
            for po in (sorted(grid.phi_o) if to > 0 else (0.0,))]
    return file_radians(np.asarray(rows, dtype=np.float64))


def file_radians(degrees) -> np.ndarray:
    """Angles in degrees as the radians a file holds: each the value with the fewest decimals
    that fitlab's reader (fitlab.io.openmaterial.to_degrees, degrees to 1e-9°) reads back as
    the same degrees. Whole degrees read back whole, and angles read from a file come back as
    the file wrote them (1.500983 rad stays 1.500983)."""
    exact = np.radians(np.asarray(degrees, dtype=np.float64))
    target, out = om.to_degrees(exact), exact.copy()
    todo = np.ones(exact.shape, dtype=bool)
    for decimals in range(17):
        candidate = np.round(exact, decimals)
        ok = todo & (om.to_degrees(candidate) == target)
        out[ok] = candidate[ok]
        todo &= ~ok
        if not todo.any():
            break
    return out + 0.0


def file_grid(path) -> dict:
    """{wavelength in nm: (K, 3) rows θi, θo, φo in radians} of an OpenMATERIAL file, read and
    checked as the reader does (its radians kept as they are)."""
    doc = om.load_document(path)
    arrays = om.table_arrays(path, doc)
    rows = arrays["rows"]
    return {float(w): rows[arrays["channel"] == c, 1:4]
            for c, w in enumerate(arrays["wavelength_nm"])}


def channel_wavelength(name: str) -> float | None:
    """The wavelength in nm a channel name ``<λ>nm`` states, else None."""
    if not name.endswith("nm"):
        return None
    try:
        w = float(name[:-2])
    except ValueError:
        return None
    return w if np.isfinite(w) and w > 0 else None


def _wavelengths(channels, wavelength_nm, source: str) -> list[float]:
    """The wavelength (nm) of each channel: the ones their names state, or ``wavelength_nm``
    for one channel that states none."""
    stated = [channel_wavelength(c) for c in channels]
    if all(w is not None for w in stated):
        if wavelength_nm is not None:
            raise FitlabError(f"--wavelength-nm {wavelength_nm:g}: {source} states its "
                              f"wavelengths ({', '.join(channels)}); drop --wavelength-nm")
        return [float(w) for w in stated]
    if len(channels) != 1:
        raise FitlabError(f"{source} has channels {', '.join(channels)}, not wavelengths; an "
                          "OpenMATERIAL table is indexed by wavelength: write one channel "
                          "(--channel NAME) with its wavelength (--wavelength-nm NM)")
    if wavelength_nm is None:
        raise FitlabError(f"{source}: channel {channels[0]} states no wavelength, and an "
                          "OpenMATERIAL table is indexed by wavelength: give --wavelength-nm "
                          "NM (e.g. 550 for visible light, 905 for a lidar)")
    w = float(wavelength_nm)
    if not (np.isfinite(w) and 1.0 <= w <= 17.16e6):
        raise FitlabError(f"--wavelength-nm {wavelength_nm}: the schema allows 1 nm to "
                          "17.16 mm (17,160,000 nm)")
    return [w]


def _nm_list(wavelengths) -> str:
    w = sorted(wavelengths)
    if len(w) > 4:
        return f"{len(w)} wavelengths, {w[0]:g} to {w[-1]:g} nm"
    return ", ".join(f"{x:g}" for x in w) + " nm"


def grid_text(grid: Grid) -> str:
    """How a grid is described in a file's header: its angles per axis, in degrees."""
    def axis(name, values):
        v = sorted(values)
        steps = set(np.round(np.diff(v), 9)) if len(v) > 2 else set()
        if len(steps) == 1:
            return f"{name} {v[0]:g}–{v[-1]:g}° step {steps.pop():g}°"
        return f"{name} " + ", ".join(f"{x:g}" for x in v) + "°"

    return (f"a grid of {axis('θi', grid.theta_i)}, {axis('θo', grid.theta_o)}, "
            f"{axis('φo', grid.phi_o)} relative to the incidence")


def _grid_for(wavelengths, grid_from, grid=None) -> tuple[dict, str]:
    """{nm: rows in radians} for each wavelength, and the grid's description."""
    if grid_from is None:
        grid = STANDARD_GRID if grid is None else Grid(*grid)
        rows = grid_rows(grid)
        return {w: rows for w in wavelengths}, (STANDARD_TEXT if grid == STANDARD_GRID
                                                else grid_text(grid))
    given = file_grid(grid_from)
    key = {round(w, om.NM_DECIMALS): w for w in given}
    missing = [w for w in wavelengths if round(w, om.NM_DECIMALS) not in key]
    if missing:
        raise FitlabError(f"--grid-from {grid_from}: holds {_nm_list(given)}, not "
                          f"{_nm_list(missing)}: the model's values at one wavelength say "
                          "nothing of another; give a grid file holding its wavelengths, or "
                          "leave --grid-from out (the standard grid)")
    return ({w: given[key[round(w, om.NM_DECIMALS)]] for w in wavelengths},
            f"the rows of {Path(grid_from).name}")


# --------------------------------------------------------------------------------------------
# The document
# --------------------------------------------------------------------------------------------


def _value(v: float) -> float:
    return float(f"{v:.{VALUE_DIGITS}g}")


def table_rows(wavelength_nm, angles, values) -> list:
    """lookupTable rows [λ (m), θi, θo, φo (rad), f (1/sr)] in the standard's order (sorted by
    wavelength, then θi, θo, φo)."""
    rows = [[float(w) / 1e9, float(a[0]), float(a[1]), float(a[2]), _value(f)]
            for w, a, f in zip(wavelength_nm, angles, values)]
    rows.sort(key=lambda r: r[:4])
    return rows


def _rows_text(rows) -> str:
    return "[\n" + ",\n".join(" " * 12 + json.dumps(r) for r in rows) + "\n        ]"


def document_text(doc: dict) -> str:
    """The file's text: 4-space indented JSON as the standard's examples, one table row a line
    (and one row a line of a completion's marks, :data:`COMPLETION_FIELD`)."""
    brdf = dict(doc["brdf"])
    table = brdf.pop("lookupTable")
    mark, marks = "@LOOKUP_TABLE@", "@COMPLETED_ROWS@"
    body = {**doc, "brdf": {**brdf, "lookupTable": mark}}
    completion = doc.get(COMPLETION_FIELD)
    if completion is not None:
        body[COMPLETION_FIELD] = {**completion, "rows": marks}
    text = json.dumps(body, indent=4, ensure_ascii=False)
    head, _, tail = text.rpartition(json.dumps(mark))
    text = head + _rows_text(table) + tail + "\n"
    if completion is not None:
        head, _, tail = text.rpartition(json.dumps(marks))
        text = head + _rows_text(completion["rows"]) + tail
    return text


def with_uuid(doc: dict) -> dict:
    """``doc`` with metadata.uuid a UUID 5 of the rest of its content (the same content, the
    same uuid)."""
    body = {**doc, "metadata": {k: v for k, v in doc["metadata"].items() if k != "uuid"}}
    digest = hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
    meta = {}
    for k in om.metadata_fields():  # the schema's order
        if k == "uuid":
            meta[k] = str(uuid.uuid5(UUID_NAMESPACE, digest))
        elif k in doc["metadata"]:
            meta[k] = doc["metadata"][k]
    return {**doc, "metadata": meta}


def _ordered(meta: dict) -> dict:
    return {k: meta[k] for k in om.metadata_fields() if meta.get(k) is not None}


def checked_text(doc: dict, what: str) -> str:
    """The text of ``doc``, read back and checked as fitlab's reader checks a file (the schema,
    then fitlab's rules) before anything is written."""
    text = document_text(doc)
    try:
        back = json.loads(text)
        om.check_schema(what, back)
        om.table_arrays(what, back)
    except InputFileError as exc:  # fitlab made it: a bug, never the user's input
        raise FitlabError(f"{what}: the OpenMATERIAL file fitlab made does not pass its own "
                          f"reader ({exc}); nothing was written. Please report this") from None
    return text


def metadata(source: dict, *, name, description, author=None, copyright=None, license=None,
             sensor=None, sources, keep=()) -> dict:
    """The header: the flags first, then the source file's fields (``source``: an
    OpenMATERIAL file's metadata, {} for other data), then the defaults (NOASSERTION where
    nothing is known). ``keep``: fields of ``source`` kept as they are (data written back:
    uuid, creationDate, versions)."""
    meta = {
        "name": name,
        "description": description,
        "materialVersion": source.get("materialVersion", MATERIAL_VERSION),
        "openMaterial3dVersion": OPENMATERIAL_VERSION,
        "copyrights": list(copyright) if copyright else source.get("copyrights", [NOASSERTION]),
        "license": license or source.get("license", NOASSERTION),
        "authors": list(author) if author else source.get("authors", [NOASSERTION]),
        "sources": sources,
        "typicalSensorTechnology": sensor or source.get("typicalSensorTechnology"),
    }
    meta.update({k: source[k] for k in keep if k in source})
    return _ordered(meta)


def _document(meta: dict, wavelengths_nm, rows, solid_angles=None) -> dict:
    brdf = {"wavelengths": [float(w) / 1e9 for w in sorted(wavelengths_nm)]}
    if solid_angles:
        brdf["receiverSolidAngles"] = [{"wavelength": float(w) / 1e9, "solidAngle": float(s)}
                                       for w, s in sorted(solid_angles.items())]
    brdf["lookupTable"] = rows
    return {"$schema": SCHEMA_URL, "metadata": meta, "brdf": brdf}


# --------------------------------------------------------------------------------------------
# A fit or a model
# --------------------------------------------------------------------------------------------


def _check_model(model):
    if not model.capabilities.reflection:
        raise FitlabError(f"model {model.name!r} does not reflect ({model.lobes}); an "
                          "OpenMATERIAL BRDF table holds reflection only: choose a reflecting "
                          "model")
    if not model.capabilities.isotropic:
        raise FitlabError(f"model {model.name!r} is anisotropic; an OpenMATERIAL BRDF table "
                          "has no incident azimuth (its φo is relative to the incidence), so "
                          "it holds an isotropic BRDF: choose an isotropic model")


def material_table(material, *, grid_from=None, wavelength_nm=None, name=None,
                   description=None, author=None, copyright=None, license=None, sensor=None,
                   grid: Grid | None = None, what: str = "the output") -> tuple[str, dict, dict]:
    """(text, document, summary) of a Material (fitlab.export.material: a fit's or a registry
    model's) sampled on the grid (the rows of the file ``grid_from``, else ``grid``, else the
    standard grid), at its channels' wavelengths; the header from the flags, else the fit's
    data when they came from an OpenMATERIAL file, else the defaults."""
    from fitlab.api import eval_bsdf
    from fitlab.io.directions import degrees_to_direction
    from fitlab.models import get_model

    model = get_model(material.model)
    _check_model(model)
    fit = material.data is not None
    label = Path(material.source).name if fit else "--model"
    channels = list(material.channels)
    wavelengths = _wavelengths(channels, wavelength_nm, label)
    angles, grid_said = _grid_for(wavelengths, grid_from, grid)
    cols_w, cols_a, cols_f = [], [], []
    for c, w in zip(channels, wavelengths):
        a = angles[w]
        ti, to, po = (np.degrees(a[:, j]) for j in range(3))
        wi = degrees_to_direction(ti, np.zeros_like(ti))
        wo = degrees_to_direction(to, po)
        f = np.asarray(eval_bsdf(model.name, material.channels[c], wi, wo, material.options),
                       dtype=np.float64)
        if not np.all(np.isfinite(f)) or np.any(f < 0):
            raise FitlabError(f"{label}: model {model.name} gives non-finite or negative values "
                              f"at channel {c}; nothing was written")
        cols_w.append(np.full(len(a), w))
        cols_a.append(a)
        cols_f.append(f)
    rows = table_rows(np.concatenate(cols_w), np.concatenate(cols_a), np.concatenate(cols_f))
    notes = []
    if model.capabilities.transmission:
        notes.append(f"model {model.name!r} also transmits light; the file holds its "
                     "reflection (BRDF) only")
    data = material.data or {}
    if data.get("quantity") == "relative":
        notes.append("relative fit: the 'scale' parameter is not applied; the file holds the "
                     "absolute model f")
    source = om.metadata_from(data.get("metadata") or {})
    given = "" if wavelength_nm is None else \
        f", its channel {channels[0]} written at {wavelengths[0]:g} nm"
    if fit:
        data_name = Path(str(data.get("path", "the data"))).name
        made = (f"the fitlab {__version__} model {model.name} fitted to {data_name} "
                f"({label}{given}), tabulated on {grid_said}")
        sources = ", ".join(s for s in (source.get("sources"), "model fitted by fitlab") if s)
        default_name = source.get("name") or f"{Path(data_name).stem} ({model.name})"
    else:
        made = f"the fitlab {__version__} model {model.name}{given}, tabulated on {grid_said}"
        sources = "model (fitlab)"
        default_name = model.name
    text_made = made[0].upper() + made[1:] + "."
    default_description = (f"{source['description'].rstrip()} {text_made}"
                           if source.get("description") else f"BRDF of {made}.")
    meta = metadata(source, name=name or default_name,
                    description=description or default_description, author=author,
                    copyright=copyright, license=license, sensor=sensor, sources=sources)
    doc = with_uuid(_document(meta, wavelengths, rows))
    text = checked_text(doc, what)
    values = np.array([r[4] for r in rows])
    summary = {"model": model.name, "channels": channels, "wavelength_nm": wavelengths,
               "rows": len(rows), "grid": grid_said, "uuid": doc["metadata"]["uuid"],
               "f_range": [float(values.min()), float(values.max())], "notes": notes}
    return text, doc, summary


def write_model(path, model: str, params: dict, options: dict | None = None, **settings) -> dict:
    """A registry model with ``params`` ({name: value}, or {channel <λ>nm: {name: value}})
    tabulated as an OpenMATERIAL file (atomically); ``settings``: :data:`SETTINGS`."""
    from fitlab.export.material import material_from_model

    params = dict(params or {})
    channels = params if params and all(isinstance(v, dict) for v in params.values()) \
        else {"Y": params}
    return _write(path, material_from_model(model, channels, options), settings)


def write_fit(path, fit_path, *, channel: str | None = None, **settings) -> dict:
    """A fit (parameter file) tabulated as an OpenMATERIAL file (atomically), one wavelength a
    channel (``channel``: only that one)."""
    from fitlab.export.material import material_from_fit
    from fitlab.fitting.result import load_fit

    return _write(path, material_from_fit(load_fit(fit_path), channel), settings)


def _write(path, material, settings) -> dict:
    text, _, summary = material_table(material, what=str(path), **settings)
    atomic_write_text(path, text)
    return {"path": str(path), **summary}


def export_parts(material, settings: dict) -> tuple[str, dict, dict]:
    """(text, document, conversion) of the ``openmaterial`` renderer export (fitlab export --to
    openmaterial; fitlab.export.renderers wraps them): the same table as ``fitlab convert``,
    on the standard grid, with the header's defaults."""
    from fitlab.export.material import ExportError

    unnamed = [c for c in material.channels if channel_wavelength(c) is None]
    if unnamed:
        raise ExportError(f"{Path(material.source).name}: channel(s) {', '.join(unnamed)} "
                          "state no wavelength, and an OpenMATERIAL table is indexed by "
                          "wavelength: write it with fitlab convert FIT.json OUT.xompt "
                          "--wavelength-nm NM (--channel NAME for one of several channels)")
    try:
        text, doc, s = material_table(material, **{k: v for k, v in settings.items()
                                                   if k in SETTINGS})
    except ExportError:
        raise
    except FitlabError as exc:  # what the format cannot hold: an export's refusal
        raise ExportError(str(exc)) from None
    return text, doc, {
        "what": f"BRDF table, {s['rows']} rows",
        "summary": f"the model's f at the rows of {s['grid']} (values to {VALUE_DIGITS} "
                   "significant digits; a renderer interpolates between them)",
        "warnings": s["notes"]}


# --------------------------------------------------------------------------------------------
# Measured data
# --------------------------------------------------------------------------------------------


def _radians_within(deg, limit: float):
    """Degrees to a file's radians (:func:`file_radians`); values up to 1e-9 rad above
    ``limit`` (the schema's own bound, read and converted back) set to it."""
    rad = file_radians(deg)
    return np.where((rad > limit) & (rad <= limit + 1e-9), limit, rad)


def data_table(m, source, *, grid_from=None, wavelength_nm=None, name=None, description=None,
               author=None, copyright=None, license=None, sensor=None,
               what: str = "the output", completion=None,
               completed_by: str | None = None) -> tuple[str, dict, dict]:
    """(text, document, summary) of measured data (a Measurement) as an OpenMATERIAL file: its
    rows as they are, the reflection rows of one incident azimuth, f in 1/sr. ``completion``:
    per row MEASURED or why its value is a fit's (listed in :data:`COMPLETION_FIELD`), and
    ``completed_by`` the sentence the description and sources add about it."""
    label = Path(m.path).name
    if grid_from is not None:
        raise FitlabError(f"--grid-from applies to a fit or a model, which fitlab samples on a "
                          f"grid; {label} is measured data, written on its own rows (fit a "
                          "model to resample it)")
    if m.quantity != "bsdf":
        raise FitlabError(f"{label} holds f up to an unknown scale (relative data); an "
                          "OpenMATERIAL table holds the BRDF in 1/sr: give the data in "
                          "absolute units")
    if m.bin_o_deg is not None or (m.source_divergence_deg is not None
                                   and np.any(m.source_divergence_deg > 0)):
        raise FitlabError(f"{label} gives detector bins or a source divergence; an "
                          "OpenMATERIAL table holds one receiver solid angle per wavelength "
                          "and nothing else of the aperture")
    notes = []
    keep = (m.wi[:, 2] > 0) & (m.wo[:, 2] > 0)
    if not np.all(keep):
        notes.append(f"{int((~keep).sum())} rows on the transmission side or in the surface "
                     "plane left out: the file holds a BRDF")
    theta_limit = np.degrees(om.MAX_ZENITH) + 1e-7
    grazing = keep & ((m.theta_i > theta_limit) | (m.theta_o > theta_limit))
    if np.any(grazing):
        keep &= ~grazing
        notes.append(f"{int(grazing.sum())} rows at θ = 90° left out: the schema's largest "
                     f"zenith angle is {om.MAX_ZENITH} rad ({np.degrees(om.MAX_ZENITH):.5f}°)")
    if not np.any(keep):
        raise FitlabError(f"{label} holds no reflection row an OpenMATERIAL table can hold")
    sel = m.select(keep)
    tilted = sel.theta_i > 0
    azimuths = np.unique(np.round(np.mod(sel.phi_i[tilted], 360.0), 9))
    if len(azimuths) > 1:
        raise FitlabError(f"{label} holds incidences at {len(azimuths)} azimuths φi; an "
                          "OpenMATERIAL table has no incident azimuth (φo is relative to the "
                          "incidence: an isotropic BRDF): write the rows of one φi")
    if np.any(sel.value < 0):
        raise FitlabError(f"{label} holds negative values; the schema's BRDF is >= 0")
    if m.wavelength_nm is None:
        wavelengths = _wavelengths(list(m.channel_names), wavelength_nm, label)
    elif wavelength_nm is not None:
        raise FitlabError(f"--wavelength-nm {wavelength_nm:g}: {label} states its wavelengths "
                          f"({', '.join(m.channel_names)}); drop --wavelength-nm")
    else:
        wavelengths = [float(w) for w in m.wavelength_nm]
    used = sorted(set(int(c) for c in sel.channel))
    phi = np.mod(sel.phi_o - sel.phi_i, 360.0)
    phi = np.where(sel.theta_o == 0, 0.0, phi)
    phi_rad = file_radians(phi)
    phi_rad = np.where(phi_rad > om.MAX_AZIMUTH, 0.0, phi_rad)  # within 3e-7 rad of 2π: 0
    angles = np.column_stack([_radians_within(sel.theta_i, om.MAX_ZENITH),
                              _radians_within(sel.theta_o, om.MAX_ZENITH), phi_rad])
    w_rows = np.asarray(wavelengths)[sel.channel]
    rows = table_rows(w_rows, angles, sel.value)
    solid = {}
    if sel.aperture_deg is not None and np.any(sel.aperture_deg > 0):
        for c in used:
            a = sel.aperture_deg[sel.channel == c]
            if np.ptp(a) > 0:
                raise FitlabError(f"{label}: channel {m.channel_names[c]} has detector cones "
                                  "of several sizes; an OpenMATERIAL table holds one receiver "
                                  "solid angle per wavelength")
            if a[0] > 0:
                solid[wavelengths[c]] = 2 * np.pi * (1 - np.cos(np.radians(a[0])))
    if m.sigma is not None:
        notes.append("sigma left out: the format has no uncertainty")
    source = om.metadata_from(m.metadata)
    made = f"Data of {label} written by fitlab {__version__}."
    said = description or source.get("description") or made
    sources = source.get("sources") or f"data converted by fitlab from {label}"
    if completed_by:
        said, sources = f"{said.rstrip()} {completed_by}", f"{sources}, model fitted by fitlab"
    meta = metadata(source, name=name or source.get("name") or Path(label).stem,
                    description=said, author=author, copyright=copyright, license=license,
                    sensor=sensor, sources=sources,
                    keep=("uuid", "creationDate", "openMaterial3dVersion") if source else ())
    doc = _document(meta, [wavelengths[c] for c in used], rows, solid)
    if completion is not None:
        from fitlab.io.measurement import MEASURED

        label_of = np.asarray(completion, dtype=object)[keep]
        done = label_of != MEASURED
        doc[COMPLETION_FIELD] = {
            "spec": "data_formats/completion_json.md",
            "columns": ["wavelength", "incidentZenith", "exitZenith", "exitAzimuth", "reason"],
            "rows": sorted([float(w) / 1e9, float(a[0]), float(a[1]), float(a[2]), str(r)]
                           for w, a, r in zip(w_rows[done], angles[done], label_of[done]))}
    if "uuid" not in doc["metadata"]:
        doc = with_uuid(doc)
    text = checked_text(doc, what)
    values = np.array([r[4] for r in rows])
    summary = {"model": None, "channels": [m.channel_names[c] for c in used],
               "wavelength_nm": [wavelengths[c] for c in used], "rows": len(rows),
               "grid": f"the rows of {label}", "uuid": doc["metadata"]["uuid"],
               "f_range": [float(values.min()), float(values.max())], "notes": notes,
               "kept": keep}
    return text, doc, summary


def write_data(path, m, source, **settings) -> dict:
    """Measured data written as an OpenMATERIAL file (atomically)."""
    text, _, summary = data_table(m, source, what=str(path), **settings)
    atomic_write_text(path, text)
    summary.pop("kept")
    return {"path": str(path), **summary}


def complete_data(path, job, **settings) -> dict:
    """A completion (fitlab.export.filling.Job) as an OpenMATERIAL file's text (written by
    fitlab.export.completion with its record): the data's rows and gaps as :func:`data_table`
    writes measured data, the fit's value where a row holds no reading or a replaced one, those
    rows listed in the file's :data:`COMPLETION_FIELD`."""
    from fitlab.export.filling import check_absolute, completed_rows, filled_rows
    from fitlab.io.files import path_for_record

    check_absolute(job.m, "OpenMATERIAL")
    rows, reason = completed_rows(job)
    n = int(np.sum(reason != "measured"))
    said = (f"{n} values are the fitlab fit {path_for_record(job.fit_path, path)}'s (model "
            f"{job.fit.model}), not readings: listed in {COMPLETION_FIELD}.")
    text, _, summary = data_table(rows, job.m.path, what=str(path), completion=reason,
                                  completed_by=said, **settings)
    keep = summary["kept"]  # the rows the file holds (a BRDF table leaves transmission out)
    return {"content": text, "filled": filled_rows(rows.select(keep), reason[keep]),
            "marks": f"in the file: its top-level field {COMPLETION_FIELD} lists the rows",
            "grid": {"rows": summary["rows"]}, "grid_source": "the data's own rows",
            "notes": list(summary["notes"])}


def describe(s: dict) -> str:
    """The line ``fitlab convert`` prints of a file written."""
    what = f"BRDF of {s['model']}" if s["model"] else "BRDF data"
    wl = ", ".join(f"{w:g}" for w in s["wavelength_nm"][:6]) + \
        (", ..." if len(s["wavelength_nm"]) > 6 else "")
    return (f"wrote {s['path']}: OpenMATERIAL 3D {what} at {wl} nm, {s['rows']} rows on "
            f"{s['grid']}; f {s['f_range'][0]:.4g} .. {s['f_range'][1]:.4g} 1/sr; uuid "
            f"{s['uuid']}")


__all__ = ["Grid", "STANDARD_GRID", "SETTINGS", "grid_rows", "file_grid", "material_table",
           "data_table", "write_model", "write_fit", "write_data", "export_parts", "describe",
           "complete_data", "COMPLETION_FIELD"]
