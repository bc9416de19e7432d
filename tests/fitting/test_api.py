"""The Python API of fitting (issue 14, item 1): fitlab.read, fitlab.fit, fitlab.load_fit and
FitResult, and that the CLI is a thin layer over them (same bytes)."""

from __future__ import annotations

import dataclasses
import doctest
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"


@pytest.fixture(scope="module")
def result():
    return fitlab.fit(fitlab.read(WALTER), "rough_dielectric", subset="theta_i == 0", starts=2)


def test_docstring_examples_run(monkeypatch):
    monkeypatch.chdir(ROOT)
    import fitlab.fitting.api as api

    failed, attempted = doctest.testmod(api, optionflags=doctest.ELLIPSIS)
    assert attempted >= 8 and failed == 0


def test_result_is_immutable_and_complete(result):
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.path = "x"
    with pytest.raises(TypeError):
        result.record["loss"] = "log"
    names, cov = result.covariance()
    assert names == ("alpha", "scale") and cov.shape == (2, 2) and not cov.flags.writeable
    assert np.isclose(np.sqrt(cov[0, 0]), result.stderr["Y"]["alpha"])
    assert result.samples() is None and result.posterior() is None
    st = result.statistics()
    assert st["n_fit"] == 69 and st["per_incidence"]
    assert result.diagnostics()["solver"]["stopped"] == "converged"
    assert result.warnings == {"Y": []}
    assert "alpha=" in repr(result)
    with pytest.raises(ValueError):
        result.covariance("R")


def test_predict_is_the_model_times_scale(result):
    p = result.parameters["Y"]
    m = fitlab.read(WALTER)
    pred = result.predict(m.wi[:5], m.wo[:5])
    f = fitlab.eval_bsdf("rough_dielectric", {k: v for k, v in p.items() if k != "scale"},
                         m.wi[:5], m.wo[:5])
    assert np.allclose(pred, p["scale"] * np.asarray(f), rtol=1e-12)
    assert np.allclose(result.predict(m.wi[:5], m.wo[:5], scaled=False), f, rtol=1e-12)
    assert result.predict(m.wi[0], m.wo[0]).shape == ()


def test_save_load_round_trip_and_cli_gives_the_same_bytes(result, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    saved = result.save(tmp_path / "api.json")
    loaded = fitlab.load_fit(tmp_path / "api.json")
    assert loaded.parameters == result.parameters and loaded.to_json() == saved.to_json()
    assert (tmp_path / "api.json").read_text() == saved.to_json()
    assert main(["fit", str(WALTER.relative_to(ROOT)), "--model", "rough_dielectric",
                 "--fit-subset", "theta_i == 0", "--starts", "2", "--quiet",
                 "--out", str(tmp_path / "cli.json")]) == 0
    assert (tmp_path / "cli.json").read_bytes() == (tmp_path / "api.json").read_bytes()
    # saving a loaded fit elsewhere keeps its data path pointing at the same file
    (tmp_path / "sub").mkdir()
    again = loaded.save(tmp_path / "sub" / "copy.json")
    assert (tmp_path / "sub" / Path(again.record["data"]["path"])).resolve() == WALTER.resolve()


def test_mcmc_samples_and_report(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    r = fitlab.fit(WALTER, "rough_dielectric", subset="theta_i == 0", starts=2, mcmc=True,
                   mcmc_steps=300, walkers=8, seed=3)
    s = r.samples()
    assert s.shape[1] == 2 and np.isfinite(s).all() and set(r.posterior()) == {"alpha", "scale"}
    summary = fitlab.write_report(r, tmp_path / "rep")
    assert Path(summary["index"]).is_file() and (tmp_path / "rep" / "fit.json").is_file()
    back = fitlab.load_fit(tmp_path / "rep" / "fit.json")
    assert np.array_equal(back.samples(), s)


def test_errors_say_what_to_do():
    m = fitlab.read(WALTER)
    with pytest.raises(FitlabError, match="has no parameter 'gamma'"):
        fitlab.fit(m, "rough_dielectric", fix={"gamma": 1})
    with pytest.raises(FitlabError, match="channels Y"):
        fitlab.fit(m, "rough_dielectric", channels=["R"])
    with pytest.raises(FitlabError, match="a mask of 276 rows"):
        fitlab.fit(m, "rough_dielectric", subset=np.ones(3, bool))
    with pytest.raises(FitlabError, match="see `fitlab models`"):
        fitlab.fit(m, "no_such_model")
    for bad in (0, True, 2.5, 10**9):
        with pytest.raises(FitlabError, match="lm_maxiter must be an integer from 1"):
            fitlab.fit(m, "rough_dielectric", lm_maxiter=bad)


def test_start_adds_one_levenberg_marquardt_start_at_the_given_values(result):
    m = fitlab.read(WALTER)
    res = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", starts=2,
                     start={"alpha": 0.05})
    starts = res.record["fits"][0]["starts"]
    assert len(starts) == len(result.record["fits"][0]["starts"])  # the extra start replaced
    # eta is fixed from the file; the scale of the relative data starts mid-range as always
    assert set(starts[-1]["start"]) == {"alpha", "scale"}
    assert starts[-1]["start"]["alpha"] == pytest.approx(0.05, rel=1e-12)
    assert result.record["fits"][0]["starts"][-1]["start"]["alpha"] != 0.05
    # the same optimum as without it (the extra start does not change a well-posed fit)
    assert res.parameters["Y"]["alpha"] == pytest.approx(result.parameters["Y"]["alpha"], rel=1e-6)


def test_start_errors_name_the_parameter_and_what_to_do(tmp_path, capsys):
    m = fitlab.read(WALTER)
    with pytest.raises(FitlabError, match="start gamma: model 'rough_dielectric' has no "):
        fitlab.fit(m, "rough_dielectric", start={"gamma": 1})
    with pytest.raises(FitlabError, match="outside its bounds"):
        fitlab.fit(m, "rough_dielectric", start={"alpha": 50})
    with pytest.raises(FitlabError, match="eta is fixed from the data file .--free eta"):
        fitlab.fit(m, "rough_dielectric", start={"eta": 1.4})
    with pytest.raises(FitlabError, match="start alpha: the parameter is also fixed"):
        fitlab.fit(m, "rough_dielectric", fix={"alpha": 0.1}, start={"alpha": 0.2})
    out = tmp_path / "fit.json"
    for bad, says in ((["--start", "alpha"], "must look like NAME=VALUE"),
                      (["--start", "alpha=x"], "--start alpha='x': the value must be a number"),
                      (["--start", "alpha=0.1", "--start", "alpha=0.2"], "given twice")):
        assert main(["fit", str(WALTER), "--model", "rough_dielectric", *bad, "--out",
                     str(out)]) == 2
        assert says in capsys.readouterr().err
    assert not out.exists()


def test_compare_candidates_take_their_own_start():
    from fitlab.fitting.compare import parse_candidate, resolve_candidates

    cand = parse_candidate("lambertian+rough_conductor --fix k=0 --start alpha=0.05")
    assert cand.start == {"alpha": "0.05"}
    (a, b) = resolve_candidates([cand, "lambertian"])
    assert a.start == {"alpha": 0.05} and b.start == {}
    assert a.spec.endswith("--start alpha=0.05")
    with pytest.raises(FitlabError, match="--start: parameter alpha=7.0 .* outside its bounds"):
        resolve_candidates(["rough_conductor --start alpha=7", "lambertian"])
