"""The thin layer's real-time table (fitlab lut thin_layer, Guo et al. 2015 section 5.5): the
subsurface lobe's mean direction, moment-matched κ̂ and albedo over (μ, κ1, κ2), checked against
closed forms, the model's own sampling (an independent estimator of the same integrals) and
the CLI's handling of bad requests. tests/lut/test_lut_glsl.py runs its GLSL in Mesa."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab import lut, vmf
from fitlab.fresnel import fresnel_conductor_exact, fresnel_dielectric_Walter2007
from fitlab.models import get_model
from fitlab.models.thin_layer import exit_concentration

MODEL = "thin_layer(rough_conductor)"
P = {"eta": 1.5, "tau": 0.3, "n2": 3.18, "k2": 4.41}
FAST = {"n_u": 24, "n_phi": 16}


def _spec(**kw):
    return lut.make_spec("thin_layer", model=MODEL, params={"G": dict(P)}, size=(4, 4, 4),
                         orders=kw.pop("orders", FAST), **kw)


def _sampled_moments(mu, k1, k2, n=400_000, chunk=50_000):
    """(E, sin θ of the mean toward the mirror azimuth, κ̂) of order 1 from the model's own
    sampling: the mean weight and the weighted mean of the sampled directions. The samples are
    drawn in chunks of one compiled shape (the thin layer's sampling holds many temporaries per
    sample: all 400,000 at once took the test process to 2.4 GB)."""
    m = get_model(MODEL)
    p = {**P, "kappa1": k1, "kappa2": k2}
    wi = jnp.broadcast_to(jnp.asarray([np.sqrt(1 - mu * mu), 0.0, mu]), (chunk, 3))
    u = np.random.default_rng(11).random((n, 3))
    draw = jax.jit(lambda a, b: m.sample(p, a, b, component="1")[:2])
    parts = [draw(wi, jnp.asarray(u[i:i + chunk])) for i in range(0, n, chunk)]
    wo = np.concatenate([np.asarray(o) for o, _ in parts])
    w = np.concatenate([np.asarray(x) for _, x in parts])
    E = w.mean()
    r = (w[:, None] * wo).sum(0) / w.sum()
    length = np.linalg.norm(r)
    kappa = 1.0 / float(vmf.nu_of_log_A3(jnp.log(length)))
    return E, -r[0] / length, kappa


def test_sharp_boundaries_give_the_closed_form_albedo_and_the_tree_concentration():
    """κ1 = κ2 = 3e4 at normal incidence: E = (1 - F)² R_b e^{-2τ} (the smooth layer), the mean
    is the normal, κ̂ the joint warping's (eq. 18), the lobe being a narrow vMF."""
    spec = _spec()
    v, err = spec.evaluate(np.array([[1.0, 3e4, 3e4]]))
    F = float(fresnel_dielectric_Walter2007(1.0, 1.5))
    Rb = float(fresnel_conductor_exact(1.0, 3.18 / 1.5, 4.41 / 1.5))
    assert v[0, 2] == pytest.approx((1 - F) ** 2 * Rb * np.exp(-2 * P["tau"]), rel=0.01)
    assert abs(v[0, 0]) < 1e-6
    tree = float(exit_concentration(1.0, 1.5, 3e4, 3e4))
    assert 10 ** v[0, 1] == pytest.approx(tree, rel=0.05)
    assert np.all(err < 1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("mu,k1,k2", [(0.8, 100.0, 30.0), (0.3, 1000.0, 10.0)])
def test_moments_agree_with_the_models_sampling(mu, k1, k2):
    """Albedo, mean direction and κ̂ by the table's quadrature equal the same moments of the
    model's own importance sampling (400,000 samples) within its noise."""
    v, _ = _spec().evaluate(np.array([[mu, k1, k2]]))
    E, s, kappa = _sampled_moments(mu, k1, k2)
    assert v[0, 2] == pytest.approx(E, rel=0.01)
    assert v[0, 0] == pytest.approx(s, abs=0.01)
    assert 10 ** v[0, 1] == pytest.approx(kappa, rel=0.05)


def test_baked_table_stores_its_accuracy_and_reads_back(tmp_path):
    from fitlab.export import exr

    table = lut.bake(_spec(), "half", check_points=8)
    acc = table.accuracy
    assert table.channels == ("sin_theta_mean", "log10_kappa", "E_G")
    assert {"storage", "quadrature", "interpolation", "vmf_lobe"} <= set(acc)
    assert acc["quadrature"]["orders"] == FAST
    assert 0 <= acc["vmf_lobe"]["median"] <= acc["vmf_lobe"]["p90"] <= acc["vmf_lobe"]["max"]
    exr.write_exr(tmp_path / "t.exr", table)
    back = exr.read_exr(tmp_path / "t.exr")
    assert back.kind == "thin_layer" and [a.name for a in back.axes] == ["mu", "kappa1", "kappa2"]
    np.testing.assert_array_equal(back.values, table.values)
    again = lut.spec_of_table(back)  # re-measurable from the file alone
    assert again.axes == table.axes and again.model["options"]["component"] == "subsurface"


@pytest.mark.parametrize("kw,message", [
    ({"model": "rough_conductor", "params": {"G": {"alpha": 0.1, "n": 1.0, "k": 2.0}}},
     "needs a thin_layer(...) model"),
    ({"kappa_range": (1e-3, 10.0)}, "must lie within [0.01, 1e+07]"),
    ({"params": {"R": dict(P), "G": {**P, "eta": 1.4}}}, "made for one η"),
])
def test_refusals_say_what_to_do(kw, message):
    args = {"model": MODEL, "params": {"G": dict(P)}, **kw}
    with pytest.raises(ValueError, match=re.escape(message)):
        lut.make_spec("thin_layer", size=(4, 4, 4), **args)


@pytest.mark.slow
def test_cli_bakes_it_and_refuses_a_model_without_two_boundaries(tmp_path, capsys):
    from fitlab.cli import main

    out = tmp_path / "film.exr"
    rc = main(["lut", "thin_layer", "--model", MODEL, "--param", "eta=1.5", "--param",
               "tau=0.2", "--param", "n2=0.2,1.0,1.2", "--param", "k2=3.9,2.6,2.4",
               "--size", "3x3x3", "--kappa-range", "10:1e4", "--check-points", "4",
               "--dtype", "float", "--out", str(out)])
    assert rc == 0 and out.exists() and out.with_suffix(".glsl").exists()
    err = capsys.readouterr().err
    assert "thin_layer" in err and "E_R" in err
    code = out.with_suffix(".glsl").read_text()
    assert "void fitlab_thin_layer(sampler2D tex0, sampler2D tex1, vec3 wi" in code
    bad = tmp_path / "bad.exr"
    rc = main(["lut", "thin_layer", "--model", "rough_conductor", "--param", "alpha=0.1",
               "--param", "n=1", "--param", "k=2", "--out", str(bad)])
    assert rc == 2 and not bad.exists()
    assert "needs a thin_layer(...) model" in capsys.readouterr().err
