"""The random walk through a layer stack, in Dr.Jit: one megakernel per stack structure.

Every path is one lane of a symbolic ``dr.while_loop`` (one scattering event per iteration)
that runs on Dr.Jit's LLVM backend (all CPU cores) or its CUDA backend (engine.py), calling the
stack's boundaries and phase functions (components.py: Mitsuba 3's own plugins where Mitsuba
has them). The loop writes each path's exit — its flux weight per channel and its tally key
(bin or cone, bounce order, side) — or, for point estimates, its running sums of next-event
connections, into per-path slots; these are summed in float64 per block of paths in path order
(:func:`tally_exits`: on the host, or on the device with one thread per block), so the same
seed gives the same bytes whatever the thread count (no unordered floating-point atomics).
Between its kernels the walk parks Dr.Jit's thread pool (:class:`_Cores`).

Geometry (scene.py): regions 0..M+1 (0 = outside, M+1 = below), boundary b between regions b
and b+1. A path has a region, a depth ``z`` below the region's top, a propagation direction
``w`` and a weight per channel. Each iteration: a path in a medium flies (free-flight sampling
by σs when volume scattering is compiled, Beer–Lambert weights for absorption); it either
scatters in the volume (the phase function sampled exactly) or meets a boundary, whose BSDF is
sampled (flux transport: the weight is the fraction of flux carried). Paths that leave into
region 0 upward or region M+1 downward exit.

Point estimates (``detector = "points"``): next-event estimation toward exact outgoing
directions d_o, in the manner of position-free Monte Carlo (Guo, Hašan, Zhao 2018). Every path
that leaves along d_o has a last non-specular event; after it only specular boundaries (or none)
lie between the path and the outside, so the direction it must take there is fixed by d_o:
reverse refraction through the specular exit boundary gives the direction d inside and the flux
factor (1 − F) (η_exit/η_inside)² |cos θo| / |cos θd| of the crossing (:func:`point_sides`). At
each event that can be that last event — the first rough boundary k from the outside and volume
scattering between it and the outside — the walk adds β · f_event(−w, d)|cos θd| (a boundary's
BSDF, radiance convention) or β · p(−w, d) (a phase function) times the transmittance along d
to the outside and the crossing factors: the flux fraction per steradian leaving along d_o,
whose expectation is f(wi, d_o)|cos θo|. The events right behind a rough dielectric k reach k
two ways, the walk's own crossing of k (its BTDF evaluated toward d) and a connection from the
vertex through a reverse sample of k's BSDF; the two are combined with the balance heuristic
(Veach 1997, ch. 9), as :func:`_connect` says. Stacks where a specular boundary could send
light back toward the outside between k and the exit are refused (detectors.point_connections).
Where a side mixes strategies, the walk only records each path's connecting events and a second
kernel evaluates them, one lane per (path, requested direction), one strategy at a time
(:meth:`_Walk.nee_from_records`), so that a SIMD packet's lanes run the same code.

Bounce order: the number of turns from downward to upward travel below the top interface (the
extended-NDF paper's eq. 25 terms: 0 = surface reflection, 1 = one-bounce subsurface
reflection); tallied in four classes 0, 1, 2, ≥3.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.simulate import components as comp
from fitlab.simulate.protocol import FORCE_CHOOSE, FORCE_REFLECT, FORCE_REFRACT, LAUNCH_PATHS

#: How a lane reaches its boundary's sampling: "mask" (every boundary's code on every lane,
#: masked) or "switch" (Dr.Jit's dr.switch: an indirect call per boundary).
DISPATCH = "switch"
#: Bounce-order classes tallied separately: 0, 1, 2, ≥ 3.
ORDER_CLASSES = ("order0", "order1", "order2", "rest")
#: Russian roulette starts after this many events of a path.
RR_START = 3
#: Smallest survival probability of Russian roulette.
RR_MIN_Q = 0.05
#: Memory of the per-path point-estimate sums (and next-event records) of one launch (bytes).
POINT_LAUNCH_BYTES = 64 << 20
#: Paths whose contributions the host sums together before adding the sum to the totals, in
#: path order; launches are whole multiples of it, so the float64 totals do not depend on the
#: launch size.
TALLY_BLOCK = 4096
#: Connecting events kept per path for the next-event kernel of point estimates (events past
#: them connect in the walk's kernel; 0: every event connects there).
RECORDS_PER_PATH = 16


class WalkConfig(NamedTuple):
    """Static description of the walk: what is compiled (one kernel per distinct config)."""

    n_media: int
    boundaries: tuple  # components.BoundarySpec per boundary 0..M
    region_phase: tuple  # per region 0..M+1: None or a key of components.PHASES
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
    # points: the boundary where the reflection side connects (first rough one from the top;
    # n_media + 1: volume events only) and the transmission side (last rough one; -1: volume
    # only); None: that side has no requested direction
    point_up: int | None = None
    point_down: int | None = None
    # branch forcing (effects.EffectPlan.force_top / force_bottom)
    force_top: bool = False
    force_bottom: bool = False
    # splitting at the first interface (effects.EffectPlan.split_first): the walk's first
    # crossing refracts (weight 1 − F); the reflected branch is tallied apart
    split_first: bool = False
    # SGGX flakes with a Schlick reflectance f0 < 1 somewhere (WalkArrays.flake_f0)
    flake_fresnel: bool = False


class WalkArrays(NamedTuple):
    """Per-region and per-boundary values (NumPy; kernel inputs, never compiled constants)."""

    thickness: np.ndarray  # (R,)
    sigma_a: np.ndarray  # (R, 3)
    sigma_s: np.ndarray  # (R,) scattering coefficient used for free flights
    sigma_s_c: np.ndarray  # (R, 3) σs per channel (extinction-only attenuation)
    phase_values: tuple  # per region: the phase builder's values ({"g": ...}, {"S": ...}) or None
    sggx_S: np.ndarray  # (R, 3, 3) (identity where no SGGX medium)
    boundary_values: tuple  # components.BoundaryValues per boundary
    eta: np.ndarray  # (Bd,) n_below / n_above
    flake_f0: np.ndarray  # (R, 3) Schlick reflectance of SGGX flakes (1: none)


class Detector(NamedTuple):
    """Per-incidence detector arrays: cones (R, 3) directions and cos of the half angle (R,);
    points: the requested directions (R, 3), reflection rows first (cone_cos unused); bins:
    unused."""

    cone_dir: np.ndarray
    cone_cos: np.ndarray


class _Event(NamedTuple):
    """One event of a path as the next-event connections read it (Dr.Jit values): the
    direction travelled into it, the flux weight (Float in a one-channel walk, else Spectrum),
    depth, the density of the path's last non-specular sampling, region, boundary met (when
    ``hit``), volume scattering (``scatter``) and the bounce order so far."""

    w: object
    beta: object
    z: object
    last_pdf: object
    region: object
    b: object
    scatter: object
    hit: object
    bounces: object


class _Records:
    """One launch's connecting events, :data:`RECORDS_PER_PATH` slots a path (slot = path × E +
    event number), and per side and strategy each path's list of its events' numbers, in event
    order, with their count (written when the path ends)."""

    def __init__(self, walk, n_pad: int, channels: int):
        import drjit as dr
        import mitsuba as mi

        E = self.E = RECORDS_PER_PATH
        size = n_pad * E
        self.channels = channels
        self.w = [dr.empty(mi.Float, size) for _ in range(3)]
        self.beta = [dr.empty(mi.Float, size) for _ in range(channels)]
        self.z, self.last_pdf = dr.empty(mi.Float, size), dr.empty(mi.Float, size)
        self.region, self.b = dr.empty(mi.Int32, size), dr.empty(mi.Int32, size)
        self.flags, self.bounces = dr.empty(mi.UInt32, size), dr.empty(mi.Int32, size)
        keys = [(side, s) for side in walk.rows for s in walk.strategies(side)]
        self.lists = {key: dr.empty(mi.UInt32, size) for key in keys}
        self.counts = {key: dr.zeros(mi.UInt32, n_pad) for key in keys}  # padding paths: 0

    def arrays(self):
        return (self.w, self.beta, self.z, self.last_pdf, self.region, self.b, self.flags,
                self.bounces, list(self.lists.values()), list(self.counts.values()))

    def write(self, slot, ev: _Event, active):
        import drjit as dr

        for c in range(3):
            dr.scatter(self.w[c], ev.w[c], slot, active)
        for c in range(self.channels):
            dr.scatter(self.beta[c], ev.beta if self.channels == 1 else ev.beta[c], slot,
                       active)
        flags = dr.select(ev.scatter, 1, 0) | dr.select(ev.hit, 2, 0)
        for arr, v in ((self.z, ev.z), (self.last_pdf, ev.last_pdf), (self.region, ev.region),
                       (self.b, ev.b), (self.flags, flags), (self.bounces, ev.bounces)):
            dr.scatter(arr, type(arr)(v), slot, active)

    def read(self, slot) -> _Event:
        import drjit as dr
        import mitsuba as mi

        g = dr.gather
        beta = [g(mi.Float, x, slot) for x in self.beta]
        flags = g(mi.UInt32, self.flags, slot)
        return _Event(mi.Vector3f(*[g(mi.Float, x, slot) for x in self.w]),
                      beta[0] if self.channels == 1 else mi.Spectrum(*beta),
                      g(mi.Float, self.z, slot), g(mi.Float, self.last_pdf, slot),
                      g(mi.Int32, self.region, slot), g(mi.Int32, self.b, slot),
                      (flags & 1) != 0, (flags & 2) != 0, g(mi.Int32, self.bounces, slot))


class Exits(NamedTuple):
    """Per path, what the host tally needs and no more. Hemisphere bins: the tallied flux
    weight (P, C) (0: not tallied) and ``key``, its tally slot computed on the device
    (:func:`_tally_key`: (block of :data:`TALLY_BLOCK` paths × order class) × bin). Other
    detectors: ``side``, the sums per block, moment and exit side, taken on the device
    (:func:`_device_sides`), and for cones found in the kernel the (path, cone) pairs
    (``cones``, by candidate column then path) with their paths' weights (``pair_x``) and keys
    (``pair_key``: (block × order class) × 2 + 1 for a downward exit); where the host finds
    the cones (wide cone tables), also the weights, keys and exit directions of every path."""

    x: np.ndarray | None
    key: np.ndarray | None
    w: np.ndarray | None = None
    cones: tuple | None = None
    side: np.ndarray | None = None
    pair_x: np.ndarray | None = None
    pair_key: np.ndarray | None = None


# --------------------------------------------------------------------------------------------
# The stack on the device: components and region arrays as kernel inputs
# --------------------------------------------------------------------------------------------


class Stack:
    """The compiled walk's inputs: boundary and phase objects, region arrays (opaque)."""

    def __init__(self, cfg: WalkConfig, arr: WalkArrays):
        import drjit as dr
        import mitsuba as mi

        self.cfg = cfg
        self.arr = arr
        # where any branch is forced, every boundary takes the forcing code (the walk forces
        # only the top or bottom one; elsewhere the code folds away for FORCE_CHOOSE): the
        # boundaries of one kind then trace to one function, which dr.switch calls once per
        # packet, not once per distinct body (measured: a forced top alone added 392 operations
        # and 30% to every event)
        forced = cfg.force_top or cfg.force_bottom or cfg.split_first
        self.boundary = [comp.make_boundary(s, v, forced)
                         for s, v in zip(cfg.boundaries, arr.boundary_values)]
        self.phase = [None if p is None else comp.PHASES[p](v)
                      for p, v in zip(cfg.region_phase, arr.phase_values)]
        F = _device_floats
        self.thickness = F(arr.thickness)
        self.sigma_a = F(arr.sigma_a)
        self.sigma_s = F(arr.sigma_s)
        self.sigma_s_c = F(arr.sigma_s_c)
        self.flake_f0 = F(arr.flake_f0)
        self.eta = [dr.opaque(mi.Float, float(e)) for e in arr.eta]

    def region_f(self, table, region, active=True):
        import drjit as dr
        import mitsuba as mi

        return dr.gather(mi.Float, table, mi.UInt32(region), active)

    def region_c(self, table, region, active=True):
        """Per lane, the region's value per channel (:func:`_gather_channels`)."""
        return _gather_channels(table, region, self.cfg.channels, active)

    def projected_area(self, region, w, active):
        """σ(w) of the SGGX medium of each lane's region (SpongeCake eq. 3/7), else 1."""
        import drjit as dr
        import mitsuba as mi

        proj = mi.Float(1.0)
        for j, ph in enumerate(self.phase):
            if self.cfg.region_phase[j] == "sggx":
                proj = dr.select(region == j, ph.projected_area(w, active), proj)
        return proj

    def sigma_t_along(self, region, w, active):
        """σt per channel of each lane's region along w: what attenuates an unscattered flight
        (σs when volume scattering or extinction-only is compiled, σa when absorption is),
        with the SGGX projected area σ(w)."""
        import mitsuba as mi

        cfg = self.cfg
        base = mi.Spectrum(0.0)
        if cfg.volume or cfg.extinction_only:
            base = base + self.region_c(self.sigma_s_c, region, active)
        if cfg.absorption:
            base = base + self.region_c(self.sigma_a, region, active)
        return base * self.projected_area(region, w, active)

    def boundary_sample(self, b, wi, s1, s2, force, active, need_pdf):
        """Sample the boundary b of each lane: (wo, weight, pdf, nonspecular)."""
        import drjit as dr
        import mitsuba as mi

        used = [(j, bd) for j, bd in enumerate(self.boundary) if bd is not None]
        if DISPATCH == "switch" and len(used) > 1:
            def target(bd):
                def f(wi, s1, s2, force, active):
                    wo, w, p = bd.sample(wi, s1, s2, force, active, need_pdf)
                    return wo, mi.Spectrum(w), mi.Float(p), mi.Bool(bd.nonspecular)
                return f

            index = mi.UInt32(0)
            sel = mi.Bool(False)
            for k, (j, _) in enumerate(used):
                index = dr.select(b == j, k, index)
                sel = sel | (b == j)
            sel = sel & active  # lanes at a "pass" boundary call nothing
            wo, weight, pdf, nonspec = dr.switch(index, [target(bd) for _, bd in used],
                                                 wi, s1, s2, force, sel)
            return (dr.select(sel, wo, -wi), dr.select(sel, weight, 1.0),
                    dr.select(sel, pdf, 0.0), nonspec & sel)
        wo = -wi
        weight = mi.Spectrum(1.0)
        pdf = mi.Float(0.0)
        nonspec = mi.Bool(False)
        for j, bd in used:
            sel = active & (b == j)
            w_j, f_j, p_j = bd.sample(wi, s1, s2, force, sel, need_pdf)
            wo = dr.select(sel, w_j, wo)
            weight = dr.select(sel, f_j, weight)
            pdf = dr.select(sel, p_j, pdf)
            nonspec = nonspec | (sel & bd.nonspecular)
        return wo, weight, pdf, nonspec

    def phase_sample(self, region, wi, s1, s2, active):
        import drjit as dr
        import mitsuba as mi

        wo = -wi
        pdf = mi.Float(0.0)
        for j, ph in enumerate(self.phase):
            if ph is None:
                continue
            sel = active & (region == j)
            w_j, _, p_j = ph.sample(wi, s1, s2, sel)
            wo = dr.select(sel, w_j, wo)
            pdf = dr.select(sel, p_j, pdf)
        return wo, pdf

    def phase_eval(self, region, wi, wo, active, regions=None):
        import drjit as dr
        import mitsuba as mi

        p = mi.Float(0.0)
        for j, ph in enumerate(self.phase):
            if ph is None or (regions is not None and j not in regions):
                continue
            sel = active & (region == j)
            p = dr.select(sel, ph.eval(wi, wo, sel), p)
        return p

    def flake_F(self, region, wi, wo, active):
        """Schlick(f0, |h·wi|) of each lane's region's flakes for the scattering wi → wo, h the
        flake normal (wi + wo normalised): F(h) of SpongeCake eq. 5 (Table 2: f0 = 1, no
        Fresnel term); 1 without ``cfg.flake_fresnel``."""
        import drjit as dr
        import mitsuba as mi

        if not self.cfg.flake_fresnel:
            return mi.Spectrum(1.0)
        h = dr.normalize(wi + wo)
        c = dr.abs(dr.dot(wi, h))
        f0 = self.region_c(self.flake_f0, region, active)
        return f0 + (1.0 - f0) * dr.power(1.0 - dr.clip(c, 0.0, 1.0), 5.0)


