"""Quadrature over an instrument's aperture: the directions a measured value averages over.

A detector that collects the flux leaving into a set of directions A (a cone around its axis, or
a θ/φ bin of a simulation) measures the cosine-weighted mean of the BSDF over A,

    f_A = ∫_A f(ωo) |cos θo| dωo / ∫_A |cos θo| dωo,

and a source whose beam diverges over a cone C of directions (uniform radiance) the
cosine-weighted mean over C of the incident direction as well (data_formats/measurement_csv.md,
"Aperture"). This module turns each row's aperture into nodes and weights, so that

    f_A ≈ Σ_k w_k f(ωi_k, ωo_k),   Σ_k w_k = 1,

and a fit predicts a row by a weighted sum of model evaluations (one array shape for all rows:
jit and vmap friendly). The rules, for an order n:

- **cone** of half-angle γ around d: s = 1 − cos ψ (ψ the angle from d) by Gauss–Legendre on
  [0, 1 − cos γ] (dω = ds dβ) with n nodes × the periodic midpoint rule in the azimuth β around
  d with 2n nodes. Averaged over β a smooth integrand is a smooth function of s, so the rule
  converges geometrically; the part of a cone beyond the surface plane (a detector near grazing)
  is left out (weight 0), which drops the convergence to algebraic for those rows.
- **bin** θ ∈ [θ0, θ1], φ ∈ [φ0, φ1]: Gauss–Legendre in θ (n) × Gauss–Legendre in φ (n) with the
  weight |cos θ| sin θ (dω = sin θ dθ dφ), smooth over a bin that touches the pole or the
  horizon.
- **source cone**: the cone rule around ωi; the row's rule is the product of the source's and
  the detector's.

Weights are normalized by their sum, so a constant is integrated exactly. A row without an
aperture (cone half-angle 0, a degenerate bin, no source divergence) has all its nodes at its
direction. Pure NumPy (float64), no state.
"""

from __future__ import annotations

import numpy as np

from fitlab.quadrature import gauss_legendre, midpoint_periodic

#: Largest order accepted (a cone of order n has 2n² nodes).
MAX_ORDER = 64


def check_order(n) -> int:
    if isinstance(n, bool) or int(n) != n or not 1 <= n <= MAX_ORDER:
        raise ValueError(f"aperture order must be an integer in [1, {MAX_ORDER}], got {n!r}")
    return int(n)


def cone_nodes(n: int) -> int:
    return check_order(n) * 2 * check_order(n)


def bin_nodes(n: int) -> int:
    return check_order(n) ** 2


