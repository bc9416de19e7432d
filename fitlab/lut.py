"""Lookup tables for shaders: pure functions that bake 1D/2D/3D tables of BSDF quantities and
return them with everything a shader author needs to read them back (axes, mappings, texel
convention, model, parameters, measured accuracy). No file I/O here: ``fitlab.export.exr`` writes
a :class:`Table`, ``fitlab.export.shader`` writes the GLSL/HLSL that reads it.

Table kinds (:data:`KINDS`):

``D``                 π α² D(cos θh; α) over (cos θh, α) for one microfacet distribution (Walter
                      eqs 25, 30, 33); D = value / (π α²). The scale keeps the peak near 1 (half
                      floats overflow at D > 65504, i.e. GGX α < 2.2e-3) and makes the α direction
                      smooth. Elek 2010 section 3.1: 512 × 512, non-linear u⁸ axis for the
                      near-specular part; α on a log axis by default (Elek's linear α axis is an
                      option: measured 17× larger RMS error at 512², benchmarks/lut_accuracy.py).
``fresnel``           F(cos θ) for one material (Elek 2010 section 3.1, 128 samples): a conductor
                      (n, k) per channel (presets copper / chromium / cuprite, Elek appendix A) or
                      a dielectric η (channels for incidence from outside and from inside).
``albedo_conductor``  directional albedo E(μ, α) = ∫ f cos θo dωo of the microfacet BRDF with
                      F = 1 (the energy-compensation table of Kulla & Conty 2017) and, in a
                      second channel, the average albedo E_avg(α) = 2 ∫ E(μ) μ dμ.
``albedo_dielectric`` the same for a rough dielectric interface over (μ, α, η): reflection and
                      transmission, for incidence from outside (relative index η) and from inside
                      (1/η), and their averages; η slices are stacked along the height.
``dfg``               the split-sum DFG table (Karis 2013): scale and bias with
                      ∫ f cos θo dωo = F0 · scale + bias under Schlick's Fresnel.
``model``             a registry model's (or a fit's) own BRDF f(wi, wo) over (cos θh, cos θd)
                      in Rusinkiewicz's half/difference parameterization at φd = 90°.

Grid and texel convention (every axis): an axis with N samples stores the value at the axis
coordinate x_i = map(t_i) with t_i = i / (N - 1), i = 0 .. N-1: the first and last texel centres
sit exactly at the ends of the range. A shader turns a coordinate x into t = map⁻¹(x) (clamped to
[0, 1]) and into the texture coordinate s = (t (N - 1) + 0.5) / N, so that hardware bilinear
filtering interpolates between the stored samples. Mappings (:data:`MAPPINGS`): ``linear``,
``u8`` (Elek's x = hi - (hi - lo) t⁸: dense near hi), ``sqrt`` (x = lo + (hi - lo) t²: dense
near lo) and ``log`` (x = lo (hi/lo)^t).

Integrals (albedo, DFG) use deterministic quadrature (``fitlab.quadrature``), never Monte
Carlo: over the microfacet normal in the warped coordinates of the distribution's sampling
(Walter eqs 28 / 35), where the integrand is Walter's sample weight (eq. 41), with Gauss–Legendre
panels (smoothed ends) in θm and φm split at the analytic breakpoints (horizon of the reflected /
refracted direction, facet facing away, total internal reflection, and where these appear in φm). Every table
stores the values of the higher of two quadrature orders and, as its error estimate, the
difference to the lower one. Accuracy against direct evaluation (bilinear lookup of the stored,
rounded values at random points vs the model or a fresh quadrature there) is measured for every
table and stored in it (:func:`measure_accuracy`).
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import fitlab
from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS, CONDUCTOR_PRESETS, fresnel_dielectric_Walter2007
from fitlab.frame import reflect, refract
from fitlab.microfacet import get_distribution
from fitlab.numerics import ALPHA_MIN
from fitlab.quadrature import gauss_legendre, gauss_legendre_panels

#: Schema of the table description (written to EXR headers).
SCHEMA = "fitlab-lut"
SCHEMA_VERSION = 1

#: Allowed number of samples along one axis.
SIZE_MIN, SIZE_MAX = 2, 4096
#: Largest number of samples in one table (W × H, slices included).
TEXELS_MAX = 4096 * 4096
#: Largest finite half float.
HALF_MAX = 65504.0
#: Relative errors are |a - b| / max(|b|, REL_FLOOR × the channel's largest |value|).
REL_FLOOR = 1e-3
#: μ below this is evaluated at MU_MIN (the albedo integrands have a finite limit at μ → 0).
MU_MIN = 1e-7


# --------------------------------------------------------------------------------------------
# Axes and mappings
# --------------------------------------------------------------------------------------------


class Mapping(NamedTuple):
    name: str
    #: x(t, lo, hi) for t in [0, 1]
    to_x: Callable
    #: t(x, lo, hi), the inverse (the shader computes this)
    to_t: Callable
    formula: str
    breaks_down: str


def _t_linear(x, lo, hi):
    return (x - lo) / (hi - lo)


def _t_u8(x, lo, hi):
    return np.sqrt(np.sqrt(np.sqrt(np.maximum((hi - x) / (hi - lo), 0.0))))


def _t_sqrt(x, lo, hi):
    return np.sqrt(np.maximum((x - lo) / (hi - lo), 0.0))


def _t_log(x, lo, hi):
    return np.log(np.maximum(x, lo) / lo) / np.log(hi / lo)


MAPPINGS = {
    "linear": Mapping(
        "linear", lambda t, lo, hi: lo + (hi - lo) * t, _t_linear, "x = lo + (hi - lo) t",
        "features narrower than (hi - lo)/(N - 1) are smeared: a D lobe of width α along "
        "cos θh (width ≈ α²/2) is unresolved for α below about sqrt(2/(N - 1))"),
    "u8": Mapping(
        "u8", lambda t, lo, hi: hi - (hi - lo) * t**8, _t_u8, "x = hi - (hi - lo) t^8 (Elek 2010)",
        "dense near hi, sparse near lo (the last texel spans 1 - (1 - 1/(N-1))^8 ≈ 8/(N-1) of the "
        "range); in float32 the shader's hi - x (1 - cos θh) has no digits below 6e-8, so lobes "
        "narrower than α ≈ 3e-4 are quantized by the input itself, not the table"),
    "sqrt": Mapping(
        "sqrt", lambda t, lo, hi: lo + (hi - lo) * t**2, _t_sqrt, "x = lo + (hi - lo) t^2",
        "dense near lo; the first interval spans (hi - lo)/(N - 1)^2, so relative steps are "
        "large just above lo when lo is tiny"),
    "log": Mapping(
        "log", lambda t, lo, hi: lo * (hi / lo) ** t, _t_log, "x = lo (hi/lo)^t",
        "equal ratios between samples; needs 0 < lo < hi; coarse near hi when the range spans "
        "many decades"),
}


class Axis(NamedTuple):
    """One table axis: ``size`` samples of coordinate ``name`` over [lo, hi] at
    x_i = mapping(i / (size - 1))."""

    name: str
    lo: float
    hi: float
    size: int
    mapping: str
    description: str

    def nodes(self) -> np.ndarray:
        t = np.arange(self.size) / (self.size - 1)
        x = MAPPINGS[self.mapping].to_x(t, self.lo, self.hi)
        x[0], x[-1] = MAPPINGS[self.mapping].to_x(np.array([0.0, 1.0]), self.lo, self.hi)
        return x

    def to_t(self, x) -> np.ndarray:
        return np.clip(MAPPINGS[self.mapping].to_t(np.asarray(x, float), self.lo, self.hi), 0.0, 1.0)

    def to_x(self, t) -> np.ndarray:
        return MAPPINGS[self.mapping].to_x(np.asarray(t, float), self.lo, self.hi)


class Table(NamedTuple):
    """A baked table. ``values`` is float64 of shape (H, W, C) as it will be stored (already
    rounded to ``dtype``): axes[0] runs along the width, axes[1] along the height, and a third
    axis (if any) stacks axes[1]-high slices along the height (H = axes[1].size × axes[2].size)."""

    kind: str
    values: np.ndarray
    channels: tuple
    axes: tuple
    dtype: str
    quantity: str
    model: dict | None
    params: dict
    accuracy: dict
    source_fit: str | None = None
    notes: tuple = ()

    def describe(self) -> dict:
        """Everything but the values, as JSON-ready data (what the EXR header holds)."""
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": self.kind,
            "channels": list(self.channels), "dtype": self.dtype, "quantity": self.quantity,
            "axes": [a._asdict() for a in self.axes], "model": self.model, "params": self.params,
            "accuracy": self.accuracy, "source_fit": self.source_fit, "notes": list(self.notes),
            "texel_convention": TEXEL_CONVENTION, "fitlab_version": fitlab.__version__,
        }


TEXEL_CONVENTION = (
    "sample i of an N-sample axis is at t = i/(N-1) (first and last texel centres at the ends of "
    "the range); a shader maps x to t = map^-1(x) clamped to [0, 1], then to the texture "
    "coordinate s = (t (N-1) + 0.5)/N and filters bilinearly; a third axis stacks slices of "
    "axes[1].size rows along the height and is interpolated linearly between two slices")


# --------------------------------------------------------------------------------------------
# Lookup (the same arithmetic as the generated shader, in float64)
# --------------------------------------------------------------------------------------------


def _texel_pos(axis: Axis, x):
    """Continuous sample index p in [0, N-1] of coordinate x (what s·N - 0.5 is in a shader)."""
    return axis.to_t(x) * (axis.size - 1)


def _lerp_index(p, n):
    i0 = np.clip(np.floor(p).astype(int), 0, n - 2) if n > 1 else np.zeros_like(p, dtype=int)
    return i0, (p - i0)[..., None]


def lookup(table: Table, coords) -> np.ndarray:
    """Bilinear (trilinear with a slice axis) interpolation of the stored values at axis
    coordinates ``coords`` (P, n_axes) → (P, C), exactly as the generated shader reads them."""
    coords = np.atleast_2d(np.asarray(coords, float))
    v = table.values
    ax = table.axes
    if len(ax) == 1:
        i, f = _lerp_index(_texel_pos(ax[0], coords[:, 0]), ax[0].size)
        return v[0, i] * (1 - f) + v[0, i + 1] * f
    i, fx = _lerp_index(_texel_pos(ax[0], coords[:, 0]), ax[0].size)
    j, fy = _lerp_index(_texel_pos(ax[1], coords[:, 1]), ax[1].size)

    def bilinear(row0):
        r0, r1 = row0 + j, row0 + j + 1
        a = v[r0, i] * (1 - fx) + v[r0, i + 1] * fx
        b = v[r1, i] * (1 - fx) + v[r1, i + 1] * fx
        return a * (1 - fy) + b * fy

    if len(ax) == 2:
        return bilinear(0)
    k, fz = _lerp_index(_texel_pos(ax[2], coords[:, 2]), ax[2].size)
    n1 = ax[1].size
    return bilinear(k * n1) * (1 - fz) + bilinear((k + 1) * n1) * fz


def grid_coords(axes) -> np.ndarray:
    """Axis coordinates of every stored sample, (H·W, n_axes), in storage (row-major) order."""
    nodes = [a.nodes() for a in axes]
    if len(axes) == 1:
        return nodes[0][:, None]
    if len(axes) == 2:
        Y, X = np.meshgrid(nodes[1], nodes[0], indexing="ij")
        return np.stack([X.ravel(), Y.ravel()], axis=-1)
    Z, Y, X = np.meshgrid(nodes[2], nodes[1], nodes[0], indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=-1)


def _shape_of(axes, n_channels):
    if len(axes) == 1:
        return (1, axes[0].size, n_channels)
    h = axes[1].size * (axes[2].size if len(axes) == 3 else 1)
    return (h, axes[0].size, n_channels)


# --------------------------------------------------------------------------------------------
# Microfacet albedo by quadrature (Walter eq. 41 weights over warped normals)
# --------------------------------------------------------------------------------------------

#: du1/dt of each distribution's sampling in the variable t with tan θm = α tan t, where u1 is
#: the CDF of D(m)|m·n| in θm: the inverse of Walter eq. 35 (GGX, tan²θm = α² u1/(1 - u1), so
#: u1 = sin²t) and of eq. 28 (Beckmann, tan²θm = -α² log(1 - u1), so u1 = 1 - exp(-tan²t)).
#: In t the lobe (θm ~ α) and the horizon (θm -> 90°) are both smooth: in u1 the horizon is a
#: square-root endpoint singularity.
def _du_dt_ggx(t):
    return jnp.sin(2.0 * t)


def _du_dt_beckmann(t):
    c = jnp.cos(t)
    ok = c > 1e-150
    tan_t = jnp.sin(t) / jnp.where(ok, c, 1.0)
    x = jnp.where(ok & (tan_t < 30.0), tan_t, 30.0)  # exp(-900) = 0: the density has vanished
    return jnp.where(ok, 2.0 * x * (1.0 + x * x) * jnp.exp(-x * x), 0.0)


_DU_DT = {"ggx": _du_dt_ggx, "beckmann": _du_dt_beckmann, "beckmann_rational": _du_dt_beckmann}

#: Default quadrature orders: Gauss–Legendre nodes per θm panel (in t), per φm panel (over
#: [0, π]) and in μ for the averages; the error estimate compares these with twice these, whose
#: values are stored.
QUAD_ORDERS = {"n_u": 8, "n_phi": 4, "n_mu": 16}
#: Panels are graded towards each horizon breakpoint at these multiples of α (the width over
#: which Smith's G1(o) falls to 0 as the outgoing direction reaches the horizon).
_GRADING = (2.0, 0.5, 0.125)


def _breakpoints(ci, eta, phi, transmission: bool):
    """θm breakpoints in [0, π/2] at fixed φm for incidence wi = (sin θi, 0, cos θi):
    horizon of the reflected direction, and (with transmission) facing, total internal
    reflection and horizon of the refracted direction. Shape (..., K), unsorted."""
    half_pi = 0.5 * jnp.pi
    si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    # o_r.z = 2(i·m) cos θm - cos θi = 0  <=>  tan 2θm = -cos θi / (sin θi cos φm)
    theta_r = 0.5 * jnp.arctan2(ci, -si * cp)
    if not transmission:
        return theta_r[..., None]
    # i·m = A cos(θm - θ0): facing boundary θ0 + π/2, TIR boundaries θ0 ± acos(c_crit / A)
    A = jnp.sqrt(ci * ci + (si * cp) ** 2)
    theta0 = jnp.arctan2(si * cp, ci)
    theta_c = theta0 + half_pi
    c_crit = jnp.sqrt(jnp.maximum(1.0 - eta * eta, 0.0))
    has_tir = (eta < 1.0) & (c_crit < A)
    delta = jnp.arccos(jnp.clip(c_crit / jnp.where(A > 0, A, 1.0), -1.0, 1.0))
    t1 = jnp.where(has_tir, theta0 - delta, 0.0)
    t2 = jnp.where(has_tir, theta0 + delta, 0.0)
    # o_t.z = 0: the generalized half-vector (Walter eq. 16) wi + η wo with wo horizontal lies on
    # the circle (sin θi, 0) + η (cos ψ, sin ψ); along φm it is at tan θm = ρ / cos θi with
    # ρ² - 2ρ sin θi cos φm + sin²θi - η² = 0.
    disc = eta * eta - (si * sp) ** 2
    root = jnp.sqrt(jnp.maximum(disc, 0.0))
    rho_p, rho_m = si * cp + root, si * cp - root
    t3 = jnp.where((disc >= 0) & (rho_p > 0), jnp.arctan2(rho_p, ci), 0.0)
    t4 = jnp.where((disc >= 0) & (rho_m > 0), jnp.arctan2(rho_m, ci), 0.0)
    return jnp.stack([theta_r, theta_c, t1, t2, t3, t4], axis=-1)


def _phi_breakpoints(ci, alpha, eta, transmission: bool):
    """φm in [0, π] where the θm-breakpoint structure of :func:`_breakpoints` changes: φ = π/2
    (the reflection horizon and the facing boundary sweep across θm for grazing incidence) and,
    for η < 1, where total internal reflection starts (A = c_crit), where it reaches the
    horizon (sin θi cos φ = c_crit) and where the refracted horizon appears (η = sin θi sin φ)."""
    half_pi = 0.5 * jnp.pi
    out = [jnp.zeros_like(ci), jnp.full_like(ci, half_pi), jnp.full_like(ci, jnp.pi)]
    # near grazing incidence the reflection horizon θ_r(φ) drops from ~π/2 to 0 across
    # |φ - π/2| ~ cos θi; the integrand follows over ~ cos θi + α: grade towards π/2
    s = ci + alpha
    out += [jnp.clip(half_pi + sign * f * s, 0.0, jnp.pi) for f in (2.0, 0.5, 0.125)
            for sign in (-1.0, 1.0)]
    if transmission:
        si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
        inv_si = 1.0 / jnp.maximum(si, 1e-300)
        c_crit = jnp.sqrt(jnp.maximum(1.0 - eta * eta, 0.0))
        c1 = jnp.sqrt(jnp.maximum(c_crit**2 - ci * ci, 0.0)) * inv_si
        c2 = c_crit * inv_si
        s3 = eta * inv_si
        for v in (c1, -c1, c2):
            out.append(jnp.where((eta < 1.0) & (jnp.abs(v) <= 1.0), jnp.arccos(jnp.clip(v, -1, 1)), 0.0))
        a3 = jnp.arcsin(jnp.clip(s3, -1.0, 1.0))
        out += [jnp.where(s3 <= 1.0, a3, 0.0), jnp.where(s3 <= 1.0, jnp.pi - a3, 0.0)]
    return jnp.sort(jnp.stack(out))


def _albedo_point(mu, alpha, eta, *, distribution, mode, n_u, n_phi):
    """Albedo integrals at one (μ, α, η) by quadrature over microfacet normals.

    E = ∫∫ w(m) du1 du2 over the sampling's uniforms (Walter eqs 24, 28, 35), w being the
    sample weight of Walter eq. 41; u1 is changed to t (tan θm = α tan t), φm = 2π u2 over
    [0, π] (the integrand is even in φm). Both directions use Gauss–Legendre panels between
    breakpoints, with smoothed ends (``gauss_legendre_panels``); ``n_phi`` counts the nodes per
    φ panel. mode "conductor": [E] with F = 1; "dfg": [scale, bias]; "dielectric": [R, T] for
    incidence from the side where the relative index is η (rough_dielectric's frame flip)."""
    dist = get_distribution(distribution)
    du_dt = _DU_DT[distribution]
    half_pi = 0.5 * jnp.pi
    ci = jnp.maximum(mu, MU_MIN)
    si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
    wi = jnp.stack([si, jnp.zeros_like(si), ci])
    transmission = mode == "dielectric"
    phi, w_phi = gauss_legendre_panels(_phi_breakpoints(ci, alpha, eta, transmission), n_phi,
                                       smooth_ends=True, xp=jnp)
    w_phi = w_phi / jnp.pi  # ∫ du2 over [0, 1] = 2 ∫_0^π dφ / 2π
    br = _breakpoints(ci, eta, phi, transmission)
    horizons = br[..., :1] if not transmission else br[..., jnp.array([0, 4, 5])]
    g = alpha * jnp.asarray(_GRADING)
    graded = horizons[..., :, None] - g if not transmission else jnp.concatenate(
        [horizons[..., :, None] - g, horizons[..., :, None] + g], axis=-1)
    ends = jnp.broadcast_to(jnp.array([0.0, half_pi]), phi.shape + (2,))
    if transmission:
        theta_b = jnp.concatenate([ends, br, graded.reshape(phi.shape + (-1,))], axis=-1)
    else:  # reflection is valid on [0, θ_r] only
        theta_b = jnp.minimum(jnp.concatenate([ends[..., :1], br, graded.reshape(phi.shape + (-1,))],
                                              axis=-1), br[..., :1])
    theta_b = jnp.sort(jnp.clip(theta_b, 0.0, half_pi), axis=-1)
    # θm -> t: tan t = tan θm / α
    t_b = jnp.arctan2(jnp.sin(theta_b), alpha * jnp.cos(theta_b))
    t, w1 = gauss_legendre_panels(t_b, n_u, smooth_ends=True, xp=jnp)
    w1 = w1 * du_dt(t)
    sin_t, cos_t = jnp.sin(t), jnp.cos(t)
    r = jax.lax.rsqrt(cos_t * cos_t + (alpha * sin_t) ** 2)  # tan θm = α tan t
    st, ct = alpha * sin_t * r, cos_t * r
    cp = jnp.cos(phi)[:, None]
    m = jnp.stack([st * cp, st * jnp.sin(phi)[:, None], ct], axis=-1)
    c = m @ wi  # i·m
    mz = m[..., 2]
    # Walter eq. 41 without G1(o): |i·m| G1(i) / (|i·n| |m·n|); G1(i)/cos θi stays finite as μ → 0
    base = jnp.where((c > 0) & (mz > 0), c * dist.G1(wi, alpha) / (ci * jnp.where(mz > 0, mz, 1.0)), 0.0)
    W = w1 * w_phi[:, None]
    o_r = reflect(jnp.broadcast_to(wi, m.shape), m)  # Walter eq. 39
    ok_r = o_r[..., 2] > 0
    g_r = jnp.where(ok_r, dist.G1(o_r, alpha), 0.0) * base
    if mode == "conductor":
        return jnp.stack([jnp.sum(W * g_r)])
    if mode == "dfg":
        fc = (1.0 - c) ** 5  # Schlick: F = F0 + (1 - F0)(1 - v·h)^5 (Karis 2013)
        return jnp.stack([jnp.sum(W * g_r * (1.0 - fc)), jnp.sum(W * g_r * fc)])
    eta_b = jnp.broadcast_to(eta, c.shape)
    F = fresnel_dielectric_Walter2007(c, eta_b)  # Walter eq. 22
    o_t, ok = refract(jnp.broadcast_to(wi, m.shape), m, eta_b)  # Walter eq. 40
    ok_t = ok & (o_t[..., 2] < 0)
    g_t = jnp.where(ok_t, dist.G1(o_t, alpha), 0.0) * base
    return jnp.stack([jnp.sum(W * F * g_r), jnp.sum(W * (1.0 - F) * g_t)])


@functools.lru_cache(maxsize=None)
def _albedo_kernel(distribution, mode, n_u, n_phi):
    point = functools.partial(_albedo_point, distribution=distribution, mode=mode, n_u=n_u,
                              n_phi=n_phi)

    @jax.jit
    def run(mu, alpha, eta):
        return jax.lax.map(lambda a: point(*a), (mu, alpha, eta), batch_size=256)

    return run


def albedo_integrals(mu, alpha, eta=None, *, distribution="ggx", mode="conductor",
                     n_u=None, n_phi=None):
    """Albedo integrals at points (μ, α[, η]) (1D arrays) → (P, K) float64.

    mode "conductor": E with F = 1; "dfg": (scale, bias); "dielectric": (R, T) with relative
    index η = η_o / η_i of the incident side. Quadrature orders default to twice
    :data:`QUAD_ORDERS` (the orders of the stored values)."""
    if distribution not in _DU_DT:
        raise ValueError(f"albedo tables support the distributions {', '.join(_DU_DT)}, not "
                         f"{distribution!r}")
    n_u = n_u or 2 * QUAD_ORDERS["n_u"]
    n_phi = n_phi or 2 * QUAD_ORDERS["n_phi"]
    mu = jnp.asarray(mu, dtype=jnp.float64).ravel()
    alpha = jnp.maximum(jnp.asarray(alpha, dtype=jnp.float64).ravel(), ALPHA_MIN)
    eta = jnp.ones_like(mu) if eta is None else jnp.asarray(eta, dtype=jnp.float64).ravel()
    mu, alpha, eta = jnp.broadcast_arrays(mu, alpha, eta)
    # pad to a power of two (at least 64) so that few array shapes are ever compiled
    n = mu.shape[0]
    size = max(64, 1 << max(n - 1, 0).bit_length())
    pad = lambda x: jnp.concatenate([x, jnp.full(size - n, 0.5, dtype=x.dtype)])  # noqa: E731
    run = _albedo_kernel(distribution, mode, int(n_u), int(n_phi))
    return np.asarray(run(pad(mu), pad(alpha), pad(eta)))[:n]


def _albedo_with_error(mu, alpha, eta, distribution, mode, orders):
    lo = albedo_integrals(mu, alpha, eta, distribution=distribution, mode=mode,
                          n_u=orders["n_u"], n_phi=orders["n_phi"])
    hi = albedo_integrals(mu, alpha, eta, distribution=distribution, mode=mode,
                          n_u=2 * orders["n_u"], n_phi=2 * orders["n_phi"])
    return hi, np.abs(hi - lo)


def _average_over_mu(alpha, eta, distribution, mode, orders):
    """E_avg = 2 ∫ E(μ) μ dμ (Gauss–Legendre in μ at n_mu and 2 n_mu nodes), with the error
    estimate |Q_n - Q_2n| + the largest error estimate of the E values used."""
    alpha = np.asarray(alpha, float).ravel()
    eta = np.ones_like(alpha) if eta is None else np.asarray(eta, float).ravel()
    # E_avg depends on (α, η) only: integrate once per distinct pair
    pairs, inverse = np.unique(np.stack([alpha, eta], axis=-1), axis=0, return_inverse=True)
    if len(pairs) < len(alpha):
        avg, err = _average_over_mu(pairs[:, 0], pairs[:, 1], distribution, mode, orders)
        return avg[inverse.ravel()], err[inverse.ravel()]
    out, err = [], []
    for n in (orders["n_mu"], 2 * orders["n_mu"]):
        x, w = gauss_legendre(n, 0.0, 1.0)
        MU = np.broadcast_to(x, (alpha.size, n)).ravel()
        A = np.repeat(alpha, n)
        H = np.repeat(eta, n)
        E, dE = _albedo_with_error(MU, A, H, distribution, mode, orders)
        E = E.reshape(alpha.size, n, -1)
        dE = dE.reshape(alpha.size, n, -1)
        out.append(2.0 * np.einsum("pnk,n->pk", E, w * x))
        err.append(dE.max(axis=1))
    return out[1], np.abs(out[1] - out[0]) + err[1]


# --------------------------------------------------------------------------------------------
# Table kinds: the evaluator behind each (the direct evaluation the accuracy is measured against)
# --------------------------------------------------------------------------------------------


class Spec(NamedTuple):
    """What a table kind evaluates: ``evaluate(coords (P, n_axes)) -> (values (P, C), error
    estimate (P, C) or None)``; bake() runs it at the grid nodes."""

    kind: str
    channels: tuple
    axes: tuple
    evaluate: Callable
    quantity: str
    model: dict | None
    params: dict
    method: str
    notes: tuple = ()
    n_check: int = 2048
    orders: dict | None = None


def _axis(name, lo, hi, size, mapping, description):
    if mapping not in MAPPINGS:
        raise ValueError(f"axis {name}: unknown mapping {mapping!r}; choose one of "
                         f"{', '.join(MAPPINGS)}")
    if int(size) != size or not SIZE_MIN <= size <= SIZE_MAX:
        raise ValueError(f"axis {name}: size must be an integer in [{SIZE_MIN}, {SIZE_MAX}], "
                         f"got {size!r}")
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"axis {name}: the range [{lo}, {hi}] must be finite with lo < hi")
    if mapping == "log" and lo <= 0:
        raise ValueError(f"axis {name}: the log mapping needs lo > 0, got {lo}")
    return Axis(name, lo, hi, int(size), mapping, description)


