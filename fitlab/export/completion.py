"""Completed measurements: ``fitlab convert DATA --complete FIT.json OUT`` and
:func:`complete_measurement`. The measurement is written in OUT's format with the values it
lacks (no reading, blocked, beyond its view edge on the output's grid, or declared bad by a
subset expression) replaced by the fit's, each marked in the file where the format allows it
(the measurement CSV's ``completion`` column, OpenMATERIAL's ``fitlabCompletion`` field), and
a side record ``OUT.completion.json`` for every format: what was filled, where, why, and the
fit's error on the readings beside it. Spec: data_formats/completion_json.md.

The places and their values are fitlab.export.filling's; each writer's ``complete``
(fitlab.export.writers) lays out its format. This module checks the data against the fit,
writes the output and the record (atomically, both or neither on a refusal) and says what it
did.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError

SCHEMA = "fitlab-completion"
SCHEMA_VERSION = 1
SPEC = "data_formats/completion_json.md"
#: The side record's name: the output's with this appended.
RECORD_SUFFIX = ".completion.json"
#: Most completed places the record lists one by one (beyond: counts only, said so).
MAX_LISTED = 20_000
#: Most incidence directions the record lists (beyond, e.g. MERL's bins: those of the
#: readings, the rest summed as one entry).
MAX_INCIDENCES = 1_000


def record_path(out) -> Path:
    """The side record of the output ``out``: ``OUT.completion.json``."""
    return Path(str(out) + RECORD_SUFFIX)


# --------------------------------------------------------------------------------------------
# The data against the fit
# --------------------------------------------------------------------------------------------


def check_fit_for(m, fit, fit_path) -> list[str]:
    """Refuse (FitlabError, naming both files and what to do) a fit whose values cannot stand
    in for the data's: other conventions, another quantity (absolute f against relative
    data), a channel of the data the fit lacks. Returns notes on what does not stop it (the
    fit made from another file, read another way)."""
    from fitlab.io.conventions import CONVENTIONS

    rec, data, notes = fit.record, fit.record["data"], []
    label, fit_label = Path(m.path).name, Path(str(fit_path)).name
    conv = rec.get("conventions")
    if conv is None:
        notes.append(f"{fit_label} states no conventions; fitlab's ({CONVENTIONS['document']}) "
                     "assumed")
    else:
        differ = [k for k in CONVENTIONS if k in conv and conv[k] != CONVENTIONS[k]]
        if differ:
            raise FitlabError(f"{fit_label} was fitted under other conventions than this "
                              f"fitlab's (field conventions.{differ[0]}: {conv[differ[0]]!r}, "
                              f"here {CONVENTIONS[differ[0]]!r}); its values are not the "
                              f"data's: fit {label} again with this fitlab")
    quantity = data.get("quantity")
    if quantity is not None and quantity != m.quantity:
        said = {"bsdf": "absolute f (1/sr)", "relative": "f up to an unknown scale"}
        raise FitlabError(f"{fit_label} was fitted to {said.get(quantity, quantity)} but "
                          f"{label} reads as {said.get(m.quantity, m.quantity)}: its values "
                          "would not be the data's. Complete with a fit of data of the same "
                          "quantity (e.g. fitted to this file), or read the file as the fit "
                          "did (--quantity)")
    missing = [c for c in m.channel_names if c not in fit.channels]
    if missing:
        raise FitlabError(f"{label} has channel(s) {', '.join(m.channel_names)} but "
                          f"{fit_label} fits {', '.join(fit.channels)}: no fit of "
                          f"{', '.join(missing)}. Channels are matched by name: complete with "
                          "a fit of these data's channels (fitlab fit DATA --model ...)")
    if data.get("sha256") and data["sha256"] != m.sha256:
        notes.append(f"{fit_label} was fitted to {Path(str(data['path'])).name} (another "
                     f"file than {label}: SHA-256 differs); its values fill {label}'s gaps")
    said = data.get("read_options") or {}
    here = m.read_options or {}
    if said != here:
        notes.append(f"{fit_label} read its data with {said or 'the defaults'}, this "
                     f"completion reads {label} with {here or 'the defaults'}")
    return notes


def _job(data, fit, *, subset, format, read):
    from fitlab.export.filling import Job
    from fitlab.fitting.result import load_fit
    from fitlab.fitting.subset import subset_mask
    from fitlab.io.formats import detect_format, read_any
    from fitlab.io.gates import notes as read_notes
    from fitlab.io.measurement import one_dataset

    fmt = detect_format(data, format)
    m = one_dataset(read_any(data, fmt.name, **read, **(fmt.whole or {})))
    fmt = fmt.name
    result = load_fit(fit)
    notes = read_notes(m) + check_fit_for(m, result, fit)
    replaced = (subset_mask(subset, m, source="--complete-subset") if subset is not None
                else np.zeros(m.n, dtype=bool))
    return Job(m, result, replaced, fmt, str(fit)), notes


# --------------------------------------------------------------------------------------------
# The record
# --------------------------------------------------------------------------------------------


def _g(x, digits: int = 10) -> float:
    return float(f"{float(x):.{digits}g}") + 0.0


def _reason_counts(reason) -> dict:
    from fitlab.io.measurement import GAP_REASONS

    return {r: int(np.sum(reason == r)) for r in GAP_REASONS}


def _incidence_keys(theta_i, phi_i) -> np.ndarray:
    """The fit error's incidence keys (fitlab.metrics.incidence_keys), rounded for matching."""
    from fitlab.metrics import incidence_keys

    return np.round(incidence_keys(theta_i, phi_i), 6) + 0.0


