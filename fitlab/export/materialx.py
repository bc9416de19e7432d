"""MaterialX export of a material as an OpenPBR Surface (``open_pbr_surface``, MaterialX 1.39),
and its check in MaterialX's own GLSL (data_formats/materialx_export.md).

- A fit (or a model) of the registry model that MaterialX's ``open_pbr_surface`` evaluates (the
  model that declares the translation ``("materialx", "open_pbr_surface")``:
  fitlab/models/openpbr.py) is written as it is: every input it fits with its value, colours as
  ``color3`` of the R, G, B channels (a grey fit repeats its one value), the scalars one value
  for every channel (a fit of R, G, B that did not share them is refused, with what to do).
- Any other material is *converted*: the OpenPBR model is fitted to it by least squares on the
  glTF export's direction pairs (fitlab/export/gltf_material.py, ``fit_conversion``: the same
  synthetic measurement, log loss, starts and error figures), with ``base_color`` per channel,
  the other inputs shared, ``base_weight``, ``specular_weight``, ``specular_color``,
  ``coat_color``, ``coat_darkening``, ``coat_ior`` and the fuzz at the spec's defaults; with
  and without the coat (kept when it lowers the error by more than 10 %). The conversion error
  (relative RMS and largest difference of f·cos θo, albedos, lobe-image PSNR/SSIM) goes in the
  record and is printed.

The inputs fitlab's model leaves out (thin film, transmission, subsurface, emission, opacity,
thin-walled, anisotropy) are written at the values under which MaterialX's graph is fitlab's
f: weights 0, opacity 1, ``geometry_thin_walled`` false, anisotropies 0.

The check (``fitlab export --to materialx --check``): MaterialX's GLSL generator
(``MaterialXGenGlsl``) turns the written document, read back and validated against MaterialX's
standard libraries, into a vertex and a pixel shader with one directional light, no
environment light and no shadows; Mesa's OpenGL (headless through EGL, via moderngl: the
renderer of tests/lut/test_lut_glsl.py) runs them on fitlab's virtual goniometer
(fitlab.export.check.check_geometries: 120 pairs, one 1 × 1 viewport per pair, the light from
wi, the viewer toward wo), and each pixel, f(wi, wo)·cos θi as MaterialX computes it, is
compared with fitlab's evaluation of the values read from the file.
"""

from __future__ import annotations

import numpy as np

from fitlab.export.material import ExportError, Material
from fitlab.version import __version__

#: The MaterialX node this export writes, and the translation a model declares for it.
NODE = "open_pbr_surface"
RENDERER = "materialx"
#: The materialx package versions the export is written and checked with.
MATERIALX_RANGE = ("1.39.4", "1.40")
INSTALL = ("pip install 'materialx>=1.39.4,<1.40' moderngl (or pip install 'fitlab[materialx]'),"
           " and Mesa's EGL (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1)")
#: The document's element names.
SHADER_NAME = "SR_fitlab"
MATERIAL_NAME = "M_fitlab"
#: Inputs of open_pbr_surface that fitlab's model leaves out, at the values under which the
#: graph evaluates fitlab's f (data_formats/materialx_export.md, "Inputs fitlab does not fit").
LEFT_OUT = (("specular_roughness_anisotropy", "float", 0.0),
            ("transmission_weight", "float", 0.0),
            ("subsurface_weight", "float", 0.0),
            ("coat_roughness_anisotropy", "float", 0.0),
            ("thin_film_weight", "float", 0.0),
            ("emission_luminance", "float", 0.0),
            ("geometry_opacity", "float", 1.0),
            ("geometry_thin_walled", "boolean", False))
#: What the conversion fit holds at the spec's defaults (the others are fitted).
CONVERSION_FIXED = {"base_weight": 1.0, "specular_weight": 1.0, "specular_color": 1.0,
                    "coat_color": 1.0, "coat_darkening": 1.0, "coat_ior": 1.6,
                    "fuzz_weight": 0.0, "fuzz_color": 1.0, "fuzz_roughness": 0.5}
#: A coat is kept when it lowers the conversion's relative RMS by more than this fraction.
COAT_GAIN = 0.10
#: The check's floor: pairs where fitlab's value is above this fraction of its largest.
CHECK_FLOOR = 1e-6


