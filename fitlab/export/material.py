"""What a renderer export starts from: a *material*, i.e. a registry model, its options and its
parameter values per colour channel, taken from a fit's parameter file or given directly.

A fit of relative data carries a ``scale`` (the instrument's unknown factor); a material is the
absolute model f, so the scale is left out (as ``fitlab convert`` does). A fit of one channel
(``Y``, ``Visible``, a band) is grey, a fit of ``R``, ``G``, ``B`` gives each parameter as an
RGB triple, a fit of two or more wavelengths (channels ``450nm``, ``550nm``, … from the
``wavelength_nm`` column) a spectrum where a format takes one; other channel sets (``X,Y,Z``)
are refused with what to do (``channel=`` picks one).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError

#: The channels of an RGB material, in order.
RGB = ("R", "G", "B")


class ExportError(FitlabError):
    """A material that an export format cannot represent; the message says what and what to do."""


class Material(NamedTuple):
    """A registry model with its options and, per channel, its parameters (absolute f)."""

    model: str
    options: dict
    #: {channel: {parameter: value}}; one channel (grey) or R, G, B
    channels: dict
    #: where it came from, for messages and the exported file's provenance ("FILE.json", "model")
    source: str = "model"
    #: of a fit, what its parameter file says of the data (data_formats/fit_json.md ``data``:
    #: ``path``, ``quantity``, ``metadata``, …) as plain values, for a format whose header
    #: carries the data's provenance (fitlab/export/openmaterial.py); None for a model
    data: dict | None = None

    @property
    def rgb(self) -> bool:
        return tuple(self.channels) == RGB

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        """The wavelengths of a spectral material (channels ``<λ>nm``), else None."""
        return wavelengths_of(tuple(self.channels))

    def values(self, name: str) -> np.ndarray:
        """Parameter ``name`` per channel: an RGB triple (a grey material repeats its one
        value), or one value per wavelength of a spectral material. A material of many texels
        (fitlab/export/maps.py: its values arrays over the texels) gives (channels, texels)."""
        vals = [np.asarray(self.channels[c][name], dtype=float) for c in self.channels]
        return np.asarray(vals * 3 if len(vals) == 1 else vals, dtype=float)

    def scalar(self, name: str, *, what: str) -> float:
        """Parameter ``name`` where a format needs one value for every channel; refused (with
        ``what`` the format's name) when the channels differ."""
        v = self.values(name)
        if np.any(np.ptp(v, axis=0) > 1e-12 * np.maximum(1.0, np.max(np.abs(v), axis=0))):
            at = lambda x: np.ravel(x)[np.argmax(np.ravel(np.ptp(v, axis=0)))]  # noqa: E731
            raise ExportError(
                f"{what} takes one value of {name!r} for every colour channel, but this material "
                f"has {', '.join(f'{c}={at(self.channels[c][name]):.6g}' for c in self.channels)}"
                "; fit the channels with that parameter shared (fitlab fit --share "
                f"{name}), or export one channel with --channel")
        return float(v[0]) if v.ndim == 1 else v[0]


def wavelengths_of(names: tuple) -> np.ndarray | None:
    """Wavelengths in nm of channel names ``<λ>nm`` (two or more, all spectral), else None."""
    if len(names) < 2 or not all(n.endswith("nm") for n in names):
        return None
    try:
        wl = np.array([float(n[:-2]) for n in names])
    except ValueError:
        return None
    return wl if np.all(np.isfinite(wl)) and np.all(wl > 0) else None


def _check_channels(channels: dict, source: str) -> dict:
    names = tuple(channels)
    if len(names) == 1 or names == RGB:
        return channels
    if set(names) == set(RGB):
        return {c: channels[c] for c in RGB}
    wl = wavelengths_of(names)
    if wl is not None:
        return {names[i]: channels[names[i]] for i in np.argsort(wl)}
    raise ExportError(f"{source}: channels {', '.join(names)}: renderers take one channel (grey), "
                      "R, G, B or a spectrum (channels <λ>nm); export one of them with "
                      "--channel")


def material_from_fit(result, channel: str | None = None) -> Material:
    """The material of a :class:`fitlab.FitResult` (``channel``: only that one, as grey)."""
    from fitlab.fitting.space import SCALE

    source = result.path or "fit"
    params = {c: {k: v for k, v in p.items() if k != SCALE}
              for c, p in result.parameters.items()}
    if channel is not None:
        if channel not in params:
            raise ExportError(f"{source}: no channel {channel!r}; channels: "
                              f"{', '.join(params)}")
        params = {channel: params[channel]}
    record = getattr(result, "record", None)
    data = None if record is None else _plain(record.get("data") or {})
    return Material(result.model, dict(result.options), _check_channels(params, source),
                    source, data)


def _plain(value):
    """A read-only record (mapping proxies, tuples: fitlab.fitting.result) as dicts and lists."""
    if hasattr(value, "items"):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def material_from_model(model: str, channels: dict, options: dict | None = None) -> Material:
    """The material of registry ``model`` with ``channels`` = {channel: params} (checked) and
    ``options`` (defaults filled in)."""
    from fitlab.models import get_model
    from fitlab.api import check_params, resolve_options

    try:
        m = get_model(model)
        opts = resolve_options(m, options)
        for params in channels.values():
            check_params(m, params)
    except ValueError as exc:
        raise ExportError(str(exc)) from None
    return Material(m.name, opts, _check_channels(dict(channels), "--model"), "model")


__all__ = ["RGB", "ExportError", "Material", "material_from_fit", "material_from_model",
           "wavelengths_of"]