# --------------------------------------------------------------------------------------------
# Point estimates: the requested directions' connection data (host side, per incidence)
# --------------------------------------------------------------------------------------------


def _fresnel_np(cos_i, eta):
    """Walter eq. 22 with the refracted cosine, for a boundary of relative index eta = n_below /
    n_above met from the side of cos_i's sign (NumPy): (F, cos_t, eta_ti)."""
    cos_i = np.asarray(cos_i, dtype=float)
    e = np.where(cos_i >= 0, eta, 1.0 / eta)  # η_t / η_i
    c = np.abs(cos_i)
    cos_t2 = 1.0 - (1.0 - c * c) / (e * e)
    tir = cos_t2 <= 0
    ct = np.sqrt(np.maximum(cos_t2, 0.0))
    rs = (c - e * ct) / np.maximum(c + e * ct, 1e-300)
    rp = (e * c - ct) / np.maximum(e * c + ct, 1e-300)
    F = np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))
    cos_t = np.where(tir, 0.0, -np.sign(np.where(cos_i == 0, 1.0, cos_i)) * ct)
    return F, cos_t, 1.0 / e


class PointSide(NamedTuple):
    """One side's connection data for its requested directions (R of them)."""

    d: np.ndarray  # (R, 3) propagation direction inside, just past the connecting event
    chain: np.ndarray  # (R,) crossing factors of the specular boundaries to the outside
    sigma_t: np.ndarray  # (regions, R, 3) extinction along d per region
    depth: np.ndarray  # (regions, R, 3) optical depth of the regions between a region and the exit
    exit_t: np.ndarray  # (R, 3) transmittance from the connecting boundary k to the outside


def _sigma_t_np(cfg, arr, d):
    regions = arr.thickness.shape[0]
    base = np.zeros((regions, 3))
    if cfg.volume or cfg.extinction_only:
        base = base + arr.sigma_s_c
    if cfg.absorption:
        base = base + arr.sigma_a
    proj = np.ones((regions, d.shape[0]))
    for r, p in enumerate(cfg.region_phase):
        if p == "sggx":
            proj[r] = np.sqrt(np.maximum(np.einsum("ri,ij,rj->r", d, arr.sggx_S[r], d), 0.0))
    return base[:, None, :] * proj[..., None]


def point_sides(cfg: WalkConfig, arr: WalkArrays, wo_all: np.ndarray, n_up: int) -> dict:
    """Per side ("up", "down"), the connection data of its requested directions: the reflection
    side's are the first ``n_up`` rows of ``wo_all``, the transmission side's the rest. A side
    without rows is left out; a side with rows but not simulated maps to its row count."""
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
        if k == exit_b or cfg.boundaries[exit_b].kind == "pass":
            d, chain = wo.copy(), np.ones(wo.shape[0])
        else:  # a specular dielectric between the connection and the outside: -wo refracted
            F, cos_t, eta_ti = _fresnel_np(wo[:, 2], arr.eta[exit_b])
            d = -np.stack([-wo[:, 0] * eta_ti, -wo[:, 1] * eta_ti, cos_t], axis=-1)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            chain = np.where(cos_t == 0, 0.0, (1.0 - F) * eta_ti**2 * np.abs(wo[:, 2])
                             / np.where(cos_t == 0, 1.0, np.abs(cos_t)))
        chain = np.where(observed, chain, 0.0)
        sig = _sigma_t_np(cfg, arr, d)
        tau = sig * arr.thickness[:, None, None] / np.maximum(np.abs(d[:, 2]), 1e-30)[None, :, None]
        if side == "up":  # the regions above region r: 1 .. r-1
            depth = np.cumsum(tau, axis=0) - tau
            r_b, z_b = k, (arr.thickness[min(k, M + 1)] if k <= M else 0.0)
        else:  # the regions below region r: r+1 .. M
            depth = np.flip(np.cumsum(np.flip(tau, 0), axis=0), 0) - tau
            r_b, z_b = k + 1, 0.0
        length = z_b if side == "up" else arr.thickness[r_b] - z_b
        exit_od = depth[r_b] + sig[r_b] * (length / np.maximum(np.abs(d[:, 2]), 1e-30))[:, None]
        exit_t = np.exp(-exit_od) * chain[:, None]
        out[side] = PointSide(d, chain, sig, depth, exit_t)
    return out


# --------------------------------------------------------------------------------------------
# The kernel
# --------------------------------------------------------------------------------------------


