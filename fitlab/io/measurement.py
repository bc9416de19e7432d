"""Measurement CSV (data_formats/measurement_csv.md) and the in-memory ``Measurement``, the one
contract between every reader and the fitter.

Internally values are the BSDF f in 1/sr (``quantity == "bsdf"``) or f up to an unknown overall
scale (``quantity == "relative"``); files holding f·|cos θo|, f·|cos θi| or π·f (a radiance
factor) are converted on reading, their sigma with them. The sanity gates that stop a valid but
implausible file are fitlab.io.gates.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import InputFileError
from fitlab.io.csvtable import read_table
from fitlab.io.directions import check_angles, degrees_to_direction
from fitlab.io.files import sha256_of
from fitlab.io.format import Format
from fitlab.io.gates import QUANTITIES, gate_error, radians_finding, summary

DIRECTION_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
RELATIVE_TO = ("bsdf", "bsdf_cos", "bsdf_cos_i")
SCATTER = ("bsdf", "brdf", "btdf")
_CHANNEL_VALUE = r"value_([A-Za-z0-9]+)"
_CHANNEL_SIGMA = r"sigma_([A-Za-z0-9]+)"
#: A dataset label (the optional ``dataset`` column): letters, digits, '_', '-', '.', ≤ 64.
DATASET_LABEL = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")


class Measurement(NamedTuple):
    path: str
    sha256: str
    theta_i: np.ndarray  # degrees, as in the file
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    wi: np.ndarray  # (N, 3) unit vectors, float64
    wo: np.ndarray
    value: np.ndarray  # f in 1/sr, or f times an unknown scale when quantity == "relative"
    sigma: np.ndarray | None  # absolute 1-σ uncertainty of value, same units; None if not given
    channel: np.ndarray  # (N,) int index into channel_names
    channel_names: tuple[str, ...]
    wavelength_nm: np.ndarray | None  # per channel, when the file gives wavelengths
    quantity: str  # "bsdf" or "relative"
    # what the file stored: bsdf, bsdf_cos, radiance_factor, relative (+ relative_to)
    file_quantity: str
    metadata: dict
    lines: np.ndarray  # file line of each row
    # The instrument's aperture (data_formats/measurement_csv.md, "Aperture"); None: not given.
    aperture_deg: np.ndarray | None = None  # (N,) detector cone half-angle, degrees; 0: a point
    bin_o_deg: np.ndarray | None = None  # (N, 4) θo_lo, θo_hi, φo_lo, φo_hi, degrees
    source_divergence_deg: np.ndarray | None = None  # (N,) source cone half-angle, degrees
    # Several datasets in one file (the ``dataset`` column): per row an index into
    # dataset_names; None: one dataset. fitlab.fit_many fits each on its own (datasets()).
    dataset: np.ndarray | None = None
    dataset_names: tuple = ()
    # The sanity gates (fitlab.io.gates): a format's stored total integrated scatter against its
    # data (TisBlock per block; Zemax, pgII), the gates' findings accepted by --accept ("NAME:
    # what it found"), and the read options that differ from the defaults (set by read_any).
    tis_blocks: tuple = ()
    accepted: tuple = ()
    read_options: dict | None = None
    # The places of the file's table that hold no reading (Gaps: a NaN value, a stored zero
    # the format means as nothing measured, a blocked reading, a row a completion filled); not
    # rows of the measurement: nothing fits them. None: the file holds a reading everywhere.
    gaps: "Gaps | None" = None

    @property
    def n(self) -> int:
        return int(self.value.shape[0])

    @property
    def has_aperture(self) -> bool:
        """Whether some row averages over a solid angle (a detector cone or bin, a divergent
        source): a fit then predicts aperture-averaged model values (fitlab.aperture)."""
        from fitlab.aperture import bin_has_extent

        return bool((self.aperture_deg is not None and np.any(self.aperture_deg > 0))
                    or (self.bin_o_deg is not None and np.any(bin_has_extent(self.bin_o_deg)))
                    or (self.source_divergence_deg is not None
                        and np.any(self.source_divergence_deg > 0)))

    def with_aperture(self, aperture_deg=None, source_divergence_deg=None) -> "Measurement":
        """The same data with a detector cone half-angle and/or a source divergence (degrees;
        a number for every row or one per row), e.g. for a format that does not record the
        instrument's aperture; checked like a file's."""
        full = lambda v: None if v is None else np.broadcast_to(  # noqa: E731
            np.asarray(v, dtype=np.float64), (self.n,)).copy()
        m = self._replace(
            aperture_deg=self.aperture_deg if aperture_deg is None else full(aperture_deg),
            source_divergence_deg=self.source_divergence_deg if source_divergence_deg is None
            else full(source_divergence_deg))
        return check_measurement(m)

    @property
    def is_relative(self) -> bool:
        return self.quantity == "relative"

    def eta(self) -> float | None:
        """n_inside / n_outside when the file states both indices."""
        if "eta_inside" in self.metadata and "eta_outside" in self.metadata:
            return float(self.metadata["eta_inside"]) / float(self.metadata["eta_outside"])
        return None

    def select(self, mask) -> "Measurement":
        """The rows where ``mask`` is true (same metadata, provenance and gaps)."""
        return self.take(np.asarray(mask, dtype=bool))

    def take(self, index) -> "Measurement":
        """The rows ``index`` picks (a boolean mask or row indices, in their order)."""
        return self._replace(**{name: None if getattr(self, name) is None
                                else getattr(self, name)[index] for name in ROW_FIELDS})

    def datasets(self) -> list["Measurement"]:
        """One Measurement per dataset of the file (the ``dataset`` column), in the file's
        order; each keeps the file's provenance, its own channels (those it has rows of), and
        names its label in ``metadata["dataset"]``. A file without the column: ``[self]``."""
        if self.dataset is None:
            return [self]
        return [self.dataset_named(label) for label in self.dataset_names]

    def dataset_named(self, label: str) -> "Measurement":
        """The rows of dataset ``label`` as a Measurement of their own (see :meth:`datasets`)."""
        if self.dataset is None or label not in self.dataset_names:
            have = ", ".join(self.dataset_names) or "none (no dataset column)"
            raise KeyError(f"{self.path} has no dataset {label!r}; its datasets: {have}")
        k = self.dataset_names.index(label)
        sub = self.select(self.dataset == k)
        used = np.unique(sub.channel)
        remap = np.full(len(self.channel_names), -1)
        remap[used] = np.arange(len(used))
        gaps = None
        if self.gaps is not None:  # the dataset's own gaps, of the channels it keeps
            g = self.gaps.select((self.gaps.rows.dataset == k)
                                 & (remap[self.gaps.rows.channel] >= 0))
            gaps = g._replace(rows=g.rows._replace(channel=remap[g.rows.channel], dataset=None,
                                                   dataset_names=())) if g.rows.n else None
        return sub._replace(
            channel=remap[sub.channel], channel_names=tuple(self.channel_names[c] for c in used),
            wavelength_nm=None if self.wavelength_nm is None else self.wavelength_nm[used],
            metadata={**self.metadata, "dataset": label}, dataset=None, dataset_names=(),
            gaps=gaps)


#: The Measurement's per-row fields (an array with one entry per row, or None where not given).
ROW_FIELDS = ("theta_i", "phi_i", "theta_o", "phi_o", "wi", "wo", "value", "sigma", "channel",
              "lines", "aperture_deg", "bin_o_deg", "source_divergence_deg", "dataset")

#: Why a value of a table is not a reading (a reader's gaps, and the values ``fitlab convert
#: --complete`` replaces by a fit): data_formats/completion_json.md.
GAP_REASONS = {
    "no_reading": "the file holds no value there (NaN, a stored zero its format means as "
                  "nothing measured, a bin marked invalid)",
    "blocked": "the file marks the reading as blocked (a spectral scan's exact zero where the "
               "detector shadows the beam)",
    "uncovered": "a direction of the output's grid where the measurement holds no reading "
                 "(beyond its view edge, or between its directions)",
    "subset": "a reading declared bad by a subset expression (--complete-subset)",
}
#: The label of a value that is a reading (the measurement CSV's ``completion`` column).
MEASURED = "measured"


class Gaps(NamedTuple):
    """Where a file's table holds no reading: the places as rows of a Measurement (value NaN,
    or the value a completion wrote there) and why each holds none (a GAP_REASONS key)."""

    rows: Measurement
    reason: np.ndarray  # (rows,) of str

    def select(self, mask) -> "Gaps":
        mask = np.asarray(mask, dtype=bool)
        return Gaps(self.rows.select(mask), self.reason[mask])

    def counts(self) -> dict:
        """{reason: rows}, in GAP_REASONS' order."""
        return {r: int(np.sum(self.reason == r)) for r in GAP_REASONS if np.any(self.reason == r)}


