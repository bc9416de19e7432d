"""What tools read out of a fit parameter file (data_formats/fit_json.md) once it has been read
and validated (``fitlab.export.paramfile.read_fit``): the fitted values per channel, the
channels a tabulating writer takes, and the summary ``fitlab info`` prints."""

from __future__ import annotations

from pathlib import Path

from fitlab.errors import FitlabError
from fitlab.fitting.space import SCALE
from fitlab.io.files import read_bytes
from fitlab.io.validate import check_schema, quote

#: A parameter file names its schema near the top; enough bytes to find it there.
SNIFF_BYTES = 256
SCHEMA_TAG = b'"fitlab-fit"'


#: fitlab's JSON Schema of a parameter file (data_formats/schemas/fit.schema.json): every field
#: the tools read, its type, range and length (channels at most 1024, parameters at most 256).
SCHEMA_NAME = "fit"


def check_fit_record(path, record) -> dict:
    """``record`` (a parsed parameter file) checked against its JSON Schema (``SCHEMA_NAME``)
    and then for what a schema cannot say (distinct channels; covariance names among the
    parameters and its matrix square; lengths that must agree), or an InputFileError naming
    ``path`` and the field."""
    from fitlab.errors import InputFileError

    hint = "give a file `fitlab fit` wrote (data_formats/fit_json.md)"
    check_schema(record, SCHEMA_NAME, path, hint=hint)
    channels = [f["channel"] for f in record["fits"]]
    if len(set(channels)) != len(channels):
        raise InputFileError(path, "field fits lists a channel twice", hint=hint)
    for k, fit in enumerate(record["fits"]):
        cov = fit.get("covariance")
        if not cov:
            continue
        names, matrix = cov["parameters"], cov["matrix"]
        unknown = [n for n in names if n not in fit["parameters"]]
        if unknown:
            raise InputFileError(path, f"field fits[{k}].covariance.parameters names "
                                 f"{quote_names(unknown)}, not parameters of the fit", hint=hint)
        if len(matrix) != len(names) or any(len(row) != len(names) for row in matrix):
            raise InputFileError(path, f"field fits[{k}].covariance.matrix is not "
                                 f"{len(names)} x {len(names)}", hint=hint)
    data = record["data"]
    if "wavelength_nm" in data and len(data["wavelength_nm"]) != len(data.get("channels") or ()):
        raise InputFileError(path, f"field data.wavelength_nm has {len(data['wavelength_nm'])} "
                             f"entries for {len(data.get('channels') or ())} data.channels",
                             hint=hint)
    colour = record.get("colour")
    if colour and colour.get("illuminant") is not None:
        from fitlab.colorimetry import illuminant_table

        try:
            illuminant_table(colour["illuminant"])
        except ValueError as exc:
            raise InputFileError(path, f"field colour.illuminant: {exc}", hint=hint) from None
    joint = record.get("joint")
    if joint:
        n = len(joint["parameters"])
        for key in ("value", "stderr"):
            if key in joint and len(joint[key]) != n:
                raise InputFileError(path, f"field joint.{key} has {len(joint[key])} entries "
                                     f"for {n} joint.parameters", hint=hint)
        cov = joint.get("covariance")
        if cov and (len(cov["matrix"]) != len(cov["parameters"])
                    or any(len(row) != len(cov["parameters"]) for row in cov["matrix"])):
            raise InputFileError(path, "field joint.covariance.matrix is not "
                                 f"{len(cov['parameters'])} x {len(cov['parameters'])}", hint=hint)
    return record


def quote_names(names) -> str:
    return ", ".join(quote(n, 30) for n in names[:5])


def is_fit_file(path) -> bool:
    """Whether ``path`` is a ``*.json`` file that calls itself a fitlab parameter file."""
    p = Path(path)
    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    return SCHEMA_TAG in read_bytes(p, limit=SNIFF_BYTES)


