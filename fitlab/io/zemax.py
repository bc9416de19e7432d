"""Zemax / Radiant Imaging tabular BSDF text files (the "BSDF Data Interchange" format,
``.bsdf``): reading to a Measurement with a TIS check, and the text of a file to write
(:func:`format_zemax`; fitlab.export.zemax tabulates registry models and fits into it).
Spec, angle conversion and decisions: data_formats/zemax_bsdf.md.

A file tabulates the BSDF per (SampleRotation, AngleOfIncidence) block on a grid of
(ScatterAzimuth, ScatterRadial) angles measured about the *pole*: the specular ray (BRDF) or
the refracted, directly transmitted ray (BTDF). Radial 0 is the pole; azimuth 0 points from
the pole toward the normal axis on the pole's side and azimuths turn counter-clockwise seen
from the detector (right-handed about the pole). In fitlab's frame, with the light at azimuth
φi = SampleRotation, the pole s, the unit vector e0 toward the normal axis and e90 = s × e0 are

    s  = dir(θs, φi + 180°),  θs = AOI (BRDF) or 180° − AOI (BTDF)
    e0 = dir(θs − 90°, φi + 180°) (BRDF) or dir(θs + 90°, φi + 180°) (BTDF)
    wo(radial r, azimuth a) = sin r cos a · e0 + sin r sin a · e90 + cos r · s

and wi = dir(θi, φi) with θi = AOI (BRDF) or arcsin(η sin AOI) (BTDF, η = n_inside/n_outside).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.csvtable import text_lines
from fitlab.io.format import Format
from fitlab.io.validate import check_count, decode_text, parse_number, quote
from fitlab.io.directions import degrees_to_direction, direction_to_degrees
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.measurement import Measurement, check_indices, describe_loaded, split_gaps
from fitlab.io.gates import TisBlock

SPEC = "data_formats/zemax_bsdf.md"
LIST_KEYWORDS = ("SampleRotation", "AngleOfIncidence", "ScatterAzimuth", "ScatterRadial")
WORD_KEYWORDS = ("Source", "Symmetry", "SpectralContent", "ScatterType")
HEADER_KEYWORDS = WORD_KEYWORDS + LIST_KEYWORDS
REQUIRED = ("Symmetry", "SpectralContent", "ScatterType", "AngleOfIncidence", "ScatterAzimuth",
            "ScatterRadial")
#: accepted spellings (case-insensitive) → the spelling fitlab reports and writes
SYMMETRY = {"planesymmetrical": "PlaneSymmetrical", "asymmetrical": "Asymmetrical",
            "asymmetrical4d": "Asymmetrical4D"}
SPECTRAL = {"monochrome": "Monochrome", "xyz": "XYZ"}
SCATTER = {"brdf": "BRDF", "btdf": "BTDF"}
#: channel each spectral-content indicator line starts; Monochrome is fitlab's single channel Y
INDICATORS = {"monochrome": "Y", "tristimulusx": "X", "tristimulusy": "Y", "tristimulusz": "Z"}
CHANNELS = {"Monochrome": ("Y",), "XYZ": ("X", "Y", "Z")}
DATA_WORDS = ("databegin", "dataend", "tis")
#: |cos θo| at or below this counts as the surface plane or the wrong side (masked)
HORIZON_EPS = 1e-9


class ZemaxFile(NamedTuple):
    """A parsed, validated file: the stored tables as they are (no mirroring, no masking)."""

    path: str
    source: str | None
    symmetry: str  # PlaneSymmetrical | Asymmetrical | Asymmetrical4D
    spectral: str  # Monochrome | XYZ
    scatter: str  # BRDF | BTDF
    rotation: np.ndarray  # SampleRotation, degrees
    aoi: np.ndarray  # AngleOfIncidence = polar angle of the pole (specular / transmitted ray)
    azimuth: np.ndarray  # ScatterAzimuth as stored, degrees
    radial: np.ndarray  # ScatterRadial, degrees
    channels: tuple[str, ...]
    tis: np.ndarray  # (channel, rotation, aoi)
    values: np.ndarray  # (channel, rotation, aoi, azimuth, radial), f in 1/sr
    row_lines: np.ndarray  # (channel, rotation, aoi, azimuth): file line of each stored row
    comments: tuple[str, ...]  # prose comment lines, '#' removed
    metadata: dict  # '# key: value' comment lines (keys lower-cased)


# --------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------


def _read_text(path: Path) -> str:
    raw = read_bytes(path, folder_hint="give the path of a .bsdf file")
    # only comments can hold non-ASCII text, often in a legacy code page: latin-1 then
    return decode_text(path, raw, what="Zemax BSDF", encoding="utf-8-sig", fallback="latin-1")


def _lines(text):
    """(line number, tokens) of every non-blank, non-comment line, plus the comment lines."""
    content, comments, metadata, meta_lines = [], [], {}, {}
    for lineno, s, meta in text_lines(text):
        if s.startswith("#"):
            if meta:
                metadata[meta[0]] = meta[1]
                meta_lines[meta[0]] = lineno
            else:
                comments.append(s.lstrip("#").strip())
            continue
        content.append((lineno, s.split()))
    return content, tuple(c for c in comments if c), metadata, meta_lines


def _is_number(token) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _number(path, lineno, token, what, hint="write a decimal number") -> float:
    return parse_number(token, path, line=lineno, column=what, hint=hint)


def _choice(path, lineno, keyword, tokens, choices):
    if len(tokens) != 2:
        raise InputFileError(path, f"'{keyword}' takes one word, found {len(tokens) - 1}",
                             line=lineno, hint=f"write '{keyword} ' and one of "
                             f"{', '.join(dict.fromkeys(choices.values()))}")
    value = choices.get(tokens[1].lower())
    if value is None:
        raise InputFileError(path, f"'{keyword} {tokens[1]}' is not one of "
                             f"{', '.join(dict.fromkeys(choices.values()))}", line=lineno,
                             hint=f"use one of {', '.join(dict.fromkeys(choices.values()))} "
                             f"(see {SPEC})")
    return value


def _keyword(tokens):
    """The canonical keyword a line starts with, or None."""
    word = tokens[0].lower()
    for k in HEADER_KEYWORDS:
        if k.lower() == word:
            return k
    return None


def _parse_header(path, content):
    """Header keywords up to the first data line; returns (header, index of the first data line)."""
    header, lines = {}, {}  # lines: where each keyword stands
    i = 0
    while i < len(content):
        lineno, tokens = content[i]
        word = tokens[0].lower()
        if word in INDICATORS or word in DATA_WORDS:
            break
        key = _keyword(tokens)
        if key is None:
            what = "numbers" if _is_number(tokens[0]) else f"the unknown keyword {quote(tokens[0])}"
            raise InputFileError(
                path, f"found {what} where a header keyword was expected", line=lineno,
                hint=f"header lines start with one of {', '.join(HEADER_KEYWORDS)}; "
                "comments start with #",
            )
        if key in header:
            raise InputFileError(path, f"'{key}' appears twice (first on line {lines[key]})",
                                 line=lineno, hint="keep one")
        lines[key] = lineno
        i += 1
        if key == "Source":
            header[key] = " ".join(tokens[1:])
        elif key == "Symmetry":
            header[key] = _choice(path, lineno, key, tokens, SYMMETRY)
        elif key == "SpectralContent":
            header[key] = _choice(path, lineno, key, tokens, SPECTRAL)
        elif key == "ScatterType":
            header[key] = _choice(path, lineno, key, tokens, SCATTER)
        else:
            i, header[key] = _parse_list(path, content, i, key, tokens)
    for key in REQUIRED:
        if key not in header:
            at = content[i][0] if i < len(content) else None
            raise InputFileError(path, f"the header lacks the '{key}' line", line=at,
                                 hint=f"a Zemax BSDF header has the lines {', '.join(REQUIRED)} "
                                 f"before the data (see {SPEC})")
    header.setdefault("SampleRotation", np.zeros(1))
    return header, i


def _parse_list(path, content, i, key, tokens):
    """'<key> <count> [angles]' then angle lines up to the next keyword line."""
    lineno = content[i - 1][0]
    if len(tokens) < 2:
        raise InputFileError(path, f"'{key}' needs the number of angles", line=lineno,
                             hint=f"write '{key} <count>' and the angles on the next line")
    try:
        count = int(tokens[1])
    except ValueError:
        raise InputFileError(path, f"'{key} {tokens[1]}': the count must be a whole number",
                             line=lineno, hint=f"write '{key} <count>'") from None
    if count < 1:
        raise InputFileError(path, f"'{key} {count}': the count must be at least 1", line=lineno,
                             hint="list at least one angle")
    cells = [(lineno, t) for t in tokens[2:]]
    while i < len(content) and _is_number(content[i][1][0]):
        cells += [(content[i][0], t) for t in content[i][1]]
        i += 1
    angles = np.array([_number(path, ln, t, key) for ln, t in cells])
    if angles.size != count:
        raise InputFileError(
            path, f"'{key} {count}' announces {count} angles but {angles.size} follow",
            line=lineno, hint="make the count match the list of angles after it",
        )
    _check_angles(path, [ln for ln, _ in cells], key, angles)
    return i, angles


_RANGES = {"AngleOfIncidence": (0.0, 90.0, False), "ScatterRadial": (0.0, 180.0, True),
           "ScatterAzimuth": (-360.0, 360.0, True), "SampleRotation": (-360.0, 360.0, True)}


def _check_angles(path, lines, key, angles):
    lo, hi, closed = _RANGES[key]
    bad = np.flatnonzero((angles < lo) | (angles > hi) | ((angles == hi) & (not closed)))
    if bad.size:
        interval = f"[{lo:g}°, {hi:g}°{']' if closed else ')'}"
        raise InputFileError(path, f"{angles[bad[0]]:g}° is outside {interval}",
                             line=lines[bad[0]], column=key,
                             hint=f"{key} angles are in degrees (see {SPEC})")
    dup = _first_duplicate(angles)  # 0° and 360° may both be listed: they differ here
    if dup is not None:
        raise InputFileError(path, f"{angles[dup[1]]:g}° is listed twice", line=lines[dup[1]],
                             column=key, hint="list every angle once")


def _first_duplicate(a):
    seen = {}
    for j, x in enumerate(a):
        if x in seen:
            return seen[x], j
        seen[x] = j
    return None


#: Above this many declared values the header's counts are checked against the numbers present
#: before the arrays are allocated.
ALLOCATION_CHECK_VALUES = 1 << 20


def _parse_data(path, content, i, header):
    """The data section(s): indicator lines, DataBegin, blocks ('TIS v' + azimuth rows), DataEnd."""
    channels = CHANNELS[header["SpectralContent"]]
    n_rot, n_aoi = len(header["SampleRotation"]), len(header["AngleOfIncidence"])
    n_az, n_rad = len(header["ScatterAzimuth"]), len(header["ScatterRadial"])
    n_blocks = n_rot * n_aoi
    # the header's counts size the arrays: check them against the values actually present
    # before allocating anything (a few kB of header must not make fitlab allocate GiB)
    # (small files go on to the block-by-block checks, which name the line where data end)
    needed = len(channels) * n_blocks * n_az * n_rad
    present = sum(len(tokens) for _, tokens in content[i:])
    if needed > ALLOCATION_CHECK_VALUES:
        check_count(needed, path, present=present,
                    what=f"the header's count of values ({len(channels)} channel(s) × {n_rot} "
                    f"SampleRotation × {n_aoi} AngleOfIncidence × {n_az} ScatterAzimuth × "
                    f"{n_rad} ScatterRadial)",
                    hint="the file is cut short or its counts are wrong")
    values = np.zeros((len(channels), n_blocks, n_az, n_rad))
    tis = np.zeros((len(channels), n_blocks))
    lines = np.zeros((len(channels), n_blocks, n_az), dtype=int)
    done = {c: 0 for c in channels}
    channel = None
    in_data = seen_begin = False
    last = content[-1][0] if content else 1

    def incomplete(at, message, hint):
        raise InputFileError(path, message, line=at, hint=hint)

    def check_complete(at, why):
        if channel is not None and done[channel] < n_blocks:
            incomplete(at, f"{why} after {done[channel]} of the {n_blocks} blocks of channel "
                       f"{channel} ({n_rot} SampleRotation × {n_aoi} AngleOfIncidence)",
                       "the file is incomplete or its counts are wrong: every block is a "
                       f"'TIS <value>' line and {n_az} rows of {n_rad} values")

    while i < len(content):
        lineno, tokens = content[i]
        word = tokens[0].lower()
        if word in INDICATORS:
            wanted = "Monochrome" if header["SpectralContent"] == "Monochrome" else \
                "TristimulusX, TristimulusY or TristimulusZ"
            if (word == "monochrome") != (header["SpectralContent"] == "Monochrome"):
                raise InputFileError(path, f"'{tokens[0]}' does not match 'SpectralContent "
                                     f"{header['SpectralContent']}'", line=lineno,
                                     hint=f"this file's data sections start with {wanted}")
            check_complete(lineno, f"'{tokens[0]}' starts")
            channel = INDICATORS[word]
            if done[channel]:
                raise InputFileError(path, f"the data of channel {channel} appear twice",
                                     line=lineno, hint="give each channel's data once")
            i += 1
        elif word == "databegin":
            if in_data:
                raise InputFileError(path, "DataBegin inside a data section", line=lineno,
                                     hint="end the previous section with DataEnd")
            in_data = seen_begin = True
            i += 1
        elif word == "dataend":
            if not in_data:
                raise InputFileError(path, "DataEnd without DataBegin", line=lineno,
                                     hint="start the data with a DataBegin line")
            check_complete(lineno, "DataEnd comes")
            in_data = False
            i += 1
        elif word == "tis":
            if not in_data:
                raise InputFileError(path, "data before DataBegin", line=lineno,
                                     hint="put a DataBegin line before the first TIS line "
                                     "(and DataEnd after the last block)")
            if channel is None:
                if header["SpectralContent"] != "Monochrome":
                    raise InputFileError(path, "a TIS block before any TristimulusX/Y/Z line",
                                         line=lineno, hint="start each colour's data with "
                                         "TristimulusX, TristimulusY or TristimulusZ")
                channel = "Y"  # lenient: a Monochrome file without its 'Monochrome' line
            c, b = channels.index(channel), done[channel]
            if b == n_blocks:
                raise InputFileError(path, f"a block more than the {n_blocks} that "
                                     f"SampleRotation × AngleOfIncidence announce", line=lineno,
                                     hint="remove the extra block or fix the counts")
            if len(tokens) != 2:
                raise InputFileError(path, "a TIS line holds 'TIS' and one number", line=lineno,
                                     hint="write 'TIS <total integrated scatter>'")
            tis[c, b] = _number(path, lineno, tokens[1], "TIS")
            if tis[c, b] < 0:
                raise InputFileError(path, f"TIS {tokens[1]} is negative", line=lineno,
                                     column="TIS", hint="TIS is a fraction of the incident flux")
            i += 1
            for a in range(n_az):
                if i >= len(content) or not _is_number(content[i][1][0]):
                    at = content[i][0] if i < len(content) else last
                    found = "the end of the file" if i >= len(content) else \
                        f"{quote(content[i][1][0])}"
                    incomplete(at, f"the block of TIS line {lineno} has {a} of its {n_az} "
                               f"azimuth rows before {found}",
                               f"each block has one row per ScatterAzimuth angle ({n_az}); the "
                               "file is truncated or a count is wrong")
                values[c, b, a], lines[c, b, a] = _row(path, content[i], header), content[i][0]
                i += 1
            done[channel] += 1
        elif _is_number(tokens[0]):
            raise InputFileError(path, "a row of numbers outside a block", line=lineno,
                                 hint=f"a block has exactly {n_az} rows after its TIS line; "
                                 "check ScatterAzimuth and the rows of the block above")
        else:
            raise InputFileError(path, f"unexpected {quote(tokens[0])} in the data section",
                                 line=lineno, hint="the data section holds Monochrome/"
                                 "TristimulusX/Y/Z, DataBegin, TIS blocks and DataEnd")
    if not seen_begin:
        raise InputFileError(path, "has no DataBegin line and no data", line=last,
                             hint="after the header write the spectral line (Monochrome), "
                             "DataBegin, the TIS blocks and DataEnd")
    check_complete(last, "the file ends")
    if in_data:
        raise InputFileError(path, "the data section has no DataEnd line", line=last,
                             hint="end the data with a DataEnd line (or the file was cut)")
    missing = [c for c in channels if done[c] < n_blocks]
    if missing:
        raise InputFileError(path, f"has no data blocks for channel(s) {', '.join(missing)}",
                             line=last, hint="each block is a 'TIS <value>' line and its rows "
                             "(SpectralContent XYZ needs TristimulusX, TristimulusY and "
                             "TristimulusZ data)")
    shape = (len(channels), n_rot, n_aoi)
    return (tis.reshape(shape), values.reshape(shape + (n_az, n_rad)),
            lines.reshape(shape + (n_az,)), channels)


def _row(path, line, header):
    lineno, tokens = line
    radial = header["ScatterRadial"]
    if len(tokens) != len(radial):
        raise InputFileError(path, f"has {len(tokens)} values but ScatterRadial lists "
                             f"{len(radial)} angles", line=lineno,
                             hint="each row holds one value per ScatterRadial angle")
    row = np.empty(len(tokens))
    for j, t in enumerate(tokens):
        what = f"value {j + 1} (radial {radial[j]:g}°)"
        row[j] = _number(path, lineno, t, what)
        if row[j] < 0:
            raise InputFileError(path, f"{t} is negative, which a BSDF cannot be", line=lineno,
                                 column=what, hint="write 0.000E+00 where nothing was measured")
    return row


def parse_zemax(path) -> ZemaxFile:
    """Read and validate a Zemax tabular BSDF file; errors name the file, line and value."""
    path = Path(path)
    content, comments, metadata, meta_lines = _lines(_read_text(path))
    check_indices(path, metadata, meta_lines)  # '# eta_inside/outside:' before they are used
    if not content:
        raise InputFileError(path, "is empty (only comments or blank lines)",
                             hint=f"a Zemax BSDF file has a header and a data section ({SPEC})")
    header, i = _parse_header(path, content)
    tis, values, lines, channels = _parse_data(path, content, i, header)
    return ZemaxFile(
        path=str(path), source=header.get("Source"), symmetry=header["Symmetry"],
        spectral=header["SpectralContent"], scatter=header["ScatterType"],
        rotation=header["SampleRotation"], aoi=header["AngleOfIncidence"],
        azimuth=header["ScatterAzimuth"], radial=header["ScatterRadial"], channels=channels,
        tis=tis, values=values, row_lines=lines, comments=comments, metadata=metadata,
    )


# --------------------------------------------------------------------------------------------
# Geometry (NumPy: this is I/O-side conversion)
# --------------------------------------------------------------------------------------------


def incidence_angle(aoi, scatter: str, eta: float = 1.0) -> np.ndarray:
    """θi of the light for AngleOfIncidence values: the same angle for BRDF; for BTDF the file
    gives the refracted ray's angle θt, and n_out sin θi = n_in sin θt gives θi."""
    aoi = np.asarray(aoi, dtype=np.float64)
    if scatter == "BRDF":
        return aoi
    s = eta * np.sin(np.radians(aoi))
    if np.any(s >= 1.0):
        raise ValueError(f"AngleOfIncidence {aoi[s >= 1][0]:g}° is no refraction angle for "
                         f"eta = {eta:g} (largest {np.degrees(np.arcsin(min(1, 1 / eta))):.4g}°)")
    return np.degrees(np.arcsin(s))


