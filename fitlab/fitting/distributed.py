"""Batched fits past one process: the files of ``fitlab fit FILE ... --workers N`` (or
``--scheduler ADDRESS``) split into chunks that Dask.distributed workers fit with
``fitlab.fit_many``, resumable and safe against a worker that dies.

* The work: ``files_per_chunk`` files per task, in the order given. A chunk's identity is a
  hash of its files' contents (SHA-256) and of the fit's settings, so a rerun with the same
  inputs finds the chunks already done and skips them (resumable), and a changed file or
  setting is fitted again.
* A task fits its chunk in the worker's process, writes each file's parameter file
  (``OUT/NAME.json``) atomically, then the chunk's record (``OUT/chunks/ID.json``: its files,
  its table rows) atomically, last: the chunk file is the commit marker. A task whose worker
  dies before that marker is run again (Dask reschedules it; ``retries``); a second run
  writes the same bytes, so every result is there exactly once and nothing is partial.
* The driver waits for every chunk, showing progress, then writes ``OUT/table.csv`` (every
  fit, data_formats/fit_table_csv.md) and ``OUT/index.json`` (the chunks and their files)
  atomically.

An embedded ``LocalCluster`` of ``workers`` processes (one thread each) runs by default; with
``scheduler`` the tasks go to a running Dask scheduler, whose workers must have fitlab
installed and see ``OUT`` at the same path (a shared file system).
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

from fitlab.errors import FitlabError

#: Files per task (each task is one fitlab.fit_many call in a worker).
FILES_PER_CHUNK = 64


def chunk_id(files: list[str], settings: dict) -> str:
    """A chunk's identity: its files' contents and the fit's settings."""
    from fitlab.io.files import sha256_of

    h = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    for f in files:
        h.update(Path(f).name.encode() + b"\0" + sha256_of(f).encode())
    return h.hexdigest()[:20]


def _fit_chunk(files: list[str], first_index: int, out_dir: str, cid: str,
               settings: dict) -> str:
    """The task: fit ``files`` (fitlab.fit_many), write their parameter files, then the chunk's
    marker. Runs in a worker process."""
    from fitlab.export.paramfile import write_fit
    from fitlab.fitting.many import fit_many
    from fitlab.io.atomic import atomic_write_text

    out = Path(out_dir)
    marker = out / "chunks" / f"{cid}.json"
    if marker.exists():  # done by an earlier run (or an earlier attempt of this task)
        return cid
    kw = {k: v for k, v in settings.items() if k not in ("model",)}
    result = fit_many(files, settings["model"], **kw)
    written = []
    for i, record in result.records():
        path = out / f"{Path(files[i]).stem}.json"
        write_fit(path, record)
        written.append(path.name)
    rows = result.table(out / "table.csv").splitlines()[2:]
    rows = [str(first_index + int(r.split(",", 1)[0])) + "," + r.split(",", 1)[1] for r in rows]
    header = result.table().splitlines()[1]
    atomic_write_text(marker, json.dumps({"chunk": cid, "files": [Path(f).name for f in files],
                                          "parameter_files": written, "header": header,
                                          "rows": rows}, indent=1) + "\n")
    return cid


def fit_files(files, model: str, out_dir, *, workers: int = 2, scheduler: str | None = None,
              files_per_chunk: int = FILES_PER_CHUNK, progress: bool = True,
              retries: int = 3, **fit_kwargs) -> dict:
    """Fit every file with ``model`` on a Dask cluster (module text); returns a summary:
    ``chunks``, ``done_before`` (skipped: already fitted), ``fitted`` (this run), ``files``,
    ``table``, ``index``."""
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise FitlabError("--workers and --scheduler need Dask.distributed: pip install "
                          "'fitlab[distributed]'") from None
    from fitlab.io.atomic import atomic_write_text

    files = [str(f) for f in files]
    names = [Path(f).stem for f in files]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise FitlabError(f"several data files are named {', '.join(dup)}; rename them (each "
                          "gets OUT/NAME.json)")
    for f in files:
        if not Path(f).is_file():
            raise FitlabError(f"{f}: no such file. check the path")
    if files_per_chunk < 1 or (scheduler is None and workers < 1):
        raise FitlabError("--workers and --files-per-chunk must be at least 1")
    out = Path(out_dir)
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    settings = {"model": model, **{k: v for k, v in fit_kwargs.items()}}
    chunks = []
    for a in range(0, len(files), files_per_chunk):
        part = [str(Path(f).resolve()) for f in files[a:a + files_per_chunk]]
        chunks.append((part, a, chunk_id(part, settings)))
    todo = [c for c in chunks if not (out / "chunks" / f"{c[2]}.json").exists()]
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=40)
    client = Client(scheduler if scheduler is not None else cluster)
    bar = None
    try:
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(chunks), initial=len(chunks) - len(todo), desc="chunks",
                       unit="chunk", file=sys.stderr, dynamic_ncols=True)
        futures = [client.submit(_fit_chunk, part, a, str(out.resolve()), cid, settings,
                                 key=f"fitlab-chunk-{cid}", retries=retries, pure=False)
                   for part, a, cid in todo]
        for fut in as_completed(futures):
            fut.result()  # a task's own error (a bad file) stops the run with its message
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        client.close()
        if cluster is not None:
            cluster.close()
    records = [json.loads((out / "chunks" / f"{cid}.json").read_text()) for _, _, cid in chunks]
    header = records[0]["header"]
    table = [f"# fitlab fit table: model {model}; one row per dataset and channel", header]
    for rec in records:
        table += rec["rows"]
    atomic_write_text(out / "table.csv", "\n".join(table) + "\n")
    index = {"model": model, "settings": {k: v for k, v in settings.items()},
             "chunks": [{"chunk": r["chunk"], "files": r["files"],
                         "parameter_files": r["parameter_files"]} for r in records]}
    atomic_write_text(out / "index.json", json.dumps(index, indent=1) + "\n")
    return {"chunks": len(chunks), "done_before": len(chunks) - len(todo),
            "fitted": len(todo), "files": len(files), "table": str(out / "table.csv"),
            "index": str(out / "index.json")}


__all__ = ["FILES_PER_CHUNK", "chunk_id", "fit_files"]
