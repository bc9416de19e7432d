"""Proof by rendering: fitlab's Mitsuba 3 exports (native plugins and fitlab's own plugin)
rendered by Mitsuba (``llvm_ad_rgb``) in a virtual goniometer and a white furnace.

* Goniometer (fitlab.export.mitsuba_plugin.goniometer_scene): a plane with the exported BSDF, a directional
  emitter of irradiance 1 from wi, an orthographic sensor from wo, the ``direct`` integrator.
  Emitter sampling of a directional light is exact, so each pixel is f(wi, wo)·cos θi up to
  float32 rounding (the render has no noise here): the criterion is 2e-5 relative (a few float32
  ulps over the BSDF's arithmetic) for exact translations, and the measured difference for the
  two approximate ones (plastic and roughplastic use Mitsuba's fitted F_dr polynomial).
* Furnace (fitlab.export.mitsuba_plugin.furnace_scene): the plugin under a constant environment of radiance
  1, one bounce; the mean pixel value equals fitlab's albedo (mean sample weight of fitlab's
  own sampler over 400,000 samples) within 4 standard errors of the render (its pixels are
  independent estimates) plus that of the reference.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import skip_or_fail

import fitlab
from fitlab.export.material import ExportError, material_from_fit, material_from_model
from fitlab.export.mitsuba import native_bsdf, plugin_bsdf, scene_xml

pytestmark = pytest.mark.mitsuba

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]
FITS = ROOT / "fits"


@pytest.fixture(scope="module")
def fm():
    try:
        import mitsuba as mi
    except ImportError:
        skip_or_fail("mitsuba is not installed (pip install -e '.[test]')")
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception as exc:  # noqa: BLE001 - Mitsuba reports a missing libLLVM this way
        skip_or_fail(f"Mitsuba's llvm_ad_rgb variant needs libLLVM (apt-get install "
                     f"libllvm19): {exc}")
    from fitlab.export import mitsuba_plugin as fm

    fm.register()
    return fm


def _dirs(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


#: Reflection geometries (θi, φi, θo, φo) in degrees: normal incidence, the plane of
#: incidence, off-plane, grazing view and light.
REFLECTION = np.array([(0, 0, 0.01, 0), (0, 0, 40, 30), (30, 0, 25, 180), (30, 0, 50, 120),
                       (60, 0, 58, 175), (75, 0, 10, 270), (45, 40, 82, 200)], float)
#: Transmission (light from below, camera above).
TRANSMISSION = np.array([(150, 0, 40, 180), (170, 0, 5, 90), (140, 0, 60, 180)], float)


def _geometry(table):
    return _dirs(table[:, 0], table[:, 1]), _dirs(table[:, 2], table[:, 3])


def _expected(material, wi, wo):
    """f(wi, wo)·|cos θi| per channel (N, 3) from fitlab in float64."""
    cols = [np.asarray(fitlab.eval_bsdf(material.model, p, wi, wo, material.options))
            * np.abs(wi[:, 2]) for p in material.channels.values()]
    cols = cols * 3 if len(cols) == 1 else cols
    return np.stack(cols, axis=-1)


def _rel(a, b):
    return np.abs(a - b) / np.maximum(np.abs(b), 1e-6 * np.max(np.abs(b)))


NATIVE_CASES = {
    "rough_conductor ggx": ("rough_conductor", {"Y": {"alpha": 0.3, "n": 0.2, "k": 3.9}}, {}),
    "rough_conductor beckmann_rational": (
        "rough_conductor", {"Y": {"alpha": 0.15, "n": 1.5, "k": 0.3}},
        {"distribution": "beckmann_rational"}),
    "rough_conductor_anisotropic": (
        "rough_conductor_anisotropic", {"Y": {"alpha_x": 0.05, "alpha_y": 0.4, "n": 0.2,
                                              "k": 3.9}}, {}),
    "rough_dielectric": ("rough_dielectric", {"Y": {"alpha": 0.25, "eta": 1.5}}, {}),
    "lambertian rgb": ("lambertian", {c: {"albedo": a} for c, a in zip("RGB", (0.8, 0.4, 0.1))},
                       {}),
    "lambertian+rough_conductor rgb": (
        "lambertian+rough_conductor",
        {c: {"albedo": a, "alpha": 0.2, "n": n, "k": 3.0}
         for c, a, n in zip("RGB", (0.6, 0.3, 0.2), (0.3, 0.5, 1.1))}, {}),
    "two lobes": ("lambertian+rough_conductor+rough_conductor",
                  {"Y": {"albedo": 0.3, "alpha": 0.05, "n": 1.5, "k": 0.0, "alpha_2": 0.4,
                         "n_2": 1.2, "k_2": 0.0}}, {}),
}


def _render_case(fm, case, make_bsdf):
    """(rendered, expected) f·cos θi of ``case`` = (model, channels, options) on the reflection
    geometries (and the transmission ones for a transmitting model)."""
    model, channels, options = case
    material = material_from_model(model, channels, options)
    table = REFLECTION
    if fitlab.get_model(model).capabilities.transmission:
        table = np.concatenate([REFLECTION, TRANSMISSION])
    wi, wo = _geometry(table)
    return fm.goniometer(make_bsdf(material), wi, wo), _expected(material, wi, wo)


@pytest.mark.parametrize("case", list(NATIVE_CASES))
def test_native_export_renders_fitlab_values(fm, case):
    rendered, expected = _render_case(fm, NATIVE_CASES[case], native_bsdf)
    assert np.all(expected[:, 1] > 0), "every geometry must test a non-zero value"
    err = _rel(rendered, expected)
    assert err.max() < 2e-5, (case, err.max(), rendered, expected)


def test_plastic_export_conversion_error(fm):
    """coated(lambertian) with the closed-form interreflection and a clear coat is Mitsuba's
    plastic up to Mitsuba's fitted F_dr polynomial (the internal diffuse reflectance, which
    fitlab integrates); the measured figure (4.5e-4 at ρ = 0.6, η = 1.5) is printed and
    bounded."""
    name = "coated(lambertian)"
    params = {"albedo": 0.6, "coat_eta": 1.5, "coat_tau": 0.0}
    material = material_from_model(name, {"Y": params}, {"interreflection": "closed_form"})
    wi, wo = _geometry(REFLECTION)
    rendered = fm.goniometer(native_bsdf(material), wi, wo)
    expected = _expected(material, wi, wo)
    err = _rel(rendered, expected)
    print(f"{name} -> {native_bsdf(material)['type']}: relative difference median "
          f"{np.median(err):.3g}, max {err.max():.3g}")
    assert err.max() < 2e-3


PLUGIN_CASES = {
    "rough_conductor": ("rough_conductor", {"Y": {"alpha": 0.3, "n": 0.2, "k": 3.9}}, {}),
    "rough_dielectric transmission": ("rough_dielectric", {"Y": {"alpha": 0.25, "eta": 1.5}},
                                      {}),
    "oren_nayar rgb": ("oren_nayar", {c: {"albedo": a, "sigma": 0.5}
                                      for c, a in zip("RGB", (0.7, 0.5, 0.2))}, {}),
    "coated single bounce": ("coated(lambertian)", {"Y": {"albedo": 0.5, "coat_eta": 1.5,
                                                          "coat_tau": 0.3}}, {}),
    "thin layer": ("thin_layer(rough_conductor)",
                   {"Y": {"kappa1": 300.0, "eta": 1.5, "tau": 0.2, "kappa2": 30.0, "n2": 0.2,
                          "k2": 3.9}}, {}),
    "spongecake with the learned lobe": (
        "spongecake(surface,multiple=learned)",
        {"Y": {"alpha1": 0.3, "theta_p1": 0.0, "phi_p1": 0.0, "albedo1": 0.8, "f0_1": 1.0,
               "tau1": 1.0}}, {}),
}


#: Cases whose model costs 7-9 s to compile for the plugin (the thin layer's masking integrals,
#: the learned lobe's budget tables): the whole suite runs them; the plugin's code path is the
#: same for every model, and the quick tier keeps the others.
SLOW_PLUGIN_CASES = {"thin layer", "spongecake with the learned lobe"}


@pytest.mark.parametrize("case", [pytest.param(c, marks=[pytest.mark.slow] * (c in SLOW_PLUGIN_CASES))
                                  for c in PLUGIN_CASES])
def test_plugin_renders_fitlab_values(fm, case):
    rendered, expected = _render_case(fm, PLUGIN_CASES[case], plugin_bsdf)
    err = _rel(rendered, expected)
    assert err.max() < 2e-5, (case, err.max())


@pytest.mark.parametrize("fit", ["brown_vinyl_weidlich_wilkie_lambert.json",
                                 "rgl_aurora_white_weidlich_wilkie_lambert.json"])
def test_plugin_renders_layered_fit(fm, fit):
    """A layered model without a Mitsuba equivalent (Weidlich–Wilkie), named by its fit file;
    the RGB fit renders each channel with its own parameters."""
    result = fitlab.load_fit(FITS / fit)
    material = material_from_fit(result)
    wi, wo = _geometry(REFLECTION)
    rendered = fm.goniometer({"type": "fitlab", "fit": str(FITS / fit)}, wi, wo)
    expected = _expected(material, wi, wo)
    assert np.all(expected > 0)
    err = _rel(rendered, expected)
    assert err.max() < 2e-5, (fit, err.max())
    if material.rgb:  # the channels differ, and the render keeps them apart
        assert np.ptp(expected, axis=1).min() > 1e-3 * expected.max()


def _fitlab_albedo(material, wo, n=400_000, seed=1):
    """Mean sample weight of fitlab's sampler from ``wo`` (reciprocal BRDF: the albedo that
    the furnace pixel seen from wo estimates) and its standard error, per channel."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 3))
    means, ses = [], []
    for p in material.channels.values():
        _, w, _ = fitlab.sample_bsdf(material.model, p, np.broadcast_to(wo, (n, 3)), u,
                                     material.options)
        w = np.asarray(w)
        means.append(w.mean())
        ses.append(w.std(ddof=1) / np.sqrt(n))
    return np.array(means), np.array(ses)


