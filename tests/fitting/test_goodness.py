"""Goodness of fit and the block bootstrap (issue 14, item 3).

Quick tier: the statistics on known inputs (runs counts, Hilbert order, Šidák, F and χ² levels,
posterior predictive p-values), the bootstrap's resampling and seed, and one misfit fit end to
end: GGX data fitted with a Beckmann lobe fails its checks, and the fit file, the terminal
summary and the report say so; older files without the new fields still load and report.
Slow tier (statistical): data from the fitted model with its own noise pass the checks at their
nominal rate and the bootstrap interval agrees with the least-squares one; data from another
model fail them and the bootstrap interval is much wider than the MCMC one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.fitting import goodness as gof
from fitlab.fitting.resampling import resample_counts
from fitlab.io.directions import degrees_to_direction
from fitlab.io.measurement import Measurement

ROOT = Path(__file__).resolve().parents[2]


# --------------------------------------------------------------------------------------------
# Synthetic data
# --------------------------------------------------------------------------------------------

#: In-plane scans (φo = 0 and 180°) and an out-of-plane ring, at several incidences.
THETAS_I = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0)


def _grid(thetas_i, step=5.0):
    rows = []
    for ti in thetas_i:
        for to in np.arange(0.0, 86.0, step):
            for po in (0.0, 180.0):
                if not (to == 0 and po == 180.0):
                    rows.append((ti, 0.0, to, po))
        for po in (90.0, 270.0):
            for to in np.arange(10.0, 81.0, 10.0):
                rows.append((ti, 0.0, to, po))
    return np.asarray(rows, float)


def synthetic(model, params, *, options=None, thetas_i=THETAS_I, rel_noise=0.03, seed=0,
              sigma=True, step=5.0):
    """A Measurement of ``model`` with Gaussian noise of known sigma, rel_noise · f (values stay
    positive, as a BSDF file needs); without ``sigma`` the same noise, no sigma column."""
    a = _grid(thetas_i, step)
    wi, wo = degrees_to_direction(a[:, 0], a[:, 1]), degrees_to_direction(a[:, 2], a[:, 3])
    f = np.asarray(fitlab.eval_bsdf(model, params, wi, wo, options))
    keep = f > 0
    a, wi, wo, f = a[keep], wi[keep], wo[keep], f[keep]
    rng = np.random.default_rng(seed)
    s = rel_noise * f
    value = f + s * rng.standard_normal(f.shape)
    n = len(f)
    return Measurement(
        path="<synthetic>", sha256="0" * 64, theta_i=a[:, 0], phi_i=a[:, 1], theta_o=a[:, 2],
        phi_o=a[:, 3], wi=wi, wo=wo, value=value, sigma=s if sigma else None,
        channel=np.zeros(n, dtype=int), channel_names=("Y",), wavelength_nm=None,
        quantity="bsdf", file_quantity="bsdf", metadata={}, lines=np.arange(n))


def _write_csv(m, path):
    lines = ["# synthetic GGX rough conductor (goodness-of-fit tests)", "# quantity: bsdf",
             "# scatter: brdf", "theta_i,phi_i,theta_o,phi_o,value,sigma"]
    lines += [f"{a:g},{b:g},{c:g},{d:g},{v:.9e},{s:.9e}" for a, b, c, d, v, s in
              zip(m.theta_i, m.phi_i, m.theta_o, m.phi_o, m.value, m.sigma)]
    path.write_text("\n".join(lines) + "\n")


TRUTH = {"alpha": 0.2, "n": 1.5, "k": 3.0}


# --------------------------------------------------------------------------------------------
# The statistics on known inputs
# --------------------------------------------------------------------------------------------


def test_runs_counts_by_hand():
    # + + − − +: 3 runs; n1 = 3, n2 = 2: mean 1 + 2·6/5 = 3.4, var 2·6·(12 − 5)/(25·4) = 0.84
    runs, mean, var = gof.runs_counts([1, 1, -1, -1, 1])
    assert (runs, mean, var) == (3, pytest.approx(3.4), pytest.approx(0.84))
    assert gof.runs_counts([1, 0, 1, 1]) == (1, 1.0, 0.0)  # zeros left out; one sign: no info


def test_runs_test_detects_stretches_not_noise():
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(400)
    groups = [np.arange(0, 200), np.arange(200, 400)]
    assert gof.runs_test(noise, groups)["p_value"] > 0.01
    blocky = np.repeat(rng.choice([-1.0, 1.0], 20), 20)  # stretches of 20 of one sign
    out = gof.runs_test(blocky, groups)
    assert out["p_value"] < 1e-10 and out["runs"] < out["expected_runs"] / 3


def test_hilbert_order_visits_neighbours():
    """Along the curve every step goes to an adjacent cell of the 2^b × 2^b grid."""
    b = 3
    c = (np.arange(2**b) + 0.5) / 2**b * 2 - 1  # cell centres in [-1, 1]
    x, y = np.meshgrid(c, c)
    d = gof.hilbert_index(x.ravel(), y.ravel(), bits=b)
    assert sorted(d.tolist()) == list(range(4**b))
    order = np.argsort(d)
    ix = np.round((x.ravel()[order] + 1) / 2 * 2**b - 0.5)
    iy = np.round((y.ravel()[order] + 1) / 2 * 2**b - 0.5)
    assert np.all(np.abs(np.diff(ix)) + np.abs(np.diff(iy)) == 1)


def test_scans_by_phi_then_hilbert_for_the_rest():
    theta_o = np.array([30.0, 10.0, 20.0, 40.0, 5.0, 50.0, 60.0])
    phi_o = np.array([0.0, 0.0, 0.0, 0.0, 33.0, 71.0, 12.0])
    wo = degrees_to_direction(theta_o, phi_o)
    groups = gof.scan_groups(np.zeros(7, int), theta_o, phi_o, wo)
    scans = [g for _, g, kind in groups if kind == "scan"]
    rest = [g for _, g, kind in groups if kind == "hilbert"]
    assert [g.tolist() for g in scans] == [[1, 2, 0, 3]]  # φo = 0 by θo
    assert len(rest) == 1 and sorted(rest[0].tolist()) == [4, 5, 6]


def test_sidak_and_levels():
    assert gof.sidak([0.5, None, 0.01]) == pytest.approx(1 - 0.99**2)
    assert gof.sidak([None]) is None
    rng = np.random.default_rng(2)
    r = rng.standard_normal(600)
    block = np.repeat(np.arange(3), 200)
    chi = gof.incidence_levels(r, block, 2, absolute_noise=True)
    assert all(0.7 < x["statistic"] < 1.3 and x["p_value"] > 1e-3 for x in chi)
    r[block == 2] *= 2.0  # one incidence twice as noisy as the others
    var = gof.incidence_levels(r, block, 2, absolute_noise=False)
    assert var[2]["statistic"] > 1.7 and var[2]["p_value"] < 1e-20  # 4 / mean(1, 1, 4)
    assert var[0]["p_value"] > 0.5
    assert gof.incidence_levels(r[:200], block[:200], 2, False)[0]["p_value"] is None


def test_posterior_predictive_p_values():
    rng = np.random.default_rng(3)
    block = np.repeat(np.arange(4), 100)
    sigma = np.full(50, 0.5)
    fine = 0.5 * rng.standard_normal((50, 400))
    out = gof.posterior_predictive(fine, sigma, block)
    assert 0.01 < out["chi2"]["p_value"] < 0.99
    assert 0.01 < out["worst_incidence"]["p_value"] < 0.99
    assert out["chi2"]["replicated_mean"] == 400
    # E[max of 4 χ²(100)/100] ≈ 1.15 (1 + 1.03·√(2/100)); the observed one is about the same
    assert 1.08 < out["worst_incidence"]["replicated_mean"] < 1.22
    bad = fine.copy()
    bad[:, block == 3] *= 1.8
    out = gof.posterior_predictive(bad, sigma, block)
    assert out["worst_incidence"]["p_value"] < 1e-6


def test_assess_and_sentence():
    rng = np.random.default_rng(4)
    theta_o = np.tile(np.arange(0.0, 80.0, 1.0), 4)
    block = np.repeat(np.arange(4), 80)
    phi_o = np.zeros(320)
    wo = degrees_to_direction(theta_o, phi_o)
    keys = np.array([[t, 0.0] for t in (0.0, 20.0, 40.0, 60.0)])
    kw = dict(block=block, keys=keys, theta_o=theta_o, phi_o=phi_o, wo=wo, n_params=2)
    good = gof.assess(rng.standard_normal(320), absolute_noise=True, **kw)
    assert good["describes_data"] and good["failed"] == []
    assert gof.failure_sentence(good, has_mcmc=True, bootstrap=False) is None
    r = rng.standard_normal(320) + 3 * np.sin(theta_o / 10)  # a smooth, structured misfit
    bad = gof.assess(r, absolute_noise=True, **kw)
    assert not bad["describes_data"]
    assert {"chi2", "runs_test"} <= set(bad["failed"])
    text = gof.failure_sentence(bad, has_mcmc=True, bootstrap=False)
    assert text.startswith("THE MODEL DOES NOT DESCRIBE THE DATA")
    assert "MCMC intervals are conditional on the model" in text and "--bootstrap" in text


def test_bootstrap_counts_are_seeded_resamples():
    a = resample_counts(7, 50, seed=3)
    assert a.shape == (50, 7) and np.all(a.sum(axis=1) == 7)
    assert np.array_equal(a, resample_counts(7, 50, seed=3))
    assert not np.array_equal(a, resample_counts(7, 50, seed=4))
    s = gof.bootstrap_summary(np.arange(101.0)[:, None])[0]
    assert (s["p16"], s["p50"], s["p84"]) == (16.0, 50.0, 84.0)


# --------------------------------------------------------------------------------------------
# A misfit end to end: GGX data, a Beckmann lobe
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def misfit(tmp_path_factory):
    """GGX conductor data (8 incidences, 3% noise with sigma) fitted with a Beckmann conductor
    by the CLI, with a short MCMC; the terminal's text is kept."""
    d = tmp_path_factory.mktemp("goodness")
    m = synthetic("rough_conductor", TRUTH, seed=5)
    data = d / "ggx.csv"
    _write_csv(m, data)
    out, chain = d / "beckmann.json", d / "beckmann.npz"
    argv = ["fit", str(data), "--model", "rough_conductor", "--option",
            "distribution=beckmann", "--fix", "n=1.5", "--fix", "k=3", "--mcmc",
            "--mcmc-steps", "300", "--bootstrap", "40", "--out", str(out), "--chain", str(chain),
            "-v"]
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(argv) == 0
    return {"data": data, "out": out, "chain": chain, "dir": d, "argv": argv,
            "stderr": err.getvalue()}