def split_gaps(m: Measurement, gap, reason) -> Measurement:
    """``m`` whose rows where ``gap`` is true are no reading (``reason``: a GAP_REASONS key, or
    one per row): the measurement of the other rows, those rows its ``gaps``."""
    gap = np.asarray(gap, dtype=bool)
    if not gap.any():
        return m
    reason = np.broadcast_to(np.asarray(reason, dtype=object), gap.shape)[gap]
    return m.select(~gap)._replace(gaps=Gaps(m.select(gap), np.asarray(reason, dtype=object)))


def join_rows(a: Measurement, b: Measurement) -> Measurement:
    """The rows of ``a`` followed by those of ``b`` (the same file's rows: the same channels
    and per-row fields), with ``a``'s metadata and provenance."""
    out = {}
    for name in ROW_FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if (x is None) != (y is None):
            raise ValueError(f"join_rows: {name} is given for one of the two only")
        out[name] = None if x is None else np.concatenate([x, y])
    return a._replace(**out)


#: Largest |value| or sigma a measurement may hold: beyond it the squares a fit sums overflow
#: float64 (any real instrument's units are far below it).
MAX_ABS_VALUE = 1e100


def check_measurement(m: Measurement) -> Measurement:
    """The checks every reader's result passes before anything uses it (``read_any`` applies
    them): at least one row, and directions, values and sigma finite and within MAX_ABS_VALUE
    after conversion to f (dividing by a cosine near grazing can overflow)."""
    from fitlab.io.validate import check_finite

    if m.n == 0:
        raise InputFileError(m.path, "holds no data rows", hint="give a file with measurements")
    line_of = lambda j: int(m.lines[j]) if j < len(m.lines) else None  # noqa: E731
    for name, arr in (("theta_i", m.theta_i), ("phi_i", m.phi_i), ("theta_o", m.theta_o),
                      ("phi_o", m.phi_o), ("wi", m.wi), ("wo", m.wo)):
        check_finite(arr, m.path, what=f"{name}", line_of=line_of, column=name)
    for name, arr in (("value", m.value), ("sigma", m.sigma)):
        if arr is None:
            continue
        check_finite(arr, m.path, what=f"{name} (as f in 1/sr)", line_of=line_of, column=name,
                     hint="a value too large overflows when converted to f; check the units")
        big = np.flatnonzero(np.abs(arr) > MAX_ABS_VALUE)
        if big.size:
            raise InputFileError(m.path, f"{arr[big[0]]:.3g} is beyond ±{MAX_ABS_VALUE:g}",
                                 line=line_of(big[0]), column=name,
                                 hint="check the units; no instrument measures such values")
    check_aperture(m, line_of)
    return m


