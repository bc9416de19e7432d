"""FitRequest: one fit's settings, checked once when made and shared by fitlab.fit, compare,
fit_many, the Dask runner and the CLI (fitlab/fitting/request.py)."""

from __future__ import annotations

import dataclasses
import doctest
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError
from fitlab.fitting.request import FitRequest

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"


def test_docstring_examples_run():
    import fitlab.fitting.request as request

    failed, attempted = doctest.testmod(request, optionflags=doctest.ELLIPSIS)
    assert attempted >= 4 and failed == 0


def test_request_is_frozen_and_normalised():
    r = FitRequest("rough_dielectric", fix={"eta": "1.5"}, free="alpha", share="alpha",
                   subset=[True, False], channels="Y", lm_maxiter=None)
    assert r.model.name == "rough_dielectric" and r.options["distribution"] == "ggx"
    assert r.fix == {"eta": 1.5} and r.free == ("alpha",) and r.share == ("alpha",)
    assert r.channels == ("Y",) and r.lm_maxiter == 200
    assert r.subset.dtype == bool and not r.subset.flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.seed = 3
    with pytest.raises(TypeError):
        r.fix["eta"] = 2.0
    # a variant is checked again, in the same spelling
    assert r.replace(seed=4).seed == 4
    with pytest.raises(FitlabError, match="^seed must be an integer of at least 0"):
        r.replace(seed=-1)
    cli = FitRequest("rough_dielectric", spelling="cli")
    with pytest.raises(FitlabError, match="^--lm-maxiter must be an integer from 1"):
        cli.replace(lm_maxiter=0)


@pytest.mark.parametrize("settings, says", [
    ({"fix": {"gamma": 1}}, "fix gamma: model 'rough_dielectric' has no parameter"),
    ({"fix": {"alpha": "x"}}, "fix alpha='x': the value must be a number"),
    ({"fix": {"alpha": 50}}, "outside its bounds"),
    ({"start": {"alpha": 0.1}, "fix": {"alpha": 0.2}}, "start alpha: the parameter is also fixed"),
    ({"free": ["gamma"]}, "free gamma: model 'rough_dielectric' has no parameter"),
    ({"options": {"distribution": "nope"}}, "must be one of"),
    ({"loss": "l1"}, "loss l1: unknown loss"),
    ({"share": ["scale"]}, "share scale: the scale of relative data is per channel"),
    ({"share": ["alpha"], "fix": {"alpha": 0.3}}, "share alpha: alpha is fixed"),
    ({"sampler": "hmc"}, "sampler: unknown sampler"),
    ({"mcmc": True, "mcmc_steps": 99}, "mcmc_steps must be at least 100"),
    ({"mcmc_steps": "many"}, "mcmc_steps must be at least 100, got 'many'"),
    ({"fix": [("alpha", 0.1)]}, "fix must be a mapping of names to values"),
    ({"options": "ggx"}, "options must be a mapping"),
    ({"channels": 3}, "channels must be channel names, got 3"),
    ({"walkers": 1}, "walkers must be an integer of at least 2"),
    ({"starts": -1}, "starts must be an integer of at least 0"),
    ({"starts": 2.5}, "starts must be an integer"),
    ({"aperture_order": 0}, "aperture_order must be an integer from 1 to"),
    ({"bootstrap": 3}, "bootstrap must be 0 (off) or a number of refits of at least 10"),
    ({"bootstrap": True}, "bootstrap must be 0"),
    ({"lm_maxiter": 0}, "lm_maxiter must be an integer from 1"),
    ({"lm_maxiter": True}, "lm_maxiter must be an integer from 1"),
    ({"global_search": "sacn"}, "global_search: unknown global search 'sacn'; did you mean "
                                "'scan'?"),
    ({"local_solver": "jaxpot"}, "local_solver: unknown local solver 'jaxpot'; did you mean "
                                 "'jaxopt'?"),
])
def test_every_setting_is_checked_with_a_message_that_names_it(settings, says):
    with pytest.raises(FitlabError) as err:
        FitRequest("rough_dielectric", **settings)
    assert says in str(err.value)


def test_unknown_model_and_bad_model_type():
    with pytest.raises(FitlabError, match="see `fitlab models`"):
        FitRequest("no_such_model")
    with pytest.raises(FitlabError, match="a registry name or a Model"):
        FitRequest(3.0)


def test_fit_takes_a_request_or_keywords_not_both():
    m = fitlab.read(WALTER)
    req = FitRequest("rough_dielectric", subset="theta_i == 0", starts=1, bootstrap=0)
    a = fitlab.fit(m, req)
    b = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", starts=1, bootstrap=0)
    assert a.to_json() == b.to_json()
    with pytest.raises(FitlabError, match="not also as keywords .seed."):
        fitlab.fit(m, req, seed=1)


