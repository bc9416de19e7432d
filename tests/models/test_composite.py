"""Sums of models ("lambertian+rough_conductor"): naming, evaluation, mixture sampling (χ² and
weight consistency), and use in a fit."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import fitlab
from chi2 import chi2_test, sidak_level

PARAMS = {"albedo": 0.4, "alpha": 0.15, "n": 1.5, "k": 0.0}


def _dirs(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_names_unique_or_prefixed():
    m = fitlab.get_model("lambertian+rough_conductor")
    assert m.parameter_names == ("albedo", "alpha", "n", "k")
    assert [o.name for o in m.options] == ["distribution", "fresnel", "sampling"]
    m = fitlab.get_model("lambertian+oren_nayar")
    assert m.parameter_names == ("lambertian.albedo", "oren_nayar.albedo", "sigma")
    m = fitlab.get_model("rough_conductor+rough_dielectric")
    assert "rough_conductor.alpha" in m.parameter_names and "eta" in m.parameter_names
    assert "rough_dielectric.distribution" in [o.name for o in m.options]


def test_repeated_components_are_numbered():
    m = fitlab.get_model("lambertian+rough_conductor+rough_conductor")
    assert m.parameter_names == ("albedo", "alpha", "n", "k", "alpha_2", "n_2", "k_2")
    assert [o.name for o in m.options] == ["distribution", "fresnel", "sampling",
                                           "distribution_2", "fresnel_2", "sampling_2"]
    assert [p.role for p in m.parameters] == ["albedo", "roughness", "index", "extinction",
                                              "roughness", "index", "extinction"]
    assert not m.capabilities.energy_conserving and m.capabilities.reciprocal
    (ex,) = m.exchangeable
    assert ex.parameters == (("alpha", "n", "k"), ("alpha_2", "n_2", "k_2"))
    assert ex.options[1] == ("distribution_2", "fresnel_2", "sampling_2") and ex.order_by == 0
    # a name shared with another component is prefixed as before, then numbered
    m = fitlab.get_model("lambertian+oren_nayar+oren_nayar")
    assert m.parameter_names == ("lambertian.albedo", "oren_nayar.albedo", "sigma", "albedo_2",
                                 "sigma_2")
    assert fitlab.get_model("lambertian+lambertian").parameter_names == ("albedo", "albedo_2")
    m = fitlab.get_model("rough_conductor+rough_conductor+rough_conductor")
    assert m.exchangeable[0].parameters[2] == ("alpha_3", "n_3", "k_3")
    # layered over a repeated sum: the inner lobes stay interchangeable
    m = fitlab.get_model("coated(lambertian+rough_conductor+rough_conductor,specular=lobe)")
    assert m.exchangeable == fitlab.get_model("lambertian+rough_conductor+rough_conductor"
                                              ).exchangeable


def test_repeated_sum_is_the_sum():
    wi, wo = _dirs(500, 1), _dirs(500, 2)
    p = {"albedo": 0.2, "alpha": 0.05, "n": 1.5, "k": 0.0, "alpha_2": 0.4, "n_2": 2.0, "k_2": 1.0}
    total = fitlab.eval_bsdf("lambertian+rough_conductor+rough_conductor", p, wi, wo,
                             {"distribution_2": "beckmann"})
    parts = (fitlab.eval_bsdf("lambertian", {"albedo": 0.2}, wi, wo)
             + fitlab.eval_bsdf("rough_conductor", {"alpha": 0.05, "n": 1.5, "k": 0.0}, wi, wo)
             + fitlab.eval_bsdf("rough_conductor", {"alpha": 0.4, "n": 2.0, "k": 1.0}, wi, wo,
                                {"distribution": "beckmann"}))
    np.testing.assert_allclose(total, parts, rtol=1e-14, atol=0)


def test_bad_sums():
    with pytest.raises(ValueError, match="unknown model 'glossy'"):
        fitlab.get_model("lambertian+glossy")


def test_eval_is_the_sum():
    wi, wo = _dirs(500, 1), _dirs(500, 2)
    total = fitlab.eval_bsdf("lambertian+rough_conductor", PARAMS, wi, wo,
                             {"distribution": "beckmann"})
    parts = (fitlab.eval_bsdf("lambertian", {"albedo": 0.4}, wi, wo)
             + fitlab.eval_bsdf("rough_conductor", {"alpha": 0.15, "n": 1.5, "k": 0.0}, wi, wo,
                                {"distribution": "beckmann"}))
    np.testing.assert_allclose(total, parts, rtol=1e-14, atol=0)


@pytest.mark.parametrize("theta_i", [0.0, 50.0, 85.0])
def test_mixture_sampling_chi2(theta_i):
    model = fitlab.get_model("lambertian+rough_conductor")
    t = np.radians(theta_i)
    wi = np.array([-np.sin(t), 0.0, np.cos(t)])
    sample = jax.jit(lambda u: model.sample(PARAMS, wi, u))
    pdf = jax.jit(lambda wo: model.pdf(PARAMS, wi, wo))

    def sampler(u):
        wo, _, p = sample(u)
        return np.asarray(wo), np.asarray(p)

    res = chi2_test(sampler, lambda wo: np.asarray(pdf(wo)), 200_000, seed=int(theta_i) + 5)
    assert res.p_value > sidak_level(0.01, 3), res.report()


def test_mixture_weight_is_f_cos_over_pdf():
    wi = _dirs(2000, 3)
    wi[:, 2] = np.abs(wi[:, 2])
    u = np.random.default_rng(4).random((2000, 3))
    wo, w, p = fitlab.sample_bsdf("lambertian+rough_conductor", PARAMS, wi, u)
    f = fitlab.eval_bsdf("lambertian+rough_conductor", PARAMS, wi, wo)
    ok = np.asarray(p) > 0
    assert ok.mean() > 0.5
    np.testing.assert_allclose(np.asarray(w)[ok], (np.asarray(f) * np.abs(np.asarray(wo)[:, 2]) /
                                                   np.asarray(p))[ok], rtol=1e-10)
    np.testing.assert_allclose(np.asarray(p),
                               fitlab.pdf_bsdf("lambertian+rough_conductor", PARAMS, wi, wo),
                               rtol=1e-10)


@pytest.mark.slow
def test_fit_a_sum(tmp_path):
    from test_fit import synthetic

    from fitlab.fitting.driver import fit_measurement
    from fitlab.fitting.request import FitRequest

    truth = {"albedo": 0.3, "alpha": 0.12, "n": 1.6, "k": 0.0}
    m = synthetic("lambertian+rough_conductor", truth, thetas_i=(15, 45, 75),
                  thetas_o=tuple(range(0, 90, 3)), seed=3)
    res = fit_measurement(m, FitRequest("lambertian+rough_conductor", fix={"k": 0.0}, seed=0))
    ch = res["channels"][0]
    got = dict(zip(ch["space"].names, ch["ls"].native))
    err = dict(zip(ch["space"].names, ch["ls"].stderr))
    for name in ("albedo", "alpha", "n"):
        assert abs(got[name] - truth[name]) < 4 * err[name], (name, got[name], err[name])
