"""`fitlab fit` from the command line: parameter file and chain written atomically and readable,
clean failures (exit 2, message naming file/line/field, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.export.paramfile import SCHEMA, SCHEMA_VERSION, read_fit

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"
WALTER = str(EXAMPLES / "walter_rough_glass.csv")


def _strip_volatile(rec):
    rec = json.loads(json.dumps(rec))
    for f in rec["fits"]:
        if f["mcmc"]:
            f["mcmc"].pop("warnings")
    return rec


def test_fit_walter_with_mcmc_and_chain(tmp_path, capsys):
    out, chain = tmp_path / "fit.json", tmp_path / "chain.npz"
    argv = ["fit", WALTER, "--model", "rough_dielectric", "--fit-subset", "theta_i == 0", "-v",
            "--mcmc", "--mcmc-steps", "400", "--seed", "7", "--walter-diagnostics",
            "--out", str(out), "--chain", str(chain)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "MCMC 100%" in err and "prediction" in err
    assert "TOO SHORT TO TRUST" in err  # 400 steps is deliberately short: it must say so
    rec = read_fit(out)
    assert rec["schema"] == SCHEMA and rec["schema_version"] == SCHEMA_VERSION
    assert rec["model"]["options"] == {"distribution": "ggx", "fresnel": "exact",
                                       "sampling": "standard"}
    assert rec["data"]["rows_fitted"] == 69 and rec["data"]["fit_subset"] == "theta_i == 0"
    assert len(rec["data"]["sha256"]) == 64 and rec["seed"] == 7
    assert "created_utc" not in rec and "timings_s" not in rec  # no clock time without --timings
    (fit,) = rec["fits"]
    p = fit["parameters"]
    assert p["eta"] == {"value": 1.51, "unit": "1", "fixed": True, "bounds": [0.2, 5.0]}
    post = p["alpha"]["posterior"]
    assert post["p16"] < post["median"] < post["p84"]
    assert fit["mcmc"]["trustworthy"] is False and fit["mcmc"]["coordinates"][-1] == "log_noise"
    assert fit["diagnostics"]["empirical_D"]["points"] > 30
    assert {r["role"] for r in fit["statistics"]["per_incidence"]} == {"fit", "prediction"}
    for pkg in ("jax", "jaxopt", "emcee", "nlopt", "numpy", "fitlab"):
        assert rec["software"][pkg]
    npz = np.load(chain)
    assert npz["chain_Y"].shape == (400, 32, 3)
    assert list(npz["coordinates_Y"]) == ["alpha", "scale", "log_noise"]
    assert sorted(q.name for q in tmp_path.iterdir()) == ["chain.npz", "fit.json"]

    # Same seed, same result (byte for byte: tests/project/test_determinism.py).
    out2 = tmp_path / "fit2.json"
    assert main(argv[:-4] + ["--out", str(out2), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    a, b = _strip_volatile(read_fit(out)), _strip_volatile(read_fit(out2))
    assert a["fits"] == b["fits"]


def test_fit_to_stdout_without_mcmc(capsys):
    data = EXAMPLES / "measurement_rgb_sigma.csv"
    assert main(["fit", str(data), "--model", "lambertian", "--quiet", "--timings"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert set(rec["timings_s"]) == {"read", "least_squares", "total"}  # asked for: no MCMC
    assert all("timings_s" not in f for f in rec["fits"])
    assert [f["channel"] for f in rec["fits"]] == ["R", "G", "B"]
    assert all(f["mcmc"] is None for f in rec["fits"])
    assert rec["loss"] == "chi2"


def test_fit_prints_a_few_lines_unless_verbose(tmp_path, capsys):
    """Issue 34 item 7: by default an RGB fit says in at most 20 lines (on stderr; the results
    go to the files and stdout) each channel's parameters, error and verdict and what limits
    trust; -v prints the rest: progress, per-incidence errors, every warning with its advice."""
    data = EXAMPLES / "measurement_rgb_sigma.csv"
    out = tmp_path / "fit.json"
    argv = ["fit", str(data), "--model", "lambertian", "--bootstrap", "0", "--out", str(out)]
    assert main(argv) == 0
    brief = capsys.readouterr()
    lines = brief.err.splitlines()
    assert brief.out == "" and len(lines) <= 20, brief.err
    assert [ln.split(":")[0] for ln in lines if ln.startswith("channel ")] == \
        ["channel R", "channel G", "channel B"]
    assert lines[-1].startswith(f"wrote {out}")
    fits = json.loads(out.read_text(encoding="utf-8"))["fits"]
    assert main(argv + ["-v"]) == 0
    full = capsys.readouterr().err
    assert len(full.splitlines()) > len(lines)
    assert "fitting lambertian to channel R" in full and "theta_i =" in full and "time:" in full
    assert "fitting lambertian" not in brief.err and "theta_i =" not in brief.err
    for fit in fits:  # every warning: whole with -v, counted by default, kept in the file
        for w in fit["warnings"]:
            assert f"warning: channel {fit['channel']}: {w}" in full and w not in brief.err
        if fit["warnings"]:
            assert f"{len(fit['warnings'])} warning" in brief.err


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--model", "nosuch"], "unknown model"),
        (["--model", "rough_dielectric", "--fix", "beta=1"], "has no parameter 'beta'"),
        (["--model", "rough_dielectric", "--fix", "alpha=7"], "outside its bounds"),
        (["--model", "rough_dielectric", "--fix", "alpha=x"], "must be a number"),
        (["--model", "rough_dielectric", "--free", "gamma"], "has no parameter 'gamma'"),
        (["--model", "rough_dielectric", "--chain", "c.npz"], "--chain needs --mcmc"),
        (["--model", "rough_dielectric", "--mcmc", "--mcmc-steps", "10"], "at least 100"),
        (["--model", "rough_dielectric", "--fit-subset", "theta_i == 99"], "selects no rows"),
        (["--model", "rough_dielectric", "--fit-subset", "import os"], "not a valid expression"),
        (["--model", "rough_dielectric", "--loss", "chi2"], "needs a sigma column"),
        (["--model", "rough_dielectric", "--option", "distribution=x"], "must be one of"),
        (["--model", "rough_dielectric", "--channel", "R"], "has channels Y"),
        (["--model", "rough_dielectric", "--lm-maxiter", "0"], "--lm-maxiter must be an integer from 1"),
    ],
)
def test_fit_bad_arguments_write_nothing(tmp_path, capsys, monkeypatch, extra, fragment):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "never.json"
    code = main(["fit", WALTER, "--quiet", "--out", str(out)] + extra)
    assert code == 2
    assert fragment in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_fit_everything_fixed(tmp_path, capsys):
    data = EXAMPLES / "measurement_rgb_sigma.csv"
    out = tmp_path / "never.json"
    assert main(["fit", str(data), "--model", "lambertian", "--fix", "albedo=0.5",
                 "--out", str(out)]) == 2
    assert "nothing to fit" in capsys.readouterr().err
    assert not out.exists()


def test_fit_bad_data_names_file_and_line(tmp_path, capsys):
    bad = EXAMPLES / "invalid" / "measurement_negative.csv"
    before = bad.read_bytes()
    out = tmp_path / "never.json"
    assert main(["fit", str(bad), "--model", "lambertian", "--out", str(out)]) == 2
    assert f"{bad}:4: column 'value'" in capsys.readouterr().err
    assert not out.exists() and bad.read_bytes() == before


def test_read_fit_rejects_other_versions(tmp_path):
    f = tmp_path / "v9.json"
    f.write_text(json.dumps({"schema": SCHEMA, "schema_version": 9}))
    with pytest.raises(InputFileError, match="schema_version 9"):
        read_fit(f)
    f.write_text("{not json")
    with pytest.raises(InputFileError, match="not valid JSON"):
        read_fit(f)
    f.write_text(json.dumps({"schema": "other"}))
    with pytest.raises(InputFileError, match="not a fitlab parameter file"):
        read_fit(f)


def test_least_squares_shows_progress_unless_quiet(tmp_path, capsys):
    """Issue 14 item 6: the least-squares stage is not silent (what the global stage does: the
    scan's one call, or nlopt's search with a bar and the time left; then the
    Levenberg-Marquardt stage); --quiet silences it."""
    from fitlab.cli import main

    src = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "walter_rough_glass.csv"
    args = ["fit", str(src), "--model", "rough_dielectric", "--fit-subset", "theta_i == 0",
            "--starts", "2", "--out", str(tmp_path / "f.json")]
    assert main(args + ["-v"]) == 0
    err = capsys.readouterr().err
    assert "global scan: the cost at 768 points in one call" in err  # 2 free: 256 x 3
    assert "Levenberg-Marquardt from 4 starts" in err
    assert main(args + ["-v", "--global-search", "mlsl"]) == 0
    err = capsys.readouterr().err
    assert "global search" in err and "eval" in err and "Levenberg-Marquardt from 4 starts" in err
    g = json.loads((tmp_path / "f.json").read_text(encoding="utf-8"))["fits"][0]["global_search"]
    assert g["algorithm"].startswith("nlopt G_MLSL_LDS") and g["evaluations"] > 0
    # by default progress is one status line on a terminal, and nothing in a file or pipe
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "global search" not in err and "Levenberg" not in err and "channel Y: alpha" in err
    assert main(args + ["--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_lm_step_limit_from_the_command_line(tmp_path, capsys):
    """--lm-maxiter sets each Levenberg-Marquardt run's step limit, and the file records it (the
    warning that names the option: tests/fitting/test_fit_failures.py)."""
    out = tmp_path / "fit.json"
    assert main(["fit", WALTER, "--model", "rough_dielectric", "--fit-subset", "theta_i == 30",
                 "--lm-maxiter", "1", "--starts", "2", "--bootstrap", "0", "--quiet",
                 "--out", str(out)]) == 0
    (fit,) = read_fit(out)["fits"]
    assert fit["solver"]["max_iterations"] == 1
    assert all(s["lm_iterations"] <= 1 for s in fit["starts"])
    assert any(s["lm_stopped"] == "max_iterations" for s in fit["starts"])
