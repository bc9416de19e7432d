"""Parameter sweeps of simulator scenes (fitlab/simulate/sweep.py, ``fitlab simulate --sweep``):
the sweep file's validation, every point equal to a plain ``fitlab simulate`` of its scene,
results independent of chunking, resumable reruns, and a worker killed mid-run (slow)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

import fitlab
from fitlab.errors import InputFileError
from fitlab.simulate.sweep import load_sweep, parse_field, point_seed, run_sweep

ROOT = Path(__file__).resolve().parents[2]
SWEEPS = ROOT / "data_formats" / "examples" / "sweeps"
GRID = SWEEPS / "coated_lambertian_grid.toml"


def _cli(*args):
    """``fitlab ARGS`` run in this process (as main() runs it; a child process would spend most
    of its time importing): its exit status and what it printed."""
    import contextlib
    import io
    import types

    from fitlab.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse
            code = exc.code
    return types.SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


def test_valid_examples_load_with_their_points():
    s = load_sweep(GRID)
    assert len(s.points) == 6 and s.keys == ("substrate.albedo", "stack[1].index")
    assert s.values(3) == {"substrate.albedo": 0.5, "stack[1].index": 1.5}
    d = s.scene_dict(5)
    assert d["substrate"]["albedo"] == 0.8 and d["stack"][1]["index"] == 1.5
    assert s.base["substrate"]["albedo"] == 0.8 and s.base["stack"][1]["index"] == 1.5
    assert s.scene_dict(0)["substrate"]["albedo"] == 0.2  # the base is not modified
    assert s.scene(0).boundaries[-1].albedo == (0.2,)
    z = load_sweep(SWEEPS / "hg_medium_zip.toml")
    assert [p[0] for p in z.points] == [0.0, 0.4, 0.8] and z.points[1][1] == [1.0, 0.8, 0.6]


def test_field_paths():
    assert parse_field("stack[1].sigma_s") == ["stack", 1, "sigma_s"]
    assert parse_field("substrate.albedo") == ["substrate", "albedo"]
    for bad in ("stack[x].a", "a..b", "1a", "stack[1"):
        with pytest.raises(ValueError):
            parse_field(bad)


@pytest.mark.parametrize("name, fragments", [
    ("sweep_bad_field.toml", ['grid."stack[one].index"', "field name"]),
    ("sweep_bad_value.toml", ["point 1 (substrate.albedo = -0.1)", "substrate.albedo",
                              "out of range"]),
    ("sweep_missing_table.toml", ['grid."below.index"', "[below] does not exist"]),
    ("sweep_no_samples.toml", ["samples: is missing"]),
    ("sweep_zip_lengths.toml", ["zip", "substrate.albedo: 3", "stack[1].index: 2"]),
])
def test_invalid_examples_name_the_field_and_write_nothing(tmp_path, name, fragments):
    path = SWEEPS / "invalid" / name
    with pytest.raises(InputFileError) as e:
        load_sweep(path)
    for f in fragments:
        assert f in str(e.value), str(e.value)
    before = path.read_bytes()
    r = _cli("simulate", "--sweep", path, "--out-dir", tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert name in r.stderr and fragments[0] in r.stderr
    assert not (tmp_path / "out").exists() and path.read_bytes() == before


def test_more_hostile_sweeps(tmp_path):
    scene = (SWEEPS.parent / "scenes" / "coated_lambertian.toml").resolve()
    cases = {
        "unknown key": ("samplez = 3\n", "did you mean 'samples'"),
        "nan": ('[grid]\n"substrate.albedo" = [nan]\n', "not a finite number"),
        "empty grid": ("[grid]\n", "grid: is missing or empty"),
        "not a list": ('[grid]\n"substrate.albedo" = 0.5\n', "must be a list"),
        "table value": ('[grid]\n"substrate.albedo" = [{a = 1}]\n', "is not a number"),
        "too many": ('mode = "product"\n[grid]\n"substrate.albedo" = ' + str([0.5] * 400)
                     + '\n"stack[1].index" = ' + str([1.5] * 400) + "\n", "more than 100000"),
        "index past the list": ('[grid]\n"stack[7].index" = [1.5]\n', "item [7] does not exist"),
        "bad toml": ("samples = = 3\n", "sweep"),
        "huge integer": ('[grid]\n"substrate.albedo" = [' + "9" * 400 + "]\n",
                         "(400 characters) is not a finite number"),
        "huge integer in a list": ('[grid]\n"substrate.albedo" = [[0.5, 0.5, ' + "9" * 400
                                   + "]]\n", "is not a number, a string"),
        "many keys": ("[grid]\n" + "".join(f'"substrate.x{i}" = [1]\n' for i in range(40)),
                      "has 40 keys, more than 32"),
        "long key": ('[grid]\n"' + "a" * 300 + '" = [1]\n', "field path of 300 characters"),
        "long index": ('[grid]\n"stack[' + "9" * 100 + '].index" = [1]\n',
                       "is not a field name"),
        "long string": ('[grid]\n"substrate.type" = ["' + "x" * 1000 + '"]\n',
                        "is not a number, a string"),
    }
    for label, (body, want) in cases.items():
        f = tmp_path / "s.toml"
        head = f'scene = "{scene.as_posix()}"\n'
        if "samples" not in body:
            head += "samples = 100\n"
        if label in ("unknown key", "bad toml"):
            body += '[grid]\n"substrate.albedo" = [0.5]\n'
        f.write_text(head + body)
        with pytest.raises(InputFileError) as e:
            load_sweep(f)
        assert want in str(e.value), (label, str(e.value))
        assert len(str(e.value)) < len(str(f)) + 300, (label, "the message echoes the file")
    f.write_bytes(b"\xff\xfe garbage")
    with pytest.raises(InputFileError):
        load_sweep(f)
    with pytest.raises(InputFileError, match="does not exist"):
        f.write_text('scene = "nope.toml"\nsamples = 10\n[grid]\n"a.b" = [1]\n')
        load_sweep(f)


def test_point_seeds_are_fixed_and_distinct():
    seeds = [point_seed(0, i) for i in range(1000)]
    assert len(set(seeds)) == 1000 and all(0 <= s < 2**31 for s in seeds)
    assert seeds[:3] == [point_seed(0, 0), point_seed(0, 1), point_seed(0, 2)]
    assert point_seed(1, 0) not in seeds[:10]


def _strip_sweep_lines(text: str) -> str:
    return "".join(l for l in text.splitlines(True)
                   if not l.startswith(("# sweep", "# scene:", "# seed:")))


@pytest.mark.slow
def test_sweep_points_equal_plain_simulations_and_reruns_skip(tmp_path):
    """Every point's CSV is what ``fitlab simulate`` writes for that point's scene and seed;
    the bytes do not depend on the chunking; a rerun skips every chunk; the outputs follow
    the umask and name no absolute path."""
    out1, out2 = tmp_path / "a", tmp_path / "b"
    s1 = run_sweep(GRID, out1, workers=2, points_per_chunk=2, progress=False)
    assert s1 == {"points": 6, "chunks": 3, "done_before": 0, "done_now": 3,
                  "index": str(out1 / "index.csv"), "truncated": 0}
    s2 = run_sweep(GRID, out2, workers=1, points_per_chunk=4, progress=False)
    assert s2["chunks"] == 2
    sweep = load_sweep(GRID)
    for i in range(6):
        a = (out1 / sweep.file_name(i)).read_bytes()
        assert a == (out2 / sweep.file_name(i)).read_bytes()  # chunking changes nothing
        text = a.decode()
        values = [l.split(": ", 1)[-1] for l in text.splitlines() if l.startswith("# ")]
        assert not any(v.startswith(("/", str(ROOT), str(tmp_path))) for v in values)
        m = fitlab.read(out1 / sweep.file_name(i))
        assert json.loads(m.metadata["sweep_values"]) == sweep.values(i)
        assert m.metadata["seed"] == str(point_seed(0, i))
        # the same point by hand: the scene with the point's values, fitlab simulate
        d = sweep.scene_dict(i)
        scene_file = tmp_path / f"scene{i}.toml"
        scene_file.write_text(
            (GRID.parent / "../scenes/coated_lambertian.toml").read_text()
            .replace("albedo = 0.8", f"albedo = {d['substrate']['albedo']}")
            .replace("index = 1.5", f"index = {d['stack'][1]['index']}"))
        r = _cli("simulate", scene_file, "--samples", 4000, "--seed", point_seed(0, i),
                 "--out", tmp_path / f"plain{i}.csv", "--quiet")
        assert r.returncode == 0, r.stderr
        assert _strip_sweep_lines(text) == _strip_sweep_lines(
            (tmp_path / f"plain{i}.csv").read_text())
    index = (out1 / "index.csv").read_text().splitlines()
    assert index[1] == "point,file,seed,substrate.albedo,stack[1].index"
    assert index[2].startswith("0,point_00000.csv,") and len(index) == 8
    assert (out1 / "index.csv").read_bytes() == (out2 / "index.csv").read_bytes()
    umask = os.umask(0)
    os.umask(umask)
    assert (out1 / "point_00000.csv").stat().st_mode & 0o777 == 0o666 & ~umask
    # resumable: nothing to do; a deleted marker is done again, giving the same bytes
    before = {p.name: p.read_bytes() for p in out1.glob("point_*.csv")}
    again = run_sweep(GRID, out1, workers=1, points_per_chunk=2, progress=False)
    assert again["done_before"] == 3 and again["done_now"] == 0
    sorted((out1 / "chunks").glob("*.json"))[0].unlink()
    third = run_sweep(GRID, out1, workers=1, points_per_chunk=2, progress=False)
    assert third["done_now"] == 1
    assert {p.name: p.read_bytes() for p in out1.glob("point_*.csv")} == before


@pytest.mark.slow
def test_sweep_cli(tmp_path):
    r = _cli("simulate", "--sweep", SWEEPS / "hg_medium_zip.toml", "--out-dir", tmp_path / "o",
             "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "3 points in" in r.stderr and "sweep" in r.stderr
    names = sorted(p.name for p in (tmp_path / "o").glob("point_*.csv"))
    assert names == ["point_00000.csv", "point_00001.csv", "point_00002.csv"]
    m = fitlab.read(tmp_path / "o" / "point_00001.csv")
    assert m.channel_names == ("R", "G", "B")  # point 1 has an RGB sigma_s
    for args, msg in [(["--sweep", GRID], "--out-dir"),
                      (["--sweep", GRID, "--out-dir", tmp_path, "--samples", "5"], "--samples"),
                      ([GRID.parent / "../scenes/hg_medium.toml", "--samples", "10", "--out-dir",
                        tmp_path], "go with --sweep"),
                      (["--sweep", GRID, "--out-dir", tmp_path, "--workers", "0"], "at least 1")]:
        r = _cli("simulate", *args)
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.slow
def test_killed_worker_every_point_exactly_once(tmp_path):
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "out"
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=40)
    client = distributed.Client(cluster)
    pids = client.run(os.getpid)
    box = {}

    def run():
        try:
            box["summary"] = run_sweep(GRID, out, scheduler=cluster.scheduler_address,
                                       points_per_chunk=1, progress=False)
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            box["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    deadline = time.time() + 300
    while time.time() < deadline and not list((out / "chunks").glob("*.json")):
        time.sleep(0.1)
    os.kill(sorted(pids.values())[0], signal.SIGKILL)  # a worker dies with points to do
    t.join(600)
    client.close()
    cluster.close()
    assert "error" not in box, box.get("error")
    assert box["summary"]["chunks"] == 6 and box["summary"]["done_now"] == 6
    markers = [json.loads(p.read_text()) for p in (out / "chunks").glob("*.json")]
    assert sorted(p["point"] for m in markers for p in m["points"]) == list(range(6))
    assert not list(out.glob("**/*.tmp*"))
    reference = tmp_path / "ref"
    run_sweep(GRID, reference, workers=1, points_per_chunk=6, progress=False)
    for i in range(6):
        name = f"point_{i:05d}.csv"
        assert (out / name).read_bytes() == (reference / name).read_bytes()


@pytest.mark.slow
def test_sweep_then_batched_fit_recovers_each_point(tmp_path):
    """The README's pipeline: a sweep of GGX widths with point estimates, then one batched
    ``fitlab fit`` of every point, gives back each point's alpha."""
    sweep = SWEEPS / "rough_glass_alpha.toml"
    r = _cli("simulate", "--sweep", sweep, "--out-dir", tmp_path / "s", "--quiet")
    assert r.returncode == 0, r.stderr
    files = sorted((tmp_path / "s").glob("point_*.csv"))
    r = _cli("fit", *files, "--model", "rough_dielectric", "--fix", "eta=1.5", "--out-dir",
             tmp_path / "f", "--quiet")
    assert r.returncode == 0, r.stderr
    for i, alpha in enumerate(load_sweep(sweep).points):
        got = fitlab.load_fit(tmp_path / "f" / f"point_{i:05d}.json").parameters["Y"]["alpha"]
        assert got == pytest.approx(alpha[0], rel=1e-5)
