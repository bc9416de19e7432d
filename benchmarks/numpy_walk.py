"""The random walk of fitlab/simulate/walk.py written again in vectorized NumPy: the peer of
``bench_simulate.py``.

Same algorithm, event by event: free flights sampled by σs with Beer–Lambert weights for σa,
Henyey–Greenstein / isotropic phase sampling, GGX interfaces sampled as in Walter section 5.3
(m ~ D(m)|m·n|, Fresnel choice, eqs 39-41), smooth interfaces by a Fresnel choice, bounce
orders (downward → upward turns below the top interface), Russian roulette after 3 events,
(θ, φ) hemisphere bins. Written the way a careful NumPy programmer would: float64 arrays of the
paths still alive (compacted after every event), no Python loop over paths.

Supports the subset of scenes the benchmark uses: dielectric interfaces (smooth or GGX),
media with σa, σs and an isotropic or HG phase function, ``pass`` boundaries, no substrate.
"""

from __future__ import annotations

import numpy as np


def _fresnel(c, eta):
    """Walter eq. 22; eta = η_t/η_i; TIR gives 1."""
    c = np.abs(c)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        F = 0.5 * a * a * (1.0 + b * b)
    return np.where(g2 <= 0, 1.0, np.clip(np.nan_to_num(F, nan=1.0), 0.0, 1.0))


def _G1_ggx(v, alpha):
    s2 = v[:, 0] ** 2 + v[:, 1] ** 2
    cz = np.abs(v[:, 2])
    den = cz + np.sqrt(cz * cz + alpha * alpha * s2)
    return np.where(den > 0, 2.0 * cz / np.where(den > 0, den, 1.0), 0.0)


def _sample_ggx_dielectric(wi, alpha, eta, u):
    """Walter section 5.3 for a GGX interface; eta = n_below / n_above; wi points away."""
    s = np.where(wi[:, 2] < 0, -1.0, 1.0)
    wi = wi * np.stack([np.ones_like(s), np.ones_like(s), s], 1)
    eta = np.where(s > 0, eta, 1.0 / eta)
    a2 = alpha * alpha
    den = 1.0 - u[:, 0] + a2 * u[:, 0]
    cos2 = (1.0 - u[:, 0]) / den
    sin2 = a2 * u[:, 0] / den
    phi = 2.0 * np.pi * u[:, 1]
    st, ct = np.sqrt(sin2), np.sqrt(cos2)
    m = np.stack([st * np.cos(phi), st * np.sin(phi), ct], 1)
    c = np.sum(wi * m, 1)
    F = _fresnel(c, eta)
    refl = u[:, 2] < F
    wo_r = 2.0 * c[:, None] * m - wi
    inv = 1.0 / eta
    k = 1.0 + inv * inv * (c * c - 1.0)
    root = np.sqrt(np.maximum(k, 0.0))
    wo_t = (inv * c - root)[:, None] * m - inv[:, None] * wi
    wo = np.where(refl[:, None], wo_r, wo_t)
    co = wo[:, 2]
    ci = wi[:, 2]
    valid = (ci > 0) & (c > 0) & np.where(refl, co > 0, co < 0)
    side_i = c * ci > 0
    side_o = np.sum(wo * m, 1) * co > 0
    G = np.where(side_i, _G1_ggx(wi, alpha), 0.0) * np.where(side_o, _G1_ggx(wo, alpha), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(valid, c * G / (ci * m[:, 2]), 0.0)
    wo = wo * np.stack([np.ones_like(s), np.ones_like(s), s], 1)
    return wo, np.nan_to_num(weight)


def _smooth(w, eta_side, u):
    cos_i = np.abs(w[:, 2])
    F = _fresnel(cos_i, eta_side)
    inv = 1.0 / eta_side
    sin2_t = inv * inv * (w[:, 0] ** 2 + w[:, 1] ** 2)
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    sgn = np.where(w[:, 2] < 0, -1.0, 1.0)
    w_t = np.stack([w[:, 0] * inv, w[:, 1] * inv, sgn * cos_t], 1)
    w_r = w * np.array([1.0, 1.0, -1.0])
    return np.where((u < F)[:, None], w_r, w_t)


def _basis(n):
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], 1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    return s, t


def _sample_hg(wi, g, u):
    small = np.abs(g) < 1e-3
    gs = np.where(small, 0.5, g)
    sq = (1.0 - gs * gs) / (1.0 + gs - 2.0 * gs * u[:, 0])
    cos_t = np.where(small, 1.0 - 2.0 * u[:, 0], (1.0 + gs * gs - sq * sq) / (2.0 * gs))
    cos_t = np.clip(cos_t, -1.0, 1.0)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    phi = 2.0 * np.pi * u[:, 1]
    d = -wi
    s, t = _basis(d)
    return (sin_t * np.cos(phi))[:, None] * s + (sin_t * np.sin(phi))[:, None] * t + cos_t[:, None] * d


