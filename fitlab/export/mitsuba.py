"""Mitsuba 3 exports of a material (fitlab/export/material.py): the plugin dictionary a scene
takes (``mi.load_dict``) and the scene XML (``mi.load_file``), with Mitsuba's native plugins
where one evaluates the same f, else fitlab's own plugin (``fitlab.export.mitsuba_plugin.register()``).

The native translations (data_formats/mitsuba_export.md has the full table and conventions):

* ``rough_conductor`` / ``_anisotropic`` → ``roughconductor`` (alpha or alpha_u/alpha_v,
  eta = n, k; GGX, or Beckmann with Walter's rational G1 = fitlab's ``beckmann_rational``);
* ``rough_dielectric`` / ``_anisotropic`` → ``roughdielectric`` (int_ior = η, ext_ior = 1);
* ``lambertian`` → ``diffuse``;
* ``coated(lambertian)`` with the closed-form interreflection and a clear coat (τ = 0) →
  ``plastic`` with ``nonlinear: true``, Mitsuba's 1/(1 − ρ F_dr) series (F_dr from Mitsuba's
  fitted polynomial: 4.5e-4 relative at ρ = 0.6, η = 1.5). Its ``specular=lobe`` form is not
  Mitsuba's ``roughplastic`` (up to 12.5 % apart) and is refused;
* a sum f = Σ f_k → nested ``blendbsdf`` of the components f_k / w_k with weights w_k (Σ w_k =
  1; :func:`blend_weights`: a diffuse reflectance must stay ≤ 1, a Fresnel-weighted lobe takes
  ``specular_reflectance`` = 1/w_k).

Everything else (Oren–Nayar, exact-erf Beckmann, Phong, non-exact Fresnel, Weidlich–Wilkie,
the thin layer, SpongeCake, a coat that absorbs or bounces once) has no native equivalent and
is refused with that said; :func:`plugin_bsdf` renders it with fitlab's own eval/sample/pdf.

Mitsuba's eval includes |cos θo| and its radiance-mode arguments are swapped relative to
fitlab's; both are the renderer's business once the plugin values are right (CONVENTIONS.md,
MITSUBA_MAPPING.md). Nothing here imports Mitsuba.
"""

from __future__ import annotations

from typing import Callable
from xml.sax.saxutils import quoteattr

import numpy as np

from fitlab.export.material import ExportError, Material

#: fitlab distribution option → Mitsuba ``distribution`` (Mitsuba's Beckmann uses Walter's
#: rational G1, eq. 27: fitlab's ``beckmann_rational``).
DISTRIBUTIONS = {"ggx": "ggx", "beckmann_rational": "beckmann"}

PLUGIN_HINT = ("export it for fitlab's Mitsuba plugin instead (fitlab export ... --to "
               "mitsuba-plugin), which renders the model with fitlab's own eval, sample and pdf")


def _num(x: float) -> float:
    """A plain Python float (shortest repr round-trips: same input, same bytes); a material of
    many texels (fitlab/export/maps.py) keeps its array over the texels."""
    return float(x) if np.ndim(x) == 0 else np.asarray(x, dtype=float)


def _alike(flags) -> bool:
    """``flags`` as one bool: a material of many texels must agree at every texel (else the
    translation's form would change from texel to texel, refused)."""
    flags = np.asarray(flags, dtype=bool)
    if flags.ndim and flags.any() != flags.all():
        raise ExportError("Mitsuba's translation of the model changes form from texel to texel")
    return bool(flags.all())


def _spectrum(material: Material, values) -> float | dict:
    """One number when the channels agree, else Mitsuba's ``rgb`` value or, for a spectral
    material, its ``spectrum`` of (wavelength in nm, value) pairs."""
    v = np.asarray(values, dtype=float)
    if _alike(np.ptp(v, axis=0) == 0.0):
        return _num(v[0])
    wl = material.wavelengths_nm
    if wl is not None:
        return {"type": "spectrum", "value": [(_num(w), _num(x)) for w, x in zip(wl, v)]}
    return {"type": "rgb", "value": [_num(x) for x in v]}


