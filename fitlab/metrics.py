"""The one rule for relative errors of a prediction against reference values: rows whose
|reference| is below a fraction of the largest |reference| are left out (the relative error of a
near-zero value says nothing). The fit statistics, the model comparison, the report and the
lobe metrics of exports and tradeoffs all use it, each with its own fraction.

A fit's error is :func:`fit_error` (that rule per incidence direction, over the fitted rows),
stored in the parameter file as ``statistics.fit_error`` and shown everywhere through
:func:`fit_error_text` (data_formats/fit_json.md, "The fit error")."""

from __future__ import annotations

import numpy as np

#: The fraction of the largest |reference| below which a row is left out, unless told otherwise.
REL_ERR_FLOOR = 0.01


def relative_errors(pred, value, floor: float = REL_ERR_FLOOR):
    """((pred − value)/value of the rows kept, which rows those are): a row is kept where
    |value| ≥ ``floor`` × max |value| and value ≠ 0."""
    pred, value = np.asarray(pred), np.asarray(value)
    if not value.size:
        return (pred - value)[:0], np.zeros(value.shape, bool)
    keep = floor_mask(np.abs(value), floor)
    return (pred[keep] - value[keep]) / value[keep], keep


def floor_mask(absval, floor: float = REL_ERR_FLOOR):
    """The rows a relative error counts, along the last axis: |value| ≥ ``floor`` × the largest
    |value| and value ≠ 0 (``absval``: |value|, 0 where a row is not scored)."""
    absval = np.asarray(absval)
    return (absval >= floor * np.max(absval, axis=-1, keepdims=True)) & (absval != 0)


#: How a fit's error leaves rows out (data_formats/fit_json.md, "The fit error"): a row is not
#: counted where its |value| is below REL_ERR_FLOOR × the largest |value| among the scored rows
#: of its incidence direction (θi, φi). Per incidence, not per channel: a goniometric scan's
#: incidences differ by orders of magnitude (a grazing specular peak against a diffuse scan at
#: normal incidence), and a channel-wide floor would drop every row of the weaker incidences and
#: count only the peaks.
FLOOR_RULE = "incidence_peak"
_FLOOR_WORDS = {
    "incidence_peak": "rows below {pct} of their incidence's peak left out",
    "channel_peak": "rows below {pct} of the channel's peak left out",
}


def incidence_keys(theta_i, phi_i) -> np.ndarray:
    """(θi, φi mod 360) of every row, degrees: the grouping of every per-incidence figure."""
    return np.stack([np.asarray(theta_i, float), np.mod(np.asarray(phi_i, float), 360.0)],
                    axis=1)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else None


def incidence_groups(theta_i, phi_i) -> list:
    """[((θi, φi), the mask of its rows)] of every incidence direction, sorted by θi, φi."""
    keys = incidence_keys(theta_i, phi_i)
    return [((float(ti), float(pi)), (keys[:, 0] == ti) & (keys[:, 1] == pi))
            for ti, pi in (np.unique(keys, axis=0) if keys.size else ())]


def incidence_floor_mask(absval, groups, floor: float = REL_ERR_FLOOR) -> np.ndarray:
    """The rows a fit error counts (:data:`FLOOR_RULE`), along the last axis of ``absval``
    (|value|, 0 where a row is not scored): per incidence of ``groups``
    (:func:`incidence_groups`), :func:`floor_mask` of its rows."""
    absval = np.asarray(absval)
    keep = np.zeros(absval.shape, bool)
    for _, sel in groups:
        keep[..., sel] = floor_mask(absval[..., sel], floor)
    return keep


