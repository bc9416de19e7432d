"""Fit parameter files (JSON, schema ``fitlab-fit`` version 1, data_formats/fit_json.md) and
optional chain files (NPZ). Both are built in memory and written atomically.

Same inputs, options and seed give the same bytes: the files carry no wall-clock time (their
provenance is the fitlab and library versions, the data's SHA-256, the seed and the options);
run times are recorded only on request, in the one top-level ``timings_s`` field."""

from __future__ import annotations

import io
import json
import platform
from importlib import metadata as _md
from pathlib import Path

import numpy as np

import fitlab.api
from fitlab.models import get_model
from fitlab.version import __version__
from fitlab.errors import FitlabError, InputFileError
from fitlab.fitting.space import SCALE
from fitlab.io.atomic import atomic_open
from fitlab.io.conventions import CONVENTIONS
from fitlab.io.files import path_for_record, read_bytes, sha256_of

SCHEMA = "fitlab-fit"
SCHEMA_VERSION = 1


def software_versions() -> dict:
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for pkg in ("fitlab", "jax", "jaxlib", "jaxopt", "emcee", "nlopt", "numpy"):
        try:
            out[pkg] = _md.version(pkg)
        except _md.PackageNotFoundError:
            out[pkg] = __version__ if pkg == "fitlab" else None
    return out


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _channel_record(ch, model, fixed):
    space, ls, mc = ch["space"], ch["ls"], ch["mcmc"]
    params = {}
    for p in model.parameters:
        if p.name in fixed:
            params[p.name] = {"value": float(fixed[p.name]), "unit": p.unit, "fixed": True,
                              "bounds": [p.lower, p.upper]}
    for k, fp in enumerate(space.free):
        rec = {"value": float(ls.native[k]), "unit": fp.unit, "fixed": False,
               "bounds": [fp.lower, fp.upper], "stderr": _num(ls.stderr[k]),
               "at_bound": fp.name in ls.at_bound,
               "transform": "log" if fp.log else "linear"}
        if fp.name in ch.get("shared", ()):  # one value for every channel (fitting/joint.py)
            rec["shared"] = True
        if mc is not None:
            s = mc.samples_native[:, k]
            q = np.percentile(s, [2.5, 16, 50, 84, 97.5])
            rec["posterior"] = {"median": float(q[2]), "p16": float(q[1]), "p50": float(q[2]),
                                "p84": float(q[3]), "p2_5": float(q[0]), "p97_5": float(q[4]),
                                "mean": float(s.mean()), "std": float(s.std(ddof=1))}
        boot = (ch.get("bootstrap") or {}).get("parameters") or {}
        if fp.name in boot:  # block bootstrap over incidences (fitlab.fitting.resampling)
            rec["bootstrap"] = boot[fp.name]
        params[fp.name] = rec
    # Preserve the registry order, scale last.
    order = [p.name for p in model.parameters] + [n for n in space.names if n not in
                                                    model.parameter_names]
    params = {k: params[k] for k in order if k in params}
    rec = {
        "channel": ch["channel"],
        "parameters": params,
        "covariance": {"parameters": list(space.names),
                       "matrix": [[_num(v) for v in row] for row in ls.covariance],
                       "source": "least squares: noise² (JᵀJ)⁻¹ at the optimum, native units"},
        "statistics": ch["statistics"],
        "warnings": list(ch.get("warnings", [])),
        "solver": ls.solver,
        "global_search": ls.global_search,
        "starts": ls.starts,
        "starts_disagree": ls.disagreement,
        "mcmc": None,
    }
    if mc is not None:
        post = {**({"sampler": mc.sampler} if mc.sampler != "emcee" else {}),
                "nwalkers": mc.nwalkers, "nsteps": mc.nsteps, "burn_in": mc.burn, "thin": mc.thin,
                "coordinates": list(mc.names),
                "autocorrelation_time": [_num(t) for t in mc.tau],
                "acceptance_fraction": mc.acceptance, "effective_sample_size": mc.ess,
                "samples": int(mc.samples_native.shape[0]), "trustworthy": mc.trustworthy,
                "warnings": mc.warnings,
                "prior": "uniform over the bounds in each parameter's transform coordinate",
                "correlation": np.corrcoef(mc.samples_native.T).tolist()
                if mc.samples_native.shape[1] > 1 else [[1.0]]}
        rec["mcmc"] = post
    if "diagnostics" in ch:
        rec["diagnostics"] = ch["diagnostics"]
    if ch.get("goodness") is not None:  # fitlab.fitting.goodness
        rec["goodness"] = ch["goodness"]
    if ch.get("bootstrap") is not None:
        rec["bootstrap"] = {k: v for k, v in ch["bootstrap"].items() if k != "parameters"}
    if ch.get("aperture") is not None:  # only for data with an aperture (fitlab.fitting.aperture)
        rec["aperture"] = ch["aperture"]
    if ch.get("model_check") is not None:  # layered models (fitlab.fitting.model_check)
        rec["model_check"] = ch["model_check"]
    return rec


