"""Deterministic quadrature rules: Gauss–Legendre on intervals, the midpoint rule for periodic
integrands, products of rules, and a (μ, φ) rule on the hemisphere.

Pure NumPy (float64), no state: every function returns fresh ``(nodes, weights)`` arrays so
callers may move them to JAX. Used by the LUT baker (``fitlab.lut``) and the layered interface
(``fitlab.interface``: angular integrals over the hemisphere).

Accuracy, for a rule of order n on [a, b]:

- Gauss–Legendre is exact for polynomials of degree ≤ 2n - 1 and converges geometrically for
  integrands analytic on [a, b]; a kink or a jump inside the interval drops it to O(n⁻²) or
  O(n⁻¹), so integrands with known breakpoints should be split there
  (:func:`gauss_legendre_panels`).
- The midpoint rule converges geometrically for smooth *periodic* integrands over one period
  (the trapezoid rule's property, Trefethen & Weideman 2014), which makes it the right rule in
  azimuth.
"""

from __future__ import annotations

import functools

import numpy as np

#: Largest order accepted (numpy's Golub–Welsch nodes stay accurate far beyond this).
MAX_ORDER = 4096


def _check_order(n: int) -> int:
    if int(n) != n or not 1 <= n <= MAX_ORDER:
        raise ValueError(f"quadrature order must be an integer in [1, {MAX_ORDER}], got {n!r}")
    return int(n)


@functools.lru_cache(maxsize=64)
def _legendre_unit(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def gauss_legendre(n: int, a: float = 0.0, b: float = 1.0):
    """n-point Gauss–Legendre rule on [a, b]: nodes (n,), weights (n,) with Σw = b - a.

    The one source of Gauss–Legendre nodes in fitlab: every other rule and every module that
    integrates by Gauss–Legendre (``fitlab.interface``, ``fitlab.lut``) takes them from here."""
    x, w = _legendre_unit(_check_order(n))
    half = 0.5 * (b - a)
    return a + half * (x + 1.0), half * w


def gauss_legendre_panels(breaks, n: int, *, smooth_ends: bool = False, xp=np):
    """Composite Gauss–Legendre: an n-point rule on each panel [breaks[j], breaks[j+1]].

    ``breaks`` has shape (..., P + 1) (non-decreasing along the last axis; empty panels get zero
    weights), so every leading index can carry its own breakpoints. Returns nodes and weights of
    shape (..., P·n).

    ``smooth_ends``: map each panel through x = a + (b - a)(3s² - 2s³) before the rule, which
    turns square-root endpoint behaviour (a Fresnel term at its critical angle, a boundary that
    appears at a breakpoint) into a smooth one; nodes gather towards both ends. ``xp`` is the
    array module (NumPy, or ``jax.numpy`` inside traced code)."""
    s, ws = gauss_legendre(n, 0.0, 1.0)
    if smooth_ends:
        q, dq = s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s)
    else:
        q, dq = s, np.ones_like(s)
    breaks = xp.asarray(breaks)
    lo, hi = breaks[..., :-1, None], breaks[..., 1:, None]
    nodes = lo + (hi - lo) * xp.asarray(q)
    weights = (hi - lo) * xp.asarray(ws * dq)
    shape = breaks.shape[:-1] + (-1,)
    return nodes.reshape(shape), weights.reshape(shape)


def midpoint_periodic(n: int, a: float = 0.0, b: float = 1.0):
    """n-point midpoint rule on [a, b], nodes at a + (j + ½)(b - a)/n: geometrically convergent
    for smooth integrands of period b - a (and, on half a period, for even periodic ones)."""
    n = _check_order(n)
    h = (b - a) / n
    return a + h * (np.arange(n) + 0.5), np.full(n, h)


def product_rule(rule_a, rule_b):
    """Tensor product of two 1D rules: nodes (n_a·n_b, 2) (first coordinate slowest) and
    weights (n_a·n_b,)."""
    (xa, wa), (xb, wb) = rule_a, rule_b
    X, Y = np.meshgrid(xa, xb, indexing="ij")
    return np.stack([X.ravel(), Y.ravel()], axis=-1), np.outer(wa, wb).ravel()


def hemisphere_rule(n_mu: int, n_phi: int):
    """Directions and weights for ∫ over the upper hemisphere of g(ω) dω.

    μ = cos θ by Gauss–Legendre on [0, 1] and φ by the periodic midpoint rule on [0, 2π)
    (dω = dμ dφ). Returns unit directions (n_mu·n_phi, 3) and weights (n_mu·n_phi,) summing
    to 2π."""
    nodes, w = product_rule(gauss_legendre(n_mu, 0.0, 1.0), midpoint_periodic(n_phi, 0.0, 2 * np.pi))
    mu, phi = nodes[:, 0], nodes[:, 1]
    s = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=-1), w


__all__ = [
    "MAX_ORDER",
    "gauss_legendre",
    "gauss_legendre_panels",
    "midpoint_periodic",
    "product_rule",
    "hemisphere_rule",
]
