"""Moments of a reflection lobe over outgoing directions: its albedo, its mean direction and the
vMF concentration that matches its mean resultant length (A3(κ̂) = |mean|, Guo et al. 2015
eqs 16-18), the quantities a shader needs to read a pre-filtered environment map (their
section 5.5). The integrals use a quadrature adapted to a vMF lobe of a given concentration
about a given direction: u by Gauss-Legendre, cos θ' = 1 + log(1 - u (1 - e^{-2κ}))/κ (the
vMF's inverse CDF) and φ' by the midpoint rule over [0, π] (the lobes are mirror-symmetric
about the plane of incidence), so one rule serves κ from 1e-2 to 1e7: the integrand divided
by the vMF density is smooth wherever the lobe resembles the vMF. The error estimate is the
difference between two orders.
"""

from __future__ import annotations

import functools

import numpy as np

from fitlab._jax import jax, jnp
from fitlab import vmf

#: Default quadrature orders: Gauss-Legendre nodes in u, midpoint nodes in φ' over [0, π].
ORDERS = {"n_u": 32, "n_phi": 24}


def _gauss_legendre01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def vmf_rule(n_u: int, n_phi: int):
    """(u (Q,), φ' (Q,), weights (Q,)) of the product rule over [0, 1] × [0, π], the weights
    summing to 1 (∫ g dω = Σ w g/p for the vMF density p, by the mirror symmetry)."""
    u, wu = _gauss_legendre01(n_u)
    phi = (np.arange(n_phi) + 0.5) * np.pi / n_phi
    U, P = np.meshgrid(u, phi, indexing="ij")
    W = np.broadcast_to(wu[:, None] / n_phi, U.shape)
    return U.ravel(), P.ravel(), W.ravel()


def vmf_directions(mean, kappa, u, phi):
    """Directions (P, Q, 3) of the rule about unit ``mean`` (P, 3) (in the x-z plane) and the
    vMF density (P, Q) there: cos θ' by the inverse CDF, stable for κ from 1e-4 to 1e7."""
    k = kappa[:, None]
    em = jnp.expm1(-2.0 * k)  # e^{-2κ} - 1, in (-1, 0)
    c = jnp.clip(1.0 + jnp.log1p(u[None, :] * em) / k, -1.0, 1.0)
    s = jnp.sqrt(jnp.maximum((1.0 - c) * (1.0 + c), 0.0))
    e3 = mean
    e1 = jnp.stack([mean[:, 2], jnp.zeros_like(mean[:, 0]), -mean[:, 0]], axis=-1)
    e2 = jnp.zeros_like(mean) + jnp.asarray([0.0, 1.0, 0.0], mean.dtype)
    d = (c[..., None] * e3[:, None, :]
         + (s * jnp.cos(phi)[None, :])[..., None] * e1[:, None, :]
         + (s * jnp.sin(phi)[None, :])[..., None] * e2[:, None, :])
    # density κ e^{κ(c - 1)} / (2π (1 - e^{-2κ}))
    p = k * jnp.exp(k * (c - 1.0)) / (2.0 * jnp.pi * -em)
    return d, p


def _integrand(f, wi, mean, kappa, params, n_u, n_phi):
    """At the rule's nodes about (``mean``, ``kappa``): (u, φ', directions (P, Q, 3), f cos θo
    (P, Q, C), 0 below the horizon, and the weights w/p (P, Q) that integrate it)."""
    u, phi, w = (jnp.asarray(a) for a in vmf_rule(n_u, n_phi))
    wo, p = vmf_directions(mean, kappa, u, phi)
    P, Q = wo.shape[:2]
    wi_q = jnp.broadcast_to(wi[:, None, :], (P, Q, 3))
    pq = {k: jnp.broadcast_to(v[:, None, ...], (P, Q) + v.shape[1:]) for k, v in params.items()}
    up = wo[..., 2] > 0
    g = jnp.where(up[..., None], f(pq, wi_q, wo) * jnp.maximum(wo[..., 2], 0.0)[..., None], 0.0)
    return u, phi, wo, g, w[None, :] / p


@functools.partial(jax.jit, static_argnums=(0, 5, 6))
def _moments(f, wi, mean, kappa, params, n_u, n_phi):
    u, phi, _, g, wq = _integrand(f, wi, mean, kappa, params, n_u, n_phi)
    g = g * wq[..., None]  # (P, Q, C)
    E = jnp.sum(g, axis=1)  # (P, C)
    # the channel-summed first moment in the rule's frame, as (1 - cos θ', sin θ' cos φ'):
    # 1 - cos θ' straight from the inverse CDF, so 1 - |mean| keeps its digits for κ ~ 1e7
    gs = jnp.sum(g, axis=-1)
    k = kappa[:, None]
    one_minus_c = -jnp.log1p(u[None, :] * jnp.expm1(-2.0 * k)) / k
    c = 1.0 - one_minus_c
    s = jnp.sqrt(jnp.maximum(one_minus_c * (1.0 + c), 0.0))
    a = jnp.sum(gs * one_minus_c, axis=1)
    b = jnp.sum(gs * s * jnp.cos(phi)[None, :], axis=1)
    return E, a, b


