"""Parameter sweeps of a simulator scene: ``fitlab simulate --sweep SWEEP.toml --out-dir DIR``
(data_formats/sweep_toml.md). A sweep names a base scene (data_formats/scene_toml.md) and a grid
of values for some of its fields (``stack[0].alpha``, ``substrate.albedo``); every point of the
grid is one scene, simulated into one measurement CSV. This is how training sets for learned
lobes and parameter studies are made.

The points run in chunks on Dask.distributed workers (fitlab/chunked.py: an embedded
LocalCluster with ``workers`` processes, or a running scheduler), resumable and safe against a
worker that dies: ``DIR/point_NNNNN.csv`` per point, ``DIR/chunks/ID.json`` per chunk (the
commit marker), then ``DIR/index.csv`` (one row per point: its file, seed and values) and
``DIR/index.json``.

Every point's scene is validated before anything runs (a bad value names the sweep file, the
point and the field). Point ``i`` is simulated with seed :func:`point_seed` (``seed``, ``i``):
the same sweep gives the same bytes, whichever worker runs a point and however the points are
chunked.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import io
import itertools
import json
import math
import re
from pathlib import Path
from typing import NamedTuple

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.files import read_bytes
from fitlab.io.validate import is_finite_number, load_toml, quote

FORMAT = "fitlab-sweep"
MODES = ("product", "zip")
TOP_KEYS = ("format", "version", "name", "description", "scene", "samples", "seed",
            "batch_size", "mode", "points_per_chunk", "grid")
#: Most points one sweep may have (each is a simulation; split bigger studies into sweeps).
MAX_POINTS = 100_000
#: Most values one grid key may list.
MAX_VALUES = 10_000
#: Longest grid key (a scene field path).
MAX_KEY = 128
POINTS_PER_CHUNK = 8
#: Most keys a grid may have (a scene has a few dozen fields).
MAX_KEYS = 32
#: Characters of a grid key or string value a message shows; string values are at most this long.
_SHOWN = 64
#: A field path: names with optional [index] parts, joined by dots (``stack[1].sigma_s``).
_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d{1,4}\])*)$")


class Sweep(NamedTuple):
    """A validated sweep; ``points[i]`` holds point i's values in ``keys`` order."""

    source: str
    name: str
    scene_path: Path
    base: dict  # the base scene's TOML as a dict
    keys: tuple
    points: tuple
    samples: int
    seed: int
    batch_size: int
    points_per_chunk: int

    def scene_dict(self, i: int) -> dict:
        """Point ``i``'s scene as a dict (the base scene with the point's values set)."""
        d = copy.deepcopy(self.base)
        for key, value in zip(self.keys, self.points[i]):
            set_field(d, parse_field(key), value)
        return d

    def scene(self, i: int):
        """Point ``i``'s validated :class:`fitlab.simulate.scene.Scene`."""
        from fitlab.simulate.scene import scene_from_dict

        return scene_from_dict(self.scene_dict(i), source=str(self.scene_path),
                               base_dir=self.scene_path.parent)

    def values(self, i: int) -> dict:
        return dict(zip(self.keys, self.points[i]))

    def file_name(self, i: int) -> str:
        width = max(5, len(str(len(self.points) - 1)))
        return f"point_{i:0{width}d}.csv"


def parse_field(key: str) -> list:
    """``"stack[1].sigma_s"`` → ``["stack", 1, "sigma_s"]``; ValueError when malformed."""
    out = []
    for part in key.split("."):
        m = _SEGMENT.match(part)
        if not m:
            raise ValueError(f"{quote(part)} is not a field name (letters, digits, _) with optional "
                             "[index]")
        out.append(m.group(1))
        out += [int(x) for x in re.findall(r"\[(\d+)\]", m.group(2))]
    return out


def set_field(d: dict, path: list, value) -> None:
    """Set ``value`` at ``path`` in ``d``: every table or list on the way must exist in the base
    scene (the last name may be new: a default the base scene leaves out). KeyError otherwise."""
    node = d
    for k, seg in enumerate(path[:-1]):
        nxt = path[k + 1]
        if isinstance(seg, int):
            if not isinstance(node, list) or seg >= len(node):
                raise KeyError(f"item [{seg}] does not exist in the base scene")
            node = node[seg]
        else:
            if not isinstance(node, dict) or seg not in node:
                raise KeyError(f"[{seg}] does not exist in the base scene")
            node = node[seg]
        if isinstance(nxt, int) and not isinstance(node, list):
            raise KeyError(f"{seg} is not a list in the base scene")
    last = path[-1]
    if isinstance(last, int):
        if not isinstance(node, list) or last >= len(node):
            raise KeyError(f"item [{last}] does not exist in the base scene")
        node[last] = value
    else:
        if not isinstance(node, dict):
            raise KeyError("the field above it is not a table in the base scene")
        node[last] = value


