"""MERL BRDF binary: index maps on known angles, half/difference coordinates, a synthetic file
written from registry models and read back (bin centres, float64), the lookup at arbitrary
directions, broken files, and the CLI (info, convert, fit) through the format registry.

No MERL data are used or stored: every file here is written by fitlab.export.merl.write_merl."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.export import merl as merl_out
from fitlab.io import merl
from fitlab.io.formats import detect_format, read_any
from fitlab.io.measurement import read_measurement

ROOT = Path(__file__).resolve().parents[2]
CONDUCTOR = [{"alpha": 0.08, "n": 0.2, "k": 3.0}, {"alpha": 0.15, "n": 1.0, "k": 2.6},
             {"alpha": 0.3, "n": 1.5, "k": 2.0}]
ALBEDO = (0.3, 0.5, 0.7)


@pytest.fixture(scope="module")
def conductor_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "conductor.binary"
    merl_out.write_merl(path, "rough_conductor", CONDUCTOR)
    return path


@pytest.fixture(scope="module")
def lambert_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "lambert.binary"
    merl_out.write_merl(path, "lambertian", [{"albedo": a} for a in ALBEDO])
    return path


def _sph(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


# --------------------------------------------------------------------------------------------
# Index maps
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("theta_h_deg, index", [
    (0.0, 0), (-1.0, 0), (0.01, 0), (0.0112, 1), (1.0, 9), (10.0, 30), (40.0, 60), (89.9, 89),
    (90.0, 89), (120.0, 89)])
def test_theta_half_index(theta_h_deg, index):
    # i = floor(sqrt(θh_deg · 90)): 1° → sqrt(90) = 9.49; 10° → 30; 0.0112° → 1.004
    assert merl.theta_half_index(np.radians(theta_h_deg)) == index


@pytest.mark.parametrize("theta_d_deg, index", [(0.0, 0), (0.99, 0), (1.0, 1), (45.5, 45),
                                                (89.99, 89), (90.0, 89), (95.0, 89)])
def test_theta_diff_index(theta_d_deg, index):
    assert merl.theta_diff_index(np.radians(theta_d_deg)) == index


@pytest.mark.parametrize("phi_d_deg, index", [(0.0, 0), (10.5, 10), (179.5, 179), (180.0, 179),
                                              (-10.0, 170), (-179.5, 0), (-0.5, 179)])
def test_phi_diff_index_folds_by_reciprocity(phi_d_deg, index):
    assert merl.phi_diff_index(np.radians(phi_d_deg)) == index


def test_bin_centres_invert_the_index_maps():
    i, j, k = np.arange(90), np.arange(90), np.arange(180)
    assert np.array_equal(merl.theta_half_index(merl.theta_half_centre(i)), i)
    assert np.array_equal(merl.theta_diff_index(merl.theta_diff_centre(j)), j)
    assert np.array_equal(merl.phi_diff_index(merl.phi_diff_centre(k)), k)
    # the documented centres: (i + 1/2)^2 / 90 degrees, j + 1/2, k + 1/2
    np.testing.assert_allclose(np.degrees(merl.theta_half_centre([0, 9, 89])),
                               [0.25 / 90, 90.25 / 90, 89.5 ** 2 / 90])
    assert merl.flat_index(1, 2, 3) == 3 + 2 * 180 + 1 * 180 * 90


def test_half_diff_on_known_configurations():
    # mirror pair: h = n, d = wi
    th, ph, td, pd = merl.half_diff_from_directions(_sph(30, 0), _sph(30, 180))
    np.testing.assert_allclose([th, td, pd], [0, np.radians(30), 0], atol=1e-12)
    # retro-reflection: h = wi, θd = 0
    th, ph, td, pd = merl.half_diff_from_directions(_sph(40, 70), _sph(40, 70))
    np.testing.assert_allclose([th, ph, td], [np.radians(40), np.radians(70), 0], atol=1e-7)
    # wi = (30°, 0°), wo = (30°, 90°): h ∝ (1/2, 1/2, √3), θh = 22.208°, φh = 45°,
    # θd = half the angle between them = arccos(cos²30°)/2 = 20.705°
    th, ph, td, pd = merl.half_diff_from_directions(_sph(30, 0), _sph(30, 90))
    np.testing.assert_allclose(np.degrees([th, ph, td]),
                               [np.degrees(np.arccos(np.sqrt(3) / np.sqrt(3.5))), 45.0,
                                np.degrees(np.arccos(0.75)) / 2], rtol=1e-12)
    # d = R_y(-θh) R_z(-45°) wi = (0, -0.354, 0.935): φd = -90°, which lies on a φd bin edge
    assert np.degrees(pd) == pytest.approx(-90.0)
    assert merl.lookup_indices(_sph(30, 0), _sph(30, 90))[:2] == (44, 20)  # sqrt(22.208·90) = 44.7


def test_half_diff_round_trip_and_theta_d_is_half_angle():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(2, 2000, 3))
    v[..., 2] = np.abs(v[..., 2])
    wi, wo = v / np.linalg.norm(v, axis=-1, keepdims=True)
    th, ph, td, pd = merl.half_diff_from_directions(wi, wo)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.cos(td), np.sum(wi * h, axis=-1), atol=1e-12)
    np.testing.assert_allclose(np.cos(th), h[:, 2], atol=1e-12)
    wi2, wo2 = merl.directions_from_half_diff(th, ph, td, pd)
    np.testing.assert_allclose(wi2, wi, atol=1e-12)
    np.testing.assert_allclose(wo2, wo, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Writing and reading back
# --------------------------------------------------------------------------------------------


def test_file_layout(conductor_file):
    data = conductor_file.read_bytes()
    assert len(data) == merl.FILE_BYTES == 34_992_012
    assert struct.unpack("<3i", data[:12]) == (90, 90, 180)
    raw = np.frombuffer(data, "<f8", offset=12)
    i, j, k = 12, 40, 97  # one bin, all three planes
    wi, wo = merl.bin_directions(i, j, k)
    for c in range(3):
        f = float(fitlab.eval_bsdf("rough_conductor", CONDUCTOR[c], wi, wo))
        stored = raw[c * merl.N_BINS + k + 180 * j + 180 * 90 * i]
        assert stored == pytest.approx(f / merl.SCALES[c], rel=1e-14)
    # below the horizon: the reference value -1 (times the scale when read)
    wi, wo = merl.bin_directions(89, 89, 0)
    assert wi[2] < 0 or wo[2] < 0
    assert raw[merl.flat_index(89, 89, 0)] == merl.INVALID_RAW


@pytest.mark.parametrize("fixture, model, params", [
    ("conductor_file", "rough_conductor", CONDUCTOR),
    ("lambert_file", "lambertian", [{"albedo": a} for a in ALBEDO])])
def test_round_trip_every_bin(request, fixture, model, params):
    path = request.getfixturevalue(fixture)
    m = merl.read_merl(path, stride=1)
    table = merl.read_merl_table(path)
    assert m.channel_names == ("R", "G", "B") and m.quantity == "bsdf"
    assert m.n == int(table.valid.sum()) and m.n > 3 * 1_000_000
    assert np.all(m.wi[:, 2] > 0) and np.all(m.wo[:, 2] > 0)
    for c in range(3):
        rows = m.channel == c
        f = np.asarray(fitlab.eval_bsdf(model, params[c], m.wi[rows], m.wo[rows]))
        np.testing.assert_allclose(m.value[rows], f, rtol=1e-13, atol=0)
    # the degrees stored agree with the vectors
    from fitlab.io.directions import degrees_to_direction

    np.testing.assert_allclose(degrees_to_direction(m.theta_o[:1000], m.phi_o[:1000]), m.wo[:1000],
                               atol=1e-12)


def test_default_subsample(conductor_file):
    m = read_any(conductor_file)
    assert detect_format(conductor_file).name == "merl"
    assert m.metadata["stride"] == "1,6,12" and m.metadata["bins_read"] == str(90 * 15 * 15)
    i, j, k = merl.subsample_indices()
    assert set(np.unique(j)) == set(range(3, 90, 6)) and set(np.unique(k)) == set(range(6, 180, 12))
    # each row's bin index is recorded in `lines`
    i2, rem = np.divmod(m.lines, 180 * 90)
    j2, k2 = np.divmod(rem, 180)
    wi, wo = merl.bin_directions(i2, j2, k2)
    np.testing.assert_array_equal(wi, m.wi)
    assert merl.read_merl(conductor_file, stride="2,3,4").n < merl.read_merl(conductor_file, stride="all").n


@pytest.mark.parametrize("stride", [0, (1, 2), "a,b,c", (1, -1, 2)])
def test_bad_stride(conductor_file, stride):
    with pytest.raises((FitlabError, ValueError)):
        merl.read_merl(conductor_file, stride=stride)


def test_lookup_at_arbitrary_directions(conductor_file, lambert_file):
    rng = np.random.default_rng(11)
    v = rng.normal(size=(2, 5000, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    wi, wo = v / np.linalg.norm(v, axis=-1, keepdims=True)
    table = merl.read_merl_table(conductor_file)
    got = merl.eval_merl(table, wi, wo)
    assert got.shape == (5000, 3)
    # nearest-bin lookup: the value at the centre of the bin the pair falls in
    wi_c, wo_c = merl.bin_directions(*merl.lookup_indices(wi, wo))
    ok = ~np.isnan(got[:, 0])
    assert ok.mean() > 0.97
    for c in range(3):
        f = np.asarray(fitlab.eval_bsdf("rough_conductor", CONDUCTOR[c], wi_c[ok], wo_c[ok]))
        np.testing.assert_allclose(got[ok, c], f, rtol=1e-13)
    # Lambertian: the lookup is exact wherever the bin has a value
    lam = merl.eval_merl(merl.read_merl_table(lambert_file), wi, wo)
    ok = ~np.isnan(lam[:, 0])
    np.testing.assert_allclose(lam[ok], np.broadcast_to(np.array(ALBEDO) / np.pi, lam[ok].shape),
                               rtol=1e-14)
    # below the horizon: 0
    below = merl.eval_merl(table, wi * [1, 1, -1], wo)
    assert np.all(below == 0)


def test_write_is_atomic_and_reading_does_not_modify(tmp_path, lambert_file):
    before = lambert_file.read_bytes()
    merl.read_merl(lambert_file)
    assert lambert_file.read_bytes() == before
    with pytest.raises(FitlabError):
        merl_out.write_merl(tmp_path / "nope" / "x.binary", "lambertian", {"albedo": 0.5})
    target = tmp_path / "x.binary"
    with pytest.raises(ValueError):  # albedo out of bounds: nothing written
        merl_out.write_merl(target, "lambertian", {"albedo": 2.0})
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# Broken files
# --------------------------------------------------------------------------------------------


def _broken(tmp_path, source, edit):
    data = bytearray(source.read_bytes())
    data = edit(data)
    path = tmp_path / "broken.binary"
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("edit, fragment", [
    (lambda d: struct.pack("<3i", 90, 90, 360) + d[12:], "header dimensions (90, 90, 360)"),
    (lambda d: struct.pack(">3i", 90, 90, 180) + d[12:], "big-endian"),
    (lambda d: d[:1000], "truncated: 1000 bytes"),
    (lambda d: d[: 12 + 8 * merl.N_BINS * 2 + 8], "the B channel is incomplete"),
    (lambda d: d[:7], "shorter than the 12-byte MERL header"),
    (lambda d: d + b"\0" * 16, "16 more than the 34992012"),
])
def test_broken_files(tmp_path, lambert_file, edit, fragment):
    path = _broken(tmp_path, lambert_file, edit)
    with pytest.raises(InputFileError) as info:
        merl.read_merl(path)
    assert fragment in str(info.value) and str(path) in str(info.value)


def test_nan_is_reported_with_its_bin(tmp_path, lambert_file):
    def poke(d):
        pos = 12 + 8 * (merl.N_BINS + merl.flat_index(5, 6, 7))  # green plane
        d[pos:pos + 8] = struct.pack("<d", float("nan"))
        return d

    path = _broken(tmp_path, lambert_file, poke)
    with pytest.raises(InputFileError, match=r"channel G, bin θh=5 θd=6 φd=7 .*holds nan"):
        merl.read_merl(path)


def test_cli_reports_broken_file(tmp_path, lambert_file, capsys):
    path = _broken(tmp_path, lambert_file, lambda d: d[:5000])
    assert main(["info", str(path), "--format", "merl"]) == 2
    assert "size mismatch" in capsys.readouterr().err
    assert main(["convert", str(path), str(tmp_path / "out.csv"), "--format", "merl"]) == 2
    assert not (tmp_path / "out.csv").exists()


# --------------------------------------------------------------------------------------------
# Through the registry and the command line
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_info_convert_and_fit(tmp_path, lambert_file, capsys):
    assert main(["info", str(lambert_file), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "merl" and info["spec"] == "data_formats/merl_binary.md"
    assert info["channels"] == ["R", "G", "B"]
    assert info["f_normal_incidence_and_view"]["G"] == pytest.approx(0.5 / np.pi, rel=1e-14)
    assert 0 < info["bins_without_value"]["R"] < merl.N_BINS / 2

    out = tmp_path / "lambert.csv"
    assert main(["convert", str(lambert_file), str(out)]) == 0
    back = read_measurement(out)
    m = merl.read_merl(lambert_file)
    assert back.n == m.n and back.channel_names == ("R", "G", "B")
    np.testing.assert_allclose(back.value, m.value, rtol=1e-9)

    fit = tmp_path / "fit.json"
    assert main(["fit", str(lambert_file), "--model", "lambertian", "--channel", "B",
                 "--starts", "1", "--quiet", "--out", str(fit)]) == 0
    rec = json.loads(fit.read_text())
    assert rec["fits"][0]["parameters"]["albedo"]["value"] == pytest.approx(0.7, rel=1e-9)


def _bins_sample(table, n=4000, seed=3):
    """Random bins that hold a value in every channel, and their centre directions."""
    rng = np.random.default_rng(seed)
    i, j, k = (rng.integers(0, d, n) for d in merl.DIMS)
    keep = np.all(table.brdf[:, i, j, k] >= 0, axis=0)
    i, j, k = i[keep], j[keep], k[keep]
    return (i, j, k), merl.bin_directions(i, j, k)


def test_convert_fit_to_merl_round_trip(tmp_path, capsys):
    """`fitlab convert FIT.json OUT.binary`: an R, G, B fit tabulated channel by channel, read
    back by the MERL reader equal to the model at the bin centres."""
    fit = ROOT / "fits" / "rgl_aurora_white_lambert_ggx_conductor.json"
    rec = json.loads(fit.read_text())
    out = tmp_path / "aurora.binary"
    assert main(["convert", str(fit), str(out)]) == 0
    assert "MERL BRDF of lambertian+rough_conductor (R/G/B)" in capsys.readouterr().err
    assert detect_format(out).name == "merl"
    table = merl.read_merl_table(out)
    (i, j, k), (wi, wo) = _bins_sample(table)
    assert i.size > 3000
    for c, f in enumerate(rec["fits"]):
        assert f["channel"] == merl.CHANNELS[c]
        params = {n: p["value"] for n, p in f["parameters"].items()}
        want = np.asarray(fitlab.eval_bsdf(rec["model"]["name"], params, wi, wo,
                                           rec["model"]["options"]))
        np.testing.assert_allclose(table.brdf[c, i, j, k], want, rtol=1e-13)
    # one channel of it, with --to naming the writer for an unclaimed suffix: all three the same
    out_g = tmp_path / "aurora_g.dat"
    assert main(["convert", str(fit), str(out_g), "--to", "merl", "--channel", "G"]) == 0
    green = merl.read_merl_table(out_g)
    valid = table.valid[1]
    for c in range(3):
        np.testing.assert_array_equal(green.valid[c], valid)
        np.testing.assert_allclose(green.brdf[c][valid], table.brdf[1][valid], rtol=1e-12)


def test_convert_model_to_merl(tmp_path, capsys):
    out = tmp_path / "white.binary"
    assert main(["convert", "--model", "lambertian", "--param", "albedo=0.5", str(out)]) == 0
    err = capsys.readouterr().err
    assert "wrote " + str(out) in err and "note:" not in err
    m = read_any(out)
    assert m.channel_names == ("R", "G", "B")
    np.testing.assert_allclose(m.value, 0.5 / np.pi, rtol=1e-14)
    # a model that also transmits: its BRDF is written, and the command says what is left out
    glass = tmp_path / "glass.binary"
    assert main(["convert", "--model", "rough_dielectric", "--param", "alpha=0.3", "--param",
                 "eta=1.5", str(glass)]) == 0
    assert "a MERL file holds its reflection (BRDF) only" in capsys.readouterr().err
    table = merl.read_merl_table(glass)
    (i, j, k), (wi, wo) = _bins_sample(table, n=1000)
    want = np.asarray(fitlab.eval_bsdf("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, wi, wo))
    np.testing.assert_allclose(table.brdf[0, i, j, k], want, rtol=1e-13)


@pytest.mark.parametrize("argv, fragment", [
    # MERL holds reflection only: a transmission (BTDF) request is a Zemax setting
    (["--model", "rough_dielectric", "--param", "alpha=0.3", "--param", "eta=1.5",
      "--scatter", "BTDF", "{out}/t.binary"], "--scatter: applies to Zemax output only"),
    (["--model", "lambertian", "--param", "albedo=0.5", "--aoi", "0,10", "{out}/t.binary"],
     "--aoi: applies to Zemax output only; name the output *.bsdf (or give --to zemax)"),
    # measured data are not resampled into bins
    (["{lambert}", "{out}/t.binary"], "measured data would need resampling"),
    # a fit is tabulated, not copied into a measurement CSV
    (["{fit}", "{out}/t.csv"], "applies to Zemax or MERL or OpenMATERIAL output only; name the "
     "output *.bsdf or *.binary or *.xompt (or give --to zemax or --to merl or --to "
     "openmaterial)"),
    (["{fit}", "{out}/t.binary", "--channel", "Z"], "--channel Z: "),
    (["--model", "lambertian", "--param", "albedo=2", "{out}/t.binary"], "outside its bounds"),
])
def test_convert_to_merl_refused(tmp_path, lambert_file, capsys, argv, fragment):
    work = tmp_path / "work"
    work.mkdir()
    fit = ROOT / "fits" / "rgl_aurora_white_lambert_ggx_conductor.json"
    argv = [a.format(out=work, lambert=lambert_file, fit=fit) for a in argv]
    assert main(["convert", *argv]) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.startswith("fitlab convert: error:"), err
    assert list(work.iterdir()) == []


def test_xyz_fit_needs_a_channel_for_merl(tmp_path, capsys):
    fit = json.loads((ROOT / "fits" / "rgl_aurora_white_lambert_ggx_conductor.json").read_text())
    for f, c in zip(fit["fits"], "XYZ"):
        f["channel"] = c
    path = tmp_path / "xyz.json"
    path.write_text(json.dumps(fit))
    assert main(["convert", str(path), str(tmp_path / "x.binary")]) == 2
    assert "a MERL file holds one channel or R, G, B: choose one with --channel" in \
        capsys.readouterr().err
    assert not (tmp_path / "x.binary").exists()