@pytest.mark.parametrize("theta_o", [0.0, 60.0])
def test_plugin_furnace_matches_fitlab_albedo(fm, theta_o):
    import mitsuba as mi

    result = fitlab.load_fit(FITS / "brown_vinyl_weidlich_wilkie_lambert.json")
    material = material_from_fit(result)
    assert fitlab.get_model(material.model).capabilities.reciprocal
    wo = _dirs(np.array([theta_o]), np.array([0.0]))[0]
    scene = mi.load_dict(fm.furnace_scene({"type": "fitlab",
                                           "fit": str(FITS / result.path.split("/")[-1])},
                                          wo, spp=64, pixels=16))
    pixels = fm.render(scene, seed=3).reshape(-1, 3)[:, 0]
    rendered, se = pixels.mean(), pixels.std(ddof=1) / np.sqrt(pixels.size)
    albedo, se_ref = _fitlab_albedo(material, wo)
    z = (rendered - albedo[0]) / np.hypot(se, se_ref[0])
    print(f"furnace θo={theta_o}: Mitsuba {rendered:.5f} ± {se:.5f}, fitlab "
          f"{albedo[0]:.5f} ± {se_ref[0]:.5f}, z = {z:.2f}")
    assert abs(z) < 4.0


def test_scene_xml_loads_and_renders_like_the_dict(fm):
    import mitsuba as mi

    material = material_from_model("lambertian+rough_conductor",
                                   {"Y": {"albedo": 0.4, "alpha": 0.2, "n": 0.2, "k": 3.9}})
    bsdf = native_bsdf(material)
    scene = mi.load_string(scene_xml(bsdf, preview=True))
    assert len(scene.shapes()) == 1 and len(scene.emitters()) == 2
    loaded = scene.shapes()[0].bsdf()
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0.3, 0.1, float(np.sqrt(1 - 0.1)))
    wo = mi.Vector3f(-0.2, 0.0, float(np.sqrt(1 - 0.04)))
    ctx = mi.BSDFContext()
    direct = mi.load_dict(bsdf)
    assert np.allclose(np.array(loaded.eval(ctx, si, wo)), np.array(direct.eval(ctx, si, wo)),
                       rtol=1e-6)


