"""Phase functions of participating media: isotropic, Henyey–Greenstein, SGGX specular microflakes.

Directions follow the frame convention (data_formats/CONVENTIONS.md): ``wi`` points back toward
where the light comes from (minus the propagation direction before scattering), ``wo`` toward
where it goes. Every phase function p(wi, wo) is a density over wo in 1/sr with ∫ p dωo = 1
(SpongeCake eq. 2); isotropic and HG are reciprocal (eq. 6), SGGX in the form
σ(wi) p(wi, wo) = σ(wo) p(wo, wi) of eq. 1. ``sample(params, wi, u[..., 2]) -> (wo, pdf)``
samples p exactly (the weight p/pdf is 1). All functions are pure, broadcast over leading
dimensions, and keep float32 inputs in float32.

SGGX (Heitz et al. 2015; SpongeCake eq. 7): D(m) = 1 / (π sqrt|S| (mᵀS⁻¹m)²), projected area
σ(ω) = sqrt(ωᵀSω); the specular microflake phase function is p(wi, wo) = D(h) / (4 σ(wi)),
h = (wi + wo)/|wi + wo| (SpongeCake eq. 4 with F = 1). Surface-like flakes: S = diag(α², α², 1) in
the frame whose z is the flake normal ``axis``; fiber-like: S = diag(1, 1, α²) with z along the
fiber (SpongeCake §3.3). In a microflake medium the extinction of a direction is proportional
to σ(ω) (SpongeCake eq. 3): ``sggx_sigma`` gives that factor to the random walk.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

from fitlab._jax import jnp
from fitlab.frame import dot, normalize, reflect
from fitlab.numerics import safe_div, safe_rsqrt, safe_sqrt
from fitlab.registry import Registry

_INV_4PI = 0.25 / math.pi


def orthonormal_basis(n):
    """Two unit vectors (s, t) with (s, t, n) right-handed orthonormal, for unit n; branchless
    (Duff et al. 2017, "Building an Orthonormal Basis, Revisited")."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = jnp.where(z >= 0, jnp.ones_like(z), -jnp.ones_like(z))
    a = -1.0 / (sign + z)
    b = x * y * a
    s = jnp.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t = jnp.stack([b, sign + y * y * a, -y], axis=-1)
    return s, t


def _from_local(local, n):
    s, t = orthonormal_basis(n)
    return local[..., 0:1] * s + local[..., 1:2] * t + local[..., 2:3] * n


# --------------------------------------------------------------------------------------------
# Isotropic
# --------------------------------------------------------------------------------------------


def eval_isotropic(params, wi, wo):
    """p = 1/(4π)."""
    return jnp.full(wi.shape[:-1], _INV_4PI, dtype=wi.dtype)


def sample_isotropic(params, wi, u):
    z = 1.0 - 2.0 * u[..., 0]
    r = safe_sqrt(1.0 - z * z)
    phi = 2.0 * jnp.pi * u[..., 1]
    wo = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), z], axis=-1)
    return wo, eval_isotropic(params, wi, wo)


# --------------------------------------------------------------------------------------------
# Henyey–Greenstein (SpongeCake §3.2 lists it among the analytic phase functions)
# --------------------------------------------------------------------------------------------


def eval_hg(params, wi, wo):
    """p = (1 - g²) / (4π (1 + g² - 2 g cos θ)^{3/2}), cos θ = (-wi)·wo the scattering angle
    between propagation directions (g > 0: forward scattering)."""
    g = params["g"]
    c = -dot(wi, wo)
    den = 1.0 + g * g - 2.0 * g * c
    return _INV_4PI * (1.0 - g * g) * safe_rsqrt(den) / jnp.maximum(den, 1e-30)


def sample_hg(params, wi, u):
    """Inverse CDF of cos θ (pbrt-v4 SampleHenyeyGreenstein); exact for every g in (-1, 1)."""
    g = params["g"]
    xi = u[..., 0]
    small = jnp.abs(g) < 1e-3
    g_safe = jnp.where(small, 0.5, g)
    sq = (1.0 - g_safe * g_safe) / (1.0 + g_safe - 2.0 * g_safe * xi)
    cos_hg = -(1.0 + g_safe * g_safe - sq * sq) / (2.0 * g_safe)
    # here cos_hg is the cosine to +wi (pbrt's convention); the scattering cosine to the
    # propagation direction -wi is its negative
    cos_t = jnp.where(small, 1.0 - 2.0 * xi, -cos_hg)
    cos_t = jnp.clip(cos_t, -1.0, 1.0)
    sin_t = safe_sqrt(1.0 - cos_t * cos_t)
    phi = 2.0 * jnp.pi * u[..., 1]
    local = jnp.stack([sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t], axis=-1)
    wo = _from_local(local, -wi)
    return wo, eval_hg(params, wi, wo)