class _Rows:
    """One side's requested directions on the device (gathered by row index in the loop)."""

    def __init__(self, ps: PointSide, first: int, channels: int):
        F = _device_floats
        self.channels = channels
        self.n = ps.d.shape[0]
        self.first = first
        self.d = F(ps.d)
        self.sigma_t = F(np.transpose(ps.sigma_t, (1, 0, 2)))  # (R, regions, 3)
        self.depth = F(np.transpose(ps.depth, (1, 0, 2)))
        self.exit_t = F(ps.exit_t)
        self.chain = F(ps.chain)
        self.regions = ps.sigma_t.shape[0]

    def vec(self, r):
        import drjit as dr
        import mitsuba as mi

        i = mi.UInt32(r) * 3
        return mi.Vector3f(dr.gather(mi.Float, self.d, i), dr.gather(mi.Float, self.d, i + 1),
                           dr.gather(mi.Float, self.d, i + 2))

    def spec(self, table, idx):
        return _gather_channels(table, idx, self.channels)


def _gather_channels(table, idx, channels: int, active=True):
    """Row ``idx`` of a (rows, 3) per-channel table on the device, as a Spectrum; a
    one-channel walk gathers channel 0 only (the spectrum holds it three times: Dr.Jit folds
    the repeated arithmetic)."""
    import drjit as dr
    import mitsuba as mi

    i = mi.UInt32(idx) * 3
    if channels == 1:
        return mi.Spectrum(dr.gather(mi.Float, table, i, active))
    return mi.Spectrum(*[dr.gather(mi.Float, table, i + c, active) for c in range(3)])


def _device_floats(a):
    """A NumPy array as an evaluated Dr.Jit Float (a kernel input)."""
    import drjit as dr
    import mitsuba as mi

    with np.errstate(over="ignore"):  # an optical depth past float32's range: inf, exp(-inf) = 0
        v = mi.Float(np.ascontiguousarray(a, dtype=np.float32).ravel())
    dr.make_opaque(v)
    return v


def _order_class(order):
    import drjit as dr
    import mitsuba as mi

    return mi.UInt32(dr.minimum(order, len(ORDER_CLASSES) - 1))


