"""The command line: every subcommand has --help; `models` lists the registry; `eval` reproduces
the library's eval_bsdf, writes atomically, and fails cleanly (exit 2, message, no output file)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import build_parser, main
from fitlab.io.csvtable import read_table
from fitlab.io.directions import read_directions

EXAMPLE = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "directions_inplane.csv"


def _subcommands():
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return list(action.choices)


@pytest.mark.parametrize("sub", _subcommands())
def test_every_subcommand_has_help(sub, capsys):
    with pytest.raises(SystemExit) as info:
        main([sub, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "usage: fitlab " + sub in out


def test_models_lists_every_model(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for name, model in fitlab.MODELS.items():
        assert name in out
        for p in model.parameters:
            assert f"--param {p.name}=" in out
    assert "normal = +z" in out and "eta = n_inside / n_outside" in out


def test_models_json(capsys):
    assert main(["models", "rough_dielectric", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    (m,) = data["models"]
    assert m["name"] == "rough_dielectric"
    alpha = next(p for p in m["parameters"] if p["name"] == "alpha")
    assert (alpha["lower"], alpha["upper"]) == (1e-4, 1.0)
    assert {o["name"] for o in m["options"]} == {"distribution", "fresnel", "sampling"}


@pytest.mark.parametrize(
    "model, params, options",
    [
        ("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, {}),
        ("rough_dielectric", {"alpha": 0.05, "eta": 1 / 1.33}, {"distribution": "beckmann"}),
        ("rough_conductor", {"alpha": 0.2, "n": 1.04, "k": 2.59}, {"fresnel": "lazanyi"}),
        ("lambertian", {"albedo": 0.7}, {}),
        ("oren_nayar", {"albedo": 0.7, "sigma": 0.4}, {}),
    ],
)
def test_eval_matches_library(tmp_path, model, params, options):
    out = tmp_path / "f.csv"
    argv = ["eval", model, "--directions", str(EXAMPLE), "--out", str(out)]
    argv += [a for k, v in params.items() for a in ("--param", f"{k}={v!r}")]
    argv += [a for k, v in options.items() for a in ("--option", f"{k}={v}")]
    assert main(argv) == 0
    table = read_table(out, ("theta_i", "phi_i", "theta_o", "phi_o", "value"))
    assert table.metadata["quantity"] == "bsdf"
    assert table.metadata["model"] == model
    pairs = read_directions(EXAMPLE)
    wi, wo = pairs.cartesian()
    expected = np.asarray(fitlab.eval_bsdf(model, params, wi, wo, options))
    np.testing.assert_allclose(table.columns["value"], expected, rtol=1e-9, atol=0)
    np.testing.assert_array_equal(table.columns["theta_o"], pairs.theta_o)
    assert np.any(expected > 0)


def test_eval_float32(tmp_path):
    out = tmp_path / "f32.csv"
    assert main(["eval", "rough_dielectric", "--param", "alpha=0.3", "--param", "eta=1.5",
                 "--directions", str(EXAMPLE), "--out", str(out), "--dtype", "float32"]) == 0
    table = read_table(out, ("theta_i", "phi_i", "theta_o", "phi_o", "value"))
    wi, wo = read_directions(EXAMPLE).cartesian()
    f64 = np.asarray(fitlab.eval_bsdf("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, wi, wo))
    np.testing.assert_allclose(table.columns["value"], f64, rtol=2e-4, atol=1e-6)
    assert table.metadata["precision"] == "float32"


def test_eval_to_stdout(capsys):
    assert main(["eval", "lambertian", "--param", "albedo=0.5", "--directions", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1].endswith(",0.000000000e+00")  # θo = 180°: below the surface
    assert f"{0.5 / np.pi:.9e}" in out


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["eval", "nosuchmodel", "--param", "a=1"], "unknown model 'nosuchmodel'"),
        (["eval", "rough_dielectric", "--param", "alpha=0.3"], "needs values for: eta in [0.2, 5]"),
        (["eval", "rough_dielectric", "--param", "alpha=2", "--param", "eta=1.5"], "outside its bounds"),
        (["eval", "rough_dielectric", "--param", "alpha=0.3", "--param", "eta=1.5", "--param", "beta=1"],
         "has no parameter 'beta'"),
        (["eval", "rough_dielectric", "--param", "alpha=x", "--param", "eta=1.5"], "must be a number"),
        (["eval", "rough_dielectric", "--param", "alpha", "--param", "eta=1.5"], "NAME=VALUE"),
        (["eval", "rough_dielectric", "--param", "alpha=0.3", "--param", "eta=1.5",
          "--option", "distribution=cauchy"], "must be one of ggx"),
        (["eval", "lambertian", "--param", "albedo=0.3", "--option", "distribution=ggx"],
         "has no option 'distribution'"),
        (["eval", "lambertian", "--param", "albedo=nan"], "must be finite"),
    ],
)
def test_eval_bad_arguments(tmp_path, capsys, argv, fragment):
    out = tmp_path / "never.csv"
    argv = argv + ["--directions", str(EXAMPLE), "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_eval_bad_directions_leaves_nothing(tmp_path, capsys):
    bad = EXAMPLE.parent / "invalid" / "directions_non_numeric.csv"
    out = tmp_path / "never.csv"
    assert main(["eval", "lambertian", "--param", "albedo=0.5", "--directions", str(bad),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:2: column 'theta_o'" in err
    assert list(tmp_path.iterdir()) == []


def test_eval_missing_output_folder(tmp_path, capsys):
    out = tmp_path / "no" / "such" / "f.csv"
    assert main(["eval", "lambertian", "--param", "albedo=0.5", "--directions", str(EXAMPLE),
                 "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_eval_overwrites_atomically(tmp_path):
    out = tmp_path / "f.csv"
    out.write_text("old")
    assert main(["eval", "lambertian", "--param", "albedo=0.5", "--directions", str(EXAMPLE),
                 "--out", str(out)]) == 0
    assert out.read_text().startswith("# fitlab eval output")
    assert [p.name for p in tmp_path.iterdir()] == ["f.csv"]


def test_console_script_runs():
    """The installed entry point (the README quick start uses it) works as a process."""
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-m", "fitlab.cli", "models"], capture_output=True,
                          text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "rough_dielectric" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "fitlab.cli", "eval", "lambertian",
                           "--directions", str(EXAMPLE)], capture_output=True, text=True,
                          env=env, timeout=120)
    assert proc.returncode == 2
    assert "needs values for: albedo" in proc.stderr


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_output_into_a_closed_pipe_is_not_an_error():
    """`fitlab info FILE | head -1`: a reader that closes the pipe early ends fitlab quietly."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fitlab.cli", "info", "data_formats/examples/lut_fresnel_copper.exr"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=Path(__file__).resolve().parents[2])
    proc.stdout.close()  # closed before fitlab has written anything (it is still importing jax)
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, stderr
    assert "Traceback" not in stderr, stderr


