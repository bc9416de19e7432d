"""pab pgII goniophotometer text scans ("mountain" export), one incident direction per file.
Spec and decisions: data_formats/pgii_text.md.

Header lines start with ``#``: ``#key value`` or ``#key: value`` (tabs or spaces). Keys fitlab
interprets: ``sample_name``, ``sample_label``, ``incident_angle θ φ`` (or ``intheta`` /
``inphi``), ``format: theta phi DSF|BSDF|BRDF|BTDF|[unit]``, ``colorimetry: CIE-Y|CIE-XYZ``,
``datapoints_in_file``, ``upphi``, ``front_integral``. Data lines: ``θ_out φ_out value`` (three
values per line after the angles with CIE-XYZ), degrees, same frame as the incident angles; θ > 90°
is the back (transmission) side.

Values: BSDF/BRDF/BTDF are f in 1/sr; DSF = f·|cos θo| (Radiance pabopto2bsdf); a bracketed
detector unit such as ``[uA]`` is raw photocurrent, read as f·|cos θo| times an unknown scale
(quantity ``relative``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.format import Format
from fitlab.io.validate import decode_text, quote
from fitlab.io.csvtable import text_lines
from fitlab.io.directions import degrees_to_direction
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.measurement import Measurement, describe_loaded
from fitlab.io.gates import TisBlock

_KEY = re.compile(r"#\s*([A-Za-z_][\w\-]*)\s*(:?)\s*(.*?)\s*$")
CALIBRATED = {"bsdf": "bsdf", "brdf": "bsdf", "btdf": "bsdf", "dsf": "bsdf_cos"}
COLORIMETRY = {"cie-y": ("Y",), "cie-xyz": ("X", "Y", "Z")}
#: header keys copied into Measurement.metadata (as found; quotes removed)
KEPT = ("sample_label", "lamp", "measured_at", "mountain-version", "beamshape", "filterlamp",
        "filterdet", "upphi", "front_integral", "database_id")
DUPLICATES = ("average", "error")


class PgiiHeader(NamedTuple):
    keys: dict  # key -> value text (last occurrence)
    lines: dict  # key -> line number
    theta_i: float
    phi_i: float
    kind: str  # the format's third word as written: DSF, BSDF, [uA], ...
    file_quantity: str  # bsdf, bsdf_cos, or relative (bsdf_cos)
    channels: tuple


def _unquote(s: str) -> str:
    """A header value for display: quotes removed, runs of tabs/spaces as one space."""
    s = " ".join(s.split())
    return s[1:-1] if len(s) >= 2 and s[0] == s[-1] == '"' else s


def _header_number(path, keys, lines, key, count=1):
    fields = keys[key].split()
    try:
        vals = [float(x) for x in fields[:count]]
    except ValueError:
        vals = []
    if len(vals) != count or not all(np.isfinite(vals)):
        raise InputFileError(path, f"'#{key} {_unquote(keys[key])}' needs {count} number(s)",
                             line=lines[key], hint=f"write e.g. '#{key}" + " 0" * count + "'")
    return vals


def parse_header(path, header_lines) -> PgiiHeader:
    """Interpret the ``#`` lines [(line number, text), ...]."""
    keys, lines = {}, {}
    for lineno, text in header_lines:
        m = _KEY.match(text)
        if m:
            keys[m.group(1).lower()], lines[m.group(1).lower()] = m.group(3), lineno
    if "spectral" in keys and "data" in keys.get("spectral", ""):
        raise InputFileError(path, "is a spectral pgII export", line=lines["spectral"],
                             hint="fitlab reads the CIE-Y / CIE-XYZ / detector-current exports")
    if "format" not in keys:
        raise InputFileError(path, "has no '#format: theta phi <quantity>' header line",
                             hint="pgII files state their values as DSF, BSDF or a detector unit "
                             "such as [uA]")
    words = keys["format"].split()
    if len(words) < 3 or [w.lower() for w in words[:2]] != ["theta", "phi"]:
        raise InputFileError(path, f"'#format: {_unquote(keys['format'])}' is not 'theta phi "
                             "<quantity>'",
                             line=lines["format"], hint="columns must be theta, phi, values")
    kind = words[2]
    if kind.lower() in CALIBRATED:
        file_quantity = CALIBRATED[kind.lower()]
    elif re.fullmatch(r"\[[^\]]+\]", kind):
        file_quantity = "relative (bsdf_cos)"
    else:
        raise InputFileError(path, f"'#format: {_unquote(keys['format'])}': quantity {kind!r} is "
                             "unknown",
                             line=lines["format"], hint="use DSF, BSDF (BRDF, BTDF) or a bracketed "
                             "detector unit such as [uA]")
    colorimetry = (keys.get("colorimetry") or "CIE-Y").split()[0]
    if colorimetry.lower() not in COLORIMETRY:
        raise InputFileError(path, f"'#colorimetry: {keys['colorimetry']}' is not CIE-Y or CIE-XYZ",
                             line=lines["colorimetry"], hint="fitlab reads CIE-Y and CIE-XYZ data")
    channels = COLORIMETRY[colorimetry.lower()]

    theta = phi = None
    if "incident_angle" in keys:
        theta, phi = _header_number(path, keys, lines, "incident_angle", 2)
    for key, which in (("intheta", 0), ("inphi", 1)):
        if key in keys:
            (v,) = _header_number(path, keys, lines, key)
            known = (theta, phi)[which]
            if known is not None and abs(known - v) > 1e-6:
                raise InputFileError(path, f"'#{key} {v:g}' disagrees with '#incident_angle "
                                     f"{_unquote(keys['incident_angle'])}' "
                                     f"(line {lines['incident_angle']})",
                                     line=lines[key], hint="the two must give the same angle")
            theta, phi = (v, phi) if which == 0 else (theta, v)
    if theta is None or phi is None:
        raise InputFileError(path, "states no incident angle",
                             hint="add '#incident_angle θ φ' (degrees) or '#intheta' and '#inphi'")
    if not (0 <= theta <= 180) or theta == 90:
        raise InputFileError(path, f"incident θ = {theta:g}° is outside [0°, 180°] or in the "
                             "surface plane", line=lines.get("incident_angle", lines.get("intheta")),
                             hint="θ is measured from the sample normal in degrees")
    if abs(phi) > 360:
        raise InputFileError(path, f"incident φ = {phi:g}° is outside [-360°, 360°]",
                             line=lines.get("incident_angle", lines.get("inphi")))
    return PgiiHeader(keys, lines, theta, phi, kind, file_quantity, channels)


