"""Deeply nested input files (issue 13: a RecursionError traceback from the JSON and TOML
parsers): exit 2, the file named, nothing written."""

from __future__ import annotations

import pytest

from fitlab.cli import main


@pytest.mark.parametrize("argv_of, fragment", [
    (lambda src, out: ["report", str(src), "--out", str(out / "r")],
     "nests too deeply to be a fitlab parameter file"),
    (lambda src, out: ["lut", "model", "--from-fit", str(src), "--out", str(out / "t.exr")],
     "nests too deeply to be a fitlab parameter file"),
])
def test_deep_json_fit_file(tmp_path, capsys, argv_of, fragment):
    src = tmp_path / "deep.json"
    src.write_text("[" * 200_000 + "]" * 200_000)
    out = tmp_path / "out"
    out.mkdir()
    assert main(argv_of(src, out)) == 2
    err = capsys.readouterr().err
    assert f"{src}: {fragment}" in err and "Traceback" not in err and len(err) < 400
    assert not any(out.iterdir())


def test_deep_scene_toml(tmp_path, capsys):
    src = tmp_path / "deep.toml"
    src.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(src), "--samples", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{src}: nests too deeply to be a scene" in err and "Traceback" not in err
    assert not out.exists()
