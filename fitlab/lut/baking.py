"""Baking and accuracy: evaluate a :class:`~fitlab.lut.axes.Spec` at every sample, round the
values to the stored type, and measure the table against direct evaluation.

Accuracy against direct evaluation (bilinear lookup of the stored, rounded values at random
points vs the model or a fresh quadrature there) is measured for every table and stored in it
(:func:`measure_accuracy`); quadrature tables also store their error estimate.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from fitlab.lut.axes import Spec, Table, grid_coords, lookup, shape_of

#: Largest number of samples in one table (W × H, slices included).
TEXELS_MAX = 4096 * 4096
#: Largest finite half float.
HALF_MAX = 65504.0
#: Relative errors are |a - b| / max(|b|, REL_FLOOR × the channel's largest |value|).
REL_FLOOR = 1e-3


def relative_error(approx, ref, scale):
    """|approx - ref| / max(|ref|, REL_FLOOR · scale) (scale: the channel's largest |value|)."""
    den = np.maximum(np.abs(ref), REL_FLOOR * scale)
    den = np.where(den > 0, den, 1.0)
    return np.abs(approx - ref) / den


def error_stats(err):
    """Max and RMS of relative errors."""
    return {"max_rel": float(np.max(err)), "rms_rel": float(np.sqrt(np.mean(err**2)))}


def round_to(values, dtype: str) -> np.ndarray:
    """Values as the file stores them (float64 array holding half or float values)."""
    if dtype not in ("half", "float"):
        raise ValueError(f"dtype must be 'half' or 'float', got {dtype!r}")
    if dtype == "half":
        big = np.abs(values).max(initial=0.0)
        if big > HALF_MAX:
            raise ValueError(f"the table holds values up to {big:.4g}, beyond the largest half "
                             f"float {HALF_MAX:g}; use dtype float")
        return values.astype(np.float16).astype(np.float64)
    return values.astype(np.float32).astype(np.float64)


def _random_points(axes, n, seed):
    rng = np.random.default_rng(seed)
    t = rng.random((n, len(axes)))
    return np.stack([a.to_x(t[:, k]) for k, a in enumerate(axes)], axis=-1)


def measure_accuracy(table: Table, evaluate: Callable, n_points: int, seed: int = 0,
                     points=None) -> dict:
    """Bilinear lookup of the stored values vs direct evaluation at ``n_points`` random points
    (uniform in the texture coordinates), or at the given axis coordinates ``points`` (P, n_axes),
    per channel: max and RMS relative error."""
    pts = _random_points(table.axes, n_points, seed) if points is None else np.asarray(points)
    n_points = len(pts)
    ref, _ = evaluate(pts)
    approx = lookup(table, pts)
    scale = np.abs(table.values).reshape(-1, len(table.channels)).max(axis=0)
    err = relative_error(approx, ref, scale)
    per = {ch: error_stats(err[:, k]) for k, ch in enumerate(table.channels)}
    return {"points": int(n_points), "seed": seed, "floor": REL_FLOOR,
            "reference": "direct evaluation at random points (uniform in texture coordinates)",
            **error_stats(err), "per_channel": per}


def bake(spec: Spec, dtype: str = "float", *, check_points: int | None = None,
         source_fit: str | None = None, progress: Callable | None = None) -> Table:
    """Evaluate ``spec`` at every sample, round to ``dtype`` and measure the accuracy."""
    n_texels = int(np.prod([a.size for a in spec.axes]))
    if n_texels > TEXELS_MAX:
        raise ValueError(f"the table would have {n_texels} samples; at most {TEXELS_MAX} are "
                         "allowed (reduce --size)")
    coords = grid_coords(spec.axes)
    if progress:
        progress(f"evaluating {spec.kind} at {len(coords)} samples ({spec.method})")
    values, err = _evaluate_in_rows(spec, coords, progress)
    values = np.asarray(values, float)
    if not np.all(np.isfinite(values)):
        bad = int(np.sum(~np.isfinite(values)))
        raise FloatingPointError(f"{spec.kind}: {bad} non-finite values; this is a bug in the "
                                 "table's evaluation, please report it")
    shape = shape_of(spec.axes, len(spec.channels))
    exact = values.reshape(shape)
    stored = round_to(exact, dtype)
    scale = np.abs(exact).reshape(-1, len(spec.channels)).max(axis=0)
    accuracy = {"method": spec.method,
                "storage": {"dtype": dtype, **error_stats(relative_error(stored, exact, scale))}}
    if err is not None:
        e = np.asarray(err).reshape(-1, len(spec.channels))
        rel = e / np.maximum(np.abs(values), REL_FLOOR * np.maximum(scale, 1e-300))
        accuracy["quadrature"] = {"max_abs_error_estimate": float(e.max()),
                                  "max_rel_error_estimate": float(rel.max()),
                                  "per_channel_max_abs": {ch: float(e[:, k].max()) for k, ch
                                                          in enumerate(spec.channels)},
                                  "orders": spec.orders}
    table = Table(spec.kind, stored, tuple(spec.channels), tuple(spec.axes), dtype, spec.quantity,
                  spec.model, spec.params, accuracy, source_fit, tuple(spec.notes))
    n = check_points if check_points is not None else spec.n_check
    if n:
        if progress:
            progress(f"measuring accuracy at {n} random points against direct evaluation")
        accuracy["interpolation"] = measure_accuracy(table, spec.evaluate, n)
        for name, check in spec.checks:
            accuracy[name] = check(table, spec, n)
    return table


def _evaluate_in_rows(spec: Spec, coords, progress, chunks: int = 10):
    """spec.evaluate over whole rows of the table at a time (rows share α and η, so the
    averages E_avg are integrated once per row), reporting progress for the quadrature kinds."""
    if spec.orders is None or progress is None:
        return spec.evaluate(coords)
    w = spec.axes[0].size
    rows = len(coords) // w
    step = max(1, -(-rows // chunks)) * w
    vals, errs, t0 = [], [], time.perf_counter()
    for start in range(0, len(coords), step):
        v, e = spec.evaluate(coords[start:start + step])
        vals.append(np.asarray(v))
        errs.append(np.asarray(e))
        done = min(start + step, len(coords))
        el = time.perf_counter() - t0
        progress(f"  {done}/{len(coords)} samples, {el:.0f} s elapsed, about "
                 f"{el * (len(coords) - done) / done:.0f} s to go")
    return np.concatenate(vals), np.concatenate(errs)