def scatter_frame(aoi, rotation, scatter: str) -> np.ndarray:
    """(..., 3, 3) matrices whose columns are e0, e90 and the pole s (see the module doc)."""
    aoi, rotation = np.broadcast_arrays(np.asarray(aoi, float), np.asarray(rotation, float))
    below = scatter == "BTDF"
    theta_s = 180.0 - aoi if below else aoi
    phi_s = rotation + 180.0
    s = degrees_to_direction(theta_s, phi_s)
    e0 = degrees_to_direction(theta_s + 90.0 if below else theta_s - 90.0, phi_s)
    return np.stack([e0, np.cross(s, e0), s], axis=-1)


def scatter_directions(frame, radial, azimuth) -> np.ndarray:
    """wo for (radial, azimuth) in degrees about the pole of ``frame`` (broadcasting)."""
    local = degrees_to_direction(*np.broadcast_arrays(radial, azimuth))
    return np.einsum("...ij,...j->...i", frame, local)


def full_azimuths(zf: ZemaxFile):
    """Azimuths over the whole circle, sorted in [0°, 360°): PlaneSymmetrical data mirrored
    (a → 360° − a), 360° folded onto 0°. Returns (azimuths, index of each one's stored row)."""
    az = np.mod(zf.azimuth, 360.0)
    src = list(range(len(az)))
    if zf.symmetry == "PlaneSymmetrical":
        mirror = [(360.0 - a, j) for j, a in enumerate(az) if 0.0 < a < 180.0]
        az = np.concatenate([az, [m for m, _ in mirror]])
        src += [j for _, j in mirror]
    order = np.argsort(az, kind="stable")
    az, src = az[order], np.asarray(src)[order]
    keep = np.concatenate([[True], np.diff(az) > 1e-9])
    return az[keep], src[keep]


