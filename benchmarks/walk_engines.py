"""Walk engines (issue 15, item 3): the random walk of ``numpy_walk.simulate_numpy`` compiled by
other array compilers, timed against NumPy and fitlab's Dr.Jit walk, and set against this CPU's
arithmetic peak.

Engines, each the same walk as ``simulate_numpy`` (free flights sampled by σs with
Beer–Lambert weights for σa, Henyey–Greenstein / isotropic phase sampling, GGX interfaces
sampled as in Walter section 5.3, smooth interfaces by a Fresnel choice, bounce orders, Russian
roulette after 3 events with survival q = clip(weight, 0.05, 1), at most 512 events, (θ, φ)
hemisphere bins on both sides):

* ``numpy``: ``numpy_walk.simulate_numpy`` itself (float64, alive paths compacted per event);
* ``fitlab``: ``fitlab.simulate.simulate(..., device="cpu")`` on
  ``bench_simulate.throughput_scene()``: fitlab's plain walk (fitlab/simulate/walk.py: Dr.Jit's
  LLVM backend through Mitsuba 3's ``llvm_ad_rgb`` variant and its BSDF and phase-function
  plugins, float32 paths, one symbolic ``dr.while_loop`` per walk configuration with path
  regeneration on ``walk.LANES`` lanes, exits tallied into the bins on the host in float64);
* ``fitlab_nee``: the full-feature kernel, the same scene and walk with point estimates (next-
  event estimation toward the 41 directions of ``bench_simulate.arc_scene("point")``, every
  connection's BSDF, phase and transmittance evaluations) instead of bins; it has no bins to
  check against NumPy here (``bench_simulate.py`` [4] checks it against
  ``numpy_walk.simulate_numpy_points``);
* ``numba64`` / ``numba32``: :func:`simulate_numba`, ``@njit(parallel=True,
  fastmath=False)``: ``prange`` over chunks of paths, each path traced to its end in scalar
  code, float64 / float32 path state (tallies float64), per-chunk tallies summed at the end;
  random numbers from a SplitMix64 stream per path (seeded by a hash of the seed and the path
  number, so the result does not depend on the thread count);
* ``drjit``: :func:`simulate_drjit`, Dr.Jit's LLVM backend (``drjit.llvm``, float32, 16-wide
  AVX-512 packets here): one symbolic ``dr.while_loop`` over events on a wavefront of lanes
  (every lane computes the flight, the phase sample and the interface sample and selects; the
  loop runs per SIMD packet, so a packet stops when its own lanes are done), with path
  regeneration (each lane traces 32 paths one after another, so the packets stay busy), PCG32
  per lane, each exit scattered to per-path arrays and tallied after the loop with
  ``dr.scatter_reduce`` into float64 bins.

Every engine's run is checked against NumPy's (reflected and transmitted flux within 4
standard errors; per-bin χ² over the bins expecting >= 100 paths with p > 1e-3, as
``bench_simulate.py`` checks fitlab); the table says whether it agrees. Times are warm (each
engine's first call, which compiles, is timed apart), the least CPU time of ``--repeat`` runs.
An event is one iteration of a path's loop (a free flight and the scattering or boundary
crossing that ends it; the first crossing of the top interface is one), as fitlab counts them;
ns of CPU per event = CPU time (time.process_time, all threads) / events.

The limit: the floating-point work of one event is counted from the Numba kernel's own source
(:func:`kernel_cost`: the operations of each helper, along its longest branch, weighted by
:data:`WEIGHTS`), combined with the event mix the kernel measures (flights, phase samples,
interface samples, roulette draws, random numbers per event), and set against the peak of this
CPU (cores × clock × 8 float32 lanes × 2 FMA pipes); it needs numba. fitlab's two rows are set
against the limit of benchmarks/README.md, :data:`LIMIT_NS` = 7.7 ns of CPU per event (319
float32 slots per event at one core's peak, 2.6 GHz × 8 lanes × 2 FMA pipes, on the reference
machine): target <= 3x for the plain walk, the full-feature kernel's figure printed beside it.

Usage: python benchmarks/walk_engines.py [--paths 524288] [--seed 0] [--repeat 3]
       [--engines numpy,fitlab,fitlab_nee,numba64,numba32,drjit]
Exit status 0 when every engine run agrees with NumPy, 1 when one does not.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import inspect
import math
import os
import platform
import sys
import textwrap
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

try:  # fitlab's choice of libLLVM, made before drjit is imported (below, and by mitsuba)
    from fitlab.simulate import engine as _fitlab_engine

    _fitlab_engine.select_libllvm()
except Exception:  # noqa: BLE001 - no usable libLLVM: the Dr.Jit engines report it
    pass

#: The CPU cost limit of one event of this walk, ns of CPU per event (benchmarks/README.md,
#: "Engines": 319 float32 slots per event / (2.6 GHz x 8 lanes x 2 FMA pipes) per core).
LIMIT_NS = 7.7
#: fitlab's plain walk must come within this factor of LIMIT_NS.
LIMIT_FACTOR = 3.0


def _load(name):
    """A benchmark module of this folder, imported by path."""
    if name in sys.modules:
        return sys.modules[name]
    if name == "bench_simulate" and HERE not in sys.path:  # it imports numpy_walk by name
        sys.path.insert(0, HERE)
    spec = importlib.util.spec_from_file_location(name, os.path.join(HERE, name + ".py"))
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


# the benchmark scene of bench_simulate.py (throughput_scene / run_numpy)
THETA_I = 30.0
T_BINS, P_BINS = 9, 12
REGIONS = [{"index": 1.0},
           {"index": 1.5, "thickness": 1.0, "sigma_a": 0.2, "sigma_s": 0.8, "g": 0.5},
           {"index": 1.0}]
BOUNDARIES = [{"kind": "ggx", "alpha": 0.2}, {"kind": "ggx", "alpha": 0.3}]
WI = [math.sin(math.radians(THETA_I)), 0.0, math.cos(math.radians(THETA_I))]
MAX_EVENTS, RR_START, RR_MIN_Q = 512, 3, 0.05
KIND_CODE = {"pass": 0, "smooth": 1, "ggx": 2}

#: The engines fastest first (measured by ``main``; see the module's report): the test of
#: tests/benchmarks/test_walk_engines.py checks the first one that is importable.
BY_SPEED = ("drjit", "numba32", "numba64")
#: Paths each Dr.Jit lane traces one after another (path regeneration; 1: one path per lane).
#: Measured at 2^19 paths: 1 -> 38% of a packet's lanes busy, 56 ns of CPU per event; 8 -> 67%,
#: 37 ns; 32 -> 82%, 29-34 ns; 128 -> 90%, 28 ns (beyond 16 the time hardly changes).
DRJIT_PATHS_PER_LANE = 32


def _scene_arrays(regions, boundaries):
    M = len(regions) - 2
    n_idx = np.array([r["index"] for r in regions], float)
    for b in boundaries:
        if b["kind"] not in KIND_CODE:
            raise ValueError(f"unsupported boundary kind {b['kind']!r}")
    return dict(
        M=M,
        thick=np.array([r.get("thickness", 0.0) for r in regions], float),
        sig_a=np.array([r.get("sigma_a", 0.0) for r in regions], float),
        sig_s=np.array([r.get("sigma_s", 0.0) for r in regions], float),
        g=np.array([r.get("g", 0.0) for r in regions], float),
        kind=np.array([KIND_CODE[b["kind"]] for b in boundaries], np.int64),
        alpha=np.array([b.get("alpha", 0.0) for b in boundaries], float),
        eta=n_idx[1:] / n_idx[:-1])


# --------------------------------------------------------------------------------------------
# Numba: one path per iteration, scalar code, traced to its end
# --------------------------------------------------------------------------------------------

try:
    import numba
except ImportError as exc:  # the engine is optional
    numba = None
    NUMBA_ERROR = str(exc)
else:
    NUMBA_ERROR = None

_NUMBA = {}


def _numba_kernels(F):
    """The Numba walk with path state of float type ``F`` (np.float32 or np.float64). Every
    constant is of type F (a Python float literal would promote float32 arithmetic to
    float64). Returns a dict of the compiled helpers and the parallel driver ``run``."""
    key = np.dtype(F).name
    if key in _NUMBA:
        return _NUMBA[key]
    jit = numba.njit(fastmath=False, error_model="numpy", cache=False)
    U = np.uint64
    GOLD, M1, M2 = U(0x9E3779B97F4A7C15), U(0xBF58476D1CE4E5B9), U(0x94D049BB133111EB)
    S30, S27, S31 = U(30), U(27), U(31)
    f32 = np.dtype(F) == np.float32
    SH = U(40) if f32 else U(11)
    SCALE = F(2.0 ** -24) if f32 else F(2.0 ** -53)
    ZERO, ONE, TWO, HALF = F(0.0), F(1.0), F(2.0), F(0.5)
    TWO_PI, EPS_G, EPS_H = F(2.0 * math.pi), F(1e-3), F(1e-7)

    @jit
    def mix64(z):
        z = (z ^ (z >> S30)) * M1
        z = (z ^ (z >> S27)) * M2
        return z ^ (z >> S31)

    @jit
    def rand(s):
        """SplitMix64: the next state and a uniform in [0, 1) of type F."""
        s = s + GOLD
        z = s
        z = (z ^ (z >> S30)) * M1
        z = (z ^ (z >> S27)) * M2
        z = z ^ (z >> S31)
        return s, F(z >> SH) * SCALE

    @jit
    def flight(z, wz, th, sa, ss, u):
        """Free flight in a medium: (scatter, new z, Beer–Lambert factor, horizontal)."""
        abs_wz = abs(wz)
        horizontal = abs_wz < EPS_H
        d_b = (th - z if wz < ZERO else z) / (ONE if horizontal else abs_wz)
        d_b = max(d_b, ZERO)
        scatter = False
        t = d_b
        if ss > ZERO:
            t = -math.log1p(-u) / ss
            scatter = t < d_b
        d = t if scatter else d_b
        return scatter, z - d * wz, math.exp(-sa * d), horizontal

    @jit
    def sample_hg(dx, dy, dz, g, u0, u1):
        """New direction around the old one d (HG, isotropic where |g| < 1e-3)."""
        if abs(g) < EPS_G:
            cos_t = ONE - TWO * u0
        else:
            sq = (ONE - g * g) / (ONE + g - TWO * g * u0)
            cos_t = (ONE + g * g - sq * sq) / (TWO * g)
        cos_t = min(max(cos_t, -ONE), ONE)
        sin_t = math.sqrt(max(ONE - cos_t * cos_t, ZERO))
        phi = TWO_PI * u1
        sign = ONE if dz >= ZERO else -ONE
        a = -ONE / (sign + dz)
        b = dx * dy * a
        sx, sy, sz = ONE + sign * dx * dx * a, sign * b, -sign * dx
        tx, ty, tz = b, sign + dy * dy * a, -dy
        cp, sp = sin_t * math.cos(phi), sin_t * math.sin(phi)
        return (cp * sx + sp * tx + cos_t * dx, cp * sy + sp * ty + cos_t * dy,
                cp * sz + sp * tz + cos_t * dz)

    @jit
    def fresnel(c, eta):
        """Walter eq. 22; eta = η_t/η_i; TIR (and NaN) gives 1."""
        c = abs(c)
        g2 = eta * eta - ONE + c * c
        if g2 <= ZERO:
            return ONE
        g = math.sqrt(g2)
        a = (g - c) / (g + c)
        b = (c * (g + c) - ONE) / (c * (g - c) + ONE)
        fr = HALF * a * a * (ONE + b * b)
        if fr != fr:
            return ONE
        return min(max(fr, ZERO), ONE)

    @jit
    def g1(vx, vy, vz, alpha):
        cz = abs(vz)
        den = cz + math.sqrt(cz * cz + alpha * alpha * (vx * vx + vy * vy))
        return TWO * cz / den if den > ZERO else ZERO

    @jit
    def sample_ggx(ix, iy, iz, alpha, eta, u0, u1, u2):
        """Walter section 5.3; (ix, iy, iz) points away from the surface, eta = n_below /
        n_above. Returns the new direction and the weight factor."""
        s = -ONE if iz < ZERO else ONE
        iz = iz * s
        if s < ZERO:
            eta = ONE / eta
        a2 = alpha * alpha
        den = ONE - u0 + a2 * u0
        st = math.sqrt(a2 * u0 / den)
        ct = math.sqrt((ONE - u0) / den)
        phi = TWO_PI * u1
        mx, my, mz = st * math.cos(phi), st * math.sin(phi), ct
        c = ix * mx + iy * my + iz * mz
        refl = u2 < fresnel(c, eta)
        if refl:
            c2 = TWO * c
            ox, oy, oz = c2 * mx - ix, c2 * my - iy, c2 * mz - iz
        else:
            inv = ONE / eta
            root = math.sqrt(max(ONE + inv * inv * (c * c - ONE), ZERO))
            f = inv * c - root
            ox, oy, oz = f * mx - inv * ix, f * my - inv * iy, f * mz - inv * iz
        wt = ZERO
        if iz > ZERO and c > ZERO and ((oz > ZERO) if refl else (oz < ZERO)):
            gi = g1(ix, iy, iz, alpha) if c * iz > ZERO else ZERO
            go = g1(ox, oy, oz, alpha) if (ox * mx + oy * my + oz * mz) * oz > ZERO else ZERO
            wt = c * gi * go / (iz * mz)
            if wt != wt:
                wt = ZERO
        return ox, oy, oz * s, wt

    @jit
    def smooth(wx, wy, wz, eta_side, u):
        """Smooth interface by a Fresnel choice; eta_side = η_t/η_i on the path's side."""
        if u < fresnel(abs(wz), eta_side):
            return wx, wy, -wz
        inv = ONE / eta_side
        cos_t = math.sqrt(max(ONE - inv * inv * (wx * wx + wy * wy), ZERO))
        return wx * inv, wy * inv, (-cos_t if wz < ZERO else cos_t)

    @jit
    def normalize(x, y, z):
        r = ONE / math.sqrt(x * x + y * y + z * z)
        return x * r, y * r, z * r

    @jit
    def roulette(weight, q_min, u):
        """(survives, new weight)."""
        q = min(max(weight, q_min), ONE)
        return u < q, weight / q

    @jit
    def tally_bin(x, y, z, order, T, P):
        """(θ, φ) bin of an exit direction on its side, and its order class."""
        x, y, z = float(x), float(y), float(z)
        side = 1 if z < 0.0 else 0
        theta = math.atan2(math.hypot(x, y), abs(z))
        tb = min(max(int(theta / (0.5 * math.pi) * T), 0), T - 1)
        ph = math.atan2(y, x)
        if ph < 0.0:
            ph += 2.0 * math.pi
        pb = min(max(int(ph / (2.0 * math.pi) * P), 0), P - 1)
        return side, (side * T + tb) * P + pb, min(order, 3)

    @jit
    def trace(s, wix, wiy, wiz, M, thick, sig_a, sig_s, hg_g, kinds, alpha, eta, T, P,
              max_events, rr_start, rr_min_q, S1, S2, flux, cnt):
        """One path from above, to its end; tallies into S1, S2, flux; counts into cnt
        (events, flights, scatters, GGX samples, smooth samples, roulette draws, random
        numbers, exits)."""
        region = 0
        z = ZERO
        wx, wy, wz = -wix, -wiy, -wiz
        weight = ONE
        bounces = 0
        events = 0
        n_ev = n_fl = n_sc = n_ggx = n_sm = n_rr = n_u = n_exit = 0
        for _ in range(max_events):
            n_ev += 1
            down = wz < ZERO
            scatter = False
            if region >= 1 and region <= M:
                n_fl += 1
                u = ZERO
                if sig_s[region] > ZERO:
                    s, u = rand(s)
                    n_u += 1
                scatter, z, att, horizontal = flight(z, wz, thick[region], sig_a[region],
                                                     sig_s[region], u)
                weight = weight * att
                if horizontal and not scatter:
                    break
            b = region if down else region - 1
            b = min(max(b, 0), M)
            if scatter:
                n_sc += 1
                s, u0 = rand(s)
                s, u1 = rand(s)
                n_u += 2
                nx, ny, nz = sample_hg(wx, wy, wz, hg_g[region], u0, u1)
            else:
                k = kinds[b]
                if k == 2:
                    n_ggx += 1
                    s, u0 = rand(s)
                    s, u1 = rand(s)
                    s, u2 = rand(s)
                    n_u += 3
                    nx, ny, nz, wt = sample_ggx(-wx, -wy, -wz, alpha[b], eta[b], u0, u1, u2)
                    weight = weight * wt
                elif k == 1:
                    n_sm += 1
                    s, u0 = rand(s)
                    n_u += 1
                    e = eta[b] if down else ONE / eta[b]
                    nx, ny, nz = smooth(wx, wy, wz, e, u0)
                else:
                    nx, ny, nz = wx, wy, wz
            nx, ny, nz = normalize(nx, ny, nz)
            up_new = nz > ZERO
            if not scatter:
                if up_new:
                    region = b
                    z = thick[b]
                else:
                    region = b + 1
                    z = ZERO
            if down and up_new and (scatter or b >= 1):
                bounces += 1
            if (region == 0 and up_new) or (region == M + 1 and not up_new):
                if weight > ZERO:
                    n_exit += 1
                    side, j, o = tally_bin(nx, ny, nz, bounces, T, P)
                    x = float(weight)
                    S1[o, j] += x
                    S2[o, j] += x * x
                    flux[side] += x
                break
            if not (weight > ZERO):
                break
            events += 1
            if events > rr_start:
                n_rr += 1
                s, u = rand(s)
                n_u += 1
                ok, w_new = roulette(weight, rr_min_q, u)
                if not ok:
                    break
                weight = w_new
            wx, wy, wz = nx, ny, nz
        cnt[0] += n_ev
        cnt[1] += n_fl
        cnt[2] += n_sc
        cnt[3] += n_ggx
        cnt[4] += n_sm
        cnt[5] += n_rr
        cnt[6] += n_u
        cnt[7] += n_exit

    @numba.njit(parallel=True, fastmath=False, error_model="numpy", cache=False)
    def run(n, seed, n_chunks, wi, M, thick, sig_a, sig_s, hg_g, kinds, alpha, eta, T, P,
            max_events, rr_start, rr_min_q):
        n_out = 2 * T * P
        S1 = np.zeros((n_chunks, 4, n_out))
        S2 = np.zeros((n_chunks, 4, n_out))
        flux = np.zeros((n_chunks, 2))
        cnt = np.zeros((n_chunks, 8), np.int64)
        per = (n + n_chunks - 1) // n_chunks
        key = mix64(U(seed) + GOLD)
        wix, wiy, wiz = F(wi[0]), F(wi[1]), F(wi[2])
        q_min = F(rr_min_q)
        th, sa, ss, gg = thick.astype(F), sig_a.astype(F), sig_s.astype(F), hg_g.astype(F)
        al, et = alpha.astype(F), eta.astype(F)
        for ch in numba.prange(n_chunks):
            lo = ch * per
            hi = min(n, lo + per)
            for p in range(lo, hi):
                s = mix64(key ^ (U(p) * M1))
                trace(s, wix, wiy, wiz, M, th, sa, ss, gg, kinds, al, et, T, P, max_events,
                      rr_start, q_min, S1[ch], S2[ch], flux[ch], cnt[ch])
        return S1.sum(axis=0), S2.sum(axis=0), flux.sum(axis=0), cnt.sum(axis=0)

    out = dict(run=run, rand=rand, mix64=mix64, flight=flight, sample_hg=sample_hg,
               fresnel=fresnel, g1=g1, sample_ggx=sample_ggx, smooth=smooth,
               normalize=normalize, roulette=roulette, tally_bin=tally_bin, trace=trace)
    _NUMBA[key] = out
    return out


