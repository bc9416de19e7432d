"""RGL-EPFL material database files (``.bsdf``, the "tensor_file" container): parsing with
validation, evaluation of the stored BRDF, the reader to a Measurement and the registry entry.
Spec, equations and decisions: data_formats/rgl_bsdf.md.

The evaluation is a NumPy port (vectorized, float64) of ``powitacq_rgb.inl`` / ``powitacq.inl``
(``BRDF::eval``, ``Marginal2D::invert``/``eval``, ``find_interval``, ``theta2u``/``phi2u``) from
github.com/rgl-epfl/brdf-loader, the reference reader of Dupuy & Jakob, "An Adaptive
Parameterization for Efficient Material Acquisition and Rendering", ACM TOG 37(6), 2018.
Its licence requires this notice:

    Copyright 2018 Jonathan Dupuy and Wenzel Jakob

    Redistribution and use in source and binary forms, with or without modification, are
    permitted provided that the following conditions are met:

    1. Redistributions of source code must retain the above copyright notice, this list of
       conditions and the following disclaimer.
    2. Redistributions in binary form must reproduce the above copyright notice, this list of
       conditions and the following disclaimer in the documentation and/or other materials
       provided with the distribution.
    3. Neither the name of the copyright holder nor the names of its contributors may be used
       to endorse or promote products derived from this software without specific prior
       written permission.

    THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND ANY EXPRESS
    OR IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED WARRANTIES OF
    MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE DISCLAIMED. IN NO EVENT SHALL THE
    COPYRIGHT HOLDER OR CONTRIBUTORS BE LIABLE FOR ANY DIRECT, INDIRECT, INCIDENTAL, SPECIAL,
    EXEMPLARY, OR CONSEQUENTIAL DAMAGES (INCLUDING, BUT NOT LIMITED TO, PROCUREMENT OF
    SUBSTITUTE GOODS OR SERVICES; LOSS OF USE, DATA, OR PROFITS; OR BUSINESS INTERRUPTION)
    HOWEVER CAUSED AND ON ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT LIABILITY, OR
    TORT (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF THIS
    SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.

Where fitlab departs from powitacq (each is stated in the spec): the tabulated value
ρ·D(ωm)/(4σ(ωi)) is f·cos θo, and fitlab divides by cos θo to get f; spectral values are
clipped at 0 like RGB ones; the ndf/σ factor is applied only when the file's ``jacobian`` flag is
set (as Mitsuba does; powitacq always applies it, and every published file sets it); where the
VNDF has no mass along a row (θi = 90° only) the value is 0 instead of a division by zero.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab import colorimetry
from fitlab.errors import InputFileError
from fitlab.io.files import read_bytes, sha256_of
from fitlab.io.format import Format
from fitlab.io.validate import quote
from fitlab.io.measurement import Measurement, describe_loaded

# --------------------------------------------------------------------------------------------
# The tensor_file container
# --------------------------------------------------------------------------------------------

MAGIC = b"tensor_file\x00"
VERSION = (1, 0)
#: magic (12) + version (2) + field count (4)
HEADER_BYTES = 18
#: powitacq's Tensor::Type codes
DTYPES = {1: np.dtype("<u1"), 2: np.dtype("<i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"),
          5: np.dtype("<u4"), 6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"),
          9: np.dtype("<f2"), 10: np.dtype("<f4"), 11: np.dtype("<f8")}
DTYPE_CODES = {dt: code for code, dt in DTYPES.items()}


class TensorField(NamedTuple):
    name: str
    dtype: np.dtype
    offset: int  # byte offset of the data in the file
    shape: tuple[int, ...]
    data: np.ndarray  # read-only view of the file's bytes
    header_offset: int  # byte offset of this field's entry in the header


class TensorFile(NamedTuple):
    path: str
    version: tuple[int, int]
    fields: dict[str, TensorField]
    size: int  # file size in bytes
    header_end: int  # first byte after the field table
    sha256: str


def _fail(path, message, field=None, byte=None, hint=None):
    where = (f"field {field!r}" if field else "") + \
        (f"{', ' if field else ''}byte {byte}" if byte is not None else "")
    raise InputFileError(path, f"{where}: {message}" if where else message, hint=hint)


_DAMAGED = "the file is truncated or damaged; download it again from the RGL material database"


def parse_tensor_file(buf: bytes, path="<bytes>") -> TensorFile:
    """Parse and validate the container: signature, version, field table, data extents."""
    size = len(buf)
    if size < HEADER_BYTES:
        _fail(path, f"is {size} bytes long, too short for a tensor file (its header alone has "
              f"{HEADER_BYTES} bytes)", hint=_DAMAGED)
    if buf[:12] != MAGIC:
        _fail(path, f"does not start with the tensor_file signature (found {bytes(buf[:12])!r})",
              byte=0, hint="an RGL material file (.bsdf) starts with 'tensor_file' and a zero "
              "byte; this file is something else, or damaged")
    version = (buf[12], buf[13])
    if version != VERSION:
        _fail(path, f"tensor_file version {version[0]}.{version[1]} is not supported "
              f"(fitlab reads version {VERSION[0]}.{VERSION[1]}, as powitacq and Mitsuba do)",
              byte=12, hint="convert the file with the tool that wrote it, or report it")
    (n_fields,) = struct.unpack_from("<I", buf, 14)
    pos = HEADER_BYTES
    entries = []

    def take(fmt, what, k, name):
        nonlocal pos
        need = struct.calcsize(fmt)
        if pos + need > size:
            _fail(path, f"the header ends inside the {what} of field #{k + 1}"
                  + (f" ({quote(name)})" if name else "") + f" (the file has {size} bytes, "
                  f"the header says {n_fields} fields)", byte=pos, hint=_DAMAGED)
        out = struct.unpack_from(fmt, buf, pos)
        pos += need
        return out

    for k in range(n_fields):
        start = pos
        (name_len,) = take("<H", "name length", k, None)
        (raw_name,) = take(f"<{name_len}s", "name", k, None)
        try:
            name = raw_name.decode("utf-8")
        except UnicodeDecodeError:
            _fail(path, f"the name of field #{k + 1} is not text ({quote(raw_name)})", byte=start,
                  hint=_DAMAGED)
        ndim, code, offset = take("<HBQ", "rank, type and offset", k, name)
        shape = take(f"<{ndim}Q", "shape", k, name)
        entries.append((name, code, offset, tuple(int(s) for s in shape), start))
    header_end = pos

    fields = {}
    for name, code, offset, shape, start in entries:
        if name in fields:
            _fail(path, "appears twice in the field table", field=name, byte=start, hint=_DAMAGED)
        if code not in DTYPES:
            _fail(path, f"has the unknown data type code {code} (known: 1-11, uint8 to float64)",
                  field=name, byte=start, hint=_DAMAGED)
        dtype = DTYPES[code]
        count = math.prod(shape)  # exact: a lying header may declare 2^64-sized dimensions
        end = offset + count * dtype.itemsize
        if offset < header_end:
            _fail(path, f"its data would start at byte {offset}, inside the field table (which "
                  f"ends at byte {header_end})", field=name, byte=start, hint=_DAMAGED)
        if end > size:
            _fail(path, f"its data (shape {shape}, {dtype.name}) would occupy bytes "
                  f"{offset}-{end - 1}, beyond the end of the file ({size} bytes)",
                  field=name, byte=offset, hint=_DAMAGED)
        data = np.frombuffer(buf, dtype=dtype, count=count, offset=offset).reshape(shape)
        fields[name] = TensorField(name, dtype, offset, shape, data, start)
    return TensorFile(str(path), version, fields, size, header_end,
                      sha256_of(buf))


def read_tensor_file(path) -> TensorFile:
    path = Path(path)
    return parse_tensor_file(read_bytes(path), path)


def format_tensor_file(fields: dict) -> bytes:
    """A tensor_file 1.0 holding ``fields`` (name → array; the array's dtype is kept, in
    little-endian order), data laid out after the field table in the order given."""
    arrays = {name: np.ascontiguousarray(a, dtype=np.asarray(a).dtype.newbyteorder("<"))
              for name, a in fields.items()}
    table_size = HEADER_BYTES + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim
                                    for n, a in arrays.items())
    head, body, offset = [MAGIC, bytes(VERSION), struct.pack("<I", len(arrays))], [], table_size
    for name, a in arrays.items():
        key = name.encode()
        code = DTYPE_CODES[a.dtype]
        head.append(struct.pack(f"<H{len(key)}sHBQ{a.ndim}Q", len(key), key, a.ndim, code,
                                offset, *a.shape))
        body.append(a.tobytes())
        offset += a.nbytes
    return b"".join(head + body)


def write_tensor_file(path, fields: dict) -> None:
    """Write ``fields`` as a tensor_file (atomically); see :func:`format_tensor_file`."""
    from fitlab.io.atomic import atomic_open

    data = format_tensor_file(fields)
    with atomic_open(path, "wb") as fh:
        fh.write(data)


# --------------------------------------------------------------------------------------------
# Marginal2D (powitacq): parameter interpolation, CDFs, invert and eval
# --------------------------------------------------------------------------------------------


class Warp2D(NamedTuple):
    """powitacq's Marginal2D: a (*params, ny, nx[, channels]) table linearly interpolated in its
    parameters and bilinearly on the unit square; with CDFs when it is a sampling warp."""
    data: np.ndarray
    param_values: tuple[np.ndarray, ...]
    marginal_cdf: np.ndarray | None = None  # (*params, ny)
    conditional_cdf: np.ndarray | None = None  # (*params, ny, nx)


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def sampling_warp(data, param_values) -> Warp2D:
    """Marginal2D(normalize=true, build_cdf=true): per slice, conditional CDFs along x and the
    marginal CDF along y by the trapezoid rule, all divided by the slice's total."""
    data = np.asarray(data, dtype=np.float64)
    cond = np.zeros_like(data)
    cond[..., 1:] = np.cumsum(0.5 * (data[..., :-1] + data[..., 1:]), axis=-1)
    rows = cond[..., -1]
    marg = np.zeros_like(rows)
    marg[..., 1:] = np.cumsum(0.5 * (rows[..., :-1] + rows[..., 1:]), axis=-1)
    norm = 1.0 / marg[..., -1]
    return Warp2D(_frozen(data * norm[..., None, None]), tuple(param_values),
                  _frozen(marg * norm[..., None]), _frozen(cond * norm[..., None, None]))


