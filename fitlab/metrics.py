"""The one rule for relative errors of a prediction against reference values: rows whose
|reference| is below a fraction of the largest |reference| are left out (the relative error of a
near-zero value says nothing). The fit statistics, the model comparison, the report and the
lobe metrics of exports and tradeoffs all use it, each with its own fraction."""

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
    keep = (np.abs(value) >= floor * np.max(np.abs(value))) & (value != 0)
    return (pred[keep] - value[keep]) / value[keep], keep