class _Rep:  # the report's figure collector, without rendering
    def figure(self, name, fig, caption, alt, half=False):
        fig.clear()
        return f"<figure {name}>"


def _channel(record):
    from types import SimpleNamespace

    fit = record["fits"][0]
    return SimpleNamespace(fit=fit, name=fit["channel"], free=[k for k, p in
                                                               fit["parameters"].items()
                                                               if not p["fixed"]])


def test_misfit_is_reported_in_file_and_terminal(misfit):
    err = misfit["stderr"]
    assert "goodness of fit FAILS: the model does not describe the data" in err
    assert "warning: channel Y: THE MODEL DOES NOT DESCRIBE THE DATA" in err
    assert "bootstrap ±" in err and "MCMC intervals are conditional on the model" in err
    rec = json.loads(misfit["out"].read_text())
    fit = rec["fits"][0]
    g = fit["goodness"]
    assert g["describes_data"] is False and "chi2" in g["failed"]
    assert g["posterior_predictive"]["draws"] > 0
    assert any(w.startswith("THE MODEL DOES NOT DESCRIBE THE DATA") for w in fit["warnings"])
    assert fit["bootstrap"]["replicates"] == 40 and fit["bootstrap"]["blocks"] == len(THETAS_I)
    alpha = fit["parameters"]["alpha"]
    assert set(alpha["bootstrap"]) == {"std", "p16", "p50", "p84", "p2_5", "p97_5"}
    post = alpha["posterior"]
    boot = alpha["bootstrap"]
    assert boot["p84"] - boot["p16"] > 3 * (post["p84"] - post["p16"])