def _interval(values: np.ndarray, x: np.ndarray):
    """powitacq ``find_interval`` and the clamped linear weight along one parameter axis:
    [(index, weight)]; an axis with one value (isotropic φi) has the single node, weight 1."""
    n = len(values)
    if n == 1:
        return [(np.zeros(x.shape, dtype=np.intp), 1.0)]
    i0 = np.clip(np.searchsorted(values, x, side="right") - 1, 0, n - 2)
    w1 = np.clip((x - values[i0]) / (values[i0 + 1] - values[i0]), 0.0, 1.0)
    return [(i0, 1.0 - w1), (i0 + 1, w1)]


def _corners(param_values, params):
    """Multilinear interpolation corners over the parameter axes: [(index tuple, weight)]."""
    corners = [((), 1.0)]
    for values, x in zip(param_values, params):
        corners = [(idx + (i,), w * wi) for idx, w in corners for i, wi in _interval(values, x)]
    return corners


def _lookup(table, corners, *index):
    """powitacq ``lookup``: Σ over corners of weight × table[corner, index]; trailing axes
    (channels) are kept."""
    total = 0.0
    for idx, w in corners:
        v = table[idx + index]
        total = total + np.reshape(w, np.shape(w) + (1,) * (v.ndim - np.ndim(w))) * v
    return total


