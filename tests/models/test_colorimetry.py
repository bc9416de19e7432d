"""fitlab.colorimetry: normalization conventions, known values, agreement with colour-science's
own integration, round trips, and refusals."""

from __future__ import annotations

import numpy as np
import pytest

from fitlab import colorimetry as C

GRID = np.arange(360.0, 831.0)  # the observer's own 1 nm grid
WL_4NM = np.arange(360.0, 1001.0, 4.0)  # like the RGL spectral files: 360-1000 nm, 4 nm steps


@pytest.mark.parametrize("illuminant", ["D65", "A", "E", "D50"])
def test_perfect_white_is_y1_and_rgb_white(illuminant):
    ones = np.ones(len(WL_4NM))
    xyz = C.spectral_to_xyz(ones, WL_4NM, illuminant)
    assert xyz[1] == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(xyz, C.illuminant_white_xyz(illuminant), rtol=1e-12)
    # the perfect white reflector maps to sRGB (1, 1, 1) under any illuminant (Bradford)
    np.testing.assert_allclose(C.spectral_to_linear_srgb(ones, WL_4NM, illuminant), 1.0,
                               rtol=1e-12)


def test_d65_white_matches_cie_chromaticity():
    import colour

    x, y, z = C.illuminant_white_xyz("D65")
    xy_cie = colour.CCS_ILLUMINANTS[C.OBSERVER]["D65"]  # (0.3127, 0.3290)
    np.testing.assert_allclose([x / (x + y + z), y / (x + y + z)], xy_cie, atol=2e-4)
    # without adaptation the integrated D65 white is sRGB white to 1e-4
    np.testing.assert_allclose(C.xyz_to_linear_srgb(C.illuminant_white_xyz("D65")), 1.0,
                               atol=2e-4)


def test_srgb_white_and_luminance_weights():
    np.testing.assert_allclose(C.linear_srgb_to_xyz([1.0, 1.0, 1.0]), [0.9505, 1.0, 1.089],
                               atol=1e-12)
    np.testing.assert_allclose(C.rgb_to_luminance(np.eye(3)), [0.2126, 0.7152, 0.0722],
                               atol=1e-12)
    rgb = np.random.default_rng(0).uniform(-0.2, 2.0, (50, 3))
    np.testing.assert_allclose(C.rgb_to_luminance(rgb), C.linear_srgb_to_xyz(rgb)[:, 1],
                               rtol=1e-13)


def test_monochromatic_line_555nm_is_the_luminance_peak():
    lines = np.eye(len(GRID))  # one spectrum per wavelength, a 1 nm line
    xyz = C.spectral_to_xyz(lines, GRID, "E")
    assert GRID[np.argmax(xyz[:, 1])] == 555.0
    _, cmf = C.observer_table()
    k = np.searchsorted(GRID, 555.0)
    np.testing.assert_allclose(xyz[k], cmf[k] / cmf[:, 1].sum(), rtol=1e-12)
    # CIE 1931 table at 555 nm: x̄ = 0.5121, ȳ = 1.0000, z̄ = 0.0057 → locus x = 0.3374, y = 0.6588
    assert xyz[k, 0] / xyz[k].sum() == pytest.approx(0.3374, abs=1e-4)
    assert xyz[k, 1] / xyz[k].sum() == pytest.approx(0.6588, abs=1e-4)


@pytest.mark.filterwarnings("ignore:Aligning")  # colour-science resamples the test spectrum
@pytest.mark.parametrize("illuminant", ["D65", "A"])
@pytest.mark.parametrize("step", [4.0, 5.0, 10.0])
def test_agrees_with_colour_integration(illuminant, step):
    import colour

    wl = np.arange(360.0, 1001.0, step)
    s = 0.3 + 0.5 * np.exp(-(((wl - 600.0) / 60.0) ** 2)) + 0.1 * np.sin(wl / 37.0)
    sd = colour.SpectralDistribution(dict(zip(wl, s)), interpolator=colour.LinearInterpolator)
    ref = colour.sd_to_XYZ(sd, cmfs=colour.MSDS_CMFS[C.OBSERVER],
                           illuminant=colour.SDS_ILLUMINANTS[illuminant],
                           method="Integration") / 100.0
    np.testing.assert_allclose(C.spectral_to_xyz(s, wl, illuminant), ref, rtol=1e-10)


def test_vectorized_over_leading_axes():
    rng = np.random.default_rng(1)
    s = rng.uniform(0, 1, (4, 5, len(WL_4NM)))
    xyz = C.spectral_to_xyz(s, WL_4NM)
    assert xyz.shape == (4, 5, 3)
    np.testing.assert_allclose(xyz[2, 3], C.spectral_to_xyz(s[2, 3], WL_4NM), rtol=1e-14)
    np.testing.assert_array_equal(C.xyz_to_y(xyz), xyz[..., 1])


def test_round_trips():
    rng = np.random.default_rng(2)
    xyz = rng.uniform(0.0, 1.2, (100, 3))
    np.testing.assert_allclose(C.linear_srgb_to_xyz(C.xyz_to_linear_srgb(xyz)), xyz,
                               rtol=1e-12, atol=1e-14)
    white = C.illuminant_white_xyz("A")
    back = C.linear_srgb_to_xyz(C.xyz_to_linear_srgb(xyz, white_xyz=white), white_xyz=white)
    np.testing.assert_allclose(back, xyz, rtol=1e-12, atol=1e-14)
    rgb = rng.uniform(0.0, 1.0, (100, 3))
    np.testing.assert_allclose(C.xyz_to_linear_srgb(C.linear_srgb_to_xyz(rgb)), rgb,
                               rtol=1e-12, atol=1e-14)


def test_inputs_are_not_modified():
    s = np.linspace(0.1, 0.9, len(WL_4NM))
    wl = WL_4NM.copy()
    s0, wl0 = s.copy(), wl.copy()
    C.spectral_to_linear_srgb(s, wl, "A")
    np.testing.assert_array_equal(s, s0)
    np.testing.assert_array_equal(wl, wl0)


def test_refusals():
    with pytest.raises(ValueError, match="380"):
        C.spectral_to_xyz(np.ones(16), np.arange(400.0, 720.0, 20.0))
    with pytest.raises(ValueError, match="increasing"):
        C.spectral_to_xyz(np.ones(3), [500.0, 400.0, 800.0])
    with pytest.raises(ValueError, match="unknown illuminant"):
        C.spectral_to_xyz(np.ones(len(WL_4NM)), WL_4NM, "D66")


def test_conversion_metadata_states_observer_and_illuminant():
    meta = C.conversion_metadata("spectra to CIE XYZ to linear sRGB", "D65")
    assert meta["observer"] == "CIE 1931 2 Degree Standard Observer"
    assert meta["illuminant"] == "D65"
    assert "BT.709" in meta["rgb_space"]
    assert "illuminant" not in C.conversion_metadata("linear sRGB to luminance Y", None)
