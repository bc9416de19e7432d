"""Statistical validation of ``fitlab simulate`` against analytic results (issue 7, "Validation").

Every comparison is a χ² or z test of the Monte Carlo estimate against its own standard error,
with fixed seeds, so the tests are deterministic. Sample counts are modest (each test runs in
seconds after compilation); the bins compared are those expected to collect at least 100 paths,
where the normal approximation of the estimator holds.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import fitlab  # noqa: F401  (x64)
from fitlab.fresnel import fresnel_dielectric_Walter2007
from fitlab.models import rough_dielectric
from fitlab.simulate import detectors, scene_from_dict, simulate

pytestmark = pytest.mark.slow


def _fresnel(cos, eta):
    return np.asarray(fresnel_dielectric_Walter2007(jnp.asarray(cos, dtype=jnp.float64),
                                                    jnp.asarray(eta, dtype=jnp.float64)))


def _chi2_pvalue(value, expected, sigma, mask):
    z = (value - expected) / np.where(mask, sigma, 1.0)
    chi2 = float(np.sum(z[mask] ** 2))
    return stats.chi2.sf(chi2, int(mask.sum())), chi2, int(mask.sum())


def _bin_average(f, theta_i, theta_c, phi_c, dtheta, dphi, cw, n=12):
    """(1/∫cos) ∫_bin f |cos θo| dω by an n×n midpoint rule; theta_c > 90 = transmission side."""
    refl = theta_c < 90
    tc = theta_c if refl else 180.0 - theta_c
    t = np.radians(tc - dtheta / 2 + (np.arange(n) + 0.5) / n * dtheta)
    p = np.radians(phi_c - dphi / 2 + (np.arange(n) + 0.5) / n * dphi)
    T, P = np.meshgrid(t, p, indexing="ij")
    wo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T) * (1 if refl else -1)], -1)
    wi = np.broadcast_to(detectors.direction(theta_i, 0.0), wo.shape)
    val = f(wi, wo)
    return float(np.sum(val * np.cos(T) * np.sin(T)) * np.radians(dtheta) / n * np.radians(dphi) / n / cw)


@pytest.mark.parametrize("theta_i", [0.0, 50.0])
def test_rough_dielectric_interface_matches_walter_brdf_btdf(theta_i):
    """One GGX interface (α = 0.3, η = 1.5): every well-populated (θo, φo) bin, reflection and
    transmission, χ²-consistent with the bin average of Walter's f_r + f_t (eqs 20-21)."""
    T, P, N = 9, 12, 300_000
    scene = scene_from_dict({
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.3}],
        "below": {"index": 1.5}, "illumination": {"theta_i": [theta_i]},
        "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P}})
    r = simulate(scene, N, seed=11)
    rows = detectors.hemisphere_rows(T, P, ("reflection", "transmission"))
    f = lambda wi, wo: np.asarray(rough_dielectric.MODEL.eval(  # noqa: E731
        {"alpha": 0.3, "eta": 1.5}, jnp.asarray(wi), jnp.asarray(wo)))
    expected = np.array([_bin_average(f, theta_i, t, p, 90 / T, 360 / P, cw)
                         for t, p, cw in zip(r.theta_o, r.phi_o, rows.cos_solid_angle)])
    counts = expected * rows.cos_solid_angle * N
    mask = (counts > 100) & (r.sigma[:, 0] > 0)
    assert mask.sum() > 40 and (mask & (r.theta_o > 90)).sum() > 20
    p, chi2, dof = _chi2_pvalue(r.value[:, 0], expected, r.sigma[:, 0], mask)
    assert p > 1e-3, (chi2, dof)
    # the whole flux: R + T equals the interface's directional albedo (energy lost by the
    # single-scattering microfacet model only), computed by quadrature of eval
    albedo = np.sum(expected * rows.cos_solid_angle)
    total = r.energy[0, :, 0].sum()
    err = np.hypot(r.energy_sigma[0, 0, 0], r.energy_sigma[0, 1, 0])
    assert abs(total - albedo) < 4 * err + 2e-3, (total, albedo, err)


