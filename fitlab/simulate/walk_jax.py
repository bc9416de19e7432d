"""Vectorized random walk through a layer stack, in JAX.

One call of :func:`run_batch` traces a fixed number of paths for one incident direction on a
fixed number of lanes inside one ``lax.while_loop`` (one scattering event per iteration, every
lane masked by ``alive``; a lane whose path ends starts the next path) and returns the tallies
in float64: per bounce-order class and detector bin, the sum and the sum of squares of the path
contributions. Paths are float32 (``WalkConfig.dtype``); only what the effect plan asks for is
compiled (``WalkConfig`` is static).

Geometry (scene.py): regions 0..M+1 (0 = outside, M+1 = below), boundary b between regions b
and b+1. A path has a region, a depth ``z`` below the region's top, a propagation direction
``w`` and a weight per channel. Each iteration: a path in a medium flies (free-flight sampling
by σs when volume scattering is compiled, Beer–Lambert weights for absorption); it either
scatters in the volume (phase function sampled exactly, fitlab/phase.py) or meets a boundary,
where the boundary's BSDF is sampled with the existing models (rough dielectric: Walter
section 5.3 through fitlab.models.rough_dielectric.MODEL.sample, weight eq. 41; rough
conductor: fitlab.models.rough_conductor.MODEL.sample; Lambertian: cosine sampling; smooth
dielectric: Fresnel choice between mirror and Snell directions, fitlab.fresnel.fresnel_dielectric). Paths that leave into region 0 upward or region M+1
downward exit; their final direction and weight are tallied after the loop.

Point estimates (``detector = "points"``): next-event estimation toward exact outgoing
directions d_o, in the manner of position-free Monte Carlo (Guo, Hašan, Zhao 2018, which
connects every vertex of a layered walk to the outgoing direction). Every path that leaves along
d_o has a last non-specular event; after it only specular boundaries (or none) lie between the
path and the outside, so the direction it must take there is fixed by d_o: reverse refraction
through the specular boundaries (fitlab.fresnel.fresnel_dielectric) gives the direction d inside
and the flux factor (1 − F) (η_exit/η_inside)² |cos θo| / |cos θd| of each crossing
(solid-angle compression). At each event that can be that last event — the first rough boundary
k from the outside (reflection there from the outside's side, transmission toward the outside
from the other side) and volume scattering between it and the outside — the walk adds
β · f_event(−w, d) |cos θd| (a boundary's BSDF, radiance convention, as its sampler) or
β · p(−w, d) (a phase function) times the transmittance along d to the outside and the crossing
factors: the flux fraction per steradian leaving along d_o, whose expectation is
f(wi, d_o) |cos θo| (detectors.py divides by |cos θo|). Where a specular boundary between k and
the outside could send light back toward the outside, the estimate would miss light: such
stacks are refused (detectors.point_connections). A path leaving by itself reaches an exact
direction with probability 0, so it adds nothing; but the events right behind a rough
dielectric k (volume scattering in the region behind it, events at that region's far boundary)
reach k two ways: the walk's own path crossing k (its BTDF evaluated toward d: noisy when k is
sharp) and a connection from the vertex through a reverse sample of k's BSDF (noisy when the
vertex is sharp). The two are combined with the balance heuristic (:func:`_connect`). Each
path's connections are summed per lane and per bounce-order class, and a lane's sums go to the
float64 totals (and their squares to the second moments) when its path ends, so the standard
error is that of the per-path estimate.

Bounce order: the number of turns from downward to upward travel below the top interface (the
extended-NDF paper's eq. 25 terms: 0 = surface reflection, 1 = one-bounce subsurface reflection);
tallied in four classes 0, 1, 2, ≥3.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from fitlab.fresnel import fresnel_conductor_exact, fresnel_dielectric, fresnel_schlick
from fitlab.frame import normalize
from fitlab.models import rough_conductor, rough_dielectric
from fitlab.models.rough_dielectric import CHOOSE, REFLECT, REFRACT
from fitlab.phase import PHASE_FUNCTIONS, sggx_sigma

#: Bounce-order classes tallied separately: 0, 1, 2, ≥ 3.
ORDER_CLASSES = ("order0", "order1", "order2", "rest")
#: Russian roulette starts after this many events of a path.
RR_START = 3
#: Smallest survival probability of Russian roulette.
RR_MIN_Q = 0.05


class WalkConfig(NamedTuple):
    """Static description of the walk (hashable: one compilation per distinct config)."""

    n_media: int
    boundary_groups: tuple  # per boundary: "pass", "smooth", "rough:<dist>", "lambertian", "conductor:<dist|smooth>"
    region_phase: tuple  # per region 0..M+1: None, "isotropic", "hg", "sggx"
    channels: int
    reflection: bool
    transmission: bool
    max_bounces: int  # -1 = all
    russian_roulette: bool
    volume: bool
    volume_limit: int  # -1 = unlimited
    absorption: bool
    extinction_only: bool
    delta: bool
    end_downward_after_last_bounce: bool
    max_events: int
    detector: str  # "bins", "cones" or "points"
    theta_bins: int
    phi_bins: int
    dtype: str = "float32"
    # points: the boundary where the reflection side connects (first rough one from the top;
    # n_media + 1: volume events only) and the transmission side (last rough one; -1: volume
    # only); None: that side has no requested direction
    point_up: int | None = None
    point_down: int | None = None
    # branch forcing (effects.EffectPlan.force_top / force_bottom)
    force_top: bool = False
    force_bottom: bool = False
    # splitting at the first interface (effects.EffectPlan.split_first): the walk's first
    # crossing refracts (weight 1 − F); the reflected branch is tallied apart (run_batch)
    split_first: bool = False
    # SGGX flakes with a Schlick reflectance f0 < 1 somewhere (WalkArrays.flake_f0)
    flake_fresnel: bool = False


class WalkArrays(NamedTuple):
    """Per-region and per-boundary properties (a pytree of arrays, float32)."""

    thickness: jax.Array  # (R,)
    sigma_a: jax.Array  # (R, C)
    sigma_s: jax.Array  # (R,) scattering coefficient used for free flights
    sigma_s_c: jax.Array  # (R, C) σs per channel (extinction-only attenuation)
    hg_g: jax.Array  # (R,)
    sggx_S: jax.Array  # (R, 3, 3)
    alpha: jax.Array  # (Bd,) width (along +x when anisotropic)
    alpha_y: jax.Array  # (Bd,) width along +y (= alpha when isotropic)
    eta: jax.Array  # (Bd,) n_below / n_above
    albedo: jax.Array  # (Bd, C)
    cond_n: jax.Array  # (Bd, C) relative to the medium above
    cond_k: jax.Array  # (Bd, C)
    flake_f0: jax.Array  # (R, C) Schlick reflectance of SGGX flakes (1: none)


class Detector(NamedTuple):
    """Per-incidence detector arrays: cones (R, 3) directions and cos of the half angle (R,);
    points: the requested directions (R, 3) (cone_cos unused); for bins these are unused
    (size-1 placeholders)."""

    cone_dir: jax.Array
    cone_cos: jax.Array


class State(NamedTuple):
    region: jax.Array
    z: jax.Array
    w: jax.Array
    weight: jax.Array
    alive: jax.Array
    exited: jax.Array
    bounces: jax.Array
    vol_events: jax.Array
    events: jax.Array
    diffuse: jax.Array
    # the next event's sampled outcomes (see _propose), carried in the loop state
    prop_wv: jax.Array  # (B, 3) direction after a volume scattering event
    prop_wb: jax.Array  # (B, 3) direction after the boundary the path travels toward
    prop_fb: jax.Array  # (B, C) weight factor of that boundary event
    prop_db: jax.Array  # (B,) whether that boundary event is non-specular
    # point estimates only (zeros otherwise): the densities of the proposed directions and the
    # density with which the path's last event sampled its current direction (0: specular)
    prop_pv: jax.Array  # (B,)
    prop_pb: jax.Array  # (B,)
    last_pdf: jax.Array  # (B,)


def _flip_z(w):
    return w * jnp.asarray([1.0, 1.0, -1.0], dtype=w.dtype)


def _smooth_dielectric(w, eta, u, force=None):
    """Smooth interface met by propagation direction w: reflect with probability F (Walter
    eq. 22, TIR included), else refract by Snell's law; both from one
    :func:`fitlab.fresnel.fresnel_dielectric` (eta = n_below / n_above; the light comes from
    above when w.z < 0, i.e. the incident direction -w has a positive cosine). Returns the new
    direction and the weight factor: 1, or with ``force`` (per lane: CHOOSE, REFLECT, REFRACT
    as in :func:`fitlab.models.rough_dielectric.walter_sample`) F or 1 − F for a forced
    branch."""
    F, cos_t, _, eta_ti = fresnel_dielectric(-w[..., 2], eta)
    w_t = jnp.stack([w[..., 0] * eta_ti, w[..., 1] * eta_ti, cos_t], axis=-1)
    reflect = u < F
    factor = jnp.ones_like(F)
    if force is not None:
        reflect = jnp.where(force == CHOOSE, reflect, force == REFLECT)
        factor = jnp.where(force == CHOOSE, 1.0, jnp.where(reflect, F, 1.0 - F))
    return jnp.where(reflect[..., None], _flip_z(w), w_t), factor


def _forced_branch(cfg, st, b):
    """Per lane, the branch forcing at boundary b (None when the walk forces nothing): the top
    boundary refracts light from outside and reflects light from inside when reflection is not
    observed; the bottom boundary reflects light from above when transmission is not."""
    if not (cfg.force_top or cfg.force_bottom or cfg.split_first):
        return None
    down = st.w[:, 2] < 0
    force = jnp.full(b.shape, CHOOSE, jnp.int32)
    if cfg.force_bottom:
        force = jnp.where((b == cfg.n_media) & down, REFLECT, force)
    if cfg.force_top:
        force = jnp.where(b == 0, jnp.where(down, REFRACT, REFLECT), force)
    if cfg.split_first:  # the first crossing, from outside: its reflection is tallied apart
        force = jnp.where((b == 0) & down & (st.region == 0), REFRACT, force)
    return force


def _rough(module, group, alpha, alpha_y):
    """The microfacet model (isotropic or anisotropic) of a rough boundary group
    ("ggx" or "ggx:anisotropic") and its width parameters."""
    if group.endswith(":anisotropic"):
        return module.ANISOTROPIC, {"alpha_x": alpha, "alpha_y": alpha_y}
    return module.MODEL, {"alpha": alpha}


def _boundary_event(cfg, arr, st, b, u, force=None):
    """New propagation direction, weight factor (B, C), whether the event is non-specular and
    the density of the sampled direction per solid angle (0 for a specular event), for every
    path meeting boundary b (B,). ``force``: the branch forcing per lane (default: the walk's,
    :func:`_forced_branch`)."""
    dt = st.w.dtype
    B = st.w.shape[0]
    C = cfg.channels
    w = st.w
    wi = -w  # toward where the light came from
    new_w = w
    factor = jnp.ones((B, C), dtype=dt)
    diffuse = jnp.zeros((B,), dtype=bool)
    pdf = jnp.zeros((B,), dtype=dt)
    groups = cfg.boundary_groups
    if force is None:
        force = _forced_branch(cfg, st, b)
    for g in sorted(set(groups)):
        ids = [j for j, gj in enumerate(groups) if gj == g]
        sel = functools.reduce(jnp.logical_or, [b == j for j in ids])
        if g == "pass":
            continue
        gp = jnp.zeros((B,), dtype=dt)
        if g == "smooth":
            gw, wt = _smooth_dielectric(w, arr.eta[b], u[:, 2], force)
            gf, gd = jnp.broadcast_to(wt[:, None], (B, C)), jnp.zeros((B,), dtype=bool)
        elif g.startswith("rough:"):
            model, params = _rough(rough_dielectric, g[6:], arr.alpha[b], arr.alpha_y[b])
            params = {**params, "eta": arr.eta[b]}
            gw, wt, gp = rough_dielectric.walter_sample(
                model.microfacet(params, g[6:].split(":")[0]), params, wi, u[:, 0:3],
                force=force)
            gf, gd = jnp.broadcast_to(wt[:, None], (B, C)), jnp.ones((B,), dtype=bool)
        elif g == "lambertian":
            # cosine-weighted hemisphere (Malley), weight = albedo
            r = jnp.sqrt(u[:, 0])
            phi = 2.0 * jnp.pi * u[:, 1]
            z = jnp.sqrt(jnp.maximum(1.0 - u[:, 0], 0.0))
            gw = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), z], axis=-1)
            gf, gd, gp = arr.albedo[b], jnp.ones((B,), dtype=bool), z / jnp.pi
        elif g == "conductor:smooth":
            gw = _flip_z(w)
            gf = fresnel_conductor_exact(jnp.abs(w[:, 2:3]), arr.cond_n[b], arr.cond_k[b])
            gd = jnp.zeros((B,), dtype=bool)
        elif g.startswith("conductor:"):
            model, params = _rough(rough_conductor, g[10:], arr.alpha[b][:, None],
                                   arr.alpha_y[b][:, None])
            wo, wt, gp = model.sample({**params, "n": arr.cond_n[b], "k": arr.cond_k[b]},
                                      wi[:, None, :], u[:, None, 0:3],
                                      distribution=g[10:].split(":")[0])
            gw, gf, gd, gp = wo[:, 0, :], wt, jnp.ones((B,), dtype=bool), gp[:, 0]
        else:  # pragma: no cover - scene.py admits no other kind
            raise ValueError(g)
        new_w = jnp.where(sel[:, None], gw, new_w)
        factor = jnp.where(sel[:, None], gf, factor)
        diffuse = jnp.where(sel, gd, diffuse)
        pdf = jnp.where(sel, gp, pdf)
    return new_w, factor, diffuse, pdf


def _volume_event(cfg, arr, st, u):
    """Phase-function sampling for every path (selected by the caller): the new direction and
    its density."""
    wi = -st.w
    new_w = st.w
    pdf = jnp.zeros(st.w.shape[:1], st.w.dtype)
    for kind in sorted({p for p in cfg.region_phase if p is not None}):
        sel = functools.reduce(jnp.logical_or, [st.region == j for j, p in
                                               enumerate(cfg.region_phase) if p == kind])
        sample = PHASE_FUNCTIONS[kind][1]
        if kind == "hg":
            params = {"g": arr.hg_g[st.region]}
        elif kind == "sggx":
            params = {"S": arr.sggx_S[st.region]}
        else:
            params = {}
        wo, p = sample(params, wi, u)
        new_w = jnp.where(sel[:, None], wo, new_w)
        pdf = jnp.where(sel, p, pdf)
    return new_w, pdf


def _projected_area(cfg, arr, st):
    """σ(w) of SGGX media (SpongeCake eq. 3/7): the directional factor of their coefficients."""
    if "sggx" not in cfg.region_phase:
        return jnp.ones_like(st.z)
    sel = functools.reduce(jnp.logical_or, [st.region == j for j, p in
                                           enumerate(cfg.region_phase) if p == "sggx"])
    return jnp.where(sel, sggx_sigma(arr.sggx_S[st.region], st.w), 1.0)


def _lowbias32(x):
    """Chris Wellons' 32-bit integer hash ("lowbias32", bias 0.17 of the best known)."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def uniforms(seed_words, i, n, k, dtype):
    """(n, k) uniforms in [0, 1) for iteration i: a counter-based hash of (seed, iteration, lane,
    slot), so every random number of a walk is a pure function of its coordinates (cheaper on
    CPU than threefry, which cost a sixth of a walk step). 24 random bits each: the smallest
    nonzero 1 - u is 2^-24, so a sampled free flight is cut at 16.6 mean free paths
    (probability 6e-8)."""
    lane = jnp.arange(n, dtype=jnp.uint32)[:, None]
    slot = jnp.arange(k, dtype=jnp.uint32)[None, :]
    h = _lowbias32(seed_words[0] ^ _lowbias32(i.astype(jnp.uint32) + jnp.uint32(0x9E3779B9)))
    h = _lowbias32(h ^ (lane * jnp.uint32(0x85EBCA6B) + seed_words[1]))
    h = _lowbias32(h + slot * jnp.uint32(0xC2B2AE35))
    return (h >> 8).astype(dtype) * jnp.asarray(2.0**-24, dtype=dtype)