def cell_weights(radial, azimuth) -> np.ndarray:
    """Solid angle of each (azimuth, radial) grid cell about the pole, (n_az, n_rad): radial
    cells run between midpoints (clipped to the first and last radial), azimuth cells likewise,
    periodic when the azimuths go round the circle (the wrap-around gap is no wider than the
    widest gap between listed azimuths)."""
    r = np.radians(np.sort(radial))
    mid = (r[1:] + r[:-1]) / 2
    dcos = np.cos(np.concatenate([[r[0]], mid])) - np.cos(np.concatenate([mid, [r[-1]]]))
    a = np.radians(azimuth)
    if a.size == 1:
        da = np.array([2 * np.pi])
    else:
        gaps = np.diff(a)
        wrap = 2 * np.pi - (a[-1] - a[0])
        if wrap <= gaps.max() + 1e-9:
            before = np.concatenate([[wrap], gaps])
            after = np.concatenate([gaps, [wrap]])
        else:
            before = np.concatenate([[0.0], gaps])
            after = np.concatenate([gaps, [0.0]])
        da = (before + after) / 2
    order = np.argsort(np.argsort(radial))
    return da[:, None] * dcos[order][None, :]


def side_cosine(wo, scatter: str) -> np.ndarray:
    """cos θo on the side the file's ScatterType scatters to; ≤ 0 means masked."""
    return wo[..., 2] if scatter == "BRDF" else -wo[..., 2]