def _refuse(model: str, why: str):
    raise ExportError(f"{model} has no Mitsuba 3 native equivalent: {why}; {PLUGIN_HINT}")


def _distribution(material: Material, option: str = "distribution") -> str:
    d = material.options.get(option, "ggx")
    if d not in DISTRIBUTIONS:
        _refuse(material.model, f"distribution={d} (Mitsuba has ggx and beckmann with Walter's "
                "rational G1, fitlab's ggx and beckmann_rational)")
    return DISTRIBUTIONS[d]


def _exact_fresnel(material: Material, option: str = "fresnel") -> None:
    f = material.options.get(option, "exact")
    if f != "exact":
        _refuse(material.model, f"fresnel={f} (Mitsuba uses the exact Fresnel equations)")


def _widths(material: Material, what: str) -> dict:
    if "alpha" in material.channels[next(iter(material.channels))]:
        return {"alpha": _num(material.scalar("alpha", what=what))}
    return {"alpha_u": _num(material.scalar("alpha_x", what=what)),
            "alpha_v": _num(material.scalar("alpha_y", what=what))}


def _rough_conductor(material: Material, scale: float = 1.0) -> dict:
    _exact_fresnel(material)
    out = {"type": "roughconductor", "distribution": _distribution(material),
           **_widths(material, "Mitsuba's roughconductor"),
           "eta": _spectrum(material, material.values("n")),
           "k": _spectrum(material, material.values("k")),
           "sample_visible": True}
    if _alike(np.not_equal(scale, 1.0)):
        out["specular_reflectance"] = _num(scale)
    return out


def _rough_dielectric(material: Material, scale: float = 1.0) -> dict:
    _exact_fresnel(material)
    out = {"type": "roughdielectric", "distribution": _distribution(material),
           **_widths(material, "Mitsuba's roughdielectric"),
           "int_ior": _num(material.scalar("eta", what="Mitsuba's roughdielectric (int_ior)")),
           "ext_ior": 1.0, "sample_visible": True}
    if _alike(np.not_equal(scale, 1.0)):
        out["specular_reflectance"] = _num(scale)
        out["specular_transmittance"] = _num(scale)
    return out


def _lambertian(material: Material, scale: float = 1.0) -> dict:
    return {"type": "diffuse",
            "reflectance": _spectrum(material, scale * material.values("albedo"))}


def _coated(material: Material, scale: float = 1.0) -> dict:
    """coated(lambertian) with the closed-form interreflection and τ = 0 is Mitsuba's plastic
    with ``nonlinear: true``: T(θi)T(θo)/η² ρ/π /(1 − ρ r)
    (coated.py, ``_closed_form_factor``); Mitsuba's r is its fitted F_dr polynomial, the source of
    the small difference the tests measure (data_formats/mitsuba_export.md)."""
    from fitlab.models import get_model

    model = get_model(material.model)
    inner = model.inner[0].model
    if model.argument("specular", "delta") == "lobe":
        _refuse(material.model, "its coat's GGX lobe sits on a diffuse term seen through the "
                "smooth coat's transmittance, where Mitsuba's roughplastic uses the rough coat's "
                "(they differ by up to 12.5 % at ρ = 0.6, η = 1.5, α = 0.1: "
                "data_formats/mitsuba_export.md)")
    if not inner.capabilities.lambertian:
        _refuse(material.model, f"Mitsuba's plastic has a Lambertian base, this one is "
                f"{inner.name}")
    if material.options.get("interreflection") != "closed_form":
        _refuse(material.model, "its coat keeps one bounce off the base "
                "(interreflection=single); Mitsuba's plastic sums every bounce (fit with "
                "--option interreflection=closed_form for a plastic)")
    if np.any(material.values("coat_tau") != 0.0):
        _refuse(material.model, "its coat absorbs (coat_tau > 0); Mitsuba's plastic coat is "
                "clear")
    if np.any(np.not_equal(scale, 1.0)):
        _refuse(material.model, "a plastic cannot be scaled inside a sum")
    albedo = inner.parameters_with_role("albedo")[0].name
    out = {"type": "plastic",
           "diffuse_reflectance": _spectrum(material, material.values(albedo)),
           "int_ior": _num(material.scalar("coat_eta", what="Mitsuba's plastic (int_ior)")),
           "ext_ior": 1.0, "nonlinear": True}
    return out