def _cell(u, n):
    """Bilinear cell index and fraction of unit coordinates ``u`` on a grid of ``n`` nodes."""
    s = np.clip(u, 0.0, 1.0) * (n - 1)
    i = np.minimum(s.astype(np.intp), n - 2)
    return i, s - i


def warp_eval(warp: Warp2D, corners, u) -> np.ndarray:
    """Marginal2D::eval on a table built with normalize=false: the interpolated stored values."""
    ny, nx = warp.data.shape[len(warp.param_values):len(warp.param_values) + 2]
    ix, fx = _cell(u[..., 0], nx)
    iy, fy = _cell(u[..., 1], ny)
    t = warp.data
    v00, v10 = _lookup(t, corners, iy, ix), _lookup(t, corners, iy, ix + 1)
    v01, v11 = _lookup(t, corners, iy + 1, ix), _lookup(t, corners, iy + 1, ix + 1)
    e = (v00.ndim - fx.ndim)
    fx, fy = fx.reshape(fx.shape + (1,) * e), fy.reshape(fy.shape + (1,) * e)
    return (1 - fy) * ((1 - fx) * v00 + fx * v10) + fy * ((1 - fx) * v01 + fx * v11)


def warp_invert(warp: Warp2D, corners, u):
    """Marginal2D::invert: the unit-square sample that the warp maps to ``u`` (…, 2), and
    whether it exists (False where the interpolated row has no mass)."""
    ny, nx = warp.data.shape[-2:]
    ix, fx = _cell(u[..., 0], nx)
    iy, fy = _cell(u[..., 1], ny)
    d, cond, marg = warp.data, warp.conditional_cdf, warp.marginal_cdf
    v00, v10 = _lookup(d, corners, iy, ix), _lookup(d, corners, iy, ix + 1)
    v01, v11 = _lookup(d, corners, iy + 1, ix), _lookup(d, corners, iy + 1, ix + 1)
    c0 = (1 - fy) * v00 + fy * v01
    c1 = (1 - fy) * v10 + fy * v11
    sx = fx * (c0 + 0.5 * fx * (c1 - c0))
    sx = sx + (1 - fy) * _lookup(cond, corners, iy, ix) + fy * _lookup(cond, corners, iy + 1, ix)
    r0 = _lookup(cond, corners, iy, np.full_like(ix, nx - 1))
    r1 = _lookup(cond, corners, iy + 1, np.full_like(ix, nx - 1))
    row = (1 - fy) * r0 + fy * r1
    ok = row > 0
    sx = np.where(ok, sx / np.where(ok, row, 1.0), 0.0)
    sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + _lookup(marg, corners, iy)
    return np.stack([sx, sy], axis=-1), ok


