"""A comparison's result: :class:`CompareResult` (its tables, summary and files) and
:func:`load_compare`, which reads one back."""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from fitlab.errors import FitlabError
from fitlab.fitting.compare.common import READABLE_VERSIONS, SCHEMA, SCHEMA_VERSION
from fitlab.fitting.compare.record import _fmt
from fitlab.fitting.result import _freeze, thaw
from fitlab.fitting.status import Status, trusted

#: The files ``CompareResult.save`` writes into the output folder (the report adds index.html).
TABLE_JSON, TABLE_CSV, INCIDENCE_CSV, FITS_DIR = ("compare.json", "compare.csv",
                                                  "compare_incidences.csv", "fits")


# --------------------------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------------------------


SUMMARY_COLUMNS = (
    "channel", "label", "model", "n_free", "in_sample_rms_rel", "cv_rank", "cv_rms_rel",
    "cv_delta", "cv_delta_se", "cv_delta_over_noise", "loo_rank", "elpd_loo", "elpd_loo_se",
    "p_loo", "loo_elpd_diff", "loo_dse", "loo_weight", "pareto_k_max", "pareto_k_bad_rows",
    "waic_rank", "elpd_waic", "elpd_waic_se", "p_waic", "waic_elpd_diff", "waic_dse",
    "waic_weight")
INCIDENCE_COLUMNS = ("channel", "label", "theta_i", "phi_i", "rows", "rows_counted",
                     "in_sample_rms_rel", "cv_rms_rel", "pareto_k_max")


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _csv(columns, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_cell(row.get(c)) for c in columns])
    return buf.getvalue()


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:60] or "model"