def _propose(cfg, arr, key, i, st):
    """Sample the outcomes iteration i needs from the state at its start: the direction after a
    volume event (if volume code is compiled) and the event at the boundary the path travels
    toward. They are stored in the loop state, so XLA materializes them once per iteration:
    computed inside the step, the sampling chains were fused into each of their many consumers
    and evaluated several times over (7 copies of the phase function's sin/cos in the compiled
    step, whose transcendental functions XLA:CPU evaluates in scalar code)."""
    dt = st.w.dtype
    B = st.w.shape[0]
    u = uniforms(key, i, B, 8, dt)
    down = st.w[:, 2] < 0
    b = jnp.clip(jnp.where(down, st.region, st.region - 1), 0, cfg.n_media)
    w_b, f_b, diff_b, p_b = _boundary_event(cfg, arr, st, b, u[:, 0:3])
    w_v, p_v = _volume_event(cfg, arr, st, u[:, 4:6]) if cfg.volume else (st.prop_wv, st.prop_pv)
    if cfg.detector != "points":  # the densities serve the point estimates' weights only
        p_b, p_v = st.prop_pb, st.prop_pv
    return st._replace(prop_wv=w_v, prop_wb=w_b, prop_fb=f_b, prop_db=diff_b, prop_pv=p_v,
                       prop_pb=p_b)


