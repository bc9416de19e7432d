"""Spectral fits as colour: the per-band parameters of a fit whose channels are wavelengths,
reduced to CIE XYZ and linear sRGB for the parameter file's ``colour`` block and for every
export that takes RGB (data_formats/fit_json.md, "Colour of a spectral fit").

The colour maths is :mod:`fitlab.colorimetry`'s (CIE 1931 2° observer, a named illuminant,
D65 by default, Bradford to the sRGB white); this module decides what is reduced and how:

* A fit is **spectral** when two or more of its fitted channels carry a wavelength (the
  Measurement's ``wavelength_nm``, which the parameter file keeps as ``data.wavelength_nm``);
  the bands are taken in ascending wavelength.
* A parameter whose role is a colour (:data:`COLOUR_ROLES`: reflectances and albedos; the model
  says, ``Parameter.role``) is a spectrum over the bands: its XYZ (relative to the perfect
  white under the illuminant, Y = 1) and its linear sRGB (the perfect white maps to 1, 1, 1).
  Both are linear in the band values, so their standard errors follow from the bands'
  covariance (a joint fit's covariance across the bands, else the bands' own standard errors,
  independent fits being independent).
* Any other parameter (roughness, index, extinction, ...) with one value in every band (shared
  with ``--share``, fixed, or equal) keeps that value; one that differs between bands is
  reduced to its **luminance-weighted mean** Σ w_λ p_λ, w_λ the bands' weights in CIE Y (they
  sum to 1: the mean is the Y of the parameter's spectrum), one value for R, G and B. The
  colour such a parameter carries (a conductor's n, k) is lost, and exports say so.
* ``scale`` (relative data: the instrument's unknown factor per band) is no part of the
  material and is not reduced; a relative fit's colours are then relative to those factors,
  which the block notes.
* The bands must cover 380–780 nm (:data:`fitlab.colorimetry.REQUIRED_RANGE_NM`). A narrower
  spectral fit has no colour: its block says why (``parameters`` null, ``reason``), exports that
  take only RGB refuse it with that reason, and those that take spectra keep them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab import colorimetry

#: Parameter roles (fitlab.models.base.ROLES) whose per-band values are a colour.
COLOUR_ROLES = ("albedo",)
#: The block's ``reduction`` of a parameter: a colour, one value for every band, or the mean.
COLOUR = "colour"
ONE_VALUE = "one value"
LUMINANCE_MEAN = "luminance-weighted mean"
CONVERSION = ("per-band parameter spectra (piecewise linear between the bands) to CIE XYZ "
              "relative to the perfect white under the illuminant (Y = 1), then to linear sRGB "
              "(Bradford from the illuminant's white to the sRGB white)")
#: The channels of a reduced material.
RGB = ("R", "G", "B")


class Bands(NamedTuple):
    """A spectral fit's channels in ascending wavelength, with their wavelengths (nm)."""

    channels: tuple[str, ...]
    nm: np.ndarray

    def coverage_problem(self) -> str | None:
        """Why the bands cannot be reduced to colour (they do not span 380–780 nm), or None."""
        lo, hi = colorimetry.REQUIRED_RANGE_NM
        if self.nm[0] <= lo and self.nm[-1] >= hi:
            return None
        return (f"its {len(self.nm)} bands span {self.nm[0]:g}-{self.nm[-1]:g} nm, and colour "
                f"needs bands from {lo:g} nm or below to {hi:g} nm or above (where the CIE 1931 "
                "observer has its weight)")


def bands_of(wavelength_of: dict) -> Bands | None:
    """The bands of channels {name: wavelength in nm or None}: None unless there are two or
    more, each with a distinct positive wavelength."""
    if len(wavelength_of) < 2 or any(w is None for w in wavelength_of.values()):
        return None
    names = tuple(wavelength_of)
    nm = np.array([float(wavelength_of[c]) for c in names])
    if not np.all(np.isfinite(nm) & (nm > 0)) or len(set(nm.tolist())) != len(nm):
        return None
    order = np.argsort(nm)
    return Bands(tuple(names[i] for i in order), nm[order])


def wavelengths_of(names: tuple) -> np.ndarray | None:
    """Wavelengths in nm of channel names ``<λ>nm`` (two or more, all spectral), else None: the
    one place a wavelength is read from a channel's name (for materials given by name on the
    command line, and parameter files written before ``data.wavelength_nm``)."""
    if len(names) < 2 or not all(n.endswith("nm") for n in names):
        return None
    try:
        wl = np.array([float(n[:-2]) for n in names])
    except ValueError:
        return None
    return wl if np.all(np.isfinite(wl)) and np.all(wl > 0) else None


