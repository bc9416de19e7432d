"""The random-walk algorithm of fitlab's simulator (fitlab/simulate/walk.py, whose product walk
is Dr.Jit) written again in vectorized NumPy: the peer of ``bench_simulate.py``.

Same algorithm, event by event: free flights sampled by σs with Beer–Lambert weights for σa,
Henyey–Greenstein / isotropic phase sampling, GGX interfaces sampled as in Walter section 5.3
(m ~ D(m)|m·n|, Fresnel choice, eqs 39-41), smooth interfaces by a Fresnel choice, bounce
orders (downward → upward turns below the top interface), Russian roulette after 3 events,
(θ, φ) hemisphere bins. Written the way a careful NumPy programmer would: float64 arrays of the
paths still alive (compacted after every event), no Python loop over paths.

Supports the subset of scenes the benchmark uses: dielectric interfaces (smooth or GGX),
media with σa, σs and an isotropic or HG phase function, ``pass`` boundaries, no substrate.

Two estimators:

* :func:`simulate_numpy`: exits tallied into hemisphere (θ, φ) bins, and optionally into cones
  (``cones=(axes, cos_half_angle)``, the cosine-weighted solid angle of each by quadrature);
* :func:`simulate_numpy_points`: point estimates of f(wi, wo) at exact directions by
  next-event estimation, the method of walk.py "Point estimates" (connections at the first /
  last GGX boundary through reverse refraction of a smooth exit boundary, direct connections of
  volume events, and the vertex strategy behind a GGX boundary balanced against the walk's own
  crossings), written again from the equations (Walter 2007 eqs 13-24, 38-41) in NumPy.
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


def _roulette(alive, weight, events, u, rr_start, rr_min_q):
    """Russian roulette after ``rr_start`` events: survival q = clip(weight, rr_min_q, 1), the
    survivors' weight divided by q (unbiased)."""
    q = np.clip(weight, rr_min_q, 1.0)
    play = alive & (events > rr_start)
    survive = u < q
    return alive & (~play | survive), np.where(play & survive, weight / q, weight)


def _flight(w, region, z, weight, u, thick, sig_s, sig_a, M):
    """One free flight of every live path: a distance sampled by σs (``u[:, 3]``) against the
    distance to the boundary ahead, Beer–Lambert weights for σa. Returns (down, scatter,
    weight, z, alive): whether each path travels downward, scatters in the volume, its new
    weight and depth, and whether it goes on (a horizontal flight in a medium never ends)."""
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
    return down, scatter, weight, z, ~(in_med & horizontal & ~scatter)