# ------------------------------------------------------------------------------------------
# The model MaterialX evaluates, asked of the registry
# ------------------------------------------------------------------------------------------


def openpbr_model():
    """The registry model that declares the translation (``materialx``, ``open_pbr_surface``)."""
    from fitlab.models import MODELS

    for m in MODELS.values():
        if m.translation(RENDERER) == NODE:
            return m
    raise ExportError(f"no registry model evaluates MaterialX's {NODE}")  # pragma: no cover


def colour_inputs(model) -> tuple[str, ...]:
    """The model's parameters that are colours (one value per channel): the albedo role."""
    return tuple(p.name for p in model.parameters_with_role("albedo"))


# ------------------------------------------------------------------------------------------
# What can run here
# ------------------------------------------------------------------------------------------


def materialx_missing() -> str | None:
    """Why the materialx package cannot write and validate here (None: it can)."""
    try:
        import MaterialX as mx
    except ImportError as exc:
        return f"the materialx package is not installed ({exc})"
    v = tuple(int(x) for x in mx.__version__.split(".")[:3])
    lo = tuple(int(x) for x in MATERIALX_RANGE[0].split("."))
    hi = tuple(int(x) for x in MATERIALX_RANGE[1].split("."))
    if not lo <= v < hi:
        return (f"materialx {mx.__version__} is installed; fitlab writes and checks MaterialX "
                f"{MATERIALX_RANGE[0]} to below {MATERIALX_RANGE[1]}")
    return None


def gl_context(install: str = INSTALL):
    """A headless OpenGL 3.3+ context of Mesa through EGL (moderngl), or ExportError saying
    what to install (``install``). The LUT shaders' tests (tests/lut/test_lut_glsl.py) run in
    it too."""
    try:
        import moderngl
    except ImportError as exc:
        raise ExportError(f"--check cannot run: moderngl is not installed ({exc}); "
                          f"install {install}") from None
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # noqa: BLE001 - no EGL / no Mesa driver: moderngl raises plainly
        raise ExportError(f"--check cannot run: no headless OpenGL through EGL ({exc}); "
                          f"install {install}") from None
    if ctx.version_code < 330:
        ctx.release()
        raise ExportError(f"--check cannot run: OpenGL {ctx.version_code} < 3.3 here")
    return ctx


def check_missing() -> str | None:
    """Why the MaterialX GLSL check cannot run here (None: it can)."""
    why = materialx_missing()
    if why is not None:
        return why
    try:
        gl_context().release()
    except ExportError as exc:
        return str(exc).removeprefix("--check cannot run: ")
    return None


# ------------------------------------------------------------------------------------------
# Parameters: direct or converted
# ------------------------------------------------------------------------------------------


def _rgb(material: Material, name: str) -> list[float]:
    return [float(v) for v in material.values(name)]


def direct_inputs(material: Material) -> dict:
    """{input: value or RGB list} of a material of the OpenPBR model itself: colours per
    channel, every other parameter one value (refused when the channels differ)."""
    model = openpbr_model()
    colours = colour_inputs(model)
    return {p.name: _rgb(material, p.name) if p.name in colours
            else material.scalar(p.name, what="MaterialX's open_pbr_surface")
            for p in model.parameters}


def converted(material: Material, *, seed: int = 0, progress: bool = False):
    """({input: value or RGB}, conversion figures) of the OpenPBR model fitted to
    ``material`` (fitlab.export.gltf_material.fit_conversion)."""
    from fitlab.export.gltf_material import conversion_warnings, fit_conversion

    model = openpbr_model()
    per_channel = colour_inputs(model)
    without_coat = dict(CONVERSION_FIXED, coat_weight=0.0, coat_roughness=0.1)
    name, params, errors = fit_conversion(
        material, ((model.name, without_coat), (model.name, CONVERSION_FIXED)),
        per_channel=("base_color",), gain=COAT_GAIN, label="openpbr", what="OpenPBR",
        seed=seed, progress=progress)
    first = next(iter(params.values()))
    from fitlab.models import get_model

    warnings = conversion_warnings(material, name, errors, params, what="OpenPBR",
                                   ordinary=_ORDINARY)
    if get_model(material.model).capabilities.transmission:
        warnings.append(f"{material.model} transmits light and the OpenPBR export holds "
                        "reflection only (transmission is left out): the transmitted side "
                        "counts in the conversion error as missing")
    inputs = {p.name: [float(params[c][p.name]) for c in params] * (3 if len(params) == 1
                                                                     else 1)
              if p.name in per_channel else float(first[p.name]) for p in model.parameters}
    conversion = {"converted": True, "target_title": "OpenPBR", "fitted": params, **errors,
                  "warnings": warnings,
                  "summary": f"OpenPBR ({NODE}) fitted to {material.model} on "
                  f"{errors['fit_pairs']} direction pairs (log loss), errors over "
                  f"{errors['pairs']}; SSIM of the lobe images "
                  + ", ".join(f"{v['ssim']:.3f} at {t}°"
                              for t, v in errors["lobe_images"].items())}
    return inputs, conversion


