"""Issue 34, items 2 and 3: one fit error, and a bootstrap that respects time.

One definition of the fit error (fitlab.metrics.fit_error, data_formats/fit_json.md "The fit
error"): the terminal of `fitlab fit`, the parameter file, the report's text, `fitlab compare`'s
in-sample error and `fitlab tradeoffs` show the same figure for one fit. The block bootstrap
stops when its intervals settle (below its cap on a well-constrained fit, with the reason
recorded), is skipped when least squares ends at a bound or its iteration limit (the Status
recorded, the reason printed), and such a fit says so on stderr the moment least squares ends,
before the bootstrap."""

from __future__ import annotations

import contextlib
import html
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.metrics import fit_error, fit_error_of, fit_error_text

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"
NUMBER = re.compile(r"RMS relative error ([0-9.eE+-]+) over (\d+) of (\d+) fitted rows "
                    r"\(rows below 1% of their incidence's peak left out\)")


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def test_rule_is_per_incidence_peak():
    """A weak incidence keeps its rows (a channel-wide floor would drop them all), and a row
    below 1% of its own incidence's peak is left out."""
    value = np.array([100.0, 50.0, 5.0, 0.2, 0.1, 0.0005])
    theta = np.array([60.0, 60.0, 60.0, 0.0, 0.0, 0.0])
    fe = fit_error(value * 1.1, value, theta, np.zeros(6))
    assert fe["rows"] == 5 and fe["rows_scored"] == 6  # only 0.0005 < 1% of 0.2
    assert fe["rms_relative_error"] == pytest.approx(0.1)
    assert [r["rows_counted"] for r in fe["per_incidence"]] == [2, 3]
    assert fit_error_text(fe) == ("RMS relative error 0.1 over 5 of 6 fitted rows (rows below "
                                  "1% of their incidence's peak left out)")
    # a file written before fit_error: its own figure, with its own (channel) rule
    old = fit_error_of({"rms_relative_error_fit": 0.93, "relative_error_floor": 0.01})
    assert "0.93 over the fitted rows (rows below 1% of the channel's peak" in fit_error_text(old)


@pytest.fixture(scope="module")
def walter_fit(tmp_path_factory):
    """The Walter example fitted with rough_dielectric (no bootstrap), its parameter file and
    report, as a user runs `fitlab fit ... --report`."""
    out = tmp_path_factory.mktemp("fit")
    code, _, err = run_cli(["fit", str(WALTER), "--model", "rough_dielectric", "--bootstrap",
                            "0", "--starts", "2", "--out", str(out / "fit.json"),
                            "--report", str(out / "report")])
    assert code == 0, err
    return out, err


def test_one_fit_error_everywhere(walter_fit, tmp_path):
    out, err = walter_fit
    st = json.loads((out / "fit.json").read_text(encoding="utf-8"))["fits"][0]["statistics"]
    fe = st["fit_error"]
    assert "rms_relative_error_fit" not in st  # one figure, not two
    assert fe["rows_scored"] == st["n_fit"] == 276 and 0 < fe["rows"] < 276
    text = fit_error_text(fe)
    # the terminal: the stored figure with its rule beside it
    (shown,) = NUMBER.findall(err)
    assert float(shown[0]) == pytest.approx(fe["rms_relative_error"], rel=1e-3)
    assert (int(shown[1]), int(shown[2])) == (fe["rows"], fe["rows_scored"]) and text in err
    # the report's text
    page = html.unescape((out / "report" / "index.html").read_text(encoding="utf-8"))
    assert text in page
    # fitlab compare: the same fit (same starts, no bootstrap) has that in-sample error
    code, _, cerr = run_cli([
        "compare", str(WALTER), "--model", "rough_dielectric", "--model",
        "rough_dielectric --option distribution=beckmann --label beckmann", "--no-mcmc",
        "--starts", "2", "--no-report", "--no-fits", "--out", str(tmp_path / "cmp"), "--quiet"])
    assert code == 0, cerr
    rec = json.loads((tmp_path / "cmp" / "compare.json").read_text(encoding="utf-8"))
    mine = rec["channels"][0]["models"][0]
    assert mine["label"] == "rough_dielectric"
    assert mine["in_sample"]["rms_relative_error"] == fe["rms_relative_error"]
    assert mine["in_sample"]["text"] == text
    assert mine["in_sample"]["per_incidence"] == [r["rms_relative_error"]
                                                  for r in fe["per_incidence"]]
    # fitlab tradeoffs shows the fit's own error (its material record)
    from fitlab.tradeoffs.run import fit_errors

    assert fit_errors(fitlab.load_fit(out / "fit.json"))["Y"]["text"] == text


