"""Lookup tables (fitlab.lut) and quadrature (fitlab.quadrature): rules, albedo integrals against
independent Monte Carlo through the models' own samplers, physical limits, table contents, the
stored accuracy, and bad input. Small sizes and orders keep this file fast."""

from __future__ import annotations

import numpy as np
import pytest

import fitlab
from fitlab import lut, quadrature
from fitlab.fresnel import fresnel_dielectric_Walter2007, schlick_f0
from fitlab.microfacet import D_GGX

SMALL = {"n_u": 6, "n_phi": 3, "n_mu": 8}


# --------------------------------------------------------------------------------------------
# quadrature
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 3, 8, 20])
def test_gauss_legendre_is_exact_to_degree_2n_minus_1(n):
    x, w = quadrature.gauss_legendre(n, -0.5, 2.0)
    for d in range(2 * n):
        exact = (2.0 ** (d + 1) - (-0.5) ** (d + 1)) / (d + 1)
        assert np.isclose(np.sum(w * x**d), exact, rtol=1e-12, atol=1e-12)


def test_panels_and_smoothed_ends():
    # sqrt(x) on [0, 1]: an endpoint singularity; smoothed ends converge much faster
    exact = 2.0 / 3.0
    plain = [abs(np.sum(w * np.sqrt(x)) - exact) for x, w in
             (quadrature.gauss_legendre_panels([0.0, 1.0], n) for n in (4, 8))]
    smooth = [abs(np.sum(w * np.sqrt(x)) - exact) for x, w in
              (quadrature.gauss_legendre_panels([0.0, 1.0], n, smooth_ends=True) for n in (4, 8))]
    assert smooth[1] < plain[1] / 30
    # per-row breakpoints, empty panels contribute nothing
    x, w = quadrature.gauss_legendre_panels(np.array([[0.0, 0.5, 0.5, 2.0], [1.0, 1.0, 1.0, 1.0]]), 5)
    assert x.shape == (2, 15)
    assert np.isclose(w[0].sum(), 2.0) and np.all(w[1] == 0)


def test_midpoint_is_spectral_for_periodic_integrands():
    from scipy.special import i0

    x, w = quadrature.midpoint_periodic(12, 0.0, 2 * np.pi)
    assert np.isclose(np.sum(w * np.exp(np.cos(x))), 2 * np.pi * i0(1.0), rtol=1e-13)


def test_hemisphere_rule():
    d, w = quadrature.hemisphere_rule(8, 16)
    assert np.isclose(w.sum(), 2 * np.pi)
    assert np.isclose(np.sum(w * d[:, 2]), np.pi)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    with pytest.raises(ValueError):
        quadrature.gauss_legendre(0)


# --------------------------------------------------------------------------------------------
# albedo integrals
# --------------------------------------------------------------------------------------------


def _mc(model, params, mu, side=1.0, n=200_000, seed=0, options=None):
    """Reflection and transmission albedo by the model's own importance sampler."""
    wi = np.array([np.sqrt(1 - mu * mu), 0.0, side * mu])
    u = np.random.default_rng(seed).random((n, 3))
    wo, w, _ = fitlab.sample_bsdf(model, params, np.broadcast_to(wi, (n, 3)), u, options)
    wo, w = np.asarray(wo), np.asarray(w)
    refl = np.where(wo[:, 2] * side > 0, w, 0.0)
    tran = np.where(wo[:, 2] * side < 0, w, 0.0)
    return (refl.mean(), tran.mean()), (refl.std() / np.sqrt(n), tran.std() / np.sqrt(n))


@pytest.mark.slow
@pytest.mark.parametrize("mu,alpha", [(1.0, 0.1), (0.5, 0.5), (0.1, 0.9), (0.7, 0.02)])
@pytest.mark.parametrize("side", [1.0, -1.0], ids=["outside", "inside"])
def test_dielectric_albedo_matches_monte_carlo_of_the_model(mu, alpha, side):
    eta = 1.5
    q = lut.albedo_integrals([mu], [alpha], [eta if side > 0 else 1 / eta], mode="dielectric")[0]
    (R, T), (sR, sT) = _mc("rough_dielectric", {"alpha": alpha, "eta": eta}, mu, side)
    assert abs(q[0] - R) < 5 * sR + 1e-4
    assert abs(q[1] - T) < 5 * sT + 1e-4


