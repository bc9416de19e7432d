"""glTF 2.0 export of a material: glTF's BRDF is fixed by its specification (the registry's
``gltf_pbr`` / ``gltf_pbr_clearcoat``, fitlab/models/gltf_pbr.py), so a fitted material is
converted by *fitting* that BRDF to it over the hemisphere, and the conversion error is
reported (data_formats/gltf_material.md).

The conversion fit: the material's f on a fixed set of direction pairs (:func:`conversion_pairs`:
incidences 0-80°, the outgoing hemisphere every 5° and rings around the mirror direction down
to 0.2°), per channel, becomes a synthetic measurement that ``fitlab.fit`` fits with the log
loss (relative errors on the specular peak and on the diffuse floor alike): ``base_color`` per
channel, the rest shared by R, G, B (glTF has one roughness, one metallic), ``specular_color``
fixed at 1 (its effect on f0 is the ior's). The clear-coat variant is tried too and kept when it
lowers the conversion error by more than 10 %. Errors are those of f·cos θo where a renderer
sees them: relative RMS and largest relative difference over the pairs above 1e-3 of the
largest value, directional albedo at 0, 30, 60, 80°, and PSNR / SSIM (scikit-image) of the
hemispherical images of f·cos θo at 0, 30 and 60° incidence (PSNR null for identical
images).

The file: one material (pbrMetallicRoughness + KHR_materials_ior / _specular / _clearcoat where
their values differ from the defaults) on a UV sphere (positions, normals, indices in one
base64 buffer), a node and a scene; fitlab's provenance and the conversion figures in the
material's ``extras``. Deterministic: same material, same bytes.
"""

from __future__ import annotations

import base64
import json

import numpy as np

from fitlab.export.material import ExportError, Material
from fitlab.lobe_metrics import (ERROR_FLOOR, albedo_sampled, directions, image_errors,
                                 lobe_image, model_evaluator, relative_errors)
from fitlab.version import __version__

#: Incidences (θi, degrees, φi = 0) and the outgoing grid of the conversion fit.
THETA_I = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 80.0)
THETA_O_STEP = 5.0
PHI_O_STEP = 10.0
#: Rings around the mirror direction: angular radii (degrees) and points per ring.
MIRROR_RINGS = (0.2, 0.5, 1.0, 2.0, 3.5)
RING_POINTS = 8
#: A clear coat is kept when it lowers the relative RMS by more than this fraction.
COAT_GAIN = 0.10
#: The preview sphere's tessellation (rings of latitude, segments of longitude).
SPHERE = (24, 48)


