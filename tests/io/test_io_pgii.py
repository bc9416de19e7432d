"""pab pgII text scans: synthetic files written from a model (DSF, BSDF, detector units, CIE-XYZ),
the cosine handling, duplicates, broken files, the CLI, and the real raw scan from
rgl-epfl/tekari read from the shared data folder (never copied: its licence is unknown)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.io import pgii
from fitlab.io.directions import degrees_to_direction
from fitlab.io.formats import detect_format, read_any
from fitlab.io.measurement import read_measurement

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "tekari_pgII" / \
    "golden_glossy_paper_pgII_theta26.84.txt"
PARAMS = {"alpha": 0.25, "n": 1.2, "k": 2.4}
THETA_I, PHI_I = 35.0, 0.0


def _grid():
    t, p = np.meshgrid(np.arange(2.5, 88, 5.0), np.arange(-177.5, 180, 15.0), indexing="ij")
    return t.ravel(), p.ravel()


def _model_values(theta_o, phi_o, kind, scale=1.0):
    wo = degrees_to_direction(theta_o, phi_o)
    wi = np.broadcast_to(degrees_to_direction(THETA_I, PHI_I), wo.shape)
    f = np.asarray(fitlab.eval_bsdf("rough_conductor", PARAMS, wi, wo))
    with_cos = kind == "DSF" or kind.startswith("[")
    return f * (np.abs(wo[:, 2]) if with_cos else 1.0) * scale


def pgii_text(rows, kind="DSF", theta_i=THETA_I, phi_i=PHI_I, declared=True, header=(),
              colorimetry=None):
    lines = ['#pgII synthetic data written by tests/io/test_io_pgii.py',
             '#sample_name\t"Synthetic conductor"', f"#incident_angle\t{theta_i:g}\t{phi_i:g}",
             f"#intheta\t{theta_i:g}", f"#inphi\t{phi_i:g}", *header]
    if colorimetry:
        lines.append(f"#colorimetry: {colorimetry}")
    if declared is True:
        lines.append(f"#datapoints_in_file\t{len(rows)}")
    elif declared is not None:
        lines.append(f"#datapoints_in_file\t{declared}")
    lines.append(f"#format: theta\tphi\t{kind}")
    lines += [r if isinstance(r, str) else "\t".join(f"{x:.17g}" for x in r) for r in rows]
    return "\n".join(lines) + "\n"


def _rows(kind, scale=1.0):
    t, p = _grid()
    v = _model_values(t, p, kind, scale)
    return [np.array([a, b, c]) for a, b, c in zip(t, p, v)]


def _write(tmp_path, text, name="scan.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


# --------------------------------------------------------------------------------------------
# Conversions
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, quantity, file_quantity, scale", [
    ("DSF", "bsdf", "bsdf_cos", 1.0), ("BSDF", "bsdf", "bsdf", 1.0),
    ("BRDF", "bsdf", "bsdf", 1.0), ("[uA]", "relative", "relative (bsdf_cos)", 3.7e-3)])
def test_values_become_f(tmp_path, kind, quantity, file_quantity, scale):
    path = _write(tmp_path, pgii_text(_rows(kind, scale), kind=kind))
    assert detect_format(path).name == "pgii"
    m = read_any(path)
    assert (m.quantity, m.file_quantity) == (quantity, file_quantity)
    t, p = _grid()
    assert m.n == t.size and m.channel_names == ("Y",)
    np.testing.assert_array_equal(m.theta_i, THETA_I)
    f = np.asarray(fitlab.eval_bsdf("rough_conductor", PARAMS, m.wi, m.wo))
    np.testing.assert_allclose(m.value, f * scale, rtol=1e-12)
    assert m.lines[0] == 8 and m.metadata["sample"] == "Synthetic conductor"


def test_cie_xyz_three_channels_and_back_side(tmp_path):
    rows = [np.array([30.0, 180.0, 0.1, 0.2, 0.3]), np.array([150.0, 10.0, 0.4, 0.5, 0.6])]
    m = pgii.read_pgii(_write(tmp_path, pgii_text(rows, colorimetry="CIE-XYZ")))
    assert m.channel_names == ("X", "Y", "Z") and m.n == 6
    c30, c150 = np.cos(np.radians(30)), abs(np.cos(np.radians(150)))
    np.testing.assert_allclose(m.value, np.array([0.1 / c30, 0.4 / c150, 0.2 / c30, 0.5 / c150,
                                                  0.3 / c30, 0.6 / c150]), rtol=1e-12)
    assert m.wo[1, 2] < 0 and m.wi[1, 2] > 0  # θ > 90°: the back (transmission) side
    assert list(m.channel) == [0, 0, 1, 1, 2, 2]


def test_header_forms_with_colons_and_spaces(tmp_path):
    text = ("#sample_name \"A\"\n#incident_angle: 10 20\n#datapoints_in_file: 2\n"
            "#format: theta phi BSDF\n5 0 1.0\n6 0 2.0\n")
    m = pgii.read_pgii(_write(tmp_path, text))
    assert (m.theta_i[0], m.phi_i[0]) == (10.0, 20.0) and m.value.tolist() == [1.0, 2.0]


def test_duplicates_are_averaged_or_refused(tmp_path):
    rows = ["10\t0\t1.0", "20\t30\t2.0", "10\t360\t3.0", "30\t0\t4.0", "20\t30\t6.0"]
    path = _write(tmp_path, pgii_text(rows, kind="BSDF"))
    m = pgii.read_pgii(path)
    assert m.n == 3 and m.metadata["duplicates_averaged"] == "2"
    np.testing.assert_allclose(m.value, [2.0, 4.0, 4.0])  # (1+3)/2, (2+6)/2, 4; first lines kept
    assert m.theta_o.tolist() == [10.0, 20.0, 30.0] and m.lines.tolist() == [8, 9, 11]
    with pytest.raises(InputFileError, match="repeats the direction of line 8") as info:
        pgii.read_pgii(path, duplicates="error")
    assert info.value.line == 10
    with pytest.raises(FitlabError, match="duplicates='sum'"):
        pgii.read_pgii(path, duplicates="sum")


def test_negative_detector_noise_only_in_raw_units(tmp_path):
    rows = ["10\t0\t-1e-6", "20\t0\t2.0"]
    assert pgii.read_pgii(_write(tmp_path, pgii_text(rows, kind="[uA]"))).value[0] < 0
    with pytest.raises(InputFileError, match="negative, which a calibrated DSF cannot be") as info:
        pgii.read_pgii(_write(tmp_path, pgii_text(rows, kind="DSF"), "dsf.txt"))
    assert info.value.line == 8


# --------------------------------------------------------------------------------------------
# Broken files
# --------------------------------------------------------------------------------------------

GOOD = ["10\t0\t1.0", "20\t30\t2.0", "30\t60\t3.0"]


@pytest.mark.parametrize("text, line, fragment", [
    (pgii_text(GOOD, declared=4), 6, "'#datapoints_in_file 4' but the file has 3 data lines"),
    (pgii_text(GOOD, declared="many"), 6, "is not a whole number"),
    (pgii_text(GOOD[:1] + ["20\t3O\t2.0"] + GOOD[2:]), 9, "'3O' is not a number"),
    (pgii_text(GOOD[:2] + ["30\t60"]), 10, "has 2 fields, expected 3"),
    (pgii_text(GOOD[:2] + ["30,60,3.0"]), 10, "has 1 fields, expected 3"),
    (pgii_text(GOOD[:2] + ["30\t60\tnan"]), 10, "not finite"),
    (pgii_text(GOOD[:2] + ["181\t60\t3.0"]), 10, "theta_out 181° is outside [0°, 180°]"),
    (pgii_text(GOOD[:2] + ["30\t400\t3.0"]), 10, "phi_out 400° is outside [-360°, 360°]"),
    (pgii_text(GOOD[:2] + ["90\t60\t3.0"]), 10, "lies in the surface plane"),
    (pgii_text(GOOD, kind="FOO"), 7, "quantity 'FOO' is unknown"),
    (pgii_text(GOOD, header=["#intheta\t40"]), 6, "'#intheta 40' disagrees with '#incident_angle"),
    (pgii_text(GOOD, colorimetry="RGB"), 6, "is not CIE-Y or CIE-XYZ"),
    (pgii_text(GOOD, theta_i=90), 3, "in the surface plane"),
    ("#sample_name \"x\"\n#format: theta phi DSF\n10 0 1\n", None, "states no incident angle"),
    ("#incident_angle 10 0\n#pgII raw\n10 0 1\n", None, "no '#format: theta phi <quantity>'"),
    ("#incident_angle 10 0\n#format: theta phi DSF\n", None, "has no data lines"),
    ("#incident_angle 10 zero\n#format: theta phi DSF\n10 0 1\n", 1, "needs 2 number(s)"),
])
def test_broken_files(tmp_path, text, line, fragment):
    path = _write(tmp_path, text)
    with pytest.raises(InputFileError) as info:
        pgii.read_pgii(path)
    assert fragment in str(info.value) and str(path) in str(info.value)
    assert info.value.line == line


def test_not_utf8(tmp_path):
    path = tmp_path / "scan.txt"
    path.write_bytes(b"#incident_angle 10 0\n#format: theta phi DSF\n10 0 \xff\n")
    with pytest.raises(InputFileError, match="not UTF-8") as info:
        pgii.read_pgii(path)
    assert info.value.line == 3


def test_detection_does_not_claim_other_files(tmp_path):
    csv = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / \
        "measurement_rgb_sigma.csv"
    assert detect_format(csv).name == "csv"
    assert not pgii.FORMAT.detect(b"# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n", None)


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_info_convert_fit(tmp_path, capsys):
    path = _write(tmp_path, pgii_text(_rows("[uA]", 2e-3), kind="[uA]"))
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "pgii" and info["quantity"] == "relative"
    assert info["file_values"] == "[uA] → relative (bsdf_cos)"
    assert info["points_read"] == info["rows"] == 18 * 24

    out = tmp_path / "scan.csv"
    assert main(["convert", str(path), str(out)]) == 0
    back = read_measurement(out)
    assert back.quantity == "relative" and back.n == info["rows"]
    np.testing.assert_allclose(back.value, read_any(path).value, rtol=1e-9)

    fit = tmp_path / "fit.json"
    assert main(["fit", str(path), "--model", "rough_conductor", "--fix", "n=1.2", "--fix",
                 "k=2.4", "--starts", "2", "--quiet", "--out", str(fit)]) == 0
    p = json.loads(fit.read_text())["fits"][0]["parameters"]
    assert p["alpha"]["value"] == pytest.approx(0.25, rel=1e-6)
    assert p["scale"]["value"] == pytest.approx(2e-3, rel=1e-6)


def test_cli_error(tmp_path, capsys):
    path = _write(tmp_path, pgii_text(GOOD, declared=7))
    assert main(["convert", str(path), str(tmp_path / "out.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{path}:6:" in err and "datapoints_in_file" in err
    assert not (tmp_path / "out.csv").exists()


# --------------------------------------------------------------------------------------------
# The real raw scan (shared data folder; not part of the repository)
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def real():
    if not REAL.is_file():
        pytest.skip(f"the raw pgII scan {REAL.name} is not in ../shared/data/tekari_pgII "
                    "(licence unknown, so it is never copied into the repository)")
    return REAL


def test_real_scan(real):
    assert detect_format(real).name == "pgii"
    m = read_any(real)
    assert m.n == 127_039 and m.channel_names == ("Y",)
    assert (m.quantity, m.file_quantity) == ("relative", "relative (bsdf_cos)")
    assert m.theta_i[0] == pytest.approx(26.8421) and m.phi_i[0] == 0
    assert m.metadata["sample"] == "Golden_glossy_paper" and m.metadata["front_integral"] == "0.0263"
    # first data line (31): "89.98829  44.44809  2.138e-06", divided by |cos θo|
    assert m.lines[0] == 31
    assert m.value[0] == pytest.approx(2.138e-06 / np.cos(np.radians(89.98829)), rel=1e-12)
    # the peak of the raw signal is the mirror direction (θ 26.84°, φ 180° in fitlab's frame)
    scan = pgii.read_pgii_scan(real)
    peak = np.argmax(scan.values[:, 0])
    mirror = m.wi[0] * [-1, -1, 1]
    assert np.degrees(np.arccos(m.wo[peak] @ mirror)) < 5


def test_real_scan_integral_supports_the_dsf_reading(real):
    """pab's '#front_integral 0.0263' is ∫ signal dω: the signal is DSF-like (∝ f cos θo).
    Reading it as proportional to f instead would give ∫ signal·cos θo dω, 18% lower."""
    scan = pgii.read_pgii_scan(real)
    wo = degrees_to_direction(scan.theta_o, scan.phi_o)
    as_dsf, gap = pgii.hemisphere_integral(wo, scan.values[:, 0])
    as_f, _ = pgii.hemisphere_integral(wo, scan.values[:, 0] * wo[:, 2])
    assert as_dsf == pytest.approx(0.0263, rel=0.01)
    assert as_f / 0.0263 - 1 < -0.15
    assert gap < 12


def test_real_scan_cli_info(real, capsys):
    assert main(["info", str(real), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    check = info["front_hemisphere_check"]
    assert abs(check["relative_difference"]) < 0.01
    assert info["negative_values"] == 368 and info["datapoints_in_file"] == "127039"
