"""Direction-file reader: valid files parse; each deliberately broken example gets an error that
names the file, the line and column where they apply, and says what to do."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fitlab.errors import InputFileError
from fitlab.io.directions import degrees_to_direction, read_directions

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"


def test_bundled_example_parses():
    pairs = read_directions(EXAMPLES / "directions_inplane.csv")
    assert pairs.theta_i.shape == (148,)
    wi, wo = pairs.cartesian()
    np.testing.assert_allclose(np.linalg.norm(wi, axis=-1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=-1), 1.0, rtol=1e-15)
    assert set(pairs.theta_i) == {0.0, 30.0, 60.0, 80.0}


def test_degrees_to_direction_convention():
    # θ from +z, φ from +x: (90°, 0°) is +x, (90°, 90°) is +y, (180°, any) is -z.
    np.testing.assert_allclose(degrees_to_direction(90.0, 0.0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(degrees_to_direction(90.0, 90.0), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(degrees_to_direction(180.0, 33.0), [0, 0, -1], atol=1e-15)


def test_columns_in_any_order_and_comments(tmp_path):
    f = tmp_path / "d.csv"
    f.write_text("# sample: test\n\nphi_o,theta_o,phi_i,theta_i\n# inline comment\n180,30,0,45\n")
    pairs = read_directions(f)
    assert pairs.theta_i[0] == 45 and pairs.theta_o[0] == 30 and pairs.phi_o[0] == 180
    assert pairs.metadata == {"sample": "test"}


@pytest.mark.parametrize(
    "name, line, column, fragment",
    [
        ("directions_bom.csv", 1, None, "byte-order mark"),
        ("directions_non_numeric.csv", 2, "theta_o", "'thirty' is not a number"),
        ("directions_nan.csv", 2, "theta_o", "not a finite number"),
        ("directions_missing_column.csv", 1, None, "lacks the column(s) phi_o"),
        ("directions_unknown_column.csv", 1, "value", "unknown column"),
        ("directions_theta_out_of_range.csv", 2, "theta_o", "outside [0°, 180°]"),
        ("directions_semicolons.csv", 2, None, "semicolon"),
        ("directions_short_row.csv", 2, None, "has 3 fields but the header names 4"),
        ("directions_header_only.csv", None, None, "no data rows"),
    ],
)
def test_invalid_examples(name, line, column, fragment):
    path = EXAMPLES / "invalid" / name
    before = path.read_bytes()
    with pytest.raises(InputFileError) as info:
        read_directions(path)
    err = info.value
    assert err.path == str(path)
    assert err.line == line
    assert err.column == column
    assert fragment in str(err)
    assert str(path) in str(err)
    assert path.read_bytes() == before  # inputs are never modified


def test_every_invalid_example_is_tested():
    tested = {p.name for p in (EXAMPLES / "invalid").glob("directions_*.csv")}
    listed = (EXAMPLES.parent / "directions_csv.md").read_text()
    for name in tested:
        assert name in listed, f"{name} is not documented in directions_csv.md"


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_directions(tmp_path / "nope.csv")
    with pytest.raises(InputFileError, match="is a folder"):
        read_directions(tmp_path)


def test_empty_file(tmp_path):
    f = tmp_path / "empty.csv"
    f.write_text("")
    with pytest.raises(InputFileError, match="is empty"):
        read_directions(f)


def test_not_utf8(tmp_path):
    f = tmp_path / "latin1.csv"
    f.write_bytes(b"theta_i,phi_i,theta_o,phi_o\n# \xe9\n1,2,3,4\n")
    with pytest.raises(InputFileError) as info:
        read_directions(f)
    assert info.value.line == 2


def test_duplicate_header_column(tmp_path):
    f = tmp_path / "dup.csv"
    f.write_text("theta_i,phi_i,theta_o,phi_o,phi_o\n1,2,3,4,5\n")
    with pytest.raises(InputFileError, match="appears twice"):
        read_directions(f)


def test_header_missing_numbers_first(tmp_path):
    f = tmp_path / "noheader.csv"
    f.write_text("30,0,30,180\n")
    with pytest.raises(InputFileError, match="should be the header"):
        read_directions(f)


def test_phi_out_of_range(tmp_path):
    f = tmp_path / "phi.csv"
    f.write_text("theta_i,phi_i,theta_o,phi_o\n30,0,30,180\n30,400,30,180\n")
    with pytest.raises(InputFileError) as info:
        read_directions(f)
    assert info.value.line == 3 and info.value.column == "phi_i"