# --------------------------------------------------------------------------------------------
# The material (powitacq BRDF::Data) and its evaluation
# --------------------------------------------------------------------------------------------

FLOAT_FIELDS = ("theta_i", "phi_i", "sigma", "ndf", "vndf", "luminance", "rgb", "wavelengths",
                "spectra")
REQUIRED = ("description", "theta_i", "phi_i", "sigma", "ndf", "vndf", "luminance", "jacobian")


class RGLMaterial(NamedTuple):
    path: str
    description: str
    kind: str  # "rgb" or "spectral"
    theta_i: np.ndarray  # radians, as stored
    phi_i: np.ndarray
    channel_names: tuple[str, ...]  # R, G, B or "<λ>nm"
    wavelength_nm: np.ndarray | None
    isotropic: bool
    jacobian: bool
    ndf: Warp2D  # (2, 128): (φ, θ) of the microfacet normal
    sigma: Warp2D  # projected area σ(ωi)
    vndf: Warp2D  # (φi, θi) → sampling warp of the visible normals
    spectra: Warp2D  # (φi, θi) → (32, 32, channels)
    luminance: Warp2D  # (φi, θi) → (32, 32), the file's luminance as stored (not normalized)
    tensor: TensorFile


def theta2u(theta):
    return np.sqrt(theta * (2.0 / np.pi))


def phi2u(phi):
    return (phi + np.pi) / (2.0 * np.pi)


def _field(tf: TensorFile, name: str) -> TensorField:
    if name not in tf.fields:
        _fail(tf.path, f"has no field {name!r}",
              hint="an RGL material file holds " + ", ".join(REQUIRED) +
              " and either rgb or wavelengths + spectra; this tensor file is not one, or it is "
              "incomplete")
    return tf.fields[name]


def _check_structure(tf: TensorFile) -> str:
    """powitacq's structure checks, one message per rule; returns "rgb" or "spectral"."""
    path = tf.path
    for name in REQUIRED:
        _field(tf, name)
    if "rgb" not in tf.fields and "spectra" not in tf.fields and "wavelengths" not in tf.fields:
        _field(tf, "rgb")
    kind = "rgb" if "rgb" in tf.fields else "spectral"
    if kind == "spectral":
        _field(tf, "spectra"), _field(tf, "wavelengths")
    f = tf.fields
    ranks = {"description": 1, "theta_i": 1, "phi_i": 1, "ndf": 2, "sigma": 2, "vndf": 4,
             "luminance": 4, "jacobian": 1, "rgb": 5, "wavelengths": 1, "spectra": 5}
    for name, rank in ranks.items():
        if name in f and len(f[name].shape) != rank:
            _fail(path, f"has shape {f[name].shape} but must have {rank} dimension(s)",
                  field=name, byte=f[name].header_offset, hint=_DAMAGED)
    for name in FLOAT_FIELDS:
        if name in f and f[name].dtype != np.dtype("<f4"):
            _fail(path, f"is stored as {f[name].dtype.name}, but RGL files store it as float32",
                  field=name, byte=f[name].header_offset, hint=_DAMAGED)
    for name in ("description", "jacobian"):
        if f[name].dtype != np.dtype("u1"):
            _fail(path, f"is stored as {f[name].dtype.name}, but must be uint8", field=name,
                  byte=f[name].header_offset, hint=_DAMAGED)
    for name in ("description", "theta_i", "phi_i", "wavelengths"):
        if name in f and f[name].shape[0] == 0:
            _fail(path, "holds no values", field=name, byte=f[name].header_offset, hint=_DAMAGED)
    if f["jacobian"].shape != (1,):
        _fail(path, f"has shape {f['jacobian'].shape}, but must hold one flag", field="jacobian",
              byte=f["jacobian"].header_offset, hint=_DAMAGED)
    n_phi, n_theta = f["phi_i"].shape[0], f["theta_i"].shape[0]
    colour = "rgb" if kind == "rgb" else "spectra"
    n_ch = 3 if kind == "rgb" else f["wavelengths"].shape[0]
    expect = [("vndf", 0, n_phi, "phi_i"), ("vndf", 1, n_theta, "theta_i"),
              ("luminance", 0, n_phi, "phi_i"), ("luminance", 1, n_theta, "theta_i"),
              (colour, 0, n_phi, "phi_i"), (colour, 1, n_theta, "theta_i"),
              (colour, 2, n_ch, "the channel count (3)" if kind == "rgb" else "wavelengths"),
              (colour, 3, f["luminance"].shape[2], "luminance"),
              (colour, 4, f["luminance"].shape[3], "luminance")]
    axis_names = ("first", "second", "third", "fourth", "fifth")
    for name, axis, n, other in expect:
        if f[name].shape[axis] != n:
            _fail(path, f"has shape {f[name].shape}: its {axis_names[axis]} dimension must be "
                  f"{n}, to match {other}", field=name, byte=f[name].header_offset,
                  hint="the fields disagree; " + _DAMAGED)
    if f["luminance"].shape[2] != f["luminance"].shape[3]:
        _fail(path, f"has shape {f['luminance'].shape}; its last two dimensions must be equal",
              field="luminance", byte=f["luminance"].header_offset, hint=_DAMAGED)
    for name in ("ndf", "sigma", "vndf", "luminance", colour):
        if min(f[name].shape[-2:]) < 2:
            _fail(path, f"has shape {f[name].shape}; interpolation needs at least 2 × 2 values",
                  field=name, byte=f[name].header_offset, hint=_DAMAGED)
    return kind


