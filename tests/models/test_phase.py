"""Phase functions (fitlab/phase.py) and the vMF NDF (fitlab/microfacet.py): normalization,
exact sampling (χ² of sampled directions against the density), reciprocity, float32 and finite
gradients."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import fitlab  # noqa: F401
from fitlab import phase
from fitlab.microfacet import D_vMF, G1_vMF, get_distribution, sample_m_vMF, vmf_A3

_T, _P = 24, 48  # bins in cos θ and φ over the sphere


def _sphere_grid(nt=600, nph=1200):
    ct = 1.0 - 2.0 * (np.arange(nt) + 0.5) / nt
    ph = (np.arange(nph) + 0.5) * 2.0 * np.pi / nph
    C, P = np.meshgrid(ct, ph, indexing="ij")
    S = np.sqrt(1.0 - C * C)
    w = np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1)
    return w, 4.0 * np.pi / (nt * nph)


def _params(name, dtype=jnp.float64):
    if name == "isotropic":
        return "isotropic", {}
    if name.startswith("hg"):
        return "hg", {"g": jnp.asarray(float(name[3:]), dtype=dtype)}
    kind, rough, axis = {"sggx_surface": ("surface", 0.2, [0.0, 0.6, 0.8]),
                         "sggx_fiber": ("fiber", 0.3, [1.0, 0.0, 0.0]),
                         "sggx_rough": ("surface", 1.0, [0.0, 0.0, 1.0])}[name]
    S = phase.sggx_matrix(kind, jnp.asarray(rough, dtype=dtype), jnp.asarray(axis, dtype=dtype))
    return "sggx", {"S": S}


CASES = ["isotropic", "hg_0.8", "hg_-0.4", "hg_0.0", "sggx_surface", "sggx_fiber", "sggx_rough"]
WI = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


@functools.lru_cache(maxsize=None)
def _jitted(name, which):
    """``phase.PHASE_FUNCTIONS[name].<which>`` compiled, its parameters traced: one compilation
    per kind, function and shape for all of a kind's cases (op by op, every operation compiled
    on its own)."""
    return jax.jit(getattr(phase.PHASE_FUNCTIONS[name], which))


@pytest.mark.parametrize("case", CASES)
def test_phase_function_is_normalized(case):
    name, params = _params(case)
    w, dw = _sphere_grid()
    p = np.asarray(_jitted(name, "eval")(params, jnp.asarray(np.broadcast_to(WI, w.shape)),
                                         jnp.asarray(w)))
    assert np.sum(p) * dw == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("case", CASES)
def test_phase_function_sampling_chi2(case):
    """Sampled directions binned in (cos θ, φ) against the bin integrals of p (Šidák-free
    single χ² test at p > 1e-3, bins with an expected count of at least 20)."""
    name, params = _params(case)
    ev, sample = _jitted(name, "eval"), _jitted(name, "sample")
    n = 200_000
    u = jax.random.uniform(jax.random.PRNGKey(3), (n, 2), dtype=jnp.float64)
    wi = jnp.asarray(np.broadcast_to(WI, (n, 3)))
    wo, pdf = sample(params, wi, u)
    wo = np.asarray(wo)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(pdf), np.asarray(ev(params, wi, jnp.asarray(wo))),
                               rtol=1e-9)
    ti = np.clip(((1.0 - wo[:, 2]) / 2.0 * _T).astype(int), 0, _T - 1)
    pi = np.clip((np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2 * np.pi) / (2 * np.pi) * _P).astype(int), 0, _P - 1)
    observed = np.bincount(ti * _P + pi, minlength=_T * _P)
    w, dw = _sphere_grid(_T * 10, _P * 10)
    p = np.asarray(ev(params, jnp.asarray(np.broadcast_to(WI, w.shape)), jnp.asarray(w)))
    expected = p.reshape(_T, 10, _P, 10).sum(axis=(1, 3)).reshape(-1) * dw * n
    ok = expected >= 20
    assert ok.sum() >= 10
    chi2 = np.sum((observed[ok] - expected[ok]) ** 2 / expected[ok])
    assert stats.chi2.sf(chi2, ok.sum() - 1) > 1e-3, chi2
    assert observed[~ok].sum() <= max(5 * expected[~ok].sum(), 50)


@pytest.mark.parametrize("case", CASES)
def test_phase_reciprocity(case):
    """HG and isotropic: p(wi, wo) = p(wo, wi); SGGX: σ(wi) p(wi, wo) = σ(wo) p(wo, wi)
    (SpongeCake eqs 1, 6)."""
    name, params = _params(case)
    ev = _jitted(name, "eval")
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 3)); a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = rng.normal(size=(50, 3)); b /= np.linalg.norm(b, axis=1, keepdims=True)
    pab = np.asarray(ev(params, jnp.asarray(a), jnp.asarray(b)))
    pba = np.asarray(ev(params, jnp.asarray(b), jnp.asarray(a)))
    if name == "sggx":
        pab = pab * np.asarray(phase.sggx_sigma(params["S"], jnp.asarray(a)))
        pba = pba * np.asarray(phase.sggx_sigma(params["S"], jnp.asarray(b)))
    np.testing.assert_allclose(pab, pba, rtol=1e-10)


@pytest.mark.parametrize("case", CASES)
def test_phase_float32_values_and_gradients_finite(case):
    name, params = _params(case, jnp.float32)
    rng = np.random.default_rng(2)
    wi = rng.normal(size=(256, 3)).astype(np.float32)
    wi[:4] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 1e-7]]
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    u = jax.random.uniform(jax.random.PRNGKey(0), (256, 2), dtype=jnp.float32)
    wo, pdf, p, g = _phase_values_and_gradients(name, params, jnp.asarray(wi), u)
    assert wo.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(wo))) and bool(jnp.all(pdf >= 0))
    assert p.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(p)))
    assert bool(jnp.all(jnp.isfinite(g)))


@functools.partial(jax.jit, static_argnums=0)  # one compilation per phase function
def _phase_values_and_gradients(name, params, wi, u):
    ev, sample = phase.PHASE_FUNCTIONS[name]
    wo, pdf = sample(params, wi, u)
    wo_back = -wi  # backscatter exactly: h = 0 for SGGX
    p = ev(params, wi, jnp.concatenate([wo[:128], wo_back[128:]]))
    g = jax.grad(lambda x: jnp.sum(ev(params, x, wo)))(wi)
    return wo, pdf, p, g


# --------------------------------------------------------------------------------------------
# vMF NDF (extended-NDF paper eqs 5-8)
# --------------------------------------------------------------------------------------------

ALPHAS = (1e-4, 1e-3, 0.01, 0.1, 0.3, 1.0)


@jax.jit  # one compilation for every α (op by op, every operation compiled on its own)
def _vmf_density_and_samples(m, u, alpha):
    return D_vMF(m, alpha), sample_m_vMF(u[:, 0], u[:, 1], alpha)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_vmf_projected_area_is_one_and_sampling_matches(alpha):
    """∫ D(m) cos θm dω = 1 over the upper hemisphere (Gauss-Legendre in 1 - cos θm scaled to
    the lobe), and sampled cos θm has the mean of the density D cos θm."""
    kappa = 2.0 / alpha**2
    x, wts = np.polynomial.legendre.leggauss(200)
    tmax = min(1.0, 60.0 / kappa)
    t = 0.5 * (x + 1) * tmax
    mu = 1 - t
    m = np.stack([np.sqrt(t * (2 - t)), 0 * t, mu], -1)
    u = np.random.default_rng(4).random((100_000, 2))
    D, ms = _vmf_density_and_samples(jnp.asarray(m), jnp.asarray(u), jnp.asarray(alpha))
    D, ms = np.asarray(D), np.asarray(ms)
    assert np.sum(0.5 * tmax * wts * D * mu) * 2 * np.pi == pytest.approx(1.0, rel=1e-9)
    mean_t = np.sum(0.5 * tmax * wts * D * mu * t) * 2 * np.pi
    ts = 1 - ms[:, 2]
    assert abs(ts.mean() - mean_t) < 5 * ts.std() / np.sqrt(ts.size)
    np.testing.assert_allclose(np.linalg.norm(ms, axis=1), 1.0, atol=1e-12)


def test_vmf_matches_paper_density_and_masking():
    """For κ > 100, D ≈ M(m; n, κ) = κ/(4π sinh κ) e^{κ cos θm} (paper eq. 5 and its remark);
    G1 at the normal = 4 A3 / (A3 + 1)², eq. 8 evaluated at θv = 0."""
    for alpha in (0.1, 0.05):
        kappa = 2 / alpha**2
        th = np.radians([0.0, 2.0, 5.0])
        m = np.stack([np.sin(th), 0 * th, np.cos(th)], -1)
        M = kappa / (2 * np.pi * (1 - np.exp(-2 * kappa))) * np.exp(kappa * (np.cos(th) - 1))
        np.testing.assert_allclose(np.asarray(D_vMF(jnp.asarray(m), alpha)), M,
                                   rtol=1.5 / kappa)
    A3 = float(vmf_A3(jnp.asarray(2.0)))
    assert A3 == pytest.approx(1 / np.tanh(2.0) - 0.5)
    g = float(G1_vMF(jnp.asarray([0.0, 0.0, 1.0]), 1.0))
    assert g == pytest.approx(4 * A3 / (A3 + 1) ** 2)
    assert get_distribution("vmf").name == "vmf"


@jax.jit  # one compilation for every α (op by op, every operation compiled on its own)
def _vmf_values_and_gradients(m, a, u):
    values = [(f(m, a), jax.grad(lambda x: jnp.sum(f(x, a)))(m),
               jax.grad(lambda s: jnp.sum(f(m, s)))(a)) for f in (D_vMF, G1_vMF)]
    return values, sample_m_vMF(u, u, a)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_vmf_float32_values_and_gradients_finite(alpha):
    th = np.radians([0.0, 1e-3, 30.0, 89.0, 89.99, 90.0])
    m = np.stack([np.sin(th), 0 * th, np.cos(th)], -1).astype(np.float32) * 3.0
    a = jnp.asarray(alpha, dtype=jnp.float32)
    u = jnp.asarray([0.0, 1e-7, 0.5, 0.999999], dtype=jnp.float32)
    values, ms = _vmf_values_and_gradients(jnp.asarray(m), a, u)
    for v, g, ga in values:
        assert v.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(v)))
        assert bool(jnp.all(jnp.isfinite(g)))
        assert bool(jnp.isfinite(ga))
    assert ms.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(ms)))
    assert bool(jnp.all(ms[:, 2] > 0))
