"""Resumable chunked work on Dask.distributed: the engine under ``fitlab fit FILE... --workers``
(fitlab/fitting/distributed.py) and ``fitlab simulate --sweep`` (fitlab/simulate/sweep.py).

* The work is a list of chunks, each ``(chunk id, arguments)``. A chunk's id is a hash of
  everything its result depends on (its inputs' contents and the settings), so a rerun with the
  same inputs finds the chunks already done and skips them (resumable), and a changed input is
  done again.
* A task does its chunk in a worker process, writes its outputs atomically, then the chunk's
  record ``OUT/chunks/ID.json`` atomically, last: the record is the commit marker. A task whose
  worker dies before its marker is run again (Dask reschedules it, ``retries``); the second run
  writes the same bytes, so every result is there exactly once and nothing is partial.
* The driver waits for every chunk, showing progress (tqdm: chunks done, rate, time left), and
  reads the records back in chunk order.

An embedded ``LocalCluster`` of ``workers`` processes (one thread each) runs by default; with
``scheduler`` the tasks go to a running Dask scheduler, whose workers must have fitlab
installed and see ``OUT`` at the same path (a shared file system). One worker and no scheduler
runs the chunks in the calling process, one after another, with the same markers, outputs and
progress: a cluster of one worker process would only add its start (a few seconds of importing
fitlab in a new process) and nothing in parallel.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

from fitlab.errors import FitlabError


def digest(*parts) -> str:
    """A chunk id: SHA-256 over ``parts`` (str, bytes, or JSON-able values), 20 hex digits."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, str):
            p = p.encode()
        elif not isinstance(p, bytes):
            p = json.dumps(p, sort_keys=True).encode()
        h.update(len(p).to_bytes(8, "little") + p)
    return h.hexdigest()[:20]


def marker_path(out_dir, cid: str) -> Path:
    """Where chunk ``cid``'s record (its commit marker) lives."""
    return Path(out_dir) / "chunks" / f"{cid}.json"


def write_marker(out_dir, cid: str, record: dict) -> None:
    """Commit a chunk: its record, atomically, after every output of the chunk is written."""
    from fitlab.io.atomic import atomic_write_text

    atomic_write_text(marker_path(out_dir, cid),
                      json.dumps({"chunk": cid, **record}, indent=1) + "\n")


def read_marker(out_dir, cid: str) -> dict:
    return json.loads(marker_path(out_dir, cid).read_text(encoding="utf-8"))


def client_for(workers: int, scheduler: str | None):
    """A Dask client: of an embedded LocalCluster of ``workers`` processes, or of the running
    scheduler at ``scheduler``. Returns ``(client, cluster or None)``."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise FitlabError("--workers and --scheduler need Dask.distributed: pip install "
                          "'fitlab[distributed]'") from None
    if scheduler is None:
        if workers < 1:
            raise FitlabError("--workers must be at least 1")
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=40)
        return Client(cluster), cluster
    try:
        return Client(scheduler, timeout="30s"), None
    except (OSError, TimeoutError) as exc:
        raise FitlabError(f"--scheduler {scheduler}: no Dask scheduler answers ({exc}); start "
                          "one with `dask scheduler` and its workers with `dask worker "
                          "ADDRESS`") from None


def run_chunks(task, chunks, out_dir, *, workers: int = 2, scheduler: str | None = None,
               progress: bool = True, retries: int = 3, desc: str = "chunks") -> dict:
    """Run ``task(*args, out_dir, cid)`` for every chunk ``(cid, args)`` whose marker is missing,
    on a Dask cluster; the task must write its outputs and then :func:`write_marker`. Returns
    ``{"chunks": n, "done_before": skipped, "done_now": run now, "records": [record per chunk
    in order]}``. A task's own error (a bad input) stops the run with its message."""
    out = Path(out_dir)
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    ids = [cid for cid, _ in chunks]
    if len(set(ids)) != len(ids):
        raise FitlabError("two chunks of this run have the same inputs; remove the duplicates")
    todo = [(cid, args) for cid, args in chunks if not marker_path(out, cid).exists()]
    if todo:
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(chunks), initial=len(chunks) - len(todo), desc=desc,
                       unit="chunk", file=sys.stderr, dynamic_ncols=True)
        done = (lambda: None) if bar is None else (lambda: bar.update(1))
        try:
            if scheduler is None and workers == 1:
                _run_here(task, todo, out, done)
            else:
                _run_on_dask(task, todo, out, done, workers, scheduler, retries, desc)
        finally:
            if bar is not None:
                bar.close()
    remove_orphan_temporaries(out)
    remove_orphan_temporaries(out / "chunks")
    return {"chunks": len(chunks), "done_before": len(chunks) - len(todo),
            "done_now": len(todo), "records": [read_marker(out, cid) for cid in ids]}


def _run_here(task, todo, out: Path, done) -> None:
    """The chunks ``todo`` in this process, in order (one worker, no scheduler)."""
    root = str(out.resolve())
    for cid, args in todo:
        task(*args, root, cid)
        done()


def _run_on_dask(task, todo, out: Path, done, workers, scheduler, retries, desc) -> None:
    """The chunks ``todo`` on a Dask cluster (embedded, or the running ``scheduler``)."""
    from distributed import as_completed

    client, cluster = client_for(workers, scheduler)
    try:
        root = str(out.resolve())
        futures = [client.submit(task, *args, root, cid, key=f"fitlab-{desc}-{cid}",
                                 retries=retries, pure=False) for cid, args in todo]
        for fut in as_completed(futures):
            fut.result()
            done()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def remove_orphan_temporaries(folder: Path) -> None:
    """Remove the atomic writer's temporary files (``.NAME.RANDOM.tmp``,
    fitlab.io.atomic.temporary_beside) whose file NAME exists in ``folder``: left by a worker
    killed while writing, whose chunk ran again elsewhere and wrote NAME whole."""
    for tmp in Path(folder).glob(".*.tmp"):
        name = tmp.name[1:].rsplit(".", 2)[0]
        if name and (tmp.parent / name).exists():
            tmp.unlink(missing_ok=True)


__all__ = ["client_for", "digest", "marker_path", "read_marker", "remove_orphan_temporaries",
           "run_chunks", "write_marker"]
