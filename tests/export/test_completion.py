"""Completed measurements (`fitlab convert DATA --complete FIT.json OUT`,
fitlab.complete_measurement; data_formats/completion_json.md): the places without reading are
filled by the fit and marked (CSV column, OpenMATERIAL field) or listed in the side record
(Zemax, MERL), the readings are written as they are, the same inputs give the same bytes, and
a fit of other channels or another quantity is refused with exit status 2 leaving nothing.

One fit is used throughout (the brown vinyl's lambertian+rough_conductor, a structure other
tests compile), on its own data or on a small CSV made of them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.export import zemax as zemax_export
from fitlab.io.validate import check_schema
from fitlab.io import zemax as zemax_io
from fitlab.io.directions import degrees_to_direction
from fitlab.io.measurement import MEASURED, format_measurement_csv

ROOT = Path(__file__).resolve().parents[2]
VINYL = ROOT / "data_formats" / "examples" / "zemax_brown_vinyl.bsdf"
FIT = ROOT / "fits" / "brown_vinyl_lambert_ggx_conductor.json"
RELATIVE_FIT = ROOT / "fits" / "walter_rough_glass.json"


def _convert(capsys, *argv):
    code = main(["convert", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def fit():
    return fitlab.load_fit(FIT)


def _vinyl_csv(path, nan_rows=(3, 17, 40)) -> np.ndarray:
    """60 readings of the brown vinyl at θi = 45° as a measurement CSV, NaN at ``nan_rows``;
    returns the true values of those rows."""
    m = fitlab.read(VINYL)
    m = m.select(m.theta_i == 45.0)._replace(gaps=None)
    m = m.select(np.arange(m.n) < 60)
    truth = m.value[list(nan_rows)].copy()
    value = m.value.copy()
    value[list(nan_rows)] = np.nan
    path.write_text(format_measurement_csv(m._replace(value=value)), encoding="utf-8")
    return truth


def test_nan_readings_of_a_csv_are_completed_marked_and_read_back_as_gaps(tmp_path, fit,
                                                                           capsys):
    data, out = tmp_path / "vinyl45.csv", tmp_path / "vinyl45_complete.csv"
    _vinyl_csv(data)
    m = fitlab.read(data)
    assert m.n == 57 and m.gaps.counts() == {"no_reading": 3}
    code, stdout, err = _convert(capsys, data, "--complete", FIT, out)
    assert code == 0, err
    assert "completed 3 of 60 values" in stdout and "no_reading 3" in stdout
    assert "SHA-256 differs" in err  # the fit was made from the Zemax file, noted
    back = fitlab.read(out)
    assert back.n == 57 and back.gaps.counts() == {"no_reading": 3}
    np.testing.assert_array_equal(back.value, m.value)  # the readings as they were
    g = back.gaps.rows
    np.testing.assert_allclose(g.value, fit.predict(g.wi, g.wo), rtol=1e-8)
    text = out.read_text()
    assert text.count(",no_reading\n") == 3 and text.count(f",{MEASURED}\n") == 57
    record = json.loads((tmp_path / "vinyl45_complete.csv.completion.json").read_text())
    check_schema(record, "completion", "the record")  # data_formats/schemas/completion.schema.json
    assert record["values"] == {"places": 60, "measured": 57, "completed": 3}
    assert record["output"]["marks"] == "in the file: its column completion"
    assert record["data"]["path"] == "vinyl45.csv" and record["fit"]["path"].endswith(
        "fits/brown_vinyl_lambert_ggx_conductor.json")
    listed = record["completed"]["rows"]
    assert len(listed) == 3 and {r[5] for r in listed} == {"no_reading"}
    (inc,) = record["by_incidence"]
    assert (inc["theta_i"], inc["completed"]) == (45.0, 3)
    assert inc["fit_rms_relative_error"] == record["fit_error"]["rms_relative_error"] > 0
    # a fit of the completed file fits its readings only: completing it again changes nothing
    again = tmp_path / "again.csv"
    fitlab.complete_measurement(out, FIT, again)
    assert fitlab.read(again).gaps.counts() == {"no_reading": 3}
    np.testing.assert_array_equal(fitlab.read(again).gaps.rows.value, g.value)


def test_zemax_completion_on_its_own_grid_with_its_record_is_reproducible(tmp_path, fit,
                                                                          capsys):
    out = tmp_path / "vinyl.bsdf"
    code, stdout, err = _convert(capsys, VINYL, "--complete", FIT, out)
    assert code == 0, err
    record_file = tmp_path / "vinyl.bsdf.completion.json"
    record = json.loads(record_file.read_text())
    # the stored zeros above the horizon, place by place of the file's own (plane-symmetric) grid
    zf = zemax_io.parse_zemax(VINYL)
    _, _, good = zemax_export.grid_directions(zemax_export.resolve_grid(VINYL), "BRDF")
    zeros = int(np.sum((zf.values[0] == 0) & good))
    assert record["completed_by_reason"] == {"no_reading": zeros, "blocked": 0,
                                             "uncovered": 0, "subset": 0}
    assert record["values"] == {"places": int(good.sum()), "measured": int(good.sum()) - zeros,
                                "completed": zeros}
    assert record["output"]["grid"] == {"source": "the data's own", "rotation": 1, "aoi": 13,
                                        "azimuth": 19, "radial": 11}
    assert sum(e["completed"] for e in record["by_incidence"]) == zeros
    assert f"completed {zeros} of" in stdout and "record" in stdout
    text = out.read_text()
    # the data's TIS lines and comments kept, the completion said in the header
    src = VINYL.read_text()
    assert [ln for ln in text.splitlines() if ln.startswith("TIS")] == \
        [ln for ln in src.splitlines() if ln.startswith("TIS")]
    assert "#Data Generated by Radiant Imaging's 'Imaging Sphere'" in text
    assert f"# completed_values: {zeros} of" in text and "vinyl.bsdf.completion.json" in text
    # read back: every place above the horizon a value, the readings unchanged
    m, back = fitlab.read(VINYL), fitlab.read(out)
    assert m.gaps.rows.n == 168  # the zeros, the plane-symmetric grid mirrored
    assert back.gaps is None and back.n == m.n + 168
    rows = {(round(a, 6), round(b, 6), round(c, 6)): v for a, b, c, v in
            zip(back.theta_i, back.theta_o, back.phi_o, back.value)}
    got = np.array([rows[(round(a, 6), round(b, 6), round(c, 6))]
                    for a, b, c in zip(m.theta_i, m.theta_o, m.phi_o)])
    np.testing.assert_allclose(got, m.value, rtol=1e-12)
    listed = np.array([r[1:5] + [r[6]] for r in record["completed"]["rows"]])
    wi = degrees_to_direction(listed[:, 0], listed[:, 1])
    wo = degrees_to_direction(listed[:, 2], listed[:, 3])
    np.testing.assert_allclose(listed[:, 4], fit.predict(wi, wo), rtol=1e-6)
    # the same inputs, the same bytes (through the Python API too)
    first = (out.read_bytes(), record_file.read_bytes())
    done = fitlab.complete_measurement(VINYL, FIT, out)
    assert (out.read_bytes(), record_file.read_bytes()) == first
    assert done["values"]["completed"] == zeros and str(tmp_path) not in first[1].decode()


def test_a_subset_expression_replaces_readings(tmp_path, capsys):
    out = tmp_path / "vinyl_edge.bsdf"
    code, stdout, err = _convert(capsys, VINYL, "--complete", FIT, out,
                                 "--complete-subset", "theta_o > 80")
    assert code == 0, err
    record = json.loads(Path(str(out) + ".completion.json").read_text())
    n = int(np.sum(fitlab.read(VINYL).theta_o > 80))
    assert record["subset"] == "theta_o > 80" and record["subset_readings"] == n > 0
    # the file's own grid holds azimuths 0-180° only: fewer places than the mirrored readings
    assert 0 < record["completed_by_reason"]["subset"] <= n
    assert record["fit_error"]["rows_scored"] == 3877 - n
    assert "subset" in stdout


def test_openmaterial_completion_lists_its_rows_in_the_file(tmp_path):
    out = tmp_path / "vinyl.xompt"
    done = fitlab.complete_measurement(VINYL, FIT, out, wavelength_nm=550.0)
    doc = json.loads(out.read_text())
    marks = doc["fitlabCompletion"]["rows"]
    assert len(marks) == done["values"]["completed"] == 168
    back = fitlab.read(out)
    assert back.gaps.counts() == {"no_reading": 168} and back.n == 3877


def _listing(tmp_path) -> list:
    return sorted(p.name for p in tmp_path.iterdir())


def test_mismatched_channels_are_refused_and_nothing_written(tmp_path, capsys):
    data = tmp_path / "rgb.csv"
    data.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value_R,value_G\n"
                    "0,0,10,180,0.05,NaN\n0,0,20,180,0.04,0.03\n", encoding="utf-8")
    before = _listing(tmp_path)
    code, _, err = _convert(capsys, data, "--complete", FIT, tmp_path / "out.csv")
    assert code == 2 and "channel(s) R, G" in err and "no fit of R, G" in err
    assert "Traceback" not in err and _listing(tmp_path) == before


def test_a_fit_of_another_quantity_or_conventions_is_refused_and_nothing_written(tmp_path, capsys):
    code, _, err = _convert(capsys, VINYL, "--complete", RELATIVE_FIT, tmp_path / "out.bsdf")
    assert code == 2 and "f up to an unknown scale" in err and "absolute f" in err
    assert _listing(tmp_path) == []
    code, _, err = _convert(capsys, VINYL, "--complete-subset", "theta_o > 80",
                            tmp_path / "out.bsdf")
    assert code == 2 and "--complete FIT.json" in err and _listing(tmp_path) == []
    other = json.loads(FIT.read_text())  # a fit made under other conventions
    other["conventions"]["frame"] = "local shading frame, normal = +y"
    fit = tmp_path / "other.json"
    fit.write_text(json.dumps(other), encoding="utf-8")
    code, _, err = _convert(capsys, VINYL, "--complete", fit, tmp_path / "out.bsdf")
    assert code == 2 and "conventions.frame" in err and _listing(tmp_path) == ["other.json"]


@pytest.mark.slow
def test_merl_completion_fills_every_bin_the_data_do_not_sample(tmp_path, fit):
    out = tmp_path / "vinyl.binary"
    done = fitlab.complete_measurement(VINYL, FIT, out)
    assert done["completed_by_reason"]["uncovered"] > 1e6
    assert done["completed"]["listed"] is False and "by_incidence_rest" in done
    table = fitlab.io.merl.read_merl_table(out)
    assert np.all(np.isfinite(table.brdf))