def _step(cfg, arr, key, i, st, pts=None):
    """One event of every live lane, with the outcomes sampled by ``_propose(..., i, st)``.
    With ``pts`` (:func:`_point_setup`), also the next-event connections of this event to the
    requested directions: returns (state, contributions (B, 4, R, C)); else the state."""
    dt = st.w.dtype
    B = st.w.shape[0]
    M = cfg.n_media
    u = uniforms(key, i, B, 8, dt)
    wz = st.w[:, 2]
    down = wz < 0
    in_medium = st.alive & (st.region >= 1) & (st.region <= M)

    # --- flight through the current medium -------------------------------------------------
    thick = arr.thickness[st.region]
    abs_wz = jnp.abs(wz)
    horizontal = abs_wz < 1e-7
    safe_wz = jnp.where(horizontal, 1.0, abs_wz)
    d_boundary = jnp.where(down, thick - st.z, st.z) / safe_wz
    d_boundary = jnp.where(in_medium, jnp.maximum(d_boundary, 0.0), 0.0)
    proj = _projected_area(cfg, arr, st) if (cfg.volume or cfg.absorption or cfg.extinction_only) \
        else None
    scatter = jnp.zeros((B,), dtype=bool)
    d = d_boundary
    factor = jnp.ones_like(st.weight)
    if cfg.volume:
        sig_s = arr.sigma_s[st.region] * proj
        can = sig_s > 0
        if cfg.volume_limit >= 0:
            can = can & (st.vol_events < cfg.volume_limit)
        t = -jnp.log1p(-u[:, 3]) / jnp.where(can, sig_s, 1.0)
        scatter = in_medium & can & (t < d_boundary)
        d = jnp.where(scatter, t, d_boundary)
        if cfg.volume_limit >= 0:
            # after the allowed events σs only attenuates (the unscattered part of the light)
            lost = in_medium & ~can
            factor = factor * jnp.exp(-jnp.where(lost, sig_s * d, 0.0))[:, None]
    if cfg.absorption:
        sig_a = arr.sigma_a[st.region] * proj[:, None]
        factor = factor * jnp.exp(-jnp.where(in_medium[:, None], sig_a * d[:, None], 0.0))
    if cfg.extinction_only:
        sig = arr.sigma_s_c[st.region] * proj[:, None]
        factor = factor * jnp.exp(-jnp.where(in_medium[:, None], sig * d[:, None], 0.0))
    z = jnp.where(in_medium, st.z - d * wz, st.z)
    weight = st.weight * factor
    alive = st.alive & ~(in_medium & horizontal & ~scatter)  # a horizontal flight never ends

    # --- next-event connections of this event to the requested directions --------------------
    hit = alive & ~scatter
    b = jnp.clip(jnp.where(down, st.region, st.region - 1), 0, M)
    nee = None if pts is None else _connect(cfg, arr, pts, st, weight, z, scatter & alive, hit,
                                            b, key, i)

    # --- volume scattering -------------------------------------------------------------------
    w = st.w
    vol_events = st.vol_events
    diffuse = st.diffuse
    if cfg.volume:
        w_v = st.prop_wv
        if cfg.flake_fresnel:
            weight = weight * jnp.where(scatter[:, None], _flake_F(
                cfg, arr, st.region, -st.w[:, None], w_v[:, None])[:, 0], 1.0)
        w = jnp.where(scatter[:, None], w_v, w)
        vol_events = vol_events + scatter.astype(jnp.int32)
        diffuse = diffuse | scatter

    # --- boundary events ---------------------------------------------------------------------
    w_b, f_b, diff_b = st.prop_wb, st.prop_fb, st.prop_db
    w = jnp.where(hit[:, None], w_b, w)
    weight = jnp.where(hit[:, None], weight * f_b, weight)
    diffuse = diffuse | (hit & diff_b)
    last_pdf = st.last_pdf
    if pts is not None:
        last_pdf = jnp.where(scatter, st.prop_pv, jnp.where(hit, jnp.where(diff_b, st.prop_pb, 0.0),
                                                            last_pdf))
    # float32 rounding of the sampled directions would compound over long paths (the phase
    # functions' local frames assume unit vectors): renormalize after every event
    w = normalize(w)
    up_new = w[:, 2] > 0
    region = jnp.where(hit, jnp.where(up_new, b, b + 1), st.region)
    z = jnp.where(hit, jnp.where(up_new, arr.thickness[b], 0.0), z)

    # --- bounce order: a downward → upward turn below the top interface --------------------
    turned = alive & down & up_new & (scatter | (b >= 1))
    bounces = st.bounces + turned.astype(jnp.int32)

    # --- exits -------------------------------------------------------------------------------
    out_top = alive & (region == 0) & up_new
    out_bottom = alive & (region == M + 1) & ~up_new
    leaving = out_top | out_bottom
    tallied = (out_top & cfg.reflection) | (out_bottom & cfg.transmission)
    if not cfg.delta:
        tallied = tallied & diffuse
    if cfg.max_bounces >= 0:
        tallied = tallied & (bounces <= cfg.max_bounces)
    exited = st.exited | tallied
    alive = alive & ~leaving

    # --- what can no longer reach an observed quantity ends here ---------------------------
    if cfg.max_bounces >= 0:
        alive = alive & (bounces <= cfg.max_bounces)
        if cfg.end_downward_after_last_bounce:
            alive = alive & ~((bounces == cfg.max_bounces) & ~up_new & (region >= 1))
    alive = alive & jnp.any(weight > 0, axis=1)
    events = st.events + alive.astype(jnp.int32)
    if cfg.russian_roulette:
        q = jnp.clip(jnp.max(weight, axis=1), RR_MIN_Q, 1.0)
        play = alive & (events > RR_START)
        survive = u[:, 7] < q
        alive = alive & (~play | survive)
        weight = jnp.where((play & survive)[:, None], weight / q[:, None], weight)
    new = st._replace(region=region, z=z, w=w, weight=weight, alive=alive, exited=exited,
                      bounces=bounces, vol_events=vol_events, events=events, diffuse=diffuse,
                      last_pdf=last_pdf)
    return new if pts is None else (new, nee)


