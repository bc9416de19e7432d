"""The places of a file's table that hold no reading (Measurement.gaps): a measurement CSV's NaN
values and its completion column, a Zemax file's stored zeros, a spectral scan's blocked
zeros; kept beside the readings (never fitted) with their reason, and the CSV rules around
them (data_formats/measurement_csv.md, "No reading, and completed rows")."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fitlab.errors import InputFileError
from fitlab.io.formats import read_any
from fitlab.io.measurement import read_measurement

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"
HEAD = "# quantity: bsdf\n"


def _csv(tmp_path, text) -> Path:
    p = tmp_path / "m.csv"
    p.write_text(HEAD + text, encoding="utf-8")
    return p


def test_nan_values_are_gaps_of_their_channel(tmp_path):
    m = read_measurement(_csv(tmp_path, "theta_i,phi_i,theta_o,phi_o,value_R,value_G\n"
                                        "0,0,10,180,0.5,NaN\n0,0,20,180,nan,0.3\n"
                                        "0,0,30,180,0.4,0.2\n"))
    assert m.n == 4 and np.all(np.isfinite(m.value))
    assert m.gaps.counts() == {"no_reading": 2}
    assert [m.channel_names[c] for c in m.gaps.rows.channel] == ["G", "R"]
    assert list(m.gaps.rows.theta_o) == [10.0, 20.0]
    assert m.metadata["rows_without_reading"] == "2 (no_reading 2)"


def test_completion_column_reads_filled_rows_as_gaps(tmp_path):
    m = read_measurement(_csv(tmp_path, "theta_i,phi_i,theta_o,phi_o,value,sigma,completion\n"
                                        "0,0,10,180,0.5,0.1,measured\n"
                                        "0,0,20,180,0.45,nan,uncovered\n"
                                        "0,0,30,180,nan,nan,measured\n"
                                        "0,0,40,180,0.3,0.1,measured\n"))
    assert m.n == 2 and list(m.gaps.reason) == ["uncovered", "no_reading"]
    assert m.gaps.rows.value[0] == 0.45 and np.isnan(m.gaps.rows.value[1])


@pytest.mark.parametrize("text, fragment", [
    ("theta_i,phi_i,theta_o,phi_o,value,sigma\n0,0,10,180,0.5,nan\n0,0,20,180,0.4,0.1\n",
     "NaN (no reading) beside a value"),
    ("theta_i,phi_i,theta_o,phi_o,value\n0,0,10,180,nan\n0,0,20,180,NaN\n", "holds no reading"),
    ("theta_i,phi_i,theta_o,phi_o,value,completion\n0,0,10,180,0.5,guessed\n",
     "'guessed' is not a completion label"),
    ("theta_i,phi_i,theta_o,phi_o,value_R,completion\n0,0,10,180,0.5,measured\n",
     "completion column"),
    ("theta_i,phi_i,theta_o,phi_o,value\n0,0,10,180,-nan\n", "not a finite number"),
    ("theta_i,phi_i,theta_o,phi_o,value\nnan,0,10,180,0.5\n", "not a finite number"),
])
def test_what_no_reading_does_not_allow(tmp_path, text, fragment):
    with pytest.raises(InputFileError, match=re.escape(fragment)):
        read_measurement(_csv(tmp_path, text))


def test_zemax_stored_zeros_and_blocked_scan_readings_are_gaps():
    m = read_any(EXAMPLES / "zemax_brown_vinyl.bsdf")
    assert m.gaps.counts() == {"no_reading": m.metadata["masked_zero"]} == {"no_reading": 168}
    assert np.all(m.gaps.rows.theta_o > 84) and np.all(np.isnan(m.gaps.rows.value))
    scan = read_any(EXAMPLES / "spectral_scan.csv", quantity="radiance_factor")
    assert scan.gaps.counts() == {"blocked": 15}
