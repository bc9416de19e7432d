"""Registry of the renderer exports of a material (what ``fitlab export`` and
:func:`fitlab.export_material` reach): each format says what it writes, its file suffixes,
its spec in ``data_formats/`` and how to build the file from a
:class:`~fitlab.export.material.Material`. A format that cannot represent a material raises
:class:`~fitlab.export.material.ExportError` saying what and what to do.

Formats: ``mitsuba`` (Mitsuba 3's own plugins: scene XML for ``.xml``, the ``mi.load_dict``
dictionary as JSON for ``.json``), ``mitsuba-plugin`` (the same forms with fitlab's plugin,
for any model), ``gltf`` (a glTF 2.0 material fitted to the material, with a preview sphere),
``openmaterial`` (an ASAM OpenMATERIAL 3D BRDF look-up table: the writer of ``fitlab convert``,
fitlab.export.openmaterial), ``materialx`` (an OpenPBR Surface document, MaterialX 1.39: a fit of
the OpenPBR model as it is, any other converted by least squares; fitlab.export.materialx).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, NamedTuple

from fitlab.export.material import ExportError, Material
from fitlab.registry import Registry
from fitlab.version import __version__


class Exported(NamedTuple):
    """What an export made: the file's text, the object it holds (a Mitsuba dict, a glTF
    document) and what the conversion cost (``conversion``: figures, notes)."""

    text: str
    value: object
    conversion: dict


class Exporter(NamedTuple):
    name: str
    title: str
    description: str
    suffixes: tuple  # lower-case suffixes this format writes (the first is the default)
    spec: str  # its data_formats/ document
    #: build(material, suffix, settings) -> Exported
    build: Callable
    #: what it does with a spectral material (a fit whose channels are wavelengths):
    #: "rgb": takes linear sRGB only (the material reduced, fitlab.export.spectral_colour;
    #: refused where the bands do not span 380-780 nm); "rgb or spectrum": the reduction where
    #: the bands span the visible range, else the spectrum as it is; "spectrum": the bands kept
    spectra: str = "rgb"
    #: with_check(made, check) -> the file's text with the check's figure recorded in it
    #: (fitlab.export.check); None: the text as built
    with_check: Callable | None = None


def _json_text(value) -> str:
    return json.dumps(value, indent=2, sort_keys=False, ensure_ascii=False) + "\n"


def _comment(material: Material) -> str:

    colour = material.colour
    spectral = "" if not colour else (
        f", linear sRGB of a spectral fit's {colour['bands']} under {colour['illuminant']} "
        "(CIE 1931 2 degree observer; data_formats/fit_json.md)")
    return (f"fitlab {__version__} export of {material.model} from {material.source} "
            f"(channels {','.join(material.channels)}{spectral}); conventions: data_formats/"
            "mitsuba_export.md")


def _mitsuba_build(make_bsdf: Callable) -> Callable:
    def build(material: Material, suffix: str, settings: dict) -> Exported:
        from fitlab.export.mitsuba import scene_xml

        bsdf = make_bsdf(material)
        conversion = {"translation": bsdf["type"]}
        if suffix == ".json":
            return Exported(_json_text(bsdf), bsdf, conversion)
        return Exported(scene_xml(bsdf, preview=bool(settings.get("preview")),
                                  comment=_comment(material)), bsdf, conversion)

    return build


def _gltf_build(material: Material, suffix: str, settings: dict) -> Exported:
    from fitlab.export.gltf_material import gltf_export, gltf_text

    doc, conversion = gltf_export(material, progress=bool(settings.get("progress")))
    return Exported(gltf_text(doc), doc, conversion)


def _materialx_build(material: Material, suffix: str, settings: dict) -> Exported:
    from fitlab.export.materialx import materialx_export

    text, doc, conversion = materialx_export(material, progress=bool(settings.get("progress")))
    return Exported(text, doc, conversion)


def _materialx_with_check(made: Exported, check: dict) -> str:
    from fitlab.export.materialx import text_with_check

    return text_with_check(made.text, check)


def _openmaterial_build(material: Material, suffix: str, settings: dict) -> Exported:
    from fitlab.export.openmaterial import export_parts

    return Exported(*export_parts(material, settings))


def _native(material):
    from fitlab.export.mitsuba import native_bsdf

    return native_bsdf(material)


def _plugin(material):
    from fitlab.export.mitsuba import plugin_bsdf

    return plugin_bsdf(material)


EXPORTERS: Registry[Exporter] = Registry("export format", {
    e.name: e for e in (
        Exporter("mitsuba", "Mitsuba 3",
                 "Mitsuba 3's own plugins (roughconductor, roughdielectric, diffuse, plastic, "
                 "blendbsdf for sums): scene XML (.xml) or the mi.load_dict dictionary (.json); "
                 "refused for models Mitsuba has no plugin for",
                 (".xml", ".json"), "data_formats/mitsuba_export.md", _mitsuba_build(_native),
                 "rgb or spectrum"),
        Exporter("mitsuba-plugin", "Mitsuba 3 (fitlab plugin)",
                 "fitlab's Mitsuba plugin (fitlab.export.mitsuba_plugin.register()) with the model and its "
                 "values written out: any registry model, rendered with fitlab's own code",
                 (".xml", ".json"), "data_formats/mitsuba_export.md", _mitsuba_build(_plugin)),
        Exporter("gltf", "glTF 2.0",
                 "a glTF 2.0 metallic-roughness material (KHR_materials_ior, _specular, "
                 "_clearcoat where needed) fitted to the material over the hemisphere, on a "
                 "preview sphere; the conversion error is reported",
                 (".gltf",), "data_formats/gltf_material.md", _gltf_build),
        Exporter("openmaterial", "ASAM OpenMATERIAL 3D",
                 "a BRDF look-up table (.xompt) of the material's f on the standard grid at its "
                 "channels' wavelengths (<N>nm), the same file as fitlab convert FIT.json "
                 "OUT.xompt (which also takes --grid-from and the header's flags)",
                 (".xompt",), "data_formats/openmaterial_xompt.md", _openmaterial_build,
                 "spectrum"),
        Exporter("materialx", "MaterialX (OpenPBR Surface)",
                 "a MaterialX 1.39 document with one open_pbr_surface: a fit of the openpbr "
                 "model written as it is, any other material converted to OpenPBR by least "
                 "squares (the conversion error is reported); validated by the materialx "
                 "package",
                 (".mtlx",), "data_formats/materialx_export.md", _materialx_build,
                 with_check=_materialx_with_check),
    )
})


def exporter_for(to: str | None, out: str | None) -> tuple[Exporter, str]:
    """The exporter named ``to`` (else the one whose suffix ``out`` has; .xml/.json go to
    ``mitsuba``) and the suffix to write."""
    suffix = Path(out).suffix.lower() if out else ""
    if to is None:
        for e in EXPORTERS.values():
            if suffix in e.suffixes:
                return e, suffix
        raise ExportError(f"cannot tell the export format from {out!r}: give --to "
                          f"{'|'.join(EXPORTERS)} or an output ending in "
                          f"{', '.join(sorted({s for e in EXPORTERS.values() for s in e.suffixes}))}")
    if to not in EXPORTERS:
        raise ExportError(str(EXPORTERS.unknown(to)))
    e = EXPORTERS[to]
    if out is None:
        return e, e.suffixes[0]
    if suffix not in e.suffixes:
        raise ExportError(f"{out}: a {e.title} export is written as "
                          f"{' or '.join(e.suffixes)}; change the output's suffix")
    return e, suffix


def material_of(fit=None, *, model: str | None = None, params: dict | None = None,
                options: dict | None = None, channel: str | None = None) -> Material:
    """The material of a fit (a :class:`fitlab.FitResult` or a parameter file's path) or of
    registry ``model`` with ``params`` ({name: value}, or {channel: {name: value}} for R, G, B)
    and ``options``."""
    from fitlab.export.material import material_from_fit, material_from_model

    if (fit is None) == (model is None):
        raise ExportError("give a fit (FIT.json) or a model with its parameters, not both")
    if fit is not None:
        if params or options:
            raise ExportError("a fit brings its own parameters and options; to change them, "
                              "export the model (--model NAME --param ...)")
        if not hasattr(fit, "record"):
            from fitlab.fitting.result import load_fit

            fit = load_fit(fit)
        return material_from_fit(fit, channel)
    params = dict(params or {})
    channels = params if params and all(isinstance(v, dict) for v in params.values()) \
        else {"Y": params}
    if channel is not None:
        if channel not in channels:
            raise ExportError(f"no channel {channel!r}; channels: {', '.join(channels)}")
        channels = {channel: channels[channel]}
    return material_from_model(model, channels, options)


def spectral_for(exporter: Exporter, material: Material,
                 illuminant: str | None = None) -> tuple[Material, dict]:
    """The material ``exporter`` writes for ``material`` and what that conversion did: a
    spectral material reduced to linear sRGB (fitlab.export.material.rgb_material) where the
    exporter takes RGB, its spectrum kept where it takes spectra (and, for "rgb or spectrum",
    where the bands do not span the visible range: said in ``warnings``); any other material
    as it is."""
    from fitlab.export.material import material_bands, rgb_material

    unused = {} if illuminant is None else {"warnings": [
        f"--illuminant {illuminant}: not used (only a spectral fit reduced to RGB uses it)"]}
    if illuminant is not None:
        from fitlab.export.spectral_colour import check_illuminant

        try:
            check_illuminant(illuminant)
        except ValueError as exc:
            raise ExportError(f"--illuminant: {exc}") from None
    bands = material_bands(material)
    if bands is None or exporter.spectra == "spectrum":
        return material, unused
    if exporter.spectra == "rgb or spectrum" and bands.coverage_problem() is not None:
        return material, {"warnings": unused.get("warnings", []) + [
            f"spectral material with no colour ({bands.coverage_problem()}): written as "
            f"{exporter.title} spectra, which a spectral variant renders as they are and an "
            "RGB variant integrates over the bands given only"]}
    return rgb_material(material, illuminant, what=f"{exporter.title} ({exporter.name})")


def export_material(fit=None, to: str | None = None, out=None, *, model: str | None = None,
                    params: dict | None = None, options: dict | None = None,
                    channel: str | None = None, preview: bool = False,
                    check: bool | str = False, progress: bool = False,
                    illuminant: str | None = None) -> Exported:
    """Export a fit (or ``model`` with ``params``/``options``) for a renderer: format ``to``
    (:data:`EXPORTERS`; else from ``out``'s suffix). With ``out`` the file is written
    atomically; the :class:`Exported` holds its text, the object (Mitsuba dict, glTF document)
    and the conversion figures. ``preview``: a Mitsuba scene around the material (a sphere,
    an environment and a sun).

    ``check``: a renderer evaluates the export on 120 fixed goniometer pairs and
    ``conversion["check"]`` holds how far its values are from the material's (relative RMS,
    largest relative difference, what was compared and what the figure means:
    fitlab.export.check). Mitsuba 3 checks the Mitsuba exports; three.js (headless Chromium)
    checks a glTF file, else Mitsuba with glTF's specified BRDF of the file's values;
    MaterialX's own GLSL for the document, run in Mesa's OpenGL, checks a MaterialX file. ``True``
    (or ``"auto"``) takes the first that can run, ``"three"`` or ``"mitsuba"`` names one. When
    none can, ExportError says what to install, before anything is built or written; the file
    is written only after its check ran.

    A spectral fit (channels that are wavelengths spanning 380-780 nm) goes to a format that
    takes RGB as its reduction to linear sRGB (data_formats/fit_json.md, "Colour of a spectral
    fit"): colours from their spectra under ``illuminant`` (a colour-science name; None: the one
    the fit's colour block states, else D65), other parameters their one value or
    luminance-weighted mean; ``conversion["colour"]`` says what was done. OpenMATERIAL keeps
    the bands; narrower bands are refused by RGB-only formats and kept as spectra by Mitsuba."""
    from fitlab.io.atomic import atomic_write_text

    exporter, suffix = exporter_for(to, None if out is None else str(out))
    renderer = None
    if check:
        from fitlab.export.check import renderer_for

        renderer = renderer_for(exporter.name, "auto" if check is True else str(check))
    material = material_of(fit, model=model, params=params, options=options, channel=channel)
    material, spectral = spectral_for(exporter, material, illuminant)
    if material.source != "model":  # how the file names its source: never an absolute path
        from fitlab.io.files import path_for_record

        material = material._replace(source=path_for_record(material.source, out)
                                     if out is not None else Path(material.source).name)
    made = exporter.build(material, suffix, {"preview": preview, "progress": progress})
    if spectral:
        conv = dict(made.conversion)
        conv["warnings"] = list(conv.get("warnings", ())) + spectral.get("warnings", [])
        if "colour" in spectral:
            conv["colour"] = spectral["colour"]
        made = made._replace(conversion=conv)
    if renderer is not None:
        from fitlab.export.check import run_check

        check = run_check(exporter.name, renderer, material, made)
        made = made._replace(conversion={**made.conversion, "check": check})
        if exporter.with_check is not None:
            made = made._replace(text=exporter.with_check(made, check))
    if out is not None:
        atomic_write_text(out, made.text)
    return made


__all__ = ["EXPORTERS", "Exported", "Exporter", "exporter_for", "export_material",
           "material_of", "spectral_for"]