#: Columns of a measurement CSV that give each row's aperture (data_formats/measurement_csv.md).
CONE_COLUMNS = ("aperture_deg", "source_divergence_deg")
BIN_COLUMNS = ("theta_o_lo", "theta_o_hi", "phi_o_lo", "phi_o_hi")
#: Largest cone half-angle (degrees, exclusive): a cone is at most a hemisphere.
MAX_CONE_DEG = 90.0
#: Tolerance (degrees) of "the row's direction lies in its bin".
BIN_TOL_DEG = 1e-6


def check_aperture(m: Measurement, line_of) -> None:
    """The aperture fields, where given: one entry per row, finite, cones in [0°, 90°), bins
    on one side of the surface (θ0 ≤ θ1, φ0 ≤ φ1 ≤ φ0 + 360°, a point or an area) holding the
    row's direction, and no row with both a cone and a bin."""
    from fitlab.aperture import bin_has_extent
    from fitlab.io.validate import check_finite

    def fail(j, column, message, hint):
        raise InputFileError(m.path, message, line=line_of(j), column=column, hint=hint)

    for name in CONE_COLUMNS:
        arr = getattr(m, name)
        if arr is None:
            continue
        if np.shape(arr) != (m.n,):
            raise InputFileError(m.path, f"{name} has shape {np.shape(arr)}, not ({m.n},)")
        check_finite(arr, m.path, what=name, line_of=line_of, column=name)
        bad = np.flatnonzero((arr < 0) | (arr >= MAX_CONE_DEG))
        if bad.size:
            fail(bad[0], name, f"{arr[bad[0]]:g}° is not a cone half-angle in [0°, 90°)",
                 "give the half-angle of the cone in degrees (0 for a point)")
    b = m.bin_o_deg
    if b is None:
        return
    if np.shape(b) != (m.n, 4):
        raise InputFileError(m.path, f"bin_o_deg has shape {np.shape(b)}, not ({m.n}, 4)")
    for k, name in enumerate(BIN_COLUMNS):
        check_finite(b[:, k], m.path, what=name, line_of=line_of, column=name)
    t0, t1, p0, p1 = b.T
    hint = ("a bin is theta_o_lo <= theta_o_hi on one side of the surface (both <= 90 or both "
            ">= 90) and phi_o_lo <= phi_o_hi <= phi_o_lo + 360, in degrees; a row without a bin "
            "repeats its direction (theta_o_lo = theta_o_hi = theta_o, phi_o_lo = phi_o_hi = "
            "phi_o)")
    checks = (
        ((t0 < 0) | (t1 > 180), "theta_o_lo", "the θo bin is outside [0°, 180°]"),
        (t0 > t1, "theta_o_hi", "theta_o_hi is below theta_o_lo"),
        ((t0 < 90) & (t1 > 90), "theta_o_hi", "the θo bin crosses the surface plane (90°)"),
        ((np.abs(p0) > 360) | (np.abs(p1) > 360), "phi_o_lo",
         "the φo bin is outside [-360°, 360°]"),
        ((p0 > p1) | (p1 - p0 > 360), "phi_o_hi",
         "phi_o_hi is below phi_o_lo or more than 360° above it"),
        ((t0 == t1) != (p0 == p1), "theta_o_lo",
         "the bin has zero width in one angle only (an arc, with no solid angle)"),
    )
    for bad, column, message in checks:
        j = np.flatnonzero(bad)
        if j.size:
            fail(j[0], column, message, hint)
    to = m.theta_o
    out = np.flatnonzero((to < t0 - BIN_TOL_DEG) | (to > t1 + BIN_TOL_DEG))
    if out.size:
        j = out[0]
        fail(j, "theta_o", f"θo = {to[j]:g}° lies outside its bin [{t0[j]:g}°, {t1[j]:g}°]",
             "a row's direction is a point of its bin (usually its centre)")
    on_pole = np.sin(np.radians(to)) < 1e-12  # φ means nothing there
    rel = np.mod(m.phi_o - p0 + BIN_TOL_DEG, 360.0) - BIN_TOL_DEG
    out = np.flatnonzero(~on_pole & (rel > (p1 - p0) + BIN_TOL_DEG))
    if out.size:
        j = out[0]
        fail(j, "phi_o", f"φo = {m.phi_o[j]:g}° lies outside its bin [{p0[j]:g}°, {p1[j]:g}°] "
             "(modulo 360°)", "a row's direction is a point of its bin (usually its centre)")
    if m.aperture_deg is not None:
        both = np.flatnonzero((m.aperture_deg > 0) & bin_has_extent(b))
        if both.size:
            fail(both[0], "aperture_deg", "the row has both a detector cone and a bin",
                 "give a row either aperture_deg or bin edges, not both")


