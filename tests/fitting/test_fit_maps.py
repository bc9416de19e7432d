"""Spatially varying materials (``fitlab fit-maps``, ``fitlab.fit_maps``; data_formats/stack.md):
known per-texel parameters recovered from the bundled 4 x 4 stack, the maps' channels and
dtypes, the same bytes from the command and from Python, "no data" texels, hostile stacks
refused with exit status 2 and nothing written, the Mitsuba hand-off, tiles on Dask."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
STACK = EXAMPLES / "stack"
MODEL = "lambertian+rough_conductor"
#: The fit the module shares (one compiled structure: R, G, B jointly, alpha shared).
ARGS = ["--model", MODEL, "--fix", "n=0.2", "--fix", "k=3.9", "--share", "alpha"]


def _truth():
    sys.path.insert(0, str(EXAMPLES))
    try:
        import make_stack_examples as make
    finally:
        sys.path.remove(str(EXAMPLES))
    return make


def _read(path):
    from fitlab.io.exr_image import image_header, read_image

    names, _ = image_header(path)
    order = [c for c in ("R", "G", "B", "Y") if c in names]
    return order, read_image(path, tuple(order))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The example fitted by the command and by Python (two runs of the same fit)."""
    base = tmp_path_factory.mktemp("maps")
    code = main(["fit-maps", str(STACK), *ARGS, "--out-dir", str(base / "cli"), "--quiet"])
    assert code == 0
    result = fitlab.fit_maps(STACK, MODEL, fix={"n": 0.2, "k": 3.9}, share=["alpha"],
                             out_dir=base / "api")
    return base, result


def test_recovers_known_texels(runs):
    _, r = runs
    make = _truth()
    albedo, alpha = make.truth()
    assert r.shape == (4, 4) and r.channel_names == ("R", "G", "B")
    assert r.values["albedo"].shape == (4, 4, 3) and r.values["alpha"].shape == (4, 4, 1)
    got = np.isfinite(r.values["alpha"][..., 0])
    assert got.sum() == 15 and not got[3, 3]  # the texel without readings
    # 1 % noise on 24 readings: within 0.01 of the truth, and within 4 standard errors
    assert np.nanmax(np.abs(r.values["albedo"] - albedo)) < 0.01
    assert np.nanmax(np.abs(r.values["alpha"][..., 0] - alpha)) < 0.01
    z = (r.values["alpha"][..., 0] - alpha) / r.stderr["alpha"][..., 0]
    assert np.nanmax(np.abs(z)) < 4
    # the fit error is the noise's size; texel (x=0, y=3) was fitted on its 22 readings
    assert 0.004 < np.nanmedian(r.rms) < 0.02 and np.isfinite(r.rms[3, 0]).all()
    codes = np.zeros((4, 4), int)
    codes[3, 3] = fitlab.fitting.status.Status.NO_DATA.code
    np.testing.assert_array_equal(r.status, codes)
    assert r.counts() == {"converged": 15, "no_data": 1} and not r.ok
    with pytest.raises(fitlab.errors.FitlabError, match="1 texel: no_data"):
        r.raise_for_status()


def test_outputs_channels_dtypes_and_record(runs):
    base, r = runs
    out = base / "cli"
    rec = json.loads((out / "maps.json").read_text())
    assert rec["schema"] == "fitlab-maps" and rec["model"] == MODEL
    assert rec["fixed"] == {"n": 0.2, "k": 3.9} and rec["settings"]["share"] == ["alpha"]
    assert sorted(p.name for p in out.rglob("*") if p.is_file()) == sorted(
        Path(f).name for f in rec["files"])
    expect = {"albedo.exr": ["R", "G", "B"], "albedo_std.exr": ["R", "G", "B"],
              "alpha.exr": ["Y"], "alpha_std.exr": ["Y"], "rms.exr": ["R", "G", "B"],
              "status.exr": ["Y"]}
    for name, channels in expect.items():
        got, pixels = _read(out / name)
        assert got == channels and pixels.dtype == np.float32 and pixels.shape[:2] == (4, 4)
    _, status = _read(out / "status.exr")
    np.testing.assert_array_equal(status[..., 0], r.status)
    _, alpha = _read(out / "alpha.exr")
    np.testing.assert_allclose(alpha[..., 0], r.values["alpha"][..., 0], rtol=1e-6)
    codes = rec["status"]["codes"]
    assert codes["0"] == "converged" and codes["11"] == "no_data"
    assert rec["status"]["counts"] == {"converged": 15, "no_data": 1}
    assert rec["handoff"]["mitsuba"]["written"] and not rec["handoff"]["gltf"]["written"]
    text = "".join(p.read_text(errors="replace") for p in out.glob("*.j*"))
    assert str(base) not in text  # no absolute path of this machine: the stack's is relative
    assert not rec["stack"]["folder"].startswith("/")
    assert (out / rec["stack"]["folder"]).resolve() == STACK.resolve()