def by_incidence(filled, error: dict) -> tuple[list, dict | None]:
    """Per incidence direction (θi, φi) of the output's places: how many, how many the fit's
    and why, and the fit's RMS relative error on the readings of that incidence; sorted by θi,
    φi. Beyond MAX_INCIDENCES directions, those the readings have and one entry for the rest."""
    keys = _incidence_keys(filled.theta_i, filled.phi_i)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    err = {tuple(k): e for k, e in zip(
        _incidence_keys([e["theta_i"] for e in error["per_incidence"]],
                        [e["phi_i"] for e in error["per_incidence"]]).tolist()
        if error["per_incidence"] else [], error["per_incidence"])}
    listed = np.ones(len(uniq), dtype=bool)
    if len(uniq) > MAX_INCIDENCES:
        listed = np.array([tuple(k) in err for k in uniq.tolist()], dtype=bool)
    done = filled.completed
    out = []
    for u in np.flatnonzero(listed):
        sel = inverse == u
        e = err.get(tuple(uniq[u].tolist()))
        out.append({"theta_i": _g(uniq[u, 0]), "phi_i": _g(uniq[u, 1]),
                    "places": int(sel.sum()), "completed": int((sel & done).sum()),
                    "by_reason": {k: v for k, v in _reason_counts(filled.reason[sel]).items()
                                  if v},
                    "fit_rms_relative_error": None if e is None else e["rms_relative_error"],
                    "readings_counted": 0 if e is None else e["rows_counted"]})
    rest = None
    if not listed.all():
        sel = ~listed[inverse]
        rest = {"incidences": int((~listed).sum()), "places": int(sel.sum()),
                "completed": int((sel & done).sum()),
                "by_reason": {k: v for k, v in _reason_counts(filled.reason[sel]).items() if v}}
    return out, rest


def _recorded_error(fit, channels) -> dict:
    """{channel: the fit's error as its parameter file records it (over the rows it was fitted
    to): rms_relative_error, rows, floor_rule}, for the data's channels."""
    from fitlab.metrics import fit_error_of

    stats = {f["channel"]: f.get("statistics") or {} for f in fit.record["fits"]}
    out = {}
    for c in channels:
        fe = fit_error_of(dict(stats.get(c, {})))
        out[c] = None if fe is None else {k: fe.get(k) for k in ("rms_relative_error", "rows",
                                                                 "floor_rule")}
    return out


