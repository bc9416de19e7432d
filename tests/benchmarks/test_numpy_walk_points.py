"""The NumPy peer of the simulator (benchmarks/numpy_walk.py): its point estimates
(``simulate_numpy_points``, next-event estimation at exact directions) and cone detectors
against fitlab's, and its Walter helpers against fitlab's rough dielectric model.

* one GGX interface: the first event is the only connection, so the peer's point values are
  Walter's BSDF to rounding, with no Monte Carlo spread;
* the scene of ``bench_simulate.py``'s ``throughput_scene()`` (HG slab between GGX interfaces,
  light at 30°) and the same slab under a smooth top: peer and fitlab agree within 4 combined
  standard errors at in-plane directions on both sides (independent walks, independent random
  numbers), and their standard errors are those of the same estimator;
* the peer's points against the peer's own narrow cones, and its cones against fitlab's.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.models import rough_dielectric
from fitlab.simulate import scene_from_dict, simulate
from fitlab.simulate.detectors import direction

_SPEC = importlib.util.spec_from_file_location(
    "numpy_walk", Path(__file__).resolve().parents[2] / "benchmarks" / "numpy_walk.py")
nw = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(nw)

THETA_I = 30.0
#: in-plane θo (fitlab's convention: θo >= 0 at φi + 180°, < 0 at φi, |θo| > 90°: transmission)
ARC = [-60.0, -30.0, 0.0, 20.0, 30.0, 45.0, 70.0, -110.0, -150.0, 100.0, 130.0, 150.0, 160.0,
       175.0]
MEDIUM = {"type": "medium", "index": 1.5, "thickness": 1.0, "sigma_a": 0.2, "sigma_s": 0.8,
          "phase": "hg", "g": 0.5}
REGIONS = [{"index": 1.0}, {"index": 1.5, "thickness": 1.0, "sigma_a": 0.2, "sigma_s": 0.8,
                            "g": 0.5}, {"index": 1.0}]
TOPS = {"ggx": ({"type": "interface", "distribution": "ggx", "alpha": 0.2},
                {"kind": "ggx", "alpha": 0.2}),
        "smooth": ({"type": "interface", "distribution": "smooth"}, {"kind": "smooth"})}
BOTTOM = ({"type": "interface", "distribution": "ggx", "alpha": 0.3},
          {"kind": "ggx", "alpha": 0.3})


def _scene(top, detector):
    """bench_simulate.throughput_scene() with the given top interface and detector."""
    return scene_from_dict({"name": "HG slab between interfaces",
                            "stack": [TOPS[top][0], MEDIUM, BOTTOM[0]],
                            "illumination": {"theta_i": [THETA_I]}, "detector": detector})


def _inplane(theta_o):
    t = np.asarray(theta_o, float)
    return direction(np.abs(t), np.where(t >= 0, 180.0, 0.0))


def _walter(wi, wo, alpha, eta):
    return np.asarray(rough_dielectric.MODEL.eval(
        {"alpha": jnp.float64(alpha), "eta": jnp.float64(eta)}, jnp.asarray(wi, jnp.float64),
        jnp.asarray(wo, jnp.float64)))


def test_walter_helpers_match_fitlab_model():
    """f (eqs 20/21), the sampling density (eqs 14/17/24/38) and the sampler (section 5.3,
    weight eq. 41) of the peer against fitlab.models.rough_dielectric, both sides, η < 1 too."""
    rng = np.random.default_rng(1)
    wi, wo = rng.normal(size=(2, 4000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    u = rng.random((4000, 3))
    for alpha, eta in ((0.2, 1.5), (0.5, 1 / 1.5), (0.05, 1.33)):
        params = {"alpha": jnp.float64(alpha), "eta": jnp.float64(eta)}
        f = _walter(wi, wo, alpha, eta)
        np.testing.assert_allclose(nw._walter_f(wi, wo, alpha, eta), f, rtol=1e-9, atol=1e-12)
        p = np.asarray(rough_dielectric.MODEL.pdf(params, jnp.asarray(wi), jnp.asarray(wo)))
        np.testing.assert_allclose(nw._walter_pdf(wi, wo, alpha, eta), p, rtol=1e-7, atol=1e-12)
        o, wt, q = nw._walter_sample(wi, u, alpha, eta)
        o2, wt2, q2 = (np.asarray(x) for x in
                       rough_dielectric.MODEL.sample(params, jnp.asarray(wi), jnp.asarray(u)))
        ok = wt2 > 0
        assert ok.mean() > 0.5
        np.testing.assert_allclose(o[ok], o2[ok], atol=1e-12)
        np.testing.assert_allclose(wt, wt2, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(q, q2, rtol=1e-9, atol=1e-12)
        # the sampler's density is the pdf of its direction
        np.testing.assert_allclose(nw._walter_pdf(wi[q > 0], o[q > 0], alpha, eta), q[q > 0],
                                   rtol=1e-8)


@pytest.mark.parametrize("n_above,n_below", [(1.0, 1.5), (1.5, 1.0)])
def test_one_ggx_interface_is_walters_bsdf_exactly(n_above, n_below):
    """The light's first event is the only connection: every path adds the same value, so
    the point estimate is f itself (reflection and transmission, grazing too) with no spread."""
    theta_o = [-89.0, -60.0, -30.0, 0.0, 20.0, 45.0, 70.0, 89.0, -95.0, -130.0, 95.0, 120.0,
               150.0, 179.0]
    wo = _inplane(theta_o)
    for theta_i in (0.0, 35.0, 75.0):
        wi = direction(theta_i, 0.0)
        value, sigma, events = nw.simulate_numpy_points(
            [{"index": n_above}, {"index": n_below}], [{"kind": "ggx", "alpha": 0.25}], wi,
            3000, wo, seed=4, batch=1024)
        f = _walter(np.broadcast_to(wi, wo.shape), wo, 0.25, n_below / n_above)
        assert np.count_nonzero(f) >= 5
        np.testing.assert_allclose(value, f, rtol=1e-12, atol=1e-300)
        assert np.all(sigma <= 1e-7 * value + 1e-300)
        assert events == 3000  # one event per path


def test_peer_points_against_peer_cones():
    """The peer's point estimates, averaged over each cone by quadrature (cos θ weights), against
    its own bin walk's cones of 8° half angle on the throughput scene: checks the next-event
    estimate and the cone detector of the peer without fitlab."""
    wi = direction(THETA_I, 0.0)
    theta_o = [0.0, 30.0, 45.0, 130.0, 150.0, 175.0]
    axes = _inplane(theta_o)
    cg = np.cos(np.radians(8.0))
    # midpoint rule in (cos ψ, φ) around each axis: 2 × 8 nodes per cone
    c = 1.0 - (np.arange(2) + 0.5) / 2 * (1.0 - cg)
    sn = np.sqrt(1.0 - c * c)
    phi = (np.arange(8) + 0.5) / 8 * 2.0 * np.pi
    e1, e2 = nw._basis(axes)
    nodes = (c[None, :, None, None] * axes[:, None, None, :]
             + sn[None, :, None, None] * (np.cos(phi)[None, None, :, None] * e1[:, None, None, :]
                                          + np.sin(phi)[None, None, :, None]
                                          * e2[:, None, None, :])).reshape(-1, 3)
    boundaries = [TOPS["ggx"][1], BOTTOM[1]]
    v, s, _ = nw.simulate_numpy_points(REGIONS, boundaries, wi, 1 << 14, nodes, seed=5)
    cz = np.abs(nodes[:, 2]).reshape(len(theta_o), -1)
    pv = np.sum((v.reshape(cz.shape)) * cz, 1) / cz.sum(1)
    ps = np.sum((s.reshape(cz.shape)) * cz, 1) / cz.sum(1)  # >= the average's (correlated)
    *_, cv, cs = nw.simulate_numpy(REGIONS, boundaries, wi, 1 << 17, 1, 1, seed=6,
                                   cones=(axes, cg))
    assert np.all(ps < 0.03 * pv) and np.all(cs > 0)
    dev = np.abs(cv - pv)
    assert np.all(dev <= 4.0 * np.hypot(ps, cs) + 0.005 * pv), np.c_[theta_o, pv, ps, cv, cs]
    # the cosine-weighted solid angle of a cone off the horizon is π sin²γ |axis_z|
    np.testing.assert_allclose(nw.cone_cos_solid_angle(axes, cg),
                               np.pi * (1 - cg * cg) * np.abs(axes[:, 2]), rtol=1e-3)


def _agree(res, value, sigma, z_max=4.0):
    fv, fs = res.value[:, 0], res.sigma[:, 0]
    z = (value - fv) / np.hypot(sigma, fs)
    table = np.c_[res.theta_o, res.phi_o, fv, fs, value, sigma, z]
    assert np.all(fv > 0) and np.all(value > 0), table
    assert np.all(np.abs(z) < z_max), table
    # the same estimator, fitlab sampling its GGX boundaries by visible normals (Mitsuba's
    # roughdielectric) where the peer samples D(m)|m·n| (Walter section 5.3): fitlab's relative
    # standard errors at most the peer's (same path counts; an estimate of a standard error from
    # heavy-tailed per-path sums is itself noisy, hence the loose bound)
    assert np.all((fs / fv) / (sigma / value) < 1.35), table


@pytest.mark.slow
@pytest.mark.parametrize("top", ["ggx", "smooth"])
def test_points_agree_with_fitlab(top):
    """bench_simulate's throughput scene (GGX α 0.2 / 0.3 around an HG slab) and its smooth-top
    variant (reverse refraction through the top, no vertex strategy on the reflection side):
    point estimates of the peer and of fitlab at 14 in-plane directions on both sides, within 4
    combined standard errors everywhere (fitlab's compilation dominates the time)."""
    n = 1 << 14
    res = simulate(_scene(top, {"type": "inplane", "theta_o": ARC, "estimator": "point"}), n,
                   seed=11)
    wo = direction(res.theta_o, res.phi_o)
    np.testing.assert_allclose(wo, _inplane(ARC), atol=1e-12)
    value, sigma, events = nw.simulate_numpy_points(REGIONS, [TOPS[top][1], BOTTOM[1]],
                                                    direction(THETA_I, 0.0), n, wo, seed=12)
    _agree(res, value, sigma)
    assert abs(events / res.events - 1.0) < 0.05  # the same walk: the same events per path


@pytest.mark.slow
def test_cones_agree_with_fitlab():
    """Cone against cone: the peer's cone tally (quadrature divisor) and fitlab's inplane cones
    (0.02 sr) on the throughput scene."""
    n = 1 << 16
    sr = 0.02
    theta_o = [0.0, 20.0, 30.0, 45.0, -30.0, 130.0, 150.0, 160.0, 175.0]
    res = simulate(_scene("ggx", {"type": "inplane", "theta_o": theta_o, "acceptance_sr": sr}),
                   n, seed=13)
    wo = direction(res.theta_o, res.phi_o)
    *_, value, sigma = nw.simulate_numpy(REGIONS, [TOPS["ggx"][1], BOTTOM[1]],
                                         direction(THETA_I, 0.0), n, 1, 1, seed=14,
                                         cones=(wo, 1.0 - sr / (2.0 * np.pi)))
    fv, fs = res.value[:, 0], res.sigma[:, 0]
    z = (value - fv) / np.hypot(sigma, fs)
    assert np.all(np.abs(z) < 4.0), np.c_[res.theta_o, fv, fs, value, sigma, z]
