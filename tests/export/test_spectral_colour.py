"""Spectral fits as colour (issue 37 item 3; fitlab/export/spectral_colour.py,
data_formats/fit_json.md "Colour of a spectral fit"): a known spectrum reduced as colour-science
reduces it, a spectral fit's parameter file carrying its colour block and every RGB export using
it, and a fit whose bands do not span the visible range (no colour, RGB exports refused)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab import colorimetry
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.export import spectral_colour as S
from fitlab.export.material import ExportError
from fitlab.fitting.result import FitResult, thaw
from fitlab.io.directions import degrees_to_direction
from fitlab.io.measurement import Measurement

#: colour-science says so when it resamples a test spectrum or an illuminant onto its 1 nm grid
pytestmark = pytest.mark.filterwarnings("ignore:Aligning")

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
BANDS = np.arange(380.0, 781.0, 50.0)  # nine bands, 380-780 nm
PATCH = "orange"  # a saturated ColorChecker patch (N. Ohta's spectra in colour-science)
#: XYZ: fitlab against colour-science's own integration (sd_to_XYZ), float64 sums of the same
#: tables: they agree to rounding
TOLERANCE = 1e-10
#: linear sRGB: IEC 61966-2-1 rounds both of its matrices to 4 decimals; colour-science's
#: XYZ_to_RGB uses the rounded XYZ -> RGB matrix and the xy white (0.3127, 0.3290), fitlab the
#: exact inverse of the RGB -> XYZ matrix and its row sums (so RGB -> XYZ -> RGB is exact,
#: fitlab/colorimetry.py): the two differ by up to 1e-4 of the value
SRGB_TOLERANCE = 2e-4


def _patch(name=PATCH, bands=BANDS) -> np.ndarray:
    import colour

    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"][name]
    return np.array([sd[w] for w in bands])


def _colour_science(values, bands, illuminant):
    """colour-science's own XYZ (÷100) and linear sRGB of a spectrum sampled at ``bands``,
    linear between them: sd_to_XYZ, then XYZ_to_RGB with Bradford from the illuminant's
    perfect white and no transfer function."""
    import colour

    sd = colour.SpectralDistribution(dict(zip(bands, values)),
                                     interpolator=colour.LinearInterpolator)
    kw = {"cmfs": colour.MSDS_CMFS[colorimetry.OBSERVER],
          "illuminant": colour.SDS_ILLUMINANTS[illuminant], "method": "Integration"}
    xyz = colour.sd_to_XYZ(sd, **kw) / 100.0
    white = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(bands, np.ones(len(bands)))),
                                                         interpolator=colour.LinearInterpolator),
                             **kw) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], colour.XYZ_to_xy(white),
                            chromatic_adaptation_transform="Bradford", apply_cctf_encoding=False)
    return xyz, rgb


@pytest.mark.parametrize("illuminant", ["D65", "A"])
def test_colourchecker_patch_reduces_as_colour_science_does(illuminant):
    """A ColorChecker reflectance sampled at the bands: fitlab's colour block equals
    colour-science's conversion of the same samples; a parameter that is no colour gets its
    luminance-weighted mean (the Y of its spectrum, by colour-science too)."""
    albedo = _patch()
    n = np.linspace(1.3, 1.7, len(BANDS))
    bands = S.bands_of({f"{w:g}nm": w for w in BANDS[::-1]})  # any order in, ascending out
    assert bands.channels[0] == "380nm" and bands.coverage_problem() is None
    sd_err = np.full(len(BANDS), 0.01)
    red = S.reduce_parameters(fitlab.get_model("lambertian+rough_conductor"),
                              {"albedo": albedo, "alpha": np.full(len(BANDS), 0.2), "n": n},
                              bands, illuminant, covariance=lambda name: np.diag(sd_err ** 2))
    xyz, rgb = _colour_science(albedo, BANDS, illuminant)
    a = red["albedo"]
    assert a["role"] == "albedo" and a["reduction"] == "colour"
    np.testing.assert_allclose(a["xyz"], xyz, rtol=0, atol=TOLERANCE)
    np.testing.assert_allclose(a["linear_srgb"], rgb, rtol=0, atol=SRGB_TOLERANCE)
    assert rgb[0] > 2 * rgb[1] > 0  # orange: red over green over blue
    # standard errors: the linear map's rows, one band at a time (independent bands)
    basis = [_colour_science(np.eye(len(BANDS))[j], BANDS, illuminant)
             for j in range(len(BANDS))]
    for k, key in enumerate(("xyz_stderr", "linear_srgb_stderr")):
        rows = np.array([b[k] for b in basis])
        np.testing.assert_allclose(a[key], 0.01 * np.sqrt((rows ** 2).sum(0)),
                                   rtol=1e-9 if k == 0 else 1e-3)
    assert red["alpha"] == {"role": "roughness", "reduction": "one value", "value": 0.2}
    y = _colour_science(n, BANDS, illuminant)[0][1]
    assert red["n"]["reduction"] == "luminance-weighted mean" and red["n"]["role"] == "index"
    assert red["n"]["value"] == pytest.approx(y, abs=TOLERANCE)
    assert red["n"]["range"] == [1.3, 1.7]


def test_grey_spectrum_is_grey_and_white_is_one():
    bands = S.bands_of(dict(zip(map(str, BANDS), BANDS)))
    for level in (0.0, 0.35, 1.0):
        red = S.reduce_parameters(fitlab.get_model("lambertian"),
                                  {"albedo": np.full(len(BANDS), level)}, bands, "D50")
        np.testing.assert_allclose(red["albedo"]["linear_srgb"], level, atol=1e-12)
        assert red["albedo"]["xyz"][1] == pytest.approx(level, abs=1e-12)


# --------------------------------------------------------------------------------------------
# A spectral fit, end to end
# --------------------------------------------------------------------------------------------


def spectral_lambertian(albedo, bands=BANDS, seed=5) -> Measurement:
    """Nine bands of a Lambertian surface (f = albedo/π), 2% noise, one channel per band with
    its wavelength (as the spectral readers give them)."""
    rows = [(ti, 0.0, to, po) for ti in (0.0, 45.0) for to in range(5, 86, 10)
            for po in (0.0, 180.0)]
    a = np.tile(np.asarray(rows, dtype=float), (len(bands), 1))
    chan = np.repeat(np.arange(len(bands)), len(rows))
    f = np.asarray(albedo)[chan] / np.pi
    sigma = 0.02 * f + 1e-4
    value = f + sigma * np.random.default_rng(seed).standard_normal(f.shape)
    wi, wo = degrees_to_direction(a[:, 0], a[:, 1]), degrees_to_direction(a[:, 2], a[:, 3])
    return Measurement(
        path="<synthetic spectral>", sha256="0" * 64, theta_i=a[:, 0], phi_i=a[:, 1],
        theta_o=a[:, 2], phi_o=a[:, 3], wi=wi, wo=wo, value=value, sigma=sigma, channel=chan,
        channel_names=tuple(f"{w:g}nm" for w in bands), wavelength_nm=np.asarray(bands, float),
        quantity="bsdf", file_quantity="bsdf", metadata={}, lines=np.arange(len(f)))


@pytest.fixture(scope="module")
def spectral_fit(tmp_path_factory):
    m = spectral_lambertian(_patch())
    fit = fitlab.fit(m, "lambertian", bootstrap=0, starts=1)
    return fit.save(tmp_path_factory.mktemp("spectral") / "orange.json")


def test_spectral_fit_carries_its_colour_and_every_rgb_export_uses_it(spectral_fit, tmp_path):
    r = spectral_fit
    rec = r.record
    assert list(rec["data"]["wavelength_nm"]) == BANDS.tolist()
    c = r.colour
    assert c["channels"] == [f"{w:g}nm" for w in BANDS] and c["wavelength_nm"] == BANDS.tolist()
    assert (c["illuminant"], c["observer"]) == ("D65", colorimetry.OBSERVER)
    assert "BT.709" in c["rgb_space"]
    fitted = np.array([r.parameters[ch]["albedo"] for ch in c["channels"]])
    np.testing.assert_allclose(fitted, _patch(), rtol=0.05)  # the fit found the patch
    a = c["parameters"]["albedo"]
    np.testing.assert_array_equal(a["linear_srgb"],
                                  colorimetry.spectral_to_linear_srgb(fitted, BANDS))
    np.testing.assert_allclose(a["linear_srgb"], _colour_science(fitted, BANDS, "D65")[1],
                               atol=SRGB_TOLERANCE)
    assert len(a["linear_srgb_stderr"]) == 3 and 0 < max(a["linear_srgb_stderr"]) < 0.01
    assert fitlab.load_fit(r.path).colour == c  # read back as written (schema-checked)

    rgb = np.clip(a["linear_srgb"], 0.0, 1.0)
    made = fitlab.export_material(r.path, "mitsuba", tmp_path / "m.json")
    assert made.value["type"] == "diffuse" and made.value["reflectance"]["type"] == "rgb"
    np.testing.assert_array_equal(made.value["reflectance"]["value"], rgb)
    assert made.conversion["colour"]["illuminant"] == "D65"
    assert any(note.startswith("albedo: its spectrum as linear sRGB")
               for note in made.conversion["colour"]["notes"])
    plugin = fitlab.export_material(r, "mitsuba-plugin").value
    np.testing.assert_array_equal([plugin[f"{ch}__albedo"] for ch in "RGB"], rgb)
    # MERL (fitlab convert FIT.json OUT.binary) tabulates the same R, G, B
    from fitlab.io.fitfile import tabulation_channels

    fits, notes = tabulation_channels(thaw(rec), source="f.json", channel=None,
                                      layout=("R", "G", "B"), single="Y", file_kind="MERL")
    np.testing.assert_array_equal([fits[ch]["albedo"] for ch in "RGB"], rgb)
    assert "reduced to linear sRGB under D65" in notes[0]
    # another illuminant: the export's, from the same bands
    under_a = fitlab.export_material(r, "mitsuba", illuminant="A")
    np.testing.assert_array_equal(
        under_a.value["reflectance"]["value"],
        np.clip(colorimetry.spectral_to_linear_srgb(fitted, BANDS, "A"), 0, 1))
    assert under_a.conversion["colour"]["illuminant"] == "A"
    with pytest.raises(ExportError, match="unknown illuminant"):
        fitlab.export_material(r, "mitsuba", illuminant="D66")
    # OpenMATERIAL keeps the bands
    from fitlab.export.material import material_from_fit
    from fitlab.export.renderers import EXPORTERS, spectral_for

    material = material_from_fit(r)
    assert material.wavelength_nm == tuple(BANDS)
    assert spectral_for(EXPORTERS["openmaterial"], material) == (material, {})


def test_bands_short_of_the_visible_range_have_no_colour(spectral_fit, tmp_path):
    """Drop the 380 and 780 nm bands: the block says why there is no colour, RGB-only exports
    refuse with that reason, Mitsuba keeps spectra (with a warning)."""
    rec = thaw(spectral_fit.record)
    rec["fits"] = [f for f in rec["fits"] if f["channel"] not in ("380nm", "780nm")]
    block = S.colour_block(rec)
    assert block["parameters"] is None and block["wavelength_nm"][0] == 430.0
    assert "span 430-730 nm" in block["reason"] and "380 nm" in block["reason"]
    narrow = FitResult.from_record({**rec, "colour": block}, path="narrow.json")
    for to in ("gltf", "mitsuba-plugin"):
        with pytest.raises(ExportError, match="no colour: its 7 bands span 430-730 nm"):
            fitlab.export_material(narrow, to, tmp_path / f"x.{'gltf' if to == 'gltf' else 'xml'}")
        assert not list(tmp_path.iterdir())
    made = fitlab.export_material(narrow, "mitsuba")
    assert made.value["reflectance"]["type"] == "spectrum"
    assert any("integrates over the bands given only" in w for w in made.conversion["warnings"])
    from fitlab.io.fitfile import tabulation_channels

    with pytest.raises(FitlabError, match="MERL file holds R, G, B, and this spectral fit has no"):
        tabulation_channels(rec, source="f.json", channel=None, layout=("R", "G", "B"),
                            single="Y", file_kind="MERL")
    # one band is no spectrum: no block
    one = {**rec, "fits": rec["fits"][:1]}
    assert S.colour_block(one) is None


def test_hostile_colour_fields_are_refused(spectral_fit, tmp_path):
    rec = thaw(spectral_fit.record)
    for change, field in [
            (lambda r: r["data"]["wavelength_nm"].pop(), "data.wavelength_nm has 8 entries"),
            (lambda r: r["colour"].update(illuminant="D66"), "colour.illuminant"),
            (lambda r: r["colour"]["parameters"]["albedo"].update(linear_srgb=[1, 2]),
             "colour.parameters.albedo.linear_srgb"),
            (lambda r: r["data"]["wavelength_nm"].__setitem__(0, -5.0), "data.wavelength_nm")]:
        bad = json.loads(json.dumps(rec))
        change(bad)
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(InputFileError, match=field.replace(".", r"\.")):
            fitlab.load_fit(path)


def test_cli_illuminant_option(capsys):
    assert main(["fit", str(EXAMPLES / "measurement_spectral_visible.csv"), "--model",
                 "lambertian", "--illuminant", "D66"]) == 2
    err = capsys.readouterr().err
    assert "--illuminant: unknown illuminant 'D66'" in err
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    assert "--illuminant NAME" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    assert "--illuminant NAME" in capsys.readouterr().out


@pytest.mark.slow
def test_cli_shared_geometry_fit_of_the_visible_example(tmp_path, capsys):
    """The bundled nine-band example, one width shared by the bands (--share alpha; n per
    band): the file's colour is the orange patch's, n its luminance-weighted mean, and glTF and
    Mitsuba take them. (The global scan of this 19-coordinate problem alone lands in a basin at
    alpha = 0.7 with n at its bound: the run starts near the truth too.)"""
    out = tmp_path / "orange.json"
    assert main(["fit", str(EXAMPLES / "measurement_spectral_visible.csv"), "--model",
                 "lambertian+rough_conductor", "--share", "alpha", "--fix", "k=0",
                 "--start", "alpha=0.3", "--start", "n=1.4", "--bootstrap", "0", "--starts",
                 "2", "--out", str(out)]) == 0
    assert "colour under D65" in capsys.readouterr().err
    rec = json.loads(out.read_text())
    a = rec["colour"]["parameters"]["albedo"]
    np.testing.assert_allclose(a["linear_srgb"], _colour_science(_patch(), BANDS, "D65")[1],
                               atol=0.03)
    assert rec["colour"]["parameters"]["alpha"]["reduction"] == "one value"
    assert rec["colour"]["parameters"]["n"]["reduction"] == "luminance-weighted mean"
    assert len(a["linear_srgb_stderr"]) == 3  # from the joint covariance
    assert main(["export", str(out), "--out", str(tmp_path / "o.gltf")]) == 0
    err = capsys.readouterr().err
    assert "reduced to linear sRGB under D65" in err and "n: " in err
    doc = json.loads((tmp_path / "o.gltf").read_text())
    base = doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"]
    assert base[0] > base[1] > base[2]  # orange
    assert main(["export", str(out), "--out", str(tmp_path / "o.xml")]) == 0


@pytest.mark.slow
def test_cli_fit_of_the_bundled_narrow_scan_states_no_colour(tmp_path, capsys):
    out = tmp_path / "scan.json"
    assert main(["fit", str(EXAMPLES / "spectral_scan.csv"), "--quantity", "radiance_factor",
                 "--model", "lambertian+rough_conductor", "--share", "alpha", "--bootstrap",
                 "0", "--starts", "2", "--out", str(out)]) == 0
    assert "colour: no colour: its 3 bands span 450-650 nm" in capsys.readouterr().err
    rec = json.loads(out.read_text())
    assert rec["colour"]["parameters"] is None
    assert main(["export", str(out), "--out", str(tmp_path / "s.gltf")]) == 2
    assert "no colour" in capsys.readouterr().err
