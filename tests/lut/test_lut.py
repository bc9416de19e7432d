"""Lookup tables (fitlab.lut) and quadrature (fitlab.quadrature): rules, albedo integrals against
independent Monte Carlo through the models' own samplers, physical limits, table contents, the
stored accuracy, and bad input. Small sizes and orders keep this file fast."""

from __future__ import annotations

from pathlib import Path

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


@pytest.mark.slow
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
# the model table's φd axis (Rusinkiewicz's difference azimuth) and --phi-d auto
# --------------------------------------------------------------------------------------------

VINYL_WW = Path(__file__).resolve().parents[2] / "fits" / "brown_vinyl_weidlich_wilkie_lambert.json"


def _vinyl():
    from fitlab.export.lut_files import from_fit

    model, options, params = from_fit(VINYL_WW)
    return dict(model=model, options=options, params=params)


def test_phi_d_directions_at_90_degrees_are_the_2d_slice():
    rng = np.random.default_rng(4)
    ch, cd = rng.random(500), rng.random(500)
    ch[:3], cd[:3] = (0.0, 1.0, 1e-9), (1.0, 0.0, 0.5)
    # the 2D table's directions as written before the φd axis existed (lut_exr.md)
    c, d = np.clip(ch, lut.MU_MIN, 1), np.clip(cd, lut.MU_MIN, 1)
    sh, sd = np.sqrt(1 - c * c), np.sqrt(1 - d * d)
    wi2 = np.stack([sh * d, sd, c * d], -1)
    wo2 = np.stack([sh * d, -sd, c * d], -1)
    for wi, wo in (lut.halfdiff_directions(ch, cd), lut.halfdiff_directions(ch, cd, 90.0)):
        np.testing.assert_allclose(wi, wi2, rtol=0, atol=1e-15)
        np.testing.assert_allclose(wo, wo2, rtol=0, atol=1e-15)
    wi, wo = lut.halfdiff_directions(ch, cd)
    assert np.array_equal(wi, lut.halfdiff_directions(ch, cd, 90.0)[0])


def test_phi_d_directions_round_trip_and_fold():
    rng = np.random.default_rng(5)
    ch, cd, phi = rng.random(4000), rng.random(4000), 180.0 * rng.random(4000)
    wi, wo = lut.halfdiff_directions(ch, cd, phi)
    assert np.allclose(np.linalg.norm(wi, axis=-1), 1) and np.allclose(np.linalg.norm(wo, axis=-1), 1)
    assert np.all(wi[:, 2] >= lut.MU_MIN * 0.999) and np.all(wo[:, 2] >= lut.MU_MIN * 0.999)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    assert np.allclose(np.einsum("ij,ij->i", wo, h), np.einsum("ij,ij->i", wi, h))  # wo = reflect
    # where both directions are above the horizon the shader's coordinates give back the inputs
    up = (ch * cd - np.sqrt(1 - ch**2) * np.sqrt(1 - cd**2) * np.abs(np.cos(np.radians(phi)))) > 1e-6
    assert 0.3 < up.mean() < 0.45  # most of the (cos θh, cos θd, φd) box lies beyond the horizon
    got = lut.model_coordinates((None, None, lut.Axis("phi_d", 0, 180, 2, "linear", "")), wi, wo)
    np.testing.assert_allclose(got[up], np.stack([ch, cd, phi], -1)[up], atol=1e-9)
    # the folds: φd and -φd (mirror) are one coordinate; swapping wi and wo gives 180° - φd,
    # which a reciprocal table folds back; a whole rotation about the normal changes nothing
    f180 = lut.phi_d_of(wi, wo, reciprocal=False)
    assert np.allclose(lut.phi_d_of(wi * [1, -1, 1], wo * [1, -1, 1], reciprocal=False), f180)
    assert np.allclose(lut.phi_d_of(wo, wi, reciprocal=False)[up], 180 - f180[up], atol=1e-9)
    assert np.allclose(lut.phi_d_of(wo, wi)[up], lut.phi_d_of(wi, wo)[up], atol=1e-9)
    a = 1.234
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    assert np.allclose(lut.phi_d_of(wi @ rot.T, wo @ rot.T), lut.phi_d_of(wi, wo), atol=1e-8)
    # beyond the horizon a (θh, θd, φd) holds the value at the horizon on the same side
    i = np.flatnonzero(~up)[0]
    w_edge = lut.halfdiff_directions(ch[i], cd[i], phi[i])[0]
    assert min(w_edge[2], lut.halfdiff_directions(ch[i], cd[i], phi[i])[1][2]) < 1e-6