# --------------------------------------------------------------------------------------------
# Point estimates: next-event connections (module text, "Point estimates")
# --------------------------------------------------------------------------------------------


class PointSide(NamedTuple):
    """One side's connection data for the requested directions (R of them)."""

    d: jax.Array  # (R, 3) propagation direction inside, just past the connecting event
    chain: jax.Array  # (R,) crossing factors of the specular boundaries to the outside
    sigma_t: jax.Array  # (regions, R, C) extinction along d per region
    depth: jax.Array  # (regions, R, C) optical depth of the regions between a region and the exit


def _extinction(cfg, arr, d):
    """σt (regions, R, C) of every region along directions d (R, 3) (:func:`_sigma_t_along`)."""
    regions = arr.thickness.shape[0]
    return _sigma_t_along(cfg, arr, jnp.arange(regions, dtype=jnp.int32),
                          jnp.broadcast_to(d[None], (regions,) + d.shape))


def _reverse_crossing(wo, eta):
    """The direction d inside a specular dielectric boundary that leaves along wo (unit, on the
    outside of the crossing) and the flux factor per solid angle of wo, (1 − F) η_ti² |wo_z| /
    |d_z| (η_ti = η_exit / η_inside): the reverse ray -wo refracted by Snell's law."""
    F, cos_t, _, eta_ti = fresnel_dielectric(wo[..., 2], eta)
    d = -jnp.stack([-wo[..., 0] * eta_ti, -wo[..., 1] * eta_ti, cos_t], axis=-1)
    factor = (1.0 - F) * eta_ti**2 * jnp.abs(wo[..., 2]) / jnp.where(cos_t == 0, 1.0,
                                                                       jnp.abs(cos_t))
    return normalize(d), jnp.where(cos_t == 0, 0.0, factor)


def _point_setup(cfg, arr, wo_all, n_up):
    """Per side, the connection data of its requested directions: the reflection side's are
    the first ``n_up`` rows of ``wo_all`` (wo_z > 0), the transmission side's the rest. A side
    without rows is left out; a side with rows but not simulated gets its row count (zeros)."""
    M = cfg.n_media
    out = {}
    for side, k, wo in (("up", cfg.point_up, wo_all[:n_up]), ("down", cfg.point_down,
                                                               wo_all[n_up:])):
        if wo.shape[0] == 0:
            continue
        if k is None:
            out[side] = wo.shape[0]
            continue
        observed = wo[:, 2] > 0 if side == "up" else wo[:, 2] < 0
        exit_b = 0 if side == "up" else M
        connect_at_exit = (k == exit_b) or cfg.boundary_groups[exit_b] == "pass"
        if connect_at_exit:
            d, chain = wo, jnp.ones(wo.shape[:1], wo.dtype)
        else:  # a specular dielectric between the connection and the outside
            d, chain = _reverse_crossing(wo, arr.eta[exit_b])
        chain = jnp.where(observed, chain, 0.0)
        sig = _extinction(cfg, arr, d)
        tau = sig * arr.thickness[:, None, None] / jnp.maximum(jnp.abs(d[:, 2]), 1e-30)[None, :, None]
        if side == "up":  # the regions above region r: 1 .. r-1
            depth = jnp.cumsum(tau, axis=0) - tau
        else:  # the regions below region r: r+1 .. M
            depth = jnp.flip(jnp.cumsum(jnp.flip(tau, 0), axis=0), 0) - tau
        out[side] = PointSide(d, chain, sig, depth)
    return out