# --------------------------------------------------------------------------------------------
# SGGX microflakes (Heitz et al. 2015; SpongeCake eqs 3, 4, 7)
# --------------------------------------------------------------------------------------------


def sggx_matrix(kind, roughness, axis):
    """S (..., 3, 3) of surface-like (S = α²I + (1 - α²) a aᵀ = R diag(α², α², 1) Rᵀ) or
    fiber-like (S = I + (α² - 1) a aᵀ = R diag(1, 1, α²) Rᵀ) flakes, SpongeCake §3.3.
    ``axis``: unit flake normal / fiber direction (..., 3)."""
    a2 = (roughness * roughness)[..., None, None]
    aat = axis[..., :, None] * axis[..., None, :]
    eye = jnp.eye(3, dtype=axis.dtype)
    if kind == "surface":
        return a2 * eye + (1.0 - a2) * aat
    if kind == "fiber":
        return eye + (a2 - 1.0) * aat
    raise ValueError(f"unknown SGGX kind {kind!r}; choose 'surface' or 'fiber'")


def sggx_axial(kind, roughness, axis, w):
    """(c², s²) of w against an axial SGGX distribution: c = w·a along the axis and
    s² = |w × a|² across it, for the closed forms of a rotated diag(α², α², 1) (surface) or
    diag(1, 1, α²) (fiber) matrix. The cross product keeps s² accurate where w is near the axis,
    which 1 - c² is not in float32 (its error, divided by α² = 1e-6, would swamp D)."""
    c = dot(w, axis)
    x = jnp.cross(w, axis)
    return c * c, dot(x, x)


def sggx_axial_sigma(kind, roughness, axis, w):
    """σ(w) = sqrt(wᵀSw) of :func:`sggx_matrix` without forming S (SpongeCake eq. 7):
    surface sqrt(α² s² + c²), fiber sqrt(s² + α² c²)."""
    c2, s2 = sggx_axial(kind, roughness, axis, w)
    a2 = roughness * roughness
    return safe_sqrt(a2 * s2 + c2) if kind == "surface" else safe_sqrt(s2 + a2 * c2)


def sggx_axial_D(kind, roughness, axis, m):
    """D(m) of :func:`sggx_matrix` without inverting S (SpongeCake eq. 7): with
    q = mᵀS⁻¹m, surface q = s²/α² + c² and √|S| = α², fiber q = s² + c²/α² and √|S| = α;
    written as D = α² / (π (s² + α² c²)²) (surface) and α³ / (π (α² s² + c²)²) (fiber), which
    stay finite for α down to the bound without dividing by α."""
    c2, s2 = sggx_axial(kind, roughness, axis, m)
    a2 = roughness * roughness
    if kind == "surface":
        den = s2 + a2 * c2
        return safe_div(a2, jnp.pi * den * den)
    den = a2 * s2 + c2
    return safe_div(a2 * roughness, jnp.pi * den * den)


def _quad(S, w):
    """wᵀ S w."""
    return jnp.einsum("...i,...ij,...j->...", w, S, w)


def sggx_sigma(S, w):
    """Projected area of the flakes seen from w, σ(w) = sqrt(wᵀSw) (SpongeCake eq. 7)."""
    return safe_sqrt(_quad(S, w))


