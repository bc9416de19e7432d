"""MERL BRDF database binary files (Matusik et al. 2003): reading, lookup, and the bytes of a
table to write (:func:`merl_bytes`; fitlab.export.merl tabulates registry models and fits).
Spec and decisions: data_formats/merl_binary.md.

Layout (little-endian): ``int32 dims[3] = (90, 90, 180)``, then 3 × 1,458,000 float64, all red
values, then all green, then all blue. Bin ``(i, j, k)`` of θh, θd, φd is at flat index
``k + 180 j + 180·90 i``. Stored values times the channel scale (1/1500, 1.15/1500, 1.66/1500)
are the BRDF f in 1/sr without cosine; negative values mark bins that hold no measurement.

The index maps (MERL's reference reader, restated):

* θh (half vector from the normal): ``i = floor(sqrt(θh_deg · 90))``, clamped to 0..89;
* θd (difference angle): ``j = floor(θd_deg)``, clamped to 0..89;
* φd: ``k = floor(φd_deg)`` after adding 180° to a negative φd (f(φd) = f(φd + 180°) by
  reciprocity), clamped to 0..179.

fitlab tabulates and reports each bin at its centre in index space (the inverse maps):
``θh_deg = (i + ½)² / 90``, ``θd_deg = j + ½``, ``φd_deg = k + ½``, with φh = 0.
"""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.format import Format
from fitlab.io.measurement import Measurement, describe_loaded, split_gaps

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
DIMS = (N_THETA_H, N_THETA_D, N_PHI_D)
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D  # 1,458,000
HEADER_BYTES = 12
FILE_BYTES = HEADER_BYTES + 3 * N_BINS * 8  # 34,992,012
CHANNELS = ("R", "G", "B")
SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: raw value written for a bin that holds no value (below the horizon)
INVALID_RAW = -1.0
#: default subsample for read_merl: every θh bin, every 6th θd bin, every 12th φd bin
DEFAULT_STRIDE = (1, 6, 12)
HEADER = struct.pack("<3i", *DIMS)


class MerlTable(NamedTuple):
    path: str
    sha256: str
    #: (3, 90, 90, 180): f in 1/sr per channel R, G, B; negative where the file marks no value
    brdf: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.brdf >= 0


# --------------------------------------------------------------------------------------------
# Index maps and their inverses (angles in radians)
# --------------------------------------------------------------------------------------------


def theta_half_index(theta_h):
    """The non-linear θh index: floor(sqrt(θh_deg · 90)), clamped to 0..89."""
    deg = np.degrees(np.asarray(theta_h, dtype=np.float64))
    idx = np.floor(np.sqrt(np.maximum(deg, 0.0) * N_THETA_H))
    return np.clip(idx, 0, N_THETA_H - 1).astype(np.int64)


def theta_diff_index(theta_d):
    idx = np.floor(np.degrees(np.asarray(theta_d, dtype=np.float64)))
    return np.clip(idx, 0, N_THETA_D - 1).astype(np.int64)


def phi_diff_index(phi_d):
    """φd folded into [0°, 180°) (reciprocity), one bin per degree."""
    phi = np.asarray(phi_d, dtype=np.float64)
    phi = np.where(phi < 0, phi + np.pi, phi)
    idx = np.floor(np.degrees(phi))
    return np.clip(idx, 0, N_PHI_D - 1).astype(np.int64)


def theta_half_centre(i):
    return np.radians((np.asarray(i, dtype=np.float64) + 0.5) ** 2 / N_THETA_H)


def theta_diff_centre(j):
    return np.radians(np.asarray(j, dtype=np.float64) + 0.5)


def phi_diff_centre(k):
    return np.radians(np.asarray(k, dtype=np.float64) + 0.5)


def flat_index(i, j, k):
    return (np.asarray(i) * N_THETA_D + np.asarray(j)) * N_PHI_D + np.asarray(k)


# --------------------------------------------------------------------------------------------
# Rusinkiewicz half/difference coordinates
# --------------------------------------------------------------------------------------------


def _rot_z(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def _rot_y(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], -1)


def _spherical(theta, phi):
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def half_diff_from_directions(wi, wo):
    """(θh, φh, θd, φd) in radians of unit directions wi, wo (both pointing away from the
    surface): h = normalize(wi + wo); d = wi rotated by −φh about n, then by −θh about y."""
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    # φh is undefined when h is the normal; 0 there (instead of the angle of round-off noise)
    on_axis = np.hypot(h[..., 0], h[..., 1]) < 1e-12
    phi_h = np.where(on_axis, 0.0, np.arctan2(h[..., 1], h[..., 0]))
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, phi_h, theta_d, phi_d


