"""A model redefined in a running session is never served from code compiled for the old one
(issue: caches keyed on names reused stale kernels): the API's kernels, the fitter's kernels and
derived models (sums, layered models) are keyed on the model object, and register_model
rebuilds the listed layered examples."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import fitlab
from fitlab.fitting.space import make_space, model_values
from fitlab.models import MODELS, get_model, register_model
from fitlab.models.base import Capabilities, Model, Parameter

WI = np.array([0.0, 0.0, 1.0])
WO = np.array([0.6, 0.0, 0.8])


def _constant(name, value):
    def eval(params, wi, wo):
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), value * params["albedo"] / jnp.pi, 0.0)

    def pdf(params, wi, wo):
        return jnp.where(wo[..., 2] > 0, wo[..., 2] / jnp.pi, 0.0)

    def sample(params, wi, u):
        r, phi = jnp.sqrt(u[..., 0]), 2 * jnp.pi * u[..., 1]
        wo = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), jnp.sqrt(1 - u[..., 0])], -1)
        return wo, value * params["albedo"] * jnp.ones_like(u[..., 0]), pdf(params, wi, wo)

    return Model(name=name, summary="test model", parameters=(
        Parameter("albedo", 0.0, 1.0, 0.5, "1", "albedo", "albedo"),), options=(),
        eval=eval, sample=sample, pdf=pdf, reference="test",
        capabilities=Capabilities(lambertian=True))


@pytest.fixture
def scratch_name():
    name = "contract_scratch_model"
    yield name
    MODELS.unregister(name)


def test_redefined_model_is_not_served_stale_code(scratch_name):
    register_model(_constant(scratch_name, 1.0))
    f1 = float(fitlab.eval_bsdf(scratch_name, {"albedo": 0.5}, WI, WO))
    s1 = float(np.asarray(fitlab.eval_bsdf(f"coated({scratch_name})",
                                           {"albedo": 0.5, "coat_eta": 1.5, "coat_tau": 0.0}, WI, WO)))
    k1 = float(model_values(scratch_name, (), {"albedo": 0.5}, WI[None], WO[None])[0])
    with pytest.raises(ValueError, match="already registered"):
        register_model(_constant(scratch_name, 2.0))
    register_model(_constant(scratch_name, 2.0), replace=True)
    assert float(fitlab.eval_bsdf(scratch_name, {"albedo": 0.5}, WI, WO)) == pytest.approx(2 * f1)
    s2 = float(np.asarray(fitlab.eval_bsdf(f"coated({scratch_name})",
                                           {"albedo": 0.5, "coat_eta": 1.5, "coat_tau": 0.0}, WI, WO)))
    assert s2 == pytest.approx(2 * s1)
    k2 = float(model_values(scratch_name, (), {"albedo": 0.5}, WI[None], WO[None])[0])
    assert k2 == pytest.approx(2 * k1)
    space = make_space(get_model(scratch_name), {}, {}, relative=False)
    assert space.model is get_model(scratch_name)
    # a sum with the redefined component is rebuilt too
    total = float(fitlab.eval_bsdf(f"lambertian+{scratch_name}",
                                   {"lambertian.albedo": 0.0, f"{scratch_name}.albedo": 0.5}, WI, WO))
    assert total == pytest.approx(2 * f1)


def test_register_model_validates():
    with pytest.raises(TypeError):
        register_model("lambertian")
    bad = _constant("bad(name)", 1.0)
    with pytest.raises(ValueError, match="letters"):
        register_model(bad)
    odd = _constant("odd_role_model", 1.0)
    odd = odd._replace(parameters=(odd.parameters[0]._replace(role="colour"),))
    with pytest.raises(ValueError, match="role"):
        register_model(odd)