def fit_parameters(record: dict, *, source="the parameter file", channel: str | None = None,
                   scale: bool = True) -> dict[str, dict[str, float]]:
    """{channel: {parameter: fitted value}} of a parameter file's fits, in file order.

    ``channel`` keeps that channel only (a FitlabError naming ``source`` and its channels if it
    has none of that name). ``scale=False`` leaves out the ``scale`` of a relative fit, which
    is not part of the model."""
    out = {f["channel"]: {k: v["value"] for k, v in f["parameters"].items()
                          if scale or k != SCALE}
           for f in record["fits"]}
    if channel is not None:
        if channel not in out:
            raise FitlabError(f"--channel {channel}: {source} has channels {', '.join(out)}")
        out = {channel: out[channel]}
    return out


def tabulation_channels(record: dict, *, source, channel: str | None, layout: tuple,
                        single: str, file_kind: str):
    """The model parameters of a fit for a writer whose files hold one channel (under the name
    ``single``) or the channels ``layout`` (e.g. X, Y, Z), and the notes to pass on.

    Returns ({channel: parameters}, notes); a fit's ``scale`` is left out (noted): the file
    holds the absolute model f. A spectral fit goes to an R, G, B layout as its reduction to
    linear sRGB (fitlab.export.spectral_colour; noted)."""
    fits = fit_parameters(record, source=source, channel=channel)
    notes = []
    relative = any(SCALE in p for p in fits.values())
    if len(fits) == 1:
        fits = {single: next(iter(fits.values()))}
    elif set(fits) != set(layout):
        spectral = _spectral_rgb(record, fits, layout, source, file_kind)
        if spectral is None:
            raise FitlabError(f"{source} has channels {', '.join(fits)}; a {file_kind} file "
                              f"holds one channel or {', '.join(layout)}: choose one with "
                              "--channel")
        fits, notes = spectral
    else:
        fits = {c: fits[c] for c in layout}
    if relative:
        notes.append(f"relative fit: the '{SCALE}' parameter is not applied; the file holds the "
                     "absolute model f")
        fits = {c: {k: v for k, v in p.items() if k != SCALE} for c, p in fits.items()}
    return fits, notes


def _spectral_rgb(record: dict, fits: dict, layout: tuple, source, file_kind: str):
    """(R, G, B channels, notes) of a spectral fit for a writer whose layout is R, G, B: its
    reduction to linear sRGB under the colour block's illuminant
    (fitlab.export.spectral_colour); None when the fit is not spectral or the layout is not RGB;
    a FitlabError when its bands do not span the visible range."""
    from fitlab.export.spectral_colour import (RGB, bands_of, check_illuminant,
                                               record_wavelengths, reduced_channels)
    from fitlab.models import get_model

    wl = record_wavelengths(record)
    bands = bands_of({c: wl.get(c) for c in fits})
    if bands is None or tuple(layout) != RGB:
        return None
    problem = bands.coverage_problem()
    if problem is not None:
        raise FitlabError(f"{source}: a {file_kind} file holds R, G, B, and this spectral fit has "
                          f"no colour: {problem}; choose one band with --channel")
    illuminant = check_illuminant((record.get("colour") or {}).get("illuminant"))
    plain = {c: {k: v for k, v in p.items() if k != SCALE} for c, p in fits.items()}
    channels, notes = reduced_channels(get_model(record["model"]["name"]), plain, bands,
                                       illuminant)
    return channels, [f"spectral fit ({len(bands.nm)} bands, {bands.nm[0]:g}-{bands.nm[-1]:g} "
                      f"nm) reduced to linear sRGB under {illuminant} (CIE 1931 2 degree "
                      "observer)"] + notes


def describe_fit(record: dict) -> dict:
    """What ``fitlab info`` shows of a parameter file."""
    return {"format": "fit-json", "format_description": "fitlab parameter file",
            "spec": "data_formats/fit_json.md", "schema_version": record["schema_version"],
            "model": record["model"], "loss": record["loss"], "data": record["data"]["path"],
            "channels": [f["channel"] for f in record["fits"]],
            "parameters": fit_parameters(record),
            "mcmc": [bool(f["mcmc"]) for f in record["fits"]]}


__all__ = ["SCHEMA_NAME", "check_fit_record", "is_fit_file", "fit_parameters", "tabulation_channels", "describe_fit"]