def directions_from_half_diff(theta_h, phi_h, theta_d, phi_d):
    """Inverse of :func:`half_diff_from_directions`: wi = Rz(φh) Ry(θh) d, wo = 2(wi·h)h − wi
    with d the direction (θd, φd) and h the direction (θh, φh)."""
    d = _spherical(np.asarray(theta_d, np.float64), np.asarray(phi_d, np.float64))
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = _spherical(np.asarray(theta_h, np.float64), np.asarray(phi_h, np.float64))
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def bin_directions(i, j, k):
    """(wi, wo) at the centre of bins (i, j, k), with φh = 0."""
    th = theta_half_centre(i)
    return directions_from_half_diff(th, np.zeros_like(th), theta_diff_centre(j),
                                     phi_diff_centre(k))


def lookup_indices(wi, wo):
    """MERL bin (i, j, k) of each direction pair (φh is ignored: isotropic)."""
    theta_h, _, theta_d, phi_d = half_diff_from_directions(wi, wo)
    return theta_half_index(theta_h), theta_diff_index(theta_d), phi_diff_index(phi_d)


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _check_size_and_header(path: Path, size: int, head: bytes):
    if size < HEADER_BYTES:
        raise InputFileError(path, f"is {size} bytes long, shorter than the 12-byte MERL header",
                             hint="the file is truncated; a MERL .binary file is 34,992,012 bytes")
    dims = struct.unpack("<3i", head[:HEADER_BYTES])
    if dims != DIMS:
        big = struct.unpack(">3i", head[:HEADER_BYTES])
        hint = ("the header reads (90, 90, 180) as big-endian: fitlab reads the little-endian "
                "files MERL distributes" if big == DIMS else
                "a MERL BRDF file starts with the int32 dimensions 90, 90, 180 (θh, θd, φd)")
        raise InputFileError(path, f"header dimensions {dims} (bytes 0-11) are not "
                             f"{DIMS}", hint=hint)
    if size != FILE_BYTES:
        data = size - HEADER_BYTES
        if size < FILE_BYTES:
            full = data // (N_BINS * 8)
            what = (f"truncated: {size} bytes, {FILE_BYTES - size} fewer than the {FILE_BYTES} "
                    f"of a full table (the {CHANNELS[min(full, 2)]} channel is incomplete)")
        else:
            what = (f"{size} bytes, {size - FILE_BYTES} more than the {FILE_BYTES} of a "
                    "90×90×180 RGB table of float64")
        raise InputFileError(path, f"size mismatch: {what}",
                             hint="the file must hold the 12-byte header and 3 × 1,458,000 "
                             "float64 values; re-copy it")


def read_merl_table(path) -> MerlTable:
    """Read and validate a MERL .binary file into f (1/sr) per channel; the file is not modified."""
    path = Path(path)
    raw_bytes = read_bytes(path)
    _check_size_and_header(path, len(raw_bytes), raw_bytes)
    raw = np.frombuffer(raw_bytes, dtype="<f8", offset=HEADER_BYTES).reshape(3, *DIMS)
    bad = ~np.isfinite(raw)
    if bad.any():
        c, i, j, k = (int(x[0]) for x in np.nonzero(bad))
        offset = HEADER_BYTES + 8 * (c * N_BINS + int(flat_index(i, j, k)))
        raise InputFileError(path, f"channel {CHANNELS[c]}, bin θh={i} θd={j} φd={k} (byte "
                             f"{offset}) holds {float(raw[c, i, j, k])}; {int(bad.sum())} "
                             "value(s) in the file are not finite", hint="a MERL table holds finite numbers only "
                             "(negative marks a bin without value); re-copy the file")
    if not np.any(raw >= 0):
        raise InputFileError(path, "every bin is marked invalid (negative): the table holds no "
                             "BRDF value", hint="re-copy the file or give another material")
    brdf = raw * np.asarray(SCALES).reshape(3, 1, 1, 1)
    return MerlTable(str(path), sha256_of(raw_bytes), brdf)


def eval_merl(table: MerlTable, wi, wo) -> np.ndarray:
    """f (1/sr) per channel, shape (..., 3), by MERL's nearest-bin lookup at arbitrary (wi, wo).

    0 where wi or wo is below the horizon (MERL tables are one-sided BRDFs); NaN where the bin
    holds no value (negative in the file)."""
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    i, j, k = lookup_indices(wi, wo)
    f = np.moveaxis(table.brdf[:, i, j, k], 0, -1)
    above = ((wi[..., 2] > 0) & (wo[..., 2] > 0))[..., None]
    return np.where(above, np.where(f >= 0, f, np.nan), 0.0)


