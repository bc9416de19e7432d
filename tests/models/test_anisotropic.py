"""Anisotropic GGX / Beckmann end to end: the models' symmetries, the Zemax writer
(Asymmetrical, sample rotations), the formats and tables that cannot hold anisotropy refusing it
(MERL, the (θh, θd) model LUT), and a fit that recovers α_x and α_y from a tabulated file.
(Mitsuba agreement: tests/models/test_mitsuba_agreement.py; χ² sampling: tests/models/test_sampling.py;
simulator: tests/simulate/test_simulate_validation.py.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.export import zemax as zemax_out
from fitlab.io import zemax
from fitlab.io.formats import read_any

PARAMS = {"alpha_x": 0.08, "alpha_y": 0.3, "n": 0.2, "k": 3.9}


def _dir(theta, phi):
    t, p = np.radians(theta), np.radians(phi)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)


@pytest.mark.parametrize("name, params", [
    ("rough_conductor_anisotropic", PARAMS),
    ("rough_dielectric_anisotropic", {"alpha_x": 0.08, "alpha_y": 0.3, "eta": 1.5}),
])
def test_anisotropy_symmetries(name, params):
    """Equal widths give the isotropic model; swapping the widths is a 90° rotation; the
    mirror symmetries of the stretched distribution (x → -x, y → -y) hold; a rotation by
    another angle changes the values."""
    rng = np.random.default_rng(0)
    wi = _dir(rng.uniform(0, 80, 500), rng.uniform(0, 360, 500))
    wo = _dir(rng.uniform(0, 180, 500), rng.uniform(0, 360, 500))
    iso = name.removesuffix("_anisotropic")
    rest = {k: v for k, v in params.items() if not k.startswith("alpha")}
    for a in (0.05, 0.4):
        np.testing.assert_allclose(
            fitlab.eval_bsdf(name, {**rest, "alpha_x": a, "alpha_y": a}, wi, wo),
            fitlab.eval_bsdf(iso, {**rest, "alpha": a}, wi, wo), rtol=1e-12, atol=1e-300)
    f = np.asarray(fitlab.eval_bsdf(name, params, wi, wo))
    swapped = {**params, "alpha_x": params["alpha_y"], "alpha_y": params["alpha_x"]}
    rot90 = lambda w: np.stack([-w[:, 1], w[:, 0], w[:, 2]], -1)  # noqa: E731
    np.testing.assert_allclose(fitlab.eval_bsdf(name, swapped, rot90(wi), rot90(wo)), f,
                               rtol=1e-10, atol=1e-300)
    flip_x = np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(fitlab.eval_bsdf(name, params, wi * flip_x, wo * flip_x), f,
                               rtol=1e-10, atol=1e-300)
    rot30 = lambda w: np.stack([w[:, 0] * np.cos(0.5) - w[:, 1] * np.sin(0.5),  # noqa: E731
                                w[:, 0] * np.sin(0.5) + w[:, 1] * np.cos(0.5), w[:, 2]], -1)
    g = np.asarray(fitlab.eval_bsdf(name, params, rot30(wi), rot30(wo)))
    assert np.max(np.abs(g - f) / np.maximum(f, 1e-6)) > 0.1


def test_zemax_writer_declares_asymmetrical_and_round_trips(tmp_path):
    path = tmp_path / "brushed.bsdf"
    grid = zemax_out.Grid((0.0, 45.0, 90.0), (0.0, 30.0, 60.0),
                          tuple(float(x) for x in range(0, 360, 30)),
                          tuple(float(x) for x in range(0, 81, 10)))
    summary = zemax_out.write_zemax(path, "rough_conductor_anisotropic", PARAMS, grid=grid)
    assert summary["symmetry"] == "Asymmetrical"
    zf = zemax.parse_zemax(path)
    assert zf.symmetry == "Asymmetrical" and list(zf.rotation) == [0.0, 45.0, 90.0]
    m = read_any(path)
    ok = m.value > 1e-3
    f = np.asarray(fitlab.eval_bsdf("rough_conductor_anisotropic", PARAMS, m.wi, m.wo))
    np.testing.assert_allclose(m.value[ok], f[ok], rtol=1e-4)  # the file keeps 5 digits
    # the rotations differ: the file holds the anisotropy
    assert not np.allclose(zf.values[0, 0, 1], zf.values[0, 2, 1])


def test_zemax_writer_refuses_a_half_circle_for_an_anisotropic_model(tmp_path):
    with pytest.raises(fitlab.errors.FitlabError, match="not symmetric about the plane"):
        zemax_out.write_zemax(tmp_path / "x.bsdf", "rough_conductor_anisotropic", PARAMS,
                              azimuth="0:180:10")
    assert not (tmp_path / "x.bsdf").exists()


def test_standard_zemax_grid_of_an_anisotropic_model_is_asymmetrical(tmp_path):
    out = tmp_path / "std.bsdf"
    assert main(["convert", "--model", "rough_conductor_anisotropic",
                 *[f"--param={k}={v}" for k, v in PARAMS.items()], "--aoi", "0,40",
                 "--radial", "0:80:20", str(out)]) == 0
    zf = zemax.parse_zemax(out)
    assert zf.symmetry == "Asymmetrical"
    assert list(zf.rotation) == list(zemax_out.STANDARD_ROTATION_FULL)
    assert max(zf.azimuth) > 180


def test_merl_and_model_lut_refuse_anisotropic_models(tmp_path, capsys):
    params = [f"--param={k}={v}" for k, v in PARAMS.items()]
    out = tmp_path / "x.binary"
    assert main(["convert", "--model", "rough_conductor_anisotropic", *params, str(out)]) == 2
    assert "is anisotropic; a MERL file holds an isotropic BRDF" in capsys.readouterr().err
    assert not out.exists()
    exr = tmp_path / "t.exr"
    assert main(["lut", "model", "--model", "rough_conductor_anisotropic", *params,
                 "--size", "8x8", "--out", str(exr)]) == 2
    assert "is anisotropic: a (cos θh, cos θd) table holds isotropic BRDFs only" in \
        capsys.readouterr().err
    assert not exr.exists()


@pytest.mark.slow
def test_fit_recovers_both_widths_from_a_tabulated_file(tmp_path, capsys):
    """fitlab fit on an Asymmetrical Zemax file of a brushed conductor: α_x, α_y recovered."""
    path = tmp_path / "brushed.bsdf"
    grid = zemax_out.Grid((0.0, 90.0), (20.0, 50.0), tuple(float(x) for x in range(0, 360, 30)),
                          tuple(float(x) for x in range(0, 61, 10)))
    zemax_out.write_zemax(path, "rough_conductor_anisotropic", PARAMS, grid=grid)
    fit = tmp_path / "fit.json"
    assert main(["fit", str(path), "--model", "rough_conductor_anisotropic", "--fix", "n=0.2",
                 "--fix", "k=3.9", "--loss", "relative", "--quiet", "--out", str(fit),
                 "--report", str(tmp_path / "report")]) == 0
    rec = json.loads(fit.read_text())
    p = rec["fits"][0]["parameters"]
    assert p["alpha_x"]["value"] == pytest.approx(0.08, rel=1e-3)
    assert p["alpha_y"]["value"] == pytest.approx(0.3, rel=1e-3)
    assert rec["model"]["lobes"] == "reflection"
    # the report's hemisphere maps show the data and the anisotropic model per sample rotation
    html = (tmp_path / "report" / "index.html").read_text()
    assert "Hemispherical maps" in html and "φi = 90°" in html
