"""Colour conversions, in one place: spectra → CIE XYZ → Y and linear sRGB, tristimulus XYZ ↔
linear sRGB, and RGB → luminance. Every reader that converts colour calls these functions, and
the metadata of a converted measurement states the observer and illuminant
(:func:`conversion_metadata`).

Choices (colour-science supplies the tables and matrices):

* **Observer**: CIE 1931 2° standard observer, colour-science's 1 nm table over 360–830 nm
  (``colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]``).
* **Illuminant**: CIE D65 by default, configurable by name (any key of
  ``colour.SDS_ILLUMINANTS``: "A", "E", "D50", ...), aligned to the 1 nm observer grid with
  colour-science's ``align`` (its default interpolation, constant extension at the ends).
* **Spectra** are reflectance-like quantities (a BSDF value per wavelength). They are taken as
  piecewise linear between their wavelengths, held constant beyond the first and last one, and
  integrated on the 1 nm grid of the observer:

      XYZ = Σ_λ s(λ) S(λ) x̄ȳz̄(λ) / Σ_λ S(λ) ȳ(λ)

  so a spectrum equal to 1 everywhere (a perfect white reflector) has Y = 1 under any
  illuminant; a BSDF spectrum in 1/sr gives X, Y, Z in 1/sr. This is colour-science's
  ``sd_to_XYZ`` ("Integration" method) with a linear interpolator, divided by 100. Spectra must
  span at least 380–780 nm (:data:`REQUIRED_RANGE_NM`), where the observer has its weight.
* **Linear sRGB**: ITU-R BT.709 primaries and D65 white, no transfer function (values are
  linear, as a BSDF needs). XYZ → RGB uses the inverse of colour-science's sRGB RGB → XYZ matrix
  (IEC 61966-2-1), so the two directions are exact inverses and
  **luminance Y = 0.2126 R + 0.7152 G + 0.0722 B** is that matrix's middle row.
* **White mapping**: spectra converted to sRGB are adapted (Bradford) from the perfect white
  under the chosen illuminant to the sRGB white, so the perfect white reflector maps to
  RGB (1, 1, 1) whichever illuminant is chosen (a tiny adaptation for D65 itself, whose
  integrated white differs from sRGB's rounded white by about 1e-4). Tristimulus XYZ given
  directly are taken as relative to the sRGB (D65) white unless a white is given.
* Out-of-gamut colours give negative RGB components; these functions return them as they are.
  Callers that need a non-negative BSDF clip (and say so).
"""

from __future__ import annotations

import functools

import numpy as np

OBSERVER = "CIE 1931 2 Degree Standard Observer"
DEFAULT_ILLUMINANT = "D65"
RGB_SPACE = "linear sRGB (ITU-R BT.709 primaries, D65 white, no transfer function)"
#: spectra converted to colour must cover this range (nm)
REQUIRED_RANGE_NM = (380.0, 780.0)


def _colour():
    import colour  # noqa: PLC0415 — colour-science is slow to import; load it on first use

    return colour


# --------------------------------------------------------------------------------------------
# Tables (cached, read-only)
# --------------------------------------------------------------------------------------------


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@functools.lru_cache(maxsize=None)
def observer_table() -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths (n,) in nm at 1 nm steps, x̄ȳz̄ (n, 3)) of the CIE 1931 2° observer."""
    cmfs = _colour().MSDS_CMFS[OBSERVER]
    return _frozen(cmfs.wavelengths), _frozen(cmfs.values)


@functools.lru_cache(maxsize=None)
def illuminant_table(illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """The relative spectral power of ``illuminant`` on the observer's 1 nm grid."""
    colour = _colour()
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"unknown illuminant {illuminant!r}; use one of colour-science's "
                         f"SDS_ILLUMINANTS, e.g. D65, D50, A, E")
    sd = colour.SDS_ILLUMINANTS[illuminant].copy().align(colour.MSDS_CMFS[OBSERVER].shape)
    return _frozen(sd.values)


@functools.lru_cache(maxsize=None)
def _weights_on_grid(illuminant: str) -> np.ndarray:
    """S(λ) x̄ȳz̄(λ) / Σ S ȳ on the 1 nm grid, (n, 3)."""
    _, cmf = observer_table()
    s = illuminant_table(illuminant)
    w = s[:, None] * cmf
    return _frozen(w / w[:, 1].sum())