class _Walk:
    """The walk of one stack for one incidence and one launch of paths."""

    def __init__(self, stack: Stack, sides: dict | None, n_rows: int):
        self.S = stack
        self.cfg = stack.cfg
        self.sides = sides
        self.n_rows = n_rows
        self.rows = {}
        if sides:
            first = 0
            for side in ("up", "down"):
                if side not in sides:
                    continue
                ps = sides[side]
                n = ps if isinstance(ps, int) else ps.d.shape[0]
                if not isinstance(ps, int):
                    self.rows[side] = _Rows(ps, first, self.cfg.channels)
                first += n
        # the next-event kernel pays where a side mixes strategies (see the section below)
        self.use_records = RECORDS_PER_PATH > 0 and any(
            len(self.strategies(side)) > 1 for side in self.rows)
        self.records = None  # the launch's _Records while its walk is traced

    def counters(self):
        """The per-path counters of the records (loop state, reset for each new path)."""
        if not self.use_records:
            return ()
        return ("n_rec",) + tuple(f"cnt_{side}_{s}" for side in self.rows
                                  for s in self.strategies(side))

    # ---- one event ---------------------------------------------------------------------------

    def step(self, st, acc, path):
        """One event of every live lane (st: the loop state dict); point estimates add this
        event's connections to ``acc`` (per path: 4 orders × rows × channels)."""
        import drjit as dr
        import mitsuba as mi

        S, cfg = self.S, self.cfg
        M = cfg.n_media
        rng = st["rng"]
        alive = st["alive"]
        region, z, w, weight = st["region"], st["z"], st["w"], st["weight"]
        down = w.z < 0
        in_medium = alive & (region >= 1) & (region <= M)

        # --- flight through the current medium -----------------------------------------------
        thick = S.region_f(S.thickness, region)
        abs_wz = dr.abs(w.z)
        horizontal = abs_wz < 1e-7
        safe_wz = dr.select(horizontal, 1.0, abs_wz)
        d_boundary = dr.select(down, thick - z, z) / safe_wz
        d_boundary = dr.select(in_medium, dr.maximum(d_boundary, 0.0), 0.0)
        needs_proj = cfg.volume or cfg.absorption or cfg.extinction_only
        proj = S.projected_area(region, w, in_medium) if needs_proj else None
        scatter = mi.Bool(False)
        dist = d_boundary
        # the flight's optical depth, one exp at the end (one channel: scalar, broadcast)
        one = cfg.channels == 1
        tau = mi.Float(0.0) if one else mi.Spectrum(0.0)
        attenuates = False
        u_flight = rng.next_float32()
        if cfg.volume:
            sig_s = S.region_f(S.sigma_s, region) * proj
            can = sig_s > 0
            if cfg.volume_limit >= 0:
                can = can & (st["vol_events"] < cfg.volume_limit)
            t = -dr.log(dr.maximum(1.0 - u_flight, 2.0**-24)) / dr.select(can, sig_s, 1.0)
            scatter = in_medium & can & (t < d_boundary)
            dist = dr.select(scatter, t, d_boundary)
            if cfg.volume_limit >= 0:
                # after the allowed events σs only attenuates (the unscattered part of the light)
                lost = in_medium & ~can
                tau = tau + dr.select(lost, sig_s * dist, 0.0)
                attenuates = True
        for on, table in ((cfg.absorption, S.sigma_a), (cfg.extinction_only, S.sigma_s_c)):
            if on:
                sig = S.region_f(table, mi.UInt32(region) * 3) if one else S.region_c(table, region)
                tau = tau + dr.select(in_medium, sig * proj * dist, 0.0)
                attenuates = True
        z = dr.select(in_medium, z - dist * w.z, z)
        if attenuates:
            weight = weight * dr.exp(-tau)
        alive = alive & ~(in_medium & horizontal & ~scatter)  # a horizontal flight never ends

        hit = alive & ~scatter
        b = mi.Int32(dr.clip(dr.select(down, region, region - 1), 0, M))
        scatter = scatter & alive

        # --- next-event connections of this event to the requested directions ----------------
        if self.rows:
            ev = _Event(w, weight, z, st["last_pdf"], region, b, scatter, hit, st["bounces"])
            if self.records is not None:
                self._record(st, ev, path, acc, rng)
            else:
                self._connect(ev, acc, path, rng, mi.Bool(True))

        # --- volume scattering ---------------------------------------------------------------
        wi = -w
        last_pdf = st["last_pdf"]
        new_w = w
        vol_events = st["vol_events"]
        diffuse = st["diffuse"]
        # a lane scatters in the volume or meets a boundary, never both: one set of uniforms
        # serves whichever sampling the lane takes
        u1 = rng.next_float32()
        u2 = mi.Point2f(rng.next_float32(), rng.next_float32())
        if cfg.volume:
            w_v, p_v = S.phase_sample(region, wi, u1, u2, scatter)
            if cfg.flake_fresnel:
                flake = S.flake_F(region, wi, w_v, scatter)
                weight = dr.select(scatter, weight * (flake.x if one else flake), weight)
            new_w = dr.select(scatter, w_v, new_w)
            vol_events = vol_events + dr.select(scatter, 1, 0)
            diffuse = diffuse | scatter
            last_pdf = dr.select(scatter, p_v, last_pdf)

        # --- boundary events -----------------------------------------------------------------
        force = self._forced_branch(region, b, down)
        w_b, f_b, p_b, diff_b = S.boundary_sample(b, wi, u1, u2, force, hit, bool(self.rows))
        new_w = dr.select(hit, w_b, new_w)
        weight = dr.select(hit, weight * (f_b.x if one else f_b), weight)
        diffuse = diffuse | (hit & diff_b)
        if self.rows:
            last_pdf = dr.select(hit, dr.select(diff_b, p_b, 0.0), last_pdf)
        # float32 rounding of the sampled directions would compound over long paths
        new_w = dr.normalize(new_w)
        up_new = new_w.z > 0
        region = dr.select(hit, dr.select(up_new, b, b + 1), region)
        z = dr.select(hit, dr.select(up_new, S.region_f(S.thickness, b), 0.0), z)

        # --- bounce order: a downward → upward turn below the top interface ----------------
        turned = alive & down & up_new & (scatter | (b >= 1))
        bounces = st["bounces"] + dr.select(turned, 1, 0)

        # --- exits -----------------------------------------------------------------------------
        out_top = alive & (region == 0) & up_new
        out_bottom = alive & (region == M + 1) & ~up_new
        leaving = out_top | out_bottom
        tallied = (out_top & cfg.reflection) | (out_bottom & cfg.transmission)
        if not cfg.delta:
            tallied = tallied & diffuse
        if cfg.max_bounces >= 0:
            tallied = tallied & (bounces <= cfg.max_bounces)
        exited = st["exited"] | tallied
        alive = alive & ~leaving

        # --- what can no longer reach an observed quantity ends here -----------------------
        if cfg.max_bounces >= 0:
            alive = alive & (bounces <= cfg.max_bounces)
            if cfg.end_downward_after_last_bounce:
                alive = alive & ~((bounces == cfg.max_bounces) & ~up_new & (region >= 1))
        w_max = weight if one else dr.max(weight)  # per lane (one channel: a Float)
        alive = alive & (w_max > 0)
        events = st["events"] + dr.select(alive, 1, 0)
        u_rr = rng.next_float32()
        if cfg.russian_roulette:
            q = dr.clip(w_max, RR_MIN_Q, 1.0)
            play = alive & (events > RR_START)
            survive = u_rr < q
            alive = alive & (~play | survive)
            weight = dr.select(play & survive, weight / q, weight)
        capped = alive & (events >= cfg.max_events)
        st.update(region=region, z=z, w=new_w, weight=weight, alive=alive & ~capped,
                  exited=exited, bounces=bounces, vol_events=vol_events, events=events,
                  diffuse=diffuse, last_pdf=last_pdf, capped=capped,
                  steps=st["steps"] + 1, rng=rng)

    def _forced_branch(self, region, b, down):
        """Per lane, the branch forcing at boundary b: the top boundary refracts light from
        outside and reflects light from inside when reflection is not observed; the bottom
        boundary reflects light from above when transmission is not."""
        import drjit as dr
        import mitsuba as mi

        cfg = self.cfg
        force = mi.UInt32(FORCE_CHOOSE)
        if cfg.force_bottom:
            force = dr.select((b == cfg.n_media) & down, FORCE_REFLECT, force)
        if cfg.force_top:
            force = dr.select(b == 0, dr.select(down, FORCE_REFRACT, FORCE_REFLECT), force)
        if cfg.split_first:  # the first crossing, from outside: its reflection is tallied apart
            force = dr.select((b == 0) & down & (region == 0), FORCE_REFRACT, force)
        return force

    # ---- next-event estimation ------------------------------------------------------------
    #
    # The connections of an event to the requested directions are computed in one of two
    # places. With records (where a side mixes strategies and :data:`RECORDS_PER_PATH` > 0),
    # the walk's kernel writes each connecting event into its path's slots, with per-path lists
    # by side and strategy, and a second kernel (:meth:`nee_from_records`) runs one lane per (path,
    # requested direction) over the path's events of one strategy at a time: the lanes of a
    # SIMD packet share their path and so their strategy, where in the walk's own loop every
    # lane executes both strategies of the MIS pair (measured on the throughput arc: 1.94-2.06x
    # less CPU). Events past a path's slots connect in the walk's kernel (:meth:`_connect`).

    def side_static(self, side):
        """(k, k_ok, behind, v_ok, direct_vol) of one side (Python constants): the connecting
        boundary k, the region behind it, whether the vertex strategy applies (k a rough
        dielectric with a medium behind it) and whether volume events on the exit's side of k
        connect directly."""
        cfg = self.cfg
        M = cfg.n_media
        k = cfg.point_up if side == "up" else cfg.point_down
        k_ok = 0 <= k <= M
        behind = k + 1 if side == "up" else k
        v_ok = (k_ok and cfg.boundaries[k].kind == "dielectric"
                and cfg.boundaries[k].nonspecular and 1 <= behind <= M)
        exit_side = range(1, min(k, M) + 1) if side == "up" else range(max(k + 1, 1), M + 1)
        direct_vol = cfg.volume and any(cfg.region_phase[j] is not None for j in exit_side)
        return k, k_ok, behind, v_ok, direct_vol

    def strategies(self, side):
        """The strategies of one side that can occur: 'k' (events at k), 'vol' (volume events
        on the exit's side), 'vertex' (events behind k, through a reverse sample of k)."""
        k, k_ok, behind, v_ok, direct_vol = self.side_static(side)
        return tuple(s for s, on in (("k", k_ok), ("vol", direct_vol), ("vertex", v_ok)) if on)

    def masks(self, ev, side):
        """{strategy: Bool} of an event for one side."""
        import mitsuba as mi

        k, k_ok, behind, v_ok, direct_vol = self.side_static(side)
        any_event = ev.scatter | ev.hit
        out = {}
        if k_ok:
            out["k"] = any_event & ev.hit & (ev.b == k)
        if direct_vol:
            vol = ev.region <= k if side == "up" else ev.region >= k + 1
            out["vol"] = any_event & ev.scatter & vol
        if v_ok:
            out["vertex"] = any_event & self._vertex_candidates(ev, side, k, behind)
        return {s: out.get(s, mi.Bool(False)) for s in self.strategies(side)}

    def _connect(self, ev, acc, path, rng, only):
        """This event's contributions to the per-path point estimates (the flux fraction per
        steradian leaving along each requested direction), by bounce-order class, added to
        ``acc``, for the lanes ``only``, in the walk's own kernel.

        Two strategies reach the connecting rough dielectric boundary k from the vertices right
        behind it (volume events in the region behind k, events at the boundary behind that
        region that send the path toward k), combined by the balance heuristic:

        * crossing (C): the walk's own path reaches k and the BSDF of k is evaluated toward the
          requested direction; its density is that of the vertex's sampling, p_v(d');
        * vertex (V): at the vertex, d' is sampled from k's BSDF in reverse, from the requested
          direction's side (density q(d')), and the vertex's BSDF or phase function is
          evaluated; by the generalized reciprocity of the BTDF (Walter eq. 21),
          f_k(−d' → d) = (η_d / η_d')² f_k(d → −d'), so the sample's weight gives the
          contribution.

        Weights q/(q + p_v) and p_v/(q + p_v) for the same (vertex, d'), so the sum stays
        unbiased; events farther away have only the crossing, events on the exit's side of k
        only the direct connection."""
        import drjit as dr
        import mitsuba as mi

        for side, rows in self.rows.items():
            m = self.masks(ev, side)
            active = mi.Bool(False)
            for v in m.values():
                active = active | v
            active = only & active
            n_rows = rows.n

            def cond(r, *_, active=active):
                return (r < n_rows) & active

            def body(r, rng_state, active=active, rows=rows, side=side, m=m):
                rng_l = mi.PCG32(rng)
                rng_l.state = rng_state
                for strategy in m:
                    value, order = self.contribution(strategy, ev, side, r, rng_l,
                                                     active & m[strategy])
                    self._add(acc, path, rows, r, value, order, active & m[strategy])
                return r + 1, rng_l.state

            r, state = dr.while_loop((mi.UInt32(0), rng.state), cond, body,
                                     labels=("r", "rng"), label=f"rows_{side}")
            rng.state = state

    def contribution(self, strategy, ev, side, r, rng, active):
        """(value, bounce order) of one event ``ev`` toward requested direction r of ``side``
        by one strategy (see :meth:`_connect`); value 0 where ``active`` is false."""
        if strategy == "vertex":
            return self._vertex_strategy(ev, rng, side, r, active)
        return self._direct(strategy, ev, side, r, active)

    def _direct(self, strategy, ev, side, r, active):
        """The crossing strategy at k ('k') or a volume event's direct connection ('vol')."""
        import drjit as dr
        import mitsuba as mi

        S = self.S
        rows = self.rows[side]
        k, k_ok, behind, v_ok, direct_vol = self.side_static(side)
        wi = -ev.w
        down = ev.w.z < 0
        d = rows.vec(r)
        if strategy == "k":
            bd = S.boundary[k]
            if v_ok:
                # one Mitsuba call for the pair d -> wi: q, the reverse sample's density of -w
                # (the crossing strategy's weight below), and f(d, wi), turned into f(wi, d)
                # by reciprocity (Walter eq. 21: f(i, o) / η_o² = f(o, i) / η_i²; η² the
                # boundary's n_below² / n_above²)
                f_rev, q = bd.eval_pdf(d, wi, active)
                eta2 = dr.square(S.eta[k])
                ratio = dr.select(wi.z * d.z < 0, dr.select(d.z < 0, eta2, 1.0 / eta2), 1.0)
                fb = f_rev * ratio * dr.abs(d.z)
                # crossing strategy weight, for paths whose last event could have connected
                p_last = ev.last_pdf
                w_c = dr.select(p_last > 0, p_last / dr.maximum(p_last + q, 1e-30), 1.0)
                fb = fb * dr.select(ev.region == behind, w_c, 1.0)
            else:
                fb = bd.eval(wi, d, active) * dr.abs(d.z)
            value = fb * rows.spec(rows.exit_t, r)
            turn = down if side == "up" and k >= 1 else mi.Bool(False)
        else:
            region = ev.region
            dist = ev.z if side == "up" else S.region_f(S.thickness, region) - ev.z
            idx = r * rows.regions + mi.UInt32(region)
            od = rows.spec(rows.depth, idx) + rows.spec(rows.sigma_t, idx) * (
                dist / dr.maximum(dr.abs(d.z), 1e-30))
            value = (S.phase_eval(region, wi, d, active) * S.flake_F(region, wi, d, active)
                     * dr.exp(-od) * dr.gather(mi.Float, rows.chain, r))
            turn = down if side == "up" else mi.Bool(False)
        value = dr.select(active, value * ev.beta, 0.0)
        return value, ev.bounces + dr.select(turn, 1, 0)

    def _vertex_candidates(self, ev, side, k, behind):
        """Lanes whose event is a vertex of the vertex strategy (see :meth:`_vertex_strategy`)."""
        import mitsuba as mi

        cfg = self.cfg
        M = cfg.n_media
        far = behind if side == "up" else behind - 1
        vol = (ev.scatter & (ev.region == behind)) if cfg.volume and \
            cfg.region_phase[behind] is not None else mi.Bool(False)
        far_ok = 0 <= far <= M and cfg.boundaries[far].nonspecular
        at_far = (ev.hit & (ev.b == far)) if far_ok else mi.Bool(False)
        return vol | at_far

    def _vertex_strategy(self, ev, rng, side, r, active):
        """The vertex strategy of :meth:`_connect` for one requested direction: events in region
        ``behind`` (volume) or at the boundary on its far side, connected through the rough
        dielectric k by a reverse sample of k's BSDF. Returns (contribution, order)."""
        import drjit as dr
        import mitsuba as mi

        S, cfg = self.S, self.cfg
        M = cfg.n_media
        rows = self.rows[side]
        k, k_ok, behind, v_ok, direct_vol = self.side_static(side)
        d = rows.vec(r)
        exit_t = rows.spec(rows.exit_t, r)
        region = ev.region
        wi = -ev.w
        down = ev.w.z < 0
        far = behind if side == "up" else behind - 1
        # reverse sample of k from the requested direction's side: t into region `behind`
        u1 = rng.next_float32()
        u2 = mi.Point2f(rng.next_float32(), rng.next_float32())
        t, weight, q = S.boundary[k].sample(d, u1, u2, mi.UInt32(FORCE_CHOOSE), active, True)
        weight = weight.x
        into = (t.z < 0) if side == "up" else (t.z > 0)
        dp = -t  # the path's direction from the vertex toward k
        dz = dr.maximum(dr.abs(dp.z), 1e-30)
        eta2 = dr.square(S.eta[k])
        ratio = 1.0 / eta2 if side == "up" else eta2  # (η on d's side / η on d′'s side)²
        w_rev = dr.select(into, ratio * weight * dr.abs(d.z) / dz, 0.0)
        vol = (ev.scatter & (region == behind)) if cfg.volume and \
            cfg.region_phase[behind] is not None else mi.Bool(False)
        far_ok = 0 <= far <= M and cfg.boundaries[far].nonspecular
        at_far = (ev.hit & (ev.b == far)) if far_ok else mi.Bool(False)
        f_v = mi.Spectrum(0.0)
        p_v = mi.Float(0.0)
        if far_ok:
            f_far, p_far = S.boundary[far].eval_pdf(wi, dp, active & at_far)
            f_v = dr.select(at_far, f_far * dz, f_v)
            p_v = dr.select(at_far, p_far, p_v)
        if cfg.volume and cfg.region_phase[behind] is not None:
            ph = S.phase_eval(region, wi, dp, active & vol, regions={behind})
            f_v = dr.select(vol, ph * S.flake_F(region, wi, dp, active & vol), f_v)
            p_v = dr.select(vol, ph, p_v)
        # attenuation across `behind` from the vertex to k
        thick_b = S.region_f(S.thickness, mi.UInt32(behind))
        length = dr.select(at_far, thick_b, ev.z if side == "up" else thick_b - ev.z)
        sig = S.sigma_t_along(mi.UInt32(behind), dp, active)
        att = dr.exp(-sig * (length / dz))
        w_v = q / dr.maximum(q + p_v, 1e-30)
        val = ev.beta * f_v * att * (w_rev * w_v) * exit_t
        val = dr.select(active & (vol | at_far) & into & dr.all(dr.isfinite(val)), val, 0.0)
        turn = (down & (vol | at_far)) if side == "up" else mi.Bool(False)
        return val, ev.bounces + dr.select(turn, 1, 0)

    def _record(self, st, ev, path, acc, rng):
        """Keep this event in its path's slots and lists (see the section's comment); an event
        past the path's slots connects here, in the walk's kernel."""
        import drjit as dr
        import mitsuba as mi

        E = RECORDS_PER_PATH
        masks = {(side, s): m for side in self.rows for s, m in self.masks(ev, side).items()}
        need = mi.Bool(False)
        for m in masks.values():
            need = need | m
        e = st["n_rec"]
        room = e < E
        store = need & room
        self.records.write(path * E + e, ev, store)
        for (side, s), m in masks.items():
            key = f"cnt_{side}_{s}"
            sel = store & m
            dr.scatter(self.records.lists[(side, s)], e, path * E + st[key], sel)
            st[key] = st[key] + dr.select(sel, 1, 0)
        st["n_rec"] = e + dr.select(store, 1, 0)
        self._connect(ev, acc, path, rng, need & ~room)

    def nee_from_records(self, rec: _Records, n_pad: int, first: int, words):
        """The next-event kernel: one lane per (path, requested direction) of each side (a
        SIMD packet holds consecutive directions of one path, so its lanes run one strategy
        together), which runs over its path's events of one strategy after another, in event
        order, and sums their contributions per bounce-order class and channel (each lane its
        own sums: no atomics). Returns [(rows, sums)] per side, sums[k × C + c] evaluated, lane
        = path × rows + row; the caller adds them to the walk's own per-path sums. Its reverse
        samples come from a PCG32 stream per (path, side, direction), seeded by the path's
        global id: the same numbers whatever the launch size or thread count."""
        import drjit as dr
        import mitsuba as mi

        cfg = self.cfg
        C = cfg.channels
        E = rec.E
        Ke = point_classes(cfg)
        out = []
        first_v = dr.opaque(mi.UInt32, first & 0xFFFFFFFF)
        for si, (side, rows) in enumerate(self.rows.items()):
            Rs = rows.n
            lane = dr.arange(mi.UInt32, n_pad * Rs)
            p = lane // Rs  # a SIMD packet: consecutive directions of one path
            r = lane % Rs
            rng = mi.PCG32(dr.width(lane))
            rng.seed(*_tea_seeds(p + first_v, words, r * 0x9E3779B1 + (si + 1) * 0x7F4A7C15))
            sums = [dr.zeros(mi.Float, dr.width(lane)) for _ in range(Ke * C)]
            for s in self.strategies(side):
                count = dr.gather(mi.UInt32, rec.counts[(side, s)], p)
                lst = rec.lists[(side, s)]

                def cond(j, *_, count=count):
                    return j < count

                def body(j, rng_state, *sums, s=s, lst=lst, side=side, r=r, p=p):
                    rng_l = mi.PCG32(rng)
                    rng_l.state = rng_state
                    e = dr.gather(mi.UInt32, lst, p * E + j)
                    ev = rec.read(p * E + e)
                    value, order = self.contribution(s, ev, side, r, rng_l, mi.Bool(True))
                    ok = self._kept(value, order, mi.Bool(True))
                    cls = _order_class(order)
                    out = list(sums)
                    for k in range(Ke):
                        for c in range(C):
                            out[k * C + c] = out[k * C + c] + dr.select(ok & (cls == k),
                                                                        value[c], 0.0)
                    return (j + 1, rng_l.state, *out)

                j, state, *sums = dr.while_loop((mi.UInt32(0), rng.state, *sums), cond, body,
                                                label=f"nee_{side}_{s}")
                rng.state = state
            out.append((rows, sums))
        dr.eval([x for _, x in out])
        return out

    def _kept(self, value, order, active):
        """Whether a contribution counts: non-zero, of an order within ``max_bounces``."""
        import drjit as dr

        ok = active & (dr.max(value) > 0)
        if self.cfg.max_bounces >= 0:
            ok = ok & (order <= self.cfg.max_bounces)
        return ok

    def _add(self, acc, path, rows, r, value, order, active):
        """acc[class(order), rows.first + r, :C, path] += value (each lane its own slots; C the
        walk's channels; paths last, so a block of paths is contiguous for the device-side
        sums of :func:`_point_sums`; ``self.stride`` the launch's padded path count)."""
        import drjit as dr

        C = self.cfg.channels
        ok = self._kept(value, order, active)
        slot = ((_order_class(order) * self.n_rows + rows.first + r) * C) * self.stride + path
        for c in range(C):
            # every path owns its slots: a plain read-modify-write, no atomics
            dr.scatter_add(acc, value[c], slot + c * self.stride, ok,
                           mode=dr.ReduceMode.NoConflicts)