def _slab_scene(sigma_a, theta_i, thickness=1.0, **effects):
    return scene_from_dict({
        "stack": [{"type": "interface", "distribution": "smooth"},
                  {"type": "medium", "index": 1.5, "thickness": thickness, "sigma_a": sigma_a},
                  {"type": "interface", "distribution": "smooth"}],
        "illumination": {"theta_i": [theta_i]},
        "detector": {"type": "hemisphere", "theta_bins": 6, "phi_bins": 4},
        "effects": effects})


def test_absorbing_smooth_slab_energy_and_bounce_orders_match_the_closed_form():
    """Smooth slab (η = 1.5, σa d = 0.3) at 35°: every internal path keeps the refraction angle,
    so with F = F(θi) (equal at both faces) and τ = exp(-σa d / cos θt):
    R_k (k bounces) = (1 - F)² F^(2k-1) τ^(2k), R_0 = F, T = (1 - F)² τ / (1 - F² τ²),
    absorbed = 1 - R - T (the independent estimate of the missing energy)."""
    N, ti = 200_000, 35.0
    r = simulate(_slab_scene(0.3, ti), N, seed=5)
    ci = np.cos(np.radians(ti))
    ct = np.sqrt(1 - (np.sin(np.radians(ti)) / 1.5) ** 2)
    F = float(_fresnel(ci, 1.5))
    tau = np.exp(-0.3 / ct)
    R = F + (1 - F) ** 2 * F * tau**2 / (1 - F**2 * tau**2)
    T = (1 - F) ** 2 * tau / (1 - F**2 * tau**2)
    got_R, got_T = r.energy[0, 0, 0], r.energy[0, 1, 0]
    sR, sT = r.energy_sigma[0, 0, 0], r.energy_sigma[0, 1, 0]
    assert abs(got_R - R) < 4 * sR and abs(got_T - T) < 4 * sT
    absorbed = 1 - got_R - got_T
    assert abs(absorbed - (1 - R - T)) < 4 * np.hypot(sR, sT)
    assert absorbed > 0.15  # the test means something
    # reflected flux per bounce order: orders 0, 1, 2 and the rest
    rows = detectors.hemisphere_rows(6, 4, ("reflection", "transmission"))
    refl = r.theta_o < 90
    per_order = np.sum(r.by_order[:, refl, 0] * rows.cos_solid_angle[refl], axis=1)
    expect = [F] + [(1 - F) ** 2 * F ** (2 * k - 1) * tau ** (2 * k) for k in (1, 2)]
    expect.append(R - sum(expect))
    for k in range(4):
        sig = np.sqrt(np.sum((r.sigma_by_order[k, refl, 0] * rows.cos_solid_angle[refl]) ** 2))
        assert abs(per_order[k] - expect[k]) < 4 * sig + 1e-6, (k, per_order[k], expect[k])


@pytest.mark.parametrize("phase", [{"phase": "isotropic"}, {"phase": "hg", "g": 0.7},
                                   {"phase": "sggx_fiber", "roughness": 0.3,
                                    "orientation": [1, 0, 0]}])
def test_non_absorbing_scattering_slab_conserves_energy(phase):
    """A slab with σa = 0 between smooth interfaces: reflected + transmitted = 1 within the
    Monte Carlo error (Russian roulette and every path order included)."""
    scene = scene_from_dict({
        "stack": [{"type": "interface"}, {"type": "medium", "index": 1.3, "thickness": 1.0,
                                          "sigma_s": 2.0, **phase},
                  {"type": "interface"}],
        "illumination": {"theta_i": [30.0]},
        "detector": {"type": "hemisphere", "theta_bins": 3, "phi_bins": 2}})
    r = simulate(scene, 40_000, seed=2)
    total = r.energy[0, :, 0].sum()
    # R + T of one path is its weight (1, or 1/q after roulette): its spread is the error
    err = np.hypot(*r.energy_sigma[0, :, 0])
    assert r.truncated == 0
    assert abs(total - 1.0) < 4 * err + 1e-6, (total, err)
    assert r.energy[0, 0, 0] > 0.05 and r.energy[0, 1, 0] > 0.05