#: OpenPBR inputs whose bounds are ordinary ends of a conversion (shares, weights, colours).
_ORDINARY = {"base_weight", "base_color", "base_metalness", "base_diffuse_roughness",
             "specular_weight", "specular_color", "coat_weight", "coat_color", "coat_darkening",
             "fuzz_weight", "fuzz_color"}


# ------------------------------------------------------------------------------------------
# The document
# ------------------------------------------------------------------------------------------


def _fmt(v: float) -> str:
    return format(float(v), ".9g")


def document_text(material: Material, inputs: dict, conversion: dict) -> str:
    """The .mtlx text: one ``open_pbr_surface`` with every input of the model and the
    left-out ones, one ``surfacematerial``; fitlab's provenance in comments. Deterministic."""
    lines = ['<?xml version="1.0"?>', '<materialx version="1.39">',
             f"  <!-- fitlab {__version__} export of {_xml_comment(material.model)} from "
             f"{_xml_comment(material.source)} (channels {','.join(material.channels)}); "
             "spec: data_formats/materialx_export.md -->"]
    if conversion.get("converted"):
        lines.append(f"  <!-- converted by least squares: relative RMS of f cos "
                     f"{conversion['relative_rms']:.4g}, largest "
                     f"{conversion['relative_max']:.4g} over {conversion['pairs']} pairs -->")
    lines.append(f'  <{NODE} name="{SHADER_NAME}" type="surfaceshader">')
    for name, value in inputs.items():
        if isinstance(value, list):
            lines.append(f'    <input name="{name}" type="color3" value="'
                         + ", ".join(_fmt(v) for v in value) + '" />')
        else:
            lines.append(f'    <input name="{name}" type="float" value="{_fmt(value)}" />')
    for name, kind, value in LEFT_OUT:
        text = ("true" if value else "false") if kind == "boolean" else _fmt(value)
        lines.append(f'    <input name="{name}" type="{kind}" value="{text}" />')
    lines += [f"  </{NODE}>",
              f'  <surfacematerial name="{MATERIAL_NAME}" type="material">',
              f'    <input name="surfaceshader" type="surfaceshader" nodename="{SHADER_NAME}" />',
              "  </surfacematerial>", "</materialx>", ""]
    return "\n".join(lines)


def _xml_comment(text: str) -> str:
    return str(text).replace("--", "- -")


def _library():
    import MaterialX as mx

    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def load_document(text: str, source: str = "the MaterialX document"):
    """The document of ``text`` with MaterialX's standard libraries imported, validated
    (``doc.validate()``); ExportError with MaterialX's message otherwise."""
    import MaterialX as mx

    doc = mx.createDocument()
    try:
        mx.readFromXmlString(doc, text)
    except Exception as exc:  # noqa: BLE001 - MaterialX raises its own ExceptionParseError
        raise ExportError(f"{source}: MaterialX cannot read it: {exc}") from None
    doc.importLibrary(_library())
    ok, message = doc.validate()
    if not ok:
        raise ExportError(f"{source}: MaterialX {mx.__version__} does not validate it: "
                          f"{message.strip()}")
    return doc


