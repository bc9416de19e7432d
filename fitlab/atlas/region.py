"""The validation atlas's verdicts: where on its grid a layered model is within
:data:`THRESHOLD` of the simulator, that region in words, the record (the package data
``fitlab/models/data/layered_atlas.json``, data_formats/layered_atlas.md) and the look-up
:func:`within_region` that ``fitlab models`` and the fit report use. No JAX, no simulator:
this module reads numbers.

A grid point is **within 5%** when, over the incidences θi ≤ REGION_MAX_THETA_DEG, the largest
|albedo error| and the largest relative RMS error of f·cos over the hemisphere (with the
simulation's noise taken out: :mod:`fitlab.atlas.compute`) are both at most THRESHOLD. It is
**noise-limited** where the simulation's noise in that measure at some of those incidences is above :data:`NOISE_LIMIT` (half
the threshold) or the albedo error's standard error above :data:`ALBEDO_SE_LIMIT`: there the
verdict is the noise-corrected one, but a rerun with more paths may move it. Between grid
values the boundary is known to one grid step.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from fitlab.atlas.grids import REGION_MAX_THETA_DEG

SCHEMA = "fitlab-layered-atlas"
VERSION = 1
#: The package data: the atlas shipped with fitlab.
DATA_PATH = Path(__file__).resolve().parents[1] / "models" / "data" / "layered_atlas.json"
#: The atlas's page, relative to fitlab's source tree (what links name).
PAGE = "reports/layered_atlas/README.md"
THRESHOLD = 0.05
NOISE_LIMIT = 0.5 * THRESHOLD
ALBEDO_SE_LIMIT = 0.01
#: A parameter off the grid's axes is on the atlas's slice when it is within this fraction of
#: max(|its value there|, 1) of it.
SLICE_TOLERANCE = 0.1


# --------------------------------------------------------------------------------------------
# Verdicts on the grid
# --------------------------------------------------------------------------------------------


def _counted(entry) -> np.ndarray:
    return np.asarray(entry["theta_i"], float) <= REGION_MAX_THETA_DEG + 1e-9


def _nanmax(a: np.ndarray) -> np.ndarray:
    """The maximum over the last axis, NaN only where every value is NaN."""
    filled = np.where(np.isnan(a), -np.inf, a)
    out = filled.max(axis=-1)
    return np.where(np.isneginf(out), np.nan, out)


def worst(entry) -> tuple[np.ndarray, np.ndarray]:
    """(n0, n1) grids of the largest |albedo error| and the largest RMS error of f·cos (noise
    taken out) over the counted incidences."""
    k = _counted(entry)
    a = np.abs(np.asarray(entry["albedo_error"], float))[..., k]
    r = np.asarray(entry["rms_error"], float)[..., k]
    return _nanmax(a), _nanmax(r)


def verdicts(entry) -> tuple[np.ndarray, np.ndarray]:
    """(within, noise_limited): boolean (n0, n1) grids (a point with no measure is not
    within)."""
    a, r = worst(entry)
    k = _counted(entry)
    within = (a <= THRESHOLD) & (r <= THRESHOLD)
    noise = _nanmax(np.asarray(entry["rms_noise"], float)[..., k])
    se = _nanmax(np.asarray(entry["albedo_error_se"], float)[..., k])
    limited = ~(noise <= NOISE_LIMIT) | ~(se <= ALBEDO_SE_LIMIT)
    return within, limited


# --------------------------------------------------------------------------------------------
# The region in words
# --------------------------------------------------------------------------------------------


def number_text(x: float) -> str:
    """A grid value as the region's words write it: 4 significant digits, no exponent between
    1e-4 and 1e7 (κ = 10000, not 1e+04)."""
    s = f"{x:.4g}"
    if "e" in s and 1e-4 <= abs(x) < 1e7:
        s = f"{float(s):.10f}".rstrip("0").rstrip(".")
    return s


_g = number_text


def runs(mask) -> list[tuple[int, int]]:
    """The runs (first, last index) of True in a 1-D boolean sequence."""
    out, start = [], None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((start, i - 1))
            start = None
    return out


def run_text(axis: dict, i: int, j: int) -> str | None:
    """A run [i, j] of an axis's values in words (None: the whole axis)."""
    v, name, n = axis["values"], axis["name"], len(axis["values"])
    if i == 0 and j == n - 1:
        return None
    if i == j:
        return f"{name} = {_g(v[i])}"
    if i == 0:
        return f"{name} ≤ {_g(v[j])}"
    if j == n - 1:
        return f"{name} ≥ {_g(v[i])}"
    return f"{_g(v[i])} ≤ {name} ≤ {_g(v[j])}"


