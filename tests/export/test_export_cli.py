"""`fitlab export` and `fitlab.export_material` without a renderer: what the files hold, that
they are reproducible, atomic, umask-readable and free of absolute paths, and refusals with
exit status 2 that leave nothing behind. Rendering them is tests/export/test_mitsuba_render.py."""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import fitlab
from fitlab.cli import main
from fitlab.export.material import ExportError

ROOT = Path(__file__).resolve().parents[2]
FITS = ROOT / "fits"
EXAMPLES = ROOT / "data_formats" / "examples"


def _run(capsys, *argv):
    code = main(["export", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("example,fit,extra", [
    ("mitsuba_aurora_white.xml", "rgl_aurora_white_two_lobe_shared.json", ["--preview"]),
    ("mitsuba_plugin_brown_vinyl.xml", "brown_vinyl_weidlich_wilkie_lambert.json",
     ["--to", "mitsuba-plugin", "--preview"]),
])
def test_examples_are_what_the_command_writes(capsys, tmp_path, example, fit, extra):
    """The committed examples are reproduced byte for byte (written beside the examples, so the
    source fit is named by the same relative path)."""
    out = EXAMPLES / f"_test_{os.getpid()}_{example}"
    try:
        code, _, err = _run(capsys, FITS / fit, "--out", out, *extra)
        assert code == 0, err
        assert out.read_bytes() == (EXAMPLES / example).read_bytes()
    finally:
        out.unlink(missing_ok=True)


def test_xml_names_the_material_and_no_absolute_path(capsys, tmp_path):
    out = tmp_path / "vinyl.xml"
    code, _, err = _run(capsys, FITS / "brown_vinyl_lambert_ggx_conductor.json", "--out", out)
    assert code == 0, err
    text = out.read_text(encoding="utf-8")
    source = text.split(" from ", 1)[1].split(" ", 1)[0]  # the XML comment names the fit
    assert not Path(source).is_absolute() and source.endswith(
        "fits/brown_vinyl_lambert_ggx_conductor.json")
    assert (out.parent / source).resolve() == (FITS / "brown_vinyl_lambert_ggx_conductor.json")
    root = ET.fromstring(text)
    assert root.tag == "scene" and root.get("version") == "3.0.0"
    bsdf = root.find("bsdf")
    assert bsdf.get("id") == "material" and bsdf.get("type") == "blendbsdf"
    assert [b.get("type") for b in bsdf.findall("bsdf")] == ["diffuse", "roughconductor"]
    # f = albedo/π + f_ggx = w (albedo/w)/π + (1 - w) f_ggx/(1 - w): the blend's weight is the
    # second component's share, the diffuse reflectance the albedo over its share
    fit = fitlab.load_fit(FITS / "brown_vinyl_lambert_ggx_conductor.json").parameters["Y"]
    w = 1.0 - float(bsdf.find("float[@name='weight']").get("value"))
    refl = float(bsdf.find("bsdf[@type='diffuse']/float[@name='reflectance']").get("value"))
    spec = float(bsdf.find("bsdf[@type='roughconductor']/float[@name='specular_reflectance']")
                 .get("value"))
    assert refl * w == pytest.approx(fit["albedo"], rel=1e-12)
    assert spec * (1.0 - w) == pytest.approx(1.0, rel=1e-12)
    alpha = float(bsdf.find("bsdf[@type='roughconductor']/float[@name='alpha']").get("value"))
    assert alpha == fit["alpha"]  # the fit's value to the last bit


def test_same_fit_same_bytes_and_umask_mode(capsys, tmp_path):
    old = os.umask(0o027)
    try:
        for name in ("a.json", "b.json"):
            code, _, err = _run(capsys, FITS / "walter_rough_glass.json", "--out",
                                tmp_path / name)
            assert code == 0, err
    finally:
        os.umask(old)
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o640
    d = json.loads((tmp_path / "a.json").read_text())
    fit = fitlab.load_fit(FITS / "walter_rough_glass.json").parameters["Y"]
    assert d["type"] == "roughdielectric" and d["int_ior"] == fit["eta"]
    assert d["ext_ior"] == 1.0 and d["alpha"] == fit["alpha"]


def test_model_with_rgb_parameters(capsys, tmp_path):
    out = tmp_path / "m.json"
    code, _, err = _run(capsys, "--model", "lambertian+rough_conductor", "--param",
                        "albedo=0.5,0.4,0.3", "--param", "alpha=0.2", "--param",
                        "n=0.2,0.4,1.1", "--param", "k=3.9", "--out", out)
    assert code == 0, err
    d = json.loads(out.read_text())
    assert d["type"] == "blendbsdf"
    assert d["bsdf_1"]["eta"] == {"type": "rgb", "value": [0.2, 0.4, 1.1]}
    assert d["bsdf_1"]["k"] == 3.9  # equal channels: one number


def test_plugin_export_writes_every_parameter(capsys, tmp_path):
    out = tmp_path / "p.json"
    code, _, err = _run(capsys, FITS / "rgl_aurora_white_weidlich_wilkie_lambert.json", "--to",
                        "mitsuba-plugin", "--out", out)
    assert code == 0, err
    d = json.loads(out.read_text())
    fit = fitlab.load_fit(FITS / "rgl_aurora_white_weidlich_wilkie_lambert.json")
    assert d["type"] == "fitlab" and d["model"] == fit.model
    for channel, params in fit.parameters.items():
        for name, value in params.items():
            if name != "scale":
                assert d[f"{channel}__{name}"] == value
    assert "R__scale" not in d
    assert {k[len("option__"):]: v for k, v in d.items() if k.startswith("option__")} == \
        fit.options


@pytest.mark.parametrize("argv,needle", [
    (["{fits}/brown_vinyl_weidlich_wilkie_lambert.json", "--to", "mitsuba"],
     "--to mitsuba-plugin"),
    (["{fits}/rgl_aurora_white_two_lobe.json"], "--share alpha"),
    (["{fits}/missing.json"], "no such file"),
    (["--model", "oren_nayar", "--param", "albedo=0.5", "--param", "sigma=0.3"],
     "no Mitsuba 3 native equivalent"),
    (["--model", "rough_conductor", "--param", "alpha=2", "--param", "n=0.2", "--param",
      "k=3.9"], "outside its bounds"),
    (["--model", "rough_conductor", "--param", "alpha=0.2"], "needs values for"),
    (["{fits}/walter_rough_glass.json", "--model", "lambertian"], "not both"),
])
def test_refusals_exit_2_and_write_nothing(capsys, tmp_path, argv, needle):
    out = tmp_path / "out.xml"
    argv = [a.format(fits=FITS) for a in argv]
    code, _, err = _run(capsys, *argv, "--out", out)
    assert code == 2
    assert needle in err and "Traceback" not in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_suffix_decides_and_is_checked(capsys, tmp_path):
    code, _, err = _run(capsys, FITS / "walter_rough_glass.json", "--out", tmp_path / "x.txt")
    assert code == 2 and "--to" in err
    code, _, err = _run(capsys, FITS / "walter_rough_glass.json", "--to", "mitsuba", "--out",
                        tmp_path / "x.gltf")
    assert code == 2 and ".xml or .json" in err


def test_help_lists_the_formats(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["export", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for name in ("mitsuba", "mitsuba-plugin", "gltf", "--preview", "--check"):
        assert name in text


def test_python_api_mirrors_the_cli(tmp_path):
    made = fitlab.export_material(FITS / "walter_rough_glass.json", "mitsuba")
    assert made.value["type"] == "roughdielectric" and made.conversion["translation"] == \
        "roughdielectric"
    with pytest.raises(ExportError, match="mitsuba-plugin"):
        fitlab.export_material(model="oren_nayar", params={"albedo": 0.5, "sigma": 0.3},
                               to="mitsuba")
    made = fitlab.export_material(model="oren_nayar", params={"albedo": 0.5, "sigma": 0.3},
                                  to="mitsuba-plugin", out=tmp_path / "on.xml")
    assert (tmp_path / "on.xml").read_text(encoding="utf-8") == made.text


def test_check_without_a_renderer_fails_before_anything_is_written(capsys, tmp_path,
                                                                    monkeypatch):
    """--check with no renderer: exit 2, what to install, nothing written (and no glTF
    conversion fit run first: the renderer is found before the export is built)."""
    from fitlab.export import check, threejs, renderers

    monkeypatch.setattr(threejs, "missing", lambda: "Chromium not found")
    monkeypatch.setattr(check, "mitsuba_missing", lambda: "Mitsuba 3 is not installed")
    monkeypatch.setattr(renderers, "material_of", lambda *a, **k: pytest.fail("built"))
    for out, needles in [("m.gltf", ("Chromium not found", "Mitsuba 3 is not installed",
                                     "apt-get install chromium", "npm", "pip install mitsuba")),
                         ("m.xml", ("Mitsuba 3 is not installed", "pip install mitsuba"))]:
        code, _, err = _run(capsys, "--model", "lambertian", "--param", "albedo=0.5", "--out",
                            tmp_path / out, "--check")
        assert code == 2 and "Traceback" not in err, err
        assert "--check cannot run" in err and all(n in err for n in needles), err
        assert list(tmp_path.iterdir()) == []


def test_gltf_check_takes_three_js_else_mitsuba(monkeypatch):
    from fitlab.export import check, threejs

    monkeypatch.setattr(check, "mitsuba_missing", lambda: None)
    monkeypatch.setattr(threejs, "missing", lambda: None)
    assert check.renderer_for("gltf") == "three" and check.renderer_for("mitsuba") == "mitsuba"
    assert check.renderer_for("gltf", "mitsuba") == "mitsuba"
    monkeypatch.setattr(threejs, "missing", lambda: "Chromium not found")
    assert check.renderer_for("gltf") == "mitsuba"
    with pytest.raises(ExportError, match="Chromium not found"):
        check.renderer_for("gltf", "three")
    with pytest.raises(ExportError, match="checked by mitsuba, not 'three'"):
        check.renderer_for("mitsuba-plugin", "three")


def test_gltf_validator_errors_fail_the_check(monkeypatch):
    from fitlab.export import check, threejs

    monkeypatch.setattr(threejs, "validator_missing", lambda: None)
    monkeypatch.setattr(threejs, "validate", lambda path: {
        "validator": "2.0.0-dev.3.10", "numErrors": 1, "numWarnings": 0, "numInfos": 0,
        "numHints": 0, "messages": [{"code": "VALUE_NOT_IN_RANGE", "pointer": "/materials/0"}]})
    with pytest.raises(ExportError, match="VALUE_NOT_IN_RANGE at /materials/0.*nothing written"):
        check._validate_gltf("{}")
    monkeypatch.setattr(threejs, "validator_missing", lambda: "Node.js is not installed")
    assert check._validate_gltf("{}") == {"skipped": "Node.js is not installed"}


def test_a_page_still_pending_gets_one_longer_run(monkeypatch, tmp_path):
    """Chromium dumps a three.js page when its virtual time runs out: a page still "pending"
    (a loaded machine) is run once more with the larger budget; a second "pending" is an
    error that says so."""
    from fitlab.export import threejs

    page = tmp_path / "page.html"
    page.write_text("<pre id=\"result\">pending</pre>")
    monkeypatch.setattr(threejs, "node_modules", lambda: tmp_path)
    monkeypatch.setattr(threejs, "browser", lambda: "chromium")
    budgets = []

    def dump(chrome, url, tmp, budget, timeout, answers):
        budgets.append(budget)
        return answers[len(budgets) - 1], None

    answers = ["pending", '{"ok": true, "three": "r170"}']
    monkeypatch.setattr(threejs, "_dump", lambda *a: dump(*a, answers))
    assert threejs.run_page(page, {}, {})["three"] == "r170"
    assert budgets == list(threejs.VIRTUAL_TIME_MS)
    budgets.clear()
    answers[1] = "pending"
    with pytest.raises(threejs.RenderError, match="pending"):
        threejs.run_page(page, {}, {})
    assert budgets == list(threejs.VIRTUAL_TIME_MS)