# --------------------------------------------------------------------------------------------
# To a Measurement, with the TIS check
# --------------------------------------------------------------------------------------------


def _eta(zf: ZemaxFile, eta):
    if eta is not None:
        return float(eta), "given"
    try:
        inside = float(zf.metadata["eta_inside"])
        outside = float(zf.metadata.get("eta_outside", 1.0))
    except (KeyError, ValueError):
        return 1.0, "assumed"
    return inside / outside, "file"


def _grid(zf: ZemaxFile, eta: float):
    """Incidence angles, full azimuths and outgoing directions of every grid point."""
    try:
        theta_i = incidence_angle(zf.aoi, zf.scatter, eta)
    except ValueError as exc:
        raise InputFileError(zf.path, str(exc), hint="give the refractive-index ratio "
                             "(eta = n_inside/n_outside) the file was made for") from None
    az, src = full_azimuths(zf)
    frame = scatter_frame(zf.aoi[None, :], zf.rotation[:, None], zf.scatter)  # (rot, aoi, 3, 3)
    wo = scatter_directions(frame[:, :, None, None], zf.radial[None, :], az[:, None])
    return theta_i, az, src, wo  # wo: (rot, aoi, az, rad, 3)


def tis_check(zf: ZemaxFile, eta: float | None = None) -> list[dict]:
    """Per (channel, rotation, AOI) block: ∫ f cos θo dω over the file's grid (cells about the
    pole, masked directions counting 0) against the stored TIS, and the grid's coverage: the
    fraction of the projected hemisphere (∫ cos θo dω = π) its cells span."""
    eta, _ = _eta(zf, eta)
    _, az, src, wo = _grid(zf, eta)
    cos = np.clip(side_cosine(wo, zf.scatter), 0.0, None)
    weights = cell_weights(zf.radial, az)
    values = zf.values[:, :, :, src, :]
    integral = np.sum(values * cos[None] * weights, axis=(-1, -2))
    coverage = np.sum(cos * weights, axis=(-1, -2)) / np.pi  # (rot, aoi)
    out = []
    for c, ch in enumerate(zf.channels):
        for r, rot in enumerate(zf.rotation):
            for k, aoi in enumerate(zf.aoi):
                t, v = float(zf.tis[c, r, k]), float(integral[c, r, k])
                out.append({"channel": ch, "sample_rotation": float(rot), "aoi": float(aoi),
                            "tis": t, "integral": v,
                            "difference": (v / t - 1.0) if t > 0 else None,
                            "coverage": float(coverage[r, k])})
    return out


