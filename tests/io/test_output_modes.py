"""Outputs follow the umask like a plain open() (issue 13: atomic writes kept the temporary
file's private 0600 mode): JSON, CSV, Zemax, MERL, EXR, GLSL and report files."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from fitlab.cli import main
from fitlab.io.atomic import atomic_write_text

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_atomic_write_follows_the_umask(tmp_path):
    for mask in (0o022, 0o077, 0o002):
        old = os.umask(mask)
        try:
            p = tmp_path / f"x{mask:o}.txt"
            atomic_write_text(p, "hello\n")
            assert _mode(p) == 0o666 & ~mask
        finally:
            os.umask(old)


def test_command_outputs_are_readable_by_others(tmp_path, umask_022):
    outs = {"bsdf": tmp_path / "m.bsdf", "binary": tmp_path / "m.binary",
            "exr": tmp_path / "t.exr"}
    assert main(["convert", "--model", "lambertian", "--param", "albedo=0.5", "--aoi", "0,40",
                 "--radial", "0:80:20", str(outs["bsdf"])]) == 0
    assert main(["convert", "--model", "lambertian", "--param", "albedo=0.5",
                 str(outs["binary"])]) == 0
    assert main(["lut", "fresnel", "--preset", "copper", "--size", "16", "--out",
                 str(outs["exr"])]) == 0
    written = [*outs.values(), tmp_path / "t.glsl"]
    assert main(["convert", str(outs["bsdf"]), str(tmp_path / "m.csv")]) == 0
    written.append(tmp_path / "m.csv")
    for p in written:
        assert _mode(p) == 0o644, (p, oct(_mode(p)))
