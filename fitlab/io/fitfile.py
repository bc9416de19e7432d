"""What tools read out of a fit parameter file (data_formats/fit_json.md) once it has been read
and validated (``fitlab.export.paramfile.read_fit``): the fitted values per channel, the
channels a tabulating writer takes, and the summary ``fitlab info`` prints."""

from __future__ import annotations

from pathlib import Path

from fitlab.errors import FitlabError
from fitlab.fit.space import SCALE
from fitlab.io.files import read_bytes

#: A parameter file names its schema near the top; enough bytes to find it there.
SNIFF_BYTES = 256
SCHEMA_TAG = b'"fitlab-fit"'


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
    holds the absolute model f."""
    fits = fit_parameters(record, source=source, channel=channel)
    if len(fits) == 1:
        fits = {single: next(iter(fits.values()))}
    elif set(fits) != set(layout):
        raise FitlabError(f"{source} has channels {', '.join(fits)}; a {file_kind} file holds "
                          f"one channel or {', '.join(layout)}: choose one with --channel")
    else:
        fits = {c: fits[c] for c in layout}
    notes = []
    if any(SCALE in p for p in fits.values()):
        notes.append(f"relative fit: the '{SCALE}' parameter is not applied; the file holds the "
                     "absolute model f")
        fits = {c: {k: v for k, v in p.items() if k != SCALE} for c, p in fits.items()}
    return fits, notes


def describe_fit(record: dict) -> dict:
    """What ``fitlab info`` shows of a parameter file."""
    return {"format": "fit-json", "format_description": "fitlab parameter file",
            "spec": "data_formats/fit_json.md", "schema_version": record["schema_version"],
            "model": record["model"], "loss": record["loss"], "data": record["data"]["path"],
            "channels": [f["channel"] for f in record["fits"]],
            "parameters": fit_parameters(record),
            "mcmc": [bool(f["mcmc"]) for f in record["fits"]]}


__all__ = ["is_fit_file", "fit_parameters", "tabulation_channels", "describe_fit"]