def _boundary_f(cfg, arr, k, wi, d, with_pdf=False):
    """The BSDF (radiance convention, no cosine) of boundary k from wi (B, R, 3) to d (B, R, 3):
    (B, R, C); with ``with_pdf`` also the density (B, R) with which the walk samples d there.
    Boundary k is never specular (the connection boundary or a vertex next to it)."""
    C = cfg.channels
    g = cfg.boundary_groups[k]
    if g.startswith("rough:"):
        model, params = _rough(rough_dielectric, g[6:], arr.alpha[k], arr.alpha_y[k])
        params = {**params, "eta": arr.eta[k]}
        dist = g[6:].split(":")[0]
        f = model.eval(params, wi, d, distribution=dist)
        f = jnp.broadcast_to(f[..., None], f.shape + (C,))
        pdf = model.pdf(params, wi, d, distribution=dist) if with_pdf else None
    elif g == "lambertian":
        up = (wi[..., 2] > 0) & (d[..., 2] > 0)
        f = jnp.where(up[..., None], arr.albedo[k] / jnp.pi, 0.0)
        pdf = jnp.where(up, d[..., 2] / jnp.pi, 0.0) if with_pdf else None
    elif g.startswith("conductor:") and g != "conductor:smooth":
        model, params = _rough(rough_conductor, g[10:], arr.alpha[k], arr.alpha_y[k])
        dist = g[10:].split(":")[0]
        params = {**params, "n": arr.cond_n[k], "k": arr.cond_k[k]}
        f = model.eval(params, wi[..., None, :], d[..., None, :], distribution=dist)
        pdf = model.pdf(params, wi[..., None, :], d[..., None, :],
                        distribution=dist)[..., 0] if with_pdf else None
    else:  # pragma: no cover - the caller connects at non-specular boundaries only
        raise ValueError(f"boundary {k} ({g}) cannot take a next-event connection")
    return (f, pdf) if with_pdf else f


def _phase_p(cfg, arr, region, wi, d, kinds=None):
    """Phase function of each lane's region from wi (B, R, 3) to d (B, R, 3): (B, R); it is
    also the density with which the walk samples d (exact phase sampling). ``kinds``: the
    phase functions to consider (default: every one in the stack)."""
    p = jnp.zeros(wi.shape[:-1], wi.dtype)
    if kinds is None:
        kinds = {q for q in cfg.region_phase if q is not None}
    for kind in sorted(kinds):
        sel = functools.reduce(jnp.logical_or, [region == j for j, q in
                                               enumerate(cfg.region_phase) if q == kind])
        if kind == "hg":
            params = {"g": arr.hg_g[region][:, None]}
        elif kind == "sggx":
            params = {"S": arr.sggx_S[region][:, None]}
        else:
            params = {}
        p = jnp.where(sel[:, None], PHASE_FUNCTIONS[kind][0](params, wi, d), p)
    return p


def _flake_F(cfg, arr, region, wi, d):
    """(B, R, C) reflectance of each lane's region's flakes for the scattering wi → d:
    Schlick(f0, |h·wi|) with h the flake normal (wi + d normalized), the F(h) of SpongeCake
    eq. 5 (Table 2: f0 = 1, no Fresnel term); 1 outside SGGX media and without
    ``cfg.flake_fresnel``."""
    one = jnp.ones(wi.shape[:1] + d.shape[1:-1] + (cfg.channels,), wi.dtype)
    if not cfg.flake_fresnel:
        return one
    h = normalize(wi + d)
    c = jnp.abs(jnp.sum(wi * h, axis=-1))[..., None]
    return fresnel_schlick(c, arr.flake_f0[region][:, None, :])


def _sigma_t_along(cfg, arr, region, d):
    """σt (B, R, C) of each lane's region along directions d (B, R, 3): what attenuates an
    unscattered flight in the walk (σs when volume scattering or extinction-only is compiled,
    σa when absorption is), with the SGGX projected area σ(d)."""
    base = jnp.zeros_like(arr.sigma_a[region])
    if cfg.volume or cfg.extinction_only:
        base = base + arr.sigma_s_c[region]
    if cfg.absorption:
        base = base + arr.sigma_a[region]
    base = jnp.broadcast_to(base[:, None, :], d.shape[:-1] + base.shape[-1:])
    if "sggx" in cfg.region_phase:
        is_sggx = jnp.asarray([p == "sggx" for p in cfg.region_phase])[region]
        proj = jnp.where(is_sggx[:, None], sggx_sigma(arr.sggx_S[region][:, None], d), 1.0)
        base = base * proj[..., None]
    return base