def _check_values(tf: TensorFile, kind: str) -> None:
    path, f = tf.path, tf.fields
    for name in FLOAT_FIELDS:
        if name not in f:
            continue
        bad = np.argwhere(~np.isfinite(f[name].data))
        if bad.size:
            idx = tuple(int(i) for i in bad[0])
            flat = int(np.ravel_multi_index(idx, f[name].shape)) if idx else 0
            byte = f[name].offset + f[name].dtype.itemsize * flat
            _fail(path, f"holds {f[name].data[idx]} at index {idx} ({len(bad)} non-finite "
                  "values in all)", field=name, byte=byte, hint=_DAMAGED)
    theta, phi = f["theta_i"].data, f["phi_i"].data
    if np.any(np.diff(theta) <= 0) or theta[0] < 0 or theta[-1] > np.pi / 2 + 1e-5:
        _fail(path, f"must increase strictly within [0, π/2] radians; it holds {theta.tolist()}",
              field="theta_i", byte=f["theta_i"].offset, hint=_DAMAGED)
    if np.any(np.diff(phi) <= 0) or np.any(np.abs(phi) > np.pi + 1e-5):
        _fail(path, f"must increase strictly within [-π, π] radians; it holds {phi.tolist()}",
              field="phi_i", byte=f["phi_i"].offset, hint=_DAMAGED)
    if len(phi) > 2:
        reduction = int(np.rint(2 * np.pi / (phi[-1] - phi[0])))
        if reduction != 1:
            _fail(path, f"covers 1/{reduction} of the circle (a symmetry reduction); fitlab, "
                  "like powitacq, reads only files whose φi covers the whole circle",
                  field="phi_i", byte=f["phi_i"].offset,
                  hint="render it with Mitsuba's 'measured' plugin, which supports reductions")
    if kind == "spectral":
        wl = f["wavelengths"].data
        if np.any(np.diff(wl) <= 0) or wl[0] <= 0:
            _fail(path, "must be positive and increase strictly (nm)", field="wavelengths",
                  byte=f["wavelengths"].offset, hint=_DAMAGED)
    if np.any(f["sigma"].data <= 0):
        _fail(path, "must be positive (it is the projected area σ(ωi) that divides the BRDF)",
              field="sigma", byte=f["sigma"].offset, hint=_DAMAGED)
    for name in ("ndf", "vndf"):
        if np.any(f[name].data < 0):
            _fail(path, "holds negative values; a distribution of normals cannot",
                  field=name, byte=f[name].offset, hint=_DAMAGED)
    mass = f["vndf"].data.astype(np.float64).sum(axis=(-2, -1))
    empty = np.argwhere(mass <= 0)
    if empty.size:
        _fail(path, f"the slice for (φi index {empty[0][0]}, θi index {empty[0][1]}) is all "
              "zero, so it cannot be inverted", field="vndf", byte=f["vndf"].offset,
              hint=_DAMAGED)


def material_from_tensor(tf: TensorFile) -> RGLMaterial:
    """Validate the fields (powitacq's checks and value checks) and build the interpolants."""
    kind = _check_structure(tf)
    _check_values(tf, kind)
    f = tf.fields
    theta_i, phi_i = _frozen(f["theta_i"].data), _frozen(f["phi_i"].data)
    params = (phi_i, theta_i)
    if kind == "rgb":
        names, wl, colour = ("R", "G", "B"), None, f["rgb"].data
    else:
        wl = _frozen(f["wavelengths"].data)
        names, colour = tuple(f"{w:g}nm" for w in wl), f["spectra"].data
    desc = bytes(f["description"].data).split(b"\x00", 1)[0].decode("utf-8", errors="replace")
    return RGLMaterial(
        path=tf.path, description=desc.strip(), kind=kind, theta_i=theta_i, phi_i=phi_i,
        channel_names=names, wavelength_nm=wl, isotropic=len(phi_i) <= 2,
        jacobian=bool(f["jacobian"].data[0]),
        ndf=Warp2D(_frozen(f["ndf"].data), ()), sigma=Warp2D(_frozen(f["sigma"].data), ()),
        vndf=sampling_warp(f["vndf"].data, params),
        spectra=Warp2D(_frozen(np.moveaxis(colour, 2, -1)), params),
        luminance=Warp2D(_frozen(f["luminance"].data), params), tensor=tf)


