"""Spectral in-plane scan CSV, as goniometer software exports it: ``Incident_angle,
Measure_angle, 390nm, 400nm, …`` (one column per wavelength band), a signed measure angle in the
plane of incidence, exact zeros where the detector blocks the beam. The file does not state what
its values are: the user declares it (``--quantity``). Spec: data_formats/spectral_scan_csv.md.

Frame (data_formats/CONVENTIONS.md): the light at φi = 0, θi = Incident_angle; a measure angle
m > 0 lies on the specular side (θo = m, φo = 180°: m = θi is the mirror direction), m < 0 on
the side of the light (θo = |m|, φo = 0°: m = -θi is retro-reflection), m = 0 the normal.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from fitlab.errors import InputFileError
from fitlab.io.csvtable import read_table
from fitlab.io.directions import degrees_to_direction
from fitlab.io.files import sha256_of
from fitlab.io.format import Format
from fitlab.io.gates import QUANTITIES
from fitlab.io.measurement import (TO_F, Measurement, check_measurement, describe_loaded,
                                   first_line, split_gaps)

ANGLE_COLUMNS = ("Incident_angle", "Measure_angle")
#: A band column: a wavelength in nanometres followed by ``nm`` (spaces around it are allowed).
BAND = re.compile(r"(\d+(?:\.\d+)?)nm")
QUANTITY_ADVICE = ("declare what its values are with --quantity " + "|".join(QUANTITIES)
                   + " (Python: quantity=...; data_formats/spectral_scan_csv.md), e.g. "
                   "radiance_factor for π·f, about 1 off-specular on a white sample")


def _read_scan(path):
    """(table, band column names, wavelengths) of a scan file, its angles checked."""
    table = read_table(path, ANGLE_COLUMNS, what="spectral scan CSV",
                       column_pattern=BAND.pattern)
    bands = [c for c in table.columns if BAND.fullmatch(c)]
    if not bands:
        raise InputFileError(path, "has no band column", line=int(table.lines[0]) - 1,
                             hint="name one column per wavelength, e.g. 550nm")
    wl = np.array([float(BAND.fullmatch(c).group(1)) for c in bands])
    for j, c in enumerate(bands):
        if wl[j] <= 0 or wl[j] in wl[:j]:
            raise InputFileError(path, "is not a positive wavelength" if wl[j] <= 0 else
                                 "names a wavelength an earlier band column names too",
                                 line=int(table.lines[0]) - 1, column=c,
                                 hint="name each band column once by its wavelength, e.g. 550nm")
    cols = table.columns
    for name, ok, rng in (("Incident_angle", lambda a: (a >= 0) & (a < 90), "[0°, 90°)"),
                          ("Measure_angle", lambda a: np.abs(a) < 90, "(-90°, 90°)")):
        bad = np.flatnonzero(~ok(cols[name]))
        if bad.size:
            raise InputFileError(
                path, f"{cols[name][bad[0]]:g}° is outside {rng}", line=int(table.lines[bad[0]]),
                column=name, hint="angles are degrees from the normal in the plane of incidence; "
                "the measure angle is signed (> 0 on the specular side)")
    key = np.stack([cols["Incident_angle"], cols["Measure_angle"]], axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        j = first[counts > 1].min()
        same = np.flatnonzero(np.all(key == key[j], axis=1))
        raise InputFileError(path, f"repeats the angles of line {int(table.lines[same[0]])}",
                             line=int(table.lines[same[1]]), column="Measure_angle",
                             hint="merge repeated readings into one row or remove one")
    for c in bands:
        v = cols[c]
        bad = np.flatnonzero(v < 0)
        if bad.size:
            raise InputFileError(path, f"{v[bad[0]]:g} is negative, which no reading can be",
                                 line=int(table.lines[bad[0]]), column=c,
                                 hint="subtract the right dark level, or give the values as "
                                 "a measurement CSV with '# quantity: relative'")
    return table, bands, wl


def blocked_mask(incident, values) -> np.ndarray:
    """(rows, bands) True where a value is a blocked reading: an exact 0 in a scan (one incidence,
    one band) that holds a positive value elsewhere (the detector shadowing the beam near
    retro-reflection). A scan of zeros only is kept as read."""
    blocked = np.zeros(values.shape, dtype=bool)
    for t in np.unique(incident):
        rows = incident == t
        v = values[rows]
        blocked[rows] = (v == 0) & np.any(v > 0, axis=0)
    return blocked


def _measurement(path, quantity: str | None) -> tuple[Measurement, dict]:
    """The scan as a Measurement (``quantity`` None: read as relative, for ``fitlab info``) and
    what reading it found (blocked readings per incidence)."""
    table, bands, wl = _read_scan(path)
    cols = table.columns
    ti, m = cols["Incident_angle"], cols["Measure_angle"]
    values = np.stack([cols[c] for c in bands], axis=1)
    blocked = blocked_mask(ti, values)
    k = len(bands)
    gap = blocked.reshape(-1)  # no reading: the Measurement's gaps
    if gap.all():
        raise InputFileError(path, "holds no reading", hint="give a file with positive values")
    rep = lambda a: np.repeat(a, k)  # noqa: E731
    theta_i, theta_o = rep(ti), rep(np.abs(m))
    phi_i = np.zeros_like(theta_i)
    phi_o = np.where(rep(m) > 0, 180.0, 0.0)
    wi, wo = degrees_to_direction(theta_i, phi_i), degrees_to_direction(theta_o, phi_o)
    stored = quantity or "relative"
    value = np.where(gap, np.nan, values.reshape(-1)) \
        / TO_F["bsdf" if stored == "relative" else stored](wi, wo)
    meas = check_measurement(split_gaps(Measurement(
        path=str(path), sha256=sha256_of(path), theta_i=theta_i, phi_i=phi_i, theta_o=theta_o,
        phi_o=phi_o, wi=wi, wo=wo, value=value, sigma=None,
        channel=np.tile(np.arange(k), len(ti)), channel_names=tuple(f"{w:g}nm" for w in wl),
        wavelength_nm=wl, quantity="relative" if stored == "relative" else "bsdf",
        file_quantity=stored if quantity else "undeclared (read as relative)",
        metadata=dict(table.metadata), lines=rep(table.lines)), gap, "blocked"))
    per = {f"{t:g}": int(blocked[ti == t].sum()) for t in np.unique(ti)}
    return meas, {"blocked_readings": int(blocked.sum()), "blocked_by_incidence_deg": per,
                  "rows_in_file": int(len(ti)), "bands": k}


def read_spectral_scan(path, quantity: str | None = None, accept=()) -> Measurement:
    """Read a spectral in-plane scan; ``quantity`` (one of fitlab.io.gates.QUANTITIES) is
    required, as the file does not state it. ``accept``: sanity gates accepted (they run in
    read_any)."""
    path = Path(path)
    if quantity is None:
        _read_scan(path)  # a malformed file says what is wrong with it first
        raise InputFileError(path, "is a spectral in-plane scan of undeclared quantity",
                             hint=QUANTITY_ADVICE)
    return _measurement(path, quantity)[0]


def describe_spectral_scan(path, format_name: str = "spectral_scan", accept=(),
                           quantity: str | None = None) -> dict:
    m, found = _measurement(Path(path), quantity)
    info = describe_loaded(m, format_name, accept)
    if quantity is None:
        info["quantity"] = "undeclared"
        info["unit"] = "not stated by the file (values as read)"
        info["warnings"] = ["quantity undeclared: fit, convert, compare and report refuse the "
                            "file; " + QUANTITY_ADVICE] + info["warnings"]
    info.update({
        **found,
        "wavelength_nm": [float(w) for w in m.wavelength_nm],
        "sign_convention": "measure angle > 0: specular side (phi_o = 180°, light at phi_i = 0); "
                           "< 0: the light's side (phi_o = 0°)",
        "blocked": "exact zeros in a scan holding positive values: no reading, left out (the "
                   "Measurement's gaps; fitlab convert --complete fills them from a fit)",
    })
    return info


def _detect(head: bytes, path) -> bool:
    s = first_line(head)
    return s is not None and tuple(f.strip() for f in s.split(",")[:2]) == ANGLE_COLUMNS


FORMAT = Format("spectral_scan", "spectral in-plane scan CSV (Incident_angle, Measure_angle, "
                "<N>nm bands; quantity declared with --quantity)", _detect, read_spectral_scan,
                describe_spectral_scan, "data_formats/spectral_scan_csv.md", suffixes=(),
                takes=("quantity",))