def _adjugate3(S):
    """The adjugate (transposed cofactor matrix) and the determinant of 3 × 3 matrices, in
    closed form: elementwise arithmetic only. jnp.linalg.det / inv lower to LAPACK calls, and a
    LAPACK call inside the simulator's compiled while loop hung jaxlib 0.10.2's CPU runtime (the
    executable waited forever, some runs in a few, when other processes ran beside it)."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 0], S[..., 1, 1], S[..., 1, 2]
    g, h, i = S[..., 2, 0], S[..., 2, 1], S[..., 2, 2]
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    adj = jnp.stack([jnp.stack([A, c * h - b * i, b * f - c * e], axis=-1),
                     jnp.stack([B, a * i - c * g, c * d - a * f], axis=-1),
                     jnp.stack([C, b * g - a * h, a * e - b * d], axis=-1)], axis=-2)
    return adj, a * A + b * B + c * C


def sggx_D(S, m):
    """SGGX NDF, D(m) = 1 / (π sqrt(det S) (mᵀ S⁻¹ m)²) for unit m (SpongeCake eq. 7), with
    S⁻¹ = adj(S) / det S: D = det^{3/2} / (π (mᵀ adj(S) m)²)."""
    adj, det = _adjugate3(S)
    q = _quad(adj, m)
    return safe_div(det * safe_sqrt(det), jnp.pi * q * q)


def eval_sggx(params, wi, wo):
    """Specular microflake phase function p = D(h) / (4 σ(wi)) (SpongeCake eq. 4, F = 1);
    ``params["S"]``: the SGGX matrix (..., 3, 3). 0 for wo = -wi (h undefined)."""
    S = params["S"]
    h = wi + wo
    ok = dot(h, h) > 1e-12
    hh = normalize(jnp.where(ok[..., None], h, jnp.ones_like(h)))
    p = safe_div(sggx_D(S, hh), 4.0 * sggx_sigma(S, wi))
    return jnp.where(ok, p, 0.0)


def sample_sggx_vndf(S, wi, u):
    """A microflake normal visible from wi, density ⟨wi, m⟩ D(m) / σ(wi) over ⟨wi, m⟩ > 0
    (Heitz et al. 2015, supplemental "sample_VNDF")."""
    r = jnp.sqrt(u[..., 0])
    phi = 2.0 * jnp.pi * u[..., 1]
    uu, vv = r * jnp.cos(phi), r * jnp.sin(phi)
    ww = safe_sqrt(1.0 - uu * uu - vv * vv)
    wk, wj = orthonormal_basis(wi)
    S_kk, S_jj, S_ii = _quad(S, wk), _quad(S, wj), _quad(S, wi)
    S_kj = jnp.einsum("...i,...ij,...j->...", wk, S, wj)
    S_ki = jnp.einsum("...i,...ij,...j->...", wk, S, wi)
    S_ji = jnp.einsum("...i,...ij,...j->...", wj, S, wi)
    sqrt_det = safe_sqrt(jnp.abs(S_kk * S_jj * S_ii - S_kj * S_kj * S_ii - S_ki * S_ki * S_jj
                                 - S_ji * S_ji * S_kk + 2.0 * S_kj * S_ki * S_ji))
    inv_sqrt_ii = safe_rsqrt(S_ii)
    tmp = safe_sqrt(S_jj * S_ii - S_ji * S_ji)
    inv_tmp = safe_div(1.0, tmp)
    zero = jnp.zeros_like(uu)
    Mk = jnp.stack([sqrt_det * inv_tmp, zero, zero], axis=-1)
    Mj = jnp.stack([-inv_sqrt_ii * (S_ki * S_ji - S_kj * S_ii) * inv_tmp, inv_sqrt_ii * tmp, zero],
                   axis=-1)
    Mi = jnp.stack([inv_sqrt_ii * S_ki, inv_sqrt_ii * S_ji, inv_sqrt_ii * S_ii], axis=-1)
    m_kji = normalize(uu[..., None] * Mk + vv[..., None] * Mj + ww[..., None] * Mi)
    return m_kji[..., 0:1] * wk + m_kji[..., 1:2] * wj + m_kji[..., 2:3] * wi


def sample_sggx(params, wi, u):
    """wo = reflect(wi, m), m ~ VNDF(wi): density D(h)/(4σ(wi)) = p, so the weight is 1."""
    S = params["S"]
    m = sample_sggx_vndf(S, wi, u)
    wo = reflect(wi, m)
    return wo, eval_sggx(params, wi, wo)


#: name → (eval, sample); params: hg {"g"}, sggx {"S"} (see sggx_matrix), isotropic {}.
class PhaseFunction(NamedTuple):
    eval: Callable
    sample: Callable


PHASE_FUNCTIONS: Registry[PhaseFunction] = Registry("phase function", {
    "isotropic": PhaseFunction(eval_isotropic, sample_isotropic),
    "hg": PhaseFunction(eval_hg, sample_hg),
    "sggx": PhaseFunction(eval_sggx, sample_sggx),
})