#: Mitsuba's plugins fitlab translates to, by the plugin a model declares it is
#: (``Model.translations``): plugin → translator(material, scale) → dict.
NATIVE: dict[str, Callable] = {
    "roughconductor": _rough_conductor,
    "roughdielectric": _rough_dielectric,
    "diffuse": _lambertian,
    "plastic": _coated,
}


def _component_materials(material: Material) -> list[Material] | None:
    """The components of a sum as materials of their own (None if ``material`` is no sum)."""
    from fitlab.models import get_model

    terms = get_model(material.model).terms
    if not terms:
        return None
    out = []
    for m, pn, on in terms:
        channels = {c: {p.name: v[n] for p, n in zip(m.parameters, pn)}
                    for c, v in material.channels.items()}
        options = {o.name: material.options[n] for o, n in zip(m.options, on)
                   if n in material.options}
        out.append(Material(m.name, options, channels, material.source,
                            wavelength_nm=material.wavelength_nm))
    return out


def _largest_scale(material: Material) -> float:
    """How far a component's own values can be scaled up inside a ``blendbsdf``: Mitsuba's RGB
    reflectances must stay within [0, 1] (``diffuse``), Fresnel-weighted plugins take any
    ``specular_reflectance``; a ``plastic`` cannot be scaled."""
    from fitlab.models import get_model

    model = get_model(material.model)
    if model.translation("mitsuba") not in NATIVE:
        return 1.0
    if model.capabilities.lambertian:
        top = np.max(material.values(model.parameters_with_role("albedo")[0].name), axis=0)
        if np.ndim(top) == 0:
            return np.inf if top == 0.0 else 1.0 / float(top)
        with np.errstate(divide="ignore"):
            return np.where(top == 0.0, np.inf, 1.0 / top)
    return np.inf


def blend_weights(parts: list[Material]) -> np.ndarray:
    """Weights w_k (Σ w_k = 1) of a sum's components in a blend: component k is scaled by
    1/w_k, so w_k ≥ 1/(its largest scale); what is left is shared by the components that can
    be scaled without limit (else in proportion to the smallest weights)."""
    largest = [_largest_scale(p) for p in parts]
    shape = np.broadcast(*largest).shape  # () or a material of many texels' (texels,)
    largest = np.array([np.broadcast_to(x, shape) for x in largest])
    w_min = 1.0 / largest
    left = 1.0 - w_min.sum(axis=0)
    if np.any(left < 0.0):
        raise ExportError(f"a blend of {' + '.join(p.model for p in parts)} would need "
                          "reflectances above 1 (the components reflect more than all light "
                          f"together); {PLUGIN_HINT}")
    free = ~np.isfinite(largest)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(free.any(axis=0), free / free.sum(axis=0),
                         np.where(w_min.sum(axis=0) > 0.0, w_min / w_min.sum(axis=0),
                                  1.0 / len(parts)))
    w = w_min + left * share
    if np.any(w <= 0.0):
        raise ExportError(f"a component of {' + '.join(p.model for p in parts)} would get no "
                          f"weight in Mitsuba's blendbsdf; {PLUGIN_HINT}")
    return w


def _translate(material: Material, scale: float = 1.0) -> dict:
    from fitlab.models import get_model

    parts = _component_materials(material)
    if parts is not None:
        w = blend_weights(parts)
        # f = Σ f_k = Σ w_k (f_k / w_k): nested blends, innermost the last two components;
        # blendbsdf's ``weight`` is that of its second child (1 − weight for the first).
        bsdf = _translate(parts[-1], scale / w[-1])
        for j in range(len(parts) - 2, -1, -1):
            rest = _num(w[j + 1:].sum(axis=0))
            bsdf = {"type": "blendbsdf", "weight": _num(rest / (w[j] + rest)),
                    "bsdf_0": _translate(parts[j], scale / w[j]), "bsdf_1": bsdf}
        return bsdf
    plugin = get_model(material.model).translation("mitsuba")
    if plugin in NATIVE:
        return NATIVE[plugin](material, scale)
    _refuse(material.model, "Mitsuba 3 has no plugin that evaluates this model")


