"""The directional-albedo tables (fitlab/models/directional_albedo.py) and the energy budget of
SpongeCake's multiple-scattering approximation that reads them
(fitlab/models/spongecake_multiple.py): the tables against plain Monte Carlo of the model's
own sampler, per-row parameters against per-set calls, the upper envelope, and the budget's
factor: 1 where the approximation fits within the energy that arrives, an albedo of at most 1
where it does not, reciprocity either way."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitlab  # noqa: F401  (x64)
from fitlab.models import directional_albedo as da
from fitlab.models import get_model
from fitlab.models import spongecake as sc
from fitlab.models.spongecake_multiple import approximation


def _dir(theta, phi=0.0):
    t, f = np.radians(theta), np.radians(phi)
    return np.array([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)])


def _mc_albedo(model, params, w, n=100_000, seed=0):
    """Mean sample weight of the model's own sampler and its standard error."""
    rng = np.random.default_rng(seed)
    wt = np.asarray(jax.jit(model.sample)({k: jnp.float64(v) for k, v in params.items()},
                                          np.repeat(w[None], n, 0), rng.random((n, 3)))[1])
    return wt.mean(), wt.std() / np.sqrt(n)


def test_tabulated_albedo_agrees_with_monte_carlo_of_the_sampler():
    """The per-layer Sobol estimator at the grid's nodes against 1e5 samples of the model's
    mixture sampler: within 0.01 from normal incidence to 89.95°, both sides."""
    model = get_model("spongecake(fiber,surface)")
    layers = (sc.Layer("fiber", 1), sc.Layer("surface", 2))
    p = {q.name: q.default for q in model.parameters}
    g = da.grid(isotropic=False, both_sides=True)
    table = np.asarray(jax.jit(lambda q: da.tabulate(
        lambda q_, w, u: sc.single_scattering_albedo_weights(layers, q_, w, u), q, g,
        jnp.float64))({k: jnp.float64(v) for k, v in p.items()}))
    dirs = da.directions(g)
    T, F = len(g.theta), len(g.phi)
    for side in (0, 1):
        for i in (0, T - 3, T - 1):
            k = (side * T + i) * F + 3
            mc, se = _mc_albedo(model, p, dirs[k])
            assert abs(table[k] - mc) < 0.01 + 4 * se, (dirs[k], table[k], mc, se)


def test_per_row_parameters_give_each_row_its_own_sets_table():
    """Rows holding three parameter sets (a joint fit's channels) get the table of their own
    set, as three separate calls do; rows of one set get one table; more sets than
    MAX_DISTINCT give NaN, never another row's table."""
    def make(q):
        a, b = jnp.asarray(q["a"])[..., None], jnp.asarray(q["b"])[..., None]
        return jnp.concatenate([a * jnp.ones(3), a * b + jnp.arange(3.0)], axis=-1)
    a = np.repeat([1.0, 2.0, 3.0], 40)
    b = np.repeat([5.0, 7.0, 11.0], 40)
    t = da.per_parameter_set(make, {"a": jnp.asarray(a), "b": jnp.asarray(b)})
    got = np.asarray(t.values)[np.asarray(t.rows)]
    want = np.stack([np.asarray(make({"a": x, "b": y})) for x, y in zip(a, b)])
    np.testing.assert_array_equal(got, want)
    t1 = da.per_parameter_set(make, {"a": jnp.full(120, 2.0), "b": jnp.full(120, 7.0)})
    np.testing.assert_array_equal(np.asarray(t1.values)[np.asarray(t1.rows)],
                                  np.broadcast_to(np.asarray(make({"a": 2.0, "b": 7.0})),
                                                  (120, 6)))
    many = np.arange(da.MAX_DISTINCT + 3.0).repeat(10)
    tn = da.per_parameter_set(make, {"a": jnp.asarray(many), "b": jnp.ones_like(many)})
    vals = np.asarray(tn.values)[np.asarray(tn.rows)]
    assert np.all(np.isnan(vals[many >= da.MAX_DISTINCT]))
    ok = many < da.MAX_DISTINCT
    np.testing.assert_array_equal(vals[ok], np.stack([np.asarray(make({"a": x, "b": 1.0}))
                                                      for x in many[ok]]))


