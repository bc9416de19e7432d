"""Spectral in-plane scan CSV (issue 37, item 2; data_formats/spectral_scan_csv.md): detection,
the sign convention against fitlab's mirror direction, blocked zeros, the declared quantity, the
broken examples, and info / convert / fit through the CLI on the bundled excerpt and the real
file in the shared data folder (never copied whole)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.io import spectral_scan
from fitlab.io.formats import detect_format
from fitlab.io.measurement import read_measurement

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
EXAMPLE = EXAMPLES / "spectral_scan.csv"
INVALID = EXAMPLES / "invalid"
REAL = ROOT.parent / "shared" / "data" / "ansys_optical_automation" / \
    "test_brdf_viewer_2D_data.csv"


def _real() -> Path:
    if not REAL.is_file():
        from conftest import skip_or_fail

        skip_or_fail(f"{REAL} is not here (the shared data folder sits beside the repository)")
    return REAL


def test_example_is_detected_and_read_as_spectral_channels():
    assert detect_format(EXAMPLE).name == "spectral_scan"
    m = fitlab.read(EXAMPLE, quantity="radiance_factor")
    assert m.channel_names == ("450nm", "550nm", "650nm")
    np.testing.assert_array_equal(m.wavelength_nm, [450.0, 550.0, 650.0])
    # 34 rows x 3 bands, less 5 blocked rows (3 at 10°, 2 at 60°) x 3 bands
    assert m.n == 34 * 3 - 5 * 3 and m.quantity == "bsdf" and m.file_quantity == "radiance_factor"
    assert set(m.phi_i) == {0.0} and set(m.phi_o) == {0.0, 180.0}
    # line 3: 10,-78,0.7194,... -> theta_o = 78 on the light's side (phi_o = 0), f = value / pi
    j = np.flatnonzero((m.lines == 3) & (m.channel == 0))[0]
    assert (m.theta_i[j], m.theta_o[j], m.phi_o[j]) == (10.0, 78.0, 0.0)
    assert m.value[j] == pytest.approx(0.7194 / np.pi, rel=1e-12)


def test_specular_peak_lands_at_the_mirror_direction_of_fitlabs_frame():
    from fitlab.frame import reflect

    m = fitlab.read(EXAMPLE, quantity="bsdf")
    mirror = np.asarray(reflect(m.wi, np.array([0.0, 0.0, 1.0])))
    for t in np.unique(m.theta_i):
        for c in range(len(m.channel_names)):
            rows = np.flatnonzero((m.theta_i == t) & (m.channel == c))
            peak = rows[np.argmax(m.value[rows])]
            np.testing.assert_allclose(m.wo[peak], mirror[peak], atol=1e-12)
            assert m.phi_o[peak] == 180.0 and m.theta_o[peak] == t


def test_blocked_zeros_are_no_reading_and_an_all_zero_scan_is_kept():
    v = np.array([[1.0, 0.0], [0.0, 0.0], [2.0, 0.0], [0.0, 3.0], [0.5, 0.0]])
    ti = np.array([10.0, 10.0, 10.0, 20.0, 20.0])
    # the 0 between 1 and 2 (10°, band 0) and the 0 beside 3 (20°, band 1) are blocked; band 1
    # at 10° holds only zeros: kept as readings, as is nothing else
    np.testing.assert_array_equal(spectral_scan.blocked_mask(ti, v),
                                  [[False, False], [True, False], [False, False], [True, False],
                                   [False, True]])


def test_quantity_must_be_declared(tmp_path, capsys):
    with pytest.raises(InputFileError, match="--quantity") as err:
        fitlab.read(EXAMPLE)
    assert str(EXAMPLE) in str(err.value) and "undeclared quantity" in str(err.value)
    out = tmp_path / "o.csv"
    assert main(["convert", str(EXAMPLE), str(out)]) == 2
    e = capsys.readouterr().err
    assert "spectral_scan.csv" in e and "--quantity" in e and not out.exists()
    # info still describes it, saying the quantity is undeclared
    assert main(["info", str(EXAMPLE), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["quantity"] == "undeclared" and info["blocked_readings"] == 15
    assert info["blocked_by_incidence_deg"] == {"10": 9, "60": 6}
    assert any("undeclared" in w for w in info["warnings"])
    # --angles does not apply: the spec fixes degrees
    assert main(["info", str(EXAMPLE), "--angles", "radians"]) == 2
    assert "--angles" in capsys.readouterr().err


def test_each_quantity_converts_with_the_shared_conversion():
    f = fitlab.read(EXAMPLE, quantity="bsdf")
    rf = fitlab.read(EXAMPLE, quantity="radiance_factor")
    cos = fitlab.read(EXAMPLE, quantity="bsdf_cos")
    rel = fitlab.read(EXAMPLE, quantity="relative")
    np.testing.assert_allclose(rf.value, f.value / np.pi, rtol=1e-15)
    np.testing.assert_allclose(cos.value, f.value / np.abs(f.wo[:, 2]), rtol=1e-15)
    assert rel.quantity == "relative" and np.array_equal(rel.value, f.value)


def test_convert_writes_a_measurement_csv_that_reads_back(tmp_path, capsys):
    out = tmp_path / "scan.csv"
    assert main(["convert", str(EXAMPLE), str(out), "--quantity", "radiance_factor"]) == 0
    back = read_measurement(out)
    m = fitlab.read(EXAMPLE, quantity="radiance_factor")
    assert back.channel_names == m.channel_names and back.n == m.n
    np.testing.assert_allclose(np.sort(back.value), np.sort(m.value), rtol=1e-8)


@pytest.mark.parametrize("name, line, column, fragment", [
    ("spectral_scan_no_band.csv", 2, None, "has no band column"),
    ("spectral_scan_bad_wavelength.csv", 2, "0nm", "is not a positive wavelength"),
    ("spectral_scan_incident_out_of_range.csv", 5, "Incident_angle", "90° is outside [0°, 90°)"),
    ("spectral_scan_measure_out_of_range.csv", 5, "Measure_angle", "-95° is outside"),
    ("spectral_scan_duplicate.csv", 7, "Measure_angle", "repeats the angles of line 6"),
    ("spectral_scan_negative.csv", 5, "550nm", "-0.4 is negative"),
    ("spectral_scan_non_numeric.csv", 5, "450nm", "is not a number"),
    ("spectral_scan_short_row.csv", 5, None, "has 4 fields but the header names 5"),
])
def test_invalid(name, line, column, fragment):
    path = INVALID / name
    before = path.read_bytes()
    with pytest.raises(InputFileError) as info:
        fitlab.read(path, quantity="radiance_factor")
    err = info.value
    assert (err.line, err.column) == (line, column), str(err)
    assert fragment in str(err) and str(path) in str(err) and err.hint
    assert path.read_bytes() == before


def test_every_invalid_spectral_scan_example_is_documented_and_tested():
    spec = (ROOT / "data_formats" / "spectral_scan_csv.md").read_text()
    tested = Path(__file__).read_text()
    found = list(INVALID.glob("spectral_scan_*.csv"))
    assert len(found) == 8
    for p in found:
        assert p.name in spec and p.name in tested, p.name


def test_real_file_reads_with_its_blocked_readings(capsys):
    real = _real()
    assert main(["info", str(real), "--quantity", "radiance_factor", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "spectral_scan" and len(info["channels"]) == 35
    assert info["wavelength_nm"][0] == 390.0 and info["wavelength_nm"][-1] == 730.0
    assert info["rows_in_file"] == 329 and info["blocked_readings"] == 26 * 35
    assert info["rows"] == 329 * 35 - 26 * 35 and not info["warnings"]
    assert info["theta_i_deg"] == [10.0, 25.0, 40.0, 60.0, 80.0]


@pytest.mark.slow
def test_fit_one_band_of_the_example(tmp_path, capsys):
    out = tmp_path / "f.json"
    assert main(["fit", str(EXAMPLE), "--quantity", "radiance_factor", "--model",
                 "lambertian+rough_conductor", "--channel", "550nm", "--bootstrap", "0",
                 "--starts", "2", "--quiet", "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["data"]["read_options"] == {"quantity": "radiance_factor"}
    (fit,) = rec["fits"]
    assert fit["channel"] == "550nm"
