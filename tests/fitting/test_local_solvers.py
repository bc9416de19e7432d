"""The single fit's Levenberg–Marquardt solvers (fitlab/fitting/solvers.py): fitlab's own (the
default) and jaxopt's (the reference) reach the same optimum from the same starts, and each
says in the parameter file which one ran."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.fitting.solvers import LOCAL_SOLVERS

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"


@pytest.fixture(scope="module")
def fits():
    m = fitlab.read(WALTER)
    return {s: fitlab.fit(m, "rough_dielectric", subset="theta_i == 30", starts=2, bootstrap=0,
                          local_solver=s) for s in LOCAL_SOLVERS}


def test_both_solvers_reach_the_same_optimum_from_the_same_starts(fits):
    own, ref = fits["fitlab"], fits["jaxopt"]
    for name, p in ref.parameters["Y"].items():
        assert own.parameters["Y"][name] == pytest.approx(p, rel=1e-6), name
    a, b = (f.record["fits"][0] for f in (own, ref))
    assert [s["start"] for s in a["starts"]] == [s["start"] for s in b["starts"]]
    for sa, sb in zip(a["starts"], b["starts"]):  # every start, not only the best
        assert sa["cost"] == pytest.approx(sb["cost"], rel=1e-6)
        assert sa["lm_stopped"] == sb["lm_stopped"] == "converged"
    assert a["solver"]["algorithm"] == LOCAL_SOLVERS["fitlab"].algorithm
    assert b["solver"]["algorithm"] == LOCAL_SOLVERS["jaxopt"].algorithm
    assert a["solver"]["algorithm"] != b["solver"]["algorithm"]


def test_the_command_line_chooses_the_solver(tmp_path, capsys):
    out = tmp_path / "fit.json"
    args = ["fit", str(WALTER), "--model", "rough_dielectric", "--fit-subset", "theta_i == 30",
            "--starts", "2", "--bootstrap", "0", "--quiet", "--out", str(out)]
    assert main(args + ["--local-solver", "jaxopt"]) == 0
    fit = json.loads(out.read_text(encoding="utf-8"))["fits"][0]
    assert fit["solver"]["algorithm"].startswith("jaxopt")
    with pytest.raises(SystemExit) as stop:
        main(args + ["--local-solver", "scipy"])
    assert stop.value.code == 2 and "--local-solver" in capsys.readouterr().err
    assert not np.isnan(fit["parameters"]["alpha"]["value"])