def point_seed(seed: int, i: int) -> int:
    """The seed of point ``i`` of a sweep with ``seed``: SHA-256 of both, 31 bits (streams of
    different points and of different sweep seeds do not overlap in any simple way)."""
    return int.from_bytes(hashlib.sha256(f"{seed}/{i}".encode()).digest()[:4], "little") >> 1


def _grid_key(key: str, j: int | None = None) -> str:
    """How a message names grid key ``key`` (and its value ``j``): ``grid."stack[0].alpha"[2]``,
    a long key cut short (a message never echoes much of a file)."""
    shown = key if len(key) <= _SHOWN else f"{key[:_SHOWN]}... ({len(key)} characters)"
    return f"grid.\"{shown}\"" + ("" if j is None else f"[{j}]")


def _fail(path, field, message, hint=None):
    raise InputFileError(path, f"{field}: {message}" if field else message, hint=hint)


def _int(path, d, key, default, lo, hi):
    if key not in d:
        if default is None:
            _fail(path, key, "is missing", f"give {key} = a whole number from {lo} to {hi}")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        _fail(path, key, f"{quote(v)} is not a whole number from {lo} to {hi}",
              f"write {key} = a whole number from {lo} to {hi}")
    return v


def _grid_value(path, key, j, v):
    """A grid value: a finite number, a string, a bool, or a list of finite numbers."""
    where = _grid_key(key, j)
    if isinstance(v, bool) or (isinstance(v, str) and len(v) <= _SHOWN):
        return v
    if isinstance(v, (int, float)):
        if not is_finite_number(v):
            _fail(path, where, f"{quote(v)} is not a finite number")
        return v
    if isinstance(v, list) and v and len(v) <= 16 and all(is_finite_number(x) for x in v):
        return v
    _fail(path, where, f"{quote(v)} is not a number, a string, true/false or a short list of "
          "finite numbers", "give the values the scene field takes (data_formats/scene_toml.md)")