def _interpolation_matrix(x_new: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Matrix R (len(x_new), len(x)) with R @ y = np.interp(x_new, x, y) for every y."""
    n = len(x)
    if n == 1:
        return np.ones((len(x_new), 1))
    j = np.clip(np.searchsorted(x, x_new, side="right") - 1, 0, n - 2)
    t = np.clip((x_new - x[j]) / (x[j + 1] - x[j]), 0.0, 1.0)
    r = np.zeros((len(x_new), n))
    rows = np.arange(len(x_new))
    r[rows, j] = 1.0 - t
    r[rows, j + 1] += t
    return r


def xyz_weights(wavelength_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """Weights W (n_λ, 3) with XYZ = spectrum @ W for spectra sampled at ``wavelength_nm``
    (strictly increasing, covering :data:`REQUIRED_RANGE_NM`); see the module docstring."""
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths must be a strictly increasing list of at least two values")
    lo, hi = REQUIRED_RANGE_NM
    if wl[0] > lo or wl[-1] < hi:
        raise ValueError(f"the spectrum covers {wl[0]:g}–{wl[-1]:g} nm but colour conversion "
                         f"needs at least {lo:g}–{hi:g} nm (where the CIE 1931 observer is "
                         "significant)")
    grid, _ = observer_table()
    return _interpolation_matrix(grid, wl).T @ _weights_on_grid(illuminant)


# --------------------------------------------------------------------------------------------
# Conversions
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _srgb_matrices() -> tuple[np.ndarray, np.ndarray]:
    m = np.asarray(_colour().RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, dtype=np.float64)
    return _frozen(m), _frozen(np.linalg.inv(m))


def srgb_white_xyz() -> np.ndarray:
    """XYZ of linear sRGB (1, 1, 1): the sRGB D65 white with Y = 1."""
    return _srgb_matrices()[0].sum(axis=1)


def illuminant_white_xyz(illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """XYZ of the perfect white reflector under ``illuminant`` (Y = 1) by the integration above."""
    return _weights_on_grid(illuminant).sum(axis=0)


def spectral_to_xyz(values, wavelength_nm, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """CIE 1931 XYZ (…, 3) of spectra ``values`` (…, n_λ) sampled at ``wavelength_nm``."""
    values = np.asarray(values, dtype=np.float64)
    return values @ xyz_weights(wavelength_nm, illuminant)


def xyz_to_y(xyz) -> np.ndarray:
    """Luminance Y of tristimulus values (…, 3)."""
    return np.asarray(xyz, dtype=np.float64)[..., 1]


def _bradford(source_white, target_white) -> np.ndarray:
    from colour.adaptation import matrix_chromatic_adaptation_VonKries

    return np.asarray(matrix_chromatic_adaptation_VonKries(
        np.asarray(source_white, dtype=np.float64), np.asarray(target_white, dtype=np.float64),
        transform="Bradford"), dtype=np.float64)


def xyz_to_linear_srgb(xyz, white_xyz=None) -> np.ndarray:
    """Linear sRGB (…, 3) of XYZ (…, 3). With ``white_xyz`` (the XYZ of the white the data are
    relative to), colours are first adapted (Bradford) from that white to the sRGB white."""
    xyz = np.asarray(xyz, dtype=np.float64)
    to_rgb = _srgb_matrices()[1]
    if white_xyz is not None:
        to_rgb = to_rgb @ _bradford(white_xyz, srgb_white_xyz())
    return xyz @ to_rgb.T


def linear_srgb_to_xyz(rgb, white_xyz=None) -> np.ndarray:
    """XYZ (…, 3) of linear sRGB (…, 3); the exact inverse of :func:`xyz_to_linear_srgb`."""
    rgb = np.asarray(rgb, dtype=np.float64)
    to_xyz = _srgb_matrices()[0]
    if white_xyz is not None:
        to_xyz = _bradford(srgb_white_xyz(), white_xyz) @ to_xyz
    return rgb @ to_xyz.T


def rgb_to_luminance(rgb) -> np.ndarray:
    """Luminance Y of linear Rec. 709 / sRGB values (…, 3): 0.2126 R + 0.7152 G + 0.0722 B."""
    return np.asarray(rgb, dtype=np.float64) @ _srgb_matrices()[0][1]


def spectral_to_linear_srgb(values, wavelength_nm,
                            illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
    """Linear sRGB (…, 3) of spectra (…, n_λ): XYZ under ``illuminant``, adapted so that the
    perfect white reflector maps to (1, 1, 1)."""
    return xyz_to_linear_srgb(spectral_to_xyz(values, wavelength_nm, illuminant),
                              white_xyz=illuminant_white_xyz(illuminant))


def conversion_metadata(conversion: str, illuminant: str | None = DEFAULT_ILLUMINANT) -> dict:
    """Metadata entries (one-word keys, one-line values) describing a colour conversion."""
    meta = {"colour_conversion": conversion, "observer": OBSERVER}
    if illuminant is not None:
        meta["illuminant"] = illuminant
    if "rgb" in conversion.lower():
        meta["rgb_space"] = RGB_SPACE
    return meta