@pytest.mark.parametrize("model,channels,options,needle", [
    ("oren_nayar", {"Y": {"albedo": 0.5, "sigma": 0.3}}, {}, "no plugin that evaluates"),
    ("rough_conductor", {"Y": {"alpha": 0.2, "n": 0.2, "k": 3.9}},
     {"distribution": "beckmann"}, "distribution=beckmann"),
    ("rough_conductor", {"Y": {"alpha": 0.2, "n": 0.2, "k": 3.9}}, {"fresnel": "schlick"},
     "fresnel=schlick"),
    ("rough_dielectric", {"Y": {"alpha": 0.2, "eta": 1.5}}, {"fresnel": "schlick"},
     "fresnel=schlick"),
    ("rough_conductor", {c: {"alpha": a, "n": 0.2, "k": 3.9} for c, a in
                         zip("RGB", (0.1, 0.2, 0.3))}, {}, "--share alpha"),
    ("coated(lambertian)", {"Y": {"albedo": 0.5, "coat_eta": 1.5, "coat_tau": 0.0}}, {},
     "interreflection=single"),
    ("coated(lambertian)", {"Y": {"albedo": 0.5, "coat_eta": 1.5, "coat_tau": 0.5}},
     {"interreflection": "closed_form"}, "coat_tau > 0"),
    ("coated(lambertian,specular=lobe)", {"Y": {"albedo": 0.5, "coat_eta": 1.5,
                                                "coat_tau": 0.0, "coat_alpha": 0.1}},
     {"interreflection": "closed_form"}, "roughplastic"),
    ("weidlich_wilkie(lambertian)", {"Y": {"alpha1": 0.2, "n1": 1.5, "k1": 0.0, "tau1": 0.0,
                                           "albedo2": 0.5}}, {}, "mitsuba-plugin"),
])
def test_native_export_refuses_what_mitsuba_cannot_represent(model, channels, options, needle):
    material = material_from_model(model, channels, options)
    with pytest.raises(ExportError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        native_bsdf(material)


def test_examples_load_and_the_invalid_one_is_refused(fm):
    """data_formats/examples: the plugin example renders (its preview scene, 4 spp), the native
    one too; the invalid one (alpha1 = 5) fails to load with fitlab's message."""
    import mitsuba as mi

    ex = ROOT / "data_formats" / "examples"
    for name in ("mitsuba_aurora_white.xml", "mitsuba_plugin_brown_vinyl.xml"):
        image = fm.render(mi.load_file(str(ex / name)), spp=4)
        assert image.shape == (256, 256, 3) and np.isfinite(image).all() and image.mean() > 0.05
    with pytest.raises(Exception, match=r"alpha1=5.0 of 'weidlich_wilkie\(lambertian\)' is "
                                        r"outside its bounds"):
        mi.load_file(str(ex / "mitsuba_plugin_invalid.xml"))


def test_plugin_fit_is_found_relative_to_the_scene(fm, tmp_path):
    """A scene naming its fit by a relative path loads from any working directory (Mitsuba's
    file resolver has the scene's folder)."""
    import shutil

    import mitsuba as mi

    (tmp_path / "scene").mkdir()
    shutil.copy(FITS / "walter_rough_glass.json", tmp_path / "scene" / "glass.json")
    xml = scene_xml({"type": "fitlab", "fit": "glass.json"}, preview=True)
    (tmp_path / "scene" / "s.xml").write_text(xml, encoding="utf-8")
    scene = mi.load_file(str(tmp_path / "scene" / "s.xml"))
    assert "rough_dielectric" in str(scene.shapes()[0].bsdf())


def test_cli_check_renders_the_export(capsys, tmp_path, fm):
    from fitlab.cli import main

    code = main(["export", str(FITS / "brown_vinyl_lambert_ggx_conductor.json"), "--out",
                 str(tmp_path / "v.xml"), "--check"])
    err = capsys.readouterr().err
    assert code == 0, err
    line = [x for x in err.splitlines() if x.startswith("check:")][0]
    rms = float(line.split("relative RMS ")[1].split(",")[0])
    assert "120 goniometer pairs" in line and rms < 2e-5
    assert "meaning: an exact translation is within float32 rounding" in err


def test_gltf_check_through_mitsuba(fm):
    """The glTF check without three.js (fitlab.export.check): the material read back from the
    file and rendered by Mitsuba with glTF's specified BRDF (fitlab's plugin); for a material
    that is glTF's own BRDF the figure is float32 rounding."""
    from fitlab.export.check import run_check
    from fitlab.export.gltf_material import gltf_document, gltf_text
    from fitlab.export.renderers import Exported

    d = {q.name: q.default for q in fitlab.get_model("gltf_pbr_anisotropic").parameters}
    channels = {c: {**d, "base_color": b, "metallic": 1.0, "roughness_factor": 0.4,
                    "anisotropy_strength": 0.5, "anisotropy_rotation": 20.0}
                for c, b in zip("RGB", (0.9, 0.6, 0.3))}
    material = material_from_model("gltf_pbr_anisotropic", channels)
    doc = gltf_document(material, "gltf_pbr_anisotropic", channels, {})
    c = run_check("gltf", "mitsuba", material, Exported(gltf_text(doc), doc, {}))
    assert c["renderer"].startswith("Mitsuba 3.9") and "gltf_pbr_anisotropic" in c["renderer"]
    assert c["pairs"] == 120 and c["relative_max"] < 2e-5, c


@pytest.mark.slow
def test_report_hand_off_section(fm, tmp_path):
    """fitlab report --renderers: the table of exports with their measured conversion errors
    (the native refusal included) and the Mitsuba preview figure."""
    import re

    from fitlab.cli import main

    assert main(["report", str(FITS / "brown_vinyl_weidlich_wilkie_lambert.json"), "--out",
                 str(tmp_path / "r"), "--renderers", "--quiet"]) == 0
    page = (tmp_path / "r" / "index.html").read_text(encoding="utf-8")
    section = page[page.index('id="renderers"'):]
    assert "refused" in section and "mitsuba-plugin" in section
    rms = re.search(r"Mitsuba 3 \(fitlab plugin\)</td><td>bsdf type fitlab</td><td>([0-9.e+-]+) /",
                    section)
    assert rms and float(rms.group(1)) < 2e-5
    png = (tmp_path / "r" / "renderer_preview.png").read_bytes()
    assert png.startswith(b"\x89PNG")


SPECTRAL_CHECK = r"""
import json, sys
import numpy as np
import mitsuba as mi
mi.set_variant("scalar_spectral")
import fitlab
from fitlab.export.material import material_from_model
from fitlab.export.mitsuba import native_bsdf, scene_xml
ch = {f"{w}nm": {"albedo": a, "alpha": 0.2, "n": n, "k": k}
      for w, a, n, k in [(450, 0.1, 1.4, 1.9), (550, 0.3, 0.4, 2.4), (650, 0.6, 0.2, 3.5)]}
m = material_from_model("lambertian+rough_conductor", ch)
d = native_bsdf(m)
from_json = mi.load_dict(json.loads(json.dumps(d)))
from_xml = mi.load_string(scene_xml(d, preview=True)).shapes()[0].bsdf()
wi = np.array([0.3, 0.1, np.sqrt(0.9)]); wo = np.array([-0.2, 0.05, np.sqrt(1 - 0.0425)])
si = mi.SurfaceInteraction3f()
si.wi = mi.Vector3f(*map(float, wo))
worst = 0.0
for w in (450, 550, 650):
    si.wavelengths = mi.Spectrum([w] * 4)
    ref = float(fitlab.eval_bsdf(m.model, ch[f"{w}nm"], wi, wo)) * wi[2]
    for b in (from_json, from_xml):
        v = b.eval(mi.BSDFContext(), si, mi.Vector3f(*map(float, wi)))[0]
        worst = max(worst, abs(v - ref) / ref)
print(json.dumps({"worst": worst, "eta": d["bsdf_1"]["eta"]["type"]}))
"""


def test_spectral_fit_exports_mitsuba_spectra(fm):
    """Channels <λ>nm become Mitsuba ``spectrum`` values (dict and XML) that a spectral
    variant evaluates to fitlab's f·cos θ at each wavelength (in a child process: the variant is
    process-wide)."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", SPECTRAL_CHECK], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["eta"] == "spectrum" and got["worst"] < 2e-5, got


@pytest.mark.parametrize("model,channels", [
    ("rough_conductor", {"Y": {"alpha": 0.2, "n": 0.2, "k": 3.9}}),
    ("lambertian+rough_conductor", {c: {"albedo": a, "alpha": 0.1, "n": 1.5, "k": 0.0}
                                    for c, a in zip("RGB", (0.7, 0.4, 0.2))}),
])
def test_plugin_image_equals_native_image(fm, model, channels):
    """The preview sphere lit by the sun alone, direct lighting by emitter sampling (no BSDF
    sampling: each pixel is deterministic for a seed), rendered with the native export and with
    the plugin: the two images agree to float32 (scikit-image PSNR and SSIM)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    from fitlab.export.mitsuba import preview_scene

    material = material_from_model(model, channels)
    images = []
    for bsdf in (native_bsdf(material), plugin_bsdf(material)):
        scene = preview_scene(bsdf, resolution=64, spp=4)
        del scene["environment"]
        scene["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}
        images.append(fm.render(fm.load_scene(scene), seed=0))
    a, b = images
    assert a.max() > 0.05
    rng = float(a.max())
    psnr = peak_signal_noise_ratio(a, b, data_range=rng)
    ssim = structural_similarity(a, b, data_range=rng, channel_axis=-1)
    print(f"{model}: plugin vs native image PSNR {psnr:.1f} dB, SSIM {ssim:.6f}")
    assert psnr > 80.0 and ssim > 0.99999