def _listed(filled) -> dict:
    done = np.flatnonzero(filled.completed)
    if done.size > MAX_LISTED:
        return {"listed": False, "why": f"{done.size} places, more than {MAX_LISTED}: the "
                "counts above say where"}
    order = done[np.lexsort((filled.phi_o[done], filled.theta_o[done], filled.phi_i[done],
                             filled.theta_i[done], filled.channel[done].astype(str)))]
    return {"listed": True,
            "columns": ["channel", "theta_i", "phi_i", "theta_o", "phi_o", "reason", "value"],
            "rows": [[str(filled.channel[j]), _g(filled.theta_i[j]), _g(filled.phi_i[j]),
                      _g(filled.theta_o[j]), _g(filled.phi_o[j]), str(filled.reason[j]),
                      _g(filled.value[j], 9)] for j in order]}


def completion_record(job, done: dict, out, writer, subset, content_sha256: str,
                      error: dict, notes: list) -> dict:
    """The side record (data_formats/completion_json.md) of a completion: no absolute path,
    nothing of the time or machine, so the same inputs give the same bytes."""
    from fitlab.io.files import path_for_record, sha256_of
    from fitlab.version import __version__

    m, filled = job.m, done["filled"]
    incid, rest = by_incidence(filled, error)
    completed = filled.completed
    channels = [str(c) for c in m.channel_names]
    return {
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "spec": SPEC,
        "software": {"fitlab": __version__},
        "output": {"path": path_for_record(out, record_path(out)), "format": writer.name,
                   "sha256": content_sha256, "marks": done["marks"],
                   "grid": {"source": done["grid_source"], **done["grid"]}},
        "data": {"path": path_for_record(m.path, record_path(out)), "format": job.format,
                 "sha256": m.sha256, "readings": m.n,
                 "without_reading": m.gaps.counts() if m.gaps is not None else {},
                 "channels": channels, "quantity": m.quantity,
                 "read_options": m.read_options or {}},
        "fit": {"path": path_for_record(job.fit_path, record_path(out)),
                "sha256": sha256_of(job.fit_path), "model": job.fit.model,
                "channels": list(job.fit.channels),
                "data_sha256": job.fit.record["data"].get("sha256"),
                "fit_subset": job.fit.record["data"].get("fit_subset"),
                "recorded_error": _recorded_error(job.fit, channels)},
        "subset": subset, "subset_readings": int(job.replaced.sum()),
        "values": {"places": int(filled.value.size), "measured": int((~completed).sum()),
                   "completed": int(completed.sum())},
        "completed_by_reason": _reason_counts(filled.reason),
        "completed_by_channel": {c: int((completed & (filled.channel == c)).sum())
                                 for c in channels},
        "fit_error": error,
        "by_incidence": incid,
        **({"by_incidence_rest": rest} if rest is not None else {}),
        "completed": _listed(filled),
        "notes": list(notes) + list(done.get("notes", [])),
    }


def record_text(record: dict) -> str:
    """The record's text: 1-space indented JSON, one listed place a line."""
    rows = record["completed"].get("rows")
    if rows is None:
        return json.dumps(record, indent=1, ensure_ascii=False) + "\n"
    mark = "@COMPLETED_ROWS@"
    text = json.dumps({**record, "completed": {**record["completed"], "rows": mark}},
                      indent=1, ensure_ascii=False)
    head, _, tail = text.rpartition(json.dumps(mark))
    body = ",\n".join("   " + json.dumps(r, ensure_ascii=False) for r in rows)
    return head + ("[\n" + body + "\n  ]" if rows else "[]") + tail + "\n"


# --------------------------------------------------------------------------------------------
# The entry point
# --------------------------------------------------------------------------------------------