@pytest.mark.slow
@pytest.mark.parametrize("mu,alpha", [(0.9, 0.3), (0.2, 0.7)])
def test_dfg_reproduces_schlick_conductor_albedo(mu, alpha):
    """F0 · scale + bias = ∫ f cos of rough_conductor with Schlick's Fresnel (by Monte Carlo)."""
    n, k = 0.2, 3.9
    scale, bias = lut.albedo_integrals([mu], [alpha], mode="dfg")[0]
    (R, _), (sR, _) = _mc("rough_conductor", {"alpha": alpha, "n": n, "k": k}, mu,
                          options={"fresnel": "schlick"})
    assert abs(schlick_f0(n, k) * scale + bias - R) < 5 * sR + 1e-4
    E = lut.albedo_integrals([mu], [alpha], mode="conductor")[0, 0]
    assert np.isclose(E, scale + bias, atol=1e-10)


def test_albedo_limits_and_energy():
    mu = np.array([1.0, 0.5, 0.1, 0.0])
    # α -> 0: a smooth mirror (E = 1) and a smooth interface (R = F, T = 1 - F)
    E = lut.albedo_integrals(mu, np.full(4, 1e-4), mode="conductor")[:, 0]
    assert np.allclose(E[:3], 1.0, atol=1e-5)
    for eta in (1.5, 1 / 1.5):
        RT = lut.albedo_integrals(mu[:3], np.full(3, 1e-4), np.full(3, eta), mode="dielectric")
        F = np.asarray(fresnel_dielectric_Walter2007(mu[:3], np.full(3, eta)))
        assert np.allclose(RT[:, 0], F, atol=1e-5)
        assert np.allclose(RT[:, 1], 1 - F, atol=1e-5)
    # energy <= 1 everywhere, finite at grazing and at α = 1, index ratio near 1
    rng = np.random.default_rng(1)
    m, a = rng.random(64), rng.uniform(1e-4, 1.0, 64)
    for eta in (1.001, 1.5, 1 / 1.001, 1 / 3.0):
        RT = lut.albedo_integrals(np.r_[m, 0.0, 1.0], np.r_[a, 1.0, 1.0],
                                  np.full(66, eta), mode="dielectric", n_u=8, n_phi=4)
        assert np.all(np.isfinite(RT)) and np.all(RT >= 0)
        assert np.all(RT.sum(axis=1) <= 1 + 1e-6)
    # an interface with η -> 1 is nearly invisible at low roughness
    RT = lut.albedo_integrals([0.8], [0.05], [1.001], mode="dielectric")[0]
    assert RT[0] < 1e-5 and RT.sum() > 0.99
    # E decreases with roughness at normal incidence (more shadowing)
    E = lut.albedo_integrals(np.ones(5), np.linspace(0.1, 1.0, 5), mode="conductor")[:, 0]
    assert np.all(np.diff(E) < 0)


def test_quadrature_error_estimate_is_conservative():
    rng = np.random.default_rng(2)
    mu, a = np.r_[rng.random(24), 0.0], np.r_[rng.uniform(1e-3, 1.0, 24), 0.02]
    lo = lut.albedo_integrals(mu, a, mode="conductor", n_u=8, n_phi=4)
    hi = lut.albedo_integrals(mu, a, mode="conductor", n_u=16, n_phi=8)
    ref = lut.albedo_integrals(mu, a, mode="conductor", n_u=48, n_phi=24)
    assert np.all(np.abs(hi - ref) <= np.abs(hi - lo) + 1e-12)
    assert np.max(np.abs(hi - ref)) < 1e-4


# --------------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------------


def test_mappings_invert_and_keep_the_ends_exact():
    for name in lut.MAPPINGS:
        lo, hi = (1e-4, 1.0) if name == "log" else (0.0, 1.0)
        ax = lut.Axis("x", lo, hi, 17, name, "")
        t = np.linspace(0, 1, 17)
        assert np.allclose(ax.to_t(ax.to_x(t)), t, atol=1e-12)
        x = ax.nodes()
        assert {x[0], x[-1]} == {lo, hi}
        assert np.all(np.diff(x) < 0) if name == "u8" else np.all(np.diff(x) > 0)