def test_the_3d_table_is_the_model_at_its_samples_and_folds_by_reciprocity():
    p = {"Y": {"albedo": 0.5, "sigma": 0.4}}
    t = lut.bake(lut.make_spec("model", model="oren_nayar", params=p, size=(8, 6, 5)), "float",
                 check_points=64)
    assert t.values.shape == (6 * 5, 8, 1) and [a.name for a in t.axes][2] == "phi_d"
    assert (t.axes[2].lo, t.axes[2].hi, t.axes[2].mapping) == (0.0, 90.0, "linear")
    coords = lut.grid_coords(t.axes)
    wi, wo = lut.halfdiff_directions(*coords.T)
    f = np.asarray(fitlab.eval_bsdf("oren_nayar", p["Y"], wi, wo))
    assert np.allclose(t.values.reshape(-1), f, rtol=1e-6)
    # the φd = 90° slice (the last one) is the 2D table
    t2 = lut.bake(lut.make_spec("model", model="oren_nayar", params=p, size=(8, 6)), "float",
                  check_points=0)
    assert np.array_equal(t.values[-6:], t2.values)
    # f(φd) = f(180° - φd) for the reciprocal model: what the [0°, 90°] range relies on
    wi2, wo2 = lut.halfdiff_directions(*coords[:, :2].T, 180.0 - coords[:, 2])
    assert np.allclose(np.asarray(fitlab.eval_bsdf("oren_nayar", p["Y"], wi2, wo2)), f, rtol=1e-9)
    assert any("3D" in n for n in t.notes)


def test_a_model_without_declared_reciprocity_gets_phi_d_up_to_180_degrees():
    base = fitlab.get_model("oren_nayar")
    m = base._replace(name="oren_nayar_unreciprocal_lut_test",
                      capabilities=base.capabilities._replace(reciprocal=False))
    fitlab.models.register_model(m, replace=True)
    t = lut.bake(lut.make_spec("model", model=m.name, params={"Y": {"albedo": 0.5, "sigma": 0.4}},
                               size=(8, 6, 9)), "float", check_points=256)
    assert t.axes[2].hi == 180.0 and "[0°, 180°]" in t.axes[2].description
    rng = np.random.default_rng(0)
    wi, wo = (fitlab.lut.kinds._hemisphere(rng.random((200, 2))) for _ in range(2))
    c = lut.model_coordinates(t.axes, wi, wo)
    assert c[:, 2].max() > 90 and np.allclose(c[:, 2], lut.phi_d_of(wi, wo, reciprocal=False))