def _connect(cfg, arr, pts, st, beta, z, scatter, hit, b, key, i):
    """This event's contributions (B, 4, R, C) to the per-path point estimates (the flux
    fraction per steradian leaving along each requested direction), by bounce-order class.

    Two strategies reach the connecting rough dielectric boundary k from the vertices right
    behind it (volume events in the region behind k, events at the boundary behind that region
    that send the path toward k), combined by the balance heuristic (Veach 1997, ch. 9):

    * crossing (C): the walk's own path reaches k and the BSDF of k is evaluated toward the
      requested direction; its density is that of the vertex's sampling, p_v(d');
    * vertex (V): at the vertex, d' is sampled from k's BSDF in reverse, from the requested
      direction's side (density q(d')), and the vertex's BSDF or phase function is evaluated;
      by the generalized reciprocity of the BTDF (Walter eq. 21), f_k(−d' → d) =
      (η_d / η_d')² f_k(d → −d'), so the sample's weight (eq. 41) gives the contribution.

    Weights q/(q + p_v) and p_v/(q + p_v) for the same (vertex, d'), so the sum stays
    unbiased; events farther away have only the crossing, events on the exit's side of k only
    the direct connection."""
    M = cfg.n_media
    B = st.w.shape[0]
    wi = -st.w[:, None, :]
    down = st.w[:, 2] < 0
    classes = jnp.arange(len(ORDER_CLASSES), dtype=jnp.int32)
    parts = []
    for side, ps in pts.items():
        if isinstance(ps, int):  # rows of a side that is not simulated
            parts.append(jnp.zeros((B, len(ORDER_CLASSES), ps, cfg.channels), beta.dtype))
            continue
        total = 0.0
        R = ps.d.shape[0]
        k = cfg.point_up if side == "up" else cfg.point_down
        wi_full, d = jnp.broadcast_arrays(wi, ps.d[None])
        inv_dz = 1.0 / jnp.maximum(jnp.abs(ps.d[:, 2]), 1e-30)
        if side == "up":
            vol = scatter & (st.region <= k)
            r_b, z_b = k, arr.thickness[min(k, M + 1)] if k <= M else 0.0
        else:
            vol = scatter & (st.region >= k + 1)
            r_b, z_b = k + 1, 0.0
        at_k = hit & (b == k) if 0 <= k <= M else jnp.zeros((B,), bool)
        value = jnp.zeros((B, R, cfg.channels), beta.dtype)
        # transmittance from boundary k to the outside along d (and the crossing factors)
        exit_od = ps.depth[r_b] + ps.sigma_t[r_b] * (
            (z_b if side == "up" else arr.thickness[r_b] - z_b) * inv_dz)[:, None]
        exit_t = jnp.exp(-exit_od) * ps.chain[:, None]  # (R, C)
        # the vertex strategy exists behind a rough dielectric k with a medium behind it
        behind = k + 1 if side == "up" else k
        v_ok = (0 <= k <= M and cfg.boundary_groups[k].startswith("rough:")
                and 1 <= behind <= M)
        if 0 <= k <= M:
            fb = _boundary_f(cfg, arr, k, wi_full, d) * jnp.abs(ps.d[:, 2])[None, :, None]
            if v_ok:
                # crossing strategy weight, for paths whose last event could have connected
                g = cfg.boundary_groups[k]
                model, params = _rough(rough_dielectric, g[6:], arr.alpha[k], arr.alpha_y[k])
                # q: the reverse sample's density of t = -w (the path's direction reversed)
                q = model.pdf({**params, "eta": arr.eta[k]}, d, wi_full,
                              distribution=g[6:].split(":")[0])
                p_last = st.last_pdf[:, None]
                w_c = jnp.where(p_last > 0, p_last / jnp.maximum(p_last + q, 1e-30), 1.0)
                crossing = at_k & (st.region == behind)
                fb = fb * jnp.where(crossing[:, None], w_c, 1.0)[..., None]
            value = jnp.where(at_k[:, None, None], fb * exit_t[None], value)
        exit_side = range(1, min(k, M) + 1) if side == "up" else range(max(k + 1, 1), M + 1)
        if cfg.volume and any(cfg.region_phase[j] is not None for j in exit_side):
            # direct connection of volume events on the exit's side of k
            r = st.region
            dist = z if side == "up" else arr.thickness[r] - z
            od = ps.depth[r] + ps.sigma_t[r] * (dist[:, None] * inv_dz[None, :])[..., None]
            pv = (_phase_p(cfg, arr, r, wi_full, d)[..., None] * _flake_F(cfg, arr, r, wi_full, d)
                  * jnp.exp(-od) * ps.chain[None, :, None])
            value = jnp.where(vol[:, None, None], pv, value)
        value = value * beta[:, None, :]
        value = jnp.where((at_k | vol)[:, None, None], value, 0.0)
        # bounce order of the connected path: a downward path sent upward below the top turns
        turn = down & (vol | (at_k & (k >= 1))) if side == "up" else jnp.zeros_like(down)
        orders = [(value, st.bounces + turn.astype(jnp.int32))]
        if v_ok:
            orders.append(_vertex_strategy(cfg, arr, ps, st, beta, z, scatter, hit, b, key, i,
                                           side, k, behind, wi_full, exit_t))
        for val, order in orders:
            if cfg.max_bounces >= 0:
                val = jnp.where((order <= cfg.max_bounces)[:, None, None], val, 0.0)
            onehot = (jnp.minimum(order, len(ORDER_CLASSES) - 1)[:, None] == classes[None, :])
            total = total + onehot.astype(val.dtype)[:, :, None, None] * val[:, None]
        parts.append(total)
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=2)


def _vertex_strategy(cfg, arr, ps, st, beta, z, scatter, hit, b, key, i, side, k, behind,
                     wi_full, exit_t):
    """The vertex strategy of :func:`_connect` (contributions (B, R, C) and their orders):
    events in region ``behind`` (volume) or at the boundary on its far side, connected through
    the rough dielectric k by a reverse sample of k's BSDF."""
    M = cfg.n_media
    B, R = wi_full.shape[:2]
    dt = wi_full.dtype
    g = cfg.boundary_groups[k]
    model, params = _rough(rough_dielectric, g[6:], arr.alpha[k], arr.alpha_y[k])
    params = {**params, "eta": arr.eta[k]}
    dist_name = g[6:].split(":")[0]
    far = behind if side == "up" else behind - 1  # region r lies between boundaries r-1 and r
    down = st.w[:, 2] < 0
    # reverse sample of k from the requested direction's side: t into region `behind`
    u = uniforms((key[0] ^ jnp.uint32(0x5BD1E995), key[1]), i, B, 3 * R, dt).reshape(B, R, 3)
    d_k = jnp.broadcast_to(ps.d[None], (B, R, 3))
    t, weight, q = model.sample(params, d_k, u, distribution=dist_name)
    into = t[..., 2] < 0 if side == "up" else t[..., 2] > 0
    dp = -t  # the path's direction from the vertex toward k
    dz = jnp.maximum(jnp.abs(dp[..., 2]), 1e-30)
    eta2 = arr.eta[k] ** 2
    ratio = 1.0 / eta2 if side == "up" else eta2  # (η on d's side / η on d′'s side)²
    w_rev = jnp.where(into, ratio * weight * jnp.abs(ps.d[:, 2])[None, :] / dz, 0.0)
    # the vertices: volume events in `behind`, events at `far` sending the path toward k
    vol = scatter & (st.region == behind) if cfg.volume and cfg.region_phase[behind] is not None \
        else jnp.zeros((B,), bool)
    far_ok = 0 <= far <= M and cfg.boundary_groups[far] not in ("pass", "smooth",
                                                                 "conductor:smooth")
    at_far = hit & (b == far) if far_ok else jnp.zeros((B,), bool)
    f_v = jnp.zeros((B, R, cfg.channels), dt)
    p_v = jnp.zeros((B, R), dt)
    if far_ok:
        fb, pb = _boundary_f(cfg, arr, far, wi_full, dp, with_pdf=True)
        f_v = jnp.where(at_far[:, None, None], fb * dz[..., None], f_v)
        p_v = jnp.where(at_far[:, None], pb, p_v)
    if cfg.volume and cfg.region_phase[behind] is not None:
        ph = _phase_p(cfg, arr, st.region, wi_full, dp, kinds={cfg.region_phase[behind]})
        f_v = jnp.where(vol[:, None, None],
                        ph[..., None] * _flake_F(cfg, arr, st.region, wi_full, dp), f_v)
        p_v = jnp.where(vol[:, None], ph, p_v)
    # attenuation across `behind` from the vertex to k
    length = jnp.where(at_far, arr.thickness[behind],
                       z if side == "up" else arr.thickness[behind] - z)
    sig = _sigma_t_along(cfg, arr, jnp.full((B,), behind, jnp.int32), dp)
    att = jnp.exp(-sig * (length[:, None] / dz)[..., None])
    w_v = q / jnp.maximum(q + p_v, 1e-30)
    val = (beta[:, None, :] * f_v * att * (w_rev * w_v)[..., None] * exit_t[None])
    val = jnp.where(((vol | at_far)[:, None] & into)[..., None], val, 0.0)
    val = jnp.where(jnp.isfinite(val), val, 0.0)
    turn = down & (vol | at_far) if side == "up" else jnp.zeros_like(down)
    return val, st.bounces + turn.astype(jnp.int32)