def span_text(axis: dict) -> str:
    v = axis["values"]
    return f"{axis['name']} {_g(v[0])}–{_g(v[-1])}"


def _rows_text(axes, within, along: int) -> str:
    """The region as one clause per run of equal rows: for the values of axis ``along``,
    where on the other axis the points are within."""
    other = 1 - along
    grid = within if along == 0 else within.T
    lines, k = [], 0
    n = grid.shape[0]
    while k < n:
        m = k
        while m + 1 < n and (grid[m + 1] == grid[k]).all():
            m += 1
        v = axes[along]["values"]
        where = (f"{axes[along]['name']} = {_g(v[k])}" if m == k else
                 f"{axes[along]['name']} {_g(v[k])}–{_g(v[m])}")
        parts = [run_text(axes[other], i, j) for i, j in runs(grid[k])]
        what = ("nowhere" if not parts else
                f"every {axes[other]['name']}" if parts == [None] else " or ".join(
                    p for p in parts if p))
        lines.append(f"{where}: {what}")
        k = m + 1
    return "; ".join(lines)


def describe(axes: list, within) -> str:
    """The region of the boolean grid ``within`` (n0, n1) in words: everywhere, nowhere, a
    box (one interval per axis), or, per run of rows with the same pattern, where along the
    other axis (whichever reading is shorter). Statements hold at the grid's values."""
    within = np.asarray(within, bool)
    spans = f"{span_text(axes[0])}, {span_text(axes[1])}"
    if not within.any():
        return f"nowhere on the grid ({spans})"
    if within.all():
        return f"everywhere on the grid ({spans})"
    r, c = runs(within.any(axis=1)), runs(within.any(axis=0))
    if len(r) == 1 and len(c) == 1 and within[r[0][0]:r[0][1] + 1, c[0][0]:c[0][1] + 1].all():
        parts = [run_text(axes[0], *r[0]), run_text(axes[1], *c[0])]
        return " and ".join(p for p in parts if p)
    return min((_rows_text(axes, within, k) for k in (1, 0)), key=len)