def native_bsdf(material: Material) -> dict:
    """The Mitsuba 3 plugin dictionary (``mi.load_dict``) of ``material`` with Mitsuba's own
    plugins; :class:`ExportError` where Mitsuba has none that evaluates the same f."""
    return _translate(material)


#: Mitsuba reserves '.' in property names (object paths): the plugin's property names write
#: a '.' of fitlab's names (``lambertian.albedo`` in some sums) as this, and separate the
#: option and channel prefixes with it: ``option__distribution``, ``R__alpha``.
SEP = "__"


def plugin_property(name: str, channel: str | None = None, *, option: bool = False) -> str:
    """The plugin's property name of parameter ``name`` (of ``channel``) or of an option."""
    name = name.replace(".", SEP)
    if option:
        return f"option{SEP}{name}"
    return name if channel is None else f"{channel}{SEP}{name}"


def plugin_bsdf(material: Material, fit: str | None = None) -> dict:
    """The dictionary of fitlab's Mitsuba plugin (``fitlab.export.mitsuba_plugin.register()`` first): the fit
    file ``fit`` (a path as the scene should name it), or the model with its parameters and
    options written out (:func:`plugin_property`; RGB materials: ``R__alpha`` ...)."""
    if material.wavelengths_nm is not None:
        raise ExportError(f"{material.source}: fitlab's Mitsuba plugin renders grey or R, G, B, "
                          f"not the spectrum {', '.join(material.channels)}; export one "
                          "wavelength with --channel (or --to mitsuba, whose plugins take "
                          "spectra, where the model has one)")
    out = {"type": "fitlab"}
    if fit is not None:
        out["fit"] = str(fit)
        return out
    out["model"] = material.model
    for name, value in sorted(material.options.items()):
        out[plugin_property(name, option=True)] = str(value)
    rgb = len(material.channels) > 1
    for channel, params in material.channels.items():
        for name, value in params.items():
            out[plugin_property(name, channel if rgb else None)] = _num(value)
    return out


# ------------------------------------------------------------------------------------------
# Scenes: the material alone, or a preview (a sphere under an environment and a sun)
# ------------------------------------------------------------------------------------------

MATERIAL_ID = "material"


def preview_scene(bsdf: dict, *, resolution: int = 256, spp: int = 64,
                  light_deg: tuple[float, float] = (45.0, 30.0)) -> dict:
    """A scene dict: a unit sphere with ``bsdf`` under a constant white environment of radiance
    0.2 and a directional light of irradiance 2 from (θ, φ) = ``light_deg``, seen by a 30° camera
    from +z; ``path`` integrator. The same scene the report's preview renders."""
    theta, phi = np.radians(light_deg)
    to_light = [float(np.sin(theta) * np.cos(phi)), float(np.sin(theta) * np.sin(phi)),
                float(np.cos(theta))]
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "sensor": {"type": "perspective", "fov": 30.0,
                   "to_world": {"look_at": {"origin": [0.0, -4.2, 2.4], "target": [0.0, 0.0, 0.0],
                                            "up": [0.0, 0.0, 1.0]}},
                   "sampler": {"type": "independent", "sample_count": int(spp)},
                   "film": {"type": "hdrfilm", "width": int(resolution),
                            "height": int(resolution), "pixel_format": "rgb",
                            "rfilter": {"type": "box"}}},
        MATERIAL_ID: bsdf,
        "sphere": {"type": "sphere", "bsdf": {"type": "ref", "id": MATERIAL_ID}},
        "environment": {"type": "constant", "radiance": 0.2},
        "sun": {"type": "directional", "direction": [-x for x in to_light], "irradiance": 2.0},
    }