def read_inputs(doc, source: str = "the MaterialX document") -> dict:
    """{input: value (float, or a list for a color3)} of the document's first
    ``open_pbr_surface`` node, defaults of its nodedef where an input is not written."""
    nodes = [n for n in doc.getNodes() if n.getCategory() == NODE]
    if not nodes:
        raise ExportError(f"{source} has no {NODE} node")
    node = nodes[0]
    out = {}
    for inp in node.getNodeDef().getActiveInputs():
        given = node.getInput(inp.getName())
        port = given if given is not None else inp
        text, kind = port.getValueString(), port.getType()
        if not text:
            continue
        # parsed from the text (MaterialX's own values are float32)
        if kind == "boolean":
            out[inp.getName()] = text.strip() == "true"
        elif kind == "float":
            out[inp.getName()] = float(text)
        elif kind == "color3":
            out[inp.getName()] = [float(x) for x in text.split(",")]
    return out


def material_of_document(doc, source: str = "the MaterialX document") -> Material:
    """The OpenPBR material (R, G, B) of the document's values, read as MaterialX reads them;
    refused where the document uses what fitlab's model leaves out."""
    from fitlab.export.material import material_from_model

    values = read_inputs(doc, source)
    for name, kind, neutral in LEFT_OUT:
        if name in values and values[name] != neutral:
            raise ExportError(f"{source}: {name} = {values[name]}: fitlab's OpenPBR model "
                              f"leaves {name} out (it evaluates {name} = {neutral})")
    model = openpbr_model()
    channels = {}
    for k, c in enumerate("RGB"):
        channels[c] = {p.name: float(values[p.name][k]) if isinstance(values[p.name], list)
                       else float(values[p.name]) for p in model.parameters}
    return material_from_model(model.name, channels)._replace(source=source)


def materialx_export(material: Material, *, seed: int = 0, progress: bool = False):
    """(document text, the validated MaterialX document, conversion record) of ``material``."""
    from fitlab.models import get_model

    why = materialx_missing()
    if why is not None:
        raise ExportError(f"the MaterialX export needs the materialx package: {why}; install "
                          f"{INSTALL}")
    if material.wavelengths_nm is not None:
        raise ExportError(f"{material.source}: MaterialX's color3 inputs take linear RGB, not "
                          f"the spectrum {', '.join(material.channels)}; export one band with "
                          "--channel")
    if get_model(material.model).translation(RENDERER) == NODE:
        inputs = direct_inputs(material)
        conversion = {"converted": False, "target_title": "OpenPBR",
                      "summary": f"{material.model}'s values written as {NODE} inputs (no "
                      "conversion)"}
    else:
        inputs, conversion = converted(material, seed=seed, progress=progress)
    conversion["node"] = NODE
    conversion["spec"] = "data_formats/materialx_export.md"
    text = document_text(material, inputs, conversion)
    doc = load_document(text, "the MaterialX export")
    return text, doc, conversion


# ------------------------------------------------------------------------------------------
# The check: MaterialX's GLSL in Mesa's OpenGL on the goniometer
# ------------------------------------------------------------------------------------------


def glsl_shaders(doc) -> tuple[str, str, dict]:
    """(vertex, pixel) GLSL that MaterialX's GlslShaderGenerator makes of the document's
    shader, for one directional light (light type 1), no environment, shadow or occlusion,
    and what was generated (generator, options)."""
    import MaterialX as mx
    import MaterialX.PyMaterialXGenGlsl as mx_glsl
    import MaterialX.PyMaterialXGenShader as mx_gen

    gen = mx_glsl.GlslShaderGenerator.create()
    ctx = mx_gen.GenContext(gen)
    ctx.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    opts = ctx.getOptions()
    opts.hwSpecularEnvironmentMethod = \
        mx_gen.HwSpecularEnvironmentMethod.SPECULAR_ENVIRONMENT_NONE
    opts.hwMaxActiveLightSources = 1
    opts.hwShadowMap = False
    opts.hwAmbientOcclusion = False
    opts.hwSrgbEncodeOutput = False
    light = doc.getNodeDef("ND_directional_light")
    mx_gen.HwShaderGenerator.bindLightShader(light, 1, ctx)
    node = [n for n in doc.getNodes() if n.getCategory() == NODE][0]
    shader = gen.generate("fitlab_check", node, ctx)
    vertex = shader.getSourceCode(mx_gen.VERTEX_STAGE)
    pixel = shader.getSourceCode(mx_gen.PIXEL_STAGE)
    # MaterialX 1.39's generator uses u_refractionTwoSided in mx_surface_transmission without
    # declaring it when no environment is generated; the transmission it guards is weighted 0
    if "u_refractionTwoSided" in pixel and "uniform bool u_refractionTwoSided" not in pixel:
        head, rest = pixel.split("\n", 1)
        pixel = f"{head}\nuniform bool u_refractionTwoSided = false;\n{rest}"
    albedo = "analytic" if "#define DIRECTIONAL_ALBEDO_METHOD 0" in pixel else "other"
    return vertex, pixel, {"generator": f"MaterialXGenGlsl {mx.__version__} "
                           f"({gen.getTarget()} target)", "directional_albedo": albedo}