COUNT_NAMES = ("events", "flights", "scatters", "ggx", "smooth", "roulette", "randoms", "exits")


def simulate_numba(regions, boundaries, wi, samples, theta_bins, phi_bins, seed=0,
                   max_events=MAX_EVENTS, rr_start=RR_START, rr_min_q=RR_MIN_Q,
                   dtype=np.float64, chunks=None):
    """The walk of ``numpy_walk.simulate_numpy`` in Numba. Returns (S1, S2, flux, counts):
    S1, S2 (4 orders, 2 sides × theta_bins × phi_bins) float64 sums of the exit weights and
    their squares, flux (2,) leaving up / down, counts a dict of :data:`COUNT_NAMES`."""
    if numba is None:
        raise ImportError(f"numba is not importable ({NUMBA_ERROR})")
    k = _numba_kernels(np.dtype(dtype).type)
    a = _scene_arrays(regions, boundaries)
    if chunks is None:  # enough chunks per thread to even out the path lengths
        chunks = max(1, min(16 * numba.get_num_threads(), samples // 256 or 1))
    S1, S2, flux, cnt = k["run"](int(samples), int(seed) & 0xFFFFFFFFFFFF, int(chunks),
                                 np.asarray(wi, float), a["M"], a["thick"], a["sig_a"],
                                 a["sig_s"], a["g"], a["kind"], a["alpha"], a["eta"],
                                 int(theta_bins), int(phi_bins), int(max_events), int(rr_start),
                                 float(rr_min_q))
    return S1, S2, flux, dict(zip(COUNT_NAMES, (int(c) for c in cnt)))


# --------------------------------------------------------------------------------------------
# Dr.Jit (LLVM backend): a wavefront of paths in one symbolic loop
# --------------------------------------------------------------------------------------------

try:
    import drjit as dr

    if not dr.has_backend(dr.JitBackend.LLVM):
        raise ImportError("Dr.Jit's LLVM backend is unavailable (no libLLVM found)")
except ImportError as exc:
    dr = None
    DRJIT_ERROR = str(exc)
else:
    DRJIT_ERROR = None


def _pick(idx, values, like):
    """values[idx] for a small Python list of constants, as a chain of selects (the constants
    become literals of the kernel)."""
    out = like(values[-1])
    for i in range(len(values) - 2, -1, -1):
        out = dr.select(idx == i, like(values[i]), out)
    return out


def _mix64(z):
    z = (z + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return z ^ (z >> 31)


def simulate_drjit(regions, boundaries, wi, samples, theta_bins, phi_bins, seed=0,
                   max_events=MAX_EVENTS, rr_start=RR_START, rr_min_q=RR_MIN_Q,
                   paths_per_lane=DRJIT_PATHS_PER_LANE):
    """The walk of ``numpy_walk.simulate_numpy`` on Dr.Jit's LLVM backend (float32 paths,
    float64 tallies). Returns (S1, S2, flux, counts) as :func:`simulate_numba` (counts: events,
    exits, the SIMD width and the iterations of the packets).

    ceil(samples / paths_per_lane) lanes; a lane whose path ends starts its next path (path
    regeneration: lane l traces paths l, l + L, l + 2L, ...) in the same iteration, so a packet
    of lanes stays busy until its lanes' last paths end, not its longest path. Each path's exit
    (direction, weight, order) is scattered to per-path arrays inside the loop and tallied
    into the bins after it. The seed enters as an opaque value, so a second call of the same
    size reuses the compiled kernel."""
    if dr is None:
        raise ImportError(f"drjit is not importable ({DRJIT_ERROR})")
    from drjit.llvm import Bool, Float, Float64, Int32, PCG32, UInt32, UInt64

    a = _scene_arrays(regions, boundaries)
    M = a["M"]
    kinds = set(int(k) for k in a["kind"])
    n = int(samples)
    thick, sig_a, sig_s = (list(map(float, a[k])) for k in ("thick", "sig_a", "sig_s"))
    hg_g, alpha, eta = list(map(float, a["g"])), list(map(float, a["alpha"])), \
        list(map(float, a["eta"]))
    kind_b = list(map(int, a["kind"]))

    lanes = -(-n // max(int(paths_per_lane), 1))
    rng = PCG32(lanes, dr.opaque(UInt64, _mix64(int(seed))),
                dr.opaque(UInt64, _mix64(~int(seed) & (2**64 - 1))))
    n_op = dr.opaque(Int32, n)
    lanes_op = dr.opaque(Int32, lanes)
    ex_x, ex_y, ex_z, ex_w = (dr.zeros(Float, n) for _ in range(4))
    ex_o = dr.zeros(Int32, n)
    ex_ok = dr.zeros(Bool, n)
    dr.make_opaque(ex_x, ex_y, ex_z, ex_w, ex_o, ex_ok)
    zero_i = dr.zeros(Int32, lanes)
    wi0, wi1, wi2 = -float(wi[0]), -float(wi[1]), -float(wi[2])
    state = (dr.arange(Int32, lanes), Int32(zero_i), dr.zeros(Float, lanes),
             dr.full(Float, wi0, lanes), dr.full(Float, wi1, lanes), dr.full(Float, wi2, lanes),
             dr.full(Float, 1.0, lanes), Int32(zero_i), Int32(zero_i), Int32(zero_i),
             Int32(zero_i), rng)

    def cond(p, region, z, wx, wy, wz, weight, bounces, events, steps, it, rng):
        return p < n_op

    def fresnel(c, e):
        c = dr.abs(c)
        g2 = e * e - 1.0 + c * c
        g = dr.sqrt(dr.maximum(g2, 0.0))
        a_ = (g - c) / (g + c)
        b_ = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        fr = 0.5 * a_ * a_ * (1.0 + b_ * b_)
        fr = dr.select(dr.isnan(fr), 1.0, dr.clip(fr, 0.0, 1.0))
        return dr.select(g2 <= 0.0, 1.0, fr)

    def g1(vx, vy, vz, al):
        cz = dr.abs(vz)
        den = cz + dr.sqrt(cz * cz + al * al * (vx * vx + vy * vy))
        return dr.select(den > 0.0, 2.0 * cz / den, 0.0)

    def body(p, region, z, wx, wy, wz, weight, bounces, events, steps, it, rng):
        it = it + 1
        steps = steps + 1
        down = wz < 0.0
        in_med = (region >= 1) & (region <= M)
        abs_wz = dr.abs(wz)
        horizontal = abs_wz < 1e-7
        th = _pick(region, thick, Float)
        ss = _pick(region, sig_s, Float)
        d_b = dr.select(down, th - z, z) / dr.select(horizontal, 1.0, abs_wz)
        d_b = dr.select(in_med, dr.maximum(d_b, 0.0), 0.0)
        u_f = rng.next_float32()
        t = -dr.log(1.0 - u_f) / dr.select(ss > 0.0, ss, 1.0)
        scatter = in_med & (ss > 0.0) & (t < d_b)
        d = dr.select(scatter, t, d_b)
        weight = weight * dr.select(in_med, dr.exp(-_pick(region, sig_a, Float) * d), 1.0)
        z = dr.select(in_med, z - d * wz, z)
        live = ~(in_med & horizontal & ~scatter)
        # one set of uniforms serves the phase sample or the interface sample (never both)
        u0, u1, u2 = rng.next_float32(), rng.next_float32(), rng.next_float32()
        s_phi, c_phi = dr.sincos(2.0 * math.pi * u1)
        # Henyey–Greenstein around d = w
        g = _pick(region, hg_g, Float)
        small = dr.abs(g) < 1e-3
        gs = dr.select(small, 0.5, g)
        sq = (1.0 - gs * gs) / (1.0 + gs - 2.0 * gs * u0)
        cos_t = dr.select(small, 1.0 - 2.0 * u0, (1.0 + gs * gs - sq * sq) / (2.0 * gs))
        cos_t = dr.clip(cos_t, -1.0, 1.0)
        sin_t = dr.sqrt(dr.maximum(1.0 - cos_t * cos_t, 0.0))
        sign = dr.select(wz >= 0.0, 1.0, -1.0)
        a_ = -1.0 / (sign + wz)
        b_ = wx * wy * a_
        sx, sy, sz = 1.0 + sign * wx * wx * a_, sign * b_, -sign * wx
        tx, ty, tz = b_, sign + wy * wy * a_, -wy
        cp, sp = sin_t * c_phi, sin_t * s_phi
        hx = cp * sx + sp * tx + cos_t * wx
        hy = cp * sy + sp * ty + cos_t * wy
        hz = cp * sz + sp * tz + cos_t * wz
        # the interface
        b = dr.clip(dr.select(down, region, region - 1), 0, M)
        nx, ny, nz, wt = Float(wx), Float(wy), Float(wz), Float(1.0)
        if 2 in kinds:  # GGX (Walter section 5.3), wi = -w
            al = _pick(b, alpha, Float)
            ix, iy, iz = -wx, -wy, -wz
            s = dr.select(iz < 0.0, -1.0, 1.0)
            iz = iz * s
            e = _pick(b, eta, Float)
            e = dr.select(s > 0.0, e, 1.0 / e)
            a2 = al * al
            den = 1.0 - u0 + a2 * u0
            st, ct = dr.sqrt(a2 * u0 / den), dr.sqrt((1.0 - u0) / den)
            mx, my, mz = st * c_phi, st * s_phi, ct
            c = ix * mx + iy * my + iz * mz
            refl = u2 < fresnel(c, e)
            inv = 1.0 / e
            root = dr.sqrt(dr.maximum(1.0 + inv * inv * (c * c - 1.0), 0.0))
            f = dr.select(refl, 2.0 * c, inv * c - root)
            k_ = dr.select(refl, 1.0, inv)
            ox, oy, oz = f * mx - k_ * ix, f * my - k_ * iy, f * mz - k_ * iz
            valid = (iz > 0.0) & (c > 0.0) & dr.select(refl, oz > 0.0, oz < 0.0)
            gi = dr.select(c * iz > 0.0, g1(ix, iy, iz, al), 0.0)
            go = dr.select((ox * mx + oy * my + oz * mz) * oz > 0.0, g1(ox, oy, oz, al), 0.0)
            w_g = c * gi * go / (iz * mz)
            w_g = dr.select(valid & ~dr.isnan(w_g), w_g, 0.0)
            is_g = _pick(b, [1.0 if k == 2 else 0.0 for k in kind_b], Float) > 0.0
            nx, ny, nz = dr.select(is_g, ox, nx), dr.select(is_g, oy, ny), \
                dr.select(is_g, oz * s, nz)
            wt = dr.select(is_g, w_g, wt)
        if 1 in kinds:  # smooth
            e = _pick(b, eta, Float)
            e = dr.select(down, e, 1.0 / e)
            r_ = u2 < fresnel(dr.abs(wz), e)
            inv = 1.0 / e
            cos_tt = dr.sqrt(dr.maximum(1.0 - inv * inv * (wx * wx + wy * wy), 0.0))
            is_s = _pick(b, [1.0 if k == 1 else 0.0 for k in kind_b], Float) > 0.0
            nx = dr.select(is_s, dr.select(r_, wx, wx * inv), nx)
            ny = dr.select(is_s, dr.select(r_, wy, wy * inv), ny)
            nz = dr.select(is_s, dr.select(r_, -wz, dr.select(down, -cos_tt, cos_tt)), nz)
        nx, ny, nz = dr.select(scatter, hx, nx), dr.select(scatter, hy, ny), \
            dr.select(scatter, hz, nz)
        weight = dr.select(scatter, weight, weight * wt)
        r = dr.rsqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx * r, ny * r, nz * r
        up_new = nz > 0.0
        hit = live & ~scatter
        region = dr.select(hit, dr.select(up_new, b, b + 1), region)
        z = dr.select(hit, dr.select(up_new, _pick(b, thick, Float), 0.0), z)
        bounces = bounces + dr.select(live & down & up_new & (scatter | (b >= 1)), 1, 0)
        leaving = live & (((region == 0) & up_new) | ((region == M + 1) & ~up_new))
        ok = leaving & (weight > 0.0)
        dr.scatter(ex_x, nx, p, ok)
        dr.scatter(ex_y, ny, p, ok)
        dr.scatter(ex_z, nz, p, ok)
        dr.scatter(ex_w, weight, p, ok)
        dr.scatter(ex_o, bounces, p, ok)
        dr.scatter(ex_ok, True, p, ok)
        live = live & ~leaving & (weight > 0.0)
        events = events + dr.select(live, 1, 0)
        q = dr.clip(weight, rr_min_q, 1.0)
        play = live & (events > rr_start)
        survive = rng.next_float32() < q
        live = live & (~play | survive)
        weight = dr.select(play & survive, weight / q, weight)
        # a path that ended (or reached the event cap: dropped) gives its lane the next path
        ended = ~live | (steps >= max_events)
        p = dr.select(ended, p + lanes_op, p)
        region = dr.select(ended, 0, region)
        z = dr.select(ended, 0.0, z)
        nx, ny, nz = dr.select(ended, wi0, nx), dr.select(ended, wi1, ny), \
            dr.select(ended, wi2, nz)
        weight = dr.select(ended, 1.0, weight)
        bounces = dr.select(ended, 0, bounces)
        events = dr.select(ended, 0, events)
        steps = dr.select(ended, 0, steps)
        return p, region, z, nx, ny, nz, weight, bounces, events, steps, it, rng

    it = dr.while_loop(state, cond, body, mode="symbolic")[10]
    # tally the exits
    x, y, zz = Float64(ex_x), Float64(ex_y), Float64(ex_z)
    bounces, weight, ok = ex_o, ex_w, ex_ok
    side = dr.select(zz < 0.0, 1, 0)
    theta = dr.atan2(dr.sqrt(x * x + y * y), dr.abs(zz))
    tb = dr.clip(Int32(theta / (0.5 * math.pi) * theta_bins), 0, theta_bins - 1)
    ph = dr.atan2(y, x)
    ph = dr.select(ph < 0.0, ph + 2.0 * math.pi, ph)
    pb = dr.clip(Int32(ph / (2.0 * math.pi) * phi_bins), 0, phi_bins - 1)
    n_out = 2 * theta_bins * phi_bins
    o = dr.minimum(bounces, 3)
    idx = UInt32(o * n_out + (side * theta_bins + tb) * phi_bins + pb)
    xw = Float64(weight)
    S1, S2, flux = dr.zeros(Float64, 4 * n_out), dr.zeros(Float64, 4 * n_out), \
        dr.zeros(Float64, 2)
    dr.scatter_reduce(dr.ReduceOp.Add, S1, xw, idx, ok)
    dr.scatter_reduce(dr.ReduceOp.Add, S2, xw * xw, idx, ok)
    dr.scatter_reduce(dr.ReduceOp.Add, flux, xw, UInt32(side), ok)
    dr.eval(S1, S2, flux, it)
    it = it.numpy().astype(np.int64)
    width = llvm_width()  # the loop runs per packet of this many lanes, until all are done
    packets = np.pad(it, (0, -len(it) % width)).reshape(-1, width).max(axis=1)
    return (S1.numpy().reshape(4, n_out), S2.numpy().reshape(4, n_out), flux.numpy(),
            {"events": int(it.sum()), "exits": int(dr.count(ok)[0]), "width": width,
             "packet_iterations": int(packets.sum())})


def llvm_width():
    """The SIMD width Dr.Jit's LLVM backend compiles for on this CPU (float32 lanes): 16 with
    AVX-512, 8 with AVX / AVX2, else 4."""
    flags = ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = line.split()
                    break
    except OSError:
        pass
    return 16 if "avx512f" in flags else 8 if "avx" in flags else 4


# --------------------------------------------------------------------------------------------
# NumPy with an event count
# --------------------------------------------------------------------------------------------

class _CountingRng:
    """np.random.Generator whose ``random((n, 8))`` calls (one per event, n = paths alive)
    are summed: the NumPy walk's number of events."""

    def __init__(self, rng):
        self._rng, self.events = rng, 0

    def random(self, size):
        self.events += size[0]
        return self._rng.random(size)


class _NumpyProxy:
    def __init__(self):
        self.last = None
        proxy = self

        class _Random:
            def __getattr__(self, name):
                return getattr(np.random, name)

            @staticmethod
            def default_rng(seed=None):
                proxy.last = _CountingRng(np.random.default_rng(seed))
                return proxy.last

        self.random = _Random()

    def __getattr__(self, name):
        return getattr(np, name)


def simulate_numpy(regions, boundaries, wi, samples, theta_bins, phi_bins, seed=0):
    """``numpy_walk.simulate_numpy`` (a private copy of the module whose ``np.random`` counts
    the events; the same random numbers, the same result). Returns (S1, S2, flux, counts)."""
    spec = importlib.util.spec_from_file_location("_numpy_walk_counted",
                                                  os.path.join(HERE, "numpy_walk.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.np = proxy = _NumpyProxy()
    S1, S2, flux = mod.simulate_numpy(regions, boundaries, wi, samples, theta_bins, phi_bins,
                                      seed=seed, max_events=MAX_EVENTS, rr_start=RR_START,
                                      rr_min_q=RR_MIN_Q)
    return S1, S2, flux, {"events": proxy.last.events}


# --------------------------------------------------------------------------------------------
# Agreement
# --------------------------------------------------------------------------------------------

def agreement(a, b, n_a, n_b, theta_bins=T_BINS, phi_bins=P_BINS, min_paths=100.0):
    """Statistical agreement of two runs (S1, S2, flux, ...) of n_a and n_b paths: z of the
    reflected and transmitted flux (each path leaves at most once, so a side's variance comes
    from the sums of squares of its bins), and χ² over the (all-order) bins where both runs
    expect >= ``min_paths`` paths (weight sums, weights are O(1)). Returns a dict with z
    (2,), chi2, dof, p and ok."""
    from scipy import stats

    half = theta_bins * phi_bins

    def stats_of(run, n):
        S1, S2 = run[0].sum(0), run[1].sum(0)
        mean = S1 / n
        var = np.maximum(S2 / n - mean ** 2, 0.0) / max(n - 1.0, 1.0)
        fl = np.array([S1[:half].sum(), S1[half:].sum()]) / n
        f2 = np.array([S2[:half].sum(), S2[half:].sum()]) / n
        fvar = np.maximum(f2 - fl ** 2, 0.0) / max(n - 1.0, 1.0)
        return mean, var, fl, fvar, S1

    ma, va, fa, fva, Sa = stats_of(a, float(n_a))
    mb, vb, fb, fvb, Sb = stats_of(b, float(n_b))
    z = (fa - fb) / np.sqrt(fva + fvb)
    m = (Sa >= min_paths) & (Sb >= min_paths) & (va + vb > 0)
    chi2 = float(np.sum((ma[m] - mb[m]) ** 2 / (va[m] + vb[m])))
    dof = int(m.sum())
    p = float(stats.chi2.sf(chi2, dof)) if dof else float("nan")
    return {"z": z, "flux_a": fa, "flux_b": fb, "chi2": chi2, "dof": dof, "p": p,
            "ok": bool(np.all(np.abs(z) < 4.0) and dof > 0 and p > 1e-3)}


# --------------------------------------------------------------------------------------------
# The limit: operations per event from the Numba kernel's source
# --------------------------------------------------------------------------------------------

#: Cost of one operation in float32 FP-pipe instruction slots (one slot = one SIMD instruction
#: on one FMA/FP pipe for 8 lanes; a vectorized implementation is assumed, as Dr.Jit / SLEEF
#: generate). add, sub, mul, compare, min, max, abs, negation, select: 1 (a mul + add pair
#: counts 2: without fast math there is no FMA contraction). Division and square root: 4
#: (Zen 4's divider takes one 256-bit vdivps / vsqrtps every ~3.5-5 cycles beside the two FMA
#: pipes). Transcendentals, as the instruction counts of their float32 polynomial versions
#: (range reduction, polynomial, scaling, special cases): exp 15, log / log1p 20, sin 20, cos
#: 20, atan2 35, hypot 6. Integer ops of the random number generator: 1 each, a 64-bit
#: multiply 3 (vpmullq is several uops). int <-> float conversion: 1.
WEIGHTS = {"add": 1, "mul": 1, "cmp": 1, "minmax": 1, "abs": 1, "neg": 1, "div": 4,
           "sqrt": 4, "exp": 15, "log": 20, "sin": 20, "cos": 20, "atan2": 35, "hypot": 6,
           "int": 1, "imul": 3, "cvt": 1}

_CALLS = {"sqrt": "sqrt", "exp": "exp", "log1p": "log", "log": "log", "sin": "sin",
          "cos": "cos", "atan2": "atan2", "hypot": "hypot", "min": "minmax", "max": "minmax",
          "abs": "abs", "F": "cvt", "float": "cvt", "int": "cvt"}


def _count_ops(fn, helpers, integer=False):
    """Weighted operation count of a kernel helper along its costliest branch: BinOps,
    comparisons, negations and calls (math functions by :data:`WEIGHTS`, other helpers of the
    kernel recursively). Returns (cost, Counter of operation kinds on that branch)."""
    src = textwrap.dedent(inspect.getsource(getattr(fn, "py_func", fn)))
    tree = ast.parse(src).body[0]

    def cost(counts):
        return sum(WEIGHTS[k] * v for k, v in counts.items())

    def add(c1, c2):
        out = dict(c1)
        for k, v in c2.items():
            out[k] = out.get(k, 0) + v
        return out

    def expr(node):
        c = {}
        if isinstance(node, ast.BinOp):
            op = type(node.op).__name__
            if integer and op == "Mult":
                kind = "imul"
            elif integer or op in ("BitXor", "BitAnd", "BitOr", "RShift", "LShift", "FloorDiv"):
                kind = "int"
            else:
                kind = {"Add": "add", "Sub": "add", "Mult": "mul", "Div": "div"}.get(op, "add")
            c = add(c, {kind: 1})
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            if not isinstance(node.operand, ast.Constant):
                c = add(c, {"neg": 1})
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            pass
        elif isinstance(node, ast.Compare):
            c = add(c, {"cmp": len(node.ops)})
        elif isinstance(node, ast.IfExp):
            c = add(c, expr(node.test))
            c = add(c, {"cmp": 1})  # the select
            a, b = expr(node.body), expr(node.orelse)
            return add(c, a if cost(a) >= cost(b) else b)
        elif isinstance(node, ast.Call):
            name = node.func.attr if isinstance(node.func, ast.Attribute) else \
                getattr(node.func, "id", "")
            if name in helpers:
                c = add(c, helpers[name])
            elif name in _CALLS:
                c = add(c, {_CALLS[name]: 1})
            for arg in node.args:
                c = add(c, expr(arg))
            return c
        for child in ast.iter_child_nodes(node):
            c = add(c, expr(child))
        return c

    def block(stmts):
        c = {}
        for st in stmts:
            if isinstance(st, ast.If):
                c = add(c, expr(st.test))
                a, b = block(st.body), block(st.orelse)
                c = add(c, a if cost(a) >= cost(b) else b)
            elif isinstance(st, ast.Return) and st is not stmts[-1]:
                c = add(c, expr(st))
            elif isinstance(st, (ast.Expr,)) and isinstance(st.value, ast.Constant):
                continue  # docstring
            else:
                c = add(c, expr(st))
        return c

    counts = block(tree.body)
    return cost(counts), counts


def kernel_cost(dtype=np.float32):
    """Per-helper operation counts of the Numba kernel: {name: (slots, counts)}."""
    k = _numba_kernels(np.dtype(dtype).type)
    helpers = {}
    out = {}
    for name in ("rand", "fresnel", "g1", "flight", "sample_hg", "sample_ggx", "smooth",
                 "normalize", "roulette", "tally_bin"):
        c, counts = _count_ops(k[name], helpers, integer=(name == "rand"))
        helpers[name] = counts
        out[name] = (c, counts)
    return out


def cpu_peak():
    """(cores, GHz, peak float32 lane-slots per second): cores × clock × 8 float32 lanes (one
    256-bit vector; Zen 4 runs AVX-512 as two 256-bit halves) × 2 FMA pipes. Clock: /proc/cpuinfo
    'cpu MHz' (under KVM the nominal TSC clock; boost may run higher)."""
    cores = os.cpu_count() or 1
    mhz = None
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("cpu MHz"):
                    mhz = float(line.split(":")[1])
                    break
    except OSError:
        pass
    ghz = (mhz or 2600.0) / 1000.0
    return cores, ghz, cores * ghz * 1e9 * 8 * 2


BOOKKEEPING = 12  # slots per event: region tests, boundary index, bounce order, exit tests


def limit_analysis(counts, results):
    """Slots per event from the kernel's source and the measured event mix (``counts`` of a
    Numba run); the ideal ns of CPU per event at peak and where each engine of ``results``
    sits. Returns (markdown text, slots per event, ideal ns of CPU per event)."""
    costs = kernel_cost(np.float32)
    ev = counts["events"]
    mix = {
        "flight": counts["flights"] / ev,
        "sample_hg": counts["scatters"] / ev,
        "sample_ggx": counts["ggx"] / ev,
        "smooth": counts["smooth"] / ev,
        "roulette": counts["roulette"] / ev,
        "rand": counts["randoms"] / ev,
        "normalize": 1.0,
        "tally_bin": counts["exits"] / ev,
    }
    lines = ["", "## The limit", "",
             "Operations of each helper of the Numba kernel (counted from its source along the "
             "costliest branch, helpers called inside included), in float32 FP-pipe slots "
             "(weights: " + ", ".join(f"{k} {v}" for k, v in WEIGHTS.items()) + "), times how "
             "often one event runs it (measured):", "",
             "| helper | slots | operations | per event | slots/event |", "|---|---|---|---|---|"]
    total = 0.0
    for name, per in mix.items():
        c, ops = costs[name]
        ops_s = ", ".join(f"{k} {v}" for k, v in sorted(ops.items()))
        total += c * per
        lines.append(f"| {name} | {c} | {ops_s} | {per:.3f} | {c * per:.1f} |")
    total += BOOKKEEPING
    lines.append(f"| bookkeeping (region / bounce / exit tests; estimated) | {BOOKKEEPING} | | 1"
                 f" | {BOOKKEEPING:.1f} |")
    lines.append(f"| **one event** | | | | **{total:.0f}** |")
    # the event's slots by kind of operation
    groups = {"add / mul / compare / select": ("add", "mul", "cmp", "minmax", "abs", "neg",
                                                "cvt"),
              "division / square root": ("div", "sqrt"),
              "transcendentals (log, exp, sin, cos, atan2, hypot)": ("exp", "log", "sin", "cos",
                                                                     "atan2", "hypot"),
              "random numbers (integer)": ("int", "imul")}
    by = dict.fromkeys(groups, 0.0)
    for name, per in mix.items():
        for kind, v in costs[name][1].items():
            for g, kinds in groups.items():
                if kind in kinds and not (name == "rand" and kind == "cvt"):
                    by[g] += WEIGHTS[kind] * v * per
        if name == "rand":
            by["random numbers (integer)"] += WEIGHTS["cvt"] * per
    by["add / mul / compare / select"] += BOOKKEEPING
    lines += ["", "By kind: " + "; ".join(f"{g} {v:.0f} ({v / total:.0%})"
                                           for g, v in by.items()) + "."]
    cores, ghz, peak = cpu_peak()
    per_core = peak / cores
    ideal = total / per_core * 1e9  # ns of CPU per event at the SIMD peak
    ideal_scalar = total / (per_core / 8) * 1e9
    lines += ["", f"Peak: {cores} cores × {ghz:.3f} GHz × 8 float32 lanes × 2 FMA pipes = "
              f"{peak / 1e9:.1f} G slots/s ({2 * peak / 1e9:.0f} GFLOP/s counting an FMA as 2)."
              f" Ideal: {total:.0f} slots / (8 × 2 × {ghz:.3f} GHz) = **{ideal:.2f} ns of CPU "
              f"per event** ({ideal / cores:.2f} ns of wall time on {cores} cores). Scalar code (one lane, as Numba's per-path loop compiles) is bounded "
              f"at {ideal_scalar:.1f} ns of CPU per event.", ""]
    lines += ["| engine | ns CPU/event | × ideal | fraction of SIMD peak | executed slots per "
              "event | executed work, fraction of peak |", "|---|---|---|---|---|---|"]
    # Dr.Jit's lanes run every branch: flight, phase and interface samples, 5 random numbers,
    # roulette, plus the selects of path regeneration (~10 slots)
    exec_lane = (costs["flight"][0] + costs["sample_hg"][0] + costs["sample_ggx"][0]
                 + costs["normalize"][0] + costs["roulette"][0] + 5 * costs["rand"][0]
                 + BOOKKEEPING + 10 + (costs["smooth"][0] if counts["smooth"] else 0))
    for name, r in results.items():
        ns = r["ns_event"]
        executed, frac_exec = "", ""
        info = r["out"][3] if isinstance(r["out"], tuple) and not name.startswith("fitlab") \
            else {}
        if "packet_iterations" in info:
            # every lane of a packet runs every branch until the packet's last path ends
            ex = exec_lane * info["packet_iterations"] * info["width"] / info["events"]
            executed = (f"{ex:.0f} ({exec_lane:.0f} per lane-iteration, lanes "
                        f"{info['events'] / (info['packet_iterations'] * info['width']):.0%} busy)")
            frac_exec = f"{ex / per_core * 1e9 / ns:.0%}"
        elif name.startswith("numba"):
            executed = f"{total:.0f} (scalar: 1 lane of 8)"
            frac_exec = f"{ideal / ns:.1%} ({ideal_scalar / ns:.0%} of the scalar bound)"
        lines.append(f"| {name} | {ns:.1f} | {ns / ideal:.0f}x | {ideal / ns:.1%} | {executed} | "
                     f"{frac_exec} |")
    return "\n".join(lines), total, ideal


# --------------------------------------------------------------------------------------------
# The benchmark
# --------------------------------------------------------------------------------------------

def _timed(fn, *args, **kw):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0, time.process_time() - c0


def run_engine(name, n, seed, repeat=1):
    """Warm runs of one engine: {wall, cpu, compile, out, events} of the run with the least
    CPU time of ``repeat`` runs (same seed, same result). Compilation: the first call (same
    size, another seed) less the warm one; NumPy compiles nothing and runs cold."""
    args = (REGIONS, BOUNDARIES, WI, n, T_BINS, P_BINS)
    if name == "numpy":
        fn, kw, first = simulate_numpy, {}, None
    elif name in ("fitlab", "fitlab_nee"):
        from fitlab.simulate import simulate

        bs = _load("bench_simulate")
        scene = bs.throughput_scene() if name == "fitlab" else bs.arc_scene("point")

        def fn(*_, seed):
            return simulate(scene, n, seed=seed, device="cpu")

        kw = {}
    elif name.startswith("numba"):
        fn = simulate_numba
        kw = {"dtype": np.float32 if name == "numba32" else np.float64}
    elif name == "drjit":
        fn, kw = simulate_drjit, {}
    else:
        raise ValueError(name)
    if name != "numpy":
        first = _timed(fn, *args, seed=seed + 1000, **kw)[1]
    best = None
    for _ in range(max(int(repeat), 1)):
        out, wall, cpu = _timed(fn, *args, seed=seed, **kw)
        if best is None or cpu < best[2]:
            best = (out, wall, cpu)
    out, wall, cpu = best
    events = int(out.events) if name.startswith("fitlab") else out[3]["events"]
    return {"wall": wall, "cpu": cpu, "compile": 0.0 if first is None else max(first - wall, 0.0),
            "out": out, "events": events}


def _fitlab_as_sums(res, n):
    """fitlab's result as (S1, S2, flux) sums over bins in numpy_walk's layout (the
    hemisphere rows' tallies), for the agreement check."""
    from fitlab.simulate.detectors import hemisphere_rows

    rows = hemisphere_rows(T_BINS, P_BINS, ("reflection", "transmission"))
    n_out = 2 * T_BINS * P_BINS
    mean = np.zeros(n_out)
    sig = np.zeros(n_out)
    mean[rows.tally] = np.asarray(res.value)[:, 0] * rows.cos_solid_angle
    sig[rows.tally] = np.asarray(res.sigma)[:, 0] * rows.cos_solid_angle
    S1 = mean * n
    S2 = (sig ** 2 * (n - 1.0) + mean ** 2) * n
    return S1[None], S2[None], None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=int, default=1 << 19)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--engines", default="numpy,fitlab,fitlab_nee,numba64,numba32,drjit")
    ap.add_argument("--repeat", type=int, default=3,
                    help="warm runs per engine; the one with the least CPU time is reported")
    args = ap.parse_args(argv)
    n = args.paths
    names = [e.strip() for e in args.engines.split(",") if e.strip()]
    if "numpy" not in names:
        names.insert(0, "numpy")
    _, ghz, _ = cpu_peak()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs at "
          f"{ghz:.3f} GHz, python {platform.python_version()}, numpy {np.__version__}, "
          f"numba {getattr(numba, '__version__', '-')} ({NUMBA_ERROR or 'ok'}), "
          f"drjit {getattr(dr, '__version__', '-')} ({DRJIT_ERROR or 'ok'}), load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    print(f"scene: HG slab (g 0.5, σa 0.2, σs 0.8, thickness 1, n 1.5) between GGX 0.2 / 0.3, "
          f"light at {THETA_I:g}°, {n} paths, both sides, {T_BINS} × {P_BINS} bins, "
          f"all orders, roulette after {RR_START} events, at most {MAX_EVENTS} events",
          flush=True)
    results = {}
    ok_all = True
    for name in names:
        if name.startswith("numba") and numba is None:
            print(f"{name}: skipped, numba is not importable ({NUMBA_ERROR})")
            continue
        if name == "drjit" and dr is None:
            print(f"{name}: skipped, drjit is not importable ({DRJIT_ERROR})")
            continue
        r = run_engine(name, n, args.seed, args.repeat)
        if name in ("numpy", "fitlab_nee"):
            agree = None
        elif name == "fitlab":
            agree = agreement(_fitlab_as_sums(r["out"], n), results["numpy"]["out"], n, n)
        else:
            agree = agreement(r["out"], results["numpy"]["out"], n, n)
        r["agree"] = agree
        r["ns_event"] = r["cpu"] / r["events"] * 1e9
        r["events_per_path"] = r["events"] / n
        results[name] = r
        msg = (f"{name}: {r['wall']:.3f} s wall, {r['cpu']:.3f} s CPU, {n / r['wall']:,.0f} "
               f"paths/s, {r['events'] / n:.3f} events/path, {r['ns_event']:.1f} ns CPU/event"
               f" (compile {r['compile']:.2f} s, excluded)")
        if agree is not None:
            msg += (f"; vs NumPy: z = {agree['z'][0]:+.2f} / {agree['z'][1]:+.2f}, χ² = "
                    f"{agree['chi2']:.1f} over {agree['dof']} bins, p = {agree['p']:.3f} "
                    f"-> {'agrees' if agree['ok'] else 'DISAGREES'}")
            ok_all &= agree["ok"]
        print(msg, flush=True)
    base = results["numpy"]
    print()
    print("| engine | compile s | wall s | CPU s | paths/s | events/path | ns CPU/event | "
          "wall vs NumPy | CPU vs NumPy | agrees with NumPy |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        a = r["agree"]
        agree_s = "(reference)" if name == "numpy" else "n/a (point estimates)" if a is None else (
            f"{'yes' if a['ok'] else 'NO'} (z {a['z'][0]:+.1f}/{a['z'][1]:+.1f}, "
            f"p {a['p']:.2f})")
        print(f"| {name} | {r['compile']:.2f} | {r['wall']:.3f} | {r['cpu']:.3f} | "
              f"{n / r['wall']:,.0f} | {r['events'] / n:.3f} | {r['ns_event']:.1f} | "
              f"{base['wall'] / r['wall']:.1f}x | {base['cpu'] / r['cpu']:.1f}x | {agree_s} |")
    fl_rows = [(k, d) for k, d in (("fitlab", "plain walk (bins)"),
                                   ("fitlab_nee", "full-feature kernel (NEE toward 41 arc "
                                                  "directions)")) if k in results]
    if fl_rows:
        print(f"\nfitlab's CPU per event (process_time over events, summed over cores) against "
              f"the limit of benchmarks/README.md, {LIMIT_NS:g} ns (target for the plain walk: "
              f"<= {LIMIT_FACTOR:g}x = {LIMIT_FACTOR * LIMIT_NS:.1f} ns):")
        for k, desc in fl_rows:
            r = results[k]
            ratio = r["ns_event"] / LIMIT_NS
            verdict = (("PASS" if ratio <= LIMIT_FACTOR else "MISS") if k == "fitlab"
                       else "(beside it, no target)")
            print(f"  {k:<11} {desc:<56} {r['ns_event']:7.1f} ns/event  {ratio:5.2f}x the "
                  f"limit  {verdict}  ({r['events'] / n:.3f} events/path, {r['cpu']:.3f} CPU-s, "
                  f"{r['wall']:.3f} s wall)")
    if numba is not None:
        counts = simulate_numba(REGIONS, BOUNDARIES, WI, n, T_BINS, P_BINS, seed=args.seed,
                                dtype=np.float32)[3]
        text, _, _ = limit_analysis(counts, results)
        print(text)
        print("\nevent mix (Numba float32 run): " + ", ".join(
            f"{k} {v / counts['events']:.3f}" for k, v in counts.items() if k != "events")
            + " per event")
    else:
        print("\n(the limit analysis counts the Numba kernel's operations: it needs numba)")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("agreement:", "OK" if ok_all else "FAILED")
    return 0 if ok_all else 1


if __name__ == "__main__":
    sys.exit(main())