def _tea_seeds(path, words, salt=0):
    """PCG32 initial state and stream of global path ids ``path`` (UInt32): TEA hashes
    (``mi.sample_tea_64``) of the id and the seed words, as Mitsuba's ``independent`` sampler
    seeds its lanes (consecutive unhashed seeds give correlated first draws); ``salt`` (UInt32)
    gives a path further streams of its own."""
    import mitsuba as mi

    import drjit as dr

    # kernel inputs, not constants: another seed, incidence or launch reuses the kernel
    w0 = dr.opaque(mi.UInt32, (words[0] & 0xFFFFFFFF) ^ (words[0] >> 32)) ^ salt
    w1 = dr.opaque(mi.UInt32, (words[1] & 0xFFFFFFFF) ^ (words[1] >> 32)) ^ salt
    return mi.sample_tea_64(path, w0), mi.sample_tea_64(w1, path)


def path_rng(n: int, words, first_path: int):
    """The PCG32 streams of paths first_path .. first_path + n − 1 (:func:`_tea_seeds`): a path's
    random numbers depend on its id and the seed, not on the launch or lane it is traced in."""
    import drjit as dr
    import mitsuba as mi

    rng = mi.PCG32(n)
    rng.seed(*_tea_seeds(dr.arange(mi.UInt32, n)
                         + dr.opaque(mi.UInt32, first_path & 0xFFFFFFFF), words))
    return rng


def _fresh(n, wi, channels):
    """The per-path fields of n new paths at the top of the stack, travelling along -wi; the
    flux weight is one Float in a one-channel walk (one loop variable, not three), else a
    Spectrum."""
    import drjit as dr
    import mitsuba as mi

    d = [dr.opaque(mi.Float, -float(c)) for c in wi]  # kernel inputs, not constants
    return {
        "region": dr.zeros(mi.Int32, n), "z": dr.zeros(mi.Float, n),
        "w": mi.Vector3f(d[0] + dr.zeros(mi.Float, n), d[1] + dr.zeros(mi.Float, n),
                         d[2] + dr.zeros(mi.Float, n)),
        "weight": dr.full(mi.Float if channels == 1 else mi.Spectrum, 1.0, n),
        "alive": dr.full(mi.Bool, True, n),
        "exited": dr.full(mi.Bool, False, n), "bounces": dr.zeros(mi.Int32, n),
        "vol_events": dr.zeros(mi.Int32, n), "events": dr.zeros(mi.Int32, n),
        "diffuse": dr.full(mi.Bool, False, n), "last_pdf": dr.zeros(mi.Float, n),
        "capped": dr.full(mi.Bool, False, n),
    }


def _state(lanes, wi, words, first_path, channels):
    """The loop state: ``lanes`` lanes, lane l tracing paths l, l + lanes, l + 2·lanes, ... of
    the launch (path regeneration: a lane whose path ends starts its next one, so SIMD packets
    stay busy until the launch's last paths drain)."""
    import drjit as dr
    import mitsuba as mi

    st = _fresh(lanes, wi, channels)
    st.update(rng=path_rng(lanes, words, first_path), path=dr.arange(mi.UInt32, lanes),
              steps=dr.zeros(mi.UInt32, lanes))
    return st


# --------------------------------------------------------------------------------------------
# Launches and host tallies
# --------------------------------------------------------------------------------------------

#: How the path loop is compiled: "symbolic" (one megakernel) or "evaluated" (a kernel per
#: iteration, finished lanes compressed away); benchmarks/walk_engines.py measures both.
LOOP_MODE = "symbolic"