def test_the_3d_table_of_a_layered_fit_is_more_accurate_than_the_2d_slice():
    """Brown vinyl, Weidlich–Wilkie over Lambert (fits/): the 2D table is the model at
    φd = 90° only; the φd axis removes that error (measured at the same random pairs)."""
    v = _vinyl()
    # 96 x 96: the fit of 18d4d64's Weidlich–Wilkie (measured 2D RMS 0.039, max 0.157; 3D RMS
    # 0.0036, max 0.028) needs it, its 3D table at 64 x 64 x 8 is 5.5% max off (target 5%);
    # the bounds are about 0.63 (2D) and 0.6-0.7 (ratios) of the measured figures
    t2 = lut.bake(lut.make_spec("model", size=(96, 96), **v), "float", check_points=512)
    t3 = lut.bake(lut.make_spec("model", size=(96, 96, 8), **v), "float", check_points=512)
    p2, p3 = t2.accuracy["parameterization"], t3.accuracy["parameterization"]
    print(f"\nbrown vinyl WW: 2D 96x96 RMS {p2['rms_rel']:.3g} max {p2['max_rel']:.3g}; "
          f"3D 96x96x8 RMS {p3['rms_rel']:.3g} max {p3['max_rel']:.3g}")
    assert p2["rms_rel"] > 0.024 and p2["max_rel"] > 0.098 and not p2["meets_target"]
    assert p3["rms_rel"] < p2["rms_rel"] / 7 and p3["max_rel"] < p2["max_rel"] / 3
    assert p3["meets_target"]


def test_auto_adds_phi_d_for_the_layered_fit_and_states_both_errors():
    v = _vinyl()
    # 96 x 96 (48 x 48 before 18d4d64's Weidlich–Wilkie fit: its 3D table there is 7.2% max off)
    t = lut.bake_auto("model", size=(96, 96, 8), dtype="half", check_points=512, **v)
    a = t.accuracy["auto"]
    assert len(t.axes) == 3 and a["chosen"] == "96x96x8" and a["check"] == "parameterization"
    (c2, c3) = a["candidates"]
    assert c2["size"] == "96x96" and not c2["meets_target"] and c3["meets_target"]
    assert c3["rms_rel"] == t.accuracy["parameterization"]["rms_rel"] < c2["rms_rel"]
    assert a["target"] == lut.PHI_D_TARGET and "misses the target" in a["reason"]
    assert a["meets_target"] is True
    assert any("chosen by measurement" in n for n in t.notes)


def test_auto_keeps_2d_when_f_depends_on_theta_h_and_theta_d_only():
    """A Lambertian f is exact in 2D: auto keeps the 2D table and says why. (A Walter
    microfacet conductor is not such a model: at fixed (θh, θd) its 1/(4 cos θi cos θo) and G
    depend on φd, cos θi cos θo = cos²θh cos²θd - sin²θh sin²θd cos²φd; its 2D table misses
    the target by far at α = 0.3, below.)"""
    t = lut.bake_auto("model", model="lambertian", params={"Y": {"albedo": 0.5}}, size=(8, 8),
                      check_points=256)
    a = t.accuracy["auto"]
    assert len(t.axes) == 2 and len(a["candidates"]) == 1 and a["chosen"] == "8x8"
    assert "meets the target" in a["reason"] and a["meets_target"] is True
    c = lut.bake_auto("model", model="rough_conductor",
                      params={"Y": {"alpha": 0.3, "n": 0.2, "k": 3.9}}, size=(64, 64, 8),
                      check_points=256)
    c2, c3 = c.accuracy["auto"]["candidates"]
    assert c2["rms_rel"] > 0.05 and c3["rms_rel"] < c2["rms_rel"] / 5 and len(c.axes) == 3


def test_auto_says_when_the_3d_table_misses_too_and_keeps_2d_when_3d_measures_worse(
        monkeypatch):
    v = _vinyl()
    # two φd samples (0° and 90°) interpolate linearly across the whole range: better than
    # the slice, still short of the target
    t = lut.bake_auto("model", size=(32, 32, 2), check_points=256, **v)
    assert len(t.axes) == 3 and "misses the target too" in t.accuracy["auto"]["reason"]
    assert t.accuracy["auto"]["meets_target"] is False  # fitlab lut writes nothing then
    # a 3D candidate that measured worse than the slice would not be kept
    real = lut.kinds.parameterization_error

    def worse_in_3d(table, spec, n, seed=1):
        r = real(table, spec, n, seed)
        return {**r, "rms_rel": r["rms_rel"] * (1e3 if len(table.axes) == 3 else 1)}

    monkeypatch.setattr(lut.kinds, "parameterization_error", worse_in_3d)
    t = lut.bake_auto("model", size=(32, 32, 4), check_points=128, **v)
    assert len(t.axes) == 2 and "the 2-axis table kept" in t.accuracy["auto"]["reason"]
    assert len(t.accuracy["auto"]["candidates"]) == 2