def run_timings(result, read_s: float, total_s: float) -> dict:
    """Wall-clock seconds of a fit, the ``timings_s`` field (recorded only on request: they
    differ from run to run): reading the data, least squares and MCMC (summed over the
    channels), and the whole command."""
    out = {"read": read_s,
           "least_squares": sum(ch["seconds_least_squares"] for ch in result["channels"])}
    runs = [ch["mcmc"] for ch in result["channels"] if ch["mcmc"] is not None]
    if runs:
        out["mcmc"] = sum(mc.seconds for mc in runs)
    boot = [ch.get("seconds_bootstrap") or 0.0 for ch in result["channels"]]
    if any(boot):
        out["bootstrap"] = sum(boot)
    check = [ch.get("seconds_model_check") or 0.0 for ch in result["channels"]]
    if any(check):
        out["model_check"] = sum(check)
    out["total"] = total_s
    return out


def build_record(result, measurement, *, subset_expr=None, timings=None,
                 illuminant: str | None = None) -> dict:
    """The parameter file's record. No wall-clock field unless ``timings`` (from
    :func:`run_timings`) is given: then it is the record's only varying field, ``timings_s``.
    A spectral fit (two or more fitted channels with wavelengths) gets the ``colour`` block,
    its colours under ``illuminant`` (None: D65; fitlab.export.spectral_colour)."""
    model = result["model"]
    m = measurement
    record = {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "model": {"name": model.name, "options": result["options"], "lobes": model.lobes,
                  "reference": model.reference},
        "conventions": CONVENTIONS,
        "loss": result["loss"],
        "seed": result["seed"],
        "notes": result["notes"],
        "data": {"path": m.path, "sha256": m.sha256, "rows": m.n,
                 "rows_fitted": int(np.sum(result["subset_rows"])), "fit_subset": subset_expr,
                 "file_quantity": m.file_quantity, "quantity": m.quantity,
                 "channels": list(m.channel_names),
                 # each channel's wavelength (nm), where the file gives them (spectral data)
                 **({"wavelength_nm": [float(w) for w in m.wavelength_nm]}
                    if m.wavelength_nm is not None else {}),
                 "metadata": m.metadata,
                 # how the file was read, where not by default (--angles, --accept,
                 # --quantity): the report reads it the same way
                 **({"read_options": dict(m.read_options)} if m.read_options else {})},
        "fits": [_channel_record(ch, model, result["fixed"]) for ch in result["channels"]],
        "software": software_versions(),
    }
    if result.get("joint") is not None:  # parameters shared across channels (fitting/joint.py)
        record["joint"] = result["joint"]
    if m.wavelength_nm is not None:  # a spectral fit's colours (data_formats/fit_json.md)
        from fitlab.export.spectral_colour import colour_block

        colour = colour_block(record, illuminant)
        if colour is not None:
            record["colour"] = colour
    if illuminant is not None and not (record.get("colour") or {}).get("parameters"):
        record["notes"] = list(record["notes"]) + [
            f"illuminant {illuminant}: not used (only a fit of two or more bands spanning "
            "380-780 nm has a colour block)"]
    if timings is not None:
        record["timings_s"] = timings
    return record


#: The date of every member of a chain file (the earliest a ZIP can hold): never the clock.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def chain_bytes(chains: dict) -> bytes:
    """The NPZ chain file (what ``np.savez_compressed`` writes, readable by ``np.load``) with
    every member dated :data:`ZIP_DATE`, so that equal arrays give equal bytes."""
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, array in chains.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(array), allow_pickle=False)
    return buf.getvalue()


def record_text(record) -> str:
    """A record as the parameter file's text (2-space indented JSON, no NaN)."""
    return json.dumps(record, indent=2, allow_nan=False) + "\n"


