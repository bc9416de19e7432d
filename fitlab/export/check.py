"""The renderer check of an export (``fitlab export --check``, ``export_material(check=True)``):
a renderer evaluates the exported material on a virtual goniometer and the figure says how far
its values are from the material's own (fitlab's f·cos θi of the fit or model exported).

Every pair of :func:`check_geometries` (120 reflection pairs: θi 0-80° in the plane φi = 0,
θo 5-80° at six azimuths; fixed, so figures compare between runs and materials) is rendered
as one directional light of irradiance 1 from wi seen from wo: a pixel is f(wi, wo)·cos θi.

- **Mitsuba** (``mitsuba``, ``mitsuba-plugin``): the exported dictionary rendered by Mitsuba 3
  (fitlab.export.mitsuba_plugin.conversion_error): relative RMS and largest relative difference
  over the pairs where fitlab's value is above 1e-6 of its largest. An exact translation is
  within float32 rounding (~1e-7 to 1e-5); more is a translation's approximation (``plastic``).
- **glTF** (``gltf``), by the first renderer found (:func:`gltf_renderer`):

  1. *three.js* (headless Chromium, fitlab.export.threejs): the written file loaded by three.js's
     GLTFLoader and rendered; the figure is what a three.js viewer shows against the fit: the
     conversion (glTF's BRDF cannot take every material) and three.js's own departures from
     the glTF specification (up to ~12 % at grazing angles on a rough metal; tests/browser/
     README.md). The specification's values of the file's material are compared too
     (``specification``), so the two parts can be told apart. The Khronos glTF validator checks
     the file when Node.js and the npm package gltf-validator are there (errors fail the
     check; otherwise ``validator`` says why it did not run).
  2. *Mitsuba* when three.js cannot run: Mitsuba 3 has no glTF material, so the material is
     read back from the file and rendered with glTF's specified BRDF (fitlab's ``gltf_pbr``
     models) through fitlab's Mitsuba plugin: this checks the file's values and the conversion
     as a renderer that follows the specification shows them, not a particular viewer.

  Both over the pairs where the fit's value is above 1e-3 of its largest per channel (the
  conversion's own floor, ``fitlab.lobe_metrics.ERROR_FLOOR``), per channel combined.
- **MaterialX** (``materialx``, renderer ``materialx-glsl``): MaterialX's own GLSL generator's
  shader of the written document, run in Mesa's OpenGL through EGL, one directional light per
  pair, against fitlab's OpenPBR evaluation of the values read from the file (and, for a
  converted material, against the material too): fitlab.export.materialx.run_check.

A check that cannot run (no renderer) raises :class:`~fitlab.export.material.ExportError` saying
what to install, before anything is built or written.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from fitlab.export.material import ExportError, Material, material_from_model

#: The renderers that check each export format, in the order they are tried.
CHECKERS = {"mitsuba": ("mitsuba",), "mitsuba-plugin": ("mitsuba",), "gltf": ("three", "mitsuba"),
            "materialx": ("materialx-glsl",)}
MITSUBA_INSTALL = "Mitsuba 3 (pip install mitsuba, a dependency of fitlab)"


def check_geometries() -> tuple[np.ndarray, np.ndarray]:
    """(wi, wo) of every check (120 reflection pairs, fitlab.export.mitsuba_plugin's)."""
    from fitlab.export.mitsuba_plugin import check_geometries as geometries

    return geometries()


def geometry_text() -> str:
    from fitlab.export.mitsuba_plugin import CHECK_PHI_O, CHECK_THETA_I, CHECK_THETA_O

    return ("theta_i " + ",".join(f"{t:g}" for t in CHECK_THETA_I) + " (phi_i 0); theta_o "
            + ",".join(f"{t:g}" for t in CHECK_THETA_O) + "; phi_o "
            + ",".join(f"{t:g}" for t in CHECK_PHI_O) + " (degrees)")


def mitsuba_missing() -> str | None:
    """Why Mitsuba 3 cannot render here (None: it can)."""
    from fitlab.simulate.engine import select_libllvm

    select_libllvm()  # a libLLVM Dr.Jit can use, chosen before mitsuba is imported
    import importlib.util

    if importlib.util.find_spec("mitsuba") is None:
        return "Mitsuba 3 is not installed"
    return None


def _missing(renderer: str) -> str | None:
    if renderer == "materialx-glsl":
        from fitlab.export import materialx

        return materialx.check_missing()
    if renderer == "three":
        from fitlab.export import threejs

        return threejs.missing()
    return mitsuba_missing()


def renderer_for(format_name: str, renderer: str = "auto") -> str:
    """The renderer that checks an export of ``format_name``: ``renderer`` itself (``three``,
    ``mitsuba``) if it can run here, or with ``auto`` the first of :data:`CHECKERS` that can.
    Raises ExportError with what to install when none can."""
    from fitlab.export.threejs import INSTALL

    if format_name not in CHECKERS:
        raise ExportError(f"--check: no renderer checks the {format_name} export (it holds "
                          "the model's own values on a grid); export without --check")
    names = CHECKERS[format_name]
    if renderer != "auto" and renderer not in names:
        raise ExportError(f"a {format_name} export is checked by {' or '.join(names)}, not "
                          f"{renderer!r}")
    tried = names if renderer == "auto" else (renderer,)
    reasons = []
    for name in tried:
        why = _missing(name)
        if why is None:
            return name
        reasons.append(why)
    from fitlab.export.materialx import INSTALL as MATERIALX_INSTALL

    install = {"three": f"for three.js: {INSTALL}", "mitsuba": f"for Mitsuba: {MITSUBA_INSTALL}",
               "materialx-glsl": f"for MaterialX's GLSL: {MATERIALX_INSTALL}"}
    raise ExportError(f"--check cannot run: {'; '.join(reasons)}. The {format_name} check "
                      f"renders with {' or '.join(tried)}: install " + "; or ".join(
                          install[n] for n in tried))


def _figure(expected: np.ndarray, rendered: np.ndarray, floor: float) -> dict:
    """Relative RMS and largest relative difference of ``rendered`` from ``expected`` (N, 3)
    over the pairs where ``expected`` is above ``floor`` × its channel's largest value."""
    from fitlab.lobe_metrics import relative_errors

    e = relative_errors(expected, rendered, np.ones(expected.shape[0]), floor)
    return {"relative_rms": e["relative_rms"], "relative_max": e["relative_max"],
            "values": e["pairs"]}


def material_values(material: Material, wi, wo) -> np.ndarray:
    """(N, 3) f(wi, wo)·cos θi of ``material`` per colour channel (a grey one repeated)."""
    from fitlab.api import eval_bsdf

    cols = [np.asarray(eval_bsdf(material.model, p, wi, wo, material.options)) * wi[:, 2]
            for p in material.channels.values()]
    return np.stack(cols * 3 if len(cols) == 1 else cols, axis=-1)


def gltf_material(doc: dict, source: str = "the glTF file") -> Material:
    """The first material of a glTF document as fitlab's glTF model with its values, read as
    a glTF renderer reads them (the core, KHR_materials_ior, _specular, _clearcoat,
    _anisotropy, _transmission; defaults where a value is absent), in R, G, B."""
    try:
        mat = doc["materials"][0]
    except (KeyError, IndexError, TypeError):
        raise ExportError(f"{source} has no material to check") from None
    pbr = mat.get("pbrMetallicRoughness", {})
    ext = mat.get("extensions", {})
    base = list(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]))[:3]
    common = {"metallic": float(pbr.get("metallicFactor", 1.0)),
              "roughness_factor": float(pbr.get("roughnessFactor", 1.0)),
              "ior": float(ext.get("KHR_materials_ior", {}).get("ior", 1.5)),
              "specular": float(ext.get("KHR_materials_specular", {}).get("specularFactor",
                                                                           1.0))}
    colour = ext.get("KHR_materials_specular", {}).get("specularColorFactor", [1.0, 1.0, 1.0])
    if max(colour) - min(colour) > 1e-12:
        raise ExportError(f"{source}: a coloured specularColorFactor {colour} has no fitlab "
                          "model to check it with")
    common["specular_color"] = float(colour[0])
    known = {"KHR_materials_ior", "KHR_materials_specular"}
    extra = {"KHR_materials_clearcoat": "clearcoat", "KHR_materials_anisotropy": "anisotropy",
             "KHR_materials_transmission": "transmission"}
    used = [e for e in ext if e not in known]
    unknown = [e for e in used if e not in extra]
    if unknown or len(used) > 1:
        raise ExportError(f"{source}: fitlab's glTF models take the core with at most one of "
                          f"{', '.join(extra)}; the material uses {', '.join(used)}")
    model = "gltf_pbr"
    if used:
        e = ext[used[0]]
        if used[0] == "KHR_materials_clearcoat":
            model = "gltf_pbr_clearcoat"
            common.update(clearcoat=float(e.get("clearcoatFactor", 0.0)),
                          clearcoat_roughness_factor=float(e.get("clearcoatRoughnessFactor",
                                                                 0.0)))
        elif used[0] == "KHR_materials_anisotropy":
            model = "gltf_pbr_anisotropic"
            common.update(anisotropy_strength=float(e.get("anisotropyStrength", 0.0)),
                          anisotropy_rotation=float(np.degrees(e.get("anisotropyRotation",
                                                                     0.0))))
        else:
            model = "gltf_pbr_transmission"
            common.update(transmission=float(e.get("transmissionFactor", 0.0)))
    channels = {c: {"base_color": float(v), **common} for c, v in zip("RGB", base)}
    return material_from_model(model, channels)._replace(source=source)