def _coated_lambertian(max_bounces, theta_i, rho=0.8, n=1.5):
    return scene_from_dict({
        "stack": [{"type": "interface"}, {"type": "medium", "index": n, "thickness": 0.0}],
        "substrate": {"type": "lambertian", "albedo": rho},
        "illumination": {"theta_i": [theta_i]},
        "detector": {"type": "inplane", "theta_o": [-70, -50, -30, -10, 0, 20, 40, 60, 75],
                     "acceptance_sr": 0.01},
        "effects": {"max_bounces": max_bounces, "delta": False}})


def _internal_diffuse_reflectance(n):
    """r_i = ∫ F(θ) 2 cos θ sin θ dθ for light inside (η_t/η_i = 1/n), TIR included."""
    x, w = np.polynomial.legendre.leggauss(400)
    mu = 0.5 * (x + 1)  # cos θ in (0, 1)
    return float(np.sum(0.5 * w * 2 * mu * _fresnel(mu, 1.0 / n)))


@pytest.mark.parametrize("max_bounces", [1, "all"])
def test_coated_lambertian_matches_one_bounce_formula_and_full_series(max_bounces):
    """Smooth coating (n = 1.5) over a Lambertian (ρ = 0.8), delta excluded:
    one bounce (bsdf_under_smooth_interface.txt: refracted directions, Fresnel transmittances,
    η0²/η1²): f1 = (1 - F(θi))(1 - F(θo)) ρ / (π n²); all bounces (the geometric series of
    internal reflections, r_i the internal diffuse reflectance of the smooth interface):
    f = f1 / (1 - ρ r_i)."""
    rho, n = 0.8, 1.5
    r = simulate(_coated_lambertian(max_bounces, 40.0, rho, n), 200_000, seed=8)
    Fi = _fresnel(np.cos(np.radians(40.0)), n)
    Fo = _fresnel(np.cos(np.radians(r.theta_o)), n)
    f1 = (1 - Fi) * (1 - Fo) * rho / (np.pi * n * n)
    expected = f1 if max_bounces == 1 else f1 / (1 - rho * _internal_diffuse_reflectance(n))
    p, chi2, dof = _chi2_pvalue(r.value[:, 0], expected, r.sigma[:, 0], r.sigma[:, 0] > 0)
    assert dof == 9 and p > 1e-3, (chi2, r.value[:, 0], expected)
    if max_bounces == "all":
        # the one-bounce class of the full run is the one-bounce formula, too
        p1, chi2_1, _ = _chi2_pvalue(r.by_order[1, :, 0], f1, r.sigma_by_order[1, :, 0],
                                     r.sigma[:, 0] > 0)
        assert p1 > 1e-3, chi2_1


def test_simulated_brdf_is_reciprocal():
    """A rough GGX coat over a rough conductor with a thin absorbing medium between (outside
    index on both ends): f(30° → 60°) = f(60° → 30°) in the plane of incidence, within error."""
    pairs = (20.0, 55.0)
    scene_for = lambda ti: scene_from_dict({  # noqa: E731
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.4},
                  {"type": "medium", "index": 1.4, "thickness": 0.3, "sigma_a": 0.5}],
        "substrate": {"type": "lambertian", "albedo": 0.7},
        "illumination": {"theta_i": [ti]},
        "detector": {"type": "inplane", "theta_o": [x for x in pairs if x != ti] +
                     [-x for x in pairs if x != ti], "acceptance_sr": 0.02}})
    a = simulate(scene_for(pairs[0]), 300_000, seed=21)
    b = simulate(scene_for(pairs[1]), 300_000, seed=22)
    # rows: (+θ, φo = 180°) and (-θ, φo = 0°); reciprocity pairs the same geometry swapped
    z = (a.value[:, 0] - b.value[:, 0]) / np.hypot(a.sigma[:, 0], b.sigma[:, 0])
    assert np.all(np.abs(z) < 4), (a.value[:, 0], b.value[:, 0], z)
    assert np.all(a.value[:, 0] > 0.02)