def anchor(title: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation but '-' and '_'
    dropped, spaces as '-'."""
    return re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")


def finish(entry: dict, provenance: dict) -> dict:
    """``entry`` (:func:`fitlab.atlas.compute.compute_entry`'s numbers) with its verdicts,
    region, anchor and provenance."""
    entry = _rounded(entry)  # the verdicts of the numbers as the record keeps them
    a, r = worst(entry)
    within, limited = verdicts(entry)
    return {**entry, "anchor": anchor(entry["model"]), "provenance": provenance,
            "max_albedo_error": a.tolist(), "max_rms_error": r.tolist(),
            "within": within.tolist(), "noise_limited": limited.tolist(),
            "region": describe(entry["axes"], within)}


# --------------------------------------------------------------------------------------------
# The record
# --------------------------------------------------------------------------------------------


def _rounded(x, digits: int = 4):
    """Floats to ``digits`` significant digits (NaN as None), recursively; the record's bytes
    do not carry the last bits of a sum's rounding."""
    if isinstance(x, float):
        return None if not math.isfinite(x) else float(f"{x:.{digits}g}")
    if isinstance(x, dict):
        return {k: _rounded(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_rounded(v, digits) for v in x]
    return x


def record(entries: list, method: dict) -> dict:
    """The atlas record (data_formats/layered_atlas.md) of finished entries."""
    from fitlab.version import __version__

    return _rounded({"schema": SCHEMA, "version": VERSION, "fitlab_version": __version__,
                     "page": PAGE, "threshold": THRESHOLD,
                     "region_max_theta_i": REGION_MAX_THETA_DEG, "noise_limit": NOISE_LIMIT,
                     "albedo_se_limit": ALBEDO_SE_LIMIT, "method": method,
                     "entries": list(entries)})


def merged(old: dict | None, new: dict) -> dict:
    """``new`` with the entries of ``old`` (an earlier record) that it does not replace, in
    ``new``'s order then ``old``'s."""
    if old is None:
        return new
    mine = {e["model"] for e in new["entries"]}
    return {**new, "entries": new["entries"] + [e for e in old["entries"]
                                                if e["model"] not in mine]}


def to_json(rec: dict) -> str:
    """The record as JSON text: two-space indents, each innermost list of numbers on one
    line (small, readable, byte-identical for equal records)."""
    import json

    text = json.dumps(rec, indent=1, ensure_ascii=False, allow_nan=False)
    item = r"(?:-?[0-9][0-9.eE+-]*|null|true|false)"
    return re.sub(rf"\[\s*({item}(?:\s*,\s*{item})*)\s*\]",
                  lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]",
                  text) + "\n"


def check(rec: dict, path) -> dict:
    """``rec`` against the schema, then :func:`check_shapes`. InputFileError naming the
    field."""
    from fitlab.io.validate import check_schema

    check_schema(rec, "layered_atlas", path, hint="regenerate it with `fitlab atlas`")
    return check_shapes(rec, path)


def check_shapes(rec: dict, path) -> dict:
    """What a schema cannot say: every grid's arrays shaped by its axes and incidences, one
    entry per model. InputFileError naming the field."""
    from fitlab.errors import InputFileError

    seen = set()
    for k, e in enumerate(rec["entries"]):
        if e["model"] in seen:
            raise InputFileError(path, f"entries[{k}].model {e['model']!r} appears twice")
        seen.add(e["model"])
        n0, n1 = (len(a["values"]) for a in e["axes"])
        T = len(e["theta_i"])
        for key, shape in (("albedo_error", (n0, n1, T)), ("albedo_error_se", (n0, n1, T)),
                           ("rms_error", (n0, n1, T)), ("rms_noise", (n0, n1, T)),
                           ("albedo_sim", (n0, n1, T)), ("samples", (n0, n1)),
                           ("max_albedo_error", (n0, n1)), ("max_rms_error", (n0, n1)),
                           ("within", (n0, n1)), ("noise_limited", (n0, n1))):
            if np.shape(np.asarray(e[key], dtype=object)) != shape:
                what = "axes[0] x axes[1]" + (" x theta_i" if len(shape) == 3 else "")
                raise InputFileError(path, f"field entries[{k}].{key} is not "
                                     f"{' x '.join(map(str, shape))} ({what})")
        for a in e["axes"]:
            v = a["values"]
            if any(y <= x for x, y in zip(v, v[1:])):
                raise InputFileError(path, f"field entries[{k}].axes: {a['name']}'s values "
                                     "are not ascending")
    return rec


def load(path=None, schema: bool = True) -> dict:
    """The atlas record at ``path`` (default: the package data), validated (``schema``
    False: its shapes only)."""
    from fitlab.io.files import read_bytes
    from fitlab.io.validate import load_json

    path = Path(DATA_PATH if path is None else path)
    rec = load_json(path, read_bytes(path), what="layered-model atlas")
    return check(rec, path) if schema else check_shapes(rec, path)


_CACHE: dict = {}


def package_atlas() -> dict | None:
    """The shipped atlas (read once), None where the package has none. Its shapes are checked;
    the schema is not (the test suite validates the package's own file against it): `fitlab
    models` reads it, and importing jsonschema for it cost 0.12 s of that command's 0.42 s."""
    key = str(DATA_PATH)
    if key not in _CACHE:
        _CACHE[key] = load(DATA_PATH, schema=False) if DATA_PATH.exists() else None
    return _CACHE[key]


def entry_of(model_name: str, atlas: dict | None = None) -> dict | None:
    """The atlas's entry of the model named ``model_name`` (a registry name), or None."""
    atlas = package_atlas() if atlas is None else atlas
    if atlas is None:
        return None
    return {e["model"]: e for e in atlas["entries"]}.get(model_name)


def link(entry: dict, atlas: dict | None = None) -> str:
    """The entry's place on the atlas's page, relative to fitlab's source tree."""
    page = (atlas or {}).get("page", PAGE)
    return f"{page}#{entry['anchor']}"


# --------------------------------------------------------------------------------------------
# The look-up
# --------------------------------------------------------------------------------------------


def _coordinate(axis: dict, x: float) -> tuple[int, float]:
    """(cell index, fraction) of x on the axis (log10 for a log axis)."""
    v = np.asarray(axis["values"], float)
    f = np.log10 if axis["scale"] == "log" else (lambda a: a)
    c, xc = f(v), float(f(x))
    i = int(np.clip(np.searchsorted(c, xc, side="right") - 1, 0, len(c) - 2))
    return i, float(np.clip((xc - c[i]) / (c[i + 1] - c[i]), 0.0, 1.0))


def read_grid(entry: dict, params: dict) -> tuple[float, float]:
    """(largest |albedo error|, largest RMS error) at ``params``: bilinear in the axes'
    coordinates (log10 on a log axis) between the four grid points around it, the nearest
    point's values where one of them has no measure."""
    a, r = worst(entry)
    (i, s), (j, t) = (_coordinate(ax, float(params[ax["name"]])) for ax in entry["axes"])
    w = np.array([[(1 - s) * (1 - t), (1 - s) * t], [s * (1 - t), s * t]])

    def at(grid):
        cell = grid[i:i + 2, j:j + 2]
        if np.isnan(cell).any():
            return float(grid[i + int(round(s)), j + int(round(t))])
        return float(np.sum(w * cell))

    return at(a), at(r)


def _pct(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{100 * x:.2g}%"


def within_region(model, params: dict, options: dict | None = None, atlas: dict | None = None
                  ) -> tuple[bool | None, str]:
    """Whether ``model`` (a Model or a registry name) at ``params`` with ``options`` lies in the
    atlas's 5% region: (True or False, a sentence with the atlas's errors there and its link),
    or (None, why there is no verdict): the model or its options not in the atlas, a parameter
    on an axis outside the grid's span, or one off the axes away from the atlas's slice (the
    slice's reading is given then). ``atlas``: a record (default: the package data)."""
    if isinstance(model, str):
        from fitlab.models import get_model

        model = get_model(model)
    atlas = package_atlas() if atlas is None else atlas
    entry = entry_of(model.name, atlas) if atlas is not None else None
    if entry is None:
        return None, (f"{model.name} is not in the layered-model validation atlas ({PAGE} "
                      "lists the models it covers)")
    where = link(entry, atlas)
    full = {**model.default_options(), **(options or {})}
    differ = [k for k, v in entry["options"].items() if str(full.get(k)) != str(v)]
    if differ:
        theirs = ", ".join(f"{k}={entry['options'][k]}" for k in differ)
        ours = ", ".join(f"{k}={full.get(k)}" for k in differ)
        return None, (f"the atlas maps {model.name} with {theirs}, not {ours}: no verdict "
                      f"({where})")
    missing = [ax["name"] for ax in entry["axes"] if ax["name"] not in params]
    if missing:
        return None, f"no value for {', '.join(missing)}: no verdict ({where})"
    for ax in entry["axes"]:
        x, v = float(params[ax["name"]]), ax["values"]
        if not v[0] * (1 - 1e-9) <= x <= v[-1] * (1 + 1e-9):
            return None, (f"{ax['name']} = {_g(x)} lies outside the atlas's grid "
                          f"({span_text(ax)}): no verdict ({where})")
    a, r = read_grid(entry, params)
    reading = (f"largest albedo error ≈ {_pct(a)}, RMS error of f·cos ≈ {_pct(r)} against the "
               f"simulation of its stack at θi ≤ {REGION_MAX_THETA_DEG:g}°")
    off = [(k, v, float(params[k])) for k, v in entry["fixed"].items()
           if k in params and abs(float(params[k]) - v) > SLICE_TOLERANCE * max(abs(v), 1.0)]
    if off:
        held = ", ".join(f"{k} = {_g(v)}" for k, v, _ in off)
        given = ", ".join(f"{_g(x)}" for _, _, x in off)
        return None, (f"off the atlas's slice ({held} there; {given} here): no verdict; on the "
                      f"slice at these {' and '.join(a['name'] for a in entry['axes'])} the "
                      f"atlas reads {reading} ({where})")
    inside = a <= THRESHOLD and r <= THRESHOLD
    if inside:
        return True, (f"inside the atlas's {THRESHOLD:.0%} region: {reading} ({where})")
    return False, (f"outside the atlas's {THRESHOLD:.0%} region: {reading}; the region: "
                   f"{entry['region']} ({where})")


def summary(model, atlas: dict | None = None) -> dict | None:
    """What ``fitlab models`` shows of a model's atlas entry: {"region", "options", "page",
    "threshold"}, or None where the atlas has no entry for it."""
    atlas = package_atlas() if atlas is None else atlas
    entry = entry_of(model.name, atlas) if atlas is not None else None
    if entry is None:
        return None
    return {"region": entry["region"], "options": entry["options"], "fixed": entry["fixed"],
            "page": link(entry, atlas), "threshold": atlas["threshold"]}


__all__ = ["DATA_PATH", "NOISE_LIMIT", "PAGE", "SCHEMA", "THRESHOLD", "anchor", "check",
           "check_shapes",
           "describe", "entry_of", "finish", "link", "load", "merged", "number_text",
           "read_grid", "record",
           "summary", "to_json", "verdicts", "within_region", "worst"]