def _block_label(row, zf):
    parts = []
    if len(zf.channels) > 1:
        parts.append(row["channel"])
    if len(zf.rotation) > 1:
        parts.append(f"rot {row['sample_rotation']:g}")
    parts.append(f"AOI {row['aoi']:g}")
    return " ".join(parts)


def _tis_summary(rows, zf) -> str:
    diffs = [r["difference"] for r in rows if r["difference"] is not None]
    head = ("integral of f cos(theta_o) over the file grid / stored TIS - 1: "
            + (f"{min(diffs):+.1%} to {max(diffs):+.1%}" if diffs else "n/a"))
    blocks = ", ".join(f"{_block_label(r, zf)}: {r['integral']:.4g}/{r['tis']:.4g}" for r in rows)
    return f"{head} ({blocks})"


def to_measurement(zf: ZemaxFile, eta: float | None = None, keep_zeros: bool = False,
                   tis_rows: list | None = None) -> Measurement:
    """Every grid point as a (wi, wo, value) row: plane-symmetric data mirrored, repeated
    directions (radial 0 at every azimuth, azimuth 0° and 360°) merged by their mean, and
    directions on the wrong side of the surface (or in it) dropped, as are stored zeros unless
    ``keep_zeros`` (instruments write 0.000E+00 where they measured nothing)."""
    eta, eta_source = _eta(zf, eta)
    theta_i, az, src, wo = _grid(zf, eta)
    n_ch, n_rot, n_aoi = zf.tis.shape
    n_az, n_rad = len(az), len(zf.radial)
    shape = (n_ch, n_rot, n_aoi, n_az, n_rad)
    wo = np.broadcast_to(wo[None], shape + (3,)).reshape(-1, 3)
    value = zf.values[:, :, :, src, :].reshape(-1)
    lines = np.broadcast_to(zf.row_lines[:, :, :, src, None], shape).reshape(-1)
    channel = np.broadcast_to(np.arange(n_ch)[:, None, None, None, None], shape).reshape(-1)
    block = np.broadcast_to(np.arange(n_ch * n_rot * n_aoi).reshape(n_ch, n_rot, n_aoi)
                            [..., None, None], shape).reshape(-1)
    rot = np.broadcast_to(zf.rotation[None, :, None, None, None], shape).reshape(-1)
    th_i = np.broadcast_to(theta_i[None, None, :, None, None], shape).reshape(-1)

    # Merge repeated directions of one block (mean value, first line).
    key = np.column_stack([block, np.round(wo, 9) + 0.0])
    _, first, inverse, counts = np.unique(key, axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
    inverse = inverse.reshape(-1)
    ref = value[first][inverse]  # mean as first + mean deviation: exact for equal repeats
    mean = value[first] + np.bincount(inverse, weights=value - ref) / counts
    keep_rows = np.sort(first)
    merged = len(value) - len(keep_rows)
    value = mean[inverse[keep_rows]]
    pick = lambda a: a[keep_rows]  # noqa: E731
    wo, lines, channel, rot, th_i = map(pick, (wo, lines, channel, rot, th_i))

    below = side_cosine(wo, zf.scatter) <= HORIZON_EPS
    zero = (value == 0.0) & ~below
    keep = ~below & (keep_zeros | (value != 0.0))
    if not np.any(keep):
        raise InputFileError(zf.path, "holds no nonzero value above the horizon",
                             hint="every stored value is 0 or on the wrong side of the surface")
    nonzero_below = int(np.sum(below & (value != 0.0)))
    # A stored zero above the horizon is no reading: kept as a gap (Measurement.gaps).
    gap = (zero & ~keep)[~below]
    wo, value, lines, channel, rot, th_i = (a[~below] for a in (wo, value, lines, channel, rot,
                                                                 th_i))
    value = np.where(gap, np.nan, value)
    theta_o, phi_o = direction_to_degrees(wo)
    phi_i = np.mod(rot, 360.0)
    wi = degrees_to_direction(th_i, phi_i)

    rows = tis_rows if tis_rows is not None else tis_check(zf, eta)
    metadata = {
        **zf.metadata,
        "source": zf.source or "not given",
        "symmetry": zf.symmetry,
        "spectral_content": zf.spectral,
        "scatter": zf.scatter.lower(),
        "zemax_pole": _pole_text(zf.scatter, eta, eta_source),
        "masked_below_horizon": int(np.sum(below)),
        "masked_zero": 0 if keep_zeros else int(np.sum(zero)),
        "merged_repeated_directions": merged,
        "tis_check": _tis_summary(rows, zf),
    }
    if nonzero_below:
        metadata["nonzero_below_horizon"] = nonzero_below
    if zf.comments:
        metadata["comment"] = " | ".join(zf.comments)
    return split_gaps(Measurement(
        path=zf.path, sha256=sha256_of(zf.path), theta_i=th_i, phi_i=phi_i, theta_o=theta_o,
        phi_o=phi_o, wi=wi, wo=wo, value=value, sigma=None, channel=channel.astype(int),
        channel_names=zf.channels, wavelength_nm=None, quantity="bsdf", file_quantity="bsdf",
        metadata=metadata, lines=lines,
        tis_blocks=tuple(TisBlock(_block_label(r, zf), r["tis"], r["integral"], r["coverage"])
                         for r in rows),
    ), gap, "no_reading")


def _pole_text(scatter, eta, eta_source):
    if scatter == "BRDF":
        return "specular reflection"
    if eta_source == "assumed":
        return ("directly transmitted ray, undeviated (eta = 1 assumed: read with eta=... or add "
                "'# eta_inside:' and '# eta_outside:' comments for the refracted ray)")
    return f"refracted ray for eta = n_inside/n_outside = {eta:g} ({eta_source})"


def read_zemax(path, eta: float | None = None, keep_zeros: bool = False) -> Measurement:
    """Read a Zemax tabular BSDF file to a Measurement (f in 1/sr; see data_formats/zemax_bsdf.md).

    ``eta`` (n_inside/n_outside) places the light of BTDF data: the file's AngleOfIncidence is
    the refracted ray's angle. Default: '# eta_inside/outside:' comments, else 1 (undeviated)."""
    return to_measurement(parse_zemax(path), eta=eta, keep_zeros=keep_zeros)


def describe_zemax(path, format_name: str = "zemax", accept=()) -> dict:
    zf = parse_zemax(path)
    rows = tis_check(zf)
    m = to_measurement(zf, tis_rows=rows)
    diffs = [abs(r["difference"]) for r in rows if r["difference"] is not None]
    return {
        "symmetry": zf.symmetry,
        "scatter_type": zf.scatter,
        "spectral_content": zf.spectral,
        "sample_rotation_deg": [float(x) for x in zf.rotation],
        "angle_of_incidence_deg": [float(x) for x in zf.aoi],
        "scatter_azimuth_deg": [float(x) for x in zf.azimuth],
        "scatter_radial_deg": [float(x) for x in zf.radial],
        "angles_about": m.metadata["zemax_pole"],
        "stored_values": int(zf.values.size),
        "masked": {"below_horizon_or_in_plane": m.metadata["masked_below_horizon"],
                   "stored_zero": m.metadata["masked_zero"],
                   "repeated_directions_merged": m.metadata["merged_repeated_directions"]},
        "tis_check": {
            "what": "integral of f cos(theta_o) d(omega) over the file's grid (cells about the "
                    "pole, no extrapolation beyond the last radial) vs the stored TIS",
            "largest_difference": f"{max(diffs):.1%}" if diffs else "n/a",
            **{_block_label(r, zf): f"integral {r['integral']:.4g} vs TIS {r['tis']:.4g} "
               + (f"({r['difference']:+.1%})" if r["difference"] is not None else "")
               + f"; the grid spans {r['coverage']:.1%} of the projected hemisphere"
               for r in rows},
        },
        **describe_loaded(m, format_name, accept),
    }


def _detect(head: bytes, path) -> bool:
    text = head.decode("latin-1")
    first = {s.split()[0].lower() for s in (ln.strip() for ln in text.splitlines())
             if s and not s.startswith("#")}
    if first & {"aoi", "poi", "side"}:  # LightTools blocks use the same keywords
        return False
    return len(first & {k.lower() for k in HEADER_KEYWORDS + ("DataBegin",)}) >= 2


FORMAT = Format("zemax", "Zemax / Radiant Imaging tabular BSDF (.bsdf)", _detect, read_zemax,
                describe_zemax, SPEC, suffixes=(".bsdf", ".txt"))


# --------------------------------------------------------------------------------------------
# Serializing (tabulating a model for it: fitlab.export.zemax)
# --------------------------------------------------------------------------------------------


class Grid(NamedTuple):
    """The angles of a file to write, in degrees (AngleOfIncidence as the file means it)."""

    rotation: tuple
    aoi: tuple
    azimuth: tuple
    radial: tuple


#: significant digits of the written values
DIGITS = 5


def _angles_line(values) -> str:
    return "\t".join(f"{v:.10g}" for v in values)


def format_zemax(grid: Grid, channels: tuple, values, tis, scatter: str,
                 comments=(), metadata: dict | None = None, digits: int = DIGITS,
                 tis_digits: int = 4) -> str:
    """IS-BSDF text: header, then per channel an indicator line, DataBegin, blocks, DataEnd
    (``tis_digits``: significant digits of the TIS lines; 10 keeps a file's own as read)."""
    if tuple(channels) == ("Y",):
        spectral, indicators = "Monochrome", ("Monochrome",)
    elif tuple(channels) == ("X", "Y", "Z"):
        spectral, indicators = "XYZ", ("TristimulusX", "TristimulusY", "TristimulusZ")
    else:
        raise FitlabError(f"a Zemax file holds one channel (Monochrome) or X, Y, Z; got "
                          f"{', '.join(channels)} (choose one channel)")
    symmetry = "PlaneSymmetrical" if max(grid.azimuth) <= 180.0 else "Asymmetrical"
    out = [f"#{c}" for c in comments]
    out += [f"# {k}: {v}" for k, v in (metadata or {}).items()]
    out += ["Source  Measured", f"Symmetry  {symmetry}", f"SpectralContent  {spectral}",
            f"ScatterType  {scatter}"]
    for key, vals in (("SampleRotation", grid.rotation), ("AngleOfIncidence", grid.aoi),
                      ("ScatterAzimuth", grid.azimuth), ("ScatterRadial", grid.radial)):
        out += [f"{key}  {len(vals)}", _angles_line(vals)]
    out.append("")
    fmt = f"{{:.{digits - 1}E}}"
    for c, indicator in enumerate(indicators):
        out += [indicator, "DataBegin"]
        for r in range(len(grid.rotation)):
            for k in range(len(grid.aoi)):
                out.append(f"TIS {tis[c, r, k]:.{tis_digits}g}")
                out += ["\t".join(fmt.format(v) for v in row) for row in values[c, r, k]]
        out.append("DataEnd")
    return "\n".join(out) + "\n"


__all__ = ["ZemaxFile", "Grid", "parse_zemax", "read_zemax", "describe_zemax", "tis_check",
           "to_measurement", "format_zemax", "scatter_frame", "scatter_directions",
           "incidence_angle", "side_cosine", "FORMAT"]