def test_bounce_limit_equals_the_low_orders_of_the_full_run():
    """Dropping an effect changes only what it should: max_bounces = 1 reproduces orders 0 + 1 of
    the full run (a two-interface rough absorbing slab, reflection bins), and a reflection-only
    detector reproduces the reflection bins of a two-sided one."""
    base = {
        "stack": [{"type": "interface", "distribution": "ggx", "alpha": 0.2},
                  {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2},
                  {"type": "interface", "distribution": "beckmann", "alpha": 0.3}],
        "illumination": {"theta_i": [30.0]},
        "detector": {"type": "hemisphere", "theta_bins": 6, "phi_bins": 4}}
    full = simulate(scene_from_dict(base), 150_000, seed=1)
    one = simulate(scene_from_dict({**base, "effects": {"max_bounces": 1}}), 150_000, seed=2)
    refl_only = simulate(scene_from_dict({**base, "detector": {**base["detector"],
                                                             "sides": ["reflection"]}}),
                         150_000, seed=3)
    refl = full.theta_o < 90
    low = full.by_order[0] + full.by_order[1]
    low_sig = np.hypot(full.sigma_by_order[0], full.sigma_by_order[1])
    mask = (low_sig[:, 0] > 0) & (one.sigma[:, 0] > 0) & refl
    z = (one.value[mask, 0] - low[mask, 0]) / np.hypot(one.sigma[mask, 0], low_sig[mask, 0])
    assert stats.chi2.sf(np.sum(z**2), z.size) > 1e-3
    # the limited run holds no higher orders at all, and less flux than the full run
    assert np.all(one.by_order[2:] == 0)
    assert one.energy[0, 0, 0] < full.energy[0, 0, 0]
    assert np.array_equal(refl_only.theta_o, full.theta_o[refl])
    fv, fs = full.value[refl, 0], full.sigma[refl, 0]
    m2 = (fs > 0) & (refl_only.sigma[:, 0] > 0)
    z2 = (refl_only.value[m2, 0] - fv[m2]) / np.hypot(refl_only.sigma[m2, 0], fs[m2])
    assert stats.chi2.sf(np.sum(z2**2), z2.size) > 1e-3


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_anisotropic_rough_conductor_substrate_matches_the_anisotropic_model(distribution):
    """A bare rough conductor with α_x = 0.1, α_y = 0.4 at 40° incidence from φi = 0: every
    well-populated (θo, φo) bin χ²-consistent with the bin average of
    rough_conductor_anisotropic (the azimuthal structure of the lobe included)."""
    T, P, N = 8, 16, 300_000
    params = {"alpha_x": 0.1, "alpha_y": 0.4, "n": 0.2, "k": 3.9}
    scene = scene_from_dict({
        "stack": [], "substrate": {"type": "conductor", "distribution": distribution,
                                   "alpha_x": 0.1, "alpha_y": 0.4, "n": 0.2, "k": 3.9},
        "illumination": {"theta_i": [40.0]},
        "detector": {"type": "hemisphere", "theta_bins": T, "phi_bins": P,
                     "sides": ["reflection"]}})
    r = simulate(scene, N, seed=13)
    rows = detectors.hemisphere_rows(T, P, ("reflection",))
    model = fitlab.get_model("rough_conductor_anisotropic")
    f = lambda wi, wo: np.asarray(model.eval(  # noqa: E731
        params, jnp.asarray(wi), jnp.asarray(wo), distribution=distribution))
    expected = np.array([_bin_average(f, 40.0, t, p, 90 / T, 360 / P, cw)
                         for t, p, cw in zip(r.theta_o, r.phi_o, rows.cos_solid_angle)])
    mask = (expected * rows.cos_solid_angle * N > 100) & (r.sigma[:, 0] > 0)
    assert mask.sum() > 30
    p, chi2, dof = _chi2_pvalue(r.value[:, 0], expected, r.sigma[:, 0], mask)
    assert p > 1e-3, (chi2, dof)
    # the anisotropy shows: the lobe is wider along y than along x
    iso = fitlab.get_model("rough_conductor")
    f_iso = np.array([_bin_average(lambda wi, wo: np.asarray(iso.eval(
        {"alpha": 0.25, "n": 0.2, "k": 3.9}, jnp.asarray(wi), jnp.asarray(wo),
        distribution=distribution)), 40.0, t, ph, 90 / T, 360 / P, cw)
        for t, ph, cw in zip(r.theta_o, r.phi_o, rows.cos_solid_angle)])
    assert _chi2_pvalue(r.value[:, 0], f_iso, r.sigma[:, 0], mask)[0] < 1e-6