@dataclass(frozen=True)
class CompareResult:
    """A comparison: ``record`` (what compare.json holds, read-only), the candidates' fits
    (:class:`FitResult`, in the candidates' order) and the measurement."""

    record: MappingProxyType
    fits: tuple = ()
    measurement: object = None
    path: str | None = field(default=None)

    @classmethod
    def from_record(cls, record, fits=(), measurement=None, path=None):
        return cls(_freeze(thaw(record)), tuple(fits), measurement, path)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(c["label"] for c in self.record["candidates"])

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(ch["channel"] for ch in self.record["channels"])

    def _channel(self, channel):
        chs = self.record["channels"]
        if channel is None:
            if len(chs) != 1:
                raise ValueError(f"this comparison has channels {', '.join(self.channels)}: "
                                 "name one")
            return chs[0]
        for ch in chs:
            if ch["channel"] == channel:
                return ch
        raise ValueError(f"no channel {channel!r}; channels: {', '.join(self.channels)}")

    def ranking(self, channel=None, by: str | None = None) -> tuple[str, ...]:
        """Labels best first by ``cv``, ``loo`` or ``waic`` (default: cv where it ran)."""
        rk = self._channel(channel)["ranking"]
        by = by or ("cv" if "cv" in rk else "loo")
        if by not in rk:
            raise ValueError(f"no ranking by {by!r} (this comparison has {', '.join(rk)})")
        return tuple(rk[by])

    def winner(self, channel=None, by: str | None = None) -> str:
        return self.ranking(channel, by)[0]

    def fit(self, label) -> "object":
        """The :class:`FitResult` of a candidate."""
        return self.fits[self.labels.index(label)]

    def verdict(self, channel=None) -> str:
        return self._channel(channel)["verdict"]["text"]

    @property
    def warnings(self) -> tuple[str, ...]:
        return tuple(self.record["warnings"])

    # ---- trust --------------------------------------------------------------------------

    def statuses(self, label, channel=None) -> tuple[Status, ...]:
        """What limits trust in candidate ``label``'s fit of ``channel`` (its fit's statuses,
        fitlab.fitting.status, and ``FOLDS_FAILED`` where a cross-validation fold could not be
        fitted); read from the record, so a loaded comparison answers alike."""
        if label not in self.labels:
            raise ValueError(f"no candidate {label!r}; candidates: {', '.join(self.labels)}")
        mod = self._channel(channel)["models"][self.labels.index(label)]
        if "statuses" not in mod:
            raise ValueError("this comparison was written by an older fitlab (schema_version "
                             f"{self.record.get('schema_version')}), without statuses: rerun "
                             "fitlab compare")
        return tuple(Status(s) for s in mod["statuses"])

    def _untrusted(self) -> list[tuple[str, Status]]:
        """(label, channel, status) of every status that undermines the comparison: any but
        ``converged`` and ``misfit`` (a candidate that does not describe the data is what a
        comparison finds, not a failure of it)."""
        return [(f"{lab} channel {ch}", s) for ch in self.channels for lab in self.labels
                for s in self.statuses(lab, ch) if s not in (Status.CONVERGED, Status.MISFIT)]

    @property
    def ok(self) -> bool:
        """Whether every candidate's fit and folds ran as they should, so that the ranking can
        be used as it stands (candidates may misfit: that is what is ranked)."""
        return not self._untrusted()

    def raise_for_status(self) -> "CompareResult":
        """This result if it is :attr:`ok`, else a FitlabError naming each candidate's statuses
        and what to do about each."""
        return trusted(self, "the comparison is not to be trusted as it stands",
                       self._untrusted())

    # ---- tables -----------------------------------------------------------------------

    def table(self) -> list[dict]:
        """One row per channel and candidate (the columns of compare.csv), each channel's rows
        best first (by CV where it ran, else PSIS-LOO)."""
        cands = {c["label"]: c for c in self.record["candidates"]}
        out = []
        for ch in self.record["channels"]:
            mods = {mod["label"]: mod for mod in ch["models"]}
            for lab in self.ranking(ch["channel"]):
                mod = mods[lab]
                row = {"channel": ch["channel"], "label": lab, "model": cands[lab]["model"],
                       "n_free": mod["n_free"],
                       "in_sample_rms_rel": mod["in_sample"]["rms_relative_error"]}
                cv = mod.get("cv")
                if cv:
                    row.update(cv_rank=cv["rank"], cv_rms_rel=cv["rms_relative_error"],
                               cv_delta=cv["delta"], cv_delta_se=cv["delta_se"],
                               cv_delta_over_noise=cv["delta_over_noise"])
                for kind in ("loo", "waic"):
                    b = mod.get(kind)
                    if b:
                        row.update({f"{kind}_rank": b["rank"], f"elpd_{kind}": b["elpd"],
                                    f"elpd_{kind}_se": b["se"], f"p_{kind}": b["p"],
                                    f"{kind}_elpd_diff": b["elpd_diff"], f"{kind}_dse": b["dse"],
                                    f"{kind}_weight": b["weight"]})
                if mod.get("loo"):
                    pk = mod["loo"]["pareto_k"]
                    row.update(pareto_k_max=pk["max"], pareto_k_bad_rows=pk["bad"]
                               + pk["very_bad"])
                out.append(row)
        return out

    def incidence_table(self) -> list[dict]:
        """One row per channel, candidate and incidence (compare_incidences.csv)."""
        out = []
        for ch in self.record["channels"]:
            for mod in ch["models"]:
                for k, inc in enumerate(ch["incidences"]):
                    row = {"channel": ch["channel"], "label": mod["label"], **inc,
                           "in_sample_rms_rel": mod["in_sample"]["per_incidence"][k]}
                    if mod.get("cv"):
                        row["cv_rms_rel"] = mod["cv"]["per_incidence"][k]
                    if mod.get("loo"):
                        row["pareto_k_max"] = mod["loo"]["pareto_k_per_incidence"][k]
                    out.append(row)
        return out

    def to_json(self) -> str:
        return json.dumps(thaw(self.record), indent=2, allow_nan=False, ensure_ascii=False) + "\n"

    def to_csv(self) -> str:
        return _csv(SUMMARY_COLUMNS, self.table())

    def incidences_csv(self) -> str:
        return _csv(INCIDENCE_COLUMNS, self.incidence_table())

    def summary(self, verbose: bool = True) -> str:
        """What ``fitlab compare -v`` prints: per channel the ranking table and the verdicts,
        then the warnings and the statuses that undermine the ranking (:attr:`ok`). Without
        ``verbose`` (``fitlab compare``): each channel's first verdict (CV, else PSIS-LOO, else
        WAIC) and one line that counts the warnings and names the statuses."""
        lines = []
        for ch in self.record["channels"]:
            noise = ch["noise_scale"]["relative"]
            lines.append(f"channel {ch['channel']}: {ch['rows_fitted']} rows fitted, "
                         f"{len(ch['incidences'])} incidences; per-row noise scale "
                         f"{_fmt(noise)} ({ch['noise_scale']['source']})")
            head = f"  {'model':<34} {'free':>4} {'in-sample':>9}"
            has_cv = "cv" in ch["ranking"]
            has_ic = "loo" in ch["ranking"]
            if has_cv:
                head += f" {'CV rank':>7} {'held-out':>8} {'ΔCV ± SE':>17}"
            if has_ic:
                head += (f" {'LOO rank':>8} {'ELPD_loo ± SE':>18} {'ΔELPD ± SE':>16} "
                         f"{'k>good':>6}")
            lines.append(head)
            mods = {mod["label"]: mod for mod in ch["models"]}
            for lab in self.ranking(ch["channel"]):
                mod = mods[lab]
                line = (f"  {lab[:34]:<34} {mod['n_free']:>4} "
                        f"{_fmt(mod['in_sample']['rms_relative_error'], 4):>9}")
                if has_cv:
                    cv = mod["cv"]
                    d = ("best" if cv["rank"] == 1 else
                         f"{_fmt(cv['delta'], 3)} ± {_fmt(cv['delta_se'], 2)}")
                    line += (f" {cv['rank']:>7} {_fmt(cv['rms_relative_error'], 4):>8} "
                             f"{d:>17}")
                if has_ic:
                    lo = mod["loo"]
                    d = "best" if lo["rank"] == 1 else f"{lo['elpd_diff']:.1f} ± {lo['dse']:.1f}"
                    pk = lo["pareto_k"]
                    line += (f" {lo['rank']:>8} {lo['elpd']:>10.1f} ± {lo['se']:<5.1f} {d:>16} "
                             f"{pk['bad'] + pk['very_bad']:>6}")
                lines.append(line)
            verdicts = [ch["verdict"][key]["text"] for key in ("cv", "loo", "waic")
                        if key in ch["verdict"]]
            lines += ["  " + text for text in (verdicts if verbose else verdicts[:1])]
            if ch["verdict"].get("agree") is False:
                lines.append("  CV and PSIS-LOO pick different winners (see compare.md, "
                             "'When the measures disagree').")
        untrusted = (self._untrusted() if all("statuses" in mod for ch in self.record["channels"]
                                              for mod in ch["models"]) else [])
        if verbose:
            lines += [f"warning: {w}" for w in self.record["warnings"]]
            lines += [f"status: {where}: {s.value}: {s.advice}" for where, s in untrusted]
        elif self.record["warnings"] or untrusted:
            n = len(self.record["warnings"])
            names = sorted({s.value for _, s in untrusted})
            lines.append(f"{n} warning{'' if n == 1 else 's'}"
                         + (f", statuses {', '.join(names)}" if names else "")
                         + " (-v prints them; compare.json keeps them)")
        return "\n".join(lines) + "\n"

    # ---- files ------------------------------------------------------------------------

    def save(self, out_dir, *, fits: bool = True) -> "CompareResult":
        """Write compare.json, compare.csv, compare_incidences.csv and (``fits``) each
        candidate's parameter file under fits/ into ``out_dir``, atomically; paths inside are
        relative to ``out_dir``. Returns the result with ``parameter_file`` entries set."""
        from fitlab.io.atomic import atomic_write_text
        from fitlab.io.files import path_for_record

        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise FitlabError(f"--out {out}: is a file, not a folder; give a folder")
        out.mkdir(parents=True, exist_ok=True)
        record = thaw(self.record)
        if fits and self.fits:
            (out / FITS_DIR).mkdir(exist_ok=True)
            for k, (cand, res) in enumerate(zip(record["candidates"], self.fits), start=1):
                rel = f"{FITS_DIR}/{k}_{_slug(cand['label'])}.json"
                res.save(out / rel)
                cand["parameter_file"] = rel
        if record["data"].get("path"):
            record["data"]["path"] = path_for_record(record["data"]["path"], out / TABLE_JSON)
        result = CompareResult.from_record(record, self.fits, self.measurement, str(out))
        atomic_write_text(out / TABLE_CSV, result.to_csv())
        atomic_write_text(out / INCIDENCE_CSV, result.incidences_csv())
        atomic_write_text(out / TABLE_JSON, result.to_json())
        return result

    def __repr__(self):
        return (f"CompareResult({', '.join(self.labels)}; winner "
                + ", ".join(f"{ch}: {self.winner(ch)}" for ch in self.channels) + ")")


def load_compare(path) -> CompareResult:
    """A comparison read back from its compare.json (data_formats/compare.md), without the
    candidates' fits (``fits`` is empty): its tables, summary and report page are the same."""
    from fitlab.errors import InputFileError
    from fitlab.io.files import read_bytes
    from fitlab.io.validate import check_schema, load_json

    hint = "give a compare.json written by `fitlab compare --out DIR`"
    rec = load_json(path, read_bytes(path), what="fitlab comparison", hint=hint)
    if not isinstance(rec, dict) or rec.get("schema") != SCHEMA:
        raise InputFileError(path, f"is not a fitlab comparison (no \"schema\": \"{SCHEMA}\")",
                             hint=hint)
    if rec.get("schema_version") not in READABLE_VERSIONS:
        raise InputFileError(path, f"has schema_version {rec.get('schema_version')!r}; this "
                             f"fitlab reads {READABLE_VERSIONS[0]} to {SCHEMA_VERSION}",
                             hint="rerun fitlab compare")
    check_schema(rec, "compare", path, hint=hint)  # data_formats/schemas/compare.schema.json
    return CompareResult.from_record(rec, (), None, str(Path(path).parent))