def _meta_choice(table, key, choices, default=None, hint=""):
    path, metadata = table.path, table.metadata
    line = table.metadata_lines.get(key)
    value = metadata.get(key, default)
    if value is None:
        raise InputFileError(path, f"the metadata line '# {key}: ...' is missing",
                             hint=hint or f"add '# {key}: ' followed by one of {', '.join(choices)}")
    value = value.strip().lower()
    if value not in choices:
        raise InputFileError(path, f"'# {key}: {value}' is not one of {', '.join(choices)}",
                             line=line, hint=hint or f"use one of {', '.join(choices)}")
    return value


#: Comment keys that give the refractive indices on the two sides (every reader checks them).
INDEX_KEYS = ("eta_outside", "eta_inside")


def check_indices(path, metadata: dict, lines: dict | None = None) -> None:
    """'# eta_outside:' and '# eta_inside:' comments, where present, are finite positive
    numbers (InputFileError naming the file and line otherwise)."""
    for key in INDEX_KEYS:
        if key not in metadata:
            continue
        text = str(metadata[key])
        try:
            v = float(text)
        except ValueError:
            v = float("nan")
        if not (np.isfinite(v) and v > 0):
            shown = text if len(text) <= 40 else text[:40] + "..."
            raise InputFileError(path, f"'# {key}: {shown}' must be a positive number",
                                 line=(lines or {}).get(key),
                                 hint="give the refractive index of that medium, e.g. 1.0 for air")


def _melt_channels(table):
    """Wide per-channel columns value_<NAME> [sigma_<NAME>] to long rows with a channel index."""
    cols = table.columns
    names = [re.fullmatch(_CHANNEL_VALUE, c).group(1) for c in cols if re.fullmatch(_CHANNEL_VALUE, c)]
    for c in cols:
        m = re.fullmatch(_CHANNEL_SIGMA, c)
        if m and m.group(1) not in names:
            raise InputFileError(table.path, f"has no matching value_{m.group(1)} column", line=None,
                                 column=c, hint="every sigma_<NAME> needs a value_<NAME>")
    with_sigma = [f"sigma_{n}" in cols for n in names]
    if any(with_sigma) and not all(with_sigma):
        missing = [n for n, s in zip(names, with_sigma) if not s]
        raise InputFileError(table.path, f"sigma is given for some channels but not for {', '.join(missing)}",
                             hint="give a sigma_<NAME> column for every channel or for none")
    n = len(table.lines)
    k = len(names)
    rep = lambda a: np.repeat(a, k)  # noqa: E731
    out = {c: rep(cols[c]) for c in DIRECTION_COLUMNS}
    out["value"] = np.stack([cols[f"value_{c}"] for c in names], axis=1).reshape(-1)
    if all(with_sigma) and names:
        out["sigma"] = np.stack([cols[f"sigma_{c}"] for c in names], axis=1).reshape(-1)
    out["channel"] = np.tile(np.arange(k), n)
    return out, tuple(names), rep(table.lines)


#: Angle columns, converted from radians with ``angles="radians"`` (``aperture_deg`` and
#: ``source_divergence_deg`` say degrees in their names and stay degrees).
ANGLE_COLUMNS = DIRECTION_COLUMNS + ("theta_o_lo", "theta_o_hi", "phi_o_lo", "phi_o_hi")
#: Stored quantity → the factor the value is divided by to give f (or f times a scale).
TO_F = {"bsdf": lambda wi, wo: np.ones(len(wi)), "bsdf_cos": lambda wi, wo: np.abs(wo[:, 2]),
        "bsdf_cos_i": lambda wi, wo: np.abs(wi[:, 2]),
        "radiance_factor": lambda wi, wo: np.full(len(wi), np.pi)}


def _radians_to_degrees(table) -> None:
    """``--angles radians``: the angle columns, checked to be radians (θ within [0, π], φ within
    [-2π, 2π]), converted to degrees in place."""
    limits = {"theta": np.pi, "phi": 2 * np.pi}
    for name in ANGLE_COLUMNS:
        if name not in table.columns:
            continue
        col = table.columns[name]
        lim = limits[name.split("_")[0]]
        bad = np.flatnonzero(np.abs(col) > lim * (1 + 1e-12))
        if bad.size:
            raise InputFileError(
                table.path, f"{col[bad[0]]:g} is beyond {'π' if lim == np.pi else '2π'}, but "
                "--angles radians says the angles are radians", line=int(table.lines[bad[0]]),
                column=name, hint="the file's angles look like degrees: drop --angles radians")
        table.columns[name] = np.degrees(col)


def _check_rows(table) -> None:
    """A ``# rows: N`` line: the file has exactly N data rows (a file cut at a row boundary, or
    edited, is refused)."""
    if "rows" not in table.metadata:
        return
    from fitlab.io.validate import parse_number

    line = table.metadata_lines.get("rows")
    hint = "give the number of data rows (lines of values after the header)"
    n = parse_number(table.metadata["rows"], table.path, what="'# rows:'", line=line, lo=1,
                     hint=hint)
    if n != int(n):
        raise InputFileError(table.path, f"'# rows: {table.metadata['rows']}' is not a whole "
                             "number", line=line, hint=hint)
    have = len(table.lines)
    if int(n) != have:
        raise InputFileError(table.path, f"'# rows: {int(n)}' but the file has {have} data rows "
                             f"(the last at line {int(table.lines[-1])})", line=line,
                             hint="the file is truncated or was edited: restore the missing "
                             "rows from its source (or correct the count if rows were removed "
                             "on purpose)")