def test_misfit_is_reported_in_the_report_sections(misfit):
    """The report's pieces (without rendering the figures): the warning box, the parameter
    table's bootstrap columns and the note, the goodness section."""
    from types import SimpleNamespace

    from fitlab.report import build
    from fitlab.report.goodness import goodness_section

    rec = json.loads(misfit["out"].read_text())
    ch = _channel(rec)
    warn = build._warnings(build._warning_items(SimpleNamespace(record=rec)))
    assert "THE MODEL DOES NOT DESCRIBE THE DATA" in warn
    table = build._parameter_table(ch)
    assert "bootstrap 68% interval" in table
    assert "the posterior bands and intervals are conditional on the model" in table
    section = goodness_section(_Rep(), ch, "Y")
    assert "The model does not describe the data" in section and "runs test" in section
    assert "<figure intervals_Y>" in section


@pytest.mark.slow
def test_misfit_report_end_to_end(misfit, tmp_path):
    rep = tmp_path / "report"
    assert main(["report", str(misfit["out"]), "--chain", str(misfit["chain"]), "--out",
                 str(rep), "--quiet"]) == 0
    html = (rep / "index.html").read_text(encoding="utf-8")
    assert "THE MODEL DOES NOT DESCRIBE THE DATA" in html
    assert "Goodness of fit" in html and "bootstrap 68% interval" in html
    assert "the posterior bands and intervals are conditional on the model" in html
    assert (rep / "intervals_Y.png").is_file()