def test_the_envelope_bounds_the_interpolation_and_reads_a_constant_exactly():
    """lookup_max at any direction is at least the bilinear interpolation of its cell (computed
    here from the nodes), and a constant table reads back as that constant."""
    g = da.grid(isotropic=False, both_sides=True)
    rng = np.random.default_rng(3)
    table = rng.random(g.size)
    w = rng.normal(size=(500, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    T, F = len(g.theta), len(g.phi)
    th = np.arccos(np.abs(w[:, 2]))
    i = np.clip(np.searchsorted(g.theta, th, side="right") - 1, 0, T - 2)
    t = (th - g.theta[i]) / (g.theta[i + 1] - g.theta[i])
    ph = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi) * F / (2 * np.pi)
    j0 = np.floor(ph).astype(int) % F
    s_ = ph - np.floor(ph)
    side = (w[:, 2] < 0).astype(int)
    at = lambda ii, jj: table[(side * T + ii) * F + jj]  # noqa: E731
    bilinear = ((1 - t) * ((1 - s_) * at(i, j0) + s_ * at(i, (j0 + 1) % F))
                + t * ((1 - s_) * at(i + 1, j0) + s_ * at(i + 1, (j0 + 1) % F)))
    env = np.asarray(da.lookup_max(jnp.asarray(table), g, jnp.asarray(w)))
    assert np.all(env >= bilinear - 1e-12)
    np.testing.assert_allclose(np.asarray(da.lookup_max(jnp.full(g.size, 0.7), g,
                                                        jnp.asarray(w))), 0.7, rtol=0)


LOBE = "spongecake(surface,multiple=lobe)"


def _lobe_params(w1):
    m = get_model(LOBE)
    p = {q.name: q.default for q in m.parameters}
    p.update(W1=w1, W2=0.05, W2T=0.05)
    return {k: jnp.float64(v) for k, v in p.items()}


def _raw(p, wi, wo):
    """The model before the budget: exact single scattering plus §5's approximation."""
    return _raw_jit(p, wi, wo)


@jax.jit
def _raw_jit(p, wi, wo):
    base = get_model("spongecake(surface)")
    stack = get_model("spongecake(surface,delta=false)")
    return (base.eval({k: p[k] for k in base.parameter_names}, wi, wo)
            + approximation(stack, p, wi, wo, True))


def _pairs(n=3000, seed=1):
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 80, n), rng.uniform(0, 180, n)
    wi = np.stack([_dir(a, b) for a, b in zip(ti, rng.uniform(-180, 180, n))])
    wo = np.stack([_dir(a, b) for a, b in zip(to, rng.uniform(-180, 180, n))])
    return jnp.asarray(wi), jnp.asarray(wo)


def test_budget_leaves_a_lobe_that_fits_unchanged():
    """W1 = 0.2: ss + lobe stays below 1 everywhere (albedo ≤ 0.6), so the model is the paper's
    sum exactly."""
    p = _lobe_params(0.2)
    wi, wo = _pairs()
    m = get_model(LOBE)
    np.testing.assert_allclose(np.asarray(jax.jit(m.eval)(p, wi, wo)),
                               np.asarray(_raw(p, wi, wo)), rtol=1e-12, atol=0)


def test_budget_caps_an_oversized_lobe_reciprocally():
    """W1 = 10 (the bound): the paper's sum returns several times the incident light; the model
    returns at most 1 (white furnace, 1e5 samples), is reciprocal, and never exceeds the sum."""
    p = _lobe_params(10.0)
    m = get_model(LOBE)
    w = _dir(30.0, 10.0)
    d = np.random.default_rng(4).normal(size=(50_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)  # uniform on the sphere: E = 4π mean(f |cos|)
    raw_albedo = 4 * np.pi * float(np.mean(np.asarray(
        _raw(p, jnp.asarray(np.repeat(w[None], len(d), 0)), jnp.asarray(d))) * np.abs(d[:, 2])))
    assert raw_albedo > 1.5, raw_albedo
    mean, se = _mc_albedo(m, {k: float(v) for k, v in p.items()}, w, n=60_000)
    assert mean <= 1.01 and se < 0.003, (mean, se)
    wi, wo = _pairs()
    ev = jax.jit(m.eval)
    f_io, f_oi = np.asarray(ev(p, wi, wo)), np.asarray(ev(p, wo, wi))
    np.testing.assert_allclose(f_io, f_oi, rtol=1e-10, atol=1e-30)
    assert np.all(f_io <= np.asarray(_raw(p, wi, wo)) * (1 + 1e-12))