def _split_lines(path):
    raw = read_bytes(path)
    text = decode_text(path, raw, what="pgII scan", encoding="utf-8")
    header, data = [], []
    for n, s, _ in text_lines(text):
        (header if s.startswith("#") else data).append((n, s))
    return header, data


def _parse_data(path, data, ncols):
    """(N, ncols) float array and line numbers; errors name the line."""
    lines = np.array([n for n, _ in data], dtype=np.int64)
    fields = [s.split() for _, s in data]
    counts = np.fromiter(map(len, fields), dtype=np.int64, count=len(fields))
    bad = np.flatnonzero(counts != ncols)
    if bad.size:
        raise InputFileError(path, f"has {counts[bad[0]]} fields, expected {ncols} "
                             f"(theta phi {'value' if ncols == 3 else 'X Y Z'})",
                             line=int(lines[bad[0]]),
                             hint="data lines hold numbers separated by spaces or tabs")
    flat = [f for row in fields for f in row]
    try:
        out = np.array(flat, dtype=np.float64).reshape(-1, ncols)
    except ValueError:
        r = next(r for r, row in enumerate(fields) if not all(map(_is_float, row)))
        token = next(f for f in fields[r] if not _is_float(f))
        raise InputFileError(path, f"{quote(token)} is not a number", line=int(lines[r]),
                             hint="data lines hold numbers separated by spaces or tabs") from None
    bad = np.flatnonzero(~np.all(np.isfinite(out), axis=1))
    if bad.size:
        raise InputFileError(path, f"{quote(data[bad[0]][1])} holds a value that is not finite",
                             line=int(lines[bad[0]]), hint="remove the line or give the value")
    return out, lines