def test_lookup_is_exact_at_samples_and_for_functions_linear_in_t():
    table = lut.bake(lut.make_spec("D", size=(9, 5), mappings=("u8", "sqrt")), "float",
                     check_points=0)
    nodes = lut.grid_coords(table.axes)
    assert np.allclose(lut.lookup(table, nodes), table.values.reshape(-1, 1), rtol=0, atol=0)
    t = np.random.default_rng(0).random((50, 2))
    t[:, 0] = 0.1 + 0.9 * t[:, 0]  # u8 axis: x = 1 - t^8 keeps no digits of t below ~0.01
    x = np.stack([a.to_x(t[:, k]) for k, a in enumerate(table.axes)], -1)
    T = np.stack(np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 5)), -1)
    lin = table._replace(values=(2 * T[..., 0] - 3 * T[..., 1])[..., None])
    assert np.allclose(lut.lookup(lin, x)[:, 0], 2 * t[:, 0] - 3 * t[:, 1], atol=1e-8)


def test_D_table_values_and_normalization():
    table = lut.bake(lut.make_spec("D", size=(129, 33), mappings=("u8", "log")), "float",
                     check_points=256)
    assert np.all(np.isfinite(table.values)) and np.all(table.values >= 0)
    # first row is α = 1e-4 (hard case); the u8 axis starts at cos θh = 1
    a = table.axes[1].nodes()
    assert np.isclose(a[0], 1e-4) and table.axes[0].nodes()[0] == 1.0
    m = np.array([0.0, 0.0, 1.0])
    assert np.allclose(table.values[:, 0, 0], np.pi * a**2 * np.asarray(D_GGX(m, a)), rtol=1e-6)
    # ∫ D cos θh dω = 1 from the table (α = 0.3 row, exact at the sample points)
    row = np.argmin(np.abs(a - 0.3))
    x, w = quadrature.gauss_legendre(400, 0.0, 1.0)
    vals = lut.lookup(table, np.stack([x, np.full_like(x, a[row])], -1))[:, 0]
    assert np.isclose(2 * np.pi * np.sum(w * x * vals / (np.pi * a[row] ** 2)), 1.0, rtol=2e-3)
    acc = table.accuracy
    assert acc["interpolation"]["points"] == 256 and np.isfinite(acc["interpolation"]["max_rel"])


def test_fresnel_tables():
    t = lut.bake(lut.make_spec("fresnel", params=lut.conductor_preset("copper")), "half")
    assert t.values.shape == (1, 128, 3) and t.channels == ("R", "G", "B")
    f0 = [schlick_f0(n, k) for n, k in zip((0.213, 1.04, 1.17), (4.05, 2.59, 2.36))]
    assert np.allclose(t.values[0, -1], f0, rtol=1e-3)  # cos θ = 1: normal incidence
    assert np.allclose(t.values[0, 0], 1.0, atol=1e-3)  # grazing
    assert t.accuracy["interpolation"]["max_rel"] < 5e-3
    d = lut.bake(lut.make_spec("fresnel", params={"Y": {"eta": 1.5}}), "float")
    assert d.channels == ("F_outside", "F_inside")
    cos = d.axes[0].nodes()
    crit = np.sqrt(1 - 1 / 1.5**2)
    assert np.all(d.values[0, cos < crit - 1e-9, 1] == 1.0)  # total internal reflection
    assert np.all(d.values[0, :, 0] < d.values[0, :, 1] + 1e-12)


def test_albedo_tables_are_finite_and_store_their_accuracy():
    t = lut.bake(lut.make_spec("albedo_conductor", size=(6, 5), orders=SMALL), "float",
                 check_points=16)
    assert t.values.shape == (5, 6, 2) and np.all(np.isfinite(t.values))
    assert np.all(t.values <= 1 + 1e-6) and np.all(t.values > 0)
    assert np.allclose(t.values[:, :, 1], t.values[:, :1, 1])  # E_avg constant along μ
    q = t.accuracy["quadrature"]
    assert q["orders"] == SMALL and 0 <= q["max_abs_error_estimate"] < 5e-2  # deliberately low orders
    d = lut.bake(lut.make_spec("albedo_dielectric", size=(4, 3, 2), eta_range=(1.001, 2.5),
                               orders=SMALL), "half", check_points=4)
    assert d.values.shape == (3 * 2, 4, 8) and np.all(np.isfinite(d.values))
    R, T = d.values[..., 0::2][..., :2], d.values[..., 1::2][..., :2]
    assert np.all(R + T <= 1 + 2e-3)
    g = lut.bake(lut.make_spec("dfg", size=(4, 4), orders=SMALL), "float", check_points=8)
    assert g.channels == ("scale", "bias") and np.all(g.values >= 0)