def read_material(path) -> RGLMaterial:
    return material_from_tensor(read_tensor_file(path))


def _elevation(w):
    """θ of unit vectors, stably near the pole (Mitsuba's ``elevation``): 2 asin(|w − z|/2)."""
    d = np.sqrt(w[..., 0] ** 2 + w[..., 1] ** 2 + (w[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * d, 0.0, 1.0))


class Tabulated(NamedTuple):
    """What powitacq's BRDF::eval computes, before clipping, for each direction pair."""
    value: np.ndarray  # (N, C): interpolated rgb/spectra × ndf/(4σ) = f·cos θo
    luminance: np.ndarray  # (N,): the file's luminance field through the same path
    active: np.ndarray  # (N,) bool: both directions above the horizon and the VNDF invertible


def tabulate(material: RGLMaterial, wi, wo) -> Tabulated:
    """powitacq ``BRDF::eval`` at unit directions ``wi``, ``wo`` (N, 3), all channels, unclipped."""
    wi = np.atleast_2d(np.asarray(wi, dtype=np.float64))
    wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
    wi, wo = np.broadcast_arrays(wi, wo)
    active = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    h = wi + wo
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    wm = h / np.where(norm > 0, norm, 1.0)
    theta_i, phi_i = _elevation(wi), np.arctan2(wi[..., 1], wi[..., 0])
    theta_m, phi_m = _elevation(wm), np.arctan2(wm[..., 1], wm[..., 0])
    u_wi = np.stack([theta2u(theta_i), phi2u(phi_i)], axis=-1)
    u_m_phi = phi2u(phi_m - phi_i if material.isotropic else phi_m)
    u_wm = np.stack([theta2u(theta_m), u_m_phi - np.floor(u_m_phi)], axis=-1)
    corners = _corners((material.phi_i, material.theta_i), (phi_i, theta_i))
    sample, invertible = warp_invert(material.vndf, corners, u_wm)
    value = warp_eval(material.spectra, corners, sample)
    lum = warp_eval(material.luminance, corners, sample)
    if material.jacobian:
        factor = warp_eval(material.ndf, [((), 1.0)], u_wm) / \
            (4.0 * warp_eval(material.sigma, [((), 1.0)], u_wi))
        value, lum = value * factor[..., None], lum * factor
    active = active & invertible
    return Tabulated(np.where(active[..., None], value, 0.0), np.where(active, lum, 0.0), active)


CHANNEL_CHOICES = ("native", "rgb", "y", "spectral")


def eval_bsdf(material: RGLMaterial, wi, wo, channels: str = "native",
              illuminant: str = colorimetry.DEFAULT_ILLUMINANT):
    """The BSDF f in 1/sr (no cosine) at direction pairs, (N, C), and the channel names.

    ``channels``: "native" (the file's: R, G, B or its wavelengths), "rgb" (linear sRGB; from
    spectra via :mod:`fitlab.colorimetry` under ``illuminant``), "y" (luminance; the Rec. 709
    luminance of the unclipped RGB, or CIE Y of the spectra), "spectral" (spectral files only).
    Values are clipped at 0 (powitacq clips out-of-gamut RGB) and are 0 unless both directions
    are above the surface."""
    if channels not in CHANNEL_CHOICES:
        raise ValueError(f"channels must be one of {', '.join(CHANNEL_CHOICES)}, not {channels!r}")
    if channels == "spectral" and material.kind != "spectral":
        raise ValueError(f"{material.path} is an RGB file; it has no spectral channels")
    t = tabulate(material, wi, wo)
    wo = np.broadcast_to(np.atleast_2d(np.asarray(wo, dtype=np.float64)), t.value.shape[:-1] + (3,))
    cos_o = np.where(t.active, wo[..., 2], 1.0)
    spectral = material.kind == "spectral"
    if channels in ("native", "spectral") or (channels == "rgb" and not spectral):
        out, names = t.value, material.channel_names
    elif channels == "rgb":
        out = colorimetry.spectral_to_linear_srgb(t.value, material.wavelength_nm, illuminant)
        names = ("R", "G", "B")
    elif spectral:
        out = colorimetry.xyz_to_y(
            colorimetry.spectral_to_xyz(t.value, material.wavelength_nm, illuminant))[..., None]
        names = ("Y",)
    else:
        out, names = colorimetry.rgb_to_luminance(t.value)[..., None], ("Y",)
    return np.maximum(out, 0.0) / cos_o[..., None], names


# --------------------------------------------------------------------------------------------
# Reader to a Measurement
# --------------------------------------------------------------------------------------------

#: default outgoing grid (degrees): θo = 0, 5, ..., 85; φo = 0, 10, ..., 350 (θo = 0 once)
DEFAULT_THETA_O = tuple(float(t) for t in range(0, 90, 5))
DEFAULT_PHI_O = tuple(float(p) for p in range(0, 360, 10))
#: stored θi at or above this (degrees) are left out of the default grid (the 90° slice)
GRAZING_LIMIT_DEG = 89.5


def default_theta_i(material: RGLMaterial) -> np.ndarray:
    """The file's own θi values in degrees, without the grazing 90° slice."""
    deg = np.degrees(material.theta_i.astype(np.float64))
    return deg[deg < GRAZING_LIMIT_DEG]


def direction_grid(material: RGLMaterial, theta_i=None, phi_i=None, theta_o=None, phi_o=None):
    """Degrees (θi, φi, θo, φo) of the evaluation grid: every θi × φi × outgoing direction,
    where the outgoing directions are θo × φo with θo = 0 taken once (at φo = 0)."""
    ti = default_theta_i(material) if theta_i is None else theta_i
    if phi_i is None:
        # anisotropic: the stored azimuths (±180° are one direction), to 0.001°
        phi_i = [0.0] if material.isotropic else \
            np.unique(np.mod(np.round(np.degrees(material.phi_i.astype(np.float64)), 3), 360.0))
    ti, pi = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (ti, phi_i))
    to = np.atleast_1d(np.asarray(DEFAULT_THETA_O if theta_o is None else theta_o, dtype=float))
    po = np.atleast_1d(np.asarray(DEFAULT_PHI_O if phi_o is None else phi_o, dtype=float))
    at_normal = np.zeros(int(np.any(to == 0)))
    out_t = np.concatenate([at_normal, np.repeat(to[to != 0], len(po))])
    out_p = np.concatenate([at_normal, np.tile(po, int(np.sum(to != 0)))])
    a, b, j = np.meshgrid(ti, pi, np.arange(len(out_t)), indexing="ij")
    return a.ravel(), b.ravel(), out_t[j.ravel()], out_p[j.ravel()]