def lobe_moments(f, wi, mean, kappa, params, orders=None):
    """Per point: (albedo E (P, C) = ∫ f cos θo dωo, mean direction (P, 3) of the channel-summed
    f cos θo, κ̂ (P,) with A3(κ̂) = |mean resultant|, error estimates (of E (P, C), of the mean
    direction (P,), of log10 κ̂ (P,))).

    ``f(params, wi, wo) -> (..., C)``; ``wi`` (P, 3); ``mean`` (P, 3) and ``kappa`` (P,) the
    vMF the rule is adapted to (the expected lobe); ``params`` {name: (P, ...)}. Where the lobe
    is empty (E = 0) the mean is ``mean`` and κ̂ is ``kappa``. The error estimates compare the
    rule at ``orders`` with the rule at 2/3 of them."""
    o = {**ORDERS, **(orders or {})}
    wi, mean, kappa = (jnp.asarray(a) for a in (wi, mean, kappa))
    params = {k: jnp.asarray(v) for k, v in params.items()}
    hi = _moments(f, wi, mean, kappa, params, int(o["n_u"]), int(o["n_phi"]))
    lo = _moments(f, wi, mean, kappa, params, max(2, 2 * int(o["n_u"]) // 3),
                  max(2, 2 * int(o["n_phi"]) // 3))
    out = [summarize(E, a, b, mean, kappa) for E, a, b in (hi, lo)]
    (E, m, k), (E2, m2, k2) = out
    return E, m, k, (np.abs(E - E2), np.linalg.norm(m - m2, axis=1),
                     np.abs(np.log10(k) - np.log10(k2)))


def summarize(E, a, b, mean, kappa):
    """(E, mean direction, κ̂) as NumPy from the integrals E_c = ∫ f_c cos θo and, of the
    channel sum, a = ∫ (1 - cos θ') and b = ∫ sin θ' cos φ' about ``mean``."""
    E, a, b, mean, kappa = (np.asarray(x, float) for x in (E, a, b, mean, kappa))
    total = E.sum(axis=1)
    ok = total > 0
    a, b = a / np.where(ok, total, 1.0), b / np.where(ok, total, 1.0)
    length = np.sqrt((1.0 - a) ** 2 + b * b)
    # 1 - |mean resultant| without cancellation: (2a - a² - b²) / (1 + |mean|)
    B = np.clip((2.0 * a - a * a - b * b) / (1.0 + length), 0.0, 1.0 - 1e-12)
    e1 = np.stack([mean[:, 2], np.zeros_like(mean[:, 0]), -mean[:, 0]], axis=-1)
    d = (1.0 - a)[:, None] * mean + b[:, None] * e1
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    direction = np.where(ok[:, None], d, mean)
    nu = np.asarray(vmf.nu_of_log_A3(jnp.asarray(np.log1p(-B))))
    k = np.where(ok, 1.0 / np.clip(nu, 1.0 / vmf.KAPPA_MAX, 1.0 / vmf.KAPPA_MIN), kappa)
    return E, direction, k


@functools.partial(jax.jit, static_argnums=(0, 8, 9))
def _vmf_residual(f, wi, mean0, kappa0, params, total, mean, kappa, n_u, n_phi):
    _, _, wo, g, wq = _integrand(f, wi, mean0, kappa0, params, n_u, n_phi)
    g = jnp.sum(g, axis=-1)
    k = kappa[:, None]
    c = jnp.sum(wo * mean[:, None, :], axis=-1)
    vmf_density = k * jnp.exp(k * (c - 1.0)) / (2.0 * jnp.pi * -jnp.expm1(-2.0 * k))
    g_hat = total[:, None] * vmf_density
    return jnp.sum(wq * (g - g_hat) ** 2, axis=1), jnp.sum(wq * g * g, axis=1)


def vmf_lobe_error(f, wi, mean0, kappa0, params, total, mean, kappa, orders=None):
    """Relative L2 error (P,) of the real-time form, the lobe replaced by its albedo times a
    vMF of the matched mean and κ̂ over the whole sphere: sqrt(∫ (g - ĝ)² / ∫ g²) with
    g = Σ_c f_c cos θo (0 below the horizon) and ĝ = (Σ_c E_c) vMF(ωo; mean, κ̂), by the rule
    about (``mean0``, ``kappa0``). 0/0 (an empty lobe) is 0."""
    o = {**ORDERS, **(orders or {})}
    args = [jnp.asarray(a) for a in (wi, mean0, kappa0)]
    params = {k: jnp.asarray(v) for k, v in params.items()}
    d2, g2 = _vmf_residual(f, *args, params, jnp.asarray(total), jnp.asarray(mean),
                           jnp.asarray(kappa), int(o["n_u"]), int(o["n_phi"]))
    d2, g2 = np.asarray(d2), np.asarray(g2)
    return np.where(g2 > 0, np.sqrt(d2 / np.where(g2 > 0, g2, 1.0)), 0.0)