def sweep_from_dict(d: dict, source: str, base_dir) -> Sweep:
    """Validate a sweep given as a dict with the TOML file's structure; every point's scene is
    validated too. Raises :class:`fitlab.errors.InputFileError` naming ``source``."""
    import difflib

    from fitlab.simulate.scene import scene_from_dict

    path = source
    for key in d:
        if key not in TOP_KEYS:
            close = difflib.get_close_matches(key, TOP_KEYS, n=1)
            _fail(path, key, "unknown key",
                  f"did you mean {close[0]!r}?" if close else f"allowed keys: {', '.join(TOP_KEYS)}")
    if d.get("format", FORMAT) != FORMAT:
        _fail(path, "format", f"{quote(d['format'])} is not \"{FORMAT}\"", "remove it or fix it")
    if d.get("version", 1) != 1:
        _fail(path, "version", f"{quote(d['version'])} is not a version this fitlab reads (1)",
              "write version = 1")
    name = d.get("name", Path(str(source)).stem)
    if not isinstance(name, str):
        _fail(path, "name", "must be a string")
    scene_name = d.get("scene")
    if not isinstance(scene_name, str) or not scene_name:
        _fail(path, "scene", "is missing", "give the base scene TOML file, relative to the sweep "
              "file's folder")
    scene_path = Path(base_dir) / scene_name
    if not scene_path.is_file():
        _fail(path, "scene", f"{quote(scene_name)} does not exist (looked for {scene_path})",
              "give a path relative to the sweep file's folder")
    from fitlab.simulate.simulator import BATCH_SIZE

    samples = _int(path, d, "samples", None, 2, 10**9)
    seed = _int(path, d, "seed", 0, 0, 2**31 - 1)
    batch = _int(path, d, "batch_size", BATCH_SIZE, 1, 1 << 20)
    per_chunk = _int(path, d, "points_per_chunk", POINTS_PER_CHUNK, 1, MAX_POINTS)
    mode = d.get("mode", "product")
    if mode not in MODES:
        _fail(path, "mode", f"{quote(mode)} is not one of {', '.join(MODES)}",
              "product: every combination of the grid's values; zip: the i-th value of every "
              "key together (equal lengths)")
    grid = d.get("grid")
    if not isinstance(grid, dict) or not grid:
        _fail(path, "grid", "is missing or empty", "give a [grid] table: \"FIELD\" = [values], "
              "e.g. \"stack[0].alpha\" = [0.1, 0.2]")
    if len(grid) > MAX_KEYS:
        _fail(path, "grid", f"has {len(grid)} keys, more than {MAX_KEYS}",
              "sweep a few scene fields at a time")
    keys, columns = [], []
    for key, vals in grid.items():
        if len(key) > MAX_KEY:
            _fail(path, _grid_key(key), f"is a field path of {len(key)} characters, more than "
                  f"{MAX_KEY}", "write a scene field path such as \"stack[0].alpha\"")
        try:
            parse_field(key)
        except ValueError as exc:
            _fail(path, _grid_key(key), str(exc), "write a field path such as "
                  "\"stack[0].alpha\" or \"substrate.albedo\"")
        if not isinstance(vals, list) or not vals or len(vals) > MAX_VALUES:
            _fail(path, _grid_key(key), f"must be a list of 1 to {MAX_VALUES} values",
                  "write \"FIELD\" = [value, value, ...]")
        keys.append(key)
        columns.append([_grid_value(path, key, j, v) for j, v in enumerate(vals)])
    if mode == "zip":
        lengths = {len(c) for c in columns}
        if len(lengths) != 1:
            _fail(path, "grid", f"mode = \"zip\" needs lists of one length, got "
                  f"{', '.join(f'{k}: {len(c)}' for k, c in zip(keys, columns))}",
                  "give every key as many values, or use mode = \"product\"")
        count = len(columns[0])
    else:
        count = math.prod(len(c) for c in columns)
    if count > MAX_POINTS:
        _fail(path, "grid", f"has {count} points, more than {MAX_POINTS}",
              "split the study into several sweeps")
    points = tuple(zip(*columns)) if mode == "zip" else tuple(itertools.product(*columns))
    raw = read_bytes(scene_path, folder_hint="give a scene TOML file")
    base = load_toml(scene_path, raw, what="scene",
                     hint="see data_formats/scene_toml.md for the scene's syntax and shape")
    for key, col in zip(keys, columns):
        try:
            set_field(copy.deepcopy(base), parse_field(key), col[0])
        except KeyError as exc:
            _fail(path, _grid_key(key), exc.args[0], "sweep only fields whose tables and "
                  f"list items exist in the base scene {scene_name}")
    sweep = Sweep(str(source), name, scene_path, base, tuple(keys), points, samples, seed,
                  batch, per_chunk)
    for i in range(len(points)):
        shown = ", ".join(f"{k} = {quote(v, _SHOWN) if isinstance(v, str) else v}"
                          for k, v in sweep.values(i).items())
        where = f"{source}: point {i} ({shown})"
        try:
            scene_from_dict(sweep.scene_dict(i), source=where, base_dir=scene_path.parent)
        except InputFileError as exc:
            raise InputFileError(where, str(exc).split(f"{where}: ", 1)[-1]) from None
    return sweep


def load_sweep(path) -> Sweep:
    """Read and validate a sweep TOML file (data_formats/sweep_toml.md) and its base scene."""
    path = Path(path)
    raw = read_bytes(path, folder_hint="give a sweep TOML file")
    d = load_toml(path, raw, what="sweep",
                  hint="see data_formats/sweep_toml.md for the sweep's syntax")
    return sweep_from_dict(d, str(path), path.parent)


def _chunk_id(sweep: Sweep, indices: list) -> str:
    """A chunk's identity: its points' scenes (and the file a measurement detector names),
    seeds, samples and batch size."""
    from fitlab.chunked import digest
    from fitlab.io.files import sha256_of

    parts = []
    for i in indices:
        scene = sweep.scene(i)
        ref = scene.detector.file
        parts.append([i, sweep.scene_dict(i), point_seed(sweep.seed, i),
                      sha256_of(ref) if ref else None])
    # the walk that made the numbers, not the batch size (which changes no number): a sweep
    # resumed after an upgrade of the walk simulates its points again
    return digest("fitlab-sweep", sweep.samples, WALK_ENGINE, parts)


