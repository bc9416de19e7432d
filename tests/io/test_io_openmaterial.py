"""ASAM OpenMATERIAL 3D BRDF look-up tables (issue 37, item 1; data_formats/openmaterial_xompt.md):
the two upstream examples through info / convert / fit, the frame and azimuth convention, the
schema's and fitlab's refusals (each broken example's message names the JSON path), and the
writer: a fit and a model written as .xompt, valid against the standard's schema, read back to
float32, --grid-from, the same bytes on a rerun, fitlab export's copy of it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.io import openmaterial as om
from fitlab.io.formats import detect_format

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
FOLDER = EXAMPLES / "openmaterial"
LIDAR = FOLDER / "example_material_lidar_brdf.xompt"
CAMERA = FOLDER / "example_material_camera_brdf.xompt"
WRITTEN = FOLDER / "fitlab_lambertian_ggx.xompt"
INVALID = EXAMPLES / "invalid"
SHARED = ROOT.parent / "shared" / "data" / "asam_openmaterial3d"
#: The values a written file holds: 9 significant digits, so a float32 reads back exactly.
FLOAT32 = 2.0 ** -23


def _valid_against_schema(doc) -> list:
    """The bundled schema's errors of ``doc``, found by jsonschema itself (not the writer)."""
    import jsonschema

    schema = json.loads(om.SCHEMA_FILE.read_text(encoding="utf-8"))
    return [e.message for e in jsonschema.Draft7Validator(schema).iter_errors(doc)]


