"""Filling a measurement's table from a fit (``fitlab convert DATA --complete FIT.json OUT``):
which places of an output hold a reading of the data and which the fit's value, and why. The
writers' completers (fitlab.export.writers: ``Writer.complete``) lay out their output's places
(the data's own rows and gaps, or a Zemax or MERL grid) and ask :func:`fill` or
:func:`completed_rows`; fitlab.export.completion checks the data against the fit, writes the
output and its record. Spec: data_formats/completion_json.md.

A place holds the data's reading where the measurement has a reading at the same channel and
directions (unit vectors equal to 1e-7) that no subset expression replaced; otherwise the fit's
value (FitResult.predict, the same evaluation as every use of a fit) with the reason
(fitlab.io.measurement.GAP_REASONS): the file's own gap there (``no_reading``, ``blocked``),
``subset``, or ``uncovered`` (no reading at that direction: beyond the data's view edge, or
between its directions).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError
from fitlab.io.directions import direction_to_degrees
from fitlab.io.measurement import MEASURED, Measurement, join_rows

#: Directions are matched on their unit vectors rounded to 1 / KEY_SCALE.
KEY_SCALE = 1e7


class Job(NamedTuple):
    """What a completion fills and from what (checked by fitlab.export.completion)."""

    m: Measurement  # the data's readings, with its gaps (m.gaps)
    fit: object  # the FitResult whose values fill the places
    replaced: np.ndarray  # (m.n,) bool: readings a subset expression declared bad
    format: str  # the data's format (fitlab.io.formats), e.g. "zemax"
    fit_path: str


class Filled(NamedTuple):
    """An output's places that hold a value: the data's channel, the directions (degrees), the
    value written and MEASURED or why it is the fit's (a GAP_REASONS key)."""

    channel: np.ndarray  # (K,) str
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    value: np.ndarray
    reason: np.ndarray  # (K,) str

    @property
    def completed(self) -> np.ndarray:
        return self.reason != MEASURED


def _keys(channel, wi, wo) -> np.ndarray:
    q = np.rint(np.concatenate([wi, wo], axis=1) * KEY_SCALE).astype(np.int64)
    return np.column_stack([np.asarray(channel, dtype=np.int64), q])


def lookup(table_keys, query_keys) -> np.ndarray:
    """For each query key, the index of the equal row of ``table_keys`` (unique rows), or -1."""
    both = np.concatenate([table_keys, query_keys])
    _, inverse = np.unique(both, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    at = np.full(inverse.max() + 1, -1)
    at[inverse[:len(table_keys)]] = np.arange(len(table_keys))
    return at[inverse[len(table_keys):]]


def check_absolute(m: Measurement, file_kind: str) -> None:
    """Refuse relative data for an output that holds the BSDF in 1/sr."""
    if m.quantity != "bsdf":
        raise FitlabError(f"{Path(m.path).name} holds f up to an unknown scale (relative "
                          f"data); a {file_kind} file holds the BSDF in 1/sr: complete it as "
                          "a measurement CSV (OUT.csv), or give the data in absolute units")


def check_sides(job: Job, wi, wo) -> None:
    """The fit's model scatters to every side a value is asked of (else a FitlabError)."""
    from fitlab.models import get_model

    caps = get_model(job.fit.model).capabilities
    trans = np.asarray(wi)[:, 2] * np.asarray(wo)[:, 2] < 0
    for side, rows, able in (("transmission", trans, caps.transmission),
                             ("reflection", ~trans, caps.reflection)):
        if rows.any() and not able:
            raise FitlabError(f"{job.fit_path}: model {job.fit.model} has no {side}, and "
                              f"{int(rows.sum())} places to fill are on the {side} side: "
                              "complete with a fit of a model that scatters there")


def model_at(job: Job, channel, wi, wo) -> np.ndarray:
    """The fit's values (times its scale for relative data) at direction pairs, each with the
    fit of its channel (an index into the data's channel names)."""
    out = np.empty(len(channel))
    check_sides(job, wi, wo)
    for c in np.unique(channel):
        sel = channel == c
        out[sel] = job.fit.predict(wi[sel], wo[sel], channel=job.m.channel_names[c])
    return out


def fill(job: Job, channel, wi, wo) -> Filled:
    """The values of the places (channel indices into the data's, wi, wo (K, 3)) of a grid:
    the data's reading where it has one, else the fit's with the reason."""
    m, n = job.m, len(channel)
    channel = np.asarray(channel, dtype=int)
    value = np.full(n, np.nan)
    reason = np.full(n, "uncovered", dtype=object)
    if n:
        query = _keys(channel, wi, wo)
        at = lookup(_keys(m.channel, m.wi, m.wo), query)
        hit = at >= 0
        value[hit] = m.value[at[hit]]
        reason[hit] = np.where(job.replaced[at[hit]], "subset", MEASURED)
        if m.gaps is not None:
            g = m.gaps.rows
            gat = lookup(_keys(g.channel, g.wi, g.wo), query)
            ghit = (gat >= 0) & ~hit
            reason[ghit] = m.gaps.reason[gat[ghit]]
    need = reason != MEASURED
    value[need] = model_at(job, channel[need], wi[need], wo[need])
    ti, pi = direction_to_degrees(np.asarray(wi).reshape(-1, 3))
    to, po = direction_to_degrees(np.asarray(wo).reshape(-1, 3))
    return Filled(np.asarray(m.channel_names, dtype=object)[channel], ti, pi, to, po, value,
                  reason)


def completed_rows(job: Job) -> tuple[Measurement, np.ndarray]:
    """The data's rows and gaps in file order (line, channel, directions), the fit's value (its
    aperture mean where a row declares an aperture: FitResult.predict_measurement) where a row
    holds no reading or a replaced one, sigma NaN there; and per row MEASURED or the reason."""
    m = job.m
    rows = m._replace(gaps=None)
    reason = np.where(job.replaced, "subset", MEASURED).astype(object)
    if m.gaps is not None:
        rows = join_rows(rows, m.gaps.rows)
        reason = np.concatenate([reason, m.gaps.reason]).astype(object)
    order = np.lexsort((rows.phi_o, rows.theta_o, rows.channel, rows.lines))
    rows, reason = rows.take(order), reason[order]
    need = reason != MEASURED
    value = rows.value.copy()
    if need.any():
        check_sides(job, rows.wi[need], rows.wo[need])
        value[need] = job.fit.predict_measurement(rows.select(need))
    sigma = None if rows.sigma is None else np.where(need, np.nan, rows.sigma)
    return rows._replace(value=value, sigma=sigma), reason


def filled_rows(rows: Measurement, reason) -> Filled:
    """The Filled record of rows written as they are (:func:`completed_rows`)."""
    return Filled(np.asarray(rows.channel_names, dtype=object)[rows.channel], rows.theta_i,
                  rows.phi_i, rows.theta_o, rows.phi_o, rows.value, np.asarray(reason))


__all__ = ["Job", "Filled", "KEY_SCALE", "lookup", "check_absolute", "check_sides",
           "model_at", "fill", "completed_rows", "filled_rows"]