def test_fit_many_refuses_what_only_a_single_fit_offers():
    m = fitlab.read(WALTER)
    for settings in ({"share": ["alpha"]}, {"bootstrap": 20}, {"start": {"alpha": 0.1}},
                     {"channels": ["Y"]}, {"aperture_order": 2},
                     {"walter_diagnostics": True}, {"global_search": "mlsl"},
                     {"local_solver": "jaxopt"}):
        with pytest.raises(FitlabError, match="not with " + next(iter(settings))):
            fitlab.fit_many([m], "rough_dielectric", **settings)
    with pytest.raises(FitlabError, match="samples its posteriors with NUTS"):
        fitlab.fit_many([m], FitRequest("rough_dielectric", mcmc=True, mcmc_steps=100))


def test_compare_checks_shared_settings_once_and_candidates_by_name():
    # compare's messages name the command line's options, as its others do
    with pytest.raises(FitlabError, match="^--mcmc-steps must be at least 100"):
        fitlab.compare(WALTER, ["rough_dielectric", "lambertian"], mcmc_steps=10)
    with pytest.raises(FitlabError, match="^--model 'lambertian': --start: parameter albedo"):
        fitlab.compare(WALTER, ["rough_dielectric", "lambertian --start albedo=7"], mcmc=False)


def test_cli_checks_the_request_before_reading_the_data(tmp_path, capsys):
    """A bad setting is reported under its option's name even when the data file is absent:
    the request is checked before anything is read."""
    missing = tmp_path / "absent.csv"
    for bad, says in ((["--lm-maxiter", "0"], "--lm-maxiter must be an integer from 1"),
                      (["--starts", "-2"], "--starts must be an integer of at least 0"),
                      (["--fix", "alpha=7"], "--fix: parameter alpha=7.0"),
                      (["--share", "scale"], "share scale")):
        assert main(["fit", str(missing), "--model", "rough_dielectric", *bad]) == 2
        err = capsys.readouterr().err
        assert says in err and "absent.csv" not in err, err


def test_the_cross_validation_folds_use_the_requests_step_limit(monkeypatch):
    """compare's folds refit with the candidate request's lm_maxiter (they used the default)."""
    from fitlab.fitting.compare import crossval, resolve_candidates

    seen = []
    real = crossval.fit_least_squares if hasattr(crossval, "fit_least_squares") else None
    import fitlab.fitting.least_squares as lsq

    orig = lsq.fit_least_squares

    def spy(*args, **kw):
        seen.append(kw.get("lm_maxiter"))
        return orig(*args, **kw)

    monkeypatch.setattr(lsq, "fit_least_squares", spy)
    assert real is None  # crossval imports it at call time, so the spy is what it gets
    m = fitlab.read(WALTER)
    cand = resolve_candidates(["rough_dielectric", "lambertian"],
                              settings={"lm_maxiter": 7, "starts": 0})[0]
    rows = np.isin(m.theta_i, np.unique(m.theta_i)[:2])
    crossval.cross_validate(m, cand, "relative", rows, 0, starts=0)
    assert seen and set(seen) == {7}


def test_a_fit_error_names_the_file(tmp_path, capsys):
    """A data file too small for the model: the message names the file (it named only the
    channel)."""
    one = tmp_path / "one.csv"
    one.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n0,0,10,0,0.3\n")
    with pytest.raises(FitlabError, match=r"one\.csv: channel Y: 1 rows cannot constrain"):
        fitlab.fit(one, "lambertian")
    assert main(["fit", str(one), "--model", "lambertian"]) == 2
    assert f"{one}: channel Y: 1 rows cannot constrain" in capsys.readouterr().err


def test_the_dask_runner_takes_one_checked_request(tmp_path):
    """fit_files checks its request as a batch before any worker starts, and hands the workers
    plain values; a row mask cannot travel to them (the rows are the workers' to read)."""
    from fitlab.fitting.distributed import fit_files, plain_settings

    req = FitRequest("rough_dielectric", subset="theta_i == 0", starts=2, walkers=4)
    plain = plain_settings(req)
    assert plain["subset"] == "theta_i == 0" and plain["starts"] == 2
    assert plain["options"] == dict(req.options) and plain["fix"] == {}
    with pytest.raises(FitlabError, match="not with share"):
        fit_files([WALTER], FitRequest("rough_dielectric", share="alpha"), tmp_path / "o")
    with pytest.raises(FitlabError, match="subset as an expression"):
        fit_files([WALTER], FitRequest("rough_dielectric", subset=[True] * 276), tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_mcmc_steps_default_to_the_samplers_own():
    """emcee's 3000 steps a walker, NUTS's 1000 adaptation steps and draws a chain; a number
    given is kept."""
    assert FitRequest("rough_dielectric").mcmc_steps == 3000
    assert FitRequest("rough_dielectric", sampler="nuts").mcmc_steps == 1000
    assert FitRequest("rough_dielectric", sampler="nuts", mcmc_steps=400).mcmc_steps == 400
