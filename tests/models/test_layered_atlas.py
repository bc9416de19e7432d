"""The layered models' validation atlas (fitlab/atlas/, `fitlab atlas`,
data_formats/layered_atlas.md): the command on a tiny grid (its numbers against the coated
model's exact closed form, its bytes run to run), the region in words and the look-up on a
synthetic atlas, the shipped package data (schema, every layered family, verdicts that agree
with its numbers), the link in `fitlab models`, the fit report's note outside the region, and
bad arguments.

Cheap: one model (coated(lambertian), which the model-check tests simulate too), a 2 x 2 grid
at one incidence and a few thousand paths; the synthetic atlas needs no simulation."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest

from fitlab.atlas import compute, region
from fitlab.atlas.grids import GRIDS
from fitlab.cli import main
from fitlab.models import CONSTRUCTORS, get_model
from fitlab.models.syntax import parse_call

ROOT = Path(__file__).resolve().parents[2]
COATED = "coated(lambertian)"
TINY = ["atlas", "--model", COATED, "--values", "albedo=0.2,0.8", "--values",
        "coat_eta=1.3,1.6", "--theta-i", "30", "--samples", "4000", "--quick", "--quiet"]


# --------------------------------------------------------------------------------------------
# The command on a tiny grid
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny atlas, made twice into two folders."""
    d = tmp_path_factory.mktemp("atlas")
    for k in ("a", "b"):
        assert main(TINY + ["--out", str(d / k)]) == 0
    return d