def read_measurement(path, angles: str = "degrees", quantity: str | None = None,
                     accept=()) -> Measurement:
    """Read and validate a measurement CSV; raises InputFileError naming file, line and column.

    ``angles="radians"``: the file's angles are radians (converted to degrees). ``quantity``
    replaces the file's ``# quantity:`` line. ``accept``: sanity gates accepted (here only
    'radians' matters: a file whose angles look like radians is refused with that message rather
    than one about the sides of the surface; the gates themselves run in read_any)."""
    path = Path(path)
    optional = ("value", "sigma", "channel", "wavelength_nm", "dataset", COMPLETION) \
        + CONE_COLUMNS + BIN_COLUMNS
    table = read_table(path, DIRECTION_COLUMNS, optional, what="measurement CSV",
                       text_columns=("channel", "dataset", COMPLETION),
                       column_pattern=f"{_CHANNEL_VALUE}|{_CHANNEL_SIGMA}",
                       nan_pattern=f"value|sigma|{_CHANNEL_VALUE}|{_CHANNEL_SIGMA}")
    cols, meta = table.columns, table.metadata
    wide = [c for c in cols if re.fullmatch(_CHANNEL_VALUE, c)]
    if wide and ("value" in cols or "channel" in cols or "wavelength_nm" in cols
                 or COMPLETION in cols):
        raise InputFileError(path, "mixes per-channel value_<NAME> columns with a value/channel/"
                             "wavelength_nm/completion column", line=int(table.lines[0]) - 1,
                             hint="use either one value column (with channel or wavelength_nm, "
                             "and completion) or one value_<NAME> column per channel")
    if not wide and "value" not in cols:
        raise InputFileError(path, "the header lacks the column value",
                             hint="a measurement CSV needs theta_i, phi_i, theta_o, phi_o, value")
    if "channel" in cols and "wavelength_nm" in cols:
        raise InputFileError(path, "has both a channel and a wavelength_nm column",
                             hint="name channels either by label or by wavelength, not both")
    _check_rows(table)
    if angles == "radians":
        _radians_to_degrees(table)
    check_angles(table)
    # A file whose angles look like radians gets that message, not one about the sides of the
    # surface its small angles would otherwise earn (the gate itself runs in read_any).
    radians = None
    if angles != "radians" and "radians" not in accept:
        radians = radians_finding(np.concatenate([cols["theta_i"], cols["theta_o"]]),
                                  np.concatenate([cols["phi_i"], cols["phi_o"]]), "csv")
    if quantity is None:
        quantity = _meta_choice(table, "quantity", QUANTITIES,
                                hint="state what the values are: '# quantity: bsdf' (f in 1/sr, "
                                "no cosine), 'bsdf_cos' (f·|cos θo|), 'radiance_factor' (π·f) "
                                "or 'relative' (f up to a scale)")
    relative_to = _meta_choice(table, "relative_to", RELATIVE_TO, default="bsdf")
    scatter = _meta_choice(table, "scatter", SCATTER, default="bsdf")
    check_indices(table.path, table.metadata, table.metadata_lines)

    if wide:
        long, channel_names, lines = _melt_channels(table)
        wavelengths = None
    else:
        long = {c: cols[c] for c in cols}
        lines = table.lines
        if "channel" in cols:
            channel_names = tuple(dict.fromkeys(cols["channel"]))
            index = {c: j for j, c in enumerate(channel_names)}
            long["channel"] = np.array([index[c] for c in cols["channel"]])
            wavelengths = None
        elif "wavelength_nm" in cols:
            wl = cols["wavelength_nm"]
            bad = np.flatnonzero(wl <= 0)
            if bad.size:
                raise InputFileError(path, f"{wl[bad[0]]:g} is not a positive wavelength",
                                     line=int(lines[bad[0]]), column="wavelength_nm")
            uniq = np.unique(wl)
            channel_names = tuple(f"{w:g}nm" for w in uniq)
            long["channel"] = np.searchsorted(uniq, wl)
            wavelengths = uniq
        else:
            channel_names = ("Y",)
            long["channel"] = np.zeros(len(lines), dtype=int)
            wavelengths = None

    aperture = _read_aperture(table, (lambda a: np.repeat(a, len(channel_names), axis=0)) if wide
                              else (lambda a: a))
    dataset, dataset_names = _read_datasets(table)
    if dataset is not None and wide:
        dataset = np.repeat(dataset, len(channel_names))
    ti, to = long["theta_i"], long["theta_o"]
    value = np.asarray(long["value"], dtype=np.float64)
    sigma = long.get("sigma")

    def fail_at(j, column, message, hint=None):
        if radians is not None and column in ("theta_i", "theta_o"):
            raise gate_error(path, radians)
        raise InputFileError(path, message, line=int(lines[j]), column=column, hint=hint)

    for name, th in (("theta_i", ti), ("theta_o", to)):
        bad = np.flatnonzero(th == 90.0)
        if bad.size:
            fail_at(bad[0], name, "90° lies in the surface plane, where no flux is measured",
                    "remove the row or give the angle actually measured")
    same_side = (ti < 90) == (to < 90)
    if scatter == "brdf":
        bad = np.flatnonzero(~same_side)
        if bad.size:
            fail_at(bad[0], "theta_o", f"θo = {to[bad[0]]:g}° is on the other side of the surface "
                    f"from θi = {ti[bad[0]]:g}°, but '# scatter: brdf' says these are reflection data",
                    "θ is measured from the +z normal, 0° to 180°, so θ > 90° is below the "
                    "surface; a reflected direction on the far side of the normal (a negative "
                    "in-plane angle -θ) is written θo = θ with φo + 180°. Declare '# scatter: "
                    "bsdf' only if the file really holds transmitted light too")
    if scatter == "btdf":
        bad = np.flatnonzero(same_side)
        if bad.size:
            fail_at(bad[0], "theta_o", f"θo = {to[bad[0]]:g}° is on the same side as θi = "
                    f"{ti[bad[0]]:g}°, but '# scatter: btdf' says these are transmission data",
                    "a transmitted direction has θo > 90° (below the surface) when the light "
                    "comes from above (θi < 90°), and the reverse; write θo = 180° − θ for an "
                    "angle measured from the -z normal. Declare '# scatter: bsdf' only if the "
                    "file really holds reflected light too")
    if quantity != "relative":
        bad = np.flatnonzero(value < 0)
        if bad.size:
            fail_at(bad[0], "value", f"{value[bad[0]]:g} is negative, which a {quantity} cannot be",
                    "negative values (detector noise) are allowed only with '# quantity: relative'")
    if sigma is not None:
        sigma = np.asarray(sigma, dtype=np.float64)
        bad = np.flatnonzero(sigma <= 0)
        if bad.size:
            fail_at(bad[0], "sigma", f"{sigma[bad[0]]:g} is not a positive uncertainty",
                    "sigma is the absolute 1-σ uncertainty of value and must be > 0")
    reasons = _completion_reasons(table, value, lines)
    if sigma is not None:  # a value filled in by a completion has no sigma
        bad = np.flatnonzero(np.isnan(sigma) & (reasons == MEASURED))
        if bad.size:
            fail_at(bad[0], "sigma", "NaN (no reading) beside a value",
                    "NaN marks a place without reading, in value (and sigma) alike: give the "
                    "value's sigma, or NaN as its value")

    # Duplicate rows: the same directions (and channel) twice.
    key = np.stack([long["theta_i"], np.mod(long["phi_i"], 360.0), long["theta_o"],
                    np.mod(long["phi_o"], 360.0), long["channel"].astype(float),
                    np.zeros(len(value)) if dataset is None else dataset.astype(float)], axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        dup_first = first[counts > 1].min()
        same = np.flatnonzero(np.all(key == key[dup_first], axis=1))
        fail_at(same[1], None, f"repeats the directions of line {int(lines[same[0]])}",
                "merge repeated measurements into one row (mean value, combined sigma) or remove "
                "one" + ("" if dataset is None else " (rows of different datasets may repeat "
                         "directions)"))

    wi = degrees_to_direction(long["theta_i"], long["phi_i"])
    wo = degrees_to_direction(long["theta_o"], long["phi_o"])
    # Convert to one internal quantity: f (or f times an unknown scale).
    stored = quantity if quantity != "relative" else relative_to
    factor = TO_F[stored](wi, wo)
    value = value / factor
    if sigma is not None:
        sigma = sigma / factor
    file_quantity = quantity if quantity != "relative" else f"relative ({relative_to})"
    gap = reasons != MEASURED
    if gap.all():
        raise InputFileError(path, "holds no reading: every value is NaN (or a completed value)",
                             hint="give a file with measured values")
    full = Measurement(
        path=str(path), sha256=sha256_of(path), theta_i=long["theta_i"], phi_i=long["phi_i"],
        theta_o=long["theta_o"], phi_o=long["phi_o"], wi=wi, wo=wo, value=value, sigma=sigma,
        channel=np.asarray(long["channel"], dtype=int), channel_names=channel_names,
        wavelength_nm=wavelengths, quantity="relative" if quantity == "relative" else "bsdf",
        file_quantity=file_quantity,
        metadata={k: v for k, v in meta.items() if k not in CONE_COLUMNS + ("rows",)},
        lines=np.asarray(lines), **aperture, dataset=dataset, dataset_names=dataset_names,
    )
    if gap.any():  # said where the data's metadata go (a fit's data.metadata)
        counts = ", ".join(f"{r} {int(np.sum(reasons == r))}" for r in GAP_REASONS
                           if np.any(reasons == r))
        full = full._replace(metadata={**full.metadata, GAPS_KEY: f"{int(gap.sum())} ({counts})"})
    return check_measurement(split_gaps(full, gap, reasons))


#: The metadata key under which a measurement CSV's rows without reading are counted (not
#: written back: the rows themselves are, or are left out).
GAPS_KEY = "rows_without_reading"


#: The measurement CSV's column that marks a row's value as a reading or as filled in
#: (``fitlab convert --complete``): MEASURED or a GAP_REASONS key.
COMPLETION = "completion"


def _completion_reasons(table, value, lines) -> np.ndarray:
    """Per (long) row: MEASURED, or why it holds no reading: its ``completion`` label (a value
    a completion filled in), else ``no_reading`` where the value is NaN."""
    labels = table.columns.get(COMPLETION)
    out = np.where(np.isnan(value), "no_reading", MEASURED).astype(object)
    if labels is None:
        return out
    known = (MEASURED,) + tuple(GAP_REASONS)
    for j, c in enumerate(labels):
        if c not in known:
            from fitlab.io.validate import quote

            raise InputFileError(table.path, f"{quote(c)} is not a completion label",
                                 line=int(lines[j]), column=COMPLETION,
                                 hint=f"use {', '.join(known)} (data_formats/completion_json.md)")
    return np.where(labels != MEASURED, labels, out).astype(object)


def one_dataset(m: Measurement) -> Measurement:
    """``m`` as one dataset: itself, or its only dataset; a file of several datasets raises a
    FitlabError saying how to fit them (one fit per dataset: fitlab fit FILE --out-dir DIR)."""
    from fitlab.errors import FitlabError

    if m.dataset is None:
        return m
    if len(m.dataset_names) == 1:
        return m.datasets()[0]
    shown = ", ".join(m.dataset_names[:5]) + (", ..." if len(m.dataset_names) > 5 else "")
    raise FitlabError(f"{m.path} holds {len(m.dataset_names)} datasets (column dataset: "
                      f"{shown}); fit each on its own with `fitlab fit {Path(m.path).name} "
                      "--model ... --out-dir DIR` (or --table T.csv; fitlab.fit_many in Python), "
                      "or take one with Measurement.dataset_named(LABEL)")


def _read_datasets(table):
    """The ``dataset`` column: per row an index into the labels (in the file's order), or
    (None, ()) without the column."""
    cells = table.columns.get("dataset")
    if cells is None:
        return None, ()
    from fitlab.io.validate import quote

    for j, c in enumerate(cells):
        if not DATASET_LABEL.fullmatch(c):
            raise InputFileError(table.path, f"{quote(c)} is not a dataset label",
                                 line=int(table.lines[j]), column="dataset",
                                 hint="use letters, digits, '_', '-' and '.' (at most 64, not "
                                 "starting with '-' or '.'); each label names one dataset")
    names = tuple(dict.fromkeys(cells))
    index = {c: k for k, c in enumerate(names)}
    return np.array([index[c] for c in cells], dtype=int), names


def _read_aperture(table, per_row) -> dict:
    """The Measurement's aperture fields from the columns (per row) and the ``# aperture_deg:``
    / ``# source_divergence_deg:`` metadata lines (every row; a column overrides the line).
    ``per_row`` maps a table column to the Measurement's rows (repeated per channel in the wide
    form). Ranges are checked with the rest of the Measurement (check_aperture)."""
    from fitlab.io.validate import parse_number

    cols, n = table.columns, len(table.lines)
    out = {}
    for name in CONE_COLUMNS:
        if name in cols:
            out[name] = per_row(np.asarray(cols[name], dtype=np.float64))
        elif name in table.metadata:
            v = parse_number(table.metadata[name], table.path, what=f"'# {name}:'",
                             line=table.metadata_lines.get(name), lo=0.0, hi=MAX_CONE_DEG,
                             hint="give the cone's half-angle in degrees, in [0, 90)")
            out[name] = per_row(np.full(n, v))
    given = [c for c in BIN_COLUMNS if c in cols]
    if given and len(given) != len(BIN_COLUMNS):
        missing = [c for c in BIN_COLUMNS if c not in cols]
        raise InputFileError(table.path, f"gives {', '.join(given)} but not {', '.join(missing)}",
                             line=int(table.lines[0]) - 1,
                             hint="a bin needs the four columns " + ", ".join(BIN_COLUMNS))
    if given:
        out["bin_o_deg"] = per_row(np.stack([np.asarray(cols[c], dtype=np.float64)
                                             for c in BIN_COLUMNS], axis=1))
    return out


# --------------------------------------------------------------------------------------------
# Writing, detection and description (the format registry's entry)
# --------------------------------------------------------------------------------------------


def format_measurement_csv(m: Measurement, extra_metadata: dict | None = None,
                           completion=None) -> str:
    """Measurement → fitlab measurement CSV text (long form; quantity bsdf or relative of f).
    ``completion``: per row MEASURED or the GAP_REASONS key of a value filled in (the
    ``completion`` column, data_formats/completion_json.md; its sigma is written NaN)."""
    import io

    out = io.StringIO()
    out.write("# fitlab measurement CSV (data_formats/measurement_csv.md)\n")
    meta = {k: v for k, v in m.metadata.items()
            if k not in ("quantity", "relative_to", "scatter", GAPS_KEY) + CONE_COLUMNS}
    meta.update(extra_metadata or {})
    # The aperture: a cone the same for every row as a metadata line, else per-row columns.
    per_row = {}
    for name in CONE_COLUMNS:
        arr = getattr(m, name)
        if arr is None or not arr.size:
            continue
        if np.all(arr == arr[0]):
            meta[name] = f"{arr[0]:.10g}"
        else:
            per_row[name] = arr
    if m.bin_o_deg is not None:
        per_row.update({c: m.bin_o_deg[:, k] for k, c in enumerate(BIN_COLUMNS)})
    out.write(f"# quantity: {m.quantity}\n")
    out.write(f"# rows: {m.n}\n")  # the long form: a line per row (a cut file is refused)
    for k, v in meta.items():
        out.write(f"# {k}: {v}\n")
    spectral = m.wavelength_nm is not None
    multi = len(m.channel_names) > 1 and not spectral
    cols = ["theta_i", "phi_i", "theta_o", "phi_o"] + list(per_row) \
        + (["dataset"] if m.dataset is not None else []) \
        + (["channel"] if multi else []) + (["wavelength_nm"] if spectral else []) + ["value"]
    if m.sigma is not None:
        cols.append("sigma")
    if completion is not None:
        cols.append(COMPLETION)
    out.write(",".join(cols) + "\n")
    for j in range(m.n):
        cells = [f"{m.theta_i[j]:.10g}", f"{m.phi_i[j]:.10g}", f"{m.theta_o[j]:.10g}",
                 f"{m.phi_o[j]:.10g}"] + [f"{a[j]:.10g}" for a in per_row.values()]
        if m.dataset is not None:
            cells.append(m.dataset_names[m.dataset[j]])
        if multi:
            cells.append(m.channel_names[m.channel[j]])
        if spectral:
            cells.append(f"{m.wavelength_nm[m.channel[j]]:.10g}")
        cells.append(f"{m.value[j]:.9e}")
        if m.sigma is not None:
            cells.append(f"{m.sigma[j]:.6e}")
        if completion is not None:
            cells.append(str(completion[j]))
        out.write(",".join(cells) + "\n")
    return out.getvalue()


def first_line(head: bytes) -> str | None:
    """The first line of a text file's ``head`` that is neither empty nor a ``#`` comment,
    stripped (None if there is none): where a CSV format's detection looks for its header."""
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    for line in text.splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            return s
    return None


def _detect(head: bytes, path) -> bool:
    s = first_line(head)
    return s is not None and (s.replace(" ", "").startswith(("theta_i", "phi_i", "theta_o",
                                                             "phi_o"))
                              or "theta_i" in s.split(","))


def describe_measurement(path, format_name: str = "csv", accept=(), angles: str = "degrees",
                         quantity: str | None = None) -> dict:
    m = read_measurement(path, angles=angles, quantity=quantity, accept=accept)
    return describe_loaded(m, format_name, accept)


def describe_loaded(m: Measurement, format_name: str | None = None, accept=()) -> dict:
    """What a Measurement holds, for ``fitlab info`` (shared by every reader; checked as
    ``read_any`` checks it first). ``warnings``: every sanity gate the file trips (refused by
    the commands that read it unless ``accept`` names the gate: then said to be accepted);
    ``sanity_gates``: what each gate found (fitlab.io.gates)."""
    check_measurement(m)
    warnings, gates = summary(m, format_name, accept)
    incid = np.unique(np.stack([m.theta_i, np.mod(m.phi_i, 360)], axis=1), axis=0)
    trans = (m.wi[:, 2] * m.wo[:, 2]) < 0
    return {
        "rows": m.n,
        "quantity": m.quantity,
        "stored_quantity": m.file_quantity,
        "unit": "1/sr (BSDF f, no cosine)" if m.quantity == "bsdf" else "relative (unknown scale × f)",
        "channels": list(m.channel_names),
        **({"datasets": list(m.dataset_names)} if m.dataset is not None else {}),
        "incident_directions": len(incid),
        "theta_i_deg": sorted({float(x) for x in m.theta_i}),
        "theta_o_range_deg": [float(m.theta_o.min()), float(m.theta_o.max())],
        "phi_o_range_deg": [float(m.phi_o.min()), float(m.phi_o.max())],
        "reflection_rows": int((~trans).sum()),
        "transmission_rows": int(trans.sum()),
        "value_range": [float(m.value.min()), float(m.value.max())],
        "sigma": "given" if m.sigma is not None else "not given",
        **({"without_reading": {**m.gaps.counts(), "note": "places of the file's table "
                                "holding no reading, left out of every fit; `fitlab convert "
                                "FILE --complete FIT.json OUT` fills them from a fit"}}
           if m.gaps is not None else {}),
        "eta_inside_over_outside": m.eta(),
        "metadata": m.metadata,
        "sha256": m.sha256,
        "warnings": warnings,
        "sanity_gates": gates,
        **({"aperture": aperture_summary(m)} if m.has_aperture else {}),
    }


def aperture_summary(m: Measurement) -> dict:
    """What the rows' apertures are (``fitlab info``; a fit's parameter file)."""
    from fitlab.aperture import bin_has_extent

    out = {}
    if m.aperture_deg is not None and np.any(m.aperture_deg > 0):
        a = m.aperture_deg[m.aperture_deg > 0]
        out["detector_cone_rows"] = int(a.size)
        out["detector_cone_half_angle_deg"] = [float(a.min()), float(a.max())]
    if m.bin_o_deg is not None and np.any(bin_has_extent(m.bin_o_deg)):
        b = m.bin_o_deg[bin_has_extent(m.bin_o_deg)]
        out["bin_rows"] = int(b.shape[0])
        out["bin_width_theta_deg"] = [float((b[:, 1] - b[:, 0]).min()),
                                      float((b[:, 1] - b[:, 0]).max())]
        out["bin_width_phi_deg"] = [float((b[:, 3] - b[:, 2]).min()),
                                    float((b[:, 3] - b[:, 2]).max())]
    if m.source_divergence_deg is not None and np.any(m.source_divergence_deg > 0):
        d = m.source_divergence_deg[m.source_divergence_deg > 0]
        out["source_cone_rows"] = int(d.size)
        out["source_divergence_deg"] = [float(d.min()), float(d.max())]
    return out


FORMAT = Format("csv", "fitlab measurement CSV", _detect, read_measurement,
                describe_measurement, "data_formats/measurement_csv.md", suffixes=(".csv",),
                takes=("angles", "quantity"))