def test_command_and_python_write_the_same_bytes(runs):
    """Two runs (the command, then fitlab.fit_maps): every file byte for byte."""
    base, _ = runs
    files = sorted(p.relative_to(base / "cli") for p in (base / "cli").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(base / "api") for p in (base / "api").rglob("*")
                           if p.is_file())
    for f in files:
        assert (base / "cli" / f).read_bytes() == (base / "api" / f).read_bytes(), f


def test_mitsuba_scene_with_bitmap_textures(runs):
    base, r = runs
    xml = (base / "cli" / "mitsuba.xml").read_text()
    assert '<texture name="weight" type="bitmap">' in xml
    assert 'value="mitsuba/bsdf_1.alpha.exr"' in xml and '<float name="k" value="3.9"/>' in xml
    _, alpha = _read(base / "cli" / "mitsuba" / "bsdf_1.alpha.exr")
    fitted = np.isfinite(r.values["alpha"][..., 0])
    np.testing.assert_allclose(alpha[..., 0][fitted], r.values["alpha"][..., 0][fitted],
                               rtol=1e-6)
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    scene = mi.load_file(str(base / "cli" / "mitsuba.xml"))
    assert scene is not None


def test_mitsuba_translation_on_arrays_is_the_texel_by_texel_one(runs, monkeypatch):
    """The hand-off translates every texel at once (arrays over the texels); texel by texel
    it is the same scene and the same textures, value for value."""
    from fitlab.export import maps

    _, r = runs
    scene, textures = maps.mitsuba_handoff(r)
    monkeypatch.setattr(maps, "_batch_handoff", lambda result: None)
    ref_scene, ref_textures = maps.mitsuba_handoff(r)
    assert scene == ref_scene and sorted(textures) == sorted(ref_textures)
    for name, arr in ref_textures.items():
        assert np.array_equal(textures[name], arr), name