def fit_error(pred, value, theta_i, phi_i, floor: float = REL_ERR_FLOOR) -> dict:
    """THE fit error of fitlab (the parameter file's ``statistics.fit_error``; every tool prints
    this record, never its own figure): the RMS relative error (pred − value)/value over the
    rows given (the rows a fit was fitted to, its subset applied), per incidence direction and
    pooled, where each incidence's rows below ``floor`` × the largest |value| among *its* rows
    given are left out (:data:`FLOOR_RULE`, :func:`incidence_floor_mask`).

    Returns {rms_relative_error (pooled; None when no row counts), rows (counted), rows_scored,
    floor, floor_rule, per_incidence: [{theta_i, phi_i, rows, rows_counted,
    rms_relative_error, max_abs_relative_error}] (sorted by θi, φi)}."""
    pred, value = np.asarray(pred, float), np.asarray(value, float)
    groups = incidence_groups(theta_i, phi_i)
    keep = incidence_floor_mask(np.abs(value), groups, floor)
    per, pooled = [], []
    for (ti, pi), sel in groups:
        k = keep & sel
        rel = (pred[k] - value[k]) / value[k]
        pooled.append(rel)
        per.append({"theta_i": ti, "phi_i": pi, "rows": int(sel.sum()),
                    "rows_counted": int(k.sum()), "rms_relative_error": _rms(rel),
                    "max_abs_relative_error": float(np.max(np.abs(rel))) if rel.size
                    else None})
    rel = np.concatenate(pooled) if pooled else np.zeros(0)
    return {"rms_relative_error": _rms(rel), "rows": int(rel.size),
            "rows_scored": int(value.size), "floor": float(floor), "floor_rule": FLOOR_RULE,
            "per_incidence": per}


def fit_error_rms_many(pred, value, rows, theta_i, phi_i, floor: float = REL_ERR_FLOOR):
    """:func:`fit_error`'s pooled ``rms_relative_error`` of many datasets on the same rows at
    once (the texels of a capture stack, ``fitlab fit-maps``): ``pred`` and ``value`` (N, n),
    ``rows`` (N, n) the rows each dataset was fitted to, ``theta_i``/``phi_i`` (n,) shared.
    The same rule (:func:`incidence_floor_mask`) on every dataset at once. NaN where no row
    counts."""
    pred, value = np.asarray(pred, float), np.asarray(value, float)
    rows = np.asarray(rows, bool)
    absval = np.where(rows, np.abs(np.nan_to_num(value)), 0.0)
    keep = rows & incidence_floor_mask(absval, incidence_groups(theta_i, phi_i), floor)
    v = np.where(keep, value, 1.0)
    rel = np.where(keep, (pred - v) / v, 0.0)
    total, count = np.sum(rel * rel, axis=1), keep.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def fit_error_of(statistics: dict) -> dict | None:
    """A parameter file's fit error (``statistics.fit_error``), or, for a file written before it
    existed, its older figure ``rms_relative_error_fit`` described by that file's own rule (1%
    of the channel's peak, ``floor_rule`` "channel_peak"); None when it has neither."""
    fe = statistics.get("fit_error")
    if fe is not None:
        return fe
    if statistics.get("rms_relative_error_fit") is None:
        return None
    return {"rms_relative_error": statistics["rms_relative_error_fit"], "rows": None,
            "rows_scored": statistics.get("n_fit"),
            "floor": statistics.get("relative_error_floor", REL_ERR_FLOOR),
            "floor_rule": "channel_peak", "per_incidence": []}


def fit_error_text(fe: dict | None, rows: str = "fitted rows") -> str:
    """The fit error as one sentence with its floor rule beside the number, e.g. "RMS relative
    error 0.3102 over 412 of 420 fitted rows (rows below 1% of their incidence's peak left
    out)". The terminal, the report and ``fitlab compare`` print this text."""
    if fe is None:
        return "RMS relative error: not recorded"
    x = fe["rms_relative_error"]
    num = "n/a" if x is None else f"{x:.4g}"
    n, total = fe.get("rows"), fe.get("rows_scored")
    if n is None:
        where = f"the {rows}"
    elif total is not None and total != n:
        where = f"{n} of {total} {rows}"
    else:
        where = f"{n} {rows}"
    words = _FLOOR_WORDS.get(fe.get("floor_rule"), _FLOOR_WORDS[FLOOR_RULE])
    pct = f"{fe.get('floor', REL_ERR_FLOOR):.0%}"
    return f"RMS relative error {num} over {where} ({words.format(pct=pct)})"