def record_wavelengths(record) -> dict:
    """{channel: wavelength in nm or None} of a parameter file's fits: from ``data.wavelength_nm``
    (one per ``data.channels``), else, for files written before it, from channel names
    ``<λ>nm`` (:func:`wavelengths_of`)."""
    data = record.get("data") or {}
    fitted = [f["channel"] for f in record["fits"]]
    listed = data.get("wavelength_nm")
    if listed is not None and len(listed) == len(data.get("channels") or ()):
        of = dict(zip(data["channels"], listed))
        return {c: of.get(c) for c in fitted}
    wl = wavelengths_of(tuple(fitted))
    return dict(zip(fitted, [None] * len(fitted) if wl is None else wl.tolist()))


def check_illuminant(illuminant: str | None) -> str:
    """``illuminant`` (None: the default, D65) if colour-science knows it; ValueError naming the
    choices otherwise."""
    name = colorimetry.DEFAULT_ILLUMINANT if illuminant is None else illuminant
    if not isinstance(name, str):
        raise ValueError(f"the illuminant must be a name such as D65, got {name!r}")
    colorimetry.illuminant_table(name)  # ValueError: unknown, with examples
    return name


# --------------------------------------------------------------------------------------------
# The reduction
# --------------------------------------------------------------------------------------------


def _stderr(weights: np.ndarray, cov: np.ndarray | None) -> list | None:
    """Standard errors of ``values @ weights`` (weights (bands, k)) from the bands' covariance."""
    if cov is None:
        return None
    var = np.einsum("ik,ij,jk->k", weights, cov, weights)
    return np.sqrt(np.maximum(var, 0.0)).tolist() if np.all(np.isfinite(var)) else None


def reduce_parameters(model, values: dict, bands: Bands, illuminant: str,
                      covariance=None) -> dict:
    """{parameter: its reduction} of a spectral material: ``values`` {parameter: values in
    band order}, ``covariance(name) -> (bands, bands) or None``. A colour gives ``xyz`` and
    ``linear_srgb`` (with ``xyz_stderr``, ``linear_srgb_stderr`` where the covariance is known),
    any other parameter its ``value`` (one value, or the luminance-weighted mean with the
    bands' ``range`` and its ``stderr``). Every entry names the parameter's ``role`` and its
    ``reduction``."""
    nm = bands.nm
    eye = np.eye(len(nm))
    to_xyz = colorimetry.spectral_to_xyz(eye, nm, illuminant)  # (bands, 3): linear maps
    to_rgb = colorimetry.spectral_to_linear_srgb(eye, nm, illuminant)
    out = {}
    for p in model.parameters:
        if p.name not in values:
            continue
        v = np.asarray(values[p.name], dtype=np.float64)
        cov = None if covariance is None else covariance(p.name)
        if p.role in COLOUR_ROLES:
            rec = {"role": p.role, "reduction": COLOUR,
                   "xyz": colorimetry.spectral_to_xyz(v, nm, illuminant).tolist(),
                   "linear_srgb": colorimetry.spectral_to_linear_srgb(v, nm, illuminant).tolist()}
            for key, w in (("xyz_stderr", to_xyz), ("linear_srgb_stderr", to_rgb)):
                s = _stderr(w, cov)
                if s is not None:
                    rec[key] = s
        elif np.all(v == v[0]):
            rec = {"role": p.role, "reduction": ONE_VALUE, "value": float(v[0])}
        else:
            mean = colorimetry.xyz_to_y(colorimetry.spectral_to_xyz(v, nm, illuminant))
            rec = {"role": p.role, "reduction": LUMINANCE_MEAN,
                   "value": float(np.clip(mean, v.min(), v.max())),
                   "range": [float(v.min()), float(v.max())]}
            s = _stderr(to_xyz[:, 1:2], cov)
            if s is not None:
                rec["stderr"] = s[0]
        out[p.name] = rec
    return out


