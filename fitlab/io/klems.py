"""LBNL WINDOW / Radiance BSDF XML with Klems angle bases (``WindowElement``, matrix form).
Spec, geometry and decisions: data_formats/klems_xml.md.

A file holds, per ``WavelengthData`` (Visible, Solar, CIE-X/Z or a wavelength in nm), up to four
matrices named by ``WavelengthDataDirection`` (Transmission/Reflection × Front/Back). With
``IncidentDataStructure`` ``Columns`` (the only value the LBNL schema allows) each column is an
incident patch and each text row an outgoing patch. Values are patch-averaged BSDF in 1/sr.
``ScatteringDataType`` says "BTDF" for reflection blocks too, so fitlab ignores it and takes
reflection or transmission from ``WavelengthDataDirection`` alone.

fitlab frame: **+z is WINDOW's front** (the exterior side, the side "Transmission Front" light
arrives from); this is Radiance's frame with z reversed (Radiance's +z faces the room, and its
front/back are WINDOW's back/front). A patch (θ, φ) is an outgoing direction
``(θ, φ)`` on the exit side and an incident direction ``(θ, φ + 180°)`` on the incident side
(Klems' convention: the incident patch names the direction of propagation), so the mirror and
straight-through directions share the incident patch's index (the matrix diagonal). On the
back side θ becomes 180° − θ.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple
from xml.parsers import expat

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.format import Format
from fitlab.io.validate import check_count, parse_number, quote
from fitlab.io.directions import degrees_to_direction
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.measurement import Measurement, describe_loaded

DIRECTIONS = ("Transmission Front", "Transmission Back", "Reflection Front", "Reflection Back")
#: (incident side, exit side) of each block
SIDES = {
    "Transmission Front": ("front", "back"),
    "Transmission Back": ("back", "front"),
    "Reflection Front": ("front", "front"),
    "Reflection Back": ("back", "back"),
}
BLOCK_GROUPS = {
    "all": DIRECTIONS,
    "front": ("Transmission Front", "Reflection Front"),
    "back": ("Transmission Back", "Reflection Back"),
    "transmission": ("Transmission Front", "Transmission Back"),
    "reflection": ("Reflection Front", "Reflection Back"),
}
#: Most patches one ring of a basis may declare (the Klems bases have at most 24): a bound on
#: what a header can make fitlab allocate.
NPHIS_MAX = 4096

#: Radiance's built-in Klems bases (src/common/bsdf_m.c): ring lower bounds (deg) and nPhis;
#: used only when a file names one of them without defining it.
BUILTIN_BASES = {
    "LBNL/Klems Full": ((0, 5, 15, 25, 35, 45, 55, 65, 75, 90), (1, 8, 16, 20, 24, 24, 24, 16, 12)),
    "LBNL/Klems Half": ((0, 6.5, 19.5, 32.5, 46.5, 61.5, 76.5, 90), (1, 8, 12, 16, 20, 12, 4)),
    "LBNL/Klems Quarter": ((0, 9, 27, 46, 66, 90), (1, 8, 12, 12, 8)),
}
#: largest hemispherical sum accepted as physical (Radiance's own tolerance, bsdf_m.c)
HEMI_TOLERANCE = 1.01


class AngleBasis(NamedTuple):
    name: str
    ring_theta: np.ndarray  # (rings,) centre θ in degrees
    ring_lower: np.ndarray  # (rings,) lower θ bound
    ring_upper: np.ndarray  # (rings,) upper θ bound
    ring_nphis: np.ndarray  # (rings,) patches per ring

    @property
    def n(self) -> int:
        return int(self.ring_nphis.sum())

    @property
    def theta(self) -> np.ndarray:
        """Per-patch centre θ (degrees), in file order (ring by ring, φ increasing)."""
        return np.repeat(self.ring_theta, self.ring_nphis)

    @property
    def phi(self) -> np.ndarray:
        """Per-patch centre φ = 360° k / nPhis (degrees)."""
        return np.concatenate([360.0 * np.arange(n) / n for n in self.ring_nphis])

    def projected_solid_angle(self) -> np.ndarray:
        """Λ = ∫ cos θ dω over each patch = π (cos² θlo − cos² θhi) / nPhis."""
        lo, hi = np.radians(self.ring_lower), np.radians(self.ring_upper)
        ring = np.pi * (np.cos(lo) ** 2 - np.cos(hi) ** 2) / self.ring_nphis
        return np.repeat(ring, self.ring_nphis)

    def solid_angle(self) -> np.ndarray:
        lo, hi = np.radians(self.ring_lower), np.radians(self.ring_upper)
        return np.repeat(2 * np.pi * (np.cos(lo) - np.cos(hi)) / self.ring_nphis, self.ring_nphis)


class KlemsBlock(NamedTuple):
    direction: str  # WavelengthDataDirection, canonical spelling
    channel: str  # "Visible", "Solar", "550nm", ...
    wavelength_nm: float | None
    incident: AngleBasis  # ColumnAngleBasis (Columns layout)
    outgoing: AngleBasis  # RowAngleBasis
    matrix: np.ndarray  # (n_out, n_in): f[o, i] in 1/sr
    line: int  # line of <ScatteringData>
    value_lines: np.ndarray  # (n_out, n_in) file line of each value
    scattering_data_type: str

    def hemispherical(self) -> np.ndarray:
        """Per incident patch: Σ_o f[o, i] Λ_o (directional-hemispherical reflectance or
        transmittance)."""
        return self.outgoing.projected_solid_angle() @ self.matrix


class KlemsFile(NamedTuple):
    path: str
    sha256: str
    material: dict
    structure: str  # Columns or Rows
    bases: dict
    blocks: tuple


# --------------------------------------------------------------------------------------------
# XML with line numbers (xml.etree tree built from expat events, which know their line)
# --------------------------------------------------------------------------------------------


def _clark(tag: str) -> str:
    ns, sep, local = tag.rpartition("}")
    return "{" + ns + "}" + local if sep else tag


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def parse_xml(path, data: bytes):
    """(root Element, {element: line}) of namespaced XML; malformed XML raises InputFileError."""
    builder = ET.TreeBuilder()
    lines: dict = {}
    parser = expat.ParserCreate(namespace_separator="}")

    def start(tag, attrs):
        lines[builder.start(_clark(tag), attrs)] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: builder.end(_clark(tag))
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise InputFileError(path, f"is not well-formed XML: {expat.ErrorString(exc.code)} "
                             f"(column {exc.offset + 1})", line=exc.lineno,
                             hint="fix the XML (a WINDOW/Radiance BSDF file is a WindowElement "
                             "document)") from None
    return builder.close(), lines


def _children(el, name):
    return [c for c in el if _local(c.tag) == name]


def _child(el, name):
    found = _children(el, name)
    return found[0] if found else None


def _text(el, name, default=None):
    c = _child(el, name)
    return default if c is None or c.text is None else c.text.strip()


# --------------------------------------------------------------------------------------------
# Angle bases
# --------------------------------------------------------------------------------------------


def _number(path, el, lines, what, hint=None, **bounds):
    text = (el.text or "").strip() if el is not None else ""
    return parse_number(text, path, what=f"<{what}>", line=lines.get(el),
                        hint=hint or f"give <{what}> a finite number", **bounds)


def _basis_from_rings(name, lower_bounds, nphis) -> AngleBasis:
    lower = np.asarray(lower_bounds[:-1], dtype=float)
    upper = np.asarray(lower_bounds[1:], dtype=float)
    centre = np.where(lower == 0, 0.0, 0.5 * (lower + upper))
    return AngleBasis(name, centre, lower, upper, np.asarray(nphis, dtype=int))


def parse_angle_basis(path, el, lines) -> AngleBasis:
    """An <AngleBasis> with <AngleBasisBlock>s of Theta, nPhis and ThetaBounds (bounds missing:
    worked back from 90°, as the schema suggests)."""
    name = _text(el, "AngleBasisName")
    if not name:
        raise InputFileError(path, "<AngleBasis> has no <AngleBasisName>", line=lines.get(el),
                             hint="name the basis, e.g. LBNL/Klems Full")
    theta, nphis, lo, hi = [], [], [], []
    for blk in _children(el, "AngleBasisBlock"):
        if _child(blk, "Phi") is not None:
            raise InputFileError(path, f"basis {name!r}: <AngleBasisBlock> with explicit <Phi> "
                                 "is not supported", line=lines.get(blk),
                                 hint="fitlab reads bases with nPhis evenly spaced patches per "
                                 "ring (Klems Full/Half/Quarter)")
        theta.append(_number(path, _child(blk, "Theta"), lines, "Theta"))
        nphis.append(check_count(
            _number(path, _child(blk, "nPhis"), lines, "nPhis", lo=1, hi=NPHIS_MAX,
                    hint="Klems bases have 1 to 24 patches per ring"), path,
            what=f"basis {quote(name)}: nPhis", lo=1, line=lines.get(_child(blk, "nPhis")),
            hint="Klems bases have 1 to 24 patches per ring"))
        bounds = _child(blk, "ThetaBounds")
        if bounds is not None:
            lo.append(_number(path, _child(bounds, "LowerTheta"), lines, "LowerTheta"))
            hi.append(_number(path, _child(bounds, "UpperTheta"), lines, "UpperTheta"))
    if not theta:
        raise InputFileError(path, f"basis {name!r} has no <AngleBasisBlock>", line=lines.get(el))
    theta = np.asarray(theta)
    if len(lo) != len(theta):  # no (or partial) ThetaBounds: work back from 90°
        hi_b = np.empty_like(theta)
        lo_b = np.empty_like(theta)
        edge = 90.0
        for r in range(len(theta) - 1, -1, -1):
            hi_b[r] = edge
            lo_b[r] = max(2 * theta[r] - edge, 0.0)
            edge = lo_b[r]
        lo, hi = lo_b, hi_b
    lo, hi = np.asarray(lo), np.asarray(hi)
    ok = (lo[0] == 0) and np.isclose(hi[-1], 90) and np.allclose(lo[1:], hi[:-1]) \
        and np.all((lo <= theta) & (theta <= hi) & (lo < hi))
    if not ok:
        rings = ", ".join(f"{a:g}-{b:g}" for a, b in zip(lo, hi))
        raise InputFileError(path, f"basis {name!r}: theta bounds {rings} do not tile 0°-90° "
                             "with each centre inside its ring", line=lines.get(el),
                             hint="each ring's LowerTheta must equal the previous UpperTheta, "
                             "from 0° to 90°")
    return AngleBasis(name, theta, lo, hi, np.asarray(nphis, dtype=int))


# --------------------------------------------------------------------------------------------
# ScatteringData
# --------------------------------------------------------------------------------------------

_TOKEN = re.compile(r"[^,\s]+")


def _line_of(start_line, text, offset):
    return start_line + text.count("\n", 0, offset)


def parse_scattering_data(path, el, lines, n_rows, n_cols, label):
    """Values of a <ScatteringData> as an (n_rows, n_cols) text-layout matrix and the file line
    of each value; errors name the line and token."""
    text = el.text or ""
    start = lines.get(el, 0)
    matches = list(_TOKEN.finditer(text))
    tokens = [m.group() for m in matches]
    try:
        values = np.asarray(tokens, dtype=np.float64)
    except ValueError:
        for m in matches:
            try:
                float(m.group())
            except ValueError:
                raise InputFileError(path, f"{label}: {quote(m.group())} in <ScatteringData> is not a "
                                     "number", line=_line_of(start, text, m.start()),
                                     hint="values are decimal numbers separated by commas or "
                                     "spaces") from None
        raise  # pragma: no cover - unreachable
    expected = n_rows * n_cols
    if values.size != expected:
        message, line = _size_message(text, start, values.size, n_rows, n_cols, label)
        raise InputFileError(path, message, line=line,
                             hint=f"the matrix must hold {n_rows} rows of {n_cols} values "
                             "(outgoing × incident patches of its angle bases)")
    bad = np.flatnonzero(~np.isfinite(values) | (values < 0))
    if bad.size:
        m = matches[bad[0]]
        raise InputFileError(path, f"{label}: value {quote(m.group())} (row {bad[0] // n_cols + 1}, "
                             f"column {bad[0] % n_cols + 1}) is not a finite non-negative BSDF",
                             line=_line_of(start, text, m.start()),
                             hint="a BSDF in 1/sr is finite and ≥ 0")
    newlines = np.array([m.start() for m in re.finditer("\n", text)], dtype=np.int64)
    value_lines = start + np.searchsorted(newlines, [m.start() for m in matches])
    return values.reshape(n_rows, n_cols), value_lines.reshape(n_rows, n_cols)


def _size_message(text, start, count, n_rows, n_cols, label):
    """What is wrong with a matrix of the wrong size, and the line to point at."""
    rows = [(k, len(_TOKEN.findall(s))) for k, s in enumerate(text.split("\n"))]
    rows = [(k, c) for k, c in rows if c]
    if len(rows) in (n_rows - 1, n_rows, n_rows + 1):  # one matrix row per text line
        for k, c in rows:
            if c != n_cols:
                return (f"{label}: this line has {c} values, expected {n_cols} (one row of the "
                        f"{n_rows}×{n_cols} matrix per line; {count} values in all)", start + k)
        return f"{label}: {len(rows)} rows of values, expected {n_rows}", start
    return (f"{label}: <ScatteringData> holds {count} values, expected {n_rows}×{n_cols} = "
            f"{n_rows * n_cols}", start)


# --------------------------------------------------------------------------------------------
# The document
# --------------------------------------------------------------------------------------------


def _channel_of(path, wd, lines):
    wl = _child(wd, "Wavelength")
    if wl is None or not (wl.text or "").strip():
        raise InputFileError(path, "<WavelengthData> has no <Wavelength>", line=lines.get(wd),
                             hint="state the band, e.g. <Wavelength unit=\"Integral\">Visible"
                             "</Wavelength>")
    text, unit = wl.text.strip(), wl.get("unit", "Integral").strip().lower()
    if unit == "nanometer":
        nm = _number(path, wl, lines, "Wavelength")
        return f"{nm:g}nm", nm
    if unit == "micron":
        um = _number(path, wl, lines, "Wavelength")
        return f"{um * 1000:g}nm", um * 1000
    return text, None


def _canonical_direction(text):
    for d in DIRECTIONS:
        if text.strip().lower() == d.lower():
            return d
    return None


def read_klems_file(path) -> KlemsFile:
    """Parse and validate a WINDOW/Radiance BSDF XML file (matrix form, Klems bases)."""
    path = Path(path)
    data = read_bytes(path)
    root, lines = parse_xml(path, data)
    if _local(root.tag) != "WindowElement":
        raise InputFileError(path, f"the root element is <{_local(root.tag)}>, not <WindowElement>",
                             line=lines.get(root), hint="this is not a WINDOW/Radiance BSDF file")
    layers = [el for el in root.iter() if _local(el.tag) == "Layer"]
    layers = [el for el in layers if _children(el, "WavelengthData")]
    if not layers:
        raise InputFileError(path, "has no <Layer> with <WavelengthData> blocks",
                             line=lines.get(root), hint="the file holds no BSDF data")
    if len(layers) > 1:
        raise InputFileError(path, f"has {len(layers)} layers with BSDF data",
                             line=lines.get(layers[1]),
                             hint="fitlab reads single-layer (System) files")
    layer = layers[0]
    material_el = _child(layer, "Material")
    material = {} if material_el is None else {
        _local(c.tag): (c.text or "").strip() for c in material_el if (c.text or "").strip()}
    definition = _child(layer, "DataDefinition")
    if definition is None:
        definition = next((el for el in root.iter() if _local(el.tag) == "DataDefinition"), None)
    if definition is None:
        raise InputFileError(path, "has no <DataDefinition>", line=lines.get(layer),
                             hint="the angle bases are defined in <DataDefinition>")
    structure = _text(definition, "IncidentDataStructure", "Columns")
    if structure.lower() not in ("columns", "rows"):
        hint = ("tensor-tree files (Radiance genBSDF -t3/-t4) are not supported; convert with "
                "Radiance's bsdf2klems" if structure.lower().startswith("tensortree") else
                "use Columns (incident patches in columns) or Rows")
        raise InputFileError(path, f"IncidentDataStructure {quote(structure)} is not supported",
                             line=lines.get(_child(definition, "IncidentDataStructure")), hint=hint)
    bases = {}
    for el in _children(definition, "AngleBasis"):
        b = parse_angle_basis(path, el, lines)
        bases[b.name.lower()] = b

    def basis_named(name, el):
        if not name:
            if len(bases) == 1:
                return next(iter(bases.values()))
            raise InputFileError(path, "a <WavelengthDataBlock> names no angle basis",
                                 line=lines.get(el), hint="give ColumnAngleBasis and RowAngleBasis")
        if name.lower() in bases:
            return bases[name.lower()]
        for known, (bounds, nphis) in BUILTIN_BASES.items():
            if name.lower() == known.lower():
                return _basis_from_rings(known, bounds, nphis)
        raise InputFileError(path, f"angle basis {name!r} is not defined in the file",
                             line=lines.get(el), hint=f"define it in <DataDefinition> (defined: "
                             f"{', '.join(b.name for b in bases.values()) or 'none'})")

    blocks, seen = [], {}
    for wd in _children(layer, "WavelengthData"):
        channel, nm = _channel_of(path, wd, lines)
        for wdb in _children(wd, "WavelengthDataBlock"):
            d_el = _child(wdb, "WavelengthDataDirection")
            if d_el is None:
                raise InputFileError(path, "<WavelengthDataBlock> has no <WavelengthDataDirection>",
                                     line=lines.get(wdb),
                                     hint=f"name the block: {', '.join(DIRECTIONS)}")
            raw_dir = (d_el.text or "").strip()
            direction = _canonical_direction(raw_dir)
            if direction is None:
                if raw_dir.lower().startswith("absorbed"):
                    continue  # layer absorptance vector, not a BSDF
                raise InputFileError(path, f"WavelengthDataDirection {quote(raw_dir)} is unknown",
                                     line=lines.get(d_el),
                                     hint=f"use one of {', '.join(DIRECTIONS)}")
            key = (channel, direction)
            if key in seen:
                raise InputFileError(path, f"{channel} {direction} appears twice (first at line "
                                     f"{seen[key]})", line=lines.get(d_el),
                                     hint="keep one block per band and direction")
            seen[key] = lines.get(d_el)
            col = basis_named(_text(wdb, "ColumnAngleBasis"), wdb)
            row = basis_named(_text(wdb, "RowAngleBasis"), wdb)
            sd = _child(wdb, "ScatteringData")
            if sd is None or not (sd.text or "").strip():
                raise InputFileError(path, f"{channel} {direction}: <ScatteringData> is missing or "
                                     "empty", line=lines.get(wdb),
                                     hint="each block needs its matrix of BSDF values")
            label = f"{channel} {direction}"
            if structure.lower() == "columns":
                mat, vl = parse_scattering_data(path, sd, lines, row.n, col.n, label)
            else:  # Rows: each text row is an incident patch
                mat, vl = parse_scattering_data(path, sd, lines, col.n, row.n, label)
                mat, vl = mat.T, vl.T
            blocks.append(KlemsBlock(direction, channel, nm, col, row, mat, lines.get(sd, 0), vl,
                                     _text(wdb, "ScatteringDataType", "")))
    if not blocks:
        raise InputFileError(path, "has no BSDF blocks (Transmission/Reflection Front/Back)",
                             line=lines.get(layer), hint="the file holds no scattering matrix")
    return KlemsFile(str(path), sha256_of(data), material, structure, bases, tuple(blocks))


# --------------------------------------------------------------------------------------------
# Geometry and the Measurement
# --------------------------------------------------------------------------------------------


def patch_angles(basis: AngleBasis, side: str, incident: bool):
    """(θ, φ) in degrees, fitlab frame (front = +z), of every patch of ``basis`` as an incident
    (φ + 180°) or outgoing direction on ``side``."""
    theta, phi = basis.theta, basis.phi
    if incident:
        phi = phi + 180.0
    if side == "back":
        theta = 180.0 - theta
    return theta, np.mod(phi, 360.0)


def select_blocks(kf: KlemsFile, blocks="all", channels=None):
    """The blocks named by ``blocks`` (all, front, back, transmission, reflection, or a comma
    list of WavelengthDataDirection names) and ``channels`` (None: all)."""
    if isinstance(blocks, str):
        key = blocks.strip().lower()
        wanted = BLOCK_GROUPS.get(key) or tuple(_canonical_direction(b) or b.strip()
                                                for b in blocks.split(","))
    else:
        wanted = tuple(_canonical_direction(b) or b for b in blocks)
    unknown = [w for w in wanted if w not in DIRECTIONS]
    if unknown:
        raise FitlabError(f"blocks {', '.join(map(repr, unknown))}: use {', '.join(BLOCK_GROUPS)} "
                          f"or names among {', '.join(DIRECTIONS)}")
    if isinstance(channels, str):
        channels = [c.strip() for c in channels.split(",")]
    have_channels = list(dict.fromkeys(b.channel for b in kf.blocks))
    if channels is not None:
        missing = [c for c in channels if c not in have_channels]
        if missing:
            raise InputFileError(kf.path, f"has no channel {', '.join(missing)}",
                                 hint=f"channels in the file: {', '.join(have_channels)}")
    chosen = [b for b in kf.blocks if b.direction in wanted
              and (channels is None or b.channel in channels)]
    group = isinstance(blocks, str) and blocks.strip().lower() in BLOCK_GROUPS
    missing = [w for w in wanted if not any(b.direction == w for b in chosen)]
    if (missing and not group) or not chosen:
        present = ", ".join(d for d in DIRECTIONS if any(b.direction == d for b in kf.blocks))
        raise InputFileError(kf.path, f"has no {', '.join(missing)} block",
                             hint=f"blocks in the file: {present}")
    return chosen


def measurement_from_klems(kf: KlemsFile, blocks="all", channels=None) -> Measurement:
    chosen = select_blocks(kf, blocks, channels)
    names = tuple(dict.fromkeys(b.channel for b in chosen))
    nms = [next(b.wavelength_nm for b in chosen if b.channel == c) for c in names]
    cols = {k: [] for k in ("ti", "pi", "to", "po", "v", "c", "line")}
    for b in chosen:
        side_in, side_out = SIDES[b.direction]
        ti, pi = patch_angles(b.incident, side_in, incident=True)
        to, po = patch_angles(b.outgoing, side_out, incident=False)
        o, i = np.meshgrid(np.arange(b.outgoing.n), np.arange(b.incident.n), indexing="ij")
        o, i = o.ravel(), i.ravel()
        cols["ti"].append(ti[i]), cols["pi"].append(pi[i])
        cols["to"].append(to[o]), cols["po"].append(po[o])
        cols["v"].append(b.matrix[o, i]), cols["line"].append(b.value_lines[o, i])
        cols["c"].append(np.full(o.size, names.index(b.channel)))
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    meta = {"source_format": "LBNL WINDOW / Radiance BSDF XML (Klems matrix)",
            "blocks": ", ".join(dict.fromkeys(b.direction for b in chosen)),
            "angle_basis": ", ".join(dict.fromkeys(b.incident.name for b in chosen)),
            "values": "patch-averaged BSDF at patch centres",
            "frame": "+z = WINDOW front (exterior)"}
    for key in ("Name", "Manufacturer", "DeviceType"):
        if key in kf.material:
            meta[{"Name": "sample"}.get(key, key.lower())] = kf.material[key]
    return Measurement(
        path=kf.path, sha256=kf.sha256, theta_i=cat["ti"], phi_i=cat["pi"], theta_o=cat["to"],
        phi_o=cat["po"], wi=degrees_to_direction(cat["ti"], cat["pi"]),
        wo=degrees_to_direction(cat["to"], cat["po"]), value=cat["v"], sigma=None,
        channel=cat["c"].astype(int), channel_names=names,
        wavelength_nm=np.asarray(nms, dtype=float) if all(n is not None for n in nms) else None,
        quantity="bsdf", file_quantity="bsdf", metadata=meta, lines=cat["line"],
    )


def read_klems(path, blocks="all", channels=None) -> Measurement:
    """A Klems XML file as a Measurement: one row per (block, incident patch, outgoing patch,
    channel) at patch centres. ``blocks``: all (default), front, back, transmission, reflection
    or a comma list of names; ``channels``: e.g. "Visible"."""
    return measurement_from_klems(read_klems_file(path), blocks, channels)


# --------------------------------------------------------------------------------------------
# Energy checks and the registry entry
# --------------------------------------------------------------------------------------------


def _stats(x):
    return {"normal_incidence": round(float(x[0]), 6), "min": round(float(x.min()), 6),
            "max": round(float(x.max()), 6)}


def energy_checks(kf: KlemsFile) -> dict:
    """Per channel: directional-hemispherical T and R of each side (Σ_o f Λ_o per incident patch),
    T + R, and the specular/direct part at normal incidence (diagonal excess over the column's
    median, times the patch's Λ)."""
    out = {}
    for channel in dict.fromkeys(b.channel for b in kf.blocks):
        by_dir = {b.direction: b for b in kf.blocks if b.channel == channel}
        rec = {}
        for d, b in by_dir.items():
            hemi = b.hemispherical()
            col0 = b.matrix[:, 0]
            direct = (col0[0] - np.median(col0)) * b.outgoing.projected_solid_angle()[0]
            rec[d] = {"hemispherical": _stats(hemi), "diagonal_normal_incidence": float(col0[0]),
                      "direct_part_normal_incidence": round(float(direct), 6),
                      "at_most_1": bool(hemi.max() <= HEMI_TOLERANCE)}
        for side in ("Front", "Back"):
            t, r = by_dir.get(f"Transmission {side}"), by_dir.get(f"Reflection {side}")
            if t is not None and r is not None and t.incident.n == r.incident.n:
                total = t.hemispherical() + r.hemispherical()
                rec[f"T+R {side}"] = {**_stats(total),
                                      "at_most_1": bool(total.max() <= HEMI_TOLERANCE)}
        out[channel] = rec
    return out


def describe_klems(path, format_name: str = "klems", accept=()) -> dict:
    kf = read_klems_file(path)
    m = measurement_from_klems(kf)
    info = describe_loaded(m, format_name, accept)
    info.update({
        "material": kf.material,
        "incident_data_structure": kf.structure,
        "angle_bases": {b.name: {"patches": b.n, "ring_theta_deg": b.ring_theta.tolist(),
                                 "ring_nphis": b.ring_nphis.tolist()} for b in kf.bases.values()},
        "blocks": [f"{b.channel} {b.direction}: {b.matrix.shape[0]}×{b.matrix.shape[1]} "
                   f"(line {b.line}; ScatteringDataType {b.scattering_data_type or 'absent'}, "
                   "not used)" for b in kf.blocks],
        "energy_checks": energy_checks(kf),
        "frame": "+z = WINDOW front (exterior); incident patch (θ, φ) → direction (θ, φ+180°)",
    })
    return info


def _detect(head: bytes, path) -> bool:
    text = head.decode("utf-8", errors="replace")
    return re.search(r"<(\w+:)?WindowElement[\s>]", text) is not None


FORMAT = Format("klems", "LBNL WINDOW / Radiance BSDF XML (Klems angle basis matrices)", _detect,
                read_klems, describe_klems, "data_formats/klems_xml.md", suffixes=(".xml",))