def basis(d):
    """Two unit vectors (..., 3) completing the unit vectors d (..., 3) to an orthonormal frame
    (Duff et al. 2017, "Building an orthonormal basis, revisited")."""
    d = np.asarray(d, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    e1 = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    e2 = np.stack([b, sign + y * y * a, -y], axis=-1)
    return e1, e2


def _normalize(nodes, weights, centre):
    """Weights divided by their sum; nodes of weight 0 moved to ``centre`` (a direction where
    the model is evaluated safely); a row whose weights are all 0 (a point) gets equal weights
    at ``centre``."""
    total = weights.sum(axis=-1, keepdims=True)
    point = total[..., 0] <= 0.0
    K = weights.shape[-1]
    w = np.where(point[..., None], 1.0 / K, weights / np.where(total > 0, total, 1.0))
    dead = (w <= 0.0) | point[..., None]
    nodes = np.where(dead[..., None], centre[..., None, :], nodes)
    return nodes, w


def cone_rule(axis, half_angle_deg, n: int):
    """Nodes (R, 2n², 3) and weights (R, 2n²) of the |cos θ|-weighted mean over the cones of
    half-angle ``half_angle_deg`` (R,) around the unit vectors ``axis`` (R, 3), clipped at the
    surface plane on the axis's side. A half-angle of 0 is a point (all nodes on the axis)."""
    n = check_order(n)
    axis = np.asarray(axis, dtype=np.float64).reshape(-1, 3)
    gamma = np.radians(np.broadcast_to(np.asarray(half_angle_deg, dtype=np.float64),
                                       axis.shape[:1]))
    s_unit, ws_unit = gauss_legendre(n, 0.0, 1.0)
    beta, wb = midpoint_periodic(2 * n, 0.0, 2.0 * np.pi)
    s_max = 1.0 - np.cos(gamma)  # (R,)
    s = s_max[:, None] * s_unit[None, :]  # (R, n)
    ws = s_max[:, None] * ws_unit[None, :]
    cos_psi = 1.0 - s
    sin_psi = np.sqrt(np.maximum(s * (2.0 - s), 0.0))
    e1, e2 = basis(axis)
    cb, sb = np.cos(beta), np.sin(beta)
    # ω = cos ψ d + sin ψ (cos β e1 + sin β e2), nodes ordered (ψ slowest, β fastest)
    ring = cb[None, :, None] * e1[:, None, :] + sb[None, :, None] * e2[:, None, :]  # (R, 2n, 3)
    w = (cos_psi[:, :, None, None] * axis[:, None, None, :]
         + sin_psi[:, :, None, None] * ring[:, None, :, :])  # (R, n, 2n, 3)
    w = w / np.linalg.norm(w, axis=-1, keepdims=True)
    same_side = np.sign(w[..., 2]) == np.sign(axis[:, None, None, 2])
    weight = ws[:, :, None] * wb[None, None, :] * np.abs(w[..., 2]) * same_side
    R = axis.shape[0]
    return _normalize(w.reshape(R, -1, 3), weight.reshape(R, -1), axis)


def bin_rule(edges_deg, n: int, centre=None):
    """Nodes (R, n², 3) and weights (R, n²) of the |cos θ|-weighted mean over the θ/φ bins
    ``edges_deg`` (R, 4) = θ0, θ1, φ0, φ1 in degrees (θ0 ≤ θ1 on one side of the surface,
    φ0 ≤ φ1). A bin with θ0 = θ1 and φ0 = φ1 is a point. ``centre`` (R, 3): where nodes of weight
    0 are put (default: the bin's (θ, φ) midpoint)."""
    n = check_order(n)
    e = np.radians(np.asarray(edges_deg, dtype=np.float64).reshape(-1, 4))
    x, wx = gauss_legendre(n, 0.0, 1.0)
    t0, t1, p0, p1 = (e[:, k:k + 1] for k in range(4))
    theta = t0 + (t1 - t0) * x[None, :]  # (R, n)
    wt = (t1 - t0) * wx[None, :] * np.abs(np.cos(theta)) * np.sin(theta)
    phi = p0 + (p1 - p0) * x[None, :]
    wp = (p1 - p0) * wx[None, :]
    st = np.sin(theta)[:, :, None]
    w = np.stack([st * np.cos(phi)[:, None, :], st * np.sin(phi)[:, None, :],
                  np.broadcast_to(np.cos(theta)[:, :, None], st.shape[:2] + (n,))], axis=-1)
    weight = wt[:, :, None] * wp[:, None, :]
    R = e.shape[0]
    if centre is None:
        tc, pc = 0.5 * (t0 + t1)[:, 0], 0.5 * (p0 + p1)[:, 0]
        centre = np.stack([np.sin(tc) * np.cos(pc), np.sin(tc) * np.sin(pc), np.cos(tc)], -1)
    return _normalize(w.reshape(R, -1, 3), weight.reshape(R, -1), np.asarray(centre, float))


def point_rule(d, k: int):
    """``k`` nodes at the directions d (R, 3), equal weights (a row without aperture)."""
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    return (np.broadcast_to(d[:, None, :], (d.shape[0], k, 3)).copy(),
            np.full((d.shape[0], k), 1.0 / k))


def detector_rule(wo, n: int, *, aperture_deg=None, bin_deg=None):
    """The outgoing side's rule for every row: a cone where ``aperture_deg`` > 0, a bin where
    ``bin_deg`` is not degenerate, the row's direction elsewhere; rows padded to one node count
    (nodes of weight 0 at the row's direction). Returns nodes (R, K, 3), weights (R, K)."""
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    R = wo.shape[0]
    cone = np.zeros(R, bool) if aperture_deg is None else np.asarray(aperture_deg) > 0
    binned = np.zeros(R, bool) if bin_deg is None else bin_has_extent(bin_deg)
    K = max(cone_nodes(n) if cone.any() else 1, bin_nodes(n) if binned.any() else 1)
    nodes, weights = point_rule(wo, K)
    for mask, make, k in ((cone, lambda s: cone_rule(wo[s], np.asarray(aperture_deg)[s], n),
                           cone_nodes(n)),
                          (binned, lambda s: bin_rule(np.asarray(bin_deg)[s], n, wo[s]),
                           bin_nodes(n))):
        if mask.any():
            x, w = make(mask)
            nodes[mask, :k], weights[mask, :k], weights[mask, k:] = x, w, 0.0
    return nodes, weights


def bin_has_extent(bin_deg) -> np.ndarray:
    """Rows whose bin is not a point (θ0 < θ1 or φ0 < φ1)."""
    b = np.asarray(bin_deg, dtype=np.float64).reshape(-1, 4)
    return (b[:, 1] > b[:, 0]) | (b[:, 3] > b[:, 2])


def row_rule(wi, wo, n: int, *, aperture_deg=None, bin_deg=None, source_divergence_deg=None):
    """Incident nodes, outgoing nodes (R, K, 3) and weights (R, K), Σ_k w = 1, of each row's
    aperture: the product of the source cone's rule (``source_divergence_deg``) and the
    detector's (:func:`detector_rule`). Rows without any aperture have K equal nodes at their
    directions (one node when no row has an aperture)."""
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo_nodes, wo_w = detector_rule(wo, n, aperture_deg=aperture_deg, bin_deg=bin_deg)
    if source_divergence_deg is not None and np.any(np.asarray(source_divergence_deg) > 0):
        wi_nodes, wi_w = cone_rule(wi, source_divergence_deg, n)
    else:
        wi_nodes, wi_w = point_rule(wi, 1)
    R, Ki, Ko = wi.shape[0], wi_w.shape[1], wo_w.shape[1]
    wi_all = np.broadcast_to(wi_nodes[:, :, None, :], (R, Ki, Ko, 3)).reshape(R, -1, 3)
    wo_all = np.broadcast_to(wo_nodes[:, None, :, :], (R, Ki, Ko, 3)).reshape(R, -1, 3)
    w = (wi_w[:, :, None] * wo_w[:, None, :]).reshape(R, -1)
    return wi_all, wo_all, w


__all__ = ["MAX_ORDER", "check_order", "cone_rule", "bin_rule", "point_rule", "detector_rule",
           "row_rule", "bin_has_extent", "basis"]
