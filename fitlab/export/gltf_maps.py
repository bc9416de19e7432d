"""The glTF 2.0 hand-off of a map fit (``fitlab fit-maps ... --gltf``; data_formats/stack.md,
"Renderer hand-off"): glTF's BRDF fitted to the fitted material of every texel, as ``fitlab
export --to gltf`` fits it to one material (fitlab/export/gltf_material.py), and written as a
glTF material with PNG textures on a quad the shape of the stack.

The conversion is itself a map fit (fitlab.fitting.maps.convert_to_gltf: fit_maps on a synthetic
stack): each texel's material evaluated at every ``GLTF_PAIR_STRIDE``-th pair of the export's conversion pairs
(reflection side) is one texel's readings, and ``gltf_pbr`` is fitted to them with the export's
settings (log loss; ``base_color`` per channel, the rest shared by R, G, B; ``specular_color``
fixed at 1) and one more: ``ior`` fixed at glTF's default 1.5, since KHR_materials_ior has no
texture (its effect on f0 is then ``specular``'s, which has one). Only the core model is used
(no clear coat: one model for every texel); a transmitting or anisotropic model is refused.

Textures (8-bit PNG, glTF's rules, embedded in the document as data: URIs, named):
``base_color.png`` (sRGB-encoded R, G, B), ``metallic_roughness.png`` (G roughness, B
metallic, linear), and ``specular.png`` (KHR_materials_specular's ``specularTexture``, its A
channel, linear).
Texel (x, y) is texture coordinate ((x + ½)/W, (y + ½)/H): glTF's UV origin is the image's
top-left corner, as the stack's. Texels not fitted take the mean of the fitted ones.
"""

from __future__ import annotations

import base64
import struct
import zlib

import numpy as np

from fitlab.export.gltf_material import pack_buffers

FOLDER = "gltf"
DOCUMENT = "material.gltf"


def png_bytes(pixels: np.ndarray) -> bytes:
    """A PNG (8-bit, RGB or RGBA, no filter, zlib level 9) of ``pixels`` (H, W, 3 or 4) uint8:
    the same pixels give the same bytes."""
    h, w, c = pixels.shape
    kind = {3: 2, 4: 6}[c]
    raw = b"".join(b"\x00" + pixels[y].tobytes() for y in range(h))

    def chunk(tag, data):
        return (struct.pack(">I", len(data)) + tag + data
                + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, kind, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def _srgb(linear):
    """glTF's sRGB transfer of linear values in [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _u8(x):
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def _plane(h: int, w: int):
    """A quad in glTF's x-z plane (normal +y, y up) of width 1 and the stack's aspect: its
    positions, normals, texture coordinates and indices."""
    half_w, half_h = 0.5, 0.5 * h / w
    pos = np.array([[-half_w, 0, -half_h], [half_w, 0, -half_h], [half_w, 0, half_h],
                    [-half_w, 0, half_h]], dtype=np.float32)
    nrm = np.tile(np.array([[0, 1, 0]], dtype=np.float32), (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32)
    idx = np.array([0, 2, 1, 0, 3, 2], dtype=np.uint16)
    return pos, nrm, uv, idx


def texel_centres(h: int, w: int) -> np.ndarray:
    """(h, w, 3): where texel (x, y)'s centre, texture coordinate ((x + ½)/w, (y + ½)/h),
    lies on the quad of :func:`_plane`, in the glTF file's world frame (y up)."""
    pos, _, uv, _ = _plane(h, w)
    # the quad's corners: uv (0, 0), (1, 0), (0, 1) span it (a parallelogram)
    o, du, dv = pos[0], pos[1] - pos[0], pos[3] - pos[0]
    assert (uv[0] == (0, 0)).all() and (uv[1] == (1, 0)).all() and (uv[3] == (0, 1)).all()
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    return (o[None, None] + u[None, :, None] * du[None, None]
            + v[:, None, None] * dv[None, None]).astype(float)


def gltf_maps(conv, model_name: str) -> tuple[dict, dict]:
    """(glTF document, {texture name: PNG bytes}) of the conversion ``conv`` (a MapsResult of
    ``gltf_pbr``); the document embeds the textures (data: URIs), as fitlab's glTF exports
    embed their buffers."""
    from fitlab.version import __version__

    H, W = conv.shape
    fitted = conv.status != _no_data_code()

    def filled(arr):
        out = np.array(arr, dtype=float)
        for k in range(out.shape[2]):
            plane = out[:, :, k]
            mean = np.nanmean(plane[fitted]) if fitted.any() else 0.5
            plane[~np.isfinite(plane)] = mean
        return out

    base = filled(conv.values["base_color"])
    if base.shape[2] == 1:
        base = np.repeat(base, 3, axis=2)
    metallic = filled(conv.values["metallic"])[..., 0]
    rough = filled(conv.values["roughness_factor"])[..., 0]
    spec = filled(conv.values["specular"])[..., 0]
    textures = {"base_color.png": png_bytes(_u8(_srgb(base))),
                "metallic_roughness.png": png_bytes(np.stack(
                    [np.zeros((H, W), np.uint8), _u8(rough), _u8(metallic)], axis=-1)),
                "specular.png": png_bytes(np.stack(
                    [np.zeros((H, W), np.uint8)] * 3 + [_u8(spec)], axis=-1))}
    names = list(textures)
    mat = {"name": f"fitlab {model_name} maps",
           "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                    "metallicRoughnessTexture": {"index": 1},
                                    "metallicFactor": 1.0, "roughnessFactor": 1.0},
           "extensions": {"KHR_materials_specular": {"specularFactor": 1.0,
                                                     "specularTexture": {"index": 2}}},
           "extras": {"fitlab": {"source_model": model_name, "gltf_model": "gltf_pbr",
                                 "fixed": {"ior": 1.5, "specular_color": 1.0},
                                 "spec": "data_formats/stack.md"}}}
    pos, nrm, uv, idx = _plane(H, W)
    blobs = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), idx.tobytes()]
    offsets, data = pack_buffers(blobs)
    views = [{"buffer": 0, "byteOffset": o, "byteLength": len(b),
              "target": 34963 if k == 3 else 34962} for k, (o, b) in enumerate(zip(offsets,
                                                                                    blobs))]
    doc = {
        "asset": {"version": "2.0", "generator": f"fitlab {__version__}"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "sample"}],
        "meshes": [{"name": "sample", "primitives": [
            {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3,
             "material": 0}]}],
        "materials": [mat],
        "samplers": [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"name": n, "uri": "data:image/png;base64,"
                    + base64.b64encode(textures[n]).decode("ascii")} for n in names],
        "textures": [{"sampler": 0, "source": k} for k in range(len(names))],
        "buffers": [{"byteLength": len(data), "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(data).decode("ascii")}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [float(x) for x in pos.min(0)], "max": [float(x) for x in pos.max(0)]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    return doc, textures


def _no_data_code() -> int:
    from fitlab.fitting.status import Status

    return Status.NO_DATA.code


__all__ = ["FOLDER", "DOCUMENT", "png_bytes", "gltf_maps", "texel_centres"]