def complete_measurement(data, fit, out, *, to: str | None = None, subset: str | None = None,
                         format: str | None = None, angles: str | None = None, accept=(),
                         quantity: str | None = None, **settings) -> dict:
    """Write the measurement ``data`` as ``out`` (its format from ``to`` or the suffix, as
    ``fitlab convert``) with the values it lacks replaced by the fit's (``fit``, a parameter
    file), and the side record ``out + '.completion.json'``; returns the record (a dict) with
    ``summary``, the text ``fitlab convert`` prints.

    Replaced: the data's places without reading (NaN, a Zemax stored zero, a MERL bin without
    value: ``no_reading``; a spectral scan's ``blocked`` zero), the places of a Zemax or MERL
    output's grid where the data hold no reading (``uncovered``), and the readings the subset
    expression ``subset`` selects (``subset``; the names of ``fitlab fit --fit-subset``).
    ``format``, ``angles``, ``accept``, ``quantity``: how ``data`` is read (as fitlab.read);
    ``settings``: the output writer's (a Zemax ``grid``, ``aoi``, ``azimuth``, ``radial``,
    ``scatter``; OpenMATERIAL's header fields). Refuses (FitlabError; nothing written) a fit
    of other channels, conventions or quantity than the data's."""
    from fitlab.export.writers import WRITERS, writer_for
    from fitlab.io.atomic import atomic_open, atomic_write_text
    from fitlab.metrics import fit_error

    writer = writer_for(out, to)
    if writer.complete is None:
        takers = ", ".join(w.name for w in WRITERS.values() if w.complete)
        raise FitlabError(f"{out}: a {writer.title} output cannot be completed; choose {takers}")
    unknown = [k for k in settings if k not in writer.settings]
    if unknown:
        raise FitlabError(f"{', '.join(unknown)}: not a setting of the {writer.title} writer "
                          f"({', '.join(writer.settings) or 'it has none'})")
    read = {"angles": angles, "accept": tuple(accept or ()), "quantity": quantity}
    if record_path(out).resolve() in (Path(data).resolve(), Path(fit).resolve()) \
            or Path(out).resolve() in (Path(data).resolve(), Path(fit).resolve()):
        raise FitlabError(f"{out}: the output (or its record) would replace an input; give "
                          "another output name")
    job, notes = _job(data, fit, subset=subset, format=format, read=read)
    done = writer.complete(out, job, **settings)
    content = done["content"]
    raw = content.encode("utf-8") if isinstance(content, str) else content
    kept = job.m.select(~job.replaced)
    error = fit_error(job.fit.predict_measurement(kept), kept.value, kept.theta_i, kept.phi_i)
    record = completion_record(job, done, out, writer, subset, hashlib.sha256(raw).hexdigest(),
                               error, notes)
    text = record_text(record)
    with atomic_open(out, "wb") as fh:
        fh.write(raw)
    atomic_write_text(record_path(out), text)
    return {**record, "summary": summary_text(record, out)}


def summary_text(record: dict, out) -> str:
    """What ``fitlab convert --complete`` prints: how many values were filled, why, where (per
    incidence, with the fit's error there) and the fit's error on the readings."""
    from fitlab.metrics import fit_error_text

    v = record["values"]
    why = ", ".join(f"{k} {n}" for k, n in record["completed_by_reason"].items() if n) or "none"
    lines = [f"completed {v['completed']} of {v['places']} values of {out} "
             f"({record['output']['format']}; grid: {record['output']['grid']['source']}): "
             f"{why}"]
    inc = [e for e in record["by_incidence"] if e["completed"]]
    if inc:
        def pct(x):
            return "n/a" if x is None else f"{100 * x:.1f}%"

        shown = "; ".join(f"{e['theta_i']:g}°/{e['phi_i']:g}°: {e['completed']} "
                          f"(fit error {pct(e['fit_rms_relative_error'])})" for e in inc[:12])
        more = f"; ... {len(inc) - 12} more in the record" if len(inc) > 12 else ""
        lines.append(f"  by incidence θi/φi: {shown}{more}")
    rest = record.get("by_incidence_rest")
    if rest and rest["completed"]:
        lines.append(f"  at {rest['incidences']} other incidences: {rest['completed']}")
    lines.append("  fit error on the readings kept: "
                 + fit_error_text(record["fit_error"], rows="readings"))
    own = {c: e for c, e in record["fit"]["recorded_error"].items()
           if e and e["rms_relative_error"] is not None}
    if own:
        subset = record["fit"]["fit_subset"]
        lines.append("  the fit's own, over the rows it was fitted to"
                     + (f" ({subset})" if subset else "") + ": "
                     + ", ".join(f"{c} {e['rms_relative_error']:.4g}" for c, e in own.items()))
    lines.append(f"  marks: {record['output']['marks']}; record {record_path(out)}")
    return "\n".join(lines)


__all__ = ["complete_measurement", "check_fit_for", "completion_record", "record_text",
           "record_path", "summary_text", "by_incidence", "SCHEMA", "SPEC", "RECORD_SUFFIX"]