def _check_request(material: RGLMaterial, channels: str, illuminant: str, theta_i, theta_o):
    """Reader options, checked before any work: channel choice, colour conversion, angles."""
    path = material.path
    if channels not in CHANNEL_CHOICES:
        raise InputFileError(path, f"channels={channels!r} is not a choice",
                             hint=f"choose one of {', '.join(CHANNEL_CHOICES)}")
    if channels == "spectral" and material.kind != "spectral":
        raise InputFileError(path, "channels='spectral' asks for spectra, but this is an RGB "
                             "file (field 'rgb')", hint="use channels 'native', 'rgb' or 'y'")
    if material.kind == "spectral" and channels in ("rgb", "y"):
        try:
            colorimetry.illuminant_table(illuminant)
        except ValueError as exc:
            raise InputFileError(path, str(exc), hint="pass illuminant='D65' (the default) or "
                                 "another CIE illuminant name") from None
        try:
            colorimetry.xyz_weights(material.wavelength_nm, illuminant)
        except ValueError as exc:
            raise InputFileError(path, f"field 'wavelengths': {exc}",
                                 hint="read the spectra with channels='spectral'") from None
    for name, th in (("theta_i", theta_i), ("theta_o", theta_o)):
        bad = (th < 0) | (th >= 90)
        if np.any(bad):
            raise InputFileError(path, f"the requested {name} {th[bad][0]:g}° is not in "
                                 "[0°, 90°)", hint="an RGL file holds a BRDF: both directions "
                                 "above the surface, θ in degrees")


def _axis_text(values) -> str:
    v = np.unique(np.round(np.asarray(values, dtype=np.float64), 6))
    steps = np.unique(np.round(np.diff(v), 6))
    if len(v) > 2 and len(steps) == 1:
        return f"{v[0]:g} to {v[-1]:g} step {steps[0]:g} ({len(v)})"
    return ", ".join(f"{x:.4g}" for x in v) + f" ({len(v)})"


