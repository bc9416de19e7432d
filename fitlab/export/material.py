"""What a renderer export starts from: a *material*, i.e. a registry model, its options and its
parameter values per colour channel, taken from a fit's parameter file or given directly.

A fit of relative data carries a ``scale`` (the instrument's unknown factor); a material is the
absolute model f, so the scale is left out (as ``fitlab convert`` does). A fit of one channel
(``Y``, ``Visible``, a band) is grey, a fit of ``R``, ``G``, ``B`` gives each parameter as an
RGB triple, a fit of two or more wavelengths (channels ``450nm``, ``550nm``, … from the
``wavelength_nm`` column) a spectrum where a format takes one, and its reduction to linear sRGB
where a format takes only RGB (fitlab/export/spectral_colour.py); other channel sets (``X,Y,Z``)
are refused with what to do (``channel=`` picks one).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError
from fitlab.export.spectral_colour import record_wavelengths, wavelengths_of

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
    #: of a spectral material, the wavelength (nm) of each channel, in channel order, where its
    #: source states them (a fit's ``data.wavelength_nm``); None: read from names ``<λ>nm``
    wavelength_nm: tuple | None = None
    #: the illuminant a fit's colour block states (its reduction to RGB uses it unless told
    #: otherwise); None: D65
    illuminant: str | None = None
    #: of a spectral material reduced to R, G, B (:func:`rgb_material`), what the reduction did
    #: (conversion, observer, illuminant, bands, notes), for the exported file to state
    colour: dict | None = None

    @property
    def rgb(self) -> bool:
        return tuple(self.channels) == RGB

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        """The wavelengths of a spectral material (two or more channels, each with a
        wavelength: the stated ones, else names ``<λ>nm``), else None."""
        if self.wavelength_nm is not None and len(self.channels) > 1:
            return np.asarray(self.wavelength_nm, dtype=float)
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


def _check_channels(channels: dict, source: str, wavelength_nm=None) -> dict:
    """``channels`` in a material's order: one, R, G, B, or bands by ascending wavelength
    (``wavelength_nm`` {channel: nm} where the source states them, else names ``<λ>nm``)."""
    names = tuple(channels)
    if len(names) == 1 or names == RGB:
        return channels
    if set(names) == set(RGB):
        return {c: channels[c] for c in RGB}
    stated = None if wavelength_nm is None else [wavelength_nm.get(c) for c in names]
    wl = np.array(stated, dtype=float) if stated is not None and None not in stated \
        else wavelengths_of(names)
    if wl is not None:
        return {names[i]: channels[names[i]] for i in np.argsort(wl, kind="stable")}
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
    stated, illuminant = None, None
    if record is not None:
        stated = {c: w for c, w in record_wavelengths(record).items() if c in params}
        illuminant = (record.get("colour") or {}).get("illuminant")
    channels = _check_channels(params, source, stated)
    wavelength_nm = None
    if stated and len(channels) > 1 and all(stated.get(c) is not None for c in channels):
        wavelength_nm = tuple(float(stated[c]) for c in channels)
    return Material(result.model, dict(result.options), channels, source, data, wavelength_nm,
                    illuminant)


def material_bands(material: Material):
    """The bands (:class:`fitlab.export.spectral_colour.Bands`) of a spectral material, else
    None."""
    from fitlab.export.spectral_colour import bands_of

    wl = material.wavelengths_nm
    return None if wl is None else bands_of(dict(zip(material.channels, wl.tolist())))


def rgb_material(material: Material, illuminant: str | None = None, *,
                 what: str = "this export") -> tuple[Material, dict]:
    """The R, G, B material of a spectral ``material`` (fitlab.export.spectral_colour
    .reduced_channels under ``illuminant``, else the one its fit states, else D65) and what the
    conversion did (``{"colour": {colour_conversion, observer, illuminant, rgb_space, bands,
    notes}}``); :class:`ExportError` naming ``what`` when its bands do not span 380-780 nm.
    A material that is not spectral comes back as it is, with ``{}``."""
    from fitlab import colorimetry
    from fitlab.export.spectral_colour import CONVERSION, check_illuminant, reduced_channels
    from fitlab.models import get_model

    bands = material_bands(material)
    if bands is None:
        return material, {}
    problem = bands.coverage_problem()
    if problem is not None:
        raise ExportError(f"{material.source}: {what} takes linear RGB, and this spectral "
                          f"material has no colour: {problem}; export one band with --channel, "
                          "or a format that takes spectra (--to mitsuba, --to openmaterial)")
    try:
        ill = check_illuminant(illuminant or material.illuminant)
    except ValueError as exc:
        raise ExportError(f"--illuminant: {exc}") from None
    channels, notes = reduced_channels(get_model(material.model), material.channels, bands, ill)
    colour = {**colorimetry.conversion_metadata(CONVERSION, ill),
              "bands": f"{len(bands.nm)} bands, {bands.nm[0]:g}-{bands.nm[-1]:g} nm",
              "notes": notes}
    return (material._replace(channels=channels, wavelength_nm=None, colour=colour),
            {"colour": colour})


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


__all__ = ["RGB", "ExportError", "Material", "material_bands", "material_from_fit",
           "material_from_model", "rgb_material", "wavelengths_of"]
