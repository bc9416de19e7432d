"""fitlab compare / fitlab.compare (data_formats/compare.md): on a small synthetic measurement the
true model wins over a wrong one by leave-one-incidence-out cross-validation; the tables, the
JSON and the page are written atomically (mode from the umask), name no absolute path and are
byte-identical on a rerun; errors exit 2 naming the option or file. The pointwise
log-likelihood is checked against scipy's normal density; PSIS-LOO and WAIC on real chains in
the slow tier."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_same_csv, assert_same_json, user_environment

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError
from fitlab.fitting import compare as cmp
from fitlab.io.atomic import current_umask

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data_formats" / "examples" / "compare"
SPEC = ROOT / "data_formats" / "compare.md"

# Oren–Nayar (rough diffuse) against Lambert: cheap to compile, different at grazing angles.
TRUE_MODEL = "oren_nayar"
TRUTH = {"albedo": 0.6, "sigma": 0.7}
NOISE = 0.03  # multiplicative, and the file's sigma


def _directions(theta, phi):
    t, p = np.radians(theta), np.radians(phi)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def write_synthetic(path, seed=7, thetas_i=(0.0, 20.0, 40.0, 60.0, 75.0)):
    """A BRDF of TRUE_MODEL at five incidences, 3% Gaussian noise and the matching sigma."""
    rows = [(ti, 0.0, to, po) for ti in thetas_i for to in range(0, 81, 10)
            for po in (0.0, 60.0, 120.0, 180.0)]
    a = np.array(rows, float)
    wi, wo = _directions(a[:, 0], a[:, 1]), _directions(a[:, 2], a[:, 3])
    f = np.asarray(fitlab.eval_bsdf(TRUE_MODEL, TRUTH, wi, wo))
    rng = np.random.default_rng(seed)
    v = f * (1 + NOISE * rng.standard_normal(f.shape))
    lines = ["# quantity: bsdf", "# scatter: brdf", "# sample: synthetic Oren-Nayar",
             "theta_i,phi_i,theta_o,phi_o,value,sigma"]
    lines += [f"{r[0]:g},{r[1]:g},{r[2]:g},{r[3]:g},{x:.8g},{NOISE * y:.8g}"
              for r, x, y in zip(rows, v, f)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return write_synthetic(tmp_path_factory.mktemp("data") / "synthetic.csv")


@pytest.fixture(scope="module")
def cv_runs(synthetic, tmp_path_factory):
    """The same comparison run twice (CV only), each into its own folder."""
    outs = []
    for k in range(2):
        out = tmp_path_factory.mktemp(f"run{k}") / "cmp"
        code, stdout, stderr = run_cli([
            "compare", str(synthetic), "--model", TRUE_MODEL, "--model",
            "lambertian --label 'diffuse only'", "--no-mcmc", "--starts", "2", "--out", str(out)])
        assert code == 0, stderr
        outs.append((out, stdout, stderr))
    return outs


# --------------------------------------------------------------------------------------------
# The ranking
# --------------------------------------------------------------------------------------------


def test_true_model_wins_by_cross_validation(cv_runs):
    out, stdout, stderr = cv_runs[0]
    rec = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    ch = rec["channels"][0]
    assert ch["ranking"]["cv"] == [TRUE_MODEL, "diffuse only"]
    v = ch["verdict"]["cv"]
    assert v["winner"] == TRUE_MODEL and v["decisive"] is True
    best, wrong = ch["models"]
    # The true model predicts each held-out incidence about as well as the noise allows ...
    assert best["cv"]["rms_relative_error"] < 2 * NOISE
    assert all(e < 3 * NOISE for e in best["cv"]["per_incidence"])
    # ... and its per-row noise scale is the file's sigma (3%).
    assert ch["noise_scale"]["relative"] == pytest.approx(NOISE, rel=0.02)
    assert "sigma" in ch["noise_scale"]["source"]
    # The wrong model is worse by many standard errors and many noise scales.
    assert wrong["cv"]["delta"] > 3 * wrong["cv"]["delta_se"]
    assert wrong["cv"]["delta_over_noise"] > 2
    assert wrong["cv"]["delta"] == pytest.approx(wrong["cv"]["rms_relative_error"]
                                                 - best["cv"]["rms_relative_error"])
    # A fold refits without its incidence: the true model's folds stay near the truth.
    for fold in best["cv"]["fold_parameters"]:
        assert fold["sigma"] == pytest.approx(TRUTH["sigma"], rel=0.1)
    # Terminal: the verdict on stdout (one line per channel), the table on stderr.
    assert stdout.startswith(f"Y\t{TRUE_MODEL}\t{TRUE_MODEL} wins by leave-one-incidence-out")
    assert "CV rank" in stderr and "Decisive." in stderr


def test_statuses_say_what_undermines_the_ranking(cv_runs, tmp_path):
    """Each candidate's statuses per channel are in the record (the fit's statuses, and
    folds_failed); a candidate that misfits leaves the comparison ok, any other status does not
    (ok, raise_for_status, throw=, the terminal's status: lines); a schema_version 1 file loads
    but cannot answer."""
    from fitlab.fitting.status import Status

    out, _, stderr = cv_runs[0]
    r = cmp.load_compare(out / "compare.json")
    assert r.statuses(TRUE_MODEL, "Y") == (Status.CONVERGED,)
    assert Status.MISFIT in r.statuses("diffuse only", "Y")  # what the comparison finds
    assert r.ok and r.raise_for_status() is r and "status:" not in stderr
    with pytest.raises(ValueError, match="no candidate 'nope'"):
        r.statuses("nope")
    rec = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    rec["channels"][0]["models"][0]["statuses"] = ["at_bound"]
    bad = cmp.CompareResult.from_record(rec)
    assert not bad.ok and bad.statuses(TRUE_MODEL) == (Status.AT_BOUND,)
    with pytest.raises(FitlabError, match=f"{TRUE_MODEL} channel Y: at_bound .widen"):
        bad.raise_for_status()
    assert f"status: {TRUE_MODEL} channel Y: at_bound: widen" in bad.summary()
    # a file written before statuses were recorded
    for mod in rec["channels"][0]["models"]:
        del mod["statuses"]
    rec["schema_version"] = 1
    old = tmp_path / "compare.json"
    old.write_text(json.dumps(rec), encoding="utf-8")
    r1 = cmp.load_compare(old)
    assert r1.winner() == TRUE_MODEL and "status:" not in r1.summary()
    with pytest.raises(ValueError, match="older fitlab .schema_version 1"):
        r1.statuses(TRUE_MODEL)
    rec["schema_version"] = 3
    old.write_text(json.dumps(rec), encoding="utf-8")
    with pytest.raises(FitlabError, match="schema_version 3; this fitlab reads 1 to 2"):
        cmp.load_compare(old)


def test_a_failed_fold_is_a_status(synthetic, monkeypatch):
    """A fold that cannot be fitted ranks its model last by CV and adds folds_failed, which
    throw=True turns into an error naming the candidate and what to do."""
    from fitlab.fitting.compare import crossval
    from fitlab.fitting.status import Status

    real = crossval.batched_folds

    def flaky(m, base, rows, incs, fit, lm_maxiter, order=None, solver=None):
        folds = real(m, base, rows, incs, fit, lm_maxiter, order, solver)
        if base["model"].name == "lambertian":  # its second fold could not be fitted
            folds[1] = {**folds[1], "rel": np.zeros(0), "parameters": None,
                        "error": "made to fail"}
        return folds

    monkeypatch.setattr(crossval, "batched_folds", flaky)
    r = fitlab.compare(synthetic, [TRUE_MODEL, "lambertian"], mcmc=False, starts=1)
    assert Status.FOLDS_FAILED in r.statuses("lambertian") and not r.ok
    with pytest.raises(FitlabError, match="lambertian channel Y: folds_failed .read the fold"):
        fitlab.compare(synthetic, [TRUE_MODEL, "lambertian"], mcmc=False, starts=1, throw=True)


def test_tables_match_the_spec(cv_runs):
    out = cv_runs[0][0]
    with open(out / "compare.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == cmp.SUMMARY_COLUMNS
    assert [r["label"] for r in rows] == [TRUE_MODEL, "diffuse only"]
    assert rows[0]["cv_rank"] == "1" and rows[0]["elpd_loo"] == ""  # --no-mcmc: empty cells
    with open(out / "compare_incidences.csv", newline="", encoding="utf-8") as fh:
        inc = list(csv.DictReader(fh))
    assert tuple(inc[0]) == cmp.INCIDENCE_COLUMNS
    assert len(inc) == 2 * 5 and {r["theta_i"] for r in inc} == {"0.0", "20.0", "40.0", "60.0",
                                                                 "75.0"}
    spec = SPEC.read_text(encoding="utf-8")
    for col in cmp.SUMMARY_COLUMNS + cmp.INCIDENCE_COLUMNS:
        assert f"`{col}`" in spec or f"{col}`" in spec or f"`{col}," in spec, col
    # Parameter files of the candidates, readable by fitlab.load_fit.
    res = fitlab.load_fit(out / "fits" / "1_oren_nayar.json")
    assert res.model == TRUE_MODEL


def test_outputs_identical_on_rerun_atomic_and_relative(cv_runs):
    (a, _, _), (b, _, _) = cv_runs
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert names == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    assert {"compare.json", "compare.csv", "compare_incidences.csv", "index.html",
            "heldout_Y.png", "heldout_Y.svg"} <= set(names)
    mode = 0o666 & ~current_umask()
    for name in names:
        pa = a / name
        assert pa.read_bytes() == (b / name).read_bytes(), name
        assert pa.stat().st_mode & 0o777 == mode, name
        if not name.endswith(".png"):
            text = pa.read_text(encoding="utf-8")
            for absolute in (str(a), str(b), str(ROOT), str(Path.home())):
                assert absolute not in text, (name, absolute)
    assert not [p for p in a.rglob(".*")], "a temporary file was left behind"
    page = (a / "index.html").read_text(encoding="utf-8")
    assert "Which model wins, and by how much" in page and "held-out RMS relative error" in page
    # The page can be rebuilt from compare.json alone, to the same bytes.
    again = cmp.load_compare(a / "compare.json")
    fitlab.write_report(again, a)
    assert (a / "index.html").read_text(encoding="utf-8") == page


def test_python_api_matches_the_command(cv_runs, synthetic):
    r = fitlab.compare(synthetic, [TRUE_MODEL, fitlab.Candidate("lambertian",
                                                                 label="diffuse only")],
                       mcmc=False, starts=2)
    assert r.winner() == TRUE_MODEL and r.ranking(by="cv") == (TRUE_MODEL, "diffuse only")
    assert r.fit(TRUE_MODEL).model == TRUE_MODEL
    with open(cv_runs[0][0] / "compare.csv", newline="", encoding="utf-8") as fh:
        saved = next(csv.DictReader(fh))
    assert r.table()[0]["in_sample_rms_rel"] == float(saved["in_sample_rms_rel"])
    with pytest.raises(TypeError):
        r.record["channels"] = ()  # immutable


# --------------------------------------------------------------------------------------------
# Pieces
# --------------------------------------------------------------------------------------------


def test_parse_candidate():
    c = cmp.parse_candidate("coated(lambertian,specular=lobe) --option interreflection="
                            "closed_form --fix coat_eta=1.5 --fix=coat_tau=0 --label 'my coat'")
    assert c == cmp.Candidate("coated(lambertian,specular=lobe)",
                              {"coat_eta": 1.5, "coat_tau": 0.0},
                              {"interreflection": "closed_form"}, (), "my coat")
    assert cmp.parse_candidate("coated(lambertian, specular=lobe) --free eta").model == \
        "coated(lambertian, specular=lobe)"
    for bad, what in (("--fix a=1", "give a model name"), ("lambertian --bogus 1", "unexpected"),
                      ("lambertian --fix", "needs a value"), ("lambertian --fix a=x", "number"),
                      ("lambertian 'open", "quote")):
        with pytest.raises(FitlabError, match=what):
            cmp.parse_candidate(bad)


def test_global_settings_go_to_the_candidates_that_have_them():
    cands = cmp.resolve_candidates(
        ["lambertian+rough_conductor --fix k=2 --label own", "lambertian+rough_conductor",
         "rough_dielectric --option distribution=beckmann", "lambertian"],
        fix={"k": 3.0, "eta": 1.5}, options={"distribution": "phong"})
    got = {c.label: (c.fix, c.options.get("distribution")) for c in cands}
    assert got["own"] == ({"k": 2.0}, "phong")  # its own --fix wins, the global option applies
    assert got["lambertian+rough_conductor"] == ({"k": 3.0}, "phong")
    assert got["rough_dielectric"] == ({"eta": 1.5}, "beckmann")  # its own option wins
    assert got["lambertian"] == ({}, None)
    # Two candidates of one model are told apart by their spec.
    assert [c.label for c in cmp.resolve_candidates(
        ["rough_conductor", "rough_conductor --option distribution=beckmann"])] == \
        ["rough_conductor", "rough_conductor --option distribution=beckmann"]


def test_jackknife_difference_by_brute_force():
    rng = np.random.default_rng(1)
    n = rng.integers(5, 30, size=6)
    ea = [rng.normal(0, 0.3, k) for k in n]
    eb = [rng.normal(0, 0.2, k) for k in n]
    sq_a, sq_b = [np.sum(e**2) for e in ea], [np.sum(e**2) for e in eb]
    d, se = cmp.jackknife_difference(sq_a, sq_b, n)
    rms = lambda es: np.sqrt(np.mean(np.concatenate(es) ** 2))  # noqa: E731
    assert d == pytest.approx(rms(ea) - rms(eb))
    loo = [rms(ea[:k] + ea[k + 1:]) - rms(eb[:k] + eb[k + 1:]) for k in range(len(n))]
    assert se == pytest.approx(np.sqrt((len(n) - 1) / len(n) * np.sum((loo - np.mean(loo)) ** 2)))


def _fit_with_chain(path, loss):
    return fitlab.fit(path, "lambertian", loss=loss, mcmc=True, mcmc_steps=100, walkers=8,
                      starts=1, bootstrap=0)


@pytest.mark.parametrize("loss", ["chi2", "relative"])
def test_pointwise_log_likelihood_is_the_fits_normal_density(synthetic, loss):
    """Each sample's row log-likelihood is log N(v; m, σ²) with the loss's σ (chi2: the file's
    sigma; relative: σ_r · max(|v|, 1% of max |v|)), and their sum is the chain's log-posterior
    (checked inside, too)."""
    from scipy.stats import norm

    m = fitlab.read(synthetic)
    res = _fit_with_chain(m, loss)
    cand = cmp.resolve_candidates(["lambertian", "lambertian --label b"])[0]
    rows = np.ones(m.n, dtype=bool)
    ll = cmp.pointwise_log_likelihood(m, cand, res, loss, rows, 0)
    x = np.asarray(res.chains["chain_Y"])[res.record["fits"][0]["mcmc"]["burn_in"]::
                                          res.record["fits"][0]["mcmc"]["thin"]]
    walker, draw = 3, 2
    u = x[draw, walker]
    albedo = 0.0 + (1.0 - 0.0) * u[0]  # linear unit box over the registry bounds [0, 1]
    model = albedo / np.pi * np.ones(m.n)
    if loss == "chi2":
        want = norm.logpdf(m.value, model, m.sigma)
    else:
        scale = np.maximum(np.abs(m.value), 0.01 * np.max(np.abs(m.value)))
        want = norm.logpdf(m.value, model, np.exp(u[1]) * scale)
    assert ll["loglik"].shape[:2] == (x.shape[1], x.shape[0])
    np.testing.assert_allclose(ll["loglik"][walker, draw], want, rtol=1e-9, atol=1e-9)


# --------------------------------------------------------------------------------------------
# Errors: status 2, a message naming the option or file and what to do
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("extra, message", [
    (["--model", "lambertian"], "--model: give two or more candidates"),
    (["--model", "lambertian", "--model", "no_such_model"], "--model 'no_such_model'"),
    (["--model", "lambertian", "--model", "rough_conductor --fix nope=1"],
     "--fix nope: model 'rough_conductor' has no parameter"),
    (["--model", "lambertian", "--model", "rough_conductor", "--fix", "eta=1.5"],
     "--fix eta: no candidate model has a parameter"),
    (["--model", "lambertian", "--model", "rough_conductor", "--option", "colour=red"],
     "--option colour: no candidate model has an option"),
    (["--model", "lambertian", "--model", "lambertian"], "two candidates are both"),
    (["--model", "lambertian", "--model", "rough_conductor", "--no-cv", "--no-mcmc"],
     "nothing to rank by"),
    (["--model", "lambertian", "--model", "rough_conductor", "--mcmc-steps", "10"],
     "--mcmc-steps must be at least 100"),
    (["--model", "lambertian", "--model", "rough_conductor --fix alpha=7"], "alpha"),
    (["--model", "lambertian", "--model", "rough_conductor", "--no-report"],
     "--no-report needs --out"),
    (["--model", "lambertian", "--model", "rough_conductor", "--channel", "R"],
     "--channel R"),
    (["--model", "lambertian", "--model", "rough_conductor", "--no-mcmc", "--fit-subset",
      "theta_i == 20"], "one incidence direction"),
])
def test_errors_exit_2_with_a_message(synthetic, extra, message):
    code, out, err = run_cli(["compare", str(synthetic), *extra])
    assert code == 2 and out == ""
    assert message in err and "Traceback" not in err, err


def test_file_errors(tmp_path, synthetic):
    code, _, err = run_cli(["compare", str(tmp_path / "missing.csv"), "--model", "lambertian",
                            "--model", "rough_conductor"])
    assert code == 2 and "missing.csv" in err
    afile = tmp_path / "afile"
    afile.write_text("x")
    code, _, err = run_cli(["compare", str(synthetic), "--model", "lambertian", "--model",
                            "rough_conductor", "--out", str(afile)])
    assert code == 2 and "--out" in err and "is a file" in err
    bad = tmp_path / "compare.json"
    bad.write_text('{"schema": "fitlab-fit"}')
    with pytest.raises(FitlabError, match="not a fitlab comparison"):
        cmp.load_compare(bad)


def test_without_arviz_says_what_to_install(synthetic, monkeypatch):
    monkeypatch.setitem(sys.modules, "arviz", None)  # import arviz raises ImportError
    with pytest.raises(FitlabError, match=r"fitlab\[compare\].*--no-mcmc"):
        fitlab.compare(synthetic, ["lambertian", "rough_conductor"])


def test_help():
    code, out, _ = run_cli(["compare", "--help"])
    assert code == 0 and "leave-one-incidence-out" in out and "--no-mcmc" in out
    code, out, _ = run_cli(["--help"])
    assert "compare" in out


# --------------------------------------------------------------------------------------------
# The committed example of data_formats/compare.md
# --------------------------------------------------------------------------------------------


def _keys(obj, prefix=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield k
            yield from _keys(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _keys(v)


def test_example_is_valid_and_specified():
    r = cmp.load_compare(EXAMPLE / "compare.json")
    assert r.winner() == "rough_dielectric" and r.winner(by="loo") == "rough_dielectric"
    assert (EXAMPLE / "compare.csv").read_text(encoding="utf-8") == r.to_csv()
    assert (EXAMPLE / "compare_incidences.csv").read_text(encoding="utf-8") == r.incidences_csv()
    assert (EXAMPLE / "compare.json").read_text(encoding="utf-8") == r.to_json()
    spec = SPEC.read_text(encoding="utf-8")
    rec = json.loads((EXAMPLE / "compare.json").read_text(encoding="utf-8"))
    skip = ({"Y"} | set(rec["software"]) | {"alpha", "eta", "scale"}
            | {k for c in rec["candidates"] for k in c["options"]})  # the model's own options
    missing = sorted({k for k in _keys(rec) if k not in skip and k not in spec})
    assert not missing, f"fields of the example not in data_formats/compare.md: {missing}"
    assert not os.path.isabs(rec["data"]["path"])
    assert (EXAMPLE / rec["data"]["path"]).resolve() == \
        (ROOT / "data_formats" / "examples" / "walter_rough_glass.csv").resolve()


# --------------------------------------------------------------------------------------------
# Slow: PSIS-LOO and WAIC on real chains
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_loo_and_waic_pick_the_true_model(synthetic, tmp_path):
    out = tmp_path / "cmp"
    code, stdout, stderr = run_cli([
        "compare", str(synthetic), "--model", TRUE_MODEL, "--model", "lambertian",
        "--mcmc-steps", "1500", "--starts", "2", "--out", str(out), "--quiet"])
    assert code == 0, stderr
    rec = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    ch = rec["channels"][0]
    for kind in ("cv", "loo", "waic"):
        assert ch["ranking"][kind][0] == TRUE_MODEL, kind
    v = ch["verdict"]["loo"]
    assert v["decisive"] and v["elpd_diff"] > 4 and v["elpd_diff"] > 2 * v["dse"]
    assert ch["verdict"]["agree"] is True
    best = ch["models"][0]
    assert best["mcmc"]["trustworthy"]
    # The true model with 3% noise: the Pareto k are fine, and p_loo is about its 2 free
    # parameters (albedo, sigma; chi2 loss: no noise scale sampled).
    assert best["loo"]["pareto_k"]["bad"] + best["loo"]["pareto_k"]["very_bad"] == 0
    assert 1.0 < best["loo"]["p"] < 4
    # Under the true model the rows' ELPD is the normal density's at 3% noise.
    assert best["loo"]["elpd"] == pytest.approx(best["waic"]["elpd"], abs=1.0)
    assert {"elpd_Y.png", "pareto_k_Y.png", "heldout_Y.png"} <= {p.name for p in out.iterdir()}
    assert "PSIS-LOO" in stdout


@pytest.mark.slow
def test_example_reproduced_by_its_command(tmp_path):
    """data_formats/compare.md's example command gives the committed bytes (run as a user runs
    it: a `fitlab` process under XLA's default settings, conftest.user_environment)."""
    out = tmp_path / "compare"
    proc = subprocess.run([
        sys.executable, "-m", "fitlab.cli",
        "compare", str(ROOT / "data_formats/examples/walter_rough_glass.csv"), "--model",
        "rough_dielectric", "--model", "rough_dielectric --option distribution=beckmann "
        "--label beckmann", "--mcmc-steps", "2000", "--starts", "2", "--no-report",
        "--no-fits", "--out", str(out), "--quiet"], env=user_environment(),
        capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # the committed example was made on another machine: the same rows, labels and verdicts,
    # every number within 1e-9 (the bytes of a rerun on one machine are
    # test_outputs_identical_on_rerun_atomic_and_relative's)
    for name in ("compare.csv", "compare_incidences.csv"):
        assert_same_csv((out / name).read_text(encoding="utf-8"),
                        (EXAMPLE / name).read_text(encoding="utf-8"), where=name)
    got = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    want = json.loads((EXAMPLE / "compare.json").read_text(encoding="utf-8"))
    got["data"]["path"] = want["data"]["path"]  # relative to a different folder
    # the record of the machine that ran it (its kernel build differs between machines)
    got["software"]["platform"] = want["software"]["platform"]
    assert_same_json(got, want, where="compare.json")


@pytest.mark.slow
def test_docstring_example():
    import doctest

    failed, attempted = doctest.testmod(cmp, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0