def _check_mitsuba(material: Material, bsdf: dict) -> dict:
    from fitlab.export import mitsuba_plugin as fm

    fm.ensure_variant()
    g = fm.conversion_error(material, bsdf)
    return {**g, "compared": "Mitsuba's render of the exported BSDF against fitlab's f·cos θi "
            "of the material",
            "meaning": "an exact translation is within float32 rounding (up to ~1e-5); more "
            "is the translation's own approximation"}


def _validate_gltf(text: str) -> dict:
    """The Khronos validator's counts for the file's ``text`` (or why it did not run); a file
    it finds errors in fails the check."""
    from fitlab.export import threejs

    why = threejs.validator_missing()
    if why is not None:
        return {"skipped": why}
    with tempfile.TemporaryDirectory(prefix="fitlab-gltf-check-") as tmp:
        path = Path(tmp) / "material.gltf"
        path.write_text(text, encoding="utf-8")
        report = threejs.validate(path)
    validator = {"version": report["validator"], "errors": report["numErrors"],
                 "warnings": report["numWarnings"], "infos": report["numInfos"],
                 "hints": report["numHints"],
                 "messages": [f"{m.get('code')} at {m.get('pointer', '')}"
                              for m in report.get("messages", [])][:5]}
    if validator["errors"]:
        raise ExportError(
            f"the Khronos glTF validator {validator['version']} finds {validator['errors']} "
            "error(s) in the export (" + "; ".join(validator["messages"]) + "): a fitlab bug, "
            "please report it; nothing written")
    return validator


