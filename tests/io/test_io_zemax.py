"""Zemax / Radiant tabular BSDF (data_formats/zemax_bsdf.md): reading the brown vinyl example
(values, direction conversion, mirroring, masking, TIS check), round trips through fitlab's
writer (BRDF and BTDF, to file precision), the CLI (info, convert, fit) and every broken file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.export import zemax as zemax_out
from fitlab.io import zemax
from fitlab.io.directions import degrees_to_direction
from fitlab.io.formats import describe_any, detect_format, read_any
from fitlab.io.measurement import read_measurement

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
INVALID = EXAMPLES / "invalid"
VINYL = EXAMPLES / "zemax_brown_vinyl.bsdf"
SHARED = ROOT.parent / "shared" / "data" / "ansys_optical_automation"
BTDF_REFERENCE = SHARED / "test_13_brdf_one_wavelength_BTDF_zemax_reference.bsdf"
#: relative error of a value written with 5 significant digits
FILE_PRECISION = 5e-5 * (1 + 1e-9)


@pytest.fixture(scope="module")
def vinyl():
    return zemax.read_zemax(VINYL)


def _rows(m, theta_i):
    return m.select(np.isclose(m.theta_i, theta_i))


# --------------------------------------------------------------------------------------------
# The brown vinyl example
# --------------------------------------------------------------------------------------------


def test_brown_vinyl_header_and_counts(vinyl):
    zf = zemax.parse_zemax(VINYL)
    assert (zf.symmetry, zf.spectral, zf.scatter, zf.source) == \
        ("PlaneSymmetrical", "Monochrome", "BRDF", "Measured")
    assert zf.aoi.tolist() == list(range(15, 76, 5))
    assert (len(zf.aoi), len(zf.azimuth), len(zf.radial)) == (13, 19, 11)
    assert zf.radial.tolist() == [0, 5, 10, 15, 20, 30, 40, 50, 60, 70, 80]
    assert zf.values.shape == (1, 1, 13, 19, 11)
    assert zf.tis[0, 0, 0] == 0.134506 and zf.tis[0, 0, -1] == 0.2571892
    assert vinyl.channel_names == ("Y",) and vinyl.quantity == "bsdf" and vinyl.sigma is None
    # 13 blocks × 36 azimuths (19 stored + 17 mirrored) × 11 radials = 5148 grid points, of
    # which 455 are radial-0 repeats, 648 below the horizon and 168 stored zeros above it.
    md = vinyl.metadata
    assert (md["merged_repeated_directions"], md["masked_below_horizon"], md["masked_zero"]) == \
        (455, 648, 168)
    assert vinyl.n == 5148 - 455 - 648 - 168 == 3877
    assert "nonzero_below_horizon" not in md
    assert sorted(set(vinyl.theta_i.tolist())) == list(range(15, 76, 5))
    assert np.all(vinyl.phi_i == 0) and np.all(vinyl.wo[:, 2] > 0) and np.all(vinyl.value > 0)
    assert md["symmetry"] == "PlaneSymmetrical" and md["scatter"] == "brdf"
    assert "Radiant Imaging" in md["comment"]


@pytest.mark.parametrize("aoi, radial, azimuth, theta_o, phi_o, value, line", [
    (15, 0, 0, 15, 180, 6.375e-02, 19),      # the pole: specular direction
    (15, 15, 0, 0, 0, 5.529e-02, 19),        # 15° toward the normal from 15°: the normal
    (15, 80, 0, 65, 0, 3.219e-02, 19),       # through the normal to the light's side
    (15, 10, 180, 25, 180, 6.266e-02, 37),   # away from the normal: grazing side
    (75, 5, 180, 80, 180, 9.745, 277),       # last row of the file
    (75, 0, 90, 75, 180, 5.677, 259),        # radial 0 of the last block
])
def test_brown_vinyl_values_at_converted_directions(vinyl, aoi, radial, azimuth, theta_o, phi_o,
                                                    value, line):
    frame = zemax.scatter_frame(aoi, 0.0, "BRDF")
    wo = zemax.scatter_directions(frame, float(radial), float(azimuth))
    np.testing.assert_allclose(wo, degrees_to_direction(theta_o, phi_o), atol=1e-12)
    m = _rows(vinyl, aoi)
    j = np.flatnonzero(np.all(np.isclose(m.wo, wo, atol=1e-12), axis=1))
    assert j.size == 1, (aoi, radial, azimuth)
    assert m.value[j[0]] == pytest.approx(value, rel=1e-12)
    assert m.theta_o[j[0]] == pytest.approx(theta_o, abs=1e-6)
    if theta_o > 0:
        assert m.phi_o[j[0]] == pytest.approx(phi_o, abs=1e-6)
    if radial:
        assert m.lines[j[0]] == line


def test_radial_zero_is_the_specular_direction(vinyl):
    zf = zemax.parse_zemax(VINYL)
    for k, aoi in enumerate(zf.aoi):
        m = _rows(vinyl, aoi)
        mirror = m.wi * np.array([-1.0, -1.0, 1.0])
        j = np.flatnonzero(np.all(np.isclose(m.wo, mirror, atol=1e-12), axis=1))
        assert j.size == 1  # radial 0 of every azimuth merged into one row
        assert m.value[j[0]] == zf.values[0, 0, k, 0, 0]
        assert m.theta_o[j[0]] == pytest.approx(aoi) and m.phi_o[j[0]] == pytest.approx(180)


def test_plane_symmetric_data_are_mirrored(vinyl):
    key = {(round(t, 9), round(p, 9), round(ti, 9)): v for t, p, ti, v in
           zip(vinyl.theta_o, vinyl.phi_o, vinyl.theta_i, vinyl.value)}
    upper = (vinyl.phi_o > 1e-9) & (vinyl.phi_o < 180 - 1e-9)
    lower = (vinyl.phi_o > 180 + 1e-9)
    assert upper.sum() == lower.sum() > 1000
    for t, p, ti, v in zip(vinyl.theta_o[upper], vinyl.phi_o[upper], vinyl.theta_i[upper],
                           vinyl.value[upper]):
        assert key[(round(t, 9), round(360 - p, 9), round(ti, 9))] == v
    # the mirror image of a direction is its reflection in the plane of incidence (y -> -y)
    assert np.all(vinyl.wo[upper, 1] > 0) and np.all(vinyl.wo[lower, 1] < 0)


def test_azimuth_zero_points_toward_the_normal(vinyl):
    """Data-driven check of the orientation: the IS-SA's zeros (directions it does not see)
    all lie near grazing, and no nonzero value falls below the horizon."""
    with_zeros = zemax.read_zemax(VINYL, keep_zeros=True)
    assert with_zeros.n == vinyl.n + 168
    zeros = with_zeros.value == 0
    assert zeros.sum() == 168 and with_zeros.theta_o[zeros].min() > 80
    assert vinyl.theta_o.max() < 86


def test_tis_check_figures(vinyl):
    rows = {r["aoi"]: r for r in zemax.tis_check(zemax.parse_zemax(VINYL))}
    assert len(rows) == 13
    # research notes (independent integration): 0.130 vs 0.1345, 0.137 vs 0.160, 0.221 vs 0.257
    for aoi, notes, tis in ((15, 0.130, 0.134506), (50, 0.137, 0.1597279), (75, 0.221, 0.2571892)):
        assert rows[aoi]["tis"] == tis
        assert rows[aoi]["integral"] == pytest.approx(notes, abs=0.004)
    assert rows[15]["integral"] == pytest.approx(0.1302, abs=5e-5)
    assert rows[15]["difference"] == pytest.approx(-0.032, abs=5e-4)
    assert rows[75]["difference"] == pytest.approx(-0.152, abs=5e-4)
    assert rows[15]["coverage"] == pytest.approx(0.936, abs=5e-4)
    assert rows[75]["coverage"] == pytest.approx(0.519, abs=5e-4)
    assert all(r["integral"] < r["tis"] for r in rows.values())
    assert "AOI 15: 0.1302/0.1345" in vinyl.metadata["tis_check"]
    assert "-16.3% to -3.2%" in vinyl.metadata["tis_check"]


def test_cell_weights_cover_the_sphere():
    az = np.arange(0.0, 360.0, 10.0)
    w = zemax.cell_weights(np.arange(0.0, 181.0, 5.0), az)
    assert w.sum() == pytest.approx(4 * np.pi)
    # an azimuth sector that does not go round the circle is not closed periodically
    w = zemax.cell_weights(np.array([0.0, 90.0, 180.0]), np.array([0.0, 45.0, 90.0]))
    assert w.sum() == pytest.approx(np.pi)  # a quarter of the sphere


@pytest.mark.parametrize("scatter", ["BRDF", "BTDF"])
@pytest.mark.parametrize("aoi, rotation", [(0.0, 0.0), (30.0, 0.0), (45.0, 120.0), (80.0, -30.0)])
def test_scatter_frame(scatter, aoi, rotation):
    frame = zemax.scatter_frame(aoi, rotation, scatter)
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame) == pytest.approx(1.0)  # right-handed about the pole
    side = 1.0 if scatter == "BRDF" else -1.0
    wi = degrees_to_direction(aoi, rotation)
    pole = zemax.scatter_directions(frame, 0.0, 0.0)
    expected = wi * np.array([-1.0, -1.0, 1.0]) if scatter == "BRDF" else -wi  # η = 1
    np.testing.assert_allclose(pole, expected, atol=1e-12)
    if aoi > 0:  # radial = AOI toward azimuth 0 reaches the normal axis on the pole's side
        np.testing.assert_allclose(zemax.scatter_directions(frame, aoi, 0.0),
                                   [0, 0, side], atol=1e-12)
        # azimuth 0 then 90: e90 lies in the surface plane, normal to the plane of incidence
        e90 = zemax.scatter_directions(frame, 90.0, 90.0)
        assert e90[2] == pytest.approx(0, abs=1e-12)
        assert np.dot(e90, wi) == pytest.approx(0, abs=1e-12)


def test_incidence_angle_refraction():
    assert zemax.incidence_angle([30.0], "BRDF", 1.5)[0] == 30.0
    ti = zemax.incidence_angle([0.0, 19.4712206, 41.0], "BTDF", 1.5)
    np.testing.assert_allclose(np.sin(np.radians(ti)),
                               1.5 * np.sin(np.radians([0, 19.4712206, 41])))
    assert ti[1] == pytest.approx(30.0, abs=1e-6)
    with pytest.raises(ValueError, match="no refraction angle for eta = 1.5"):
        zemax.incidence_angle([50.0], "BTDF", 1.5)


# --------------------------------------------------------------------------------------------
# Writing and reading back
# --------------------------------------------------------------------------------------------


def _against_model(m, model, params, options=None):
    f = np.asarray(fitlab.eval_bsdf(model, params, m.wi, m.wo, options))
    assert np.all(f > 0)
    rel = np.abs(m.value / f - 1)
    assert rel.max() <= FILE_PRECISION, rel.max()
    return rel.max()


def test_round_trip_brdf(tmp_path):
    out = tmp_path / "conductor.bsdf"
    params = {"albedo": 0.2, "alpha": 0.25, "n": 1.5, "k": 3.0}
    model = "lambertian+rough_conductor"
    summary = zemax_out.write_zemax(out, model, params)
    assert summary["symmetry"] == "PlaneSymmetrical" and summary["grid"] == \
        {"rotation": 1, "aoi": 17, "azimuth": 19, "radial": 29}
    m = read_any(out)  # detected from the content
    assert m.channel_names == ("Y",) and np.all(m.wo[:, 2] > 0)
    assert sorted(set(np.round(m.theta_i, 9))) == [float(x) for x in range(0, 81, 5)]
    _against_model(m, model, params)
    # every grid point above the horizon came back once (radial 0 and 180 merged)
    zf = zemax.parse_zemax(out)
    assert m.metadata["masked_zero"] == 0
    assert m.n + m.metadata["masked_below_horizon"] + m.metadata["merged_repeated_directions"] \
        == 17 * 36 * 29
    # the written TIS is the model's albedo; the grid integral agrees to a few percent
    rows = zemax.tis_check(zf)
    assert max(abs(r["difference"]) for r in rows) < 0.02
    assert all(r["coverage"] == pytest.approx(1.0, abs=5e-3) for r in rows)
    assert m.metadata["model"] == model and "alpha=0.25" in m.metadata["parameters"]


def test_round_trip_btdf(tmp_path):
    out = tmp_path / "glass.bsdf"
    params = {"alpha": 0.3, "eta": 1.5}
    zemax_out.write_zemax(out, "rough_dielectric", params, scatter="btdf")
    text = out.read_text()
    assert "ScatterType  BTDF" in text and "# eta_inside: 1.5" in text
    m = zemax.read_zemax(out)
    assert m.eta() == 1.5 and "refracted ray for eta = n_inside/n_outside = 1.5 (file)" in \
        m.metadata["zemax_pole"]
    assert np.all(m.wo[:, 2] < 0) and np.all(m.wi[:, 2] > 0)
    # the standard grid puts the light at 0..80° even though the AOI column is refracted angles
    np.testing.assert_allclose(sorted(set(np.round(m.theta_i, 6))), np.arange(0, 81, 5), atol=1e-6)
    zf = zemax.parse_zemax(out)
    assert zf.aoi.max() == pytest.approx(np.degrees(np.arcsin(np.sin(np.radians(80)) / 1.5)))
    _against_model(m, "rough_dielectric", params)
    # radial 0 is the refracted ray: sin θt = sin θi / η, on the far side
    for ti in (30.0, 60.0):
        rows = _rows(m, ti)
        tt = np.degrees(np.arcsin(np.sin(np.radians(ti)) / 1.5))
        pole = degrees_to_direction(180 - tt, 180.0)
        j = np.flatnonzero(np.all(np.isclose(rows.wo, pole, atol=1e-9), axis=1))
        assert j.size == 1
    # the TIS lines agree with the model's transmittance: a dense quadrature at θi = 0
    th = np.linspace(90, 180, 1201)
    tc = (th[1:] + th[:-1]) / 2
    T, P = np.meshgrid(tc, np.arange(0.25, 360, 0.5), indexing="ij")
    wo = degrees_to_direction(T, P).reshape(-1, 3)
    f = np.asarray(fitlab.eval_bsdf("rough_dielectric", params,
                                    np.broadcast_to([0.0, 0.0, 1.0], wo.shape), wo))
    dom = np.abs(np.diff(np.cos(np.radians(th))))[:, None] * np.radians(0.5)
    quad = float(np.sum(f.reshape(T.shape) * np.abs(np.cos(np.radians(T))) * dom))
    assert zf.tis[0, 0, 0] == pytest.approx(quad, rel=5e-3)
    # read with η = 1 instead: the light moves to the AOI column, the values stay
    m1 = zemax.read_zemax(out, eta=1.0)
    assert m1.n == m.n and np.allclose(sorted(set(m1.theta_i)), zf.aoi)


def test_tristimulus_round_trip_and_layouts(tmp_path):
    out = tmp_path / "xyz.bsdf"
    params = {"X": {"albedo": 0.3}, "Y": {"albedo": 0.4}, "Z": {"albedo": 0.5}}
    zemax_out.write_zemax(out, "lambertian", params, aoi="0,40", azimuth="0:180:45", radial="0:90:30")
    text = out.read_text()
    assert "SpectralContent  XYZ" in text and text.count("DataBegin") == 3
    m = zemax.read_zemax(out)
    assert m.channel_names == ("X", "Y", "Z")
    for c, albedo in enumerate((0.3, 0.4, 0.5)):
        np.testing.assert_allclose(m.value[m.channel == c], albedo / np.pi, rtol=FILE_PRECISION)
    zf = zemax.parse_zemax(out)
    np.testing.assert_allclose(zf.tis[:, 0, :], [[0.3] * 2, [0.4] * 2, [0.5] * 2], rtol=1e-12)
    # one data section with the indicator lines inside reads the same
    one = tmp_path / "xyz_one_section.bsdf"
    one.write_text(text.replace("DataEnd\nTristimulusY\nDataBegin\n", "TristimulusY\n")
                   .replace("DataEnd\nTristimulusZ\nDataBegin\n", "TristimulusZ\n"))
    assert one.read_text().count("DataBegin") == 1
    m1 = zemax.read_zemax(one)
    np.testing.assert_array_equal(m1.value, m.value)
    np.testing.assert_array_equal(m1.channel, m.channel)


def test_lenient_header(tmp_path):
    text = VINYL.read_text()
    lenient = (text.replace("Symmetry  PlaneSymmetrical", "symmetry ASymmetrical4D")
               .replace("SampleRotation  1\n0\n", "")
               .replace("ScatterRadial 11\n", "scatterradial   11   0 5\n")
               .replace("\n0\t5\t10\t15\t20\t30\t40\t50\t60\t70\t80\t\n",
                        "\n10 15 20\n30\t40 50\n60 70 80\n"))
    assert lenient != text
    f = tmp_path / "lenient.bsdf"
    f.write_text(lenient)
    zf = zemax.parse_zemax(f)
    assert zf.symmetry == "Asymmetrical4D" and zf.rotation.tolist() == [0.0]
    assert zf.radial.tolist() == [0, 5, 10, 15, 20, 30, 40, 50, 60, 70, 80]
    # no mirroring: only the stored half
    m = zemax.read_zemax(f)
    assert np.all(m.wo[:, 1] >= -1e-12)


@pytest.mark.parametrize("edit, line, fragment", [
    (("ScatterType  BRDF\n", "ScatterType  BRDF\nScatterType  BRDF\n"), 7, "appears twice"),
    (("0\t5\t10\t15\t20\t30", "0\t5\t10\t10\t20\t30"), 14, "10° is listed twice"),
    (("Monochrome\nDataBegin", "TristimulusX\nDataBegin"), 16, "does not match"),
    (("SpectralContent  Monochrome", "SpectralContent  XYZ"), 16, "does not match"),
])
def test_more_header_errors(tmp_path, edit, line, fragment):
    f = tmp_path / "bad.bsdf"
    f.write_text(VINYL.read_text().replace(*edit, 1))
    with pytest.raises(InputFileError) as info:
        zemax.parse_zemax(f)
    assert info.value.line == line and fragment in str(info.value), str(info.value)


def test_missing_colour(tmp_path):
    f = tmp_path / "xyz.bsdf"
    zemax_out.write_zemax(f, "lambertian", {c: {"albedo": 0.5} for c in "XYZ"}, aoi="0", radial="0,30",
                      azimuth="0,180")
    text = f.read_text()
    f.write_text(text[: text.index("TristimulusZ")])
    with pytest.raises(InputFileError, match="no data blocks for channel.s. Z"):
        zemax.parse_zemax(f)


def test_btdf_aoi_beyond_the_critical_angle(tmp_path):
    f = tmp_path / "t.bsdf"
    f.write_text(VINYL.read_text().replace("ScatterType  BRDF", "ScatterType  BTDF"))
    assert zemax.read_zemax(f).n > 0  # η = 1: every AOI is a transmission angle
    with pytest.raises(InputFileError, match="AngleOfIncidence 45° is no refraction angle for "
                       "eta = 1.5"):
        zemax.read_zemax(f, eta=1.5)
    with pytest.raises(FitlabError, match="refracted ray"):
        zemax_out.resolve_grid(aoi="0,50", scatter="BTDF", eta=1.5)


def test_parse_angles():
    assert zemax_out.parse_angles("0:80:5", "aoi") == tuple(float(x) for x in range(0, 81, 5))
    assert zemax_out.parse_angles("30, 0,15", "aoi") == (0.0, 15.0, 30.0)
    assert zemax_out.parse_angles("0:1:0.25", "radial") == (0.0, 0.25, 0.5, 0.75, 1.0)
    for bad in ("", "a,b", "0:10:0", "10:0:5", "5,5", "nan"):
        with pytest.raises(FitlabError):
            zemax_out.parse_angles(bad, "aoi")
    with pytest.raises(FitlabError, match="outside"):
        zemax_out.resolve_grid(radial="0,190")


def test_btdf_of_a_reflector_is_refused(tmp_path):
    with pytest.raises(FitlabError, match="only in reflection"):
        zemax_out.write_zemax(tmp_path / "x.bsdf", "lambertian", {"albedo": 0.5}, scatter="BTDF")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# The 2.6 MB BTDF reference of ansys/optical-automation (read from ../shared when present)
# --------------------------------------------------------------------------------------------


def test_btdf_reference_file():
    if not BTDF_REFERENCE.is_file():
        pytest.skip(f"{BTDF_REFERENCE.name} is read from ../shared/data, which is absent here")
    zf = zemax.parse_zemax(BTDF_REFERENCE)
    assert (zf.symmetry, zf.scatter) == ("Asymmetrical", "BTDF")
    assert zf.aoi.tolist() == [0.0, 22.5, 45.0, 67.5]
    assert (len(zf.azimuth), len(zf.radial)) == (361, 181)
    m = zemax.to_measurement(zf)
    assert np.all(m.wo[:, 2] < 0) and np.all(m.value > 0)
    assert "undeviated (eta = 1 assumed" in m.metadata["zemax_pole"]
    rows = zemax.tis_check(zf)
    assert [round(r["difference"], 3) for r in rows] == [0.107, -0.097, -0.597, -0.995]
    assert all(r["coverage"] == pytest.approx(1.0, abs=1e-3) for r in rows)
    # support of the data at AOI 67.5°: radial up to 90 + 67.5 toward the normal (azimuth 0)
    v = zf.values[0, 0, 3]
    assert zf.radial[v[0] > 0].max() == 157 and zf.radial[v[180] > 0].max() == 22


# --------------------------------------------------------------------------------------------
# Broken files
# --------------------------------------------------------------------------------------------


INVALID_CASES = [
    ("zemax_truncated.bsdf", 45, None, "has 7 of its 19 azimuth rows before the end of the file"),
    ("zemax_unknown_keyword.bsdf", 4, None, "unknown keyword 'Symetry'"),
    ("zemax_bad_symmetry.bsdf", 4, None, "'Symmetry Rotational' is not one of"),
    ("zemax_missing_scattertype.bsdf", 15, None, "lacks the 'ScatterType' line"),
    ("zemax_count_mismatch.bsdf", 13, None, "'ScatterRadial 11' announces 11 angles but 10 follow"),
    ("zemax_short_row.bsdf", 25, None, "has 10 values but ScatterRadial lists 11 angles"),
    ("zemax_non_numeric.bsdf", 30, "value 4 (radial 15°)", "'5.8O9E-02' is not a number"),
    ("zemax_nan.bsdf", 42, "value 6 (radial 30°)", "'NaN' is not a finite number"),
    ("zemax_negative.bsdf", 50, "value 3 (radial 10°)", "is negative"),
    ("zemax_no_databegin.bsdf", 17, None, "data before DataBegin"),
    ("zemax_no_dataend.bsdf", 57, None, "no DataEnd line"),
    ("zemax_missing_tis.bsdf", 38, None, "a row of numbers outside a block"),
    ("zemax_extra_block.bsdf", 38, None, "a block more than the 1"),
    ("zemax_aoi_out_of_range.bsdf", 10, "AngleOfIncidence", "95° is outside [0°, 90°)"),
    ("zemax_empty.bsdf", None, None, "is empty"),
]


@pytest.mark.parametrize("name, line, column, fragment", INVALID_CASES)
def test_invalid(name, line, column, fragment):
    path = INVALID / name
    before = path.read_bytes()
    if name != "zemax_empty.bsdf":
        assert detect_format(path).name == "zemax"
    with pytest.raises(InputFileError) as info:
        zemax.read_zemax(path)
    err = info.value
    assert (err.line, err.column) == (line, column), str(err)
    assert fragment in str(err) and str(path) in str(err)
    assert err.hint, "every error says what to do"
    assert path.read_bytes() == before


def test_every_invalid_zemax_example_is_documented_and_tested():
    spec = (ROOT / "data_formats" / "zemax_bsdf.md").read_text()
    tested = {c[0] for c in INVALID_CASES}
    files = {p.name for p in INVALID.glob("zemax_*.bsdf")}
    assert files == tested
    for name in files:
        assert name in spec, f"{name} missing from zemax_bsdf.md"


@pytest.mark.parametrize("name", ["zemax_truncated.bsdf", "zemax_nan.bsdf",
                                  "zemax_count_mismatch.bsdf"])
def test_convert_leaves_nothing_on_failure(tmp_path, capsys, name):
    out = tmp_path / "out.csv"
    assert main(["convert", str(INVALID / name), str(out)]) == 2
    err = capsys.readouterr().err
    assert str(INVALID / name) in err and "fitlab convert: error:" in err
    assert list(tmp_path.iterdir()) == []


def test_convert_writer_failure_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "glass.bsdf"
    argv = ["convert", "--model", "rough_dielectric", "--param", "alpha=0.3", "--param",
            "eta=1.5", "--scatter", "BTDF", "--aoi", "0:60:10", str(out)]
    assert main(argv) == 2
    assert "no refraction angle" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# Registry and command line
# --------------------------------------------------------------------------------------------


def test_detection():
    assert detect_format(VINYL).name == "zemax"
    assert detect_format(EXAMPLES / "walter_rough_glass.csv").name == "csv"
    lighttools = b"#Data Generated by MiniDiff\nSymmetry Asymmetric\nScatterAzimuth 361\n" \
                 b"ScatterRadial 91\nDataBegin\nAOI 0\nPOI 0\nSide Front\n"
    assert not zemax.FORMAT.detect(lighttools, Path("x.bsdf"))


def test_info(capsys):
    assert main(["info", str(VINYL)]) == 0
    out = capsys.readouterr().out
    for fragment in ("format: zemax", "spec: data_formats/zemax_bsdf.md",
                     "symmetry: PlaneSymmetrical", "scatter_type: BRDF", "channels: ['Y']",
                     "unit: 1/sr (BSDF f, no cosine)", "scatter_radial_deg: [0.0, 5.0",
                     "angles_about: specular reflection", "stored_zero: 168",
                     "AOI 15: integral 0.1302 vs TIS 0.1345 (-3.2%); the grid spans 93.6%",
                     "AOI 75: integral 0.2181 vs TIS 0.2572 (-15.2%)", "largest_difference: 16.3%"):
        assert fragment in out, fragment
    assert main(["info", str(VINYL), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["rows"] == 3877 and info["angle_of_incidence_deg"][0] == 15.0
    assert describe_any(VINYL)["format"] == "zemax"


def test_convert_to_csv_and_back(tmp_path, vinyl, capsys):
    out = tmp_path / "vinyl.csv"
    assert main(["convert", str(VINYL), str(out)]) == 0
    assert "wrote 3877 rows (Y)" in capsys.readouterr().err
    m = read_measurement(out)
    assert m.n == vinyl.n
    np.testing.assert_array_equal(m.value, vinyl.value)
    np.testing.assert_allclose(m.wo, vinyl.wo, atol=1e-9)
    assert m.metadata["tis_check"] == vinyl.metadata["tis_check"]


def test_convert_model_to_zemax(tmp_path, capsys):
    out = tmp_path / "white.bsdf"
    assert main(["convert", "--model", "lambertian", "--param", "albedo=0.5", "--aoi", "0:60:30",
                 "--radial", "0:90:15", str(out)]) == 0
    assert "Zemax BRDF of lambertian (PlaneSymmetrical, Y), 3 AOI x 19 azimuth x 7 radial" in \
        capsys.readouterr().err
    zf = zemax.parse_zemax(out)
    np.testing.assert_allclose(zf.tis, 0.5, rtol=1e-12)  # Lambertian weights are the albedo
    m = zemax.read_zemax(out)
    np.testing.assert_allclose(m.value, 0.5 / np.pi, rtol=FILE_PRECISION)


def test_convert_relative_fit_to_zemax(tmp_path, capsys):
    fit = ROOT / "fits" / "walter_rough_glass.json"
    rec = json.loads(fit.read_text())
    params = {k: v["value"] for k, v in rec["fits"][0]["parameters"].items() if k != "scale"}
    assert "scale" in rec["fits"][0]["parameters"]
    out = tmp_path / "walter.bsdf"
    assert main(["convert", str(fit), str(out), "--scatter", "BTDF", "--aoi", "0,20,40",
                 "--radial", "0:180:10"]) == 0
    err = capsys.readouterr().err
    assert "'scale' parameter is not applied" in err and "Zemax BTDF of rough_dielectric" in err
    m = zemax.read_zemax(out)
    assert "not applied" in m.metadata["note"] and m.eta() == pytest.approx(params["eta"])
    _against_model(m, "rough_dielectric", params, rec["model"]["options"])


def test_convert_argument_errors(tmp_path, capsys):
    out = tmp_path / "x.bsdf"
    assert main(["convert", str(VINYL), str(out)]) == 2
    assert "measured data would need resampling" in capsys.readouterr().err
    assert main(["convert", str(VINYL), str(tmp_path / "x.csv"), "--aoi", "0,10"]) == 2
    assert "--aoi: applies to Zemax output only" in capsys.readouterr().err
    assert main(["convert", "--model", "lambertian", "--param", "albedo=0.5", "a.bsdf",
                 "b.bsdf"]) == 2
    assert list(tmp_path.iterdir()) == []


def test_convert_help_documents_zemax(capsys):
    with pytest.raises(SystemExit):
        main(["convert", "--help"])
    out = capsys.readouterr().out
    for fragment in ("OUTPUT.bsdf", "zemax_bsdf.md", "--grid", "--scatter", "--aoi", "--azimuth",
                     "--radial", "--model", "--param", "scale", "measurement CSV"):
        assert fragment in out, fragment


def test_fit_reads_zemax_through_the_registry(tmp_path):
    out = tmp_path / "vinyl.json"
    assert main(["fit", str(VINYL), "--model", "lambertian", "--quiet", "--starts", "2",
                 "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["data"]["rows"] == 3877 and rec["data"]["quantity"] == "bsdf"
    assert "tis_check" in rec["data"]["metadata"]
    # diffuse level ≈ 0.064 1/sr → albedo ≈ π · 0.064
    assert rec["fits"][0]["parameters"]["albedo"]["value"] == pytest.approx(0.20, abs=0.01)


@pytest.mark.parametrize("key, value", [("eta_inside", "-1.5"), ("eta_inside", "glass"),
                                        ("eta_outside", "0"), ("eta_inside", "nan"),
                                        ("eta_outside", "inf"), ("eta_inside", "x" * 300)])
@pytest.mark.parametrize("command", ["info", "convert", "fit"])
def test_bad_refractive_index_comments_are_refused(tmp_path, capsys, key, value, command):
    """Issue 13: a bad '# eta_inside/outside:' comment in a Zemax file was used (NaN and
    negative angles written by convert, a ZeroDivisionError or ValueError traceback in info,
    convert and fit). Now: exit 2, the file and line named, a short message, nothing written."""
    src = tmp_path / "bad.bsdf"
    src.write_text(f"# {key}: {value}\n" + VINYL.read_text(encoding="latin-1"), encoding="latin-1")
    before = src.read_bytes()
    out = tmp_path / ("out.csv" if command == "convert" else "fit.json")
    args = {"info": [str(src)], "convert": [str(src), str(out)],
            "fit": [str(src), "--model", "lambertian", "--out", str(out)]}[command]
    assert main([command, *args]) == 2
    err = capsys.readouterr().err
    assert f"{src}:1: '# {key}: " in err and "must be a positive number" in err
    assert len(err) < 400 and "Traceback" not in err
    assert not out.exists() and src.read_bytes() == before


def test_header_counts_cannot_size_a_huge_allocation(tmp_path, capsys):
    """Issue 13: a 7 kB header declaring 721 × 90 × 721 × 181 values made the reader allocate
    189 GiB before reading any data. The counts are checked against the numbers present first."""
    lines = VINYL.read_text(encoding="latin-1").splitlines()
    out, i = [], 0
    sizes = {"SampleRotation": 721, "AngleOfIncidence": 90, "ScatterAzimuth": 721,
             "ScatterRadial": 181}
    while i < len(lines):
        key = lines[i].split()[0] if lines[i].split() else ""
        if key in sizes:
            n = sizes[key]
            out += [f"{key}  {n}", "\t".join(f"{x * 0.1:.1f}" for x in range(n))]
            i += 2
            continue
        out.append(lines[i])
        i += 1
    src = tmp_path / "huge.bsdf"
    src.write_text("\n".join(out) + "\n", encoding="latin-1")
    assert main(["info", str(src)]) == 2
    err = capsys.readouterr().err
    assert "ScatterRadial) is 8,468,209,890 but the file holds only" in err and "Traceback" not in err