def write_lambertian(path, thetas_i=(0.0, 20.0, 40.0, 60.0), seed=3):
    """A Lambertian BRDF (albedo 0.5, 2% noise) at these incidences: Oren–Nayar fitted to it
    ends with its roughness sigma at the lower bound 0."""
    rows = [(ti, 0.0, to, po) for ti in thetas_i for to in range(0, 81, 10)
            for po in (0.0, 90.0, 180.0)]
    rng = np.random.default_rng(seed)
    lines = ["# quantity: bsdf", "# scatter: brdf", "theta_i,phi_i,theta_o,phi_o,value"]
    lines += [f"{a:g},{b:g},{c:g},{d:g},{0.5 / np.pi * (1 + 0.02 * rng.standard_normal()):.8g}"
              for a, b, c, d in rows]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_bootstrap_stops_when_intervals_settle(tmp_path):
    """A well-constrained fit (the Lambertian it was drawn from, 13 incidences, the default
    bootstrap): fewer refits than the cap, stopped because the intervals settled, the reason
    recorded and printed."""
    from fitlab.fitting.resampling import DEFAULT_BOOTSTRAP, SETTLE_REFITS

    data = write_lambertian(tmp_path / "lambert.csv", thetas_i=tuple(range(0, 75, 6)), seed=0)
    code, _, err = run_cli(["fit", str(data), "--model", "lambertian", "--starts", "2",
                            "--out", str(tmp_path / "fit.json"), "-v"])
    assert code == 0, err
    fit = json.loads((tmp_path / "fit.json").read_text(encoding="utf-8"))["fits"][0]
    boot = fit["bootstrap"]
    assert boot["stopped"] == "converged", boot
    assert 2 * SETTLE_REFITS <= boot["refits"] < boot["requested"] == DEFAULT_BOOTSTRAP
    assert boot["replicates"] == boot["refits"]
    assert boot["stop_reason"].startswith(f"the 68% intervals settled after {boot['refits']} "
                                          "refits") and boot["stop_reason"] in err
    b = fit["parameters"]["albedo"]["bootstrap"]
    assert b["p16"] < fit["parameters"]["albedo"]["value"] < b["p84"]


def test_bound_warns_at_once_and_skips_bootstrap(tmp_path):
    data = write_lambertian(tmp_path / "lambert.csv")
    code, _, err = run_cli(["fit", str(data), "--model", "oren_nayar", "--starts", "2", "-v",
                            "--out", str(tmp_path / "fit.json")])
    assert code == 0, err
    fit = json.loads((tmp_path / "fit.json").read_text(encoding="utf-8"))["fits"][0]
    assert fit["parameters"]["sigma"]["at_bound"]
    boot = fit["bootstrap"]
    assert boot["skipped_status"] == "at_bound" and boot["refits"] == 0
    assert "sigma at a bound" in boot["skipped"] and "--fix" in boot["skipped"]
    # the warning comes the moment least squares ends, names what to try, and precedes the
    # bootstrap's line and the summary
    warn = err.index("warning: channel Y: least squares ended at a bound of the range: sigma")
    assert "fix it at the bound" in err[warn:warn + 400]
    assert warn < err.index("\nchannel Y:")  # the summary comes after
    # with -v, the progress line of the bootstrap, then the warning in full
    code, _, err = run_cli(["fit", str(data), "--model", "oren_nayar", "--starts", "2",
                            "--out", str(tmp_path / "fit.json"), "-v"])
    warn = err.index("warning: channel Y: least squares ended at a bound of the range: sigma")
    assert warn < err.index("bootstrap skipped: least squares ended with sigma at a bound")
    assert "warning: channel Y: no bootstrap: least squares ended with sigma" in err


def test_iteration_limit_warns_at_once_and_skips_bootstrap(capsys, monkeypatch):
    import fitlab.fitting.least_squares as fls

    def far_start(search, k, problem, scan_problem, scan_rows, ndim, seed, starts, *args,
                  **kwargs):  # every start far from the optimum (as in the failure tests)
        return np.full((starts + 1, ndim), 0.05), {"algorithm": "test stub", "evaluations": 0,
                                                   "non_finite": 0, "status": "skipped",
                                                   "best_cost": None}

    monkeypatch.setattr(fls, "global_start", far_start)
    r = fitlab.fit(WALTER, "rough_dielectric", starts=2, lm_maxiter=2, progress=True)
    err = capsys.readouterr().err
    boot = r.diagnostics()["bootstrap"]
    assert r.record["fits"][0]["solver"]["stopped"] == "max_iterations"
    assert boot["skipped_status"] == "max_iterations" and "did not converge" in boot["skipped"]
    warn = err.index("warning: channel Y: least squares stopped at its iteration limit (2 ")
    assert "--lm-maxiter" in err[warn:warn + 300]
    assert warn < err.index("bootstrap skipped: least squares did not converge")