def _xml_value(name: str, value, indent: str) -> list[str]:
    if isinstance(value, bool):
        return [f'{indent}<boolean name={quoteattr(name)} value="{str(value).lower()}"/>']
    if isinstance(value, int):
        return [f'{indent}<integer name={quoteattr(name)} value="{value}"/>']
    if isinstance(value, float):
        return [f'{indent}<float name={quoteattr(name)} value="{value!r}"/>']
    if isinstance(value, str):
        return [f'{indent}<string name={quoteattr(name)} value={quoteattr(value)}/>']
    if isinstance(value, list):
        return [f'{indent}<vector name={quoteattr(name)} value="'
                + ", ".join(repr(float(v)) for v in value) + '"/>']
    if isinstance(value, dict) and value.get("type") == "spectrum":
        return [f'{indent}<spectrum name={quoteattr(name)} value="'
                + ", ".join(f"{float(w)!r}:{float(v)!r}" for w, v in value["value"]) + '"/>']
    if isinstance(value, dict) and value.get("type") == "rgb":
        return [f'{indent}<rgb name={quoteattr(name)} value="'
                + ", ".join(repr(float(v)) for v in value["value"]) + '"/>']
    if isinstance(value, dict) and value.get("type") == "ref":
        return [f'{indent}<ref id={quoteattr(value["id"])} name={quoteattr(name)}/>']
    if isinstance(value, dict) and "look_at" in value:
        la = value["look_at"]
        vec = lambda v: ", ".join(repr(float(x)) for x in v)  # noqa: E731
        return [f'{indent}<transform name={quoteattr(name)}>',
                f'{indent}    <lookat origin="{vec(la["origin"])}" target="{vec(la["target"])}" '
                f'up="{vec(la["up"])}"/>', f"{indent}</transform>"]
    if isinstance(value, dict) and _TAGS.get(value.get("type")) == "texture":
        return _xml_object(value, indent, name=name)  # a texture property is named
    if isinstance(value, dict):
        return _xml_object(value, indent)
    raise TypeError(f"no XML form for {name}={value!r}")


#: Mitsuba's XML tag of each plugin type a fitlab export or preview uses.
_TAGS = {"roughconductor": "bsdf", "roughdielectric": "bsdf", "diffuse": "bsdf",
         "plastic": "bsdf", "roughplastic": "bsdf", "blendbsdf": "bsdf", "fitlab": "bsdf",
         "path": "integrator", "direct": "integrator", "perspective": "sensor",
         "orthographic": "sensor", "independent": "sampler", "hdrfilm": "film", "box": "rfilter",
         "sphere": "shape", "rectangle": "shape", "constant": "emitter",
         "directional": "emitter", "bitmap": "texture"}


def _xml_object(obj: dict, indent: str, *, id: str | None = None,
                name: str | None = None) -> list[str]:
    kind = obj["type"]
    attrs = f" type={quoteattr(kind)}"
    if name is not None:
        attrs = f" name={quoteattr(name)}" + attrs
    if id is not None:
        attrs += f" id={quoteattr(id)}"
    tag = _TAGS.get(kind)
    if tag is None:
        raise TypeError(f"no XML tag known for Mitsuba plugin type {kind!r}")
    lines = [f"{indent}<{tag}{attrs}>"]
    for key, value in obj.items():
        if key != "type":
            lines += _xml_value(key, value, indent + "    ")
    return lines + [f"{indent}</{tag}>"]


def scene_xml(bsdf: dict, *, preview: bool = False, comment: str = "") -> str:
    """Mitsuba 3 scene XML (``version="3.0.0"``) declaring ``bsdf`` with ``id="material"``
    (reference it with ``<ref id="material"/>``); with ``preview``, the scene of
    :func:`preview_scene` around it."""
    scene = preview_scene(bsdf) if preview else {"type": "scene", MATERIAL_ID: bsdf}
    lines = ['<?xml version="1.0" encoding="utf-8"?>']
    if comment:
        lines.append("<!-- " + comment.replace("--", "- -") + " -->")
    lines.append('<scene version="3.0.0">')
    for key, value in scene.items():
        if key == "type":
            continue
        if isinstance(value, dict) and "type" in value:
            lines += _xml_object(value, "    ", id=key if key == MATERIAL_ID else None)
    lines.append("</scene>")
    return "\n".join(lines) + "\n"


__all__ = ["SEP", "plugin_property", "DISTRIBUTIONS", "NATIVE", "MATERIAL_ID", "native_bsdf",
           "plugin_bsdf", "preview_scene", "scene_xml"]