def _is_float(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def _check_angles(path, theta, phi, lines):
    for name, bad in (("theta_out", (theta < 0) | (theta > 180)), ("phi_out", np.abs(phi) > 360)):
        j = np.flatnonzero(bad)
        if j.size:
            v = (theta if name == "theta_out" else phi)[j[0]]
            raise InputFileError(path, f"{name} {v:g}° is outside "
                                 f"{'[0°, 180°]' if name == 'theta_out' else '[-360°, 360°]'}",
                                 line=int(lines[j[0]]), hint="angles are degrees; θ from the "
                                 "sample normal (θ > 90° = back side), φ from the x axis")
    j = np.flatnonzero(theta == 90.0)
    if j.size:
        raise InputFileError(path, "theta_out 90° lies in the surface plane, where no flux is "
                             "measured", line=int(lines[j[0]]),
                             hint="remove the line (a DSF cannot be converted to f there)")


def merge_duplicates(path, wo, values, lines, mode="average"):
    """Rows with the same outgoing direction (unit vector equal to 1e-9) merged by their mean
    (``mode="average"``) or reported (``"error"``). Returns (keep index, merged values, count)."""
    if mode not in DUPLICATES:
        raise FitlabError(f"duplicates={mode!r}: use one of {', '.join(DUPLICATES)}")
    key = np.round(wo, 9) + 0.0  # +0.0 turns -0.0 into 0.0
    _, first, inverse, counts = np.unique(key, axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
    inverse = inverse.ravel()
    if np.all(counts == 1):
        return np.arange(len(lines)), values, 0
    if mode == "error":
        rep = np.flatnonzero(counts[inverse] > 1)
        second = next(r for r in rep if r != first[inverse[r]])
        original = int(lines[first[inverse[second]]])
        raise InputFileError(path, f"repeats the direction of line {original}",
                             line=int(lines[second]),
                             hint="read with duplicates='average' to merge repeated points")
    sums = np.stack([np.bincount(inverse, values[:, c], minlength=len(first))
                     for c in range(values.shape[1])], axis=1)
    merged = sums / counts[:, None]
    order = np.argsort(first)  # keep the file's order of first occurrences
    return first[order], merged[order], int((counts - 1).sum())


class PgiiScan(NamedTuple):
    path: str
    header: PgiiHeader
    theta_o: np.ndarray
    phi_o: np.ndarray
    values: np.ndarray  # (N, channels) as in the file (after merging duplicates)
    lines: np.ndarray
    points_read: int
    duplicates_merged: int


def read_pgii_scan(path, duplicates="average") -> PgiiScan:
    """The header and the data points as in the file (validated; duplicates merged)."""
    path = Path(path)
    header_lines, data = _split_lines(path)
    header = parse_header(path, header_lines)
    if not data:
        raise InputFileError(path, "has no data lines", hint="a pgII scan has lines 'θ φ value'")
    arr, lines = _parse_data(path, data, 2 + len(header.channels))
    if "datapoints_in_file" in header.keys:
        text = header.keys["datapoints_in_file"]
        try:
            declared = int(text.split()[0])
        except (ValueError, IndexError):
            raise InputFileError(path, f"'#datapoints_in_file {text}' is not a whole number",
                                 line=header.lines["datapoints_in_file"]) from None
        if declared != len(data):
            raise InputFileError(path, f"'#datapoints_in_file {declared}' but the file has "
                                 f"{len(data)} data lines (the last at line {int(lines[-1])})",
                                 line=header.lines["datapoints_in_file"],
                                 hint="the file is truncated or was edited; re-export it")
    theta, phi, values = arr[:, 0], arr[:, 1], arr[:, 2:]
    _check_angles(path, theta, phi, lines)
    if header.file_quantity in ("bsdf", "bsdf_cos"):
        bad = np.flatnonzero(np.any(values < 0, axis=1))
        if bad.size:
            raise InputFileError(path, f"value {values[bad[0]].min():g} is negative, which a "
                                 f"calibrated {header.kind} cannot be", line=int(lines[bad[0]]),
                                 hint="negative values (detector noise) are accepted only in "
                                 "raw detector-unit files such as '#format: theta phi [uA]'")
    wo = degrees_to_direction(theta, phi)
    keep, values, merged = merge_duplicates(path, wo, values, lines, duplicates)
    return PgiiScan(str(path), header, theta[keep], phi[keep], values, lines[keep], len(data),
                    merged)


def measurement_from_scan(scan: PgiiScan, sha256: str) -> Measurement:
    h = scan.header
    n, k = len(scan.lines), len(h.channels)
    wo = degrees_to_direction(scan.theta_o, scan.phi_o)
    wi = degrees_to_direction(np.full(n, h.theta_i), np.full(n, h.phi_i))
    cos_factor = np.abs(wo[:, 2]) if h.file_quantity != "bsdf" else np.ones(n)
    value = (scan.values / cos_factor[:, None]).T.reshape(-1)  # channel-major
    rep = lambda a: np.tile(a, k)  # noqa: E731
    meta = {"source_format": "pab pgII text scan", "instrument": "pab pgII goniophotometer",
            "sample": _unquote(h.keys.get("sample_name", Path(scan.path).stem)),
            "incident_angle": f"{h.theta_i:g} {h.phi_i:g}",
            "file_values": h.kind,
            "colorimetry": h.keys.get("colorimetry", "not stated (one channel, named Y)"),
            "points_read": str(scan.points_read), "duplicates_averaged": str(scan.duplicates_merged)}
    for key in KEPT:
        if key in h.keys:
            meta[key.replace("-", "_")] = _unquote(h.keys[key])
    return Measurement(
        path=scan.path, sha256=sha256, theta_i=np.full(n * k, h.theta_i),
        phi_i=np.full(n * k, h.phi_i), theta_o=rep(scan.theta_o), phi_o=rep(scan.phi_o),
        wi=np.tile(wi, (k, 1)), wo=np.tile(wo, (k, 1)), value=value, sigma=None,
        channel=np.repeat(np.arange(k), n), channel_names=h.channels, wavelength_nm=None,
        quantity="relative" if h.file_quantity.startswith("relative") else "bsdf",
        file_quantity=h.file_quantity, metadata=meta, lines=rep(scan.lines),
        tis_blocks=_front_blocks(scan),
    )


#: Data points on the front hemisphere needed for its integral (the front_integral check).
MIN_FRONT_POINTS = 100


def front_integral(scan: PgiiScan):
    """(∫ file values dω over the front hemisphere of channel Y, largest gap in degrees), or
    None with too few front points."""
    front = scan.theta_o < 90
    if front.sum() <= MIN_FRONT_POINTS:
        return None
    y = scan.header.channels.index("Y")
    wo = degrees_to_direction(scan.theta_o[front], scan.phi_o[front])
    return hemisphere_integral(wo, scan.values[front, y])


def _front_blocks(scan: PgiiScan) -> tuple:
    """The header's ``#front_integral`` against the integral of the file's values over the
    front hemisphere (the sanity gate 'tis'): one TisBlock, or none without the header line."""
    h = scan.header
    if "front_integral" not in h.keys:
        return ()
    found = front_integral(scan)
    if found is None:
        return ()
    (stated,) = _header_number(scan.path, h.keys, h.lines, "front_integral")
    return (TisBlock("front hemisphere (#front_integral)", stated, found[0], 1.0),)


def read_pgii(path, duplicates="average") -> Measurement:
    """A pgII scan as a Measurement (f, or f times an unknown scale for detector units)."""
    return measurement_from_scan(read_pgii_scan(path, duplicates), sha256_of(path))


def hemisphere_integral(wo, values, nodes=20000):
    """∫ values dω over the hemisphere the points lie on (nearest-neighbour quadrature on a
    Fibonacci grid of ``nodes`` equal-area nodes); also the largest node-to-point gap (deg)."""
    from scipy.spatial import cKDTree

    k = np.arange(nodes) + 0.5
    z = 1.0 - k / nodes
    r = np.sqrt(1.0 - z * z)
    ang = np.pi * (1.0 + 5 ** 0.5) * k
    side = 1.0 if np.median(wo[:, 2]) >= 0 else -1.0
    grid = np.stack([r * np.cos(ang), r * np.sin(ang), side * z], axis=1)
    dist, idx = cKDTree(wo).query(grid)
    gap = np.degrees(2 * np.arcsin(np.minimum(dist.max() / 2, 1.0)))
    return 2 * np.pi * float(values[idx].mean()), float(gap)


def describe_pgii(path, format_name: str = "pgii", accept=()) -> dict:
    scan = read_pgii_scan(path)
    m = measurement_from_scan(scan, sha256_of(path))
    h = scan.header
    info = describe_loaded(m, format_name, accept)
    info.update({
        "incident_angle_deg": [h.theta_i, h.phi_i],
        "file_values": f"{h.kind} → {m.file_quantity}",
        "datapoints_in_file": h.keys.get("datapoints_in_file", "not stated"),
        "points_read": scan.points_read,
        "duplicates_averaged": scan.duplicates_merged,
        "negative_values": int((scan.values < 0).sum()),
        "header": {k: _unquote(v) for k, v in h.keys.items() if k in
                   ("sample_name", "incident_angle", "format", "colorimetry", "upphi") + KEPT},
    })
    found = front_integral(scan)
    if found is not None:
        total, gap = found
        check = {"integral_of_file_values_dω": round(total, 6), "largest_gap_deg": round(gap, 2)}
        if "front_integral" in h.keys:
            (stated,) = _header_number(path, h.keys, h.lines, "front_integral")
            check["header_front_integral"] = stated
            check["relative_difference"] = round(total / stated - 1, 4) if stated else None
        info["front_hemisphere_check"] = check
    return info


def _detect(head: bytes, path) -> bool:
    text = head.decode("utf-8", errors="replace")
    lines = [s.strip() for s in text.splitlines() if s.strip()]
    if not lines or not lines[0].startswith("#"):
        return False
    return any(re.match(r"#\s*(format:\s*theta\s+phi|incident_angle\s|intheta\s)", s)
               for s in lines if s.startswith("#"))


FORMAT = Format("pgii", "pab pgII goniophotometer text scan (one incident direction)", _detect,
                read_pgii, describe_pgii, "data_formats/pgii_text.md", suffixes=(".txt",))