def _alpha_axis(size, mapping, rng):
    lo, hi = rng
    if lo < ALPHA_MIN or hi > 1.0:
        raise ValueError(f"axis alpha: the range must lie within [{ALPHA_MIN:g}, 1], got "
                         f"[{lo:g}, {hi:g}]")
    return _axis("alpha", lo, hi, size, mapping, "microfacet width α (Walter α_b / α_g)")


def _mu_axis(size, mapping):
    return _axis("mu", 0.0, 1.0, size, mapping,
                 f"μ = cos θi of the incident direction (values at μ < {MU_MIN:g} are the limit)")


def spec_D(distribution="ggx", size=(512, 512), mappings=("u8", "log"),
           alpha_range=(ALPHA_MIN, 1.0)):
    dist = get_distribution(distribution)
    axes = (_axis("cos_theta_h", 0.0, 1.0, size[0], mappings[0],
                  "cos θh = n·h of the microfacet normal (half vector)"),
            _alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        c = np.clip(coords[:, 0], 0.0, 1.0)
        a = coords[:, 1]
        m = np.stack([np.sqrt((1.0 - c) * (1.0 + c)), np.zeros_like(c), c], axis=-1)
        D = np.asarray(dist.D(jnp.asarray(m), jnp.asarray(a)))
        return (np.pi * a * a * D)[:, None], None

    return Spec("D", ("pi_alpha2_D",), axes, evaluate,
                f"π α² D(cos θh; α) of the {distribution} distribution ({dist.reference}); "
                "D in 1/sr = value / (π α²)",
                {"name": None, "options": {"distribution": distribution}}, {},
                "exact evaluation at the sample points (float64)")


def _conductor_channels(params):
    out = {}
    for ch, p in params.items():
        missing = [k for k in ("n", "k") if k not in p]
        if missing:
            raise ValueError(f"a conductor Fresnel table needs n and k; channel {ch} lacks "
                             f"{', '.join(missing)}")
        out[ch] = (float(p["n"]), float(p["k"]))
    return out


def spec_fresnel(params, size=128, mapping="linear", fresnel="exact"):
    """``params``: {channel: {"n": .., "k": ..}} (conductor) or {channel: {"eta": ..}}
    (dielectric, η = n_inside / n_outside)."""
    axes = (_axis("cos_theta", 0.0, 1.0, size, mapping,
                  "cos θ between the direction and the (micro)surface normal"),)
    if not params:
        raise ValueError("a Fresnel table needs a material: conductor n and k (or a preset) or "
                         "a dielectric eta")
    if all("eta" in p for p in params.values()):
        etas = {ch: float(p["eta"]) for ch, p in params.items()}
        for ch, e in etas.items():
            if not (np.isfinite(e) and e > 0):
                raise ValueError(f"eta must be a positive number, got {e!r} (channel {ch})")
        single = list(etas) == ["Y"]
        channels = tuple(f"{'' if single else ch + '.'}F_{side}" for ch in etas
                         for side in ("outside", "inside"))

        def evaluate(coords):
            c = jnp.asarray(np.clip(coords[:, 0], 0.0, 1.0))
            cols = []
            for e in etas.values():
                cols.append(np.asarray(fresnel_dielectric_Walter2007(c, jnp.full_like(c, e))))
                cols.append(np.asarray(fresnel_dielectric_Walter2007(c, jnp.full_like(c, 1.0 / e))))
            return np.stack(cols, axis=-1), None

        quantity = ("unpolarized dielectric Fresnel reflectance F(cos θ) (Walter eq. 22) for "
                    "incidence from outside (relative index η) and from inside (1/η, total "
                    "internal reflection = 1)")
        return Spec("fresnel", channels, axes, evaluate, quantity,
                    {"name": None, "options": {}}, {ch: {"eta": e} for ch, e in etas.items()},
                    "exact evaluation at the sample points (float64)")
    nk = _conductor_channels(params)
    method = CONDUCTOR_FRESNEL_METHODS[fresnel]

    def evaluate(coords):
        c = jnp.asarray(np.clip(coords[:, 0], 0.0, 1.0))
        cols = [np.asarray(method(c, jnp.full_like(c, n), jnp.full_like(c, k)))
                for n, k in nk.values()]
        return np.stack(cols, axis=-1), None

    return Spec("fresnel", tuple(nk), axes, evaluate,
                f"conductor Fresnel reflectance F(cos θ), method {fresnel!r} "
                "(exact: unpolarized average of Rs and Rp for complex index n + ik)",
                {"name": None, "options": {"fresnel": fresnel}},
                {ch: {"n": n, "k": k} for ch, (n, k) in nk.items()},
                "exact evaluation at the sample points (float64)")


def _quad_note(orders):
    return (f"quadrature over microfacet normals in the sampling's coordinates (Walter eqs 28/35, "
            f"weight eq. 41): Gauss-Legendre panels with smoothed ends in theta_m (as tan t = "
            f"tan theta_m / alpha) and phi_m, split at the analytic breakpoints and graded "
            f"towards the horizons, {2 * orders['n_u']} nodes per theta_m panel and "
            f"{2 * orders['n_phi']} per phi_m panel; averages over mu by Gauss-Legendre with "
            f"{2 * orders['n_mu']} nodes; error estimate = |Q(n) - Q(2n)| at the orders n in "
            f"accuracy.quadrature.orders")


def spec_albedo_conductor(distribution="ggx", size=(32, 32), mappings=("linear", "linear"),
                          alpha_range=(ALPHA_MIN, 1.0), orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    axes = (_mu_axis(size[0], mappings[0]), _alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        E, dE = _albedo_with_error(coords[:, 0], coords[:, 1], None, distribution, "conductor",
                                   orders)
        Ea, dEa = _average_over_mu(coords[:, 1], None, distribution, "conductor", orders)
        return np.concatenate([E, Ea], axis=1), np.concatenate([dE, dEa], axis=1)

    return Spec("albedo_conductor", ("E", "E_avg"), axes, evaluate,
                f"directional albedo E(μ, α) = ∫ f cos θo dωo of the {distribution} microfacet "
                "BRDF with F = 1 and separable Smith G (Walter eqs 20, 23), and E_avg(α) = "
                "2 ∫ E(μ) μ dμ (constant along μ); energy compensation as in Kulla & Conty 2017",
                {"name": "rough_conductor", "options": {"distribution": distribution}}, {},
                _quad_note(orders), n_check=128, orders=orders)


def spec_dfg(distribution="ggx", size=(64, 64), mappings=("linear", "linear"),
             alpha_range=(ALPHA_MIN, 1.0), orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    axes = (_mu_axis(size[0], mappings[0]), _alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        return _albedo_with_error(coords[:, 0], coords[:, 1], None, distribution, "dfg", orders)

    return Spec("dfg", ("scale", "bias"), axes, evaluate,
                f"split-sum DFG terms of the {distribution} microfacet BRDF (separable Smith G): "
                "∫ f cos θo dωo = F0 · scale + bias under Schlick's Fresnel "
                "F = F0 + (1 - F0)(1 - v·h)^5 (Karis 2013); scale + bias = E with F = 1",
                {"name": "rough_conductor", "options": {"distribution": distribution}}, {},
                _quad_note(orders), n_check=256, orders=orders)


def spec_albedo_dielectric(distribution="ggx", size=(32, 32, 16),
                           mappings=("linear", "linear", "linear"), alpha_range=(ALPHA_MIN, 1.0),
                           eta_range=(1.05, 3.0), orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    lo, hi = eta_range
    if lo < 1.0 + 1e-3 or hi > 5.0:
        raise ValueError(f"axis eta: the range must lie within [1.001, 5] (incidence from inside "
                         f"covers 1/eta), got [{lo:g}, {hi:g}]")
    axes = (_mu_axis(size[0], mappings[0]), _alpha_axis(size[1], mappings[1], alpha_range),
            _axis("eta", lo, hi, size[2], mappings[2],
                  "relative index η = n_inside / n_outside (inside = -z side)"))

    def evaluate(coords):
        mu, a, e = coords[:, 0], coords[:, 1], coords[:, 2]
        out, err = _albedo_with_error(mu, a, e, distribution, "dielectric", orders)
        inn, ierr = _albedo_with_error(mu, a, 1.0 / e, distribution, "dielectric", orders)
        avg_o, davg_o = _average_over_mu(a, e, distribution, "dielectric", orders)
        avg_i, davg_i = _average_over_mu(a, 1.0 / e, distribution, "dielectric", orders)
        return (np.concatenate([out, inn, avg_o, avg_i], axis=1),
                np.concatenate([err, ierr, davg_o, davg_i], axis=1))

    channels = ("R_outside", "T_outside", "R_inside", "T_inside",
                "Ravg_outside", "Tavg_outside", "Ravg_inside", "Tavg_inside")
    return Spec("albedo_dielectric", channels, axes, evaluate,
                f"rough dielectric ({distribution}, separable Smith G, Walter eqs 20-22) "
                "directional albedos: R = ∫ f_r cos θo dωo, T = ∫ f_t |cos θo| dωo (BTDF for "
                "radiance, eq. 21) for incidence from outside (relative index η) and from inside "
                "(1/η); *avg = 2 ∫ (.)(μ) μ dμ, constant along μ",
                {"name": "rough_dielectric", "options": {"distribution": distribution}}, {},
                _quad_note(orders), n_check=48, orders=orders)


def halfdiff_directions(cos_theta_h, cos_theta_d):
    """Directions of Rusinkiewicz's (θh, θd) at φh = 0, φd = 90°:
    wi = (sin θh cos θd, sin θd, cos θh cos θd), wo = (sin θh cos θd, -sin θd, cos θh cos θd).
    Cosines are clamped to [MU_MIN, 1]: at 0 both directions lie in the horizon, where a model
    returns 0 although its limit (the table's first texel) is finite."""
    ch = np.clip(np.asarray(cos_theta_h, float), MU_MIN, 1.0)
    cd = np.clip(np.asarray(cos_theta_d, float), MU_MIN, 1.0)
    sh, sd = np.sqrt((1 - ch) * (1 + ch)), np.sqrt((1 - cd) * (1 + cd))
    wi = np.stack([sh * cd, sd, ch * cd], axis=-1)
    wo = np.stack([sh * cd, -sd, ch * cd], axis=-1)
    return wi, wo


def halfdiff_coordinates(wi, wo):
    """(cos θh, cos θd) of direction pairs: h = normalize(wi + wo), cos θh = h.z, cos θd = wi·h."""
    h = np.asarray(wi, float) + np.asarray(wo, float)
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    return np.clip(h[..., 2], 0.0, 1.0), np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)


def spec_model(model_name, params, options=None, size=(256, 256), mappings=("u8", "linear")):
    """``params``: {channel: {parameter: value}} of a registry model (every parameter given)."""
    model = fitlab.get_model(model_name)
    opts = fitlab.api.resolve_options(model, options)
    clean = {}
    for ch, p in params.items():
        p = {k: float(v) for k, v in p.items() if k in model.parameter_names}
        fitlab.api.check_params(model, p)
        clean[ch] = p
    axes = (_axis("cos_theta_h", 0.0, 1.0, size[0], mappings[0],
                  "cos θh = n·h, h = normalize(wi + wo)"),
            _axis("cos_theta_d", 0.0, 1.0, size[1], mappings[1],
                  "cos θd = wi·h (Rusinkiewicz's difference angle), at φd = 90°"))

    def evaluate(coords):
        wi, wo = halfdiff_directions(coords[:, 0], coords[:, 1])
        cols = [np.asarray(fitlab.eval_bsdf(model.name, p, wi, wo, opts)) for p in clean.values()]
        return np.stack(cols, axis=-1), None

    notes = ("2D (θh, θd) tables are exact for BRDFs that depend on θh and θd only; other "
             "isotropic BRDFs (G and Oren–Nayar depend on φd) are represented at φd = 90°: "
             "accuracy.parameterization gives the error this makes over random direction pairs",)
    if "transmission" in model.lobes:
        notes += ("the model also transmits; the table holds its reflection (wo.z > 0) only",)
    return Spec("model", tuple(clean), axes, evaluate,
                f"BRDF f(wi, wo) in 1/sr (without the cosine) of {model.name} at "
                "(cos θh, cos θd, φd = 90°)", {"name": model.name, "options": opts}, clean,
                "exact evaluation at the sample points (float64)", notes)


# --------------------------------------------------------------------------------------------
# Baking and accuracy
# --------------------------------------------------------------------------------------------


def _rel_error(approx, ref, scale):
    den = np.maximum(np.abs(ref), REL_FLOOR * scale)
    den = np.where(den > 0, den, 1.0)
    return np.abs(approx - ref) / den


def _stats(err):
    return {"max_rel": float(np.max(err)), "rms_rel": float(np.sqrt(np.mean(err**2)))}


def round_to(values, dtype: str) -> np.ndarray:
    """Values as the file stores them (float64 array holding half or float values)."""
    if dtype not in ("half", "float"):
        raise ValueError(f"dtype must be 'half' or 'float', got {dtype!r}")
    if dtype == "half":
        big = np.abs(values).max(initial=0.0)
        if big > HALF_MAX:
            raise ValueError(f"the table holds values up to {big:.4g}, beyond the largest half "
                             f"float {HALF_MAX:g}; use dtype float")
        return values.astype(np.float16).astype(np.float64)
    return values.astype(np.float32).astype(np.float64)


def _random_points(axes, n, seed):
    rng = np.random.default_rng(seed)
    t = rng.random((n, len(axes)))
    return np.stack([a.to_x(t[:, k]) for k, a in enumerate(axes)], axis=-1)


def measure_accuracy(table: Table, evaluate: Callable, n_points: int, seed: int = 0,
                     points=None) -> dict:
    """Bilinear lookup of the stored values vs direct evaluation at ``n_points`` random points
    (uniform in the texture coordinates), or at the given axis coordinates ``points`` (P, n_axes),
    per channel: max and RMS relative error."""
    pts = _random_points(table.axes, n_points, seed) if points is None else np.asarray(points)
    n_points = len(pts)
    ref, _ = evaluate(pts)
    approx = lookup(table, pts)
    scale = np.abs(table.values).reshape(-1, len(table.channels)).max(axis=0)
    err = _rel_error(approx, ref, scale)
    per = {ch: _stats(err[:, k]) for k, ch in enumerate(table.channels)}
    return {"points": int(n_points), "seed": seed, "floor": REL_FLOOR,
            "reference": "direct evaluation at random points (uniform in texture coordinates)",
            **_stats(err), "per_channel": per}


def bake(spec: Spec, dtype: str = "float", *, check_points: int | None = None,
         source_fit: str | None = None, progress: Callable | None = None) -> Table:
    """Evaluate ``spec`` at every sample, round to ``dtype`` and measure the accuracy."""
    n_texels = int(np.prod([a.size for a in spec.axes]))
    if n_texels > TEXELS_MAX:
        raise ValueError(f"the table would have {n_texels} samples; at most {TEXELS_MAX} are "
                         "allowed (reduce --size)")
    coords = grid_coords(spec.axes)
    if progress:
        progress(f"evaluating {spec.kind} at {len(coords)} samples ({spec.method})")
    values, err = _evaluate_in_rows(spec, coords, progress)
    values = np.asarray(values, float)
    if not np.all(np.isfinite(values)):
        bad = int(np.sum(~np.isfinite(values)))
        raise FloatingPointError(f"{spec.kind}: {bad} non-finite values; this is a bug in the "
                                 "table's evaluation, please report it")
    shape = _shape_of(spec.axes, len(spec.channels))
    exact = values.reshape(shape)
    stored = round_to(exact, dtype)
    scale = np.abs(exact).reshape(-1, len(spec.channels)).max(axis=0)
    accuracy = {"method": spec.method,
                "storage": {"dtype": dtype, **_stats(_rel_error(stored, exact, scale))}}
    if err is not None:
        e = np.asarray(err).reshape(-1, len(spec.channels))
        rel = e / np.maximum(np.abs(values), REL_FLOOR * np.maximum(scale, 1e-300))
        accuracy["quadrature"] = {"max_abs_error_estimate": float(e.max()),
                                  "max_rel_error_estimate": float(rel.max()),
                                  "per_channel_max_abs": {ch: float(e[:, k].max()) for k, ch
                                                          in enumerate(spec.channels)},
                                  "orders": spec.orders}
    table = Table(spec.kind, stored, tuple(spec.channels), tuple(spec.axes), dtype, spec.quantity,
                  spec.model, spec.params, accuracy, source_fit, tuple(spec.notes))
    n = check_points if check_points is not None else spec.n_check
    if n:
        if progress:
            progress(f"measuring accuracy at {n} random points against direct evaluation")
        accuracy["interpolation"] = measure_accuracy(table, spec.evaluate, n)
        if spec.kind == "model":
            accuracy["parameterization"] = _parameterization_error(table, spec, n)
    return table


def _evaluate_in_rows(spec: Spec, coords, progress, chunks: int = 10):
    """spec.evaluate over whole rows of the table at a time (rows share α and η, so the
    averages E_avg are integrated once per row), reporting progress for the quadrature kinds."""
    if spec.orders is None or progress is None:
        return spec.evaluate(coords)
    import time

    w = spec.axes[0].size
    rows = len(coords) // w
    step = max(1, -(-rows // chunks)) * w
    vals, errs, t0 = [], [], time.perf_counter()
    for start in range(0, len(coords), step):
        v, e = spec.evaluate(coords[start:start + step])
        vals.append(np.asarray(v))
        errs.append(np.asarray(e))
        done = min(start + step, len(coords))
        el = time.perf_counter() - t0
        progress(f"  {done}/{len(coords)} samples, {el:.0f} s elapsed, about "
                 f"{el * (len(coords) - done) / done:.0f} s to go")
    return np.concatenate(vals), np.concatenate(errs)


def _parameterization_error(table, spec, n, seed=1):
    """Table lookup at (cos θh, cos θd) of random upper-hemisphere direction pairs vs the model
    at those pairs (includes the φd = 90° assumption)."""
    rng = np.random.default_rng(seed)

    def hemi(u):
        z = u[:, 0]
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z], -1)

    wi, wo = hemi(rng.random((n, 2))), hemi(rng.random((n, 2)))
    ch, cd = halfdiff_coordinates(wi, wo)
    approx = lookup(table, np.stack([ch, cd], -1))
    name = spec.model["name"]
    ref = np.stack([np.asarray(fitlab.eval_bsdf(name, p, wi, wo, spec.model["options"]))
                    for p in spec.params.values()], -1)
    scale = np.abs(table.values).reshape(-1, len(table.channels)).max(axis=0)
    return {"points": n, "reference": "the model at random direction pairs of the upper "
            "hemisphere (uniform in solid angle)", **_stats(_rel_error(approx, ref, scale))}


# --------------------------------------------------------------------------------------------
# Kinds registry and the one entry point
# --------------------------------------------------------------------------------------------


class Kind(NamedTuple):
    name: str
    summary: str
    n_axes: int
    default_size: tuple
    default_mappings: tuple
    needs: str  # which parameters the table needs from a model / fit
    axis_names: tuple = ()


KINDS = {
    "D": Kind("D", "microfacet distribution π α² D(cos θh; α) (Elek 2010 section 3.1)", 2,
              (512, 512), ("u8", "log"), "none (option distribution)", ("cos_theta_h", "alpha")),
    "fresnel": Kind("fresnel", "Fresnel reflectance F(cos θ) of one material per channel", 1,
                    (128,), ("linear",), "conductor n, k (or --preset) or dielectric eta", ("cos_theta",)),
    "albedo_conductor": Kind("albedo_conductor", "E(μ, α) and E_avg(α) of a microfacet "
                             "conductor with F = 1 (energy compensation)", 2, (32, 32),
                             ("linear", "linear"), "none (option distribution)", ("mu", "alpha")),
    "albedo_dielectric": Kind("albedo_dielectric", "R and T albedos of a rough dielectric over "
                              "(μ, α, η), from outside and inside, and their averages", 3,
                              (32, 32, 16), ("linear", "linear", "linear"),
                              "none (option distribution)", ("mu", "alpha", "eta")),
    "dfg": Kind("dfg", "split-sum DFG scale and bias over (μ, α)", 2, (64, 64),
                ("linear", "linear"), "none (option distribution)", ("mu", "alpha")),
    "model": Kind("model", "a model's or fit's BRDF over (cos θh, cos θd) at φd = 90°", 2,
                  (256, 256), ("u8", "linear"), "every parameter of the model",
                  ("cos_theta_h", "cos_theta_d")),
}


def get_kind(name: str) -> Kind:
    try:
        return KINDS[name]
    except KeyError:
        raise ValueError(f"unknown table kind {name!r}; choose one of {', '.join(KINDS)}") from None


def make_spec(kind: str, *, size=None, mappings=None, model=None, params=None, options=None,
              alpha_range=None, eta_range=None, orders=None) -> Spec:
    """The :class:`Spec` of a table kind from uniform arguments (what the CLI and the EXR
    reader use): ``model`` a registry name or None, ``params`` {channel: {name: value}},
    ``options`` the model options (``distribution``, ``fresnel``)."""
    k = get_kind(kind)
    size = tuple(int(s) for s in (size or k.default_size))
    if len(size) != k.n_axes:
        raise ValueError(f"table {kind} has {k.n_axes} axes; give {k.n_axes} sizes "
                         f"({'x'.join(map(str, k.default_size))} by default), got {len(size)}")
    mappings = tuple(mappings or k.default_mappings)
    if len(mappings) != k.n_axes:
        raise ValueError(f"table {kind} has {k.n_axes} axes, got {len(mappings)} mappings")
    options = dict(options or {})
    params = params or {}
    distribution = options.get("distribution", "ggx")
    arange = tuple(alpha_range or (ALPHA_MIN, 1.0))
    if kind == "D":
        return spec_D(distribution, size, mappings, arange)
    if kind == "fresnel":
        return spec_fresnel(params, size[0], mappings[0], options.get("fresnel", "exact"))
    if kind == "albedo_conductor":
        return spec_albedo_conductor(distribution, size, mappings, arange, orders)
    if kind == "dfg":
        return spec_dfg(distribution, size, mappings, arange, orders)
    if kind == "albedo_dielectric":
        return spec_albedo_dielectric(distribution, size, mappings, arange,
                                      tuple(eta_range or (1.05, 3.0)), orders)
    if model is None:
        raise ValueError("a model table needs a model (--model NAME --param ... or --from-fit)")
    return spec_model(model, params, options, size, mappings)


def spec_of_table(table: Table) -> Spec:
    """Rebuild the evaluator of a baked (or read) table from its description, to re-measure it."""
    ax = table.axes
    by = {a.name: a for a in ax}
    orders = (table.accuracy.get("quadrature") or {}).get("orders")
    model = table.model or {}
    return make_spec(table.kind, size=[a.size for a in ax], mappings=[a.mapping for a in ax],
                     model=model.get("name") if table.kind == "model" else None,
                     params=table.params, options=model.get("options"),
                     alpha_range=(by["alpha"].lo, by["alpha"].hi) if "alpha" in by else None,
                     eta_range=(by["eta"].lo, by["eta"].hi) if "eta" in by else None,
                     orders=orders)


def conductor_preset(name: str) -> dict:
    """{R, G, B: {n, k}} of a CONDUCTOR_PRESETS entry (Elek 2010 appendix A)."""
    try:
        p = CONDUCTOR_PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(CONDUCTOR_PRESETS)}") \
            from None
    return {ch: {"n": p["n"][i], "k": p["k"][i]} for i, ch in enumerate("RGB")}


__all__ = [
    "Axis", "Table", "Spec", "Kind", "KINDS", "MAPPINGS", "bake", "lookup", "make_spec",
    "spec_of_table", "measure_accuracy", "albedo_integrals", "conductor_preset",
    "halfdiff_directions", "halfdiff_coordinates", "grid_coords", "round_to",
]