def measurement_from_material(material: RGLMaterial, channels: str = "native",
                              illuminant: str = colorimetry.DEFAULT_ILLUMINANT, theta_i=None,
                              phi_i=None, theta_o=None, phi_o=None) -> Measurement:
    """The material evaluated on a grid (see :func:`direction_grid`), one row per direction pair
    and channel, quantity bsdf (f in 1/sr)."""
    from fitlab.io.directions import degrees_to_direction

    ti, pi, to, po = direction_grid(material, theta_i, phi_i, theta_o, phi_o)
    _check_request(material, channels, illuminant, ti, to)
    wi, wo = degrees_to_direction(ti, pi), degrees_to_direction(to, po)
    f, names = eval_bsdf(material, wi, wo, channels, illuminant)
    n, k = f.shape
    rep = lambda a: np.repeat(a, k, axis=0)  # noqa: E731
    meta = {"source_format": "RGL-EPFL material database tensor file (.bsdf)",
            "material": material.description, "sample": Path(material.path).stem,
            "scatter": "brdf", "file_kind": material.kind,
            "grid_theta_i_deg": _axis_text(ti), "grid_phi_i_deg": _axis_text(pi),
            "grid_theta_o_deg": _axis_text(to), "grid_phi_o_deg": _axis_text(po[to > 0]),
            "evaluation": "powitacq BRDF::eval (Dupuy & Jakob 2018) divided by cos(theta_o)"}
    if material.kind == "spectral" and channels in ("rgb", "y"):
        meta.update(colorimetry.conversion_metadata(
            "spectra to CIE XYZ to " + ("linear sRGB" if channels == "rgb" else "Y"), illuminant))
    elif material.kind == "rgb" and channels == "y":
        meta.update(colorimetry.conversion_metadata("linear sRGB to luminance Y (Rec. 709)",
                                                    "D65 (the sRGB white point)"))
    spectral_out = material.kind == "spectral" and channels in ("native", "spectral")
    return Measurement(
        path=material.path, sha256=material.tensor.sha256, theta_i=rep(ti), phi_i=rep(pi),
        theta_o=rep(to), phi_o=rep(po), wi=rep(wi), wo=rep(wo), value=f.reshape(-1), sigma=None,
        channel=np.tile(np.arange(k), n), channel_names=tuple(names),
        wavelength_nm=np.array(material.wavelength_nm, dtype=np.float64) if spectral_out
        else None,
        quantity="bsdf", file_quantity="bsdf_cos (tabulated rho*D/(4 sigma))", metadata=meta,
        lines=np.repeat(np.arange(1, n + 1), k))


def read_rgl(path, channels: str = "native", illuminant: str = colorimetry.DEFAULT_ILLUMINANT,
             theta_i=None, phi_i=None, theta_o=None, phi_o=None) -> Measurement:
    """An RGL ``.bsdf`` file as a Measurement on a direction grid (degrees; defaults: the
    file's θi below 90°, φi = 0, θo = 0…85° step 5, φo = 0…350° step 10). ``lines`` holds the
    1-based index of each row's direction pair in the grid."""
    return measurement_from_material(read_material(path), channels, illuminant, theta_i, phi_i,
                                     theta_o, phi_o)


# --------------------------------------------------------------------------------------------
# Registry entry
# --------------------------------------------------------------------------------------------


def _detect(head: bytes, path) -> bool:
    return head[:12] == MAGIC


def describe_rgl(path, format_name: str = "rgl", accept=()) -> dict:
    material = read_material(path)
    m = measurement_from_material(material)
    f = material.tensor.fields
    normal = np.array([[0.0, 0.0, 1.0]])
    fr_n, names = eval_bsdf(material, normal, normal)
    valid = np.unpackbits(f["valid"].data) if "valid" in f else None
    info = describe_loaded(m, format_name, accept)
    info.update({
        "file_bytes": material.tensor.size,
        "tensor_file_version": ".".join(map(str, material.tensor.version)),
        "description": material.description,
        "fields": {name: f"{fl.dtype.name}{list(fl.shape)} at byte {fl.offset}"
                   for name, fl in f.items()},
        "kind": material.kind,
        "isotropic": material.isotropic,
        "jacobian_flag": material.jacobian,
        "theta_i_stored_deg": [round(float(t), 4) for t in np.degrees(material.theta_i)],
        "phi_i_stored_deg": [round(float(p), 4) for p in np.degrees(material.phi_i)],
        "wavelength_range_nm": None if material.wavelength_nm is None else
        [float(material.wavelength_nm[0]), float(material.wavelength_nm[-1])],
        "f_normal_incidence_and_view": {c: float(v) for c, v in zip(names, fr_n[0])},
        "valid_field": "absent" if valid is None else
        f"{f['valid'].shape[0]} bytes, {valid.mean():.3f} of bits set (not used by evaluation)",
        "read_default": "the file's theta_i below 90 deg x phi_i 0 x (theta_o 0..85 step 5 x "
                        "phi_o 0..350 step 10), native channels, "
                        "f = tabulated value / cos(theta_o)",
    })
    return info


FORMAT = Format("rgl", "RGL-EPFL material database tensor file (.bsdf, Dupuy & Jakob 2018)",
                _detect, read_rgl, describe_rgl, "data_formats/rgl_bsdf.md", suffixes=(".bsdf",),
                binary=True)