def conversion_pairs(isotropic: bool = False, transmission: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(wi, wo) of the conversion fit: for each incidence of :data:`THETA_I`, the hemisphere
    at bin centres of 5° × 10° (φo in [0°, 180°] for an isotropic material: the plane of
    incidence is a mirror plane of its f) and rings around the mirror direction; with
    ``transmission`` the same directions mirrored below the surface too."""
    t_o = np.arange(THETA_O_STEP / 2, 90.0, THETA_O_STEP)
    p_o = np.arange(0.0, 180.0 + 1e-9 if isotropic else 360.0, PHI_O_STEP)
    grid_t, grid_p = (a.ravel() for a in np.meshgrid(t_o, p_o, indexing="ij"))
    wis, wos = [], []
    for ti in THETA_I:
        wi = directions(ti, 0.0)
        mirror = wi * np.array([-1.0, -1.0, 1.0])
        # an orthonormal frame about the mirror direction for its rings
        a = np.array([0.0, 1.0, 0.0])
        e1 = np.cross(a, mirror)
        e1 = e1 / np.linalg.norm(e1) if np.linalg.norm(e1) > 0 else np.array([1.0, 0.0, 0.0])
        e2 = np.cross(mirror, e1)
        ring = [mirror]
        for r in np.radians(MIRROR_RINGS):
            for k in range(RING_POINTS):
                ang = 2 * np.pi * k / RING_POINTS
                ring.append(np.cos(r) * mirror + np.sin(r) * (np.cos(ang) * e1 + np.sin(ang) * e2))
        ring = np.array(ring)
        ring = ring[ring[:, 2] > 0.02]
        wo = np.concatenate([directions(grid_t, grid_p), ring])
        if transmission:
            wo = np.concatenate([wo, wo * np.array([1.0, 1.0, -1.0])])
        wos.append(wo)
        wis.append(np.broadcast_to(wi, wo.shape))
    return np.concatenate(wis), np.concatenate(wos)


def _values(material: Material, wi, wo) -> dict:
    from fitlab.api import eval_bsdf

    return {c: np.asarray(eval_bsdf(material.model, p, wi, wo, material.options))
            for c, p in material.channels.items()}


def _measurement(values: dict, wi, wo):
    """A synthetic Measurement (absolute f, one channel per colour) of ``values`` at the pairs."""
    from fitlab.io.measurement import Measurement, check_measurement

    names = tuple(values)
    n = wi.shape[0]
    t_i, p_i = np.degrees(np.arccos(np.clip(wi[:, 2], -1, 1))), np.degrees(
        np.arctan2(wi[:, 1], wi[:, 0]))
    t_o, p_o = np.degrees(np.arccos(np.clip(wo[:, 2], -1, 1))), np.degrees(
        np.arctan2(wo[:, 1], wo[:, 0]))
    rep = lambda a: np.tile(a, len(names))  # noqa: E731
    m = Measurement(
        path="<glTF conversion>", sha256="", theta_i=rep(t_i), phi_i=rep(p_i), theta_o=rep(t_o),
        phi_o=rep(p_o), wi=np.tile(wi, (len(names), 1)), wo=np.tile(wo, (len(names), 1)),
        value=np.concatenate([values[c] for c in names]), sigma=None,
        channel=np.repeat(np.arange(len(names)), n), channel_names=names, wavelength_nm=None,
        quantity="bsdf", file_quantity="bsdf",
        metadata={"scatter": "bsdf" if np.any(wo[:, 2] < 0) else "brdf"},
        lines=np.zeros(n * len(names), dtype=int))
    return check_measurement(m)


#: What the glTF conversion fit holds fixed, and the parameters it fits per channel.
GLTF_FIXED = {"specular_color": 1.0}
GLTF_PER_CHANNEL = ("base_color",)


def _fit(model: str, values: dict, wi, wo, seed: int, progress: bool, fix: dict | None = None,
         per_channel: tuple = GLTF_PER_CHANNEL):
    """``model`` fitted to ``values`` at the pairs (log loss, 4 starts, no bootstrap), with
    ``fix`` held and every free parameter but those of ``per_channel`` shared by the
    channels."""
    from fitlab.fitting.api import fit
    from fitlab.models import get_model

    fix = GLTF_FIXED if fix is None else fix
    keep = wo[:, 2] != 0
    m = _measurement({c: v[keep] for c, v in values.items()}, wi[keep], wo[keep])
    names = get_model(model).parameter_names
    shared = [n for n in names if n not in per_channel and n not in fix]
    result = fit(m, model, fix=dict(fix), loss="log", starts=4,
                 seed=seed, bootstrap=0, share=shared if len(values) > 1 else (),
                 progress=progress)
    return result


def conversion_errors(material: Material, model: str, params_by_channel: dict,
                      label: str = "gltf") -> dict:
    """How far ``model`` with ``params_by_channel`` (glTF's BSDF, or another target's:
    ``label`` names it in the albedo figures) is from the material."""
    from fitlab.models import get_model

    # the whole hemisphere (both sides for a transmitting material): the figures do not
    # depend on the material's symmetry
    wi, wo = conversion_pairs(transmission=get_model(material.model).capabilities.transmission)
    src = model_evaluator(material.model, material.channels, material.options)
    dst = model_evaluator(model, params_by_channel, {})
    err = relative_errors(src(wi, wo), dst(wi, wo), wo[:, 2], ERROR_FLOOR)
    albedo = {}
    for t in (0.0, 30.0, 60.0, 80.0):
        a = albedo_sampled(material.model, material.channels, material.options, t)
        b = albedo_sampled(model, params_by_channel, {}, t)
        albedo[f"{t:g}"] = {"material": [float(x) for x in a], label: [float(x) for x in b]}
        if get_model(model).capabilities.transmission:
            a = albedo_sampled(material.model, material.channels, material.options, t, side=-1)
            b = albedo_sampled(model, params_by_channel, {}, t, side=-1)
            albedo[f"{t:g}"].update(material_transmitted=[float(x) for x in a],
                                    **{f"{label}_transmitted": [float(x) for x in b]})
    images = {f"{t:g}": image_errors(lobe_image(src, t), lobe_image(dst, t))
              for t in (0.0, 30.0, 60.0)}
    return {"relative_rms": err["relative_rms"], "relative_max": err["relative_max"],
            "pairs": int(wi.shape[0]), "floor": ERROR_FLOOR, "albedo": albedo,
            "lobe_images": images}


#: A fitted metallic this close to 1 is a metal (the dielectric parameters then change f by
#: less than this fraction and are written at glTF's defaults).
METAL = 1e-6


def simplified(params: dict) -> dict:
    """The fitted values with what has no visible effect at glTF's defaults: a metallic within
    :data:`METAL` of 1 is 1 (ior, specular then do not enter f: 1.5 and 1)."""
    out = {c: dict(p) for c, p in params.items()}
    for p in out.values():
        if p["metallic"] > 1.0 - METAL:
            p.update(metallic=1.0, ior=1.5, specular=1.0)
    return out


def candidates(capabilities) -> tuple[str, ...]:
    """The glTF models a material with these capabilities is fitted with: a transmitting one
    with KHR_materials_transmission, an anisotropic one with KHR_materials_anisotropy, else
    the core and the core with KHR_materials_clearcoat (each glTF model adds one extension to
    the core + ior + specular)."""
    if capabilities.transmission:
        return ("gltf_pbr_transmission",)
    if not capabilities.isotropic:
        return ("gltf_pbr_anisotropic",)
    return ("gltf_pbr", "gltf_pbr_clearcoat")


def convert(material: Material, *, seed: int = 0, progress: bool = False):
    """(glTF model name, {channel: its parameters}, conversion figures) fitted to
    ``material``."""
    from fitlab.models import get_model

    model = get_model(material.model)
    if not model.capabilities.reflection:
        raise ExportError(f"{material.model} reflects nothing (a transmission model); glTF's "
                          "metallic-roughness material reflects: export a reflecting model")
    if material.wavelengths_nm is not None:
        raise ExportError(f"{material.source}: glTF takes linear RGB, not the spectrum "
                          f"{', '.join(material.channels)}; export one wavelength with "
                          "--channel")
    return fit_conversion(material, [(name, GLTF_FIXED) for name in
                                      candidates(model.capabilities)],
                          simplify=simplified, seed=seed, progress=progress)


def fit_conversion(material: Material, targets, *, per_channel: tuple = GLTF_PER_CHANNEL,
                   gain: float = COAT_GAIN, label: str = "gltf", what: str = "glTF",
                   simplify=None, seed: int = 0, progress: bool = False):
    """(model name, {channel: its parameters}, conversion figures) of the best of ``targets``
    ((registry model, {parameter: value held}) pairs, tried in order, a later one kept when
    it lowers the relative RMS by more than ``gain``) fitted by least squares to
    ``material`` on :func:`conversion_pairs`: what the glTF export does, and the MaterialX
    export's conversion to OpenPBR (fitlab/export/materialx.py). ``simplify``: applied to the
    fitted values before the errors are measured."""
    from fitlab.models import get_model

    caps = get_model(material.model).capabilities
    if not caps.reflection:
        raise ExportError(f"{material.model} reflects nothing (a transmission model); the "
                          f"{what} material reflects: export a reflecting model")
    wi, wo = conversion_pairs(caps.isotropic, caps.transmission)
    values = _values(material, wi, wo)
    if not all(np.any(v[wo[:, 2] > 0] > 0) for v in values.values()):
        raise ExportError(f"{material.model} is 0 at every reflection direction of a channel; "
                          "there is nothing to convert")
    best = None
    for name, fix in targets:
        result = _fit(name, values, wi, wo, seed, progress, fix, per_channel)
        params = {c: dict(p) for c, p in result.parameters.items()}
        if simplify is not None:
            params = simplify(params)
        errors = {"fit_pairs": int(np.sum(wo[:, 2] > 0)),
                  **conversion_errors(material, name, params, label)}
        if best is None or errors["relative_rms"] < (1.0 - gain) * best[2]["relative_rms"]:
            best = (name, params, errors)
    return best


# ------------------------------------------------------------------------------------------
# The glTF document
# ------------------------------------------------------------------------------------------


def _sphere(rings: int, segments: int):
    """Positions, normals (unit sphere) and triangle indices of a UV sphere."""
    pos = []
    for i in range(rings + 1):
        th = np.pi * i / rings
        for j in range(segments + 1):
            ph = 2 * np.pi * j / segments
            pos.append((np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)))
    pos = np.asarray(pos, dtype=np.float32)
    idx = []
    w = segments + 1
    for i in range(rings):
        for j in range(segments):
            a, b = i * w + j, (i + 1) * w + j
            if i != 0:
                idx.append((a, b, a + 1))
            if i != rings - 1:
                idx.append((a + 1, b, b + 1))
    return pos, pos.copy(), np.asarray(idx, dtype=np.uint16).ravel()


def _sphere_tangents(rings: int, segments: int) -> np.ndarray:
    """Unit tangents (+w handedness) of :func:`_sphere` along increasing longitude φ."""
    out = []
    for i in range(rings + 1):
        for j in range(segments + 1):
            ph = 2 * np.pi * j / segments
            out.append((-np.sin(ph), 0.0, np.cos(ph), 1.0))
    return np.asarray(out, dtype=np.float32)


def _rgb_values(params: dict, name: str) -> list[float]:
    vals = [float(params[c][name]) for c in params]
    return vals * 3 if len(vals) == 1 else vals


def _shared(params: dict, name: str) -> float:
    return float(params[next(iter(params))][name])


def _offers(params: dict, name: str) -> bool:
    """The glTF model of ``params`` has parameter ``name`` (the extension that carries it)."""
    return name in params[next(iter(params))]


def pack_buffers(blobs: list[bytes]) -> tuple[list[int], bytes]:
    """(byte offsets, one buffer) of ``blobs`` laid end to end, each starting at a multiple of
    4 bytes and the buffer padded to one (glTF 2.0, 3.6.2.4 "Data alignment")."""
    offsets, data = [], b""
    for blob in blobs:
        data += b"\0" * (-len(data) % 4)
        offsets.append(len(data))
        data += blob
    return offsets, data + b"\0" * (-len(data) % 4)


def gltf_document(material: Material, model: str, params: dict, conversion: dict) -> dict:
    """The glTF 2.0 document: the fitted material on a preview sphere."""

    base = _rgb_values(params, "base_color")
    mat = {"name": f"fitlab {material.model}",
           "pbrMetallicRoughness": {"baseColorFactor": base + [1.0],
                                    "metallicFactor": _shared(params, "metallic"),
                                    "roughnessFactor": _shared(params, "roughness_factor")}}
    ext = {}
    ior = _shared(params, "ior")
    if ior != 1.5:
        ext["KHR_materials_ior"] = {"ior": ior}
    spec = _shared(params, "specular")
    if spec != 1.0:
        ext["KHR_materials_specular"] = {"specularFactor": spec}
    if _offers(params, "clearcoat") and _shared(params, "clearcoat") > 0:
        ext["KHR_materials_clearcoat"] = {
            "clearcoatFactor": _shared(params, "clearcoat"),
            "clearcoatRoughnessFactor": _shared(params, "clearcoat_roughness_factor")}
    anisotropic = (_offers(params, "anisotropy_strength")
                   and _shared(params, "anisotropy_strength") > 0)
    if anisotropic:
        ext["KHR_materials_anisotropy"] = {
            "anisotropyStrength": _shared(params, "anisotropy_strength"),
            "anisotropyRotation": float(np.radians(_shared(params, "anisotropy_rotation")))}
    if _offers(params, "transmission") and _shared(params, "transmission") > 0:
        ext["KHR_materials_transmission"] = {"transmissionFactor": _shared(params,
                                                                          "transmission")}
    if ext:
        mat["extensions"] = ext
    mat["extras"] = {"fitlab": {"source_model": material.model, "source": material.source,
                                "channels": list(material.channels), "gltf_model": model,
                                # a spectral fit's reduction to linear sRGB (spectral_colour.py)
                                **({"colour": material.colour} if material.colour else {}),
                                "conversion": conversion,
                                "spec": "data_formats/gltf_material.md"}}
    pos, nrm, idx = _sphere(*SPHERE)
    blobs = [pos.tobytes(), nrm.tobytes(), idx.tobytes()]
    if anisotropic:  # KHR_materials_anisotropy needs a tangent space: TANGENT along +u (φ)
        blobs.append(_sphere_tangents(*SPHERE).tobytes())
    offsets, data = pack_buffers(blobs)
    doc = {
        "asset": {"version": "2.0", "generator": f"fitlab {__version__}"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "preview sphere"}],
        "meshes": [{"name": "preview sphere", "primitives": [
            {"attributes": {"POSITION": 0, "NORMAL": 1, **({"TANGENT": 3} if anisotropic
                                                            else {})},
             "indices": 2, "material": 0}]}],
        "materials": [mat],
        "buffers": [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(data).decode("ascii")}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": offsets[0], "byteLength": len(blobs[0]), "target": 34962},
            {"buffer": 0, "byteOffset": offsets[1], "byteLength": len(blobs[1]), "target": 34962},
            {"buffer": 0, "byteOffset": offsets[2], "byteLength": len(blobs[2]), "target": 34963}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": int(pos.shape[0]), "type": "VEC3",
             "min": [float(x) for x in pos.min(0)], "max": [float(x) for x in pos.max(0)]},
            {"bufferView": 1, "componentType": 5126, "count": int(nrm.shape[0]), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5123, "count": int(idx.size), "type": "SCALAR"}],
    }
    if anisotropic:
        doc["bufferViews"].append({"buffer": 0, "byteOffset": offsets[3],
                                   "byteLength": len(blobs[3]), "target": 34962})
        doc["accessors"].append({"bufferView": 3, "componentType": 5126,
                                 "count": int(pos.shape[0]), "type": "VEC4"})
    if ext:
        doc["extensionsUsed"] = sorted(ext)
    return doc


#: A conversion whose relative RMS is above this gets a warning (printed by fitlab export).
FAR = 0.25


def conversion_warnings(material: Material, model: str, errors: dict,
                        params: dict | None = None, *, what: str = "glTF",
                        ordinary: set | None = None) -> list[str]:
    """Sentences for a conversion a user should not take at face value: a large error, and
    target (``what``: glTF, OpenPBR) parameters that ended at a bound of their range (the
    material wants more than the target's BRDF offers there; ``ordinary``: the parameters
    whose bounds are ordinary ends, for glTF metallic 0 or 1 and a zero clear coat)."""
    from fitlab.models import get_model

    out = []
    # shares that may well be 0 or 1, and the anisotropy's direction, whose bounds ±90° are the
    # same axis
    if ordinary is None:
        ordinary = {"metallic", "base_color", "clearcoat", "specular", "specular_color",
                    "anisotropy_strength", "anisotropy_rotation", "transmission"}
    gltf = get_model(model)
    for p in gltf.parameters:
        if params is None or p.name in ordinary:
            continue
        v = float(next(iter(params.values()))[p.name])
        if min(v - p.lower, p.upper - v) <= 1e-6 * max(1.0, p.upper - p.lower):
            out.append(f"{what}'s {p.name} ended at a bound of its range ({v:.6g} in "
                       f"[{p.lower:g}, {p.upper:g}]): {material.model} asks for more than "
                       f"{what}'s BRDF offers there")
    if errors["relative_rms"] > FAR:
        text = (f"the {what} material is far from {material.model}: relative RMS "
                f"{errors['relative_rms']:.3g} of f·cos over the hemisphere")
        if "transmission" in gltf.parameter_names:
            text += ("; KHR_materials_transmission is a thin-walled surface (light leaves "
                     "straight through, blurred by the roughness), which cannot take the "
                     "refraction of a single rough interface into a denser medium")
        out.append(text + "; check the figures before using it")
    return out


def gltf_export(material: Material, *, seed: int = 0, progress: bool = False):
    """(glTF document, conversion figures) of ``material`` (:func:`convert`)."""
    model, params, errors = convert(material, seed=seed, progress=progress)
    shown = {c: {k: v for k, v in p.items()} for c, p in params.items()}
    conversion = {"gltf_model": model, "fitted": shown, **errors,
                  "warnings": conversion_warnings(material, model, errors, params),
                  "summary": f"glTF's BRDF ({model}) fitted to the material on "
                  f"{errors['fit_pairs']} direction pairs (log loss), errors over "
                  f"{errors['pairs']}; SSIM of the lobe images "
                  + ", ".join(f"{v['ssim']:.3f} at {t}°"
                              for t, v in errors["lobe_images"].items())}
    return gltf_document(material, model, params, conversion), conversion


def gltf_text(doc: dict) -> str:
    """The document as JSON text (keys in the order built, two-space indent)."""
    return json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n"


__all__ = ["THETA_I", "conversion_pairs", "conversion_errors", "convert", "gltf_document",
           "gltf_export", "gltf_text"]