#: The walk's identity in chunk ids (the JAX walk's chunks, made before it, are run again).
WALK_ENGINE = "drjit-walk-1"


def _simulate_chunk(sweep: Sweep, indices: list, records: dict, out_dir: str,
                    cid: str) -> str:
    """The task: simulate the chunk's points, write each CSV atomically, then the marker.
    ``records``: how the outputs name the sweep and the scene (relative to ``out_dir``, made by
    the driver: a worker's working folder may be another)."""
    from fitlab.chunked import marker_path, write_marker
    from fitlab.io.atomic import atomic_write_text
    from fitlab.simulate.simulator import simulate

    out = Path(out_dir)
    if marker_path(out, cid).exists():
        return cid
    files = []
    for i in indices:
        target = out / sweep.file_name(i)
        res = simulate(sweep.scene(i), sweep.samples, point_seed(sweep.seed, i),
                       batch_size=sweep.batch_size)
        extra = {"sweep": records["sweep"], "sweep_point": str(i),
                 "sweep_values": json.dumps(sweep.values(i), separators=(",", ":"))}
        atomic_write_text(target, res.csv_text(records["scene"], extra=extra))
        files.append({"point": i, "file": target.name, "truncated": res.truncated})
    write_marker(out, cid, {"points": files})
    return cid


def _cell(v) -> str:
    return json.dumps(v, separators=(",", ":")) if isinstance(v, (list, bool)) else str(v)


def index_csv(sweep: Sweep) -> str:
    """``DIR/index.csv``: one row per point: point, file, seed, then each swept field."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    buf.write(f"# fitlab sweep index: {sweep.name}; {len(sweep.points)} points, "
              f"{sweep.samples} samples per incidence\n")
    w.writerow(["point", "file", "seed", *sweep.keys])
    for i, vals in enumerate(sweep.points):
        w.writerow([i, sweep.file_name(i), point_seed(sweep.seed, i), *map(_cell, vals)])
    return buf.getvalue()


def run_sweep(sweep: Sweep | str | Path, out_dir, *, workers: int = 2,
              scheduler: str | None = None, points_per_chunk: int | None = None,
              progress: bool = True, retries: int = 3) -> dict:
    """Simulate every point of ``sweep`` (a :class:`Sweep` or a sweep TOML path) on a Dask
    cluster into ``out_dir`` (module text). Returns ``{"points", "chunks", "done_before",
    "done_now", "index", "truncated"}`` (``truncated``: paths dropped at the event cap, summed
    over the points)."""
    from fitlab.chunked import run_chunks
    from fitlab.io.atomic import atomic_write_text

    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep)
    per = points_per_chunk or sweep.points_per_chunk
    if per < 1:
        raise FitlabError("--points-per-chunk must be at least 1")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FitlabError(f"--out-dir {out_dir}: is a file; give a folder")
    from fitlab.io.files import path_for_record

    n = len(sweep.points)
    records = {"sweep": path_for_record(sweep.source, out / "index.json"),
               "scene": path_for_record(sweep.scene_path, out / "index.json")}
    # workers resolve the scene's own files (a measurement detector's) from its absolute folder
    shipped = sweep._replace(scene_path=sweep.scene_path.resolve())
    chunks = []
    for a in range(0, n, per):
        idx = list(range(a, min(a + per, n)))
        chunks.append((_chunk_id(sweep, idx), (shipped, idx, records)))
    run = run_chunks(_simulate_chunk, chunks, out, workers=workers, scheduler=scheduler,
                     progress=progress, retries=retries, desc="sweep")
    atomic_write_text(out / "index.csv", index_csv(sweep))
    index = {"format": "fitlab-sweep-index", "name": sweep.name, **records,
             "samples": sweep.samples, "seed": sweep.seed, "keys": list(sweep.keys),
             "chunks": [{"chunk": r["chunk"], "points": [p["point"] for p in r["points"]]}
                        for r in run["records"]]}
    atomic_write_text(out / "index.json", json.dumps(index, indent=1) + "\n")
    truncated = sum(p["truncated"] for r in run["records"] for p in r["points"])
    return {"points": n, "chunks": run["chunks"], "done_before": run["done_before"],
            "done_now": run["done_now"], "index": str(out / "index.csv"), "truncated": truncated}


__all__ = ["MAX_POINTS", "Sweep", "index_csv", "load_sweep", "parse_field", "point_seed",
           "run_sweep", "set_field", "sweep_from_dict"]
