"""The fit's model check (fitlab/fitting/model_check.py; data_formats/fit_json.md, "Model
check"): a layered model against the simulation of its own fitted stack at the fitted rows.

Cheap: the tiny RGB example (4 rows a channel) and coated(lambertian), whose scene other tests
simulate; the simulator's kernels compile once per process."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError
from fitlab.fitting import model_check as mc
from fitlab.fitting.request import FitRequest
from fitlab.models import get_model

DATA = "data_formats/examples/measurement_rgb_sigma.csv"
COATED = "coated(lambertian)"
PARAMS = {"coat_eta": 1.5, "coat_tau": 0.3, "albedo": 0.7}


def _rows():
    m = fitlab.read(DATA)
    return m.select(m.channel == 0)


def _options(model):
    return {**model.default_options(), "interreflection": "closed_form"}


def test_samples_rows_and_budget_rules():
    assert mc.samples_for(0.04, pilot=500) == 2000  # (0.04 / 0.02)² × 500
    assert mc.samples_for(0.001) == mc.MIN_SAMPLES
    assert mc.samples_for(float("inf")) == mc.MAX_SAMPLES
    idx = mc.row_subset(np.arange(10_000), cap=100)
    assert idx.size == 100 and idx[0] == 0 and idx[-1] == 9_999
    assert mc.budget_s(1.0) == mc.MIN_BUDGET_S and mc.budget_s(100.0) == 20.0


def test_request_checks_the_mode():
    assert FitRequest("lambertian").check_model == "auto"
    with pytest.raises(FitlabError, match="--check-model must be one of auto, on, off"):
        FitRequest("lambertian", check_model="sometimes", spelling="cli")


def test_not_layered_models_are_not_applicable_and_off_is_recorded():
    rows = _rows()
    for name in ("lambertian", "rough_conductor", "oren_nayar"):
        model = get_model(name)
        params = {p.name: p.default for p in model.parameters}
        rec, secs = mc.check_channel(model, params, model.default_options(), rows, 0.1,
                                     mode="on")
        assert rec["status"] == "not_applicable" and secs == 0.0, name
        assert mc.check_line("Y", rec) is None and mc.check_text(rec) is None
    model = get_model(COATED)
    rec, secs = mc.check_channel(model, PARAMS, _options(model), rows, 0.1, mode="off")
    assert rec == {"status": "skipped", "reason": "check_model off (--check-model off)",
                   "fit_error": 0.1} and secs == 0.0
    assert "skipped" in mc.check_line("R", rec)


def test_auto_skips_over_its_budget_and_says_why():
    model = get_model(COATED)
    rec, _ = mc.check_channel(model, PARAMS, _options(model), _rows(), 0.1, mode="auto",
                              fit_seconds=0.0, min_budget_s=0.0)
    assert rec["status"] == "skipped"
    assert rec["reason"].startswith("auto: estimated") and "over the budget" in rec["reason"]
    assert "--check-model on runs it" in mc.check_line("R", rec)


def test_fit_with_check_model_on_records_and_prints_both_errors(tmp_path, capsys):
    """A coated(lambertian) fit of the tiny example's R channel: the record's model_check (its
    schema), the terminal line, and the model's own error small (the closed form is exact for
    its stack) against the fit's."""
    out = tmp_path / "fit.json"
    assert main(["fit", DATA, "--model", COATED, "--channel", "R", "--fix", "coat_eta=1.5",
                 "--fix", "coat_tau=0.3", "--option", "interreflection=closed_form",
                 "--starts", "0", "--bootstrap", "0", "--check-model", "on",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "channel R: model vs its own stack: " in err and "; fit vs data: " in err
    rec = json.loads(out.read_text())
    check = rec["fits"][0]["model_check"]
    assert check["status"] == "run" and check["rows"] == 4 and check["estimator"] == "point"
    assert check["samples"] >= mc.MIN_SAMPLES and check["relative_se"] <= mc.TARGET_SE
    assert check["model_error"] < 0.05
    assert check["fit_error"] == rec["fits"][0]["statistics"]["fit_error"]["rms_relative_error"]
    from fitlab.io.validate import check_schema

    check_schema(rec, "fit", out)
    assert "Model check: the model against" in mc.check_text(check)