def _model_values(m, model, params, options=None):
    return np.asarray(fitlab.eval_bsdf(model, params, m.wi, m.wo, options), dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def test_lidar_file_is_detected_and_read_in_fitlabs_frame():
    assert detect_format(LIDAR).name == "openmaterial"
    m = fitlab.read(LIDAR)
    assert m.n == 905 and m.channel_names == ("905nm",) and list(m.wavelength_nm) == [905.0]
    assert m.quantity == m.file_quantity == "bsdf" and m.sigma is None
    assert set(m.phi_i) == {0.0} and set(m.phi_o) == {0.0, 180.0}
    # radians in the file, degrees in fitlab: 1.500983 rad is 86.0° (to the file's 6 decimals)
    assert m.theta_i.min() == pytest.approx(86.0, abs=1e-4)
    assert m.theta_o.max() == pytest.approx(90.0, abs=1e-4)
    # row 3 is [905e-9, 1.500983, 0.017453, π, 0.0013255]: the specular side of the normal
    assert (m.lines[2], m.theta_o[2], m.phi_o[2]) == (3, om.to_degrees(0.017453), 180.0)
    assert m.value[2] == 0.0013255
    # φo = 180° at θo = θi is the mirror direction of fitlab's frame (φo = 0°: retro-reflection)
    from fitlab.frame import reflect

    j = np.flatnonzero((m.theta_i == m.theta_i.min()) & (m.phi_o == 180.0)
                       & np.isclose(m.theta_o, m.theta_i, atol=0.01))[0]
    mirror = np.asarray(reflect(m.wi[j], np.array([0.0, 0.0, 1.0])))
    np.testing.assert_allclose(m.wo[j], mirror, atol=1e-3)
    meta = m.metadata
    assert meta["openmaterial_name"] == "asphalt_brdf_for_lidar"
    assert meta["openmaterial_uuid"] == "c83d3856-db38-40a5-b64e-49b52869d780"
    assert json.loads(meta["openmaterial_copyrights"]) == ["(C) 2023-2024 DIVP"]
    assert meta["openmaterial_license"] == "MPL-2.0"
    assert meta["openmaterial_typical_sensor_technology"] == "lidar"
    assert om.metadata_from(meta)["authors"] == ["DIVP"]


def test_info_of_both_files(capsys):
    assert main(["info", str(LIDAR), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "openmaterial" and info["rows"] == 905 and not info["warnings"]
    assert info["wavelength_nm"] == [905.0] and info["view_directions"] == 181
    assert info["incident_directions"] == 5 and info["sorted_as_the_standard_requires"]
    assert main(["info", str(CAMERA), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["rows"] == 1888 and len(info["channels"]) == 32
    assert info["wavelength_nm"][0] == 390.0 and info["wavelength_nm"][-1] == 700.0
    assert info["view_directions"] == 1 and info["incident_directions"] == 59
    assert any("one view direction" in w for w in info["warnings"])
    assert info["metadata"]["openmaterial_typical_sensor_technology"] == "camera"


@pytest.mark.parametrize("path", [LIDAR, CAMERA], ids=["lidar", "camera"])
def test_convert_writes_a_measurement_csv_in_degrees(tmp_path, capsys, path):
    out = tmp_path / "o.csv"
    assert main(["convert", str(path), str(out)]) == 0
    text = out.read_text()
    assert "theta_i,phi_i,theta_o,phi_o,wavelength_nm,value" in text
    assert "# openmaterial_uuid: " in text
    back, m = fitlab.read(out), fitlab.read(path)
    assert back.channel_names == m.channel_names and back.n == m.n
    np.testing.assert_allclose(back.theta_i, m.theta_i, atol=1e-8)  # degrees, as fitlab's CSV
    np.testing.assert_allclose(back.value, m.value, rtol=1e-9)
    assert om.metadata_from(back.metadata) == om.metadata_from(m.metadata)


def test_camera_file_is_not_fitted_one_view_direction(tmp_path, capsys):
    out = tmp_path / "f.json"
    assert main(["fit", str(CAMERA), "--model", "lambertian", "--quiet", "--bootstrap", "0",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "example_material_camera_brdf.xompt" in err and "one view direction" in err
    assert "cannot constrain a BRDF model" in err and "several view directions" in err
    assert not out.exists()
    # the check sits where fitlab checks what it fits, so the Python API refuses it too
    with pytest.raises(FitlabError, match="share one view direction"):
        fitlab.fit(CAMERA, "lambertian", bootstrap=0)


def test_a_receiver_solid_angle_is_a_detector_cone(tmp_path):
    doc = json.loads(LIDAR.read_text())
    doc["brdf"]["receiverSolidAngles"] = [{"wavelength": 9.05e-07, "solidAngle": 1e-3}]
    path = tmp_path / "cone.xompt"
    path.write_text(json.dumps(doc))
    m = fitlab.read(path)
    alpha = np.degrees(np.arccos(1 - 1e-3 / (2 * np.pi)))  # Ω = 2π(1 − cos α)
    np.testing.assert_allclose(m.aperture_deg, alpha, rtol=1e-12)
    assert m.has_aperture


# --------------------------------------------------------------------------------------------
# Refusals: the broken examples, each message tested
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, fragment, hint", [
    ("openmaterial_degrees.xompt", "field brdf.lookupTable[0][1] (θi, rad) is 86: the largest "
     "angle in the table is 180, so the angles look like degrees", "× π/180"),
    ("openmaterial_missing_uuid.xompt", "field metadata.uuid is missing (the schema requires "
     "it)", "add it"),
    ("openmaterial_bad_uuid.xompt", "field metadata.uuid is 'asphalt-1'; the schema requires "
     "the pattern", "8-4-4-4-12"),
    ("openmaterial_short_row.xompt", "field brdf.lookupTable[3] has 4 entries; the schema "
     "requires at least 5", "a table row is"),
    ("openmaterial_negative.xompt", "field brdf.lookupTable[5][4] (BRDF, 1/sr) is -0.0013255; "
     "the schema requires >= 0", "a BRDF is >= 0"),
    ("openmaterial_zenith_out_of_range.xompt", "field brdf.lookupTable[2][2] (θo, rad) is 1.6; "
     "the schema requires <= 1.570796", "0 to π/2 rad"),
    ("openmaterial_null.xompt", "field brdf.lookupTable[4][4] (BRDF, 1/sr) is null", "give "
     "the value"),
    ("openmaterial_duplicate.xompt", "field brdf.lookupTable[3] repeats the wavelength and "
     "direction pair of brdf.lookupTable[2]", "merge repeated readings"),
    ("openmaterial_unlisted_wavelength.xompt", "field brdf.lookupTable[6][0] (wavelength, m) "
     "is 950 nm, which brdf.wavelengths does not list", "list every wavelength"),
    ("openmaterial_unused_wavelength.xompt", "field brdf.wavelengths[1] lists 1550 nm, which "
     "no row", "list only"),
    ("openmaterial_huge.xompt", "field brdf.lookupTable[1][4] (BRDF, 1/sr) is not a finite "
     "number", "finite number"),
    ("openmaterial_solid_angle.xompt", "field brdf.receiverSolidAngles[0].solidAngle is 7 sr",
     "steradians"),
    ("openmaterial_not_json.xompt", "is not valid JSON", "OpenMATERIAL"),
    ("openmaterial_completion_unmatched.xompt", "field fitlabCompletion.rows[1] names no row "
     "of brdf.lookupTable", "completed rows"),
])
def test_invalid(name, fragment, hint, capsys):
    path = INVALID / name
    before = path.read_bytes()
    with pytest.raises(InputFileError) as info:
        fitlab.read(path)
    err = info.value
    assert fragment in str(err) and str(path) in str(err), str(err)
    assert err.hint and hint in err.hint, err.hint
    assert path.read_bytes() == before
    assert main(["info", str(path)]) == 2  # exit 2, one line, no traceback
    message = capsys.readouterr().err
    assert fragment in message and "Traceback" not in message and len(message) < 600


def test_every_invalid_openmaterial_example_is_documented_and_tested():
    spec = (ROOT / "data_formats" / "openmaterial_xompt.md").read_text()
    tested = Path(__file__).read_text()
    found = list(INVALID.glob("openmaterial_*.xompt"))
    assert len(found) == 14
    for p in found:
        assert p.name in spec and p.name in tested, p.name


def test_examples_are_the_upstream_files_and_the_schema_is_theirs():
    for path in (LIDAR, CAMERA):  # valid against the schema, by jsonschema itself
        assert _valid_against_schema(json.loads(path.read_text())) == []
    if not SHARED.is_dir():
        from conftest import skip_or_fail

        skip_or_fail(f"{SHARED} is not here (the shared data folder sits beside the repository)")
    for path in (LIDAR, CAMERA):
        assert path.read_bytes() == (SHARED / path.name).read_bytes()
    assert om.SCHEMA_FILE.read_bytes() == (SHARED / "material_brdf_schema.json").read_bytes()


def test_schema_ships_as_package_data():
    import fnmatch
    import tomllib

    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]["fitlab"]
    rel = om.SCHEMA_FILE.relative_to(ROOT / "fitlab").as_posix()
    for name in (rel, str(Path(rel).parent / "LICENSE-openmaterial-MPL-2.0.txt"),
                 str(Path(rel).parent / "SOURCE-openmaterial.txt")):
        assert any(fnmatch.fnmatch(name, g) for g in globs), name
        assert (ROOT / "fitlab" / name).is_file()
    import jsonschema

    jsonschema.Draft7Validator.check_schema(om.schema())


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------

MODEL = ["--model", "lambertian+rough_conductor", "--param", "albedo=0.3", "--param",
         "alpha=0.2", "--param", "n=0.4", "--param", "k=2.4"]
PARAMS = {"albedo": 0.3, "alpha": 0.2, "n": 0.4, "k": 2.4}


def test_a_model_written_validates_reads_back_to_float32_and_reruns_to_the_same_bytes(
        tmp_path, capsys):
    out, again = tmp_path / "m.xompt", tmp_path / "again.xompt"
    for path in (out, again):
        assert main(["convert", *MODEL, str(path), "--wavelength-nm", "550", "--author", "me",
                     "--license", "CC0-1.0"]) == 0
    err = capsys.readouterr().err
    assert "7362 rows on the standard grid" in err and "550 nm" in err
    assert out.read_bytes() == again.read_bytes()
    doc = json.loads(out.read_text())
    assert _valid_against_schema(doc) == []
    meta = doc["metadata"]
    assert meta["authors"] == ["me"] and meta["license"] == "CC0-1.0"
    assert meta["copyrights"] == ["NOASSERTION"] and "creationDate" not in meta
    assert meta["name"] == "lambertian+rough_conductor" and meta["sources"] == "model (fitlab)"
    assert str(tmp_path) not in out.read_text()
    m = fitlab.read(out)
    assert m.channel_names == ("550nm",) and m.n == 18 * (17 * 24 + 1)
    assert sorted(set(m.theta_i)) == list(range(0, 90, 5))  # whole degrees read back whole
    assert sorted(set(m.phi_o)) == list(range(0, 360, 15))
    f = _model_values(m, "lambertian+rough_conductor", PARAMS)
    np.testing.assert_allclose(m.value, f, rtol=FLOAT32)
    assert oct(out.stat().st_mode & 0o044) == oct(0o044)  # readable by others


def test_export_of_a_channel_without_wavelength_says_how_to_write_it(tmp_path, capsys):
    out = tmp_path / "e.xompt"
    assert main(["export", "--model", "lambertian", "--param", "albedo=0.5", "--to",
                 "openmaterial", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "fitlab convert FIT.json OUT.xompt --wavelength-nm NM" in err and not out.exists()
    assert main(["export", "--model", "lambertian", "--param", "albedo=0.5", "--to",
                 "openmaterial", "--out", str(out), "--check"]) == 2
    assert "no renderer checks the openmaterial export" in capsys.readouterr().err


@pytest.fixture(scope="module")
def lidar_fit(tmp_path_factory):
    """A Lambertian fitted to the lidar file (the model structure other io tests compile)."""
    folder = tmp_path_factory.mktemp("lidar")
    out = folder / "lidar_fit.json"
    assert main(["fit", str(LIDAR), "--model", "lambertian", "--starts", "2", "--bootstrap", "0",
                 "--quiet", "--out", str(out)]) == 0
    return out


def test_lidar_fit_written_on_its_own_grid(lidar_fit, tmp_path, capsys):
    rec = json.loads(lidar_fit.read_text())
    (fit,) = rec["fits"]
    assert fit["channel"] == "905nm"
    assert rec["data"]["metadata"]["openmaterial_license"] == "MPL-2.0"
    albedo = fit["parameters"]["albedo"]["value"]
    out = tmp_path / "fit.xompt"
    assert main(["convert", str(lidar_fit), str(out), "--grid-from", str(LIDAR)]) == 0
    assert "905 rows on the rows of example_material_lidar_brdf.xompt" in capsys.readouterr().err
    doc = json.loads(out.read_text())
    assert _valid_against_schema(doc) == []
    src = json.loads(LIDAR.read_text())
    # the grid file's rows, in its order (sorted as the standard requires)
    assert np.array_equal(np.array(doc["brdf"]["lookupTable"])[:, :4],
                          np.array(src["brdf"]["lookupTable"])[:, :4])
    meta = doc["metadata"]  # from the data's OpenMATERIAL header, with a uuid of its own
    assert meta["name"] == "asphalt_brdf_for_lidar" and meta["license"] == "MPL-2.0"
    assert meta["copyrights"] == ["(C) 2023-2024 DIVP"] and meta["authors"] == ["DIVP"]
    assert meta["sources"] == "measurement, model fitted by fitlab"
    assert meta["typicalSensorTechnology"] == "lidar" and meta["uuid"] != src["metadata"]["uuid"]
    assert meta["description"].startswith("Reflectance properties of asphalt for lidar sensor. "
                                          "The fitlab")
    m = fitlab.read(out)
    np.testing.assert_allclose(m.value, _model_values(m, "lambertian", {"albedo": albedo}),
                               rtol=FLOAT32)
    # fitlab export writes the same bytes (one writer function): on the standard grid
    conv, exp = tmp_path / "std.xompt", tmp_path / "exp.xompt"
    assert main(["convert", str(lidar_fit), str(conv)]) == 0
    assert main(["export", str(lidar_fit), "--to", "openmaterial", "--out", str(exp)]) == 0
    assert conv.read_bytes() == exp.read_bytes()
    assert main(["convert", str(lidar_fit), str(tmp_path / "x.xompt"), "--grid-from",
                 str(CAMERA)]) == 2
    assert "not 905 nm" in capsys.readouterr().err


def test_data_written_back_keeps_the_files_rows_and_header(tmp_path):
    from fitlab.export.openmaterial import data_table

    for path in (LIDAR, CAMERA):
        text, doc, _ = data_table(fitlab.read(path), path)
        src = json.loads(path.read_text())
        assert doc["metadata"] == src["metadata"] and doc["brdf"]["wavelengths"] == \
            src["brdf"]["wavelengths"]
        # as the file has them, but π (3.141592653589793), written as 3.14159265359: the
        # shortest decimal that reads back as 180° to the reader's 1e-9°
        got, want = np.array(doc["brdf"]["lookupTable"]), np.array(src["brdf"]["lookupTable"])
        differ = got != want
        assert np.all(want[differ] == np.pi) and np.all(got[differ] == 3.14159265359)


def test_other_data_written_with_the_default_header(tmp_path, capsys):
    scan = EXAMPLES / "spectral_scan.csv"
    out = tmp_path / "scan.xompt"
    assert main(["convert", str(scan), str(out), "--quantity", "radiance_factor",
                 "--sensor", "camera"]) == 0
    doc = json.loads(out.read_text())
    assert _valid_against_schema(doc) == []
    meta = doc["metadata"]
    assert meta["name"] == "spectral_scan" and meta["license"] == "NOASSERTION"
    assert meta["authors"] == meta["copyrights"] == ["NOASSERTION"]
    assert meta["sources"] == "data converted by fitlab from spectral_scan.csv"
    assert meta["typicalSensorTechnology"] == "camera" and len(meta["uuid"]) == 36
    back, m = fitlab.read(out), fitlab.read(scan, quantity="radiance_factor")
    assert back.channel_names == m.channel_names and back.n == m.n
    key = lambda x: np.lexsort((x.phi_o, x.theta_o, x.theta_i, x.channel))  # noqa: E731
    np.testing.assert_allclose(back.value[key(back)], m.value[key(m)], rtol=FLOAT32)
    np.testing.assert_array_equal(back.theta_o[key(back)], m.theta_o[key(m)])


def test_writer_refusals(tmp_path):
    from fitlab.export.material import material_from_model
    from fitlab.export.openmaterial import material_table

    grey = material_from_model("lambertian", {"Y": {"albedo": 0.5}})
    with pytest.raises(FitlabError, match="give --wavelength-nm"):
        material_table(grey)
    rgb = material_from_model("lambertian", {c: {"albedo": 0.5} for c in "RGB"})
    with pytest.raises(FitlabError, match="--channel NAME"):
        material_table(rgb, wavelength_nm=550)
    spectral = material_from_model("lambertian", {"550nm": {"albedo": 0.5}})
    with pytest.raises(FitlabError, match="drop --wavelength-nm"):
        material_table(spectral, wavelength_nm=550)
    aniso = material_from_model("rough_conductor_anisotropic", {"550nm": {
        "alpha_x": 0.1, "alpha_y": 0.3, "n": 0.2, "k": 3.0}})
    with pytest.raises(FitlabError, match="anisotropic"):
        material_table(aniso)
    with pytest.raises(FitlabError, match="applies to a fit or a model"):
        from fitlab.export.openmaterial import data_table

        data_table(fitlab.read(LIDAR), LIDAR, grid_from=LIDAR)


def test_the_written_example_is_what_the_script_makes():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_openmaterial_examples", EXAMPLES / "make_openmaterial_examples.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.written_example() == WRITTEN.read_text(encoding="utf-8")
    doc = json.loads(WRITTEN.read_text())
    assert _valid_against_schema(doc) == []
    m = fitlab.read(WRITTEN)
    assert m.channel_names == ("450nm", "550nm", "650nm") and m.n == 3 * 99
    for c, name in enumerate(m.channel_names):
        rows = m.channel == c
        f = np.asarray(fitlab.eval_bsdf(script.MODEL, script.CHANNELS[name], m.wi[rows],
                                        m.wo[rows]))
        np.testing.assert_allclose(m.value[rows], f, rtol=FLOAT32)


def test_fittable_check_is_on_the_fitted_rows():
    """One view direction is refused per channel, naming the file; two are fitted."""
    from fitlab.fitting.channel import fitted_rows

    m = fitlab.read(CAMERA)
    rows = np.ones(m.n, dtype=bool)
    with pytest.raises(FitlabError, match=r"example_material_camera_brdf.xompt: the 59 rows of "
                       r"channel 390nm to fit share one view direction \(θo = 0°, φo = 0°\)"):
        fitted_rows(m, 0, rows)
    lidar = fitlab.read(LIDAR)
    name, _, picked = fitted_rows(lidar, 0, np.ones(lidar.n, dtype=bool))
    assert name == "905nm" and picked.sum() == 905