def _help(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv + ["--help"])
    assert info.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines


def _option(parser_argv, dest):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[parser_argv]
    return next(a for a in sub._actions if a.dest == dest)


def test_choices_and_help_come_from_the_registries(capsys):
    """No list of names the registries hold is written out in the CLI: formats, writers, LUT
    kinds, mappings, losses, presets are each listed from their registry."""
    from fitlab import lut
    from fitlab.export.writers import DEFAULT, WRITERS, writer_for
    from fitlab.fitting.losses import LOSSES
    from fitlab.io.formats import formats
    from fitlab.models.presets import PRESETS

    assert list(_option("convert", "to").choices) == list(WRITERS)
    assert list(_option("fit", "loss").choices) == list(LOSSES)
    for w in WRITERS.values():
        for suffix in w.suffixes:
            assert writer_for(f"out{suffix.upper()}") is w
    convert = _help(["convert"], capsys)
    for w in WRITERS.values():
        assert w.spec in convert
        assert w.name == DEFAULT or f"{w.name} for *{w.suffixes[0]}" in convert
    for command in ("fit", "info", "convert"):
        text = _help([command], capsys)
        assert all(name in text for name in formats()), command
    text = _help(["lut"], capsys)
    assert all(f"{k} (" in text for k in lut.KINDS) and all(m in text for m in lut.MAPPINGS)
    assert all(p in _help(["eval"], capsys) for p in PRESETS)


def test_models_json_carries_the_conventions(capsys):
    from fitlab.io.conventions import conventions_text

    assert main(["models", "lambertian", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["conventions"] == conventions_text()


def test_info_of_a_parameter_file(capsys):
    fit = EXAMPLE.parents[2] / "fits" / "walter_rough_glass.json"
    assert main(["info", str(fit), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "fit-json" and info["channels"] == ["Y"]
    assert set(info["parameters"]["Y"]) == {"alpha", "eta", "scale"}


@pytest.mark.parametrize("argv, says", [
    # no abbreviations: a prefix of an option is not that option
    (["fit", "x.csv", "--model", "lambertian", "--mcmc-step", "100"],
     "fitlab fit: error: unrecognized arguments: --mcmc-step 100 (--mcmc-step: did you mean "
     "--mcmc-steps?)"),
    (["fit", "x.csv", "--model", "lambertian", "--lm-maxiterr=3"],
     "(--lm-maxiterr: did you mean --lm-maxiter?)"),
    (["fit", "x.csv", "--modle", "lambertian"],
     "fitlab fit: error: the following arguments are required: --model (--modle: did you mean "
     "--model?)"),
    (["info", "x.csv", "--bogus"],
     "fitlab info: error: unrecognized arguments: --bogus (see `fitlab info --help`)"),
    (["fti", "x.csv"], "; did you mean fit?"),
])
def test_unknown_options_answer_with_the_subcommands_usage_and_a_suggestion(argv, says, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert says in err, err
    # the usage printed is the subcommand's own
    command = argv[0] if argv[0] != "fti" else None
    assert err.startswith(f"usage: fitlab {command} " if command else "usage: fitlab ["), err