def _bin_index(cfg, w):
    """Hemisphere bin of exit directions w: side (0 = reflection, 1 = transmission), θ bin
    over [0°, 90°] from the side's pole, φ bin over [0°, 360°)."""
    side = (w[:, 2] < 0).astype(jnp.int32)
    ct = jnp.clip(jnp.abs(w[:, 2]), 0.0, 1.0)
    st = jnp.sqrt(w[:, 0] ** 2 + w[:, 1] ** 2)
    theta = jnp.arctan2(st, ct)
    tb = jnp.clip((theta / (0.5 * jnp.pi) * cfg.theta_bins).astype(jnp.int32), 0, cfg.theta_bins - 1)
    phi = jnp.mod(jnp.arctan2(w[:, 1], w[:, 0]), 2.0 * jnp.pi)
    pb = jnp.clip((phi / (2.0 * jnp.pi) * cfg.phi_bins).astype(jnp.int32), 0, cfg.phi_bins - 1)
    return (side * cfg.theta_bins + tb) * cfg.phi_bins + pb


def _tally(cfg, det, w, x, order, n_out):
    """Float64 sums and sums of squares of path contributions x (P, C) (0 for paths that did
    not exit into an observed bin) per order class and bin (4, n_out, C), and per exit side
    (2 moments, 2 sides, C); w (P, 3) exit directions, order (P,) bounce classes."""
    C = cfg.channels
    order = jnp.minimum(order, len(ORDER_CLASSES) - 1)
    if cfg.detector == "points":  # the point estimates are tallied in the walk
        s1 = s2 = None
    elif cfg.detector == "bins":
        seg = order * n_out + _bin_index(cfg, w)
        n_seg = len(ORDER_CLASSES) * n_out
        s1 = jax.ops.segment_sum(x, seg, num_segments=n_seg).reshape(-1, n_out, C)
        s2 = jax.ops.segment_sum(x * x, seg, num_segments=n_seg).reshape(-1, n_out, C)
    else:
        # cones may overlap: a (paths × cones) membership matrix, built in chunks of paths so
        # that memory stays bounded (4096 × cones at a time)
        classes = jnp.arange(len(ORDER_CLASSES), dtype=jnp.int32)
        chunk = math.gcd(w.shape[0], 4096)

        def part(carry, blk):
            wb, xb, ob = blk
            oh = (ob[:, None] == classes[None, :]).astype(jnp.float64)
            inside = ((wb.astype(jnp.float64) @ det.cone_dir.T) >= det.cone_cos[None, :])
            inside = inside.astype(jnp.float64)
            return (carry[0] + jnp.einsum("bo,br,bc->orc", oh, inside, xb),
                    carry[1] + jnp.einsum("bo,br,bc->orc", oh, inside, xb * xb)), None

        zero = jnp.zeros((len(ORDER_CLASSES), det.cone_dir.shape[0], C), jnp.float64)
        blocks = (w.reshape(-1, chunk, 3), x.reshape(-1, chunk, C), order.reshape(-1, chunk))
        (s1, s2), _ = jax.lax.scan(part, (zero, zero), blocks)
    down = (w[:, 2] < 0)[:, None]
    xs = jnp.stack([jnp.where(down, 0.0, x), jnp.where(down, x, 0.0)])
    side = jnp.stack([jnp.sum(xs, axis=1), jnp.sum(xs * xs, axis=1)])
    return s1, s2, side


def _first_reflection(cfg, arr, det, key, wi, n_valid, paths, n_out):
    """Splitting at the first interface: the reflected branch of each path's first crossing of
    the top boundary, weight F (rough: F(i·m) times Walter's eq. 41 weight), sampled with its
    own random numbers (independent of the walk, whose first crossing is forced to refract
    with weight 1 − F) and tallied as bounce order 0: (n_out, C) sums and sums of squares per
    bin and the (2, 2, C) flux per side, as :func:`_tally`."""
    dt = wi.dtype
    st = _fresh(cfg, wi, paths, dt)
    u = uniforms((key[0] ^ jnp.uint32(0x27D4EB2F), key[1] ^ jnp.uint32(0x165667B1)),
                 jnp.int32(0), paths, 3, dt)
    b = jnp.zeros((paths,), jnp.int32)
    w, f, diffuse, _ = _boundary_event(cfg, arr, st, b, u, jnp.full((paths,), REFLECT))
    keep = (jnp.arange(paths) < n_valid) & (w[:, 2] > 0)
    if not cfg.delta:
        keep = keep & diffuse
    x = jnp.where(keep[:, None], f, 0.0).astype(jnp.float64)
    s1, s2, side = _tally(cfg, det, w, x, jnp.zeros((paths,), jnp.int32), n_out)
    return s1[0], s2[0], side


def _fresh(cfg, wi, n, dt):
    """State of n new paths at the top of the stack, travelling along -wi."""
    return State(
        region=jnp.zeros((n,), jnp.int32), z=jnp.zeros((n,), dt),
        w=jnp.broadcast_to(-wi, (n, 3)), weight=jnp.ones((n, cfg.channels), dt),
        alive=jnp.ones((n,), bool), exited=jnp.zeros((n,), bool),
        bounces=jnp.zeros((n,), jnp.int32), vol_events=jnp.zeros((n,), jnp.int32),
        events=jnp.zeros((n,), jnp.int32), diffuse=jnp.zeros((n,), bool),
        prop_wv=jnp.zeros((n, 3), dt), prop_wb=jnp.zeros((n, 3), dt),
        prop_fb=jnp.zeros((n, cfg.channels), dt), prop_db=jnp.zeros((n,), bool),
        prop_pv=jnp.zeros((n,), dt), prop_pb=jnp.zeros((n,), dt), last_pdf=jnp.zeros((n,), dt))