def test_model_table_matches_the_model_at_its_samples():
    params = {"Y": {"alpha": 0.25, "eta": 1.5}}
    t = lut.bake(lut.make_spec("model", model="rough_dielectric", params=params, size=(16, 8)),
                 "float", check_points=64)
    ch, cd = (a.nodes() for a in t.axes)
    CD, CH = np.meshgrid(cd, ch, indexing="ij")
    wi, wo = lut.halfdiff_directions(CH.ravel(), CD.ravel())
    f = np.asarray(fitlab.eval_bsdf("rough_dielectric", params["Y"], wi, wo))
    assert np.allclose(t.values.reshape(-1), f, rtol=1e-6)
    # the half/difference coordinates of the directions are the axis coordinates
    h, d = lut.halfdiff_coordinates(wi, wo)
    assert np.allclose(h, np.clip(CH.ravel(), lut.MU_MIN, 1), atol=1e-9)
    assert np.allclose(d, np.clip(CD.ravel(), lut.MU_MIN, 1), atol=1e-9)
    assert "parameterization" in t.accuracy
    assert any("transmits" in n for n in t.notes)


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("call,match", [
    (lambda: lut.make_spec("E"), "unknown table kind"),
    (lambda: lut.make_spec("D", size=(1, 4)), r"size must be an integer in \[2, 4096\]"),
    (lambda: lut.make_spec("D", size=(5000, 4)), "size must be"),
    (lambda: lut.make_spec("D", size=(4,)), "has 2 axes"),
    (lambda: lut.make_spec("D", mappings=("cubic", "linear")), "unknown mapping"),
    (lambda: lut.make_spec("D", mappings=("log", "linear")), "log mapping needs lo > 0"),
    (lambda: lut.make_spec("D", alpha_range=(0.0, 1.0)), "alpha: the range must lie"),
    (lambda: lut.make_spec("fresnel"), "needs a material"),
    (lambda: lut.make_spec("fresnel", params={"Y": {"n": 1.0}}), "needs n and k"),
    (lambda: lut.make_spec("model"), "needs a model"),
    (lambda: lut.make_spec("model", model="rough_conductor", params={"Y": {"alpha": 0.1}}),
     "needs values for"),
    (lambda: lut.make_spec("albedo_dielectric", eta_range=(1.0, 2.0)), "eta: the range"),
    (lambda: lut.make_spec("albedo_conductor", options={"distribution": "phong"}),
     "support the distributions"),
    (lambda: lut.bake(lut.make_spec("model", model="rough_conductor", size=(64, 8),
                                    params={"Y": {"alpha": 1e-3, "n": 0.2, "k": 3.9}}), "half"),
     "beyond the largest half float"),
    (lambda: lut.bake(lut.make_spec("D", size=(4096, 4096)), "float"), None),
])
def test_bad_input_is_refused_with_a_clear_message(call, match):
    if match is None:  # too many texels: refused before any evaluation
        with pytest.raises(ValueError, match="at most"):
            lut.bake(lut.make_spec("D", size=(4096, 4096))._replace(
                axes=(lut.Axis("cos_theta_h", 0, 1, 4096, "u8", ""),
                      lut.Axis("alpha", 1e-4, 1, 4096, "linear", ""),
                      lut.Axis("x", 0, 1, 2, "linear", ""))), "float")
        return
    with pytest.raises(ValueError, match=match):
        spec = call()
        if isinstance(spec, lut.Spec):  # albedo distribution errors surface when evaluating
            spec.evaluate(np.array([[0.5, 0.5]]))


# --------------------------------------------------------------------------------------------
# the kinds registry: every kind carries its maker and what it needs from a model or fit
# --------------------------------------------------------------------------------------------


