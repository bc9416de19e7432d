"""fitlab.chunked with one worker and no scheduler: the chunks run in the calling process (no
cluster to start), with the same markers, resumability and errors as on a cluster."""

from __future__ import annotations

import os

import pytest

from fitlab.chunked import marker_path, run_chunks, write_marker


def _square(x, root, cid):
    from pathlib import Path

    (Path(root) / f"{cid}.txt").write_text(str(x * x))
    write_marker(root, cid, {"pid": os.getpid(), "x": x})


def _refuse(x, root, cid):
    raise ValueError(f"chunk {cid}: bad input {x}")


def test_one_worker_runs_the_chunks_here_in_order_and_resumes(tmp_path, capsys):
    chunks = [(f"c{i}", (i,)) for i in range(4)]
    run = run_chunks(_square, chunks, tmp_path, workers=1, desc="squares")
    assert run["done_now"] == 4 and run["done_before"] == 0
    assert [r["x"] for r in run["records"]] == [0, 1, 2, 3]
    assert {r["pid"] for r in run["records"]} == {os.getpid()}  # no worker process
    assert (tmp_path / "c3.txt").read_text() == "9"
    assert "squares" in capsys.readouterr().err  # the progress bar, on stderr
    marker_path(tmp_path, "c1").unlink()
    again = run_chunks(_square, chunks, tmp_path, workers=1, progress=False)
    assert again["done_before"] == 3 and again["done_now"] == 1


def test_one_worker_stops_at_a_tasks_own_error(tmp_path):
    with pytest.raises(ValueError, match="chunk c0: bad input 5"):
        run_chunks(_refuse, [("c0", (5,))], tmp_path, workers=1, progress=False)
    assert not marker_path(tmp_path, "c0").exists()