class _Loop(NamedTuple):
    i: jax.Array  # iteration
    st: State
    path: jax.Array  # (lanes,) id of the path each lane traces
    next_path: jax.Array  # next path id to start
    exit_w: jax.Array  # (paths, 3) exit direction of each path
    exit_x: jax.Array  # (paths, C) tallied weight (0: not tallied)
    exit_order: jax.Array  # (paths,)
    events: jax.Array
    truncated: jax.Array
    # point estimates (zero-size when the detector has none): per lane, the running sum of its
    # path's connections (lanes, 4, R, C), and the float64 sums over finished paths of those
    # sums (4, R, C) and of their squares, per order and (last) of the all-order sum (5, R, C)
    point_acc: jax.Array
    point_s1: jax.Array
    point_s2: jax.Array


@functools.partial(jax.jit, static_argnames=("cfg", "lanes", "paths", "n_out", "n_up"))
def run_batch(cfg: WalkConfig, arr: WalkArrays, det: Detector, key, wi, n_valid, *, lanes: int,
              paths: int, n_out: int, n_up: int = 0):
    """Trace ``paths`` paths (the first ``n_valid`` count) lit from direction ``wi`` (unit, z > 0,
    pointing toward the light) on ``lanes`` parallel lanes. Returns float64 (4, n_out, C) sums
    of the path contributions per order class and bin, (5, n_out, C) sums of their squares per
    order class and (last) of the squares of each path's all-order total, the (2, 2, C) sums
    and sums of squares of the flux leaving per side (up, down), the number of paths dropped
    after ``cfg.max_events`` events, the total number of events, and with
    ``cfg.split_first`` the first crossings' reflected branches (:func:`_first_reflection`:
    independent of the rest, so the caller adds their variances), else None.

    Path regeneration: a lane whose path ends starts the next path at once, so every lane stays
    busy until the last paths drain (one compiled loop, no idle tail per path). Each path exits
    at most once: its exit direction, weight and order go to per-path buffers, tallied after the
    loop. Point detectors: the walk's rows are the reflection rows first, ``n_up`` of them."""
    dt = jnp.dtype(cfg.dtype)
    C = cfg.channels
    wi = wi.astype(dt)
    key = jax.random.bits(key, (2,), jnp.uint32)  # the walk's two seed words
    n_valid = jnp.minimum(n_valid, paths)
    lane = jnp.arange(lanes, dtype=jnp.int32)
    points = cfg.detector == "points"
    pts = _point_setup(cfg, arr, det.cone_dir.astype(dt), n_up) if points else None
    n_pts = n_out if points else 0
    st0 = _fresh(cfg, wi, lanes, dt)
    st0 = _propose(cfg, arr, key, jnp.int32(0), st0._replace(alive=lane < n_valid))
    classes = len(ORDER_CLASSES)
    carry = _Loop(jnp.int32(0), st0, lane, jnp.minimum(jnp.int32(lanes), n_valid),
                  jnp.zeros((paths, 3), dt), jnp.zeros((paths, C), dt),
                  jnp.zeros((paths,), jnp.int32), jnp.int32(0), jnp.int32(0),
                  jnp.zeros((lanes if points else 0, classes, n_pts, C), dt),
                  jnp.zeros((classes, n_pts, C), jnp.float64),
                  jnp.zeros((classes + 1, n_pts, C), jnp.float64))
    fresh = _fresh(cfg, wi, lanes, dt)

    def cond(c):
        return jnp.any(c.st.alive)

    def body(c):
        was_alive = c.st.alive
        if points:
            st, nee = _step(cfg, arr, key, c.i, c.st, pts)
            acc = c.point_acc + nee
        else:
            st = _step(cfg, arr, key, c.i, c.st)
        # record the paths that exited into an observed bin in this event
        new_exit = st.exited & was_alive
        target = jnp.where(new_exit, c.path, paths)  # out of range: dropped
        exit_w = c.exit_w.at[target].set(st.w, mode="drop")
        exit_x = c.exit_x.at[target].set(st.weight, mode="drop")
        exit_order = c.exit_order.at[target].set(st.bounces, mode="drop")
        # paths at the event cap are dropped (counted)
        capped = st.alive & (st.events >= cfg.max_events)
        alive = st.alive & ~capped
        # lanes whose path ended take the next paths in order
        ended = ~alive
        s1p, s2p = c.point_s1, c.point_s2
        if points:
            # a finished path's sums go to the totals (a truncated path's are dropped, as its
            # exit would be); the lane starts its next path from zero
            done = (ended & ~capped).astype(jnp.float64)
            flat = acc.reshape(lanes, -1).astype(jnp.float64)
            s1p = s1p + (done @ flat).reshape(s1p.shape)
            tot = acc.sum(axis=1).astype(jnp.float64)  # the path's estimate, all orders
            sq = jnp.concatenate([flat * flat, (tot * tot).reshape(lanes, -1)], axis=1)
            s2p = s2p + (done @ sq).reshape(s2p.shape)
            acc = jnp.where(ended[:, None, None, None], 0.0, acc)
        else:
            acc = c.point_acc
        rank = jnp.cumsum(ended, dtype=jnp.int32) - 1
        new_id = c.next_path + rank
        start = ended & (new_id < n_valid)
        st = jax.tree_util.tree_map(
            lambda f, s: jnp.where(start.reshape((-1,) + (1,) * (s.ndim - 1)), f, s),
            fresh, st._replace(alive=alive, exited=jnp.zeros_like(alive)))
        st = _propose(cfg, arr, key, c.i + 1, st)
        path = jnp.where(start, new_id, c.path)
        next_path = jnp.minimum(c.next_path + jnp.sum(ended, dtype=jnp.int32), n_valid)
        return _Loop(c.i + 1, st, path, next_path, exit_w, exit_x, exit_order,
                     c.events + jnp.sum(was_alive, dtype=jnp.int32),
                     c.truncated + jnp.sum(capped, dtype=jnp.int32), acc, s1p, s2p)

    c = jax.lax.while_loop(cond, body, carry)
    s1, s2, side = _tally(cfg, det, c.exit_w, c.exit_x.astype(jnp.float64), c.exit_order, n_out)
    if points:
        s1, s2 = c.point_s1, c.point_s2
    else:  # each path exits in one order class: its total's square is its order's
        s2 = jnp.concatenate([s2, s2.sum(axis=0, keepdims=True)])
    split = None
    if cfg.split_first:
        split = _first_reflection(cfg, arr, det, key, wi, n_valid, paths, n_out)
    return s1, s2, side, c.truncated, c.events, split