def test_api_accessors_and_file_round_trip(misfit):
    r = fitlab.load_fit(misfit["out"])
    g = r.goodness()
    assert g is not None and not g["describes_data"]
    b = r.bootstrap()
    assert set(b) == {"alpha"} and b["alpha"]["std"] > 0
    assert r.diagnostics()["bootstrap"]["blocks"] == len(THETAS_I)


def test_same_seed_same_bootstrap(misfit, tmp_path):
    """The bootstrap and the checks are seeded by the fit's seed: same bytes (the chain-free
    file, without the MCMC, run twice)."""
    argv = [a for a in misfit["argv"][:misfit["argv"].index("--mcmc")]] + ["--bootstrap", "20",
                                                                          "--quiet"]
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(argv + ["--out", str(a)]) == 0
    assert main(argv + ["--out", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()
    fit = json.loads(a.read_text())["fits"][0]
    assert fit["goodness"]["posterior_predictive"] is None  # no MCMC, no predictive check
    assert fit["bootstrap"]["replicates"] == 20


def _older(misfit, tmp_path):
    """The misfit's file as fitlab wrote it before the checks: no goodness, no bootstrap."""
    rec = json.loads(misfit["out"].read_text())
    for fit in rec["fits"]:
        fit.pop("goodness"), fit.pop("bootstrap")
        for p in fit["parameters"].values():
            p.pop("bootstrap", None)
        fit["warnings"] = [w for w in fit["warnings"] if "DOES NOT DESCRIBE" not in w]
    rec.pop("chain")
    rec["data"]["path"] = str(misfit["data"])
    old = tmp_path / "old.json"
    old.write_text(json.dumps(rec))
    return old, rec


def test_older_files_without_the_fields_load(misfit, tmp_path, capsys):
    from fitlab.cli.fit import _print_summary
    from fitlab.report import build
    from fitlab.report.goodness import goodness_section

    old, rec = _older(misfit, tmp_path)
    r = fitlab.load_fit(old)
    assert r.goodness() is None and r.bootstrap() is None
    _print_summary(rec)
    assert "goodness" not in capsys.readouterr().err
    ch = _channel(rec)
    assert goodness_section(_Rep(), ch, "Y") is None
    assert "bootstrap" not in build._parameter_table(ch)


@pytest.mark.parametrize("path, value", [
    (("goodness", "runs_test", "expected_runs"), None),
    (("goodness", "per_incidence", 0, "theta_i"), "15"),
    (("goodness", "describes_data"), "no"),
    (("bootstrap", "replicates"), -1),
    (("parameters", "alpha", "bootstrap", "p84"), float("inf")),
])
def test_malformed_goodness_fields_refused(misfit, tmp_path, capsys, path, value):
    """A parameter file whose goodness or bootstrap fields the report would read are missing or
    of the wrong type is refused (exit 2, the field named), never a traceback."""
    rec = json.loads(misfit["out"].read_text())
    rec.pop("chain")
    rec["data"]["path"] = str(misfit["data"])
    obj = rec["fits"][0]
    for key in path[:-1]:
        obj = obj[key]
    if value is None:
        del obj[path[-1]]
    else:
        obj[path[-1]] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(rec).replace("Infinity", "1e999"))
    assert main(["report", str(bad), "--out", str(tmp_path / "rep"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert ".".join(str(k) for k in path[:2]) in err.replace("[0]", ".0").replace("..", ".")
    assert "Traceback" not in err and not (tmp_path / "rep").exists()


@pytest.mark.slow
def test_older_files_without_the_fields_report(misfit, tmp_path):
    old, _ = _older(misfit, tmp_path)
    assert main(["report", str(old), "--out", str(tmp_path / "rep"), "--quiet"]) == 0
    html = (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")
    assert "Goodness of fit" not in html and "bootstrap" not in html


def test_bootstrap_argument_checked(capsys):
    m = synthetic("rough_conductor", TRUTH, thetas_i=(20.0,), step=10.0)
    with pytest.raises(fitlab.errors.FitlabError, match="bootstrap must be 0"):
        fitlab.fit(m, "rough_conductor", bootstrap=3)
    assert main(["fit", str(ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"),
                 "--model", "rough_dielectric", "--bootstrap", "5"]) == 2
    assert "--bootstrap must be 0 (off) or a number of refits of at least 10" in \
        capsys.readouterr().err


def test_fewer_than_three_incidences_no_bootstrap():
    """Nothing to resample with one or two fitted incidences: by default silently, asked for
    explicitly with a warning (no refit is attempted)."""
    from types import SimpleNamespace

    from fitlab.fitting.request import FitRequest
    from fitlab.fitting.resampling import channel_misfit

    m = synthetic("rough_conductor", TRUTH, thetas_i=(10.0, 40.0), step=10.0)
    rows = np.ones(m.n, bool)
    ls = SimpleNamespace(residuals=np.random.default_rng(0).standard_normal(m.n), starts=[{}])
    space = SimpleNamespace(ndim=1)
    out = channel_misfit(m, rows, space, None, "chi2", ls, None,
                         FitRequest("rough_conductor", bootstrap=None, seed=0))
    assert out["bootstrap"] is None and out["warnings"] == []
    assert out["goodness"]["describes_data"]
    out = channel_misfit(m, rows, space, None, "chi2", ls, None,
                         FitRequest("rough_conductor", bootstrap=50, seed=0))
    assert "needs at least 3" in out["bootstrap"]["skipped"]
    assert out["warnings"][0].startswith("no bootstrap: 2 fitted incidence direction(s)")


@pytest.mark.slow
def test_one_incidence_no_bootstrap():
    """The Walter protocol fits one incidence: nothing to resample (by default silently, asked
    for explicitly with a warning)."""
    m = fitlab.read(ROOT / "data_formats" / "examples" / "walter_rough_glass.csv")
    r = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", starts=2)
    assert r.bootstrap() is None and "bootstrap" not in r.diagnostics()
    assert r.goodness()["describes_data"]  # the example is the model plus 5% noise
    r = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", starts=2, bootstrap=50)
    assert "needs at least 3" in r.diagnostics()["bootstrap"]["skipped"]
    assert any("no bootstrap" in w for w in r.warnings["Y"])


# --------------------------------------------------------------------------------------------
# Statistical behaviour (slow)
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("with_sigma", [True, False], ids=["chi2", "relative"])
def test_checks_pass_at_their_nominal_rate(with_sigma):
    """30 datasets from the fitted model with the noise its loss assumes: no check fails beyond
    the nominal 0.1% (at most one failure in 30 is allowed for 2-3 checks each), and the runs
    and level p-values are not piled up near 0 (at most 8 of 30 below 0.1, where 3 are
    expected). The relative loss's noise model is multiplicative above its floor (1% of the
    largest value) and absolute below it: σ = 3% · max(f, floor)."""
    fails, low_runs, low_level = 0, 0, 0
    n = 30
    for seed in range(n):
        noise = 0.03
        m = synthetic("rough_conductor", TRUTH, seed=100 + seed, rel_noise=noise,
                      sigma=with_sigma)
        if not with_sigma:
            f = np.asarray(fitlab.eval_bsdf("rough_conductor", TRUTH, m.wi, m.wo))
            rng = np.random.default_rng(100 + seed)
            sigma = noise * np.maximum(f, 0.01 * f.max())
            m = m._replace(value=f + sigma * rng.standard_normal(f.shape))
        r = fitlab.fit(m, "rough_conductor", fix={"n": 1.5, "k": 3.0}, starts=2, seed=seed,
                       bootstrap=0)
        g = r.goodness()
        fails += not g["describes_data"]
        low_runs += g["runs_test"]["p_value"] < 0.1
        low_level += (g["incidence_level"]["min_p_value_sidak"] or 1.0) < 0.1
    assert fails <= 1, f"{fails} of {n} fits of the right model failed a check"
    assert low_runs <= 8 and low_level <= 8, (low_runs, low_level)


@pytest.mark.slow
@pytest.mark.optimized  # the bootstrap's refits: 14 s at -O0, 5.5 s optimized (alone)
def test_bootstrap_agrees_with_least_squares_when_the_model_is_right():
    """Right model, right noise, 12 incidences: the bootstrap standard error of α agrees with
    the least-squares one (geometric mean of the ratio over 6 datasets within [0.7, 1.4]; each
    within [0.45, 2.2]: a bootstrap over 12 blocks is itself uncertain by ~20%)."""
    ratios = []
    thetas = tuple(float(t) for t in range(0, 80, 6))[:12]
    for seed in range(6):
        m = synthetic("rough_conductor", TRUTH, seed=200 + seed, thetas_i=thetas, step=10.0)
        r = fitlab.fit(m, "rough_conductor", fix={"n": 1.5, "k": 3.0}, starts=2, seed=seed,
                       bootstrap=200)
        ratios.append(r.bootstrap()["alpha"]["std"] / r.stderr["Y"]["alpha"])
    ratios = np.asarray(ratios)
    assert np.all((ratios > 0.45) & (ratios < 2.2)), ratios
    assert 0.7 < np.exp(np.mean(np.log(ratios))) < 1.4, ratios


@pytest.mark.slow
@pytest.mark.parametrize("case", ["beckmann_for_ggx", "one_lobe_for_two"])
def test_wrong_model_fails_and_bootstrap_is_wider_than_mcmc(case):
    """Data of another model: the checks fail, the warning says so, and the bootstrap's 68%
    interval of α is at least 3 × wider than the MCMC one."""
    if case == "beckmann_for_ggx":
        m = synthetic("rough_conductor", TRUTH, seed=7)
        model, options, fix = "rough_conductor", {"distribution": "beckmann"}, {"n": 1.5, "k": 3.0}
    else:  # a sharp and a broad lobe, fitted with the broad one and a Lambertian
        params = {"albedo": 0.3, "alpha": 0.08, "n": 1.5, "k": 3.0}
        a = synthetic("lambertian+rough_conductor", params, seed=8, sigma=True)
        broad = np.asarray(fitlab.eval_bsdf("rough_conductor", {"alpha": 0.4, "n": 1.5, "k": 3.0},
                                            a.wi, a.wo))
        m = a._replace(value=a.value + 0.5 * broad, sigma=a.sigma + 0.015 * broad)
        model, options, fix = "lambertian+rough_conductor", {}, {"n": 1.5, "k": 3.0}
    r = fitlab.fit(m, model, options=options, fix=fix, mcmc=True, mcmc_steps=1500, starts=2,
                   bootstrap=100)
    g = r.goodness()
    assert not g["describes_data"] and "runs_test" in g["failed"], g["failed"]
    assert "posterior_predictive" in g["failed"]
    assert any(w.startswith("THE MODEL DOES NOT DESCRIBE THE DATA") for w in r.warnings["Y"])
    post, boot = r.posterior()["alpha"], r.bootstrap()["alpha"]
    ratio = (boot["p84"] - boot["p16"]) / (post["p84"] - post["p16"])
    assert ratio > 3, ratio
