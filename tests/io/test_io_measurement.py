"""Measurement CSV reader: conversions to the internal quantity, channels, and one test per
validation rule with a deliberately broken file (data_formats/examples/invalid/)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fitlab.errors import InputFileError
from fitlab.io.files import sha256_of
from fitlab.io.measurement import read_measurement

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"
INVALID = EXAMPLES / "invalid"


def test_walter_example():
    m = read_measurement(EXAMPLES / "walter_rough_glass.csv")
    assert m.n == 276 and m.quantity == "relative" and m.channel_names == ("Y",)
    assert m.eta() == pytest.approx(1.51)
    assert m.metadata["scatter"] == "btdf"
    # relative_to bsdf_cos_i: the stored signal was divided by |cos θi|.
    raw = np.loadtxt(EXAMPLES / "walter_rough_glass.csv", delimiter=",", comments="#", skiprows=11)
    np.testing.assert_allclose(m.value * np.abs(m.wi[:, 2]), raw[:, 4], rtol=1e-15)
    assert m.sha256 == sha256_of(EXAMPLES / "walter_rough_glass.csv")


def test_wide_rgb_with_sigma():
    m = read_measurement(EXAMPLES / "measurement_rgb_sigma.csv")
    assert m.channel_names == ("R", "G", "B")
    assert m.n == 12
    r = m.channel == 0
    np.testing.assert_allclose(m.value[r], [0.21, 1.95, 0.64, 0.30])
    np.testing.assert_allclose(m.sigma[m.channel == 2], [0.01, 0.05, 0.02, 0.01])
    assert m.quantity == "bsdf" and m.metadata["sample"] == "painted aluminium coupon"


def test_channel_column_and_bsdf_cos():
    m = read_measurement(EXAMPLES / "measurement_channel_column.csv")
    assert m.channel_names == ("R", "G")
    # bsdf_cos is divided by |cos θo| on reading, sigma too.
    np.testing.assert_allclose(m.value[0], 1.69 / np.cos(np.radians(30)), rtol=1e-14)
    np.testing.assert_allclose(m.sigma[2], 0.02 / np.cos(np.radians(45)), rtol=1e-14)


def test_spectral():
    m = read_measurement(EXAMPLES / "measurement_spectral.csv")
    assert m.channel_names == ("450nm", "550nm")
    np.testing.assert_array_equal(m.wavelength_nm, [450.0, 550.0])
    assert m.is_relative and m.eta() == pytest.approx(1.5)


def test_relative_allows_negative(tmp_path):
    f = tmp_path / "neg.csv"
    f.write_text("# quantity: relative\ntheta_i,phi_i,theta_o,phi_o,value\n0,0,30,180,-0.01\n"
                 "0,0,40,180,2\n")
    m = read_measurement(f)
    assert m.value[0] == -0.01


def test_select_keeps_provenance():
    m = read_measurement(EXAMPLES / "walter_rough_glass.csv")
    s = m.select(m.theta_i == 0)
    assert s.n == 69 and s.sha256 == m.sha256 and np.all(s.theta_i == 0)


@pytest.mark.parametrize(
    "name, line, column, fragment",
    [
        ("measurement_no_quantity.csv", None, None, "'# quantity: ...' is missing"),
        ("measurement_bad_quantity.csv", 1, None,
         "is not one of bsdf, bsdf_cos, radiance_factor, relative"),
        ("measurement_no_value.csv", None, None, "lacks the column value"),
        ("measurement_unknown_column.csv", 2, "weight", "unknown column"),
        ("measurement_non_numeric.csv", 4, "value", "'n/a' is not a number"),
        ("measurement_inf.csv", 3, "value", "not a finite number"),
        ("measurement_angle_out_of_range.csv", 3, "theta_i", "outside [0°, 180°]"),
        ("measurement_in_surface_plane.csv", 3, "theta_o", "surface plane"),
        ("measurement_below_horizon.csv", 5, "theta_o", "other side of the surface"),
        ("measurement_duplicate.csv", 5, None, "repeats the directions of line 3"),
        ("measurement_negative.csv", 4, "value", "negative"),
        ("measurement_zero_sigma.csv", 3, "sigma", "not a positive uncertainty"),
        ("measurement_partial_channel_sigma.csv", None, None, "not for G"),
        ("measurement_bad_eta.csv", 2, None, "must be a positive number"),
        ("measurement_bom.csv", 1, None, "byte-order mark"),
        ("measurement_mixed_delimiters.csv", 4, None, "tab"),
        ("measurement_empty.csv", None, None, "is empty"),
        ("measurement_header_only.csv", None, None, "no data rows"),
        ("measurement_aperture_out_of_range.csv", 4, "aperture_deg",
         "95° is not a cone half-angle in [0°, 90°)"),
        ("measurement_bad_aperture_line.csv", 2, None, "'# aperture_deg:' is -2"),
        ("measurement_bin_partial.csv", 2, None, "but not phi_o_lo, phi_o_hi"),
        ("measurement_outside_bin.csv", 4, "theta_o", "θo = 35° lies outside its bin [20°, 30°]"),
        ("measurement_bin_crosses_horizon.csv", 3, "theta_o_hi", "crosses the surface plane"),
        ("measurement_cone_and_bin.csv", 4, "aperture_deg", "both a detector cone and a bin"),
        ("measurement_bad_dataset_label.csv", 4, "dataset", "'-bad label' is not a dataset label"),
        ("measurement_dataset_duplicate.csv", 5, None, "repeats the directions of line 3"),
        ("measurement_rows_short.csv", 2, None, "'# rows: 6' but the file has 4 data rows"),
    ],
)
def test_invalid(name, line, column, fragment):
    path = INVALID / name
    before = path.read_bytes()
    with pytest.raises(InputFileError) as info:
        read_measurement(path)
    err = info.value
    assert (err.line, err.column) == (line, column), str(err)
    assert fragment in str(err) and str(path) in str(err)
    assert err.hint or "." in str(err)
    assert path.read_bytes() == before


def test_every_invalid_measurement_example_is_documented_and_tested():
    spec = (EXAMPLES.parent / "measurement_csv.md").read_text()
    tested = Path(__file__).read_text()
    for p in INVALID.glob("measurement_*.csv"):  # (sanity_*: tests/io/test_sanity_gates.py)
        assert p.name in spec, f"{p.name} missing from measurement_csv.md"
        assert p.name in tested, f"{p.name} has no test"


def test_btdf_rule(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("# quantity: bsdf\n# scatter: btdf\ntheta_i,phi_i,theta_o,phi_o,value\n"
                 "0,0,170,0,1\n0,0,10,0,1\n")
    with pytest.raises(InputFileError, match="same side") as info:
        read_measurement(f)
    assert info.value.line == 5


def test_mixed_wide_and_long(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value,value_R\n0,0,10,0,1,1\n")
    with pytest.raises(InputFileError, match="mixes per-channel"):
        read_measurement(f)


def test_sigma_without_value_channel(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value_R,sigma_G\n0,0,10,0,1,1\n")
    with pytest.raises(InputFileError, match="no matching value_G"):
        read_measurement(f)


def test_bad_wavelength(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,wavelength_nm,value\n0,0,10,0,-5,1\n")
    with pytest.raises(InputFileError) as info:
        read_measurement(f)
    assert (info.value.line, info.value.column) == (3, "wavelength_nm")


def test_angles_that_look_like_radians_are_refused_by_every_reader_but_info(tmp_path, capsys):
    """Issue 14, then issue 34: a file whose angles all lie in [0, π] is refused (exit 2) with
    the fix, which info reports instead; whole-degree angles near normal incidence are not.
    (The gates' own tests: tests/io/test_sanity_gates.py.)"""
    from fitlab.cli import main
    from fitlab.io.formats import read_any

    rows = "\n".join(f"0.5236,0,{t:.4f},3.1416,0.{k + 1}" for k, t in enumerate((0.1, 0.3, 0.6, 0.9, 1.2)))
    src = tmp_path / "rad.csv"
    src.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n" + rows + "\n")
    with pytest.raises(InputFileError, match="look like radians") as e:
        read_any(src)
    assert "--angles radians" in str(e.value) and "180/π" in str(e.value)
    assert main(["info", str(src)]) == 0
    assert "look like radians" in capsys.readouterr().out
    out = tmp_path / "o.csv"
    assert main(["convert", str(src), str(out)]) == 2 and not out.exists()
    assert "--angles radians" in capsys.readouterr().err
    deg = tmp_path / "deg.csv"
    deg.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n"
                   + "\n".join(f"0,0,{t},180,0.5" for t in (1, 2, 3, 4, 5)) + "\n")
    assert read_any(deg).accepted == ()  # whole degrees near normal incidence


