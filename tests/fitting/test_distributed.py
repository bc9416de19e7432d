"""Batched fits on Dask.distributed (fitlab/fitting/distributed.py): a run with a worker killed
in the middle completes with every result exactly once and nothing partial; a rerun skips what
is done (resumable). A two-process LocalCluster, as the issue asks."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

import fitlab

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"


@pytest.mark.slow
def test_killed_worker_every_result_exactly_once_and_resumable(tmp_path):
    from distributed import Client, LocalCluster

    from fitlab.fitting.distributed import fit_files

    files = []
    for k in range(6):
        f = tmp_path / f"d{k}.csv"
        f.write_bytes(WALTER.read_bytes())
        files.append(f)
    out = tmp_path / "out"
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=40)
    client = Client(cluster)
    pids = client.run(os.getpid)  # {worker address: pid}
    box = {}

    def run():
        try:
            box["summary"] = fit_files(files, "rough_dielectric", out,
                                       scheduler=cluster.scheduler_address, files_per_chunk=1,
                                       progress=False, subset="theta_i == 0")
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            box["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    deadline = time.time() + 300
    while time.time() < deadline and not list((out / "chunks").glob("*.json")):
        time.sleep(0.2)
    killed = sorted(pids.values())[0]
    os.kill(killed, signal.SIGKILL)  # a worker dies with chunks still to do
    t.join(600)
    client.close()
    cluster.close()
    assert "error" not in box, box.get("error")
    s = box["summary"]
    assert s["chunks"] == 6 and s["fitted"] == 6
    markers = sorted((out / "chunks").glob("*.json"))
    assert len(markers) == 6 and not list(out.glob("**/*.tmp*"))
    done = [json.loads(m.read_text()) for m in markers]
    assert sorted(f for d in done for f in d["files"]) == sorted(f.name for f in files)
    rows = (out / "table.csv").read_text().splitlines()[2:]
    assert sorted(int(r.split(",")[0]) for r in rows) == list(range(6))
    alphas = set()
    for f in files:
        r = fitlab.load_fit(out / f"{f.stem}.json")
        alphas.add(round(r.parameters["Y"]["alpha"], 9))
    assert alphas == {0.397171076}  # the same data: the same fit in every worker
    index = json.loads((out / "index.json").read_text())
    assert len(index["chunks"]) == 6

    # resumable: a rerun (local cluster of its own) finds every chunk done
    again = fit_files(files, "rough_dielectric", out, workers=1, files_per_chunk=1,
                      progress=False, subset="theta_i == 0")
    assert again["done_before"] == 6 and again["fitted"] == 0
    # a changed file is fitted again, the others not
    files[2].write_text(WALTER.read_text().replace("# quantity", "# note: changed\n# quantity",
                                                   1))
    third = fit_files(files, "rough_dielectric", out, workers=1, files_per_chunk=1,
                      progress=False, subset="theta_i == 0")
    assert third["fitted"] == 1 and third["done_before"] == 5