def _check_gltf_mitsuba(material: Material, doc: dict, text: str) -> dict:
    from fitlab.export import mitsuba_plugin as fm
    from fitlab.export.mitsuba import plugin_bsdf
    from fitlab.lobe_metrics import ERROR_FLOOR

    variant = fm.ensure_variant()
    import mitsuba as mi

    back = gltf_material(doc)
    wi, wo = check_geometries()
    rendered = fm.goniometer(plugin_bsdf(back), wi, wo)
    return {"renderer": f"Mitsuba {mi.__version__} {variant} (fitlab's plugin with glTF's "
            f"specified BRDF, {back.model}, of the values read from the file)",
            "pairs": int(wi.shape[0]), **_figure(material_values(material, wi, wo), rendered,
                                                 ERROR_FLOOR),
            "floor": ERROR_FLOOR, "geometry": geometry_text(),
            "compared": "glTF's specified BRDF with the values read from the file, rendered "
            "by Mitsuba, against fitlab's f·cos θi of the material",
            "meaning": "the glTF conversion's error as a renderer that follows the glTF "
            "specification shows it; Mitsuba has no glTF material of its own, and a glTF "
            "viewer adds its own approximations (three.js: up to ~12 % at grazing angles)",
            "validator": _validate_gltf(text)}