def seed_words(*keys: int) -> tuple[int, int]:
    """Two 64-bit words from integer keys (seed, incidence, channel walk) by SplitMix64: the
    PCG32 initial state and stream of path 0; path p uses state + p, stream + p."""
    x = 0x9E3779B97F4A7C15
    out = []
    for salt in (0x243F6A8885A308D3, 0x13198A2E03707344):
        h = salt
        for k in keys:
            h = (h ^ (int(k) & 0xFFFFFFFFFFFFFFFF)) & 0xFFFFFFFFFFFFFFFF
            h = (h + x) & 0xFFFFFFFFFFFFFFFF
            h = ((h ^ (h >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
            h = ((h ^ (h >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
            h ^= h >> 31
        out.append(h)
    return out[0], out[1]


class Tallies(NamedTuple):
    """Float64 sums over paths: per order class and output row (4, n_out, C); sums of squares
    per order class and (last) of each path's all-order total (5, n_out, C); the flux leaving
    per side (2 moments, 2 sides, C); the first crossings' split-off reflections (n_out, C)
    sums and squares and (2, 2, C) per side, or None; paths dropped at the event cap; events."""

    s1: np.ndarray
    s2: np.ndarray
    side: np.ndarray
    split: tuple | None
    truncated: int
    events: int


def bin_index(cfg: WalkConfig, w: np.ndarray) -> np.ndarray:
    """Hemisphere bin of exit directions w (P, 3): side (0 = reflection, 1 = transmission), θ bin
    over [0°, 90°] from the side's pole, φ bin over [0°, 360°)."""
    side = (w[:, 2] < 0).astype(np.int64)
    ct = np.clip(np.abs(w[:, 2]), 0.0, 1.0)
    theta = np.arctan2(np.hypot(w[:, 0], w[:, 1]), ct)
    tb = np.clip((theta / (0.5 * np.pi) * cfg.theta_bins).astype(np.int64), 0, cfg.theta_bins - 1)
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2.0 * np.pi)
    pb = np.clip((phi / (2.0 * np.pi) * cfg.phi_bins).astype(np.int64), 0, cfg.phi_bins - 1)
    return (side * cfg.theta_bins + tb) * cfg.phi_bins + pb


def _device_bin(cfg: WalkConfig, w):
    """:func:`bin_index` in the kernel (float32)."""
    import drjit as dr
    import mitsuba as mi

    side = mi.UInt32(dr.select(w.z < 0, 1, 0))
    theta = dr.atan2(dr.sqrt(dr.square(w.x) + dr.square(w.y)), dr.clip(dr.abs(w.z), 0.0, 1.0))
    tb = mi.UInt32(dr.clip(mi.Int32(theta * (2.0 / dr.pi) * cfg.theta_bins), 0,
                           cfg.theta_bins - 1))
    phi = dr.atan2(w.y, w.x)
    phi = dr.select(phi < 0, phi + 2.0 * dr.pi, phi)
    pb = mi.UInt32(dr.clip(mi.Int32(phi * (0.5 / dr.pi) * cfg.phi_bins), 0, cfg.phi_bins - 1))
    return (side * cfg.theta_bins + tb) * cfg.phi_bins + pb


class ConeIndex:
    """Candidate cones per cell of a (cos θ, φ) grid on the sphere: a cone is a candidate of a
    cell when its axis lies within its half angle plus the cell's angular radius of the cell's
    centre, so an exit direction's cones are among its cell's candidates (tested exactly
    afterwards). Turns the (paths × cones) dot products of a cone tally into (paths × a few)."""

    Z, PHI = 90, 180

    def __init__(self, det: Detector):
        axes = np.asarray(det.cone_dir, dtype=np.float64)
        gamma = np.arccos(np.clip(det.cone_cos, -1.0, 1.0))
        zc = np.linspace(-1.0, 1.0, self.Z + 1)
        pc = np.linspace(-np.pi, np.pi, self.PHI + 1)
        # cell corners and centres as unit vectors
        zz, pp = np.meshgrid(zc, pc, indexing="ij")
        corners = self._unit(zz, pp)  # (Z+1, PHI+1, 3)
        zm, pm = np.meshgrid(0.5 * (zc[1:] + zc[:-1]), 0.5 * (pc[1:] + pc[:-1]), indexing="ij")
        centre = self._unit(zm, pm)  # (Z, PHI, 3)
        radius = np.zeros((self.Z, self.PHI))
        for dz in (0, 1):
            for dp in (0, 1):
                c = corners[dz:dz + self.Z, dp:dp + self.PHI]
                radius = np.maximum(radius, np.arccos(np.clip(np.sum(c * centre, -1), -1, 1)))
        # the farthest point of a small cell from its centre is a corner or near one (a
        # bulging edge): a quarter more covers it
        radius = 1.25 * radius
        ang = np.arccos(np.clip(centre.reshape(-1, 3) @ axes.T, -1.0, 1.0))  # (cells, R)
        cand = ang <= gamma[None, :] + radius.reshape(-1)[:, None] + 1e-6
        counts = cand.sum(1)
        width = max(1, int(counts.max()))
        table = np.full((cand.shape[0], width), -1, dtype=np.int64)
        cell, cone = np.nonzero(cand)  # by cell, then cone
        start = np.cumsum(counts) - counts
        table[cell, np.arange(cell.size) - start[cell]] = cone
        self.table, self.axes, self.cos = table, axes, np.asarray(det.cone_cos, np.float64)

    #: Largest candidate count tested in the kernel (wider tables are tested on the host).
    DEVICE_WIDTH = 16

    def _device_cell(self, w):
        """In the kernel: the tables (kernel inputs) and the cell of each w."""
        import drjit as dr
        import mitsuba as mi

        if not hasattr(self, "_dev"):
            self._dev = (mi.UInt32(np.ascontiguousarray(self.table + 1, np.uint32).ravel()),
                         mi.Float(np.ascontiguousarray(self.axes, np.float32).ravel()),
                         mi.Float(np.ascontiguousarray(self.cos, np.float32)))
            for v in self._dev:
                dr.make_opaque(v)
        iz = mi.UInt32(dr.clip(mi.Int32((w.z + 1.0) * (0.5 * self.Z)), 0, self.Z - 1))
        ip = mi.UInt32(dr.clip(mi.Int32((dr.atan2(w.y, w.x) + dr.pi) * (self.PHI / (2 * dr.pi))),
                               0, self.PHI - 1))
        return self._dev, iz * self.PHI + ip

    def device_near(self, w):
        """In the kernel: whether the cell of w has a candidate cone (false: w lies in none);
        one gather, where :meth:`device_members` takes five per candidate."""
        import drjit as dr
        import mitsuba as mi

        (table, _, _), cell = self._device_cell(w)
        return dr.gather(mi.UInt32, table, cell * self.table.shape[1]) > 0

    def device_members(self, w):
        """In the kernel: the cones containing w, as ``width`` UInt32 (cone index + 1, 0: none),
        from the cell of w and its candidates (gathered from the tables as kernel inputs)."""
        import drjit as dr
        import mitsuba as mi

        (table, axes, cos), cell = self._device_cell(w)
        width = self.table.shape[1]
        out = []
        for k in range(width):
            c1 = dr.gather(mi.UInt32, table, cell * width + k)
            c = dr.maximum(mi.Int32(c1) - 1, 0)
            a = [dr.gather(mi.Float, axes, mi.UInt32(c) * 3 + j) for j in range(3)]
            inside = (c1 > 0) & (w.x * a[0] + w.y * a[1] + w.z * a[2]
                                 >= dr.gather(mi.Float, cos, mi.UInt32(c)))
            out.append(dr.select(inside, c1, 0))
        return out

    @staticmethod
    def _unit(z, phi):
        r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)

    def pairs(self, w: np.ndarray):
        """(path, cone) index pairs of the directions w (P, 3) inside each cone, by path."""
        w = w.astype(np.float64)
        iz = np.clip(((w[:, 2] + 1.0) * 0.5 * self.Z).astype(np.int64), 0, self.Z - 1)
        ip = np.clip(((np.arctan2(w[:, 1], w[:, 0]) + np.pi) / (2 * np.pi) * self.PHI)
                     .astype(np.int64), 0, self.PHI - 1)
        cand = self.table[iz * self.PHI + ip]  # (P, width)
        dots = np.einsum("pj,pkj->pk", w, self.axes[np.maximum(cand, 0)])
        inside = (cand >= 0) & (dots >= self.cos[np.maximum(cand, 0)])
        p, k = np.nonzero(inside)
        return p, cand[p, k]


def _cone_pairs(det: Detector, w, x, cones: ConeIndex | None):
    """(path, cone) pairs of the tallied exits on the host, in path order, in chunks."""
    sel = np.flatnonzero(np.any(x != 0.0, axis=1))
    ps, rs = [], []
    for lo in range(0, len(sel), 1 << 16):
        idx = sel[lo:lo + (1 << 16)]
        if cones is not None:
            p, r = cones.pairs(w[idx])
        else:
            p, r = np.nonzero(w[idx].astype(np.float64) @ det.cone_dir.T
                              >= det.cone_cos[None, :])
        ps.append(idx[p])
        rs.append(r)
    return (np.concatenate(ps), np.concatenate(rs)) if ps else (np.zeros(0, int),) * 2


def _tally_key(cfg: WalkConfig, path, w, order, n_out: int):
    """In the kernel: the host tally's slot of a path's exit (:class:`Exits`); ``path`` counts
    from the launch's first path (launches are whole blocks)."""
    import drjit as dr
    import mitsuba as mi

    slot = mi.UInt32(path) // TALLY_BLOCK * len(ORDER_CLASSES) + _order_class(order)
    if cfg.detector == "bins":
        return slot * n_out + _device_bin(cfg, w)
    return slot * 2 + dr.select(w.z < 0, 1, 0)


def _member_pairs(columns, x, key, path=None) -> tuple:
    """(path, cone) pairs from the kernel's candidate columns (cone index + 1, 0: none), column
    by column, each in path order (the same order whatever the launch size), with each pair's
    path weights (m, C) float64 and tally key. Picked on the device (``dr.compress`` keeps the
    order), so only the pairs travel: the paths in some cone first, then each column's members
    among them. ``path``: the launch's path of each row (UInt32, evaluated) where the columns
    hold picked paths only (rows in path order), else None (row = path)."""
    import drjit as dr
    import mitsuba as mi

    if path is None:
        inside = columns[0] > 0
        for col in columns[1:]:
            inside = inside | (col > 0)
        path = dr.compress(inside)
        columns = [dr.gather(mi.UInt32, col, path) for col in columns]
        x = [dr.gather(mi.Float, v, path) for v in x]
        key = dr.gather(mi.UInt32, key, path)
    if dr.width(path) == 0:
        return _no_pairs(len(x))
    member = [col > 0 for col in columns]
    dr.eval(columns, x, key, member)
    parts = []
    for col, m in zip(columns, member):
        j = dr.compress(m)
        parts.append([dr.gather(mi.UInt32, path, j), dr.gather(mi.UInt32, col, j),
                      dr.gather(mi.UInt32, key, j)] + [dr.gather(mi.Float, v, j) for v in x])
    dr.eval(parts)

    def cat(i):
        return np.concatenate([np.array(part[i]) for part in parts])

    xs = np.stack([cat(3 + c) for c in range(len(x))], axis=1).astype(np.float64)
    return (cat(0).astype(np.int64), cat(1).astype(np.int64) - 1, xs,
            cat(2).astype(np.int64))


def _no_pairs(channels: int) -> tuple:
    """:func:`_member_pairs` where no path lies in any cone."""
    return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, channels)),
            np.zeros(0, np.int64))


def _device_sides(x, key, n: int):
    """The exits' sums per block of :data:`TALLY_BLOCK` paths, moment (x, x²) and exit side
    (key's lowest bit: downward; ``key`` None: every exit upward), (nb, 2, 2, C) float64, from
    the kernel's per-path weights ``x`` (C arrays) and keys, on the device: each block reduced
    in path order by one thread (``dr.block_sum``, evaluated: no atomics)."""
    import drjit as dr
    import mitsuba as mi

    F64 = dr.float64_array_t(mi.Float)
    nb = -(-n // TALLY_BLOCK)
    idx = dr.arange(mi.UInt32, nb * TALLY_BLOCK)
    valid = idx < n
    sides = 1 if key is None else 2
    down = None if key is None else (dr.gather(mi.UInt32, key, idx, valid) & 1) != 0
    parts = []
    for v in x:
        v = F64(dr.gather(mi.Float, v, idx, valid))
        if down is None:
            parts += [v, v * v]
            continue
        v_down = dr.select(down, v, 0.0)
        v_up = v - v_down  # exact: v or 0
        parts += [v_up, v_down, v_up * v_up, v_down * v_down]
    sums = [dr.block_sum(v, TALLY_BLOCK, mode="evaluated") for v in parts]
    dr.eval(sums)
    out = np.zeros((nb, len(x), 2, 2))  # (nb, C, moment, side)
    out[..., :sides] = np.stack([np.array(v) for v in sums], axis=1).reshape(
        nb, len(x), 2, sides)
    return out.transpose(0, 2, 3, 1)  # (nb, moment, side, C)


def tally_exits(cfg: WalkConfig, det: Detector, ex: Exits, n_out: int,
                cones: ConeIndex | None = None):
    """Float64 sums and sums of squares of the exits' weights per block of
    :data:`TALLY_BLOCK` paths, order class and bin or cone, (nb, 4, n_out, C) each, and per exit
    side (nb, 2 moments, 2 sides, C), each block summed in path order."""
    C = cfg.channels
    K = len(ORDER_CLASSES)
    if cfg.detector == "bins":
        P = len(ex.x)
        nb = -(-P // TALLY_BLOCK)
        x = ex.x.astype(np.float64)  # finite: the kernel writes only finite exits
        x2 = x * x
        s1 = np.zeros((nb, K, n_out, C))
        s2 = np.zeros((nb, K, n_out, C))
        side = np.zeros((nb, 2, 2, C))
        # every tallied exit lies in one bin: the sides' sums are the bins' (reflection bins
        # first, bin_index)
        for c in range(C):
            s1[..., c] = np.bincount(ex.key, x[:, c], nb * K * n_out).reshape(nb, K, n_out)
            s2[..., c] = np.bincount(ex.key, x2[:, c], nb * K * n_out).reshape(nb, K, n_out)
        half = n_out // 2
        for m, s in enumerate((s1, s2)):
            side[:, m, 0] = s[:, :, :half].sum(axis=(1, 2))
            side[:, m, 1] = s[:, :, half:].sum(axis=(1, 2))
        return s1, s2, side
    side = ex.side
    nb = side.shape[0]
    s1 = np.zeros((nb, K, n_out, C))
    s2 = np.zeros((nb, K, n_out, C))
    if cfg.detector == "cones":
        # cones may overlap: the (path, cone) pairs of the tallied paths, summed per block,
        # order class and cone by one bincount (a fixed pair order: each block's sums are the
        # same however the launches are cut); key: (block × K + order class) × 2 + side
        R = det.cone_dir.shape[0]
        size = nb * K * R
        if ex.pair_x is not None:
            (p, r), xp, kp = ex.cones, ex.pair_x, ex.pair_key
        else:
            p, r = _cone_pairs(det, ex.w, ex.x, cones)
            xp, kp = ex.x[p].astype(np.float64), ex.key[p].astype(np.int64)
        key = (kp >> 1) * R + r
        for c in range(C):
            s1[..., c] = np.bincount(key, xp[:, c], size).reshape(nb, K, R)
            s2[..., c] = np.bincount(key, xp[:, c] * xp[:, c], size).reshape(nb, K, R)
    return s1, s2, side


def _fold(total: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """total + blocks[0] + blocks[1] + ..., added one block after the other (``np.cumsum`` is a
    left fold): the same float64 result however the blocks are split into launches."""
    return np.cumsum(np.concatenate([total[None], blocks]), axis=0)[-1]


class _Cores:
    """Dr.Jit's LLVM worker threads poll for work about half a million times after a kernel
    before they sleep: CPU burnt beside the host's tally that follows (measured on 2 cores:
    20-48 ms after each launch, a third of the throughput scene's CPU). The walk gives the
    thread pool its full size for its kernels and parks it on the calling thread for the host's
    turn; the size it found is restored on exit."""

    def __init__(self):
        import drjit as dr

        self.dr, self.n = dr, dr.thread_count()

    def kernel(self):
        self.dr.set_thread_count(self.n)

    def host(self):
        """After the kernels of a launch finished (waited for here), before the host reads."""
        self.dr.sync_thread()
        if self.n > 1:
            self.dr.set_thread_count(1)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.kernel()
        return False


#: Lanes of one launch (each traces about launch / LANES paths in turn).
LANES = 1 << 15


def _launch(stack: Stack, walk: _Walk, wi, n: int, first: int, words, n_out: int,
            cones: ConeIndex | None, cores: _Cores):
    """Trace paths first .. first + n − 1 on at most :data:`LANES` lanes; returns their Exits,
    the point estimates' block sums (:func:`_point_sums`) or None, the number of paths capped
    and the events traced."""
    import drjit as dr
    import mitsuba as mi

    lanes = min(n, LANES)
    st = _state(lanes, wi, words, first, stack.cfg.channels)
    # kernel inputs, not constants: launches of other sizes or offsets reuse the kernel
    n_v, lanes_v = dr.opaque(mi.UInt32, n), dr.opaque(mi.UInt32, lanes)
    first_v = dr.opaque(mi.UInt32, first & 0xFFFFFFFF)
    points = bool(walk.rows)
    C = stack.cfg.channels
    n_pad = -(-n // TALLY_BLOCK) * TALLY_BLOCK
    acc = dr.zeros(mi.Float, n_pad * point_classes(stack.cfg) * n_out * C) if points else None
    walk.stride = dr.opaque(mi.UInt32, n_pad)
    # per path only what the host tally reads (Exits): C weights and one slot or order word;
    # every path ends once and writes its slots then (0 where nothing is tallied), so the
    # arrays need no clearing
    ex_x = [dr.empty(mi.Float, n) for _ in range(C)]
    ex_key = dr.empty(mi.UInt32, n)
    on_device = cones is not None and cones.table.shape[1] <= ConeIndex.DEVICE_WIDTH
    host_w = cones is not None and not on_device
    ex_w = [dr.empty(mi.Float, n) for _ in range(3)] if host_w else []
    ex_cones = [dr.empty(mi.UInt32, n) for _ in range(cones.table.shape[1])] if on_device else []
    # a truncated path's point sums are dropped (below); elsewhere the count is enough
    capped_paths = dr.zeros(mi.Bool, n_pad) if points else None
    st["n_capped"] = dr.zeros(mi.UInt32, lanes)
    fresh = _fresh(1, wi, C)
    # point estimates through the next-event kernel: the events' records and their counters
    rec = walk.records = _Records(walk, n_pad, C) if points and walk.use_records else None
    for key in walk.counters():
        st[key] = dr.zeros(mi.UInt32, lanes)
        fresh[key] = dr.zeros(mi.UInt32, 1)

    def cond(s):
        return s["alive"]

    def body(s):
        walk.step(s, acc, s["path"])
        ended = ~s["alive"]
        path = s["path"]
        finite = dr.isfinite(s["weight"]) if C == 1 else dr.all(dr.isfinite(s["weight"]))
        done = ended & s["exited"] & finite & dr.all(dr.isfinite(s["w"]))
        for c in range(C):
            x = s["weight"] if C == 1 else s["weight"][c]
            dr.scatter(ex_x[c], dr.select(done, x, 0.0), path, ended)
        key = _tally_key(stack.cfg, path, s["w"], s["bounces"], n_out)
        dr.scatter(ex_key, dr.select(done, key, 0), path, ended)
        for c, arr in enumerate(ex_w):
            dr.scatter(arr, dr.select(done, s["w"][c], 0.0), path, ended)
        if on_device:
            for arr, member in zip(ex_cones, cones.device_members(s["w"])):
                dr.scatter(arr, dr.select(done, member, 0), path, ended)
        capped = ended & s["capped"]
        if points:
            dr.scatter(capped_paths, True, path, capped)
        if rec is not None:
            for (side, strategy), counts in rec.counts.items():
                dr.scatter(counts, s[f"cnt_{side}_{strategy}"], path, ended)
        s["n_capped"] = s["n_capped"] + dr.select(capped, 1, 0)
        # the lane's next path
        nxt = path + lanes_v
        start = ended & (nxt < n_v)
        for key, v in fresh.items():
            s[key] = dr.select(start, type(s[key])(v), s[key])
        s["alive"] = s["alive"] | start
        state, inc = _tea_rng_fields(nxt + first_v, words)
        s["rng"].state = dr.select(start, state, s["rng"].state)
        s["rng"].inc = dr.select(start, inc, s["rng"].inc)
        s["path"] = dr.select(start, nxt, path)
        return (s,)

    kw = {"mode": "evaluated", "compress": True} if LOOP_MODE == "evaluated" else {}
    (st,) = dr.while_loop((st,), cond, body, label="fitlab_walk", **kw)
    cores.kernel()
    dr.eval(ex_w, ex_x, ex_key, ex_cones, capped_paths, st["steps"], st["n_capped"], acc,
            rec.arrays() if rec is not None else None)
    nee = None
    if rec is not None:
        nee = walk.nee_from_records(rec, n_pad, first, words)
        walk.records = None
    cores.host()
    events = int(np.array(st["steps"]).astype(np.int64).sum())
    n_capped = int(np.array(st["n_capped"]).astype(np.int64).sum())
    ex = _exits(stack.cfg, ex_x, ex_key, n, ex_w, ex_cones)
    sums = None
    if points:
        a = np.array(acc).reshape(-1, n_out, C, n_pad)
        for rows, values in nee or ():  # the next-event kernel's sums, (k, c) → (path, row)
            for k in range(a.shape[0]):
                for c in range(C):
                    a[k, rows.first:rows.first + rows.n, c] += \
                        np.array(values[k * C + c]).reshape(n_pad, rows.n).T
        sums = _point_sums(a, np.array(capped_paths).astype(bool), n_out, C)
    return ex, sums, n_capped, events


def point_classes(cfg: WalkConfig) -> int:
    """Bounce-order classes a point estimate can reach: one where nothing lies below the top
    boundary (no turn is possible) or ``max_bounces`` is 0; at most max_bounces + 1; else all
    four. The per-path sums keep only these."""
    K = len(ORDER_CLASSES)
    if cfg.n_media == 0:
        return 1
    return K if cfg.max_bounces < 0 else min(K, cfg.max_bounces + 1)


def _point_sums(acc: np.ndarray, capped: np.ndarray, n_out: int, C: int):
    """The point estimates' per-block sums in float64 from the per-path sums ``acc``
    (Ke classes × n_out × C × padded paths, float32; Ke = :func:`point_classes`): per block of
    :data:`TALLY_BLOCK` paths, order class, row and channel the sum of the paths' values and of
    their squares, and per row and channel the sum of the squares of each path's all-order
    total: (nb, K, n_out, C), (nb, K, n_out, C), (nb, 1, n_out, C), classes beyond Ke zero.
    NumPy's float64 sums over each block, in a fixed order: the same numbers whatever the
    thread count or the launch size. A path cut at the event cap contributes nothing, as its
    exit would not."""
    K = len(ORDER_CLASSES)
    n_pad = capped.shape[0]
    nb = n_pad // TALLY_BLOCK
    x = acc.reshape(-1, n_out * C, n_pad)
    Ke = x.shape[0]
    if capped.any():
        x[:, :, capped] = 0.0
    s1 = np.zeros((K, n_out * C, nb))
    s2 = np.zeros((K, n_out * C, nb))
    tot = np.zeros((n_out * C, nb, TALLY_BLOCK)) if Ke > 1 else None
    for k in range(Ke):
        xk = x[k].reshape(n_out * C, nb, TALLY_BLOCK).astype(np.float64)
        s1[k] = xk.sum(axis=-1)
        s2[k] = np.einsum("rbt,rbt->rb", xk, xk)
        if tot is not None:
            tot += xk
    s3 = s2[0] if tot is None else np.einsum("rbt,rbt->rb", tot, tot)

    def arrange(v):  # (k, n_out * C, nb) -> (nb, k, n_out, C)
        return v.reshape(v.shape[0], n_out, C, nb).transpose(3, 0, 1, 2)

    return arrange(s1), arrange(s2), arrange(s3[None])


def _tea_rng_fields(path, words):
    """PCG32 (state, inc) of global path ids ``path``, as ``PCG32.seed`` sets them."""
    import mitsuba as mi

    rng = mi.PCG32()
    rng.seed(*_tea_seeds(path, words))
    return rng.state, rng.inc


class _Split:
    """Splitting at the first interface (:attr:`WalkConfig.split_first`): the walk's first
    crossing of the top boundary refracts (weight 1 − F); the reflected branch of that crossing
    (weight F) is tallied here, as bounce order 0 in bins or cones as the walk's own exits are,
    sampled with random numbers of its own (independent of the walk's path: its variance adds
    to the walk's). :meth:`blocks` gives one launch's sums per block of :data:`TALLY_BLOCK`
    paths, as :func:`tally_exits` does.

    A specular top reflects every path alike (one direction, weight F(θi)): its branch is
    computed once and counted once per path of each block, with no per-path kernel."""

    #: Salt of the split's seed words: its PCG32 streams are not the walk's.
    SALT = (0x27D4EB2F165667B1, 0x165667B19E3779F9)

    def __init__(self, stack: Stack, det: Detector, wi, words, n_out: int,
                 cones: ConeIndex | None, cores: _Cores):
        self.stack, self.det, self.wi, self.n_out, self.cones = stack, det, wi, n_out, cones
        self.words = (words[0] ^ self.SALT[0], words[1] ^ self.SALT[1])
        # a specular top: the sums of one path's branch (one block), scaled in :meth:`blocks`
        self.one = None if stack.boundary[0].nonspecular else self._tally(1, 0, cores)

    def blocks(self, n: int, first: int, cores):
        """The sums of paths first .. first + n − 1 (``first`` a multiple of
        :data:`TALLY_BLOCK`) per block: (nb, K, n_out, C) twice and (nb, 2, 2, C)."""
        if self.one is None:
            return self._tally(n, first, cores)
        # every path of a block adds the one branch: its count times the branch's sums
        nb = -(-n // TALLY_BLOCK)
        count = np.full(nb, float(TALLY_BLOCK))
        count[-1] = n - TALLY_BLOCK * (nb - 1)
        return tuple(count.reshape((nb,) + (1,) * (t.ndim - 1)) * t for t in self.one)

    def _branch(self, n: int, first: int):
        """The reflected branches of the first crossings of paths first .. first + n − 1: their
        weights (C Floats, 0 where not tallied) and exit directions (upward), from PCG32
        streams of their own (:func:`path_rng` of the split's words); the top sampled in its
        reflection lobe for every lane."""
        import drjit as dr
        import mitsuba as mi

        cfg = self.stack.cfg
        rng = path_rng(n, self.words, first)
        u1 = rng.next_float32()
        u2 = mi.Point2f(rng.next_float32(), rng.next_float32())
        wi_v = mi.Vector3f(*[dr.opaque(mi.Float, float(c)) for c in self.wi])
        top = self.stack.boundary[0]  # called directly: every lane meets the top (no dispatch)
        wo, f, _ = top.sample(wi_v, u1, u2, FORCE_REFLECT, mi.Bool(True), False)
        keep = (wo.z > 0) & dr.all(dr.isfinite(f)) & dr.all(dr.isfinite(wo))
        if not cfg.delta and not top.nonspecular:
            keep = mi.Bool(False)
        f = dr.select(keep, f, 0.0)
        wo = dr.select(keep, wo, mi.Vector3f(0.0, 0.0, 1.0))
        return [f[c] for c in range(cfg.channels)], wo

    def _key(self, path, wo):
        """The tally keys (order 0) of the branches of the launch's paths ``path``."""
        import mitsuba as mi

        return _tally_key(self.stack.cfg, path, wo, mi.UInt32(0), self.n_out)

    def _tally(self, n: int, first: int, cores):
        """:func:`tally_exits` of the branches of paths first .. first + n − 1, per block: in
        bins, or in cones found on the host where the cone table is too wide for the kernel,
        else in :meth:`_cones`."""
        import drjit as dr
        import mitsuba as mi

        cones = self.cones
        x, wo = self._branch(n, first)
        if cones is not None and cones.table.shape[1] <= ConeIndex.DEVICE_WIDTH:
            ex = self._cones(x, wo, n, cores)
        else:
            key = self._key(dr.arange(mi.UInt32, n), wo)
            host_w = [wo[c] for c in range(3)] if cones is not None else []
            cores.kernel()
            dr.eval(x, key, host_w)
            cores.host()
            ex = _exits(self.stack.cfg, x, key, n, host_w)
        return tally_exits(self.stack.cfg, self.det, ex, self.n_out, cones)

    def _cones(self, x, wo, n: int, cores) -> Exits:
        """The branches' :class:`Exits` in cones found on the device, in two passes: only the
        branches whose cell has a candidate cone (:meth:`ConeIndex.device_near`, one gather:
        about a quarter on the throughput arc) are picked and their members found (five
        gathers per candidate, most of a branch's cost if every branch paid them). Every
        branch leaves upward: the sides' sums need no keys."""
        import drjit as dr
        import mitsuba as mi

        cones = self.cones
        wo = [wo[c] for c in range(3)]
        near = cones.device_near(mi.Vector3f(*wo)) & (x[0] > 0)
        for v in x[1:]:
            near = near | (v > 0)  # a branch of weight 0 lies in no cone
        cores.kernel()
        dr.eval(x, near, wo)
        idx = dr.compress(near)
        picked = None
        if dr.width(idx) > 0:
            w_p = mi.Vector3f(*[dr.gather(mi.Float, v, idx) for v in wo])
            picked = [cones.device_members(w_p), [dr.gather(mi.Float, v, idx) for v in x],
                      self._key(idx, w_p), idx]
            dr.eval(picked)
        cores.host()
        pairs = _no_pairs(len(x)) if picked is None else _member_pairs(*picked)
        return Exits(None, None, cones=pairs[:2], side=_device_sides(x, None, n),
                     pair_x=pairs[2], pair_key=pairs[3])


def _exits(cfg: WalkConfig, x, key, n: int, w=(), members=()) -> Exits:
    """The host's :class:`Exits` from the kernel's evaluated per-path arrays: C weights, keys,
    the exit directions where the host finds the cones (``w``), the cone member columns where
    the kernel did (``members``). np.array(v) takes Dr.Jit's buffer as it is (its own dtype):
    conversions happen in NumPy after."""
    def host(arrays):
        return np.stack([np.array(v) for v in arrays], axis=1)

    if cfg.detector == "bins":
        return Exits(host(x), np.array(key).astype(np.int64))
    side = _device_sides(x, key, n)
    if w:
        return Exits(host(x), np.array(key), host(w), side=side)
    if members:
        p, r, xp, kp = _member_pairs(members, x, key)
        return Exits(None, None, cones=(p, r), side=side, pair_x=xp, pair_key=kp)
    return Exits(None, None, side=side)


def run(stack: Stack, det: Detector, wi, n_paths: int, words, n_out: int, n_up: int = 0,
        launch: int = LAUNCH_PATHS, on_launch=None) -> Tallies:
    """Trace ``n_paths`` paths lit from direction ``wi`` (unit, z > 0, toward the light) and sum
    their contributions (:class:`Tallies`). ``words``: the PCG32 seed words (:func:`seed_words`);
    ``on_launch(n)``: called after each launch of n paths (progress). Point detectors: the
    rows are the reflection rows first, ``n_up`` of them. ``launch``: paths per launch (a
    whole multiple of :data:`TALLY_BLOCK`, at least one; point estimates launch fewer when their
    per-path sums would pass :data:`POINT_LAUNCH_BYTES`). The result does not depend on it."""
    cfg = stack.cfg
    C = cfg.channels
    K = len(ORDER_CLASSES)
    points = cfg.detector == "points"
    sides = point_sides(cfg, stack.arr, det.cone_dir, n_up) if points else None
    walk = _Walk(stack, sides, n_out if points else 0)
    cones = ConeIndex(det) if cfg.detector == "cones" else None
    if points:
        per_path = point_classes(cfg) * n_out * C * 4
        if walk.use_records:  # a record's 9 + C words a slot, and a list word a strategy
            per_path += RECORDS_PER_PATH * 4 * (9 + C + len(walk.counters()) - 1)
        launch = min(launch, POINT_LAUNCH_BYTES // per_path)
    launch = max(TALLY_BLOCK, launch // TALLY_BLOCK * TALLY_BLOCK)
    s1 = np.zeros((K, n_out, C))
    s2 = np.zeros((K + 1, n_out, C))
    side = np.zeros((2, 2, C))
    split = [np.zeros((n_out, C)), np.zeros((n_out, C)), np.zeros((2, 2, C))] \
        if cfg.split_first else None
    truncated = events = 0
    with _Cores() as cores:
        splitter = _Split(stack, det, wi, words, n_out, cones, cores) if cfg.split_first \
            else None
        for first in range(0, n_paths, launch):
            n = min(launch, n_paths - first)
            ex, sums, capped, ev = _launch(stack, walk, wi, n, first, words, n_out, cones,
                                          cores)
            sp = splitter.blocks(n, first, cores) if splitter is not None else None
            truncated += capped
            events += ev
            t1, t2, t_side = tally_exits(cfg, det, ex, n_out, cones)
            side = _fold(side, t_side)
            if points:
                s1 = _fold(s1, sums[0])
                s2 = _fold(s2, np.concatenate([sums[1], sums[2]], axis=1))
            else:
                s1 = _fold(s1, t1)
                # each path exits in one order class: its total's square is its order's
                s2 = _fold(s2, np.concatenate([t2, t2.sum(axis=1, keepdims=True)], axis=1))
            if sp is not None:
                q1, q2, q_side = sp
                split[0] = _fold(split[0], q1[:, 0])
                split[1] = _fold(split[1], q2[:, 0])
                split[2] = _fold(split[2], q_side)
            if on_launch is not None:
                on_launch(n)
    return Tallies(s1, s2, side, None if split is None else tuple(split), truncated, events)