def write_fit(path, record: dict, chains: dict | None = None, chain_path=None) -> None:
    """Write the JSON (and the NPZ chain file) atomically; nothing is left on failure. With a
    chain, the record gains ``chain`` = {path, sha256} so that later tools (``fitlab report``)
    find it and can check it is this fit's chain."""
    blob = None
    if chains:
        blob = chain_bytes(chains)
        record = {**record, "chain": {"path": path_for_record(chain_path, path),
                                      "sha256": sha256_of(blob)}}
    if (record.get("data") or {}).get("path"):  # no absolute path of this machine
        record = {**record, "data": {**record["data"],
                                     "path": path_for_record(record["data"]["path"], path)}}
    bad = first_non_finite(record)
    if bad is not None:
        raise FitlabError(f"{path}: the fit produced a non-finite number at {bad}; nothing was "
                          "written. Check the data (values all 0 or huge, zero sigma) and the "
                          "model's options")
    text = record_text(record)
    if blob is not None:
        with atomic_open(chain_path, "wb") as fh:
            fh.write(blob)
    try:
        with atomic_open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
    except BaseException:
        if blob is not None:
            Path(chain_path).unlink(missing_ok=True)
        raise


def first_non_finite(obj, where: str = "") -> str | None:
    """The JSON path of the first NaN or infinite float in a record (None if there is none)."""
    if isinstance(obj, float):
        return None if np.isfinite(obj) else (where or "the top level")
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = ((f"[{i}]", v) for i, v in enumerate(obj))
    else:
        return None
    for k, v in items:
        key = k if str(k).startswith("[") else (f".{k}" if where else str(k))
        hit = first_non_finite(v, f"{where}{key}")
        if hit is not None:
            return hit
    return None


def read_fit(path) -> dict:
    """Read and validate a parameter file: JSON (UTF-8, bounded nesting), schema name and
    version, every field the tools read checked for type and finiteness
    (its JSON Schema, data_formats/schemas/fit.schema.json), and a model this fitlab knows."""
    from fitlab.io.fitfile import check_fit_record
    from fitlab.io.validate import load_json

    path = Path(path)
    hint = "give a file `fitlab fit` wrote (data_formats/fit_json.md)"
    data = load_json(path, read_bytes(path, folder_hint=hint), what="fitlab parameter file",
                     hint=hint)
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise InputFileError(path, f"is not a fitlab parameter file (schema is not {SCHEMA!r})",
                             column="schema")
    if data.get("schema_version") != SCHEMA_VERSION:
        from fitlab.io.validate import quote

        v = data.get("schema_version")
        shown = v if isinstance(v, int) and not isinstance(v, bool) else quote(v, 20)
        raise InputFileError(path, f"has schema_version {shown}; "
                             f"this fitlab reads version {SCHEMA_VERSION}", column="schema_version",
                             hint="refit with this fitlab version or upgrade fitlab")
    check_fit_record(path, data)
    try:
        model = get_model(data["model"]["name"])
    except (ValueError, KeyError, TypeError):
        raise InputFileError(path, "names a model this fitlab does not know",
                             column="model.name", hint="run `fitlab models`") from None
    try:
        fitlab.api.resolve_options(model, data["model"].get("options"))
    except ValueError as exc:
        raise InputFileError(path, f"field model.options: {exc}", hint=hint) from None
    # An option the file predates keeps the meaning the fit had (Option.absent: the thin
    # layer's compensation is "none" in a file written before it existed).
    given = data["model"].get("options") or {}
    old = {o.name: o.absent for o in model.options if o.absent is not None and o.name not in given}
    if old:
        data["model"]["options"] = {**given, **old}
    for k, fit in enumerate(data["fits"]):
        values = {n: p["value"] for n, p in fit["parameters"].items() if n != SCALE}
        try:
            fitlab.api.check_params(model, values)
        except ValueError as exc:
            raise InputFileError(path, f"field fits[{k}].parameters: {exc}", hint=hint) from None
    return data


def chains_payload(result) -> dict:
    out = {}
    for ch in result["channels"]:
        mc = ch["mcmc"]
        if mc is None:
            continue
        tag = ch["channel"]
        out[f"chain_{tag}"] = mc.chain_unit
        out[f"log_prob_{tag}"] = mc.log_prob
        out[f"samples_{tag}"] = mc.samples_native
        out[f"coordinates_{tag}"] = np.asarray(mc.names)
    if not out:
        raise FitlabError("--chain needs --mcmc: there is no chain to write")
    return out
