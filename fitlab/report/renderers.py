"""The report's hand-off section (``fitlab report --renderers``): each renderer export of the
fit (fitlab.export.renderers), what it cost in accuracy, and a Mitsuba 3 render of the material
on a sphere beside the fit.

Conversion errors: a Mitsuba export is rendered on the virtual goniometer (120 direction pairs,
fitlab.export.mitsuba_plugin.conversion_error) and compared with fitlab's f·cos θi; a glTF export reports the
error of its fit of glTF's BRDF to the material (fitlab.export.gltf). Refused exports show why.
"""

from __future__ import annotations

import numpy as np

from fitlab.report.html import paragraph, table_html

#: The preview render: pixels on a side, samples per pixel, Mitsuba seed.
PREVIEW_RESOLUTION = 160
PREVIEW_SPP = 64
PREVIEW_SEED = 0


def _fmt(x) -> str:
    return "n/a" if x is None else f"{float(x):.3g}"


def _srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function of linear values clipped to [0, 1] (IEC 61966-2-1)."""
    c = np.clip(linear, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def _preview_figure(image: np.ndarray, title: str):
    from fitlab.report.style import new_figure

    fig = new_figure(4.2, 4.4)
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(_srgb(image), interpolation="nearest")
    ax.set_title(title, fontsize=8)
    ax.set_xlabel("image x (pixels)")
    ax.set_ylabel("image y (pixels)")
    return fig


def renderers_section(rep, fit_path) -> str:
    """HTML of the hand-off section (figures added to ``rep``)."""
    from fitlab.fitting.result import load_fit
    from fitlab.export.material import ExportError
    from fitlab.export.renderers import EXPORTERS, material_of, spectral_for

    result = load_fit(fit_path)
    try:
        material = material_of(result)
    except ExportError as exc:
        return paragraph(f"No renderer export: {str(exc)}")
    try:
        from fitlab.export import mitsuba_plugin as fm

        variant = fm.ensure_variant()
    except ImportError:
        fm = variant = None
    rows, preview_bsdf = [], None
    for e in EXPORTERS.values():
        rep.say(f"report: export {e.name}")
        try:  # a spectral fit: its colour block's RGB where the format takes RGB
            written, _ = spectral_for(e, material)
            made = e.build(written, e.suffixes[0], {})
        except ExportError as exc:
            rows.append([e.title, "refused", "", str(exc)])
            continue
        conv = dict(made.conversion)
        if e.name.startswith("mitsuba"):
            if fm is None:
                rows.append([e.title, f"bsdf type {conv['translation']}", "n/a",
                             "Mitsuba 3 is not installed (pip install 'fitlab[mitsuba]'): not "
                             "rendered"])
                continue
            g = fm.conversion_error(written, made.value)
            if preview_bsdf is None:
                preview_bsdf = (e.title, made.value)
            rows.append([e.title, f"bsdf type {conv['translation']}",
                         f"{_fmt(g['relative_rms'])} / {_fmt(g['relative_max'])}",
                         f"rendered by {g['renderer']} on {g['pairs']} goniometer pairs "
                         "(f·cos θi against fitlab)"])
        else:
            rows.append([e.title, conv.get("what", "fitted glTF material"),
                         f"{_fmt(conv.get('relative_rms'))} / {_fmt(conv.get('relative_max'))}",
                         conv.get("summary", "glTF's BRDF fitted to the material over the "
                                             "hemisphere (data_formats/gltf_material.md)")])
    body = paragraph(
        "What the fit becomes in each renderer format of fitlab export, and the "
        "conversion error: relative RMS / largest relative difference of f·cos θi between the "
        "export and fitlab's model (the fit's relative-data scale is not applied). "
        "Specs: data_formats/mitsuba_export.md, data_formats/gltf_material.md.")
    body += table_html(["format", "export", "conversion error (RMS / max)", "how measured"],
                       rows)
    if preview_bsdf is not None:
        from fitlab.export.mitsuba import preview_scene

        title, bsdf = preview_bsdf
        rep.say(f"report: Mitsuba preview ({PREVIEW_RESOLUTION}² pixels, {PREVIEW_SPP} spp)")
        scene = fm.load_scene(preview_scene(bsdf, resolution=PREVIEW_RESOLUTION,
                                            spp=PREVIEW_SPP))
        image = fm.render(scene, seed=PREVIEW_SEED)
        fig = _preview_figure(image, f"{material.model} ({title}, {variant})")
        body += rep.figure(
            "renderer_preview", fig,
            f"The fitted material rendered by Mitsuba 3 ({variant}, {title} export): a "
            "unit sphere under a white environment of radiance 0.2 and a directional light of "
            f"irradiance 2 from θ = 45°, φ = 30°, path tracing, {PREVIEW_SPP} samples per "
            "pixel; linear radiance clipped to [0, 1] and sRGB-encoded, no tone mapping.",
            f"Mitsuba render of the fitted {material.model} material on a sphere")
    return body


__all__ = ["renderers_section"]