def _check_gltf_three(material: Material, text: str) -> dict:
    from fitlab.export import threejs
    from fitlab.lobe_metrics import ERROR_FLOOR

    validator = _validate_gltf(text)
    wi, wo = check_geometries()
    with tempfile.TemporaryDirectory(prefix="fitlab-gltf-check-") as tmp:
        path = Path(tmp) / "material.gltf"
        path.write_text(text, encoding="utf-8")
        rendered, page = threejs.render_goniometer(path, wi, wo)
    expected = material_values(material, wi, wo)
    spec = material_values(gltf_material(json.loads(text)), wi, wo)
    return {"renderer": f"three.js r{page['three']} ({page['material']}, headless Chromium)",
            "pairs": int(wi.shape[0]), **_figure(expected, rendered, ERROR_FLOOR),
            "specification": _figure(expected, spec, ERROR_FLOOR), "floor": ERROR_FLOOR,
            "geometry": geometry_text(),
            "compared": "three.js's render of the written file against fitlab's f·cos θi of "
            "the material",
            "meaning": "what a three.js viewer shows: the glTF conversion's error (glTF's "
            "specified BRDF with the file's values, given beside) plus three.js's own "
            "departures from the glTF specification (tests/browser/README.md)",
            "validator": validator}


def check_materialx(material: Material | None, made) -> dict:
    """The MaterialX check of an export ``made`` (its document, the written text as MaterialX
    read and validated it: fitlab.export.materialx.materialx_export): MaterialX's GLSL against
    fitlab's OpenPBR evaluation of the file's values, and (for a converted ``material``) against
    the material exported (``against_fit``)."""
    from fitlab.export import materialx as mx

    doc = made.value
    back = mx.material_of_document(doc, "the MaterialX export")
    wi, wo = check_geometries()
    rendered, info = mx.render_goniometer(doc, wi, wo)
    out = {"renderer": info["renderer"], "pairs": int(wi.shape[0]),
           **_figure(material_values(back, wi, wo), rendered, mx.CHECK_FLOOR),
           "floor": mx.CHECK_FLOOR,
           "geometry": geometry_text(), "directional_albedo": info["directional_albedo"],
           "compared": mx.COMPARED, "meaning": mx.MEANING}
    if made.conversion.get("converted"):
        out["against_fit"] = _figure(material_values(material, wi, wo), rendered,
                                     mx.CHECK_FLOOR)
    return out


def run_check(format_name: str, renderer: str, material: Material, made) -> dict:
    """The check's figure of ``made`` (an :class:`~fitlab.export.renderers.Exported` of
    ``format_name``) rendered by ``renderer`` (:func:`renderer_for`) against ``material``:
    ``renderer``, ``pairs``, ``relative_rms``, ``relative_max``, ``compared``, ``meaning``,
    ``geometry`` (glTF also ``specification``, ``validator``, ``floor``)."""
    if format_name.startswith("mitsuba"):
        return _check_mitsuba(material, made.value)
    if renderer == "materialx-glsl":
        return check_materialx(material, made)
    if renderer == "three":
        return _check_gltf_three(material, made.text)
    return _check_gltf_mitsuba(material, made.value, made.text)


__all__ = ["CHECKERS", "check_geometries", "check_materialx", "gltf_material", "material_values",
           "renderer_for", "run_check"]