def test_brdf_angle_on_the_far_side_hint_says_how_to_write_it(tmp_path):
    from fitlab.errors import InputFileError
    from fitlab.io.measurement import read_measurement

    src = tmp_path / "far.csv"
    src.write_text("# quantity: bsdf\n# scatter: brdf\ntheta_i,phi_i,theta_o,phi_o,value\n"
                   "30,0,120,0,0.5\n")
    with pytest.raises(InputFileError) as e:
        read_measurement(src)
    assert "φo + 180°" in str(e.value) and "only if the file really holds transmitted" in str(e.value)


def test_dataset_column_splits_rows_keeping_channels_and_provenance(tmp_path):
    m = read_measurement(EXAMPLES / "measurement_datasets.csv")
    assert m.dataset_names == ("frosted_a", "frosted_b", "frosted_c")
    parts = m.datasets()
    assert [d.metadata["dataset"] for d in parts] == list(m.dataset_names)
    assert sum(d.n for d in parts) == m.n and all(d.sha256 == m.sha256 for d in parts)
    assert all(d.dataset is None and d.channel_names == ("Y",) for d in parts)
    b = m.dataset_named("frosted_b")
    assert np.array_equal(b.value, m.value[m.dataset == 1])
    with pytest.raises(KeyError, match="frosted_a, frosted_b, frosted_c"):
        m.dataset_named("nope")
    # wide channels: each dataset keeps only the channels it has rows of
    f = tmp_path / "w.csv"
    f.write_text("# quantity: bsdf\ndataset,theta_i,phi_i,theta_o,phi_o,channel,value\n"
                 "s1,0,0,10,0,R,0.5\ns1,0,0,10,0,G,0.4\ns2,0,0,10,0,G,0.3\n")
    w = read_measurement(f)
    s1, s2 = w.datasets()
    assert s1.channel_names == ("R", "G") and s2.channel_names == ("G",)
    assert list(s2.channel) == [0] and s2.value[0] == 0.3
    g = tmp_path / "wide.csv"
    g.write_text("# quantity: bsdf\ndataset,theta_i,phi_i,theta_o,phi_o,value_R,value_G\n"
                 "s1,0,0,10,0,0.5,0.4\ns2,0,0,10,0,0.3,0.2\n")
    wide = read_measurement(g)
    assert list(wide.dataset) == [0, 0, 1, 1]
    assert list(wide.dataset_named("s2").value) == [0.3, 0.2]
    # round trip through fitlab's writer keeps the column
    from fitlab.io.measurement import format_measurement_csv

    out = tmp_path / "rt.csv"
    out.write_text(format_measurement_csv(m))
    back = read_measurement(out)
    assert back.dataset_names == m.dataset_names and np.array_equal(back.dataset, m.dataset)


@pytest.mark.parametrize("later, fragment", [
    ("0,0,10,180,0.3\n0,0,20,180\n", "fields but the header"),  # a short row after it
    ("0,0,10,180,0.3\n0\t0,20,180,0.2\n", "tab"),  # a tab after it
    ("0,0,10,180,inf\n", "finite"),  # another bad cell after it (a NaN value is no reading)
])
def test_a_bad_cell_is_named_before_any_later_error(tmp_path, later, fragment):
    """The columns are converted at once; the error is still the first bad cell in file order
    (its line and column), even when a later line holds another error."""
    p = tmp_path / "m.csv"
    p.write_text("theta_i,phi_i,theta_o,phi_o,value\n0,0,0,0,0.5\n0,0,5,0,x1\n" + later,
                 encoding="utf-8")
    with pytest.raises(InputFileError) as e:
        read_measurement(p)
    assert e.value.line == 3 and e.value.column == "value" and "'x1'" in str(e.value)
    p.write_text("theta_i,phi_i,theta_o,phi_o,value\n0,0,0,0,0.5\n" + later, encoding="utf-8")
    with pytest.raises(InputFileError, match=fragment):
        read_measurement(p)