def render_goniometer(doc, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, dict]:
    """(N, 3) pixels of MaterialX's GLSL for ``doc`` at the pairs (one directional light of
    intensity 1 from wi, the viewer toward wo, normal +z, tangent +x) and what rendered."""
    vertex, pixel, generated = glsl_shaders(doc)
    ctx = gl_context()
    made = []
    try:
        prog = ctx.program(vertex_shader=vertex, fragment_shader=pixel)
        made.append(prog)
        n = wi.shape[0]
        target = ctx.texture((n, 1), 4, dtype="f4")
        fbo = ctx.framebuffer(color_attachments=[target])
        # one triangle over the viewport; at the pixel's centre the surface point is the origin
        verts = np.array([[-1, -1, 0, 0, 0, 1, 1, 0, 0], [3, -1, 0, 0, 0, 1, 1, 0, 0],
                          [-1, 3, 0, 0, 0, 1, 1, 0, 0]], np.float32)
        vbo = ctx.buffer(verts.tobytes())
        vao = ctx.vertex_array(prog, [(vbo, "3f 3f 3f", "i_position", "i_normal",
                                       "i_tangent")])
        made += [target, fbo, vbo, vao]
        fbo.use()
        prog["u_numActiveLightSources"] = 1
        prog["u_lightData[0].type"] = 1
        prog["u_lightData[0].color"] = (1.0, 1.0, 1.0)
        prog["u_lightData[0].intensity"] = 1.0
        for k in range(n):
            ctx.viewport = (k, 0, 1, 1)
            # MaterialX's directional light: L = -direction
            prog["u_lightData[0].direction"] = tuple(float(x) for x in -wi[k])
            prog["u_viewPosition"] = tuple(float(x) for x in wo[k])
            vao.render()
        out = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(-1, 4)
        info = ctx.info
        renderer = (f"{generated['generator']} in {info['GL_RENDERER']} "
                    f"({info['GL_VERSION']}, headless EGL)")
    finally:
        for obj in reversed(made):
            obj.release()
        ctx.release()
    return out[:, :3].astype(np.float64), {**generated, "renderer": renderer}


#: What the check compares and what its figure means (fitlab.export.check.check_materialx).
COMPARED = ("MaterialX's generated GLSL of the written document (one directional light per "
            "pair) against fitlab's f·cos θi of the OpenPBR values read from it")
MEANING = ("float32 rounding (~1e-5) where MaterialX's GLSL and the spec agree; more is "
           "MaterialX's departure from the spec: its EON diffuse clamps L·V to [1e-8, 1] (up "
           "to ~50 % at base_diffuse_roughness 0.7 where the directions are more than 90° "
           "apart) and its F82 metal Fresnel goes negative for a dark F0 with a dark "
           "specular_color (fitlab clamps it at 0); data_formats/materialx_export.md")


def text_with_check(text: str, check: dict) -> str:
    """The document ``text`` with the check's figure as a comment after fitlab's provenance."""
    line = (f"  <!-- fitlab --check: {_xml_comment(check['renderer'])} on {check['pairs']} "
            f"goniometer pairs: relative RMS {check['relative_rms']:.3g}, largest "
            f"{check['relative_max']:.3g} against fitlab's OpenPBR of these values")
    if "against_fit" in check:
        a = check["against_fit"]
        line += (f"; against the material exported: relative RMS {a['relative_rms']:.3g}, "
                 f"largest {a['relative_max']:.3g}")
    lines = text.split("\n")
    at = max(i for i, x in enumerate(lines) if x.startswith("  <!--")) + 1
    return "\n".join(lines[:at] + [line + " -->"] + lines[at:])


__all__ = ["NODE", "document_text", "load_document", "material_of_document", "materialx_export",
           "openpbr_model", "read_inputs", "render_goniometer", "text_with_check"]