def simulate_numpy(regions, boundaries, wi, samples, theta_bins, phi_bins, seed=0,
                   max_events=512, rr_start=3, rr_min_q=0.05):
    """regions: list of dicts (index, thickness, sigma_a, sigma_s, g) for regions 0..M+1;
    boundaries: list of dicts (kind "pass" | "smooth" | "ggx", alpha). Returns (S1, S2) of shape
    (4 orders, 2 sides × theta_bins × phi_bins) and the flux leaving up and down."""
    rng = np.random.default_rng(seed)
    M = len(regions) - 2
    n_idx = np.array([r["index"] for r in regions])
    thick = np.array([r.get("thickness", 0.0) for r in regions])
    sig_a = np.array([r.get("sigma_a", 0.0) for r in regions])
    sig_s = np.array([r.get("sigma_s", 0.0) for r in regions])
    hg_g = np.array([r.get("g", 0.0) for r in regions])
    kinds = [b["kind"] for b in boundaries]
    alpha = np.array([b.get("alpha", 0.0) for b in boundaries])
    eta = n_idx[1:] / n_idx[:-1]
    n_out = 2 * theta_bins * phi_bins
    S1 = np.zeros((4, n_out))
    S2 = np.zeros((4, n_out))
    flux = np.zeros(2)
    N = samples
    region = np.zeros(N, dtype=np.int64)
    z = np.zeros(N)
    w = np.tile(-np.asarray(wi, dtype=float), (N, 1))
    weight = np.ones(N)
    bounces = np.zeros(N, dtype=np.int64)
    events = np.zeros(N, dtype=np.int64)

    def tally(wx, x, order):
        side = (wx[:, 2] < 0).astype(int)
        theta = np.arctan2(np.hypot(wx[:, 0], wx[:, 1]), np.abs(wx[:, 2]))
        tb = np.clip((theta / (0.5 * np.pi) * theta_bins).astype(int), 0, theta_bins - 1)
        ph = np.mod(np.arctan2(wx[:, 1], wx[:, 0]), 2 * np.pi)
        pb = np.clip((ph / (2 * np.pi) * phi_bins).astype(int), 0, phi_bins - 1)
        b = (side * theta_bins + tb) * phi_bins + pb
        o = np.minimum(order, 3)
        np.add.at(S1, (o, b), x)
        np.add.at(S2, (o, b), x * x)
        np.add.at(flux, side, x)

    for _ in range(max_events):
        if region.size == 0:
            break
        n = region.size
        u = rng.random((n, 8))
        wz = w[:, 2]
        down = wz < 0
        in_med = (region >= 1) & (region <= M)
        abs_wz = np.abs(wz)
        horizontal = abs_wz < 1e-7
        d_b = np.where(down, thick[region] - z, z) / np.where(horizontal, 1.0, abs_wz)
        d_b = np.where(in_med, np.maximum(d_b, 0.0), 0.0)
        ss = sig_s[region]
        can = ss > 0
        t = -np.log1p(-u[:, 3]) / np.where(can, ss, 1.0)
        scatter = in_med & can & (t < d_b)
        d = np.where(scatter, t, d_b)
        weight = weight * np.exp(-np.where(in_med, sig_a[region] * d, 0.0))
        z = np.where(in_med, z - d * wz, z)
        alive = ~(in_med & horizontal & ~scatter)
        new_w = w.copy()
        if scatter.any():
            new_w[scatter] = _sample_hg(-w[scatter], hg_g[region[scatter]], u[scatter, 4:6])
        hit = alive & ~scatter
        b = np.clip(np.where(down, region, region - 1), 0, M)
        for j, kind in enumerate(kinds):
            sel = hit & (b == j)
            if not sel.any() or kind == "pass":
                continue
            if kind == "smooth":
                e = np.where(w[sel, 2] < 0, eta[j], 1.0 / eta[j])
                new_w[sel] = _smooth(w[sel], e, u[sel, 2])
            else:
                wo, wt = _sample_ggx_dielectric(-w[sel], alpha[j], np.full(sel.sum(), eta[j]),
                                                u[sel, 0:3])
                new_w[sel] = wo
                weight[sel] *= wt
        new_w /= np.linalg.norm(new_w, axis=1, keepdims=True)
        up_new = new_w[:, 2] > 0
        region = np.where(hit, np.where(up_new, b, b + 1), region)
        z = np.where(hit, np.where(up_new, thick[b], 0.0), z)
        bounces = bounces + (alive & down & up_new & (scatter | (b >= 1)))
        leaving = alive & (((region == 0) & up_new) | ((region == M + 1) & ~up_new))
        if leaving.any():
            tally(new_w[leaving], weight[leaving], bounces[leaving])
        alive = alive & ~leaving & (weight > 0)
        events = events + alive
        q = np.clip(weight, rr_min_q, 1.0)
        play = alive & (events > rr_start)
        survive = u[:, 7] < q
        alive = alive & (~play | survive)
        weight = np.where(play & survive, weight / q, weight)
        keep = np.flatnonzero(alive)
        region, z, w, weight = region[keep], z[keep], new_w[keep], weight[keep]
        bounces, events = bounces[keep], events[keep]
    return S1, S2, flux