def test_spec_of_a_3d_model_table_rebuilds_it():
    t = lut.bake(lut.make_spec("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                               size=(4, 3, 2)), "float", check_points=4)
    spec = lut.spec_of_table(t)
    assert spec.axes == t.axes and len(spec.axes) == 3


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("call,match", [
    (lambda: lut.make_spec("E"), "unknown table kind"),
    (lambda: lut.make_spec("D", size=(1, 4)), r"size must be an integer in \[2, 4096\]"),
    (lambda: lut.make_spec("D", size=(5000, 4)), "size must be"),
    (lambda: lut.make_spec("D", size=(4,)), "has 2 axes"),
    (lambda: lut.make_spec("D", size=(4, 4, 4)), "has 2 axes"),
    (lambda: lut.make_spec("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                           size=(4, 4, 4, 4)), r"2 axes \(cos_theta_h, cos_theta_d\) or 3 \(with phi_d\)"),
    (lambda: lut.make_spec("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                           size=(4, 4, 1)), r"axis phi_d: size must be an integer in \[2, 4096\]"),
    (lambda: lut.make_spec("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                           size=(4, 4, 4), mappings=("u8", "linear")), "needs 3 mappings"),
    (lambda: lut.make_spec("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                           size=(4, 4, 4), mappings=("u8", "linear", "log")),
     "log mapping needs lo > 0"),
    (lambda: lut.bake_auto("model", model="lambertian", params={"Y": {"albedo": 0.5}},
                           size=(4, 4), check_points=0), "needs the accuracy check"),
    (lambda: lut.bake_auto("D"), "no optional axis"),
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
              "model": {"Y": {"alpha": 0.3, "n": 1.2, "k": 3.0}},
              "thin_layer": {"Y": {"eta": 1.5, "tau": 0.1, "n2": 1.2, "k2": 3.0}},
              "thin_layer_compensation": {"Y": {"eta": 1.5, "tau": 0.1, "n2": 1.2, "k2": 3.0}}}
    models = {"thin_layer": "thin_layer(rough_conductor)",
              "thin_layer_compensation": "thin_layer(rough_conductor)"}
    for name, kind in lut.KINDS.items():
        model = models.get(name, "rough_conductor")
        assert kind.name == name and len(kind.axis_names) == kind.n_axes
        assert len(kind.default_size) == len(kind.default_mappings) == kind.n_axes
        assert kind.axis_counts == tuple(range(kind.n_axes, len(kind.all_axis_names) + 1))
        assert (kind.auto_check is None) == (not kind.extra_axes)
        assert set(kind.distributions) <= set(DISTRIBUTIONS)  # names from the registry
        sizes = (3,) * kind.n_axes
        options, p = kind.prepare(model, {}, params.get(name, {}))
        spec = kind.make(sizes, kind.default_mappings, model=model, params=p,
                         options=options, alpha_range=(0.01, 1.0), eta_range=(1.1, 2.0),
                         orders=SMALL)
        assert isinstance(spec, lut.Spec) and spec.kind == name
        assert tuple(a.name for a in spec.axes) == kind.axis_names
        assert lut.make_spec(name, size=sizes, model=model, params=p,
                             options=options, orders=SMALL).kind == name
        if kind.extra_axes:  # the optional axes: more sizes, their names from the registry
            full = lut.make_spec(name, size=(3,) * len(kind.all_axis_names),
                                 model=model, params=p, options=options)
            assert tuple(a.name for a in full.axes) == kind.all_axis_names
            assert tuple(a.mapping for a in full.axes) == kind.all_default_mappings
    assert lut.KINDS["model"].extra_axes == (("phi_d", lut.PHI_D_SIZE, "linear"),)


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