def _record_covariance(record, bands: Bands):
    """covariance(name) of a parameter file: a joint fit's covariance of ``name[channel]`` over
    the bands, else the bands' own standard errors (independent fits); None where unknown."""
    fits = {f["channel"]: f for f in record["fits"]}
    joint = (record.get("joint") or {}).get("covariance")

    def covariance(name):
        if joint:
            from fitlab.fitting.joint import coordinate_name

            names = list(joint["parameters"])
            # a shared parameter is one coordinate for every band (fully correlated)
            coords = [name if name in names else coordinate_name(name, c)
                      for c in bands.channels]
            if all(c in names for c in coords):
                idx = [names.index(c) for c in coords]
                m = np.array([[joint["matrix"][i][j] for j in idx] for i in idx], dtype=object)
                return None if np.any(m == None) else m.astype(np.float64)  # noqa: E711
        s = [fits[c]["parameters"][name].get("stderr") for c in bands.channels]
        return None if any(x is None for x in s) else np.diag(np.square(s))

    return covariance


def colour_block(record, illuminant: str | None = None) -> dict | None:
    """The parameter file's ``colour`` block of a record (data_formats/fit_json.md, "Colour of a
    spectral fit"), or None when its fits are not spectral. ``illuminant``: a colour-science
    illuminant name (None: D65)."""
    from fitlab.fitting.space import SCALE
    from fitlab.models import get_model

    bands = bands_of(record_wavelengths(record))
    if bands is None:
        return None
    block = {"channels": list(bands.channels), "wavelength_nm": bands.nm.tolist()}
    problem = bands.coverage_problem()
    if problem is not None:
        return {**block, "parameters": None,
                "reason": f"no colour: {problem}; exports that take only RGB refuse this fit, "
                          "exports that take spectra (Mitsuba 3 spectra, OpenMATERIAL) keep them"}
    illuminant = check_illuminant(illuminant)
    fits = {f["channel"]: f["parameters"] for f in record["fits"]}
    values = {name: [fits[c][name]["value"] for c in bands.channels]
              for name in fits[bands.channels[0]] if name != SCALE}
    model = get_model(record["model"]["name"])
    block.update(colorimetry.conversion_metadata(CONVERSION, illuminant))
    block["parameters"] = reduce_parameters(model, values, bands, illuminant,
                                            _record_covariance(record, bands))
    if (record.get("data") or {}).get("quantity") == "relative":
        block["note"] = ("relative data: each band has its own unknown scale (not reduced), so "
                         "these colours are relative to the instrument's per-band factors")
    return block


# --------------------------------------------------------------------------------------------
# Materials for exports that take RGB
# --------------------------------------------------------------------------------------------


def reduced_channels(model, channels: dict, bands: Bands,
                     illuminant: str) -> tuple[dict, list[str]]:
    """{R: params, G: params, B: params} of a spectral material's ``channels`` {band: params}:
    a colour's linear sRGB components clipped to the parameter's bounds, every other parameter
    its one value or luminance-weighted mean; and sentences saying what was reduced how (and
    what was clipped or lost)."""
    values = {name: [channels[c][name] for c in bands.channels]
              for name in channels[bands.channels[0]]}
    out = {c: {} for c in RGB}
    notes = []
    bounds = {p.name: (p.lower, p.upper) for p in model.parameters}
    for name, rec in reduce_parameters(model, values, bands, illuminant).items():
        if rec["reduction"] == COLOUR:
            rgb = np.asarray(rec["linear_srgb"])
            lo, hi = bounds[name]
            clipped = np.clip(rgb, lo, hi)
            for c, x in zip(RGB, clipped):
                out[c][name] = float(x)
            notes.append(f"{name}: its spectrum as linear sRGB ("
                         + ", ".join(f"{x:.4g}" for x in rgb) + ")"
                         + ("" if np.array_equal(clipped, rgb) else
                            f", clipped to [{lo:g}, {hi:g}] (out of gamut)"))
            continue
        for c in RGB:
            out[c][name] = rec["value"]
        if rec["reduction"] == LUMINANCE_MEAN:
            lo, hi = rec["range"]
            notes.append(f"{name}: {lo:.4g} to {hi:.4g} over the bands, reduced to its "
                         f"luminance-weighted mean {rec['value']:.4g} for every colour channel "
                         f"(the colour it carries is lost; fit with --share {name} for one "
                         "value, or export one band with --channel)")
    return out, notes


__all__ = ["Bands", "COLOUR_ROLES", "RGB", "bands_of", "check_illuminant",
           "colour_block", "record_wavelengths", "reduce_parameters", "reduced_channels",
           "wavelengths_of"]