def simulate_numpy(regions, boundaries, wi, samples, theta_bins, phi_bins, seed=0,
                   max_events=512, rr_start=3, rr_min_q=0.05, cones=None):
    """regions: list of dicts (index, thickness, sigma_a, sigma_s, g) for regions 0..M+1;
    boundaries: list of dicts (kind "pass" | "smooth" | "ggx", alpha). Returns (S1, S2) of shape
    (4 orders, 2 sides × theta_bins × phi_bins) and the flux leaving up and down.

    ``cones=(axes (R, 3) unit, cos_half_angle)``: also tally the exits within each cone (every
    exit direction w with w·axis >= cos γ, as fitlab's cone detector) and return two more
    arrays, the cone averages of f (R,) (flux fraction / ∫|cos θ| dω over the part of the cone
    on the axis's side, :func:`cone_cos_solid_angle`) and their standard errors (R,)."""
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
    if cones is not None:
        c_axes = np.asarray(cones[0], dtype=float).reshape(-1, 3)
        c_axes = c_axes / np.linalg.norm(c_axes, axis=1, keepdims=True)
        c_cos = float(cones[1])
        C1 = np.zeros(c_axes.shape[0])
        C2 = np.zeros(c_axes.shape[0])
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
        if cones is not None:
            inside = (wx @ c_axes.T >= c_cos).astype(float)  # (exits, R): cones may overlap
            C1[:] += x @ inside
            C2[:] += (x * x) @ inside

    for _ in range(max_events):
        if region.size == 0:
            break
        n = region.size
        u = rng.random((n, 8))
        down, scatter, weight, z, alive = _flight(w, region, z, weight, u, thick, sig_s, sig_a, M)
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
        alive, weight = _roulette(alive, weight, events, u[:, 7], rr_start, rr_min_q)
        keep = np.flatnonzero(alive)
        region, z, w, weight = region[keep], z[keep], new_w[keep], weight[keep]
        bounces, events = bounces[keep], events[keep]
    if cones is None:
        return S1, S2, flux
    cw = cone_cos_solid_angle(c_axes, c_cos)
    mean = C1 / N
    var = np.maximum(C2 / N - mean * mean, 0.0) / max(N - 1.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return S1, S2, flux, mean / cw, np.sqrt(var) / cw


def cone_cos_solid_angle(axes, cos_half_angle, n_psi=32, n_phi=128):
    """∫ |cos θ| dω over the directions of each cone (axes (R, 3) unit, half angle γ) lying on
    the axis's side of the surface: midpoint rule in (cos ψ, φ) around the axis (dω =
    d(cos ψ) dφ); exact π sin²γ |axis_z| when the cone does not cross the horizon."""
    axes = np.asarray(axes, dtype=float).reshape(-1, 3)
    cg = float(cos_half_angle)
    c = 1.0 - (np.arange(n_psi) + 0.5) / n_psi * (1.0 - cg)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    e1, e2 = _basis(axes)
    wz = (c[None, :, None] * axes[:, None, None, 2]
          + s[None, :, None] * (np.cos(phi)[None, None, :] * e1[:, None, None, 2]
                                + np.sin(phi)[None, None, :] * e2[:, None, None, 2]))
    same_side = np.sign(wz) == np.sign(axes[:, None, None, 2])
    dw = (1.0 - cg) / n_psi * (2.0 * np.pi / n_phi)
    return np.sum(np.where(same_side, np.abs(wz), 0.0), axis=(1, 2)) * dw


# --------------------------------------------------------------------------------------------
# Point estimates: next-event estimation at exact directions (walk.py, "Point estimates")
# --------------------------------------------------------------------------------------------

_INV_4PI = 0.25 / np.pi


def _hg_p(g, cos):
    """Henyey–Greenstein phase function of the scattering angle's cosine (w_before · w_after);
    isotropic where |g| < 1e-3, as :func:`_sample_hg` samples it (so it is also the density
    of that sampler)."""
    small = np.abs(g) < 1e-3
    den = np.maximum(1.0 + g * g - 2.0 * g * cos, 1e-300)
    return np.where(small, _INV_4PI, _INV_4PI * (1.0 - g * g) / (den * np.sqrt(den)))


def _ggx_g1(vx, vy, vz_abs, alpha):
    """Smith G1 of GGX (Walter eq. 34) without the sidedness factor."""
    den = vz_abs + np.sqrt(vz_abs * vz_abs + alpha * alpha * (vx * vx + vy * vy))
    return np.where(den > 0, 2.0 * vz_abs / np.where(den > 0, den, 1.0), 0.0)


def _ggx_d(hx, hy, hz, alpha):
    """GGX D(m) (Walter eq. 33) of the normal along h (unnormalized, hz > 0): degree-0
    homogeneous, α² |h|⁴ / (π ((α² − 1) hz² + |h|²)²)."""
    h2 = hx * hx + hy * hy + hz * hz
    a2 = alpha * alpha
    den = (a2 - 1.0) * hz * hz + h2
    with np.errstate(divide="ignore", invalid="ignore"):
        d = a2 * h2 * h2 / (np.pi * den * den)
    return np.where((hz > 0) & (den > 0), d, 0.0)


def _walter_frame(wi, wo, eta):
    """Mirror (wi, wo) so that wi.z >= 0 (eta = n_below / n_above becomes η_o/η_i of that side);
    the half-vector (eq. 13 or 16, unnormalized, turned to +z) and the cosines i·ĥ, o·ĥ."""
    s = np.where(wi[..., 2] < 0, -1.0, 1.0)
    ix, iy, ci = wi[..., 0], wi[..., 1], wi[..., 2] * s
    ox, oy, co = wo[..., 0], wo[..., 1], wo[..., 2] * s
    e = np.where(s > 0, eta, 1.0 / eta)
    is_r = co > 0
    eh = np.where(is_r, 1.0, e)
    hx, hy, hz = ix + eh * ox, iy + eh * oy, ci + eh * co
    t = np.where(hz < 0, -1.0, 1.0)
    hx, hy, hz = hx * t, hy * t, hz * t
    h2 = hx * hx + hy * hy + hz * hz
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(h2 > 0, 1.0 / np.sqrt(h2), 0.0)
    i_h = (ix * hx + iy * hy + ci * hz) * r
    o_h = (ox * hx + oy * hy + co * hz) * r
    return (ix, iy, ci), (ox, oy, co), e, is_r, (hx, hy, hz, h2), i_h, o_h


def _walter_f(wi, wo, alpha, eta):
    """Walter's BSDF, f_r (eq. 20) + f_t (eq. 21, radiance transport), 1/sr without the cosine;
    wi, wo (..., 3) unit, pointing away from the surface; eta = n_below / n_above."""
    (ix, iy, ci), (ox, oy, co), e, is_r, (hx, hy, hz, h2), i_h, o_h = _walter_frame(wi, wo, eta)
    F = _fresnel(i_h, e)
    D = _ggx_d(hx, hy, hz, alpha)
    G = (np.where(i_h * ci > 0, _ggx_g1(ix, iy, np.abs(ci), alpha), 0.0)
         * np.where(o_h * co > 0, _ggx_g1(ox, oy, np.abs(co), alpha), 0.0))
    num = np.where(is_r, F, np.abs(i_h * o_h) * e * e * (1.0 - F)) * G * D
    den = ci * np.abs(co) * np.where(is_r, 4.0, h2)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = num / den
    return np.where((ci > 0) & (den > 0), f, 0.0)


def _walter_pdf(wi, wo, alpha, eta):
    """Density per solid angle of wo in :func:`_walter_sample` from wi: D(m)|m·n| (eq. 24) times
    the Fresnel choice and the Jacobian of eq. 14 (reflection) or eq. 17 (refraction)."""
    (ix, iy, ci), (ox, oy, co), e, is_r, (hx, hy, hz, h2), i_h, o_h = _walter_frame(wi, wo, eta)
    F = _fresnel(i_h, e)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_m = _ggx_d(hx, hy, hz, alpha) * np.where(h2 > 0, hz / np.sqrt(h2), 0.0)
        jac = np.where(is_r, F / (4.0 * np.abs(o_h)), (1.0 - F) * e * e * np.abs(o_h) / h2)
    p = p_m * jac
    facing = (i_h > 0) & (o_h * co > 0) & (ci > 0)
    return np.where(facing & np.isfinite(p), p, 0.0)


def _walter_sample(wi, u, alpha, eta):
    """Walter section 5.3 for wi (..., 3) on either side, u (..., 3): the sampled direction, the
    weight f|cos θo|/pdf (eq. 41) and the density of the direction (as :func:`_walter_pdf`)."""
    s = np.where(wi[..., 2] < 0, -1.0, 1.0)
    ix, iy, iz = wi[..., 0], wi[..., 1], wi[..., 2] * s
    e = np.where(s > 0, eta, 1.0 / eta)
    a2 = alpha * alpha
    u0 = u[..., 0]
    den = 1.0 - u0 + a2 * u0
    ct = np.sqrt((1.0 - u0) / den)
    st = np.sqrt(a2 * u0 / den)
    phi = 2.0 * np.pi * u[..., 1]
    mx, my, mz = st * np.cos(phi), st * np.sin(phi), ct
    c = ix * mx + iy * my + iz * mz
    F = _fresnel(c, e)
    refl = u[..., 2] < F
    inv = 1.0 / e
    root = np.sqrt(np.maximum(1.0 + inv * inv * (c * c - 1.0), 0.0))
    a = np.where(refl, 2.0 * c, inv * c - root)  # eq. 39 / eq. 40: o = a m − b i
    bb = np.where(refl, 1.0, inv)
    ox, oy, oz = a * mx - bb * ix, a * my - bb * iy, a * mz - bb * iz
    valid = (iz > 0) & (c > 0) & np.where(refl, oz > 0, oz < 0)
    o_m = ox * mx + oy * my + oz * mz
    G = (np.where(c * iz > 0, _ggx_g1(ix, iy, np.abs(iz), alpha), 0.0)
         * np.where(o_m * oz > 0, _ggx_g1(ox, oy, np.abs(oz), alpha), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = c * G / (iz * mz)
        p_m = a2 / (np.pi * ((a2 - 1.0) * mz * mz + 1.0) ** 2) * mz
        p = p_m * np.where(refl, F / (4.0 * np.abs(o_m)),
                           (1.0 - F) * e * e * np.abs(o_m) / (c + e * o_m) ** 2)
    weight = np.where(valid & np.isfinite(weight), weight, 0.0)
    p = np.where(valid & np.isfinite(p), p, 0.0)
    return np.stack([ox, oy, oz * s], -1), weight, p


class _PointSide:
    """One side's connection data (reflection: wo_z > 0, transmission: wo_z < 0)."""

    def __init__(self, side, cols, wo, kinds, alpha, eta, n_idx, thick, sig_t):
        M = len(kinds) - 1
        self.side, self.cols = side, cols
        rough = [j for j, kd in enumerate(kinds) if kd == "ggx"]
        if side == "up":
            k = rough[0] if rough else M + 1
            between = [j for j in range(1, min(k, M + 1)) if kinds[j] != "pass"]
            exit_b, n_out, n_in = 0, n_idx[0], n_idx[1]
        else:
            k = rough[-1] if rough else -1
            between = [j for j in range(max(k + 1, 0), M) if kinds[j] != "pass"]
            exit_b, n_out, n_in = M, n_idx[M + 1], n_idx[M]
        if between:
            raise ValueError(f"point estimates on the {side} side: boundary {between[0]} is "
                             "specular and lies between the outside and the connecting one")
        self.k = k
        if k == exit_b or kinds[exit_b] == "pass":
            d, chain = wo.copy(), np.ones(wo.shape[0])
        else:  # reverse refraction through the smooth exit boundary
            r = n_out / n_in  # η_exit / η_inside
            tx, ty = wo[:, 0] * r, wo[:, 1] * r
            s2 = tx * tx + ty * ty
            dz = np.sqrt(np.maximum(1.0 - s2, 0.0)) * np.sign(wo[:, 2])
            F = _fresnel(np.abs(wo[:, 2]), n_in / n_out)
            ok = s2 < 1.0
            chain = np.where(ok, (1.0 - F) * r * r * np.abs(wo[:, 2])
                             / np.where(ok, np.abs(dz), 1.0), 0.0)
            d = np.stack([tx, ty, dz], 1)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.d, self.chain = d, chain
        self.abs_dz = np.abs(d[:, 2])
        self.inv_dz = 1.0 / np.maximum(self.abs_dz, 1e-300)
        tau = sig_t[:, None] * thick[:, None] * self.inv_dz[None, :]  # (regions, R)
        if side == "up":  # optical depth of the regions above region r
            self.depth = np.cumsum(tau, 0) - tau
            exit_od = (self.depth[k] + tau[k]) if k <= M else np.zeros(d.shape[0])
        else:  # ... below region r
            self.depth = np.cumsum(tau[::-1], 0)[::-1] - tau
            exit_od = (self.depth[k + 1] + tau[k + 1]) if k >= 0 else np.zeros(d.shape[0])
        # transmittance from boundary k to the outside along d, with the crossing factor
        self.exit_t = np.exp(-exit_od) * chain
        if 0 <= k <= M:
            self.alpha_k, self.eta_k = float(alpha[k]), float(eta[k])
            # BSDF value of k toward d times |cos θd| times the way out (per direction)
            self.f_scale = self.abs_dz * self.exit_t
        # vertex strategy: k rough with a medium region behind it
        self.behind = k + 1 if side == "up" else k
        self.v_ok = 0 <= k <= M and kinds[k] == "ggx" and 1 <= self.behind <= M
        self.far = self.behind if side == "up" else self.behind - 1
        self.far_ok = self.v_ok and 0 <= self.far <= M and kinds[self.far] == "ggx"
        if self.v_ok:
            e2 = self.eta_k ** 2
            self.ratio = 1.0 / e2 if side == "up" else e2  # (η on d's side / η on d′'s side)²


def _connect_points(ps, acc, rng, region, z, w, beta, scatter, hit, b, last_pdf, thick, sig_t,
                    hg_g, alpha, eta):
    """Add this event's connections to the side ``ps`` to ``acc`` (live paths × its directions):
    the event at boundary k (reflection from the exit's side, transmission from behind it,
    balanced against the vertex strategy there), direct connections of volume events between k
    and the outside, and the vertex strategy behind k."""
    k, d = ps.k, ps.d
    up = ps.side == "up"
    M = thick.size - 2
    if 0 <= k <= M:
        sel = np.flatnonzero(hit & (b == k))
        if sel.size:
            wi = -w[sel][:, None, :]
            val = _walter_f(wi, d[None], ps.alpha_k, ps.eta_k) * ps.f_scale[None]
            if ps.v_ok:
                # crossing strategy: the walk's own path through k from the region behind it,
                # weighted against the vertex strategy that could have sampled it (balance)
                cr = np.flatnonzero(region[sel] == ps.behind)
                if cr.size:
                    q = _walter_pdf(d[None], wi[cr], ps.alpha_k, ps.eta_k)
                    pl = last_pdf[sel[cr]][:, None]
                    with np.errstate(divide="ignore", invalid="ignore"):
                        wc = np.where(pl > 0, pl / np.maximum(pl + q, 1e-300), 1.0)
                    val[cr] *= wc
            acc[sel] += beta[sel][:, None] * val
    # volume events between k and the outside: direct connections
    sel = np.flatnonzero(scatter & ((region <= k) if up else (region >= k + 1)))
    if sel.size:
        r = region[sel]
        dist = z[sel] if up else thick[r] - z[sel]
        od = ps.depth[r] + (sig_t[r] * dist)[:, None] * ps.inv_dz[None]
        p = _hg_p(hg_g[r][:, None], w[sel] @ d.T)
        acc[sel] += (beta[sel][:, None] * ps.chain[None]) * p * np.exp(-od)
    if not ps.v_ok:
        return
    # vertex strategy: volume events in the region behind k and events at its far boundary,
    # connected through a reverse sample of k's BSDF from d
    vmask = scatter & (region == ps.behind)
    if ps.far_ok:
        vmask = vmask | (hit & (b == ps.far))
    sel = np.flatnonzero(vmask)
    if not sel.size:
        return
    n, R = sel.size, d.shape[0]
    u = rng.random((n, R, 3))
    t, wt, q = _walter_sample(np.broadcast_to(d[None], (n, R, 3)), u, ps.alpha_k, ps.eta_k)
    into = t[..., 2] < 0 if up else t[..., 2] > 0
    dp = -t  # from the vertex toward k
    dz = np.maximum(np.abs(dp[..., 2]), 1e-300)
    w_rev = np.where(into, ps.ratio * wt * ps.abs_dz[None] / dz, 0.0)
    f_v = np.zeros((n, R))
    p_v = np.zeros((n, R))
    wv = w[sel]
    is_vol = scatter[sel]
    iv = np.flatnonzero(is_vol)
    if iv.size:
        ph = _hg_p(hg_g[ps.behind], np.einsum("nk,nrk->nr", wv[iv], dp[iv]))
        f_v[iv] = ph
        p_v[iv] = ph
    ib = np.flatnonzero(~is_vol)
    if ib.size:
        wi_b = -wv[ib][:, None, :]
        a_f, e_f = float(alpha[ps.far]), float(eta[ps.far])
        f_v[ib] = _walter_f(wi_b, dp[ib], a_f, e_f) * dz[ib]
        p_v[ib] = _walter_pdf(wi_b, dp[ib], a_f, e_f)
    zb = z[sel]
    length = np.where(is_vol, zb if up else thick[ps.behind] - zb, thick[ps.behind])
    att = np.exp(-sig_t[ps.behind] * length[:, None] / dz)
    with np.errstate(divide="ignore", invalid="ignore"):
        w_v = q / np.maximum(q + p_v, 1e-300)
        val = (beta[sel][:, None] * ps.exit_t[None]) * f_v * att * w_rev * w_v
    acc[sel] += np.where(into & np.isfinite(val), val, 0.0)


def simulate_numpy_points(regions, boundaries, wi, samples, wo_dirs, seed=0, max_events=512,
                          rr_start=3, rr_min_q=0.05, batch=1 << 16):
    """Point estimates of f(wi, wo) at the unit directions ``wo_dirs`` (R, 3) (z > 0:
    reflection, z < 0: transmission), by the next-event estimation of walk.py "Point
    estimates", for the scenes of :func:`simulate_numpy` (same ``regions``, ``boundaries``).

    The walk is that of :func:`simulate_numpy` (same sampling, Russian roulette, event cap);
    each event connects to the requested directions: for reflection the connecting boundary k
    is the first GGX one from the top (a smooth top is crossed by reverse refraction, factor
    (1 − F)(η_exit/η_inside)²|cos θo|/|cos θd|), the events are reflection at k from above,
    transmission through k from below and volume scattering above k; behind k (a medium
    region), volume events and events at that region's far GGX boundary also connect through a
    reverse sample of k (Walter section 5.3 from d, reciprocity eq. 21), balanced against the
    walk's own crossing of k by the balance heuristic (the crossing weighted p_v/(q + p_v),
    p_v the density of the path's last event, 0 after a specular one). Transmission is the
    mirror image from the bottom. Delta lobes are not point values and are left out.

    Each path's connections are summed; ``value`` is their mean over ``samples`` paths divided
    by |cos θo| and ``sigma`` the standard error of that mean (from the per-path sums). Paths
    run in float64 in batches of ``batch`` (memory: (batch × R) arrays), live paths compacted
    after every event. Returns (value (R,), sigma (R,), events), ``events`` the number of
    events traced in total (fitlab's ``res.events``); paths still alive after ``max_events``
    events are dropped, as fitlab drops them."""
    rng = np.random.default_rng(seed)
    M = len(regions) - 2
    n_idx = np.array([r["index"] for r in regions], dtype=float)
    thick = np.array([r.get("thickness", 0.0) for r in regions], dtype=float)
    sig_a = np.array([r.get("sigma_a", 0.0) for r in regions], dtype=float)
    sig_s = np.array([r.get("sigma_s", 0.0) for r in regions], dtype=float)
    hg_g = np.array([r.get("g", 0.0) for r in regions], dtype=float)
    sig_t = sig_a + sig_s
    kinds = [bd["kind"] for bd in boundaries]
    if len(kinds) != M + 1 or any(kd not in ("pass", "smooth", "ggx") for kd in kinds):
        raise ValueError("boundaries: M + 1 of kind 'pass', 'smooth' or 'ggx'")
    alpha = np.array([bd.get("alpha", 0.0) for bd in boundaries], dtype=float)
    eta = n_idx[1:] / n_idx[:-1]
    wo = np.asarray(wo_dirs, dtype=float).reshape(-1, 3)
    wo = wo / np.linalg.norm(wo, axis=1, keepdims=True)
    R = wo.shape[0]
    sides = []
    for side, mask in (("up", wo[:, 2] > 0), ("down", wo[:, 2] < 0)):
        cols = np.flatnonzero(mask)
        if cols.size:
            sides.append(_PointSide(side, cols, wo[cols], kinds, alpha, eta, n_idx, thick,
                                    sig_t))
    S1 = [np.zeros(ps.cols.size) for ps in sides]
    S2 = [np.zeros(ps.cols.size) for ps in sides]
    w0 = -np.asarray(wi, dtype=float)
    w0 = w0 / np.linalg.norm(w0)
    n_events = 0
    for start in range(0, samples, batch):
        N = min(batch, samples - start)
        region = np.zeros(N, dtype=np.int64)
        z = np.zeros(N)
        w = np.tile(w0, (N, 1))
        weight = np.ones(N)
        events = np.zeros(N, dtype=np.int64)
        last_pdf = np.zeros(N)
        accs = [np.zeros((N, ps.cols.size)) for ps in sides]
        for _ in range(max_events):
            n = region.size
            if n == 0:
                break
            n_events += n
            u = rng.random((n, 8))
            down, scatter, weight, z, alive = _flight(w, region, z, weight, u, thick, sig_s,
                                                      sig_a, M)
            hit = alive & ~scatter
            b = np.clip(np.where(down, region, region - 1), 0, M)
            # next-event connections of this event (weight after the flight, before the event)
            for ps, acc in zip(sides, accs):
                _connect_points(ps, acc, rng, region, z, w, weight, scatter, hit, b, last_pdf,
                                thick, sig_t, hg_g, alpha, eta)
            # the event itself
            new_w = w.copy()
            new_pdf = np.where(hit, 0.0, last_pdf)  # specular and pass boundaries: 0
            if scatter.any():
                sc = np.flatnonzero(scatter)
                g_sc = hg_g[region[sc]]
                ws = _sample_hg(-w[sc], g_sc, u[sc, 4:6])
                ws /= np.linalg.norm(ws, axis=1, keepdims=True)
                new_w[sc] = ws
                new_pdf[sc] = _hg_p(g_sc, np.sum(w[sc] * ws, 1))
            for j, kind in enumerate(kinds):
                if kind == "pass":
                    continue
                sel = np.flatnonzero(hit & (b == j))
                if not sel.size:
                    continue
                if kind == "smooth":
                    e = np.where(w[sel, 2] < 0, eta[j], 1.0 / eta[j])
                    new_w[sel] = _smooth(w[sel], e, u[sel, 2])
                else:
                    wo_s, wt, pdf = _walter_sample(-w[sel], u[sel, 0:3], alpha[j], eta[j])
                    new_w[sel] = wo_s
                    weight[sel] *= wt
                    new_pdf[sel] = pdf
            new_w /= np.linalg.norm(new_w, axis=1, keepdims=True)
            up_new = new_w[:, 2] > 0
            region = np.where(hit, np.where(up_new, b, b + 1), region)
            z = np.where(hit, np.where(up_new, thick[b], 0.0), z)
            leaving = alive & (((region == 0) & up_new) | ((region == M + 1) & ~up_new))
            alive = alive & ~leaving & (weight > 0)
            events = events + alive
            alive, weight = _roulette(alive, weight, events, u[:, 7], rr_start, rr_min_q)
            # a finished path's sums go to the totals
            done = np.flatnonzero(~alive)
            if done.size:
                for i, acc in enumerate(accs):
                    a = acc[done]
                    S1[i] += a.sum(0)
                    S2[i] += np.einsum("nr,nr->r", a, a)
            keep = np.flatnonzero(alive)
            region, z, w, weight = region[keep], z[keep], new_w[keep], weight[keep]
            events, last_pdf = events[keep], new_pdf[keep]
            accs = [acc[keep] for acc in accs]
        # paths still alive after max_events are dropped (their sums with them)
    value = np.zeros(R)
    sigma = np.zeros(R)
    Nt = float(samples)
    for ps, s1, s2 in zip(sides, S1, S2):
        mean = s1 / Nt
        var = np.maximum(s2 / Nt - mean * mean, 0.0) / max(Nt - 1.0, 1.0)
        cz = np.abs(wo[ps.cols, 2])
        value[ps.cols] = mean / cz
        sigma[ps.cols] = np.sqrt(var) / cz
    return value, sigma, n_events