def test_tiny_grid_writes_the_page_maps_and_a_valid_record(tiny):
    out = tiny / "a"
    assert sorted(p.name for p in out.iterdir()) == [
        "README.md", "atlas.json", "coated_lambertian.png", "coated_lambertian.svg"]
    rec = region.load(out / "atlas.json")  # schema and shapes
    (e,) = rec["entries"]
    assert e["model"] == COATED and e["theta_i"] == [30.0] and e["sides"] == ["reflection"]
    assert [a["values"] for a in e["axes"]] == [[0.2, 0.8], [1.3, 1.6]]
    assert e["samples"] == [[4000, 4000], [4000, 4000]]
    assert e["provenance"]["command"] == "fitlab atlas --model 'coated(lambertian)' --values " \
        "albedo=0.2,0.8 --values coat_eta=1.3,1.6 --theta-i 30 --samples 4000 --quick"
    within, _ = region.verdicts(e)
    assert e["within"] == within.tolist()
    assert e["region"] == region.describe(e["axes"], within)
    page = (out / "README.md").read_text(encoding="utf-8")
    assert f"## {COATED}\n" in page and f"(#{e['anchor']})" in page
    assert "(coated_lambertian.png)" in page and str(tiny) not in page
    assert (out / "coated_lambertian.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tiny_grid_is_byte_identical_run_to_run(tiny):
    for name in ("README.md", "atlas.json", "coated_lambertian.png", "coated_lambertian.svg"):
        assert (tiny / "a" / name).read_bytes() == (tiny / "b" / name).read_bytes(), name


def test_simulated_albedo_is_the_closed_form_and_single_bounce_misses_light(tiny):
    """The stack of coated(lambertian) has an exact all-bounce albedo (its closed_form
    interreflection option): the atlas's simulated albedo matches it within 4 standard errors
    (and the model's quadrature), and the default single-bounce model's albedo error is
    negative, larger at the higher albedo."""
    (e,) = region.load(tiny / "a" / "atlas.json")["entries"]
    model = get_model(COATED)
    spec = GRIDS[COATED]
    options = {**model.default_options(), "interreflection": "closed_form"}
    sides = compute.sides_of(model)
    rows, _ = compute.bins(sides)
    for i, albedo in enumerate((0.2, 0.8)):
        for j, eta in enumerate((1.3, 1.6)):
            p = {**compute.params_at(model, spec, 0, 0), "albedo": albedo, "coat_eta": eta}
            mv = compute.model_bins(model, options, sides, p, [30.0], compute.QUICK_MODEL_POINTS)
            exact = float((mv[0] * rows.cos_solid_angle).sum())
            sim = e["albedo_sim"][i][j][0]
            se = e["albedo_error_se"][i][j][0] * sim
            assert abs(sim - exact) < 4 * se + 2e-3 * exact, (albedo, eta, sim, exact, se)
            assert e["albedo_error"][i][j][0] < 0
        assert e["albedo_error"][1][0][0] < e["albedo_error"][0][0][0]


def test_hemisphere_rms_is_the_relative_l2_error_of_f_cos_with_its_noise():
    """The RMS error is relative to the simulation's RMS of f·cos over the hemisphere: a model
    10% above everywhere scores 0.1; an error confined to a dim cell weighs by that cell's
    share of the light, not by its own ratio; the noise is the standard errors in the same
    measure."""
    c = compute.cells(("reflection",))
    rng = np.random.default_rng(3)
    s = rng.uniform(0.5, 2.0, c.size)
    assert compute.hemisphere_rms(s, s, 0 * s, c) == (0.0, 0.0)
    rms, noise = compute.hemisphere_rms(1.1 * s, s, 0.02 * s, c)
    assert rms == pytest.approx(0.1, rel=1e-12) and noise == pytest.approx(0.02, rel=1e-12)
    dim = s.copy()
    dim[np.argmin(s)] *= 1e-3
    m = dim.copy()
    m[np.argmin(s)] *= 2.0  # 100% off in one dim cell
    assert compute.hemisphere_rms(m, dim, 0 * s, c)[0] < 1e-3


@pytest.mark.parametrize("argv, fragment", [
    (["--model", "rough_conductor"], "unknown atlas model 'rough_conductor'"),
    (["--model", COATED, "--values", "alpha=0.1,0.2"], "has no axis 'alpha'"),
    (["--model", COATED, "--values", "albedo=0.5"], "at least two ascending values"),
    (["--model", COATED, "--values", "albedo=a,b"], "is not a list of numbers"),
    (["--values", "albedo=0.2,0.5"], "give one --model with it"),
    (["--model", COATED, "--theta-i", "95"], "[0, 89] degrees"),
    (["--model", COATED, "--samples", "1"], "--samples must be at least 2"),
    (["--model", COATED, "--write-package-data", "--out", "elsewhere"],
     "--write-package-data writes the page its links name"),
])
def test_bad_arguments_exit_2_with_a_message(tmp_path, capsys, argv, fragment):
    argv = argv if "--out" in argv else argv + ["--out", str(tmp_path / "x")]
    assert main(["atlas", "--quiet"] + argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fitlab atlas: error: ") and fragment in err, err
    assert not (tmp_path / "x").exists()


def test_an_unknown_option_exits_2():
    with pytest.raises(SystemExit) as e:
        main(["atlas", "--sampels", "10"])
    assert e.value.code == 2


# --------------------------------------------------------------------------------------------
# The region and the look-up, on a synthetic atlas
# --------------------------------------------------------------------------------------------

AXES = [{"name": "albedo", "label": "albedo", "unit": "1", "scale": "linear",
         "values": [0.2, 0.5, 0.8]},
        {"name": "coat_eta", "label": "coat index", "unit": "1", "scale": "log",
         "values": [1.2, 1.5, 2.0]}]


def _synthetic(albedo_err, rms_err, noise=0.01):
    """An atlas of coated(lambertian) over AXES at one incidence with the given (3, 3) errors."""
    a = np.asarray(albedo_err, float)[..., None]
    r = np.asarray(rms_err, float)[..., None]
    entry = {"model": COATED, "options": get_model(COATED).default_options(), "axes": AXES,
             "fixed": {"coat_tau": 0.0}, "theta_i": [30.0], "sides": ["reflection"],
             "samples": [[1000] * 3] * 3, "albedo_error": a.tolist(),
             "albedo_error_se": np.full(a.shape, 0.001).tolist(), "rms_error": r.tolist(),
             "rms_noise": np.full(a.shape, noise).tolist(),
             "albedo_sim": np.full(a.shape, 0.5).tolist()}
    entry = region.finish(entry, {"command": "made up"})
    return region.record([entry], {})


#: within where albedo ≤ 0.5 and coat_eta ≤ 1.5 (a box), the errors 2% there, 20% elsewhere
BOX = [[0.02, 0.02, 0.2], [0.02, 0.02, 0.2], [0.2, 0.2, 0.2]]


def test_region_in_words():
    a = AXES
    assert region.describe(a, np.ones((3, 3), bool)).startswith("everywhere on the grid")
    assert region.describe(a, np.zeros((3, 3), bool)).startswith("nowhere on the grid")
    assert region.describe(a, np.array(BOX) < 0.05) == "albedo ≤ 0.5 and coat_eta ≤ 1.5"
    assert region.describe(a, np.array([[0, 1, 1], [0, 0, 1], [0, 0, 0]], bool)) == \
        "albedo = 0.2: coat_eta ≥ 1.5; albedo = 0.5: coat_eta = 2; albedo = 0.8: nowhere"
    # per run of equal rows, whichever axis reads shorter
    assert region.describe(a, np.array([[1, 0, 1], [1, 0, 1], [1, 1, 1]], bool)) == \
        "albedo 0.2–0.5: coat_eta = 1.2 or coat_eta = 2; albedo = 0.8: every coat_eta"
    assert region.anchor("spongecake(surface,multiple=learned)") == \
        "spongecakesurfacemultiplelearned"


def test_within_region_reads_the_grid_and_says_when_it_cannot():
    atlas = _synthetic(BOX, BOX)
    model = get_model(COATED)
    p = {"albedo": 0.3, "coat_eta": 1.3, "coat_tau": 0.0}
    ok, text = region.within_region(model, p, {}, atlas)
    assert ok is True and "inside the atlas's 5% region" in text
    assert f"{region.PAGE}#coatedlambertian" in text
    ok, text = region.within_region(COATED, {**p, "albedo": 0.75}, {}, atlas)
    assert ok is False and "outside the atlas's 5% region" in text
    assert "albedo ≤ 0.5 and coat_eta ≤ 1.5" in text
    # bilinear between the grid's points: halfway from 2% to 20% is 11%
    a, r = region.read_grid(atlas["entries"][0], {**p, "albedo": 0.65})
    assert a == pytest.approx(0.11) and r == pytest.approx(0.11)
    # log axis: halfway in log10 between 1.5 and 2.0
    a, _ = region.read_grid(atlas["entries"][0], {"albedo": 0.2, "coat_eta": (1.5 * 2.0) ** 0.5})
    assert a == pytest.approx(0.11)
    for params, options, fragment in [
        ({**p, "albedo": 0.1}, {}, "albedo = 0.1 lies outside the atlas's grid"),
        ({**p, "coat_eta": 2.5}, {}, "coat_eta = 2.5 lies outside"),
        (p, {"interreflection": "closed_form"}, "maps coated(lambertian) with "
                                                "interreflection=single"),
        ({**p, "coat_tau": 0.5}, {}, "off the atlas's slice (coat_tau = 0 there; 0.5 here)"),
    ]:
        ok, text = region.within_region(model, params, options, atlas)
        assert ok is None and fragment in text, text
    ok, text = region.within_region("coated(rough_conductor)", {"alpha": 0.1}, {}, atlas)
    assert ok is None and "not in the layered-model validation atlas" in text
    ok, _ = region.within_region(model, {**p, "coat_tau": 0.05}, {}, atlas)  # within tolerance
    assert ok is True


def test_noise_limited_points_are_flagged():
    atlas = _synthetic(BOX, BOX, noise=0.04)
    e = atlas["entries"][0]
    assert all(all(row) for row in e["noise_limited"])
    assert e["within"] == (np.array(BOX) <= 0.05).tolist()


def test_a_record_with_mismatched_shapes_is_refused(tmp_path):
    from fitlab.errors import InputFileError

    rec = copy.deepcopy(_synthetic(BOX, BOX))
    rec["entries"][0]["within"] = rec["entries"][0]["within"][:2]
    path = tmp_path / "atlas.json"
    path.write_text(region.to_json(rec), encoding="utf-8")
    with pytest.raises(InputFileError, match=r"entries\[0\]\.within is not 3 x 3"):
        region.load(path)


# --------------------------------------------------------------------------------------------
# The shipped atlas and its links
# --------------------------------------------------------------------------------------------


def test_package_data_is_valid_covers_every_family_and_agrees_with_its_numbers():
    rec = region.load()  # the schema and the shapes
    models = [e["model"] for e in rec["entries"]]
    assert set(GRIDS) <= set(models)
    assert {parse_call(m).func for m in models} == set(CONSTRUCTORS)
    for e in rec["entries"]:
        within, limited = region.verdicts(e)
        assert e["within"] == within.tolist() and e["noise_limited"] == limited.tolist()
        assert e["region"] == region.describe(e["axes"], within), e["model"]
        assert e["anchor"] == region.anchor(e["model"])
        spec = GRIDS[e["model"]]
        assert all(set(v) <= set(a.values) for v, a in
                   zip((ax["values"] for ax in e["axes"]), spec.axes))


def test_models_shows_the_atlas_entry_and_its_page(capsys):
    name = "coated(rough_conductor)"
    assert main(["models", name]) == 0
    out = capsys.readouterr().out
    entry = region.entry_of(name)
    line = next(ln for ln in out.splitlines() if ln.startswith("  atlas: "))
    assert entry["region"] in line and line.endswith(f"{region.PAGE}#{entry['anchor']}")
    assert main(["models", name, "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)["models"][0]
    assert rec["atlas"]["page"] == f"{region.PAGE}#{entry['anchor']}"
    assert main(["models", "rough_conductor", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["models"][0]["atlas"] is None
    # the page exists in the source tree, with the heading the anchor names
    page = (ROOT / region.PAGE).read_text(encoding="utf-8")
    headings = [region.anchor(h) for h in re.findall(r"^## (.+)$", page, flags=re.M)]
    assert entry["anchor"] in headings


def test_fit_report_notes_a_fit_outside_the_region(tmp_path, monkeypatch):
    """A coated(lambertian) fit of the tiny RGB example (the model-check tests fit it too), its
    report under a synthetic atlas whose region the fitted albedo lies outside: the note with
    the errors the atlas reads there and the page."""
    data = ROOT / "data_formats" / "examples" / "measurement_rgb_sigma.csv"
    fit = tmp_path / "fit.json"
    assert main(["fit", str(data), "--model", COATED, "--channel", "R", "--fix",
                 "coat_eta=1.5", "--fix", "coat_tau=0", "--starts", "0", "--bootstrap", "0",
                 "--check-model", "off", "--out", str(fit), "--quiet"]) == 0
    albedo = json.loads(fit.read_text())["fits"][0]["parameters"]["albedo"]["value"]
    # within only at the lowest albedo of a grid that holds the fitted one
    lo, hi = max(albedo / 4, 1e-3), min(albedo * 1.5, 1.0)
    atlas = _synthetic([[0.01] * 3, [0.3] * 3, [0.3] * 3], [[0.01] * 3, [0.3] * 3, [0.3] * 3])
    atlas["entries"][0]["axes"][0]["values"] = [lo, (lo + hi) / 2, hi]
    atlas["entries"][0] = region.finish({k: v for k, v in atlas["entries"][0].items()},
                                        {"command": "made up"})
    path = tmp_path / "atlas.json"
    path.write_text(region.to_json(atlas), encoding="utf-8")
    monkeypatch.setattr(region, "DATA_PATH", path)
    monkeypatch.setattr(region, "_CACHE", {})
    assert main(["report", str(fit), "--out", str(tmp_path / "rep"), "--quiet"]) == 0
    import html as html_module

    text = html_module.unescape((tmp_path / "rep" / "index.html").read_text(encoding="utf-8"))
    note = re.search(r"Validation atlas: the fitted parameters lie outside the atlas's 5% "
                     r"region: largest albedo error ≈ ([0-9.]+)%, RMS error of f·cos ≈ "
                     r"([0-9.]+)%", text)
    assert note, text[:2000]
    assert float(note.group(1)) > 5 and float(note.group(2)) > 5
    assert f"{region.PAGE}#coatedlambertian" in text