def _parse_stride(stride):
    if isinstance(stride, str):
        stride = stride.strip().lower()
        stride = 1 if stride == "all" else tuple(int(s) for s in stride.split(","))
    if isinstance(stride, (int, np.integer)):
        stride = (int(stride),) * 3
    stride = tuple(int(s) for s in stride)
    if len(stride) != 3 or any(s < 1 for s in stride):
        raise FitlabError(f"MERL stride {stride!r} must be one positive integer or three "
                          "(θh, θd, φd), e.g. 1,6,12, or 'all'")
    return stride


def subsample_indices(stride=DEFAULT_STRIDE):
    """The bins read_merl keeps: in each axis every s-th bin starting at s // 2 (the middle of
    the first block of s bins), so stride 1 keeps every bin."""
    st = _parse_stride(stride)
    axes = [np.arange(s // 2, n, s) for s, n in zip(st, DIMS)]
    i, j, k = np.meshgrid(*axes, indexing="ij")
    return i.ravel(), j.ravel(), k.ravel()


def _direction_degrees(w):
    theta = np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))
    phi = np.mod(np.degrees(np.arctan2(w[:, 1], w[:, 0])), 360.0)
    return theta, phi


def measurement_from_table(table: MerlTable, stride=DEFAULT_STRIDE) -> Measurement:
    """Rows at the centres of the subsampled bins, one per channel; bins without value (above
    the horizon) are the Measurement's gaps (no reading)."""
    i, j, k = subsample_indices(stride)
    wi, wo = bin_directions(i, j, k)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    values = table.brdf[:, i, j, k]  # (3, n)
    placed = np.broadcast_to(above[None, :], values.shape)
    chan, rows = np.nonzero(placed)  # channel-major order
    gap = values[chan, rows] < 0
    ti, pi = _direction_degrees(wi[rows])
    to, po = _direction_degrees(wo[rows])
    st = _parse_stride(stride)
    meta = {"source_format": "MERL BRDF binary", "stride": ",".join(map(str, st)),
            "channel_scales": "R 1/1500, G 1.15/1500, B 1.66/1500",
            "bins_read": str(len(i)), "sample": Path(table.path).stem}
    return split_gaps(Measurement(
        path=table.path, sha256=table.sha256, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po,
        wi=wi[rows], wo=wo[rows], value=np.where(gap, np.nan, values[chan, rows]), sigma=None,
        channel=chan, channel_names=CHANNELS, wavelength_nm=None, quantity="bsdf",
        file_quantity="bsdf", metadata=meta, lines=flat_index(i, j, k)[rows],
    ), gap, "no_reading")


def read_merl(path, stride=DEFAULT_STRIDE) -> Measurement:
    """A MERL file as a Measurement on a subsample of bin centres (``stride=1`` or ``"all"``:
    every bin, about 1.2 million valid rows per channel)."""
    return measurement_from_table(read_merl_table(path), stride)


# --------------------------------------------------------------------------------------------
# Serializing (tabulating a model for it: fitlab.export.merl)
# --------------------------------------------------------------------------------------------


def merl_bytes(raw: np.ndarray) -> bytes:
    raw = np.asarray(raw, dtype=np.float64)
    if raw.shape != (3, *DIMS):
        raise ValueError(f"a MERL table has shape (3, 90, 90, 180), got {raw.shape}")
    buf = io.BytesIO()
    buf.write(HEADER)
    buf.write(raw.astype("<f8").tobytes())
    return buf.getvalue()


# --------------------------------------------------------------------------------------------
# Registry entry
# --------------------------------------------------------------------------------------------


def _detect(head: bytes, path) -> bool:
    return head[:HEADER_BYTES] == HEADER


def describe_merl(path, format_name: str = "merl", accept=()) -> dict:
    table = read_merl_table(path)
    m = measurement_from_table(table)
    valid = table.valid
    n_wi, n_wo = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]])
    normal = eval_merl(table, n_wi, n_wo)[0]
    info = describe_loaded(m, format_name, accept)
    info.update({
        "file_bytes": os.path.getsize(path),
        "dims_theta_h_theta_d_phi_d": list(DIMS),
        "bins_per_channel": N_BINS,
        "bins_without_value": {c: int((~valid[n]).sum()) for n, c in enumerate(CHANNELS)},
        "f_range_per_channel": {c: [float(table.brdf[n][valid[n]].min()),
                                    float(table.brdf[n][valid[n]].max())]
                                for n, c in enumerate(CHANNELS) if valid[n].any()},
        "f_normal_incidence_and_view": {c: float(normal[n]) for n, c in enumerate(CHANNELS)},
        "read_default": f"stride {DEFAULT_STRIDE} over (θh, θd, φd) bins, bin centres, φh = 0",
    })
    return info


FORMAT = Format("merl", "MERL BRDF database binary (90×90×180 RGB half/difference table)",
                _detect, read_merl, describe_merl, "data_formats/merl_binary.md",
                suffixes=(".binary",), binary=True, whole={"stride": 1})
