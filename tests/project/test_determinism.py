"""Same inputs and seed, same bytes (issue 13): every writer run twice, into two folders, gives
byte-identical files, and no file names an absolute path of the machine (neither the output
folder nor the repository: the inputs are copied beside the outputs, so every recorded path is
a short relative one). Data formats: fit_json.md ("Same inputs, same bytes"), lut_exr.md,
report_html.md ("Determinism"), scene_toml.md ("Determinism and cost")."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from fitlab.cli import main
from fitlab.export.exr import read_exr

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
INPUTS = {
    "walter.csv": EXAMPLES / "walter_rough_glass.csv",
    "vinyl.bsdf": EXAMPLES / "zemax_brown_vinyl.bsdf",
    "glass_fit.json": ROOT / "fits" / "walter_rough_glass.json",
    "scene.toml": EXAMPLES / "scenes" / "rough_dielectric_interface.toml",
}


def _copy_inputs(inp: Path) -> None:
    for dst, src in INPUTS.items():
        shutil.copyfile(src, inp / dst)
    # Walter's data at two incidences only: a report with half the scan figures (matplotlib
    # is most of a report's time).
    lines = INPUTS["walter.csv"].read_text().splitlines(keepends=True)
    (inp / "walter_small.csv").write_text("".join(
        ln for ln in lines if not ln[0].isdigit() or ln.split(",")[0] in ("0", "60")))


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _run_twice(tmp_path: Path, commands) -> dict:
    """Run ``commands(inp, out)`` (a list of argv lists) in two fresh folders ``run1``, ``run2``
    (each with its own copy of the inputs); assert both wrote the same files with the same bytes
    and no absolute path; return the files of the first run."""
    runs = []
    for name in ("run1", "run2"):
        inp, out = tmp_path / name / "in", tmp_path / name / "out"
        inp.mkdir(parents=True)
        out.mkdir()
        _copy_inputs(inp)
        for argv in commands(inp, out):
            assert main([str(a) for a in argv]) == 0, argv
        runs.append(_files(out))
    first, second = runs
    assert sorted(first) == sorted(second)
    differ = [name for name in first if first[name] != second[name]]
    assert not differ, f"these outputs differ between two identical runs: {differ}"
    absolute = {str(tmp_path), str(tmp_path.resolve()), str(ROOT)}
    for name, blob in first.items():
        for path in absolute:
            assert path.encode() not in blob, f"{name} holds the absolute path {path}"
    return first


def test_fit_chain_lut_and_report_are_byte_identical(tmp_path):
    def commands(inp, out):
        fit = out / "fit.json"
        return [
            ["fit", inp / "walter_small.csv", "--model", "rough_dielectric", "--fit-subset",
             "theta_i == 0", "--mcmc", "--mcmc-steps", "100", "--walkers", "8", "--starts", "2",
             "--quiet", "--out", fit, "--chain", out / "chain.npz"],
            ["lut", "model", "--from-fit", fit, "--size", "16x16", "--phi-d", "slice",
             "--check-points", "64",
             "--quiet", "--out", out / "fit_lut.exr"],
            # the chain recorded in the fit; the table beside the fit found and previewed
            # (`fitlab fit --report` builds the same page: the slow test below runs it)
            ["report", fit, "--quiet", "--out", out / "report"],
        ]

    files = _run_twice(tmp_path, commands)
    assert {"fit.json", "chain.npz", "fit_lut.exr", "fit_lut.glsl", "report/index.html",
            "report/corner_Y.svg", "report/lut_fit_lut.svg"} <= set(files)
    fit = files["fit.json"].decode()
    assert "created_utc" not in fit and "timings_s" not in fit
    assert '"path": "../in/walter_small.csv"' in fit and '"path": "chain.npz"' in fit
    page = files["report/index.html"].decode()
    for row in ("parameter file</td><td>../fit.json", "data file</td><td>../../in/walter_small",
                "source fit</td><td>../fit.json", "MCMC chain: ../chain.npz"):
        assert row in page
    assert "fit made" not in page
    # fitlab.source_fit: relative to the table's folder
    assert read_exr(tmp_path / "run1" / "out" / "fit_lut.exr").source_fit == "fit.json"


def test_convert_writers_are_byte_identical(tmp_path):
    def commands(inp, out):
        small = ["--aoi", "0:40:20", "--azimuth", "0:180:90", "--radial", "0:90:30"]
        return [
            ["convert", inp / "vinyl.bsdf", out / "vinyl.csv"],  # Zemax -> CSV
            ["convert", inp / "walter.csv", out / "walter.csv"],  # CSV -> CSV
            ["convert", inp / "glass_fit.json", out / "glass.bsdf", "--scatter", "BTDF",
             *small],  # fit -> Zemax
            ["convert", "--model", "rough_conductor", "--param", "alpha=0.3", "--param",
             "n=0.2", "--param", "k=3.9", out / "cond.binary"],  # model -> MERL
        ]

    files = _run_twice(tmp_path, commands)
    assert b"converted_from: ../in/vinyl.bsdf" in files["vinyl.csv"]
    assert b"# fit: ../in/glass_fit.json" in files["glass.bsdf"]


def test_lut_exr_and_shaders_are_byte_identical(tmp_path):
    def commands(inp, out):
        return [
            ["lut", "fresnel", "--preset", "copper", "--hlsl", "--quiet", "--out",
             out / "copper.exr"],
            ["lut", "D", "--size", "16x16", "--check-points", "64", "--quiet", "--out",
             out / "d.exr"],
            # axes chosen by measurement: the record of both candidates, no run time
            ["lut", "model", "--from-fit", inp / "glass_fit.json", "--phi-d", "auto",
             "--size", "64x64x8", "--check-points", "64", "--quiet", "--out", out / "auto.exr"],
        ]

    files = _run_twice(tmp_path, commands)
    assert {"copper.exr", "copper.glsl", "copper.hlsl", "d.exr", "d.glsl", "auto.exr"} <= set(files)
    assert b"created_utc" not in files["copper.exr"] and b"bake_s" not in files["auto.exr"]


def test_simulate_is_byte_identical(tmp_path):
    def commands(inp, out):
        return [["simulate", inp / "scene.toml", "--samples", "256", "--seed", "5",
                 "--batch-size", "256", "--split-bounces", "--quiet", "--out", out / "sim.csv"]]

    files = _run_twice(tmp_path, commands)
    assert sorted(files) == ["sim.csv", "sim.orders.csv"]
    assert b"# scene: ../in/scene.toml\n" in files["sim.csv"]
    assert b"time_s" not in files["sim.csv"]


@pytest.mark.slow
def test_readme_main_command_is_byte_identical(tmp_path):
    """The README's main command (full MCMC) twice: every output identical."""
    def commands(inp, out):
        return [["fit", inp / "walter.csv", "--model", "rough_dielectric", "--fit-subset",
                 "theta_i == 0", "--mcmc", "--walter-diagnostics", "--quiet",
                 "--out", out / "walter_rough_glass.json",
                 "--chain", out / "walter_rough_glass_chain.npz", "--report", out / "report"]]

    _run_twice(tmp_path, commands)
