"""The glTF export's conversion (fitlab/export/gltf_material.py): glTF's BRDF fitted to a
material, the errors it reports, the document it writes, refusals. Rendering the files in a
browser and the validator: tests/export/test_gltf_browser.py."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.export.gltf_material import conversion_errors, convert, gltf_export, gltf_text
from fitlab.export.material import ExportError, material_from_model
from fitlab.io.validate import check_schema

ROOT = Path(__file__).resolve().parents[2]


def _gltf_material(values, model="gltf_pbr"):
    d = {q.name: q.default for q in fitlab.get_model(model).parameters}
    return material_from_model(model, {"Y": {**d, **values}})


@pytest.mark.slow
def test_closed_loop_recovers_a_gltf_material():
    """A material that is glTF's own BRDF converts to itself: the fitted values equal the
    source's and the conversion error is ~0 (with specular_color at 1, which the export
    fixes)."""
    src = {"base_color": 0.35, "metallic": 0.0, "roughness_factor": 0.45, "ior": 1.7,
           "specular": 0.8}
    model, params, errors = convert(_gltf_material(src))
    assert model == "gltf_pbr"
    got = params["Y"]
    for k, v in src.items():
        assert got[k] == pytest.approx(v, rel=2e-3, abs=2e-3), (k, got[k], v)
    assert errors["relative_rms"] < 1e-4 and errors["relative_max"] < 1e-3
    for t, img in errors["lobe_images"].items():
        assert img["ssim"] > 0.9999 and (img["psnr_db"] is None or img["psnr_db"] > 60), (t, img)


@pytest.mark.slow  # 15-19 s of compilation; the quick tier converts a Lambertian (below)
def test_rough_conductor_converts_to_a_metal_with_a_small_error():
    mat = material_from_model("rough_conductor", {"Y": {"alpha": 0.09, "n": 0.2, "k": 3.9}})
    model, params, errors = convert(mat)
    p = params["Y"]
    assert p["metallic"] == 1.0
    assert p["roughness_factor"] == pytest.approx(0.3, abs=0.01)  # α = r² = 0.09
    from fitlab.fresnel import fresnel_conductor_exact

    assert p["base_color"] == pytest.approx(float(fresnel_conductor_exact(
        np.array(1.0), 0.2, 3.9)), abs=0.02)  # F0 of (n, k)
    assert errors["relative_rms"] < 0.02
    a = errors["albedo"]
    for t in ("0", "30", "60"):
        assert a[t]["gltf"][0] == pytest.approx(a[t]["material"][0], rel=0.02)


def test_lambertian_converts_to_a_rough_dielectric_base():
    mat = material_from_model("lambertian", {"Y": {"albedo": 0.6}})
    _, params, errors = convert(mat)
    p = params["Y"]
    assert p["metallic"] < 0.05
    # glTF's dielectric always has a specular layer: specular → 0 makes it Lambert
    assert p["specular"] < 0.05 and p["base_color"] == pytest.approx(0.6, rel=0.02)
    assert errors["relative_rms"] < 0.01


@pytest.mark.slow
def test_rgb_material_shares_the_geometry_and_document_is_deterministic(tmp_path):
    ch = {c: {"albedo": a, "alpha": 0.2, "n": 1.5, "k": 0.0}
          for c, a in zip("RGB", (0.6, 0.3, 0.1))}
    mat = material_from_model("lambertian+rough_conductor", ch)
    doc, conv = gltf_export(mat)
    again, _ = gltf_export(mat)
    assert gltf_text(doc) == gltf_text(again)
    m = doc["materials"][0]
    base = m["pbrMetallicRoughness"]["baseColorFactor"]
    assert base[0] > base[1] > base[2] and base[3] == 1.0
    fitted = conv["fitted"]
    for name in ("metallic", "roughness_factor", "ior", "specular"):
        assert len({fitted[c][name] for c in "RGB"}) == 1, name
    assert m["extras"]["fitlab"]["source_model"] == "lambertian+rough_conductor"
    check_schema(m["extras"]["fitlab"], "gltf_material", "the RGB export")  # its JSON Schema
    assert set(doc.get("extensionsUsed", [])) == set(m.get("extensions", {}))
    assert conv["relative_rms"] < 0.1
    print(f"lambertian+rough_conductor RGB -> glTF: relative RMS {conv['relative_rms']:.3g}, "
          f"max {conv['relative_max']:.3g}")


@pytest.mark.slow
def test_cli_writes_gltf_and_reports_the_error(tmp_path, capsys):
    from fitlab.cli import main

    out = tmp_path / "vinyl.gltf"
    assert main(["export", str(ROOT / "fits" / "brown_vinyl_lambert_ggx_conductor.json"),
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "glTF conversion error: relative RMS" in err
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["asset"]["version"] == "2.0"
    src = doc["materials"][0]["extras"]["fitlab"]["source"]
    assert not Path(src).is_absolute() and src.endswith("brown_vinyl_lambert_ggx_conductor.json")


@pytest.mark.parametrize("model,channels,needle", [
    ("rough_dielectric", None, "reflects"),
    ("rough_conductor", {f"{w}nm": {"alpha": 0.2, "n": 0.2, "k": 3.9} for w in (450, 550)},
     "spectrum"),
])
def test_refusals(model, channels, needle):
    if channels is None:  # a BTDF: make the model transmission-only by its capabilities
        from fitlab.models.base import Capabilities, Model

        base = fitlab.get_model(model)
        only_t = Model(**{**base._asdict(), "name": "btdf_only",
                          "capabilities": Capabilities(reflection=False, transmission=True)})
        fitlab.register_model(only_t, replace=True)
        try:
            with pytest.raises(ExportError, match=needle):
                convert(material_from_model("btdf_only", {"Y": {"alpha": 0.2, "eta": 1.5}}))
        finally:
            from fitlab.models import MODELS

            MODELS.unregister("btdf_only")
        return
    with pytest.raises(ExportError, match=needle):
        convert(material_from_model(model, channels))


def test_errors_are_measured_against_the_material():
    """conversion_errors of a material against itself (glTF's BRDF with its own values) is 0,
    and against other values is not: the figures can fail."""
    values = {"base_color": 0.3, "metallic": 0.0, "roughness_factor": 0.4}
    mat = _gltf_material(values)
    same = conversion_errors(mat, "gltf_pbr", mat.channels)
    assert same["relative_rms"] == 0.0 and same["lobe_images"]["30"]["ssim"] == 1.0
    assert same["lobe_images"]["30"]["psnr_db"] is None  # identical: infinite PSNR
    other = {"Y": {**mat.channels["Y"], "roughness_factor": 0.6}}
    off = conversion_errors(mat, "gltf_pbr", other)
    assert off["relative_rms"] > 0.1 and off["lobe_images"]["30"]["ssim"] < 0.999
    assert off["lobe_images"]["30"]["psnr_db"] < 60


@pytest.mark.slow
def test_anisotropic_conductor_converts_with_khr_materials_anisotropy():
    """α_x = 0.05, α_y = 0.3: the anisotropy direction is +y (rotation -90°), α = r² = α_x and
    α_t = mix(α, 1, s²) = α_y."""
    mat = material_from_model("rough_conductor_anisotropic",
                              {"Y": {"alpha_x": 0.05, "alpha_y": 0.3, "n": 0.2, "k": 3.9}})
    doc, conv = gltf_export(mat)
    p = conv["fitted"]["Y"]
    assert conv["gltf_model"] == "gltf_pbr_anisotropic"
    a = p["roughness_factor"] ** 2
    assert a == pytest.approx(0.05, rel=0.05)
    assert a + (1 - a) * p["anisotropy_strength"] ** 2 == pytest.approx(0.3, rel=0.05)
    assert abs(abs(p["anisotropy_rotation"]) - 90.0) < 1.0
    ext = doc["materials"][0]["extensions"]["KHR_materials_anisotropy"]
    assert ext["anisotropyRotation"] == pytest.approx(np.radians(p["anisotropy_rotation"]))
    assert "TANGENT" in doc["meshes"][0]["primitives"][0]["attributes"]
    check_schema(doc["materials"][0]["extras"]["fitlab"], "gltf_material", "the export")
    assert conv["relative_rms"] < 0.03 and not conv["warnings"]


@pytest.mark.slow
def test_refracting_dielectric_converts_with_a_warning():
    """A rough dielectric's BTDF refracts; glTF's thin-walled transmission cannot: the export
    keeps the transmitted energy (albedo) but warns with the measured distance."""
    mat = material_from_model("rough_dielectric", {"Y": {"alpha": 0.2, "eta": 1.5}})
    doc, conv = gltf_export(mat)
    assert conv["gltf_model"] == "gltf_pbr_transmission"
    assert "KHR_materials_transmission" in doc["materials"][0]["extensions"]
    check_schema(doc["materials"][0]["extras"]["fitlab"], "gltf_material", "the export")
    a = conv["albedo"]["30"]
    assert a["gltf_transmitted"][0] == pytest.approx(a["material_transmitted"][0], rel=0.1)
    assert conv["relative_rms"] > 0.25 and any("thin-walled" in w for w in conv["warnings"])


@pytest.mark.parametrize("model,values", [
    ("gltf_pbr", {"base_color": 0.35, "metallic": 0.2, "roughness_factor": 0.45, "ior": 1.7,
                  "specular": 0.8}),
    ("gltf_pbr_clearcoat", {"base_color": 0.6, "roughness_factor": 0.6, "clearcoat": 0.7,
                            "clearcoat_roughness_factor": 0.2}),
    ("gltf_pbr_anisotropic", {"base_color": 0.9, "metallic": 1.0, "roughness_factor": 0.3,
                              "anisotropy_strength": 0.6, "anisotropy_rotation": 30.0}),
    ("gltf_pbr_transmission", {"base_color": 0.5, "roughness_factor": 0.35,
                               "transmission": 0.6}),
])
def test_check_reads_the_material_back_from_the_file(model, values):
    """What `fitlab export --check` renders without three.js (fitlab.export.check.gltf_material):
    the file's material read as a glTF renderer reads it, extensions and defaults, equals the
    values the document was written from (the rotation back from radians)."""
    from fitlab.export.check import gltf_material
    from fitlab.export.gltf_material import gltf_document

    mat = _gltf_material(values, model)
    doc = json.loads(gltf_text(gltf_document(mat, model, mat.channels, {})))
    back = gltf_material(doc)
    assert back.model == model and tuple(back.channels) == ("R", "G", "B")
    for c in "RGB":
        assert back.channels[c] == pytest.approx(mat.channels["Y"], rel=1e-12, abs=1e-12)