def test_every_kind_makes_its_own_spec_through_the_registry():
    from fitlab.microfacet import DISTRIBUTIONS

    params = {"fresnel": {"Y": {"eta": 1.5}},
              "model": {"Y": {"alpha": 0.3, "n": 1.2, "k": 3.0}}}
    for name, kind in lut.KINDS.items():
        assert kind.name == name and len(kind.axis_names) == kind.n_axes
        assert len(kind.default_size) == len(kind.default_mappings) == kind.n_axes
        assert set(kind.distributions) <= set(DISTRIBUTIONS)  # names from the registry
        sizes = (3,) * kind.n_axes
        options, p = kind.prepare("rough_conductor", {}, params.get(name, {}))
        spec = kind.make(sizes, kind.default_mappings, model="rough_conductor", params=p,
                         options=options, alpha_range=(0.01, 1.0), eta_range=(1.1, 2.0),
                         orders=SMALL)
        assert isinstance(spec, lut.Spec) and spec.kind == name
        assert tuple(a.name for a in spec.axes) == kind.axis_names
        assert lut.make_spec(name, size=sizes, model="rough_conductor", params=p,
                             options=options, orders=SMALL).kind == name


def test_distribution_kinds_take_their_distributions_from_the_registry():
    from fitlab.microfacet import DISTRIBUTIONS

    assert lut.KINDS["D"].distributions == tuple(DISTRIBUTIONS)
    for name in ("albedo_conductor", "albedo_dielectric", "dfg"):
        kind = lut.KINDS[name]
        assert kind.distributions == lut.ALBEDO_DISTRIBUTIONS
        assert set(kind.distributions) < set(DISTRIBUTIONS) and "phong" not in kind.distributions
        # a fit's other options and its parameters do not enter a distribution table
        options, params = kind.prepare("rough_conductor", {"distribution": "beckmann",
                                                           "fresnel": "schlick"},
                                       {"Y": {"alpha": 0.1}})
        assert options == {"distribution": "beckmann"} and params == {}
        with pytest.raises(ValueError, match="phong"):
            kind.prepare(None, {"distribution": "phong"}, {})
    with pytest.raises(ValueError, match="is unknown; use ggx"):
        lut.KINDS["D"].prepare(None, {"distribution": "cauchy"}, {})
    assert lut.KINDS["D"].prepare(None, {}, {}) == ({"distribution": "ggx"}, {})


def test_fresnel_and_model_kinds_prepare_what_they_need():
    fresnel = lut.KINDS["fresnel"]
    # plain and sum-qualified names (a composite's base.n), conductor or dielectric
    _, p = fresnel.prepare("x", {}, {"R": {"base.n": 0.2, "base.k": 3.9, "alpha": 0.1},
                                     "G": {"eta": 1.5}})
    assert p == {"R": {"n": 0.2, "k": 3.9}, "G": {"eta": 1.5}}
    with pytest.raises(ValueError, match="needs conductor n and k"):
        fresnel.prepare("lambertian", {}, {"Y": {"albedo": 0.5}})
    assert fresnel.preset("copper") == lut.conductor_preset("copper")
    assert all(k.preset is None for n, k in lut.KINDS.items() if n != "fresnel")
    model = lut.KINDS["model"]
    with pytest.raises(ValueError, match="needs --from-fit"):
        model.prepare(None, {}, {})
    assert model.prepare("lambertian", {"a": 1}, {"Y": {"albedo": 0.5}}) == (
        {"a": 1}, {"Y": {"albedo": 0.5}})


def test_spec_of_table_rebuilds_every_kind():
    for name, kw in [("D", {}), ("fresnel", {"params": {"Y": {"eta": 1.5}}}),
                     ("dfg", {"orders": SMALL}),
                     ("model", {"model": "lambertian", "params": {"Y": {"albedo": 0.5}}})]:
        size = (4,) * lut.KINDS[name].n_axes
        table = lut.bake(lut.make_spec(name, size=size, **kw), "float", check_points=4)
        spec = lut.spec_of_table(table)
        assert spec.kind == name and spec.axes == table.axes and spec.params == table.params
        assert ("parameterization" in table.accuracy) == (name == "model")
