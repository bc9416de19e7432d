"""Registry models and fits tabulated as MERL BRDF database binary files (90 × 90 × 180 bins of
θh, θd, φd per R, G, B channel): each bin holds the model's f at the bin centre, bins whose
directions fall below the horizon the 'no value' marker. The bytes are
:func:`fitlab.io.merl.merl_bytes`; spec: data_formats/merl_binary.md."""

from __future__ import annotations

import numpy as np

from fitlab.models import get_model
from fitlab.api import eval_bsdf, resolve_options
from fitlab.errors import FitlabError
from fitlab.export.paramfile import read_fit
from fitlab.io.atomic import atomic_open
from fitlab.io.fitfile import tabulation_channels
from fitlab.io.merl import (CHANNELS, DIMS, INVALID_RAW, N_BINS, SCALES, bin_directions,
                            merl_bytes)


def _per_channel(params) -> list:
    """Three parameter dicts (R, G, B) from one dict for all, {R, G, B: dict} or a sequence."""
    if isinstance(params, dict) and params and all(isinstance(v, dict) for v in params.values()):
        if set(params) != set(CHANNELS):
            raise FitlabError(f"a MERL file holds the channels {', '.join(CHANNELS)}; got "
                              f"{', '.join(params)}")
        return [params[c] for c in CHANNELS]
    per_channel = [params] * 3 if isinstance(params, dict) else list(params)
    if len(per_channel) != 3:
        raise ValueError("params must be one dict or three dicts (R, G, B)")
    return per_channel


def tabulate_model(model: str, params, options: dict | None = None) -> np.ndarray:
    """Raw MERL table (3, 90, 90, 180) of a registry model at the bin centres: f / scale per
    channel, INVALID_RAW where wi or wo is below the horizon. ``params`` is one dict for all
    three channels, three dicts (R, G, B) or {R, G, B: dict}."""
    per_channel = _per_channel(params)
    i, j, k = np.meshgrid(*(np.arange(n) for n in DIMS), indexing="ij")
    wi, wo = bin_directions(i.ravel(), j.ravel(), k.ravel())
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    raw = np.empty((3, N_BINS))
    for c, p in enumerate(per_channel):
        f = np.asarray(eval_bsdf(model, p, wi, wo, options), dtype=np.float64)
        if not np.all(np.isfinite(f[above])):
            raise ValueError(f"model {model!r} gave non-finite values for channel {CHANNELS[c]}")
        raw[c] = np.where(above, f / SCALES[c], INVALID_RAW)
    return raw.reshape(3, *DIMS)


def _check_model(model: str):
    """The registry model, if a MERL file can hold it (it reflects and is isotropic)."""
    m = get_model(model)
    if not m.capabilities.reflection:
        raise FitlabError(f"model {m.name!r} does not reflect ({m.lobes}); a MERL file holds a "
                          "BRDF (reflection only): choose a reflecting model or write Zemax BTDF")
    if not m.capabilities.isotropic:
        raise FitlabError(f"model {m.name!r} is anisotropic; a MERL file holds an isotropic BRDF "
                          "(its bins have no half-vector azimuth φh): write a Zemax file "
                          "(.bsdf, Asymmetrical) instead")
    return m


def write_merl(path, model: str, params, options: dict | None = None) -> dict:
    """Tabulate a registry model as a MERL .binary file (atomically). A MERL file holds a BRDF:
    a model that does not reflect is refused, the transmission of one that also transmits is
    left out (noted). Returns a summary (channels, bins with a value, f range, notes)."""
    m = _check_model(model)
    options = resolve_options(m, options)
    raw = tabulate_model(m.name, params, options)
    with atomic_open(path, "wb") as fh:
        fh.write(merl_bytes(raw))
    valid = raw >= 0
    f = raw * np.asarray(SCALES).reshape(3, 1, 1, 1)
    notes = []
    if m.capabilities.transmission:
        notes.append(f"model {m.name!r} also transmits light; a MERL file holds its reflection "
                     "(BRDF) only")
    return {"path": str(path), "model": m.name, "channels": list(CHANNELS),
            "grid": dict(zip(("theta_h", "theta_d", "phi_d"), DIMS)),
            "bins_with_value": int(valid[0].sum()),
            "f_range": [float(f[valid].min()), float(f[valid].max())], "notes": notes}


def write_merl_from_fit(path, fit_path, *, channel: str | None = None) -> dict:
    """Tabulate a fit (parameter file, data_formats/fit_json.md) as a MERL file: an R, G, B fit
    channel by channel, a one-channel fit (or ``channel``) in all three. A relative fit's
    ``scale`` is not applied: the file holds the absolute model f."""
    rec = read_fit(fit_path)
    fits, notes = tabulation_channels(rec, source=fit_path, channel=channel, layout=CHANNELS,
                                      single="Y", file_kind="MERL")
    params = fits["Y"] if "Y" in fits else fits
    try:
        summary = write_merl(path, rec["model"]["name"], params, rec["model"].get("options") or {})
    except ValueError as exc:
        raise FitlabError(f"{fit_path}: {exc}") from None
    summary["notes"] = notes + summary["notes"]
    return summary


def complete_merl(path, job) -> dict:
    """A completion (fitlab.export.filling.Job) as a MERL file's bytes (written by
    fitlab.export.completion with its record): every bin centre above the horizon holds the
    data's reading at that direction (data read from a MERL file at stride 1 have one in every
    valid bin) or the fit's value; bins below it the 'no value' marker. A one-channel
    measurement fills R, G and B alike."""
    from pathlib import Path

    from fitlab.export.filling import Filled, check_absolute, fill

    m = job.m
    check_absolute(m, "MERL")
    _check_model(job.fit.model)
    names = tuple(m.channel_names)
    if names != CHANNELS and len(names) != 1:
        raise FitlabError(f"{Path(m.path).name} has channels {', '.join(names)}; a MERL file "
                          f"holds {', '.join(CHANNELS)} or one channel (written to all three): "
                          "complete it as a measurement CSV (OUT.csv)")
    i, j, k = np.meshgrid(*(np.arange(n) for n in DIMS), indexing="ij")
    wi, wo = bin_directions(i.ravel(), j.ravel(), k.ravel())
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    raw = np.full((3, N_BINS), INVALID_RAW)
    parts = []
    for c, name in enumerate(CHANNELS):
        if c < len(names):
            parts.append(fill(job, np.full(int(above.sum()), c), wi[above], wo[above]))
        raw[c, above] = parts[-1].value / SCALES[c]
    filled = Filled(*(np.concatenate(a) for a in zip(*parts)))
    record = Path(str(path) + ".completion.json").name
    return {"content": merl_bytes(raw.reshape(3, *DIMS)), "filled": filled,
            "marks": f"none in the file (a MERL table has no per-value flag): {record}",
            "grid": dict(zip(("theta_h", "theta_d", "phi_d"), DIMS)),
            "grid_source": "MERL's bins", "notes": [] if len(names) == 3 else
            [f"channel {names[0]} written to R, G and B"]}


__all__ = ["tabulate_model", "write_merl", "write_merl_from_fit", "complete_merl"]