def test_shared_scan_and_texel_setup_are_the_per_dataset_ones(monkeypatch):
    """Every texel is on the same rows: fit_chunk computes the scan's predictions once per
    chunk (fitlab.fitting.batch.shared_scan_costs), with the per-dataset scan's costs and
    fits; the texels' problems, made from one (fitlab.fitting.maps._regular_problems), are
    those made texel by texel."""
    from fitlab.fitting import batch, maps
    from fitlab.fitting.channel import resolve_fit
    from fitlab.fitting.request import as_request
    from fitlab.io.stack import read_stack

    seen = []
    real = batch.fit_chunk
    monkeypatch.setattr(batch, "fit_chunk", lambda ps, **kw: seen.append((ps, kw)) or real(
        ps, **kw))
    fitlab.fit_maps(STACK, MODEL, fix={"n": 0.2, "k": 3.9}, share=["alpha"])
    (problems, kw), = seen
    p0 = problems[0]
    stacked = batch._stack(problems, int(np.shape(p0.data.value)[0]))
    assert batch.shares_scan(p0.space.static, stacked)
    k = batch._batched(p0.space.static, p0.loss, batch.LM_MAXITER)
    U = batch.scan_points(kw["scan"], p0.space.ndim, kw["seed"])
    shared = np.asarray(k["shared_scan"](U, stacked))
    each = np.asarray(k["batch_scan"](U, stacked))
    np.testing.assert_allclose(shared, each, rtol=1e-12, atol=0)
    once = real(problems, **kw)
    monkeypatch.setattr(batch, "shares_scan", lambda static, stacked: False)
    np.testing.assert_array_equal(real(problems, **kw).native, once.native)  # the same fits
    # texel by texel: the same problems as the regular path made
    stack = read_stack(STACK)
    request = as_request(MODEL, {"fix": {"n": 0.2, "k": 3.9}, "share": ["alpha"], "starts": 4})
    template = maps._template(stack)
    setup = resolve_fit(template, request)
    readings = np.transpose(stack.values, (0, 1, 3, 2)).reshape(16, -1).astype(float)
    regular = [p for p in problems if np.all(np.isfinite(readings[p.key[0]]))]
    assert len(regular) > 2
    for p in regular:
        t = p.key[0]
        q, = maps._texel_problems(t, template._replace(value=readings[t]),
                                  np.ones(readings.shape[1], bool), request, setup)
        for a, b in zip(jax_leaves(p.data), jax_leaves(q.data)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(p.start_native, q.start_native)
        assert p.n_rows == q.n_rows and p.space.static == q.space.static


def jax_leaves(tree):
    from fitlab._jax import jax

    return [np.asarray(x) for x in jax.tree.leaves(tree)]


def test_rerun_replaces_an_earlier_folder_and_refuses_others(runs, tmp_path):
    base, _ = runs
    out = tmp_path / "maps"
    shutil.copytree(base / "cli", out)
    (out / "stale.exr").write_bytes(b"x")
    from fitlab.export.maps import check_out_dir

    assert check_out_dir(out) == out  # an earlier fit-maps folder: replaced
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(fitlab.errors.FitlabError, match="holds other files"):
        check_out_dir(other)


def _copy_stack(tmp_path, name="s"):
    dst = tmp_path / name
    shutil.copytree(STACK, dst)
    return dst


def _hostile_cases(tmp_path):
    """(name, stack folder, text the message must hold): the invalid examples and more."""
    inv = EXAMPLES / "invalid"
    cases = [("mismatched size", inv / "stack_mismatched_size", "is 2 x 3 pixels"),
             ("missing file", inv / "stack_missing_file", "no such image"),
             ("extra channel", inv / "stack_extra_channel", "extra channel(s) A"),
             ("infinite", inv / "stack_infinite", "(infinite)"),
             ("escaping path", inv / "stack_escaping_path", "leaves the stack folder"),
             ("radians", inv / "stack_radians", "radians")]
    s = _copy_stack(tmp_path, "rows")
    head = "file,theta_i,phi_i,theta_o,phi_o\n"
    (s / "stack.csv").write_text(head + "img_000.exr,0,0,10,0\n" * 100_000)
    cases.append(("1e5 rows", s, "100000 rows"))
    s = _copy_stack(tmp_path, "absolute")
    text = (s / "stack.csv").read_text().replace("img_004.exr", str(s / "img_004.exr"))
    (s / "stack.csv").write_text(text)
    cases.append(("absolute path", s, "is an absolute path"))
    s = _copy_stack(tmp_path, "two_channels")
    from fitlab.io.exr_image import write_image

    write_image(s / "img_007.exr", {c: np.full((4, 4), 0.1, np.float32) for c in "RG"})
    cases.append(("missing channel", s, "missing B"))
    s = _copy_stack(tmp_path, "not_exr")
    (s / "img_003.exr").write_bytes(b"P6 4 4 255\n" + bytes(48))
    cases.append(("not OpenEXR", s, "is not an OpenEXR file"))
    s = _copy_stack(tmp_path, "no_table")
    (s / "stack.csv").unlink()
    cases.append(("no table", s, "stack.csv: no such file"))
    s = _copy_stack(tmp_path, "bad_angle")
    text = (s / "stack.csv").read_text().replace("img_002.exr,0,0,20,180", "img_002.exr,0,0,200,180")
    (s / "stack.csv").write_text(text)
    cases.append(("angle out of range", s, "column 'theta_o'"))
    s = _copy_stack(tmp_path, "duplicate")
    text = (s / "stack.csv").read_text().replace("img_002.exr,", "img_001.exr,")
    (s / "stack.csv").write_text(text)
    cases.append(("duplicate image", s, "is also the image of line"))
    return cases


def test_hostile_stacks_exit_2_and_write_nothing(tmp_path, capsys):
    failures = []
    for name, folder, needle in _hostile_cases(tmp_path):
        out = tmp_path / f"out_{name.replace(' ', '_')}"
        before = sorted(p.name for p in tmp_path.iterdir())
        code = main(["fit-maps", str(folder), *ARGS, "--out-dir", str(out), "--quiet"])
        err = capsys.readouterr().err
        after = sorted(p.name for p in tmp_path.iterdir())
        if code != 2 or needle not in err or "error:" not in err or after != before:
            failures.append(f"{name}: exit {code}, {err.strip()[:200]!r}, new: "
                            f"{sorted(set(after) - set(before))}")
    assert not failures, "\n".join(failures)


def test_bad_settings_are_refused_before_reading(tmp_path, capsys):
    out = tmp_path / "o"
    for extra, needle in ((["--fix", "nope=1"], "has no parameter"),
                          (["--share", "n"], "is fixed"),
                          (["--starts", "-1"], "--starts must be")):
        code = main(["fit-maps", str(STACK), "--model", MODEL, "--fix", "n=0.2", *extra,
                     "--out-dir", str(out), "--quiet"])
        assert code == 2 and needle in capsys.readouterr().err
    assert not out.exists()


def test_independent_channels_and_a_subset_of_values():
    """Without --share every channel of a texel is its own dataset (alpha per channel); a
    --fit-subset that reads the values is evaluated texel by texel."""
    make = _truth()
    albedo, alpha = make.truth()
    r = fitlab.fit_maps(STACK, MODEL, fix={"n": 0.2, "k": 3.9},
                        subset="value < 5 and theta_o < 50")
    assert r.values["alpha"].shape == (4, 4, 3) and r.shared == ()
    assert np.nanmax(np.abs(r.values["alpha"] - alpha[..., None])) < 0.02
    assert np.nanmax(np.abs(r.values["albedo"] - albedo)) < 0.01
    assert r.counts() == {"converged": 15, "no_data": 1}
    # the fit error is over the readings the subset kept: recompute one texel's by hand
    from fitlab.io.stack import read_stack
    from fitlab.metrics import fit_error

    stack = read_stack(STACK)
    v = stack.values[1, 2, :, 0].astype(float)
    keep = (v < 5) & (stack.theta_o < 50)
    params = {"albedo": r.values["albedo"][1, 2, 0], "alpha": r.values["alpha"][1, 2, 0],
              "n": 0.2, "k": 3.9}
    wi, wo = stack.directions()
    pred = np.asarray(fitlab.eval_bsdf(MODEL, params, wi[keep], wo[keep]))
    ref = fit_error(pred, v[keep], stack.theta_i[keep], stack.phi_i[keep])
    assert r.rms[1, 2, 0] == pytest.approx(ref["rms_relative_error"], rel=1e-6)


def test_fit_error_of_many_texels_is_fit_error():
    """fitlab.metrics.fit_error_rms_many is fit_error's pooled figure, texel by texel."""
    from fitlab.metrics import fit_error, fit_error_rms_many

    rng = np.random.default_rng(3)
    theta_i = np.repeat([0.0, 30.0, 60.0], 8)
    phi_i = np.zeros(24)
    value = rng.lognormal(0, 2, (5, 24))
    value[1, :8] = 0.0
    pred = value * (1 + 0.1 * rng.standard_normal((5, 24)))
    rows = rng.random((5, 24)) > 0.2
    rows[4] = False
    got = fit_error_rms_many(pred, value, rows, theta_i, phi_i)
    for t in range(4):
        r = rows[t]
        ref = fit_error(pred[t, r], value[t, r], theta_i[r], phi_i[r])["rms_relative_error"]
        assert got[t] == pytest.approx(ref, rel=1e-12)
    assert np.isnan(got[4])


def test_status_codes_are_stable():
    from fitlab.fitting.status import Status

    assert [s.code for s in Status][:3] == [0, 1, 2] and Status.CONVERGED.code == 0
    assert Status.AT_BOUND.code == 5 and Status.NO_DATA.code == 11


@pytest.mark.slow
def test_tiles_resume_and_agree(runs, tmp_path):
    """--workers 1 in tiles of one image row: the same maps as the single run; a rerun after
    an interrupted one fits only the tiles that were not done."""
    from fitlab.fitting import maps as M
    from fitlab.fitting.request import FitRequest
    from fitlab.io.stack import read_stack

    _, whole = runs
    request = FitRequest(MODEL, fix={"n": 0.2, "k": 3.9}, share=["alpha"], starts=4)
    out = tmp_path / "tiled"
    settings = M.tile_settings(request, 256, 1024)
    stack = read_stack(STACK)
    work = M.work_folder(out)
    cid = M.tile_id(settings, stack.sha256, 0, 1)
    M._fit_tile(str(STACK.resolve()), settings, 0, 1, str(work), cid)  # the run "before"
    result, summary = M.fit_maps_tiled(STACK, request, out, scan=256, chunk=1024, workers=1,
                                       tile_rows=1, progress=False)
    assert summary == {"tiles": 4, "done_before": 1, "fitted": 3}
    assert not work.exists() and (out / "maps.json").exists()
    for p in whole.values:
        np.testing.assert_allclose(result.values[p], whole.values[p], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(result.status, whole.status)


@pytest.mark.slow
def test_report_of_a_map_folder(runs, tmp_path, capsys):
    """fitlab report DIR on a fit-maps folder: the maps, the error and status maps,
    histograms and texel scans, one page."""
    base, _ = runs
    out = tmp_path / "report"
    assert main(["report", str(base / "cli"), "--out", str(out), "--quiet"]) == 0
    page = (out / "index.html").read_text()
    for name in ("map_albedo", "map_alpha_std", "map_rms", "map_status", "histograms_0",
                 "texel_3_3"):
        assert (out / f"{name}.png").exists() and f'id="{name}"' in page, name
    assert "no_data: 1 texels" in page
    assert "No three.js render: the fit has no glTF hand-off" in page  # no --gltf
    first = (out / "map_alpha.png").read_bytes()
    assert main(["report", str(base / "cli"), "--out", str(out), "--quiet"]) == 0
    assert (out / "map_alpha.png").read_bytes() == first  # the same folder, the same bytes


def _mutation_cases():
    """(label, which file of the stack, Case) of tests/hostile.py's generators: the table's
    bytes and text, and one image's bytes."""
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        import hostile as H
    finally:
        sys.path.remove(str(ROOT / "tests"))
    table = (STACK / "stack.csv").read_bytes()
    image = (STACK / "img_005.exr").read_bytes()
    cases = [("stack.csv", c) for c in H.byte_cases(table)]
    cases += [("stack.csv", c) for c in H.text_cases(table)]
    cases += [("img_005.exr", c) for c in H.byte_cases(image, text=False)]
    return H, cases


def _params_mutations():
    _, cases = _mutation_cases()
    for k, (target, case) in enumerate(cases):
        for tier in ("quick", "all"):
            if tier == "quick" and k % 9:
                continue
            marks = [pytest.mark.slow] if tier == "all" else [pytest.mark.sample_of_slow]
            yield pytest.param(k, tier, marks=marks, id=f"{target}-{case.name}-{tier}")


@pytest.mark.parametrize("k, tier", list(_params_mutations()))
def test_mutated_stacks_keep_the_contract(k, tier, tmp_path):
    """tests/hostile.py's contract on every mutation of the example's table and of an image:
    exit 0 or 2, no traceback, a message naming the file, nothing written on failure."""
    H, cases = _mutation_cases()
    target, case = cases[k]
    folder = _copy_stack(tmp_path, "stack")
    (folder / target).unlink()
    case.write(folder / target)
    out = tmp_path / "out"
    out.mkdir()
    o = H.run_contract(["fit-maps", folder, *ARGS, "--out-dir", out, "--quiet"],
                       folder / target, out)
    assert not o.problems, f"{target} {case.name}: {o.problems} ({o.err.strip()[:300]})"


def test_gltf_document_of_texture_maps():
    """The glTF document of a conversion (fitlab/export/gltf_maps.py): a quad with texture
    coordinates, the textures embedded as PNG, texels not fitted filled; the PNG writer."""
    import base64
    import zlib

    from fitlab.export.gltf_maps import gltf_maps, png_bytes
    from fitlab.fitting.maps import MapsResult
    from fitlab.fitting.status import Status

    status = np.zeros((2, 3), int)
    status[1, 2] = Status.NO_DATA.code
    val = lambda v, k=1: np.where(status[..., None] == 0, np.full((2, 3, k), v), np.nan)  # noqa
    conv = MapsResult("gltf_pbr", {}, {}, ("R", "G", "B"),
                      {"base_color": val(0.5, 3), "metallic": val(1.0),
                       "roughness_factor": val(0.25), "specular": val(0.8)}, {}, (),
                      np.zeros((2, 3, 3)), status, {}, None, [], 0.0)
    doc, textures = gltf_maps(conv, MODEL)
    assert sorted(textures) == ["base_color.png", "metallic_roughness.png", "specular.png"]
    png = base64.b64decode(doc["images"][1]["uri"].split(",", 1)[1])
    assert png == textures["metallic_roughness.png"] and png[16:24] == b"\0\0\0\3\0\0\0\2"
    rows = zlib.decompress(png[png.index(b"IDAT") + 4:png.index(b"IEND") - 8])
    # each row: filter byte 0, then R G B per texel (G roughness 0.25, B metallic 1)
    assert rows[:10] == bytes([0, 0, 64, 255, 0, 64, 255, 0, 64, 255])
    assert rows[10 + 7:10 + 10] == bytes([0, 64, 255])  # the texel not fitted: the mean
    assert doc["accessors"][2]["type"] == "VEC2" and doc["extensionsUsed"] == [
        "KHR_materials_specular"]
    px = np.array([[[255, 0, 0], [0, 128, 255]]], dtype=np.uint8)
    assert png_bytes(px) == png_bytes(px.copy())


@pytest.mark.slow
def test_gltf_handoff_fits_gltf_to_every_texel(runs, tmp_path):
    """--gltf: glTF's BRDF fitted to each texel's material (ior fixed at 1.5), a valid
    document with its PNG textures embedded, the conversion's error per texel, and three.js's
    render of the document beside the input images."""
    import base64

    _, r = runs
    out = tmp_path / "g"
    fitlab.fit_maps(r.stack, MODEL, fix={"n": 0.2, "k": 3.9}, share=["alpha"], out_dir=out,
                    gltf=True)
    rec = json.loads((out / "maps.json").read_text())
    g = rec["handoff"]["gltf"]
    assert g["written"] and g["fixed"] == {"ior": 1.5, "specular_color": 1.0}
    assert g["status_counts"].get("no_data") == 1 and 0 < g["conversion_rms"]["median"] < 0.3
    doc = json.loads((out / "material.gltf").read_text())
    mat = doc["materials"][0]
    from fitlab.io.validate import check_schema

    check_schema(mat["extras"]["fitlab"], "gltf_maps", out / "material.gltf")  # its record
    assert mat["pbrMetallicRoughness"]["baseColorTexture"] == {"index": 0}
    assert mat["extensions"]["KHR_materials_specular"]["specularTexture"] == {"index": 2}
    assert doc["accessors"][2]["type"] == "VEC2"  # texture coordinates of the quad
    base = base64.b64decode(doc["images"][0]["uri"].split(",", 1)[1])
    assert base[:8] == b"\x89PNG\r\n\x1a\n" and base[16:24] == (4).to_bytes(4, "big") * 2
    _, rms = _read(out / "gltf" / "conversion_rms.exr")
    assert rms.shape == (4, 4, 3) and np.isnan(rms[3, 3]).all() and np.isfinite(rms[0, 0]).all()
    from fitlab.export import threejs

    if threejs.node_modules() is not None and (threejs.node_modules() / "gltf-validator").exists():
        report = threejs.validate(out / "material.gltf")
        assert (report["numErrors"], report["numWarnings"]) == (0, 0), report["messages"]
    _three_js_renders_like_the_input(out, tmp_path)


def _three_js_renders_like_the_input(out, tmp_path):
    """three.js renders material.gltf at three rows of the stack (fitlab.render_maps_gltf):
    over the texels that fit well (rms.exr below 2 %: all fitted ones) the median |render -
    input| / input per row is below 0.25 (measured 0.03, 0.12, 0.17: the glTF conversion's
    error, gltf/conversion_rms.exr median 0.13, and three.js's departures), and the render read
    with v flipped, or u and v, misses by more than 0.4 (the example's glTF varies little along
    u: its conversion puts the Lambertian albedo, which varies along u, into a white metal whose
    metallic barely does; tests/export/test_gltf_browser.py checks u on synthetic texels).
    ``fitlab report DIR`` shows it; the same pixels twice. Skipped (failed in CI) without
    Chromium and three.js, after the checks above."""
    from gltf_browser import require_three_js

    from fitlab.io.exr_image import read_image

    require_three_js()
    r = fitlab.render_maps_gltf(out)
    good = np.all(read_image(out / "rms.exr", ("R", "G", "B")) < 0.02, axis=-1)
    assert good.sum() == 15 and list(r.rows) == [0, 6, 23]
    med = r.median_relative_difference(good)
    flips = {"v flipped": lambda a: a[::-1], "u and v flipped": lambda a: a[::-1, ::-1]}
    flipped = {k: r._replace(render=f(r.render)).median_relative_difference(good)
               for k, f in flips.items()}
    print(f"rows {list(r.rows)}: median |rel. diff.| {np.round(med, 4)}; "
          + ", ".join(f"{k} {np.round(v, 3)}" for k, v in flipped.items()))
    assert np.all(med < 0.25), med
    assert all(v.max() > 0.4 for v in flipped.values()), flipped
    again = fitlab.render_maps_gltf(out)
    assert np.array_equal(again.render, r.render, equal_nan=True)  # the same pixels twice
    assert main(["report", str(out), "--out", str(tmp_path / "report"), "--quiet"]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    assert 'id="threejs_render"' in page and "three.js r187" in page


def test_render_maps_gltf_refuses_folders_without_a_usable_gltf(runs, tmp_path):
    """fitlab.render_maps_gltf (three.js's render of the glTF hand-off): a folder without one,
    a record naming another document, a missing document, a record without its stack: a short
    error naming the file and field, before any browser starts. The records are the example
    fit's own maps.json with its hand-off changed (a valid record otherwise)."""
    base, _ = runs
    real = json.loads((base / "cli" / "maps.json").read_text())

    def folder(name, gltf, stack=None):
        d = tmp_path / name
        d.mkdir()
        rec = {**real, "handoff": {**real["handoff"], "gltf": gltf}}
        if stack is not None:
            rec["stack"] = stack
        if stack == {}:  # no stack at all
            del rec["stack"]
        (d / "maps.json").write_text(json.dumps(rec))
        return d

    with pytest.raises(fitlab.errors.FitlabError, match="no glTF hand-off .not requested"):
        fitlab.render_maps_gltf(folder("none", {"written": False, "reason": "not requested"}))
    with pytest.raises(fitlab.errors.InputFileError, match="handoff.gltf.document"):
        fitlab.render_maps_gltf(folder("other", {"written": True, "document": "../x.gltf"}))
    with pytest.raises(fitlab.errors.InputFileError, match="material.gltf.*missing"):
        fitlab.render_maps_gltf(folder("gone", {"written": True, "document": "material.gltf"}))
    d = folder("nostack", {"written": True, "document": "material.gltf"}, stack={})
    (d / "material.gltf").write_text("{}")
    with pytest.raises(fitlab.errors.InputFileError, match="stack"):
        fitlab.render_maps_gltf(d)
