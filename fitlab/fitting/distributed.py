"""Batched fits past one process: the files of ``fitlab fit FILE ... --workers N`` (or
``--scheduler ADDRESS``) split into chunks that Dask.distributed workers fit with
``fitlab.fit_many`` (fitlab/chunked.py runs them: resumable, safe against a worker that dies).

* The work: ``files_per_chunk`` files per task, in the order given. A chunk's identity is a
  hash of its files' names and contents (SHA-256) and of the fit's settings, so a rerun with
  the same inputs skips the chunks already done, and a changed file or setting is fitted again.
* A task fits its chunk in the worker's process, writes each file's parameter file
  (``OUT/NAME.json``) atomically, then the chunk's record (``OUT/chunks/ID.json``: its files,
  its table rows), the commit marker.
* The driver waits for every chunk, showing progress, then writes ``OUT/table.csv`` (every
  fit, data_formats/fit_table_csv.md) and ``OUT/index.json`` (the chunks and their files)
  atomically.
"""

from __future__ import annotations

import json
from pathlib import Path

from fitlab.chunked import digest, marker_path, run_chunks, write_marker
from fitlab.errors import FitlabError

#: Files per task (each task is one fitlab.fit_many call in a worker).
FILES_PER_CHUNK = 64


def chunk_id(files: list[str], settings: dict) -> str:
    """A chunk's identity: its files' names and contents and the fit's settings."""
    from fitlab.io.files import sha256_of

    return digest(settings, *[Path(f).name + "\0" + sha256_of(f) for f in files])


def _fit_chunk(files: list[str], settings: dict, out_dir: str, cid: str) -> str:
    """The task: fit ``files`` (fitlab.fit_many), write their parameter files, then the chunk's
    marker. Runs in a worker process."""
    from fitlab.export.paramfile import write_fit
    from fitlab.fitting.many import fit_many, output_name

    out = Path(out_dir)
    if marker_path(out, cid).exists():  # done by an earlier run (or attempt of this task)
        return cid
    kw = {k: v for k, v in settings.items() if k not in ("model",)}
    result = fit_many(files, settings["model"], **kw)
    written = []
    for i, record in result.records():
        path = out / f"{output_name(result.measurements[i])}.json"
        write_fit(path, record)
        written.append(path.name)
    rows = result.table(out / "table.csv").splitlines()[2:]
    header = result.table().splitlines()[1]
    write_marker(out, cid, {"files": [Path(f).name for f in files], "parameter_files": written,
                            "datasets": len(result.measurements), "header": header,
                            "rows": rows})
    return cid


def fit_files(files, model, out_dir, *, workers: int = 2, scheduler: str | None = None,
              files_per_chunk: int = FILES_PER_CHUNK, progress: bool = True,
              retries: int = 3, angles: str | None = None, accept=(),
              quantity: str | None = None, **fit_kwargs) -> dict:
    """Fit every file with ``model`` on a Dask cluster (module text); returns a summary:
    ``chunks``, ``done_before`` (skipped: already fitted), ``fitted`` (this run), ``files``,
    ``table``, ``index``. ``model`` is a registry name or a whole FitRequest, ``fit_kwargs``
    fitlab.fit_many's settings: checked once, here, before any worker starts; the workers get
    the request's settings as plain values (:func:`plain_settings`, also hashed into each
    chunk's identity). ``angles``, ``accept``, ``quantity``: how the workers read the files
    (:func:`fitlab.read`; part of the settings, so a change refits)."""
    from fitlab.io.gates import read_options

    from fitlab.fitting.many import MANY_DEFAULTS, check_batch
    from fitlab.fitting.request import FitRequest, as_request
    from fitlab.io.atomic import atomic_write_text

    request = check_batch(as_request(model, fit_kwargs if isinstance(model, FitRequest)
                                     else {**MANY_DEFAULTS, **fit_kwargs}))
    model = request.model.name
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
    settings = {"model": model, **plain_settings(request),
                **read_options(angles, accept, quantity).record()}
    chunks = []
    for a in range(0, len(files), files_per_chunk):
        part = [str(Path(f).resolve()) for f in files[a:a + files_per_chunk]]
        chunks.append((chunk_id(part, settings), (part, settings)))
    run = run_chunks(_fit_chunk, chunks, out, workers=workers, scheduler=scheduler,
                     progress=progress, retries=retries, desc="chunks")
    records = run["records"]
    header = records[0]["header"]
    table = [f"# fitlab fit table: model {model}; one row per dataset and channel", header]
    first = 0  # a chunk's rows number its datasets from 0: renumber them across the chunks
    for rec in records:
        table += [str(first + int(r.split(",", 1)[0])) + "," + r.split(",", 1)[1]
                  for r in rec["rows"]]
        first += rec["datasets"]
    atomic_write_text(out / "table.csv", "\n".join(table) + "\n")
    index = {"model": model, "settings": {k: v for k, v in settings.items()},
             "chunks": [{"chunk": r["chunk"], "files": r["files"],
                         "parameter_files": r["parameter_files"]} for r in records]}
    atomic_write_text(out / "index.json", json.dumps(index, indent=1) + "\n")
    return {"chunks": run["chunks"], "done_before": run["done_before"],
            "fitted": run["done_now"], "files": len(files), "table": str(out / "table.csv"),
            "index": str(out / "index.json")}


def plain_settings(request) -> dict:
    """What the workers' fit_many needs of ``request``, as plain values (JSON and hashing): a
    registered model's name and settings; a row mask is refused (give an expression)."""
    if request.subset is not None and not isinstance(request.subset, str):
        raise FitlabError("the Dask runner takes the subset as an expression (e.g. 'theta_i == "
                          "0'), not a row mask: the files' rows are known only to the workers")
    return {"fix": dict(request.fix), "free": list(request.free),
            "options": dict(request.options), "loss": request.loss, "subset": request.subset,
            "starts": request.starts, "seed": request.seed, "lm_maxiter": request.lm_maxiter,
            "mcmc": request.mcmc, "mcmc_steps": request.mcmc_steps, "walkers": request.walkers}


__all__ = ["FILES_PER_CHUNK", "chunk_id", "fit_files", "plain_settings"]
