"""The thin layer's energy compensation (fitlab's addition to Guo et al. 2015, in the spirit of
Kulla & Conty 2017's multiple-scattering compensation): the light the paper's K = 1 model loses,
tabulated from the simulator, returned by a lobe that carries exactly that much.

**The table** (fitlab/models/data/thin_layer_compensation.npz, made by
``python -m fitlab.learn.compensation``): per bottom kind, at the nodes of (κ1, κ2, η, bottom,
θi), from A, the simulated directional albedo of the stack (every bounce order, τ = 0), and the
paper's model (``compensation=none``, K = 1): g ≤ 1, the scale of the paper's f,
f · g(μi) g(μo), that keeps its albedo within A where the paper returns more light than the
stack (found by a fixed point over the model's own exit directions, so the scaled albedo is A
at the nodes, not only approximately), and D, the light still missing, which the lobe below
returns. Axes: log10 κ over :data:`LOG10_KAPPA_NODES` (κ from 10 to 10⁴), η over
:data:`ETA_NODES`, the bottom by one descriptor (:data:`BOTTOM_KINDS`: a conductor by the
cosine-weighted hemispherical average of its Fresnel reflectance relative to the layer,
R̄ = 2∫F(μ)μ dμ; a dielectric by ln(η2/η)), θi over :data:`THETA_NODES_DEG`. Between nodes it
is read multilinearly (in the axes' coordinates); beyond an axis's range at its edge.

**The lobe** (Kulla & Conty's form with the table's D in place of 1 − E, turned toward the
mirror azimuth):

    f_c(ωi, ωo) = D(μi) D(μo) / (π D̄) · exp(b cos Δφ) / I0(b),   D̄ = 2 ∫₀¹ D(μ) μ dμ,

D piecewise linear in μ = cos θ between the nodes (constant below the last), D̄ its exact
integral, Δφ = φo − φi − π and b = b0 sin θi sin θo (:func:`azimuthal`; the missing light is
light that bounced inside the layer and leaves mostly forward). The azimuthal factor averages
to 1 over φo for every (θi, θo), so f_c is reciprocal and its albedo is D(μ) exactly. The
model, g(μi) g(μo) f_paper + f_c, is reciprocal, and its albedo is the simulated A at the nodes
(≤ 1 as A is).

**Absorption** (τ > 0) is not a table axis: the missing light crosses the layer at least four
times (in, down and up again, out), so D(μ) is scaled by e^{−2τ/cos θt(μ)} on each side (θt the
refracted angle; the product is the four crossings' attenuation, and the albedo stays exactly
the scaled D). Orders K > 1 (``bounces``) add their own light: the compensation subtracts their
estimated weights on the specular path, Σ_{k=2..K} E_k(μ), from D on each side. Both are
approximations stated with their measured errors in data_formats/layered_models.md.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from fitlab._jax import jax, jnp, jsp_special
from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS

DATA_PATH = Path(__file__).resolve().parent / "data" / "thin_layer_compensation.npz"

#: incidence nodes (degrees), dense toward grazing where the missing light changes fastest
THETA_NODES_DEG = (0.0, 20.0, 35.0, 45.0, 55.0, 65.0, 72.0, 78.0, 84.0, 89.0)
#: log10 κ nodes of both boundaries (κ from 10 to 10⁴)
LOG10_KAPPA_NODES = (1.0, 1.75, 2.5, 3.25, 4.0)
#: the layer's index η relative to the outside (read in ln η)
ETA_NODES = (0.5, 0.6, 0.75, 0.9, 1.1, 1.3, 1.55, 2.0, 3.0)
#: per bottom kind: the model whose table it is, the descriptor's nodes and what it is
BOTTOM_KINDS = {
    "conductor": {"model": "thin_layer(rough_conductor)",
                  "nodes": (0.05, 0.35, 0.6, 0.8, 0.92, 0.99),
                  "descriptor": "R̄, the bottom's hemispherical-average Fresnel reflectance "
                                "relative to the layer"},
    "dielectric": {"model": "thin_layer(rough_dielectric)",
                   "nodes": (0.5, 0.7, 0.85, 1.0, 1.2, 1.6, 2.5),
                   "descriptor": "η2/η, the substrate's index relative to the layer (read in "
                                 "its logarithm)"},
}

#: b0 of the lobe's azimuthal shape (:func:`azimuthal`): the missing light leaves mostly
#: toward the mirror azimuth (chosen on the in-plane arcs of benchmarks/thin_layer_compensation.py)
AZIMUTHAL_CONCENTRATION = 2.0

#: Gauss-Legendre nodes on μ ∈ [0, 1] for R̄
_MU_Q, _W_Q = (lambda x, w: ((x + 1.0) / 2.0, w / 2.0))(*np.polynomial.legendre.leggauss(24))


def rbar_conductor(n_rel, k_rel):
    """R̄ = 2 ∫₀¹ F(μ) μ dμ of a conductor n + ik relative to the layer (24-point Gauss)."""
    n_rel, k_rel = jnp.asarray(n_rel), jnp.asarray(k_rel)
    F = CONDUCTOR_FRESNEL_METHODS["exact"](jnp.asarray(_MU_Q, n_rel.dtype), n_rel[..., None],
                                             k_rel[..., None])
    return 2.0 * jnp.sum(F * jnp.asarray(_W_Q * _MU_Q, n_rel.dtype), axis=-1)


def bottom_of_node(kind: str, j: int, eta: float) -> dict:
    """The bottom's parameters (relative to vacuum) at descriptor node j for a layer of index
    η: a conductor with n = η (n_rel = 1) and the k_rel whose R̄ is the node's; a dielectric
    η2 = η · node."""
    node = BOTTOM_KINDS[kind]["nodes"][j]
    if kind == "dielectric":
        return {"eta2": float(eta * node)}
    return {"n2": float(eta), "k2": float(eta * _k_rel_of_rbar(node))}


@functools.lru_cache(maxsize=None)
def _k_rel_of_rbar(rbar: float) -> float:
    """k_rel of the conductor with n_rel = 1 whose R̄ is ``rbar`` (bisection: R̄ increases with
    k there); independent of η, so found once per node."""
    lo, hi = 0.0, 1e4
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        r = float(rbar_conductor(jnp.asarray(1.0), jnp.asarray(mid)))
        lo, hi = (mid, hi) if r < rbar else (lo, mid)
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=None)
def table(kind: str) -> np.ndarray:
    """(D, g) over (κ1, κ2, η, bottom, θ, 2) of a bottom kind (float32 as shipped): the light
    the compensation lobe returns and the scale of the paper's f."""
    with np.load(DATA_PATH) as z:
        return np.stack([z[f"{kind}_D"], z[f"{kind}_g"]], axis=-1)


def mu_nodes() -> np.ndarray:
    """cos θ of the incidence nodes (descending)."""
    return np.cos(np.radians(np.asarray(THETA_NODES_DEG)))


@functools.lru_cache(maxsize=None)
def _average_weights() -> np.ndarray:
    """c_j with D̄ = 2∫₀¹ D(μ) μ dμ = Σ c_j D_j for D piecewise linear between the μ nodes and
    constant from μ = 0 to the smallest node."""
    mu = mu_nodes()[::-1]  # ascending
    c = np.zeros(len(mu))
    c[0] += mu[0] ** 2  # 2 ∫₀^{μ0} D0 μ dμ
    for j in range(len(mu) - 1):
        a, b = mu[j], mu[j + 1]
        c[j] += (b - a) * (2 * a + b) / 3.0
        c[j + 1] += (b - a) * (a + 2 * b) / 3.0
    return c[::-1].copy()


def _axis_weights(x, nodes):
    """(lower index, weight of the upper node) of x on ascending ``nodes``, clamped to the
    range."""
    nodes = jnp.asarray(nodes, x.dtype)
    x = jnp.clip(x, nodes[0], nodes[-1])
    i = jnp.clip(jnp.searchsorted(nodes, x, side="right") - 1, 0, len(nodes) - 2)
    t = (x - nodes[i]) / (nodes[i + 1] - nodes[i])
    return i, t


def _descriptor_nodes(kind):
    nodes = np.asarray(BOTTOM_KINDS[kind]["nodes"])
    return np.log(nodes) if kind == "dielectric" else nodes


def nodes_Dg(kind: str, k1, k2, eta, bottom):
    """(D, g) at the incidence nodes, each (..., T): the table read multilinearly at
    (log10 κ1, log10 κ2, ln η, the bottom's descriptor coordinate: R̄ of a conductor, ln(η2/η)
    of a dielectric), held constant under differentiation (a tabulated correction)."""
    AE = jnp.asarray(table(kind))
    coords = (jnp.log10(k1), jnp.log10(k2), jnp.log(eta), bottom)
    axes = (LOG10_KAPPA_NODES, LOG10_KAPPA_NODES, np.log(ETA_NODES), _descriptor_nodes(kind))
    iw = [_axis_weights(jnp.asarray(c), a) for c, a in zip(coords, axes)]
    out = 0.0
    for corner in range(16):
        bits = [(corner >> d) & 1 for d in range(4)]
        w = 1.0
        idx = []
        for (i, t), b in zip(iw, bits):
            w = w * (t if b else 1.0 - t)
            idx.append(i + b)
        out = out + w[..., None, None] * AE[idx[0], idx[1], idx[2], idx[3]].astype(w.dtype)
    out = jax.lax.stop_gradient(out)
    return out[..., 0], out[..., 1]


def at_mu(Dn, mu):
    """D(μ) piecewise linear between the incidence nodes (constant below the last)."""
    nodes = mu_nodes()[::-1].copy()  # ascending μ
    lead = jnp.broadcast_shapes(Dn.shape[:-1], jnp.shape(mu))
    Da = jnp.broadcast_to(Dn[..., ::-1], lead + Dn.shape[-1:])
    i, t = _axis_weights(jnp.broadcast_to(mu, lead), nodes)
    lo = jnp.take_along_axis(Da, i[..., None], axis=-1)[..., 0]
    hi = jnp.take_along_axis(Da, (i + 1)[..., None], axis=-1)[..., 0]
    return lo + t * (hi - lo)


def average(Dn):
    """D̄ = 2 ∫₀¹ D(μ) μ dμ of the piecewise-linear D."""
    return jnp.sum(Dn * jnp.asarray(_average_weights(), Dn.dtype), axis=-1)


def azimuthal(wi, wo, b0=None):
    """The lobe's azimuthal shape: a von Mises distribution around the mirror azimuth,
    exp(b cos Δφ) / I0(b) with Δφ = φo − φi − π and b = b0 sin θi sin θo, so
    b cos Δφ = −b0 (wi_x wo_x + wi_y wo_y). Its mean over φo is 1 for every (θi, θo), so the
    albedo stays D(μ) exactly; it is symmetric in (wi, wo) and flat at normal incidence."""
    b0 = AZIMUTHAL_CONCENTRATION if b0 is None else b0
    s = jnp.sqrt(jnp.clip((1.0 - wi[..., 2] ** 2) * (1.0 - wo[..., 2] ** 2), 0.0, 1.0))
    b = b0 * s
    x = -b0 * (wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1])
    return jnp.exp(x - b) / jsp_special.i0e(b)  # exp(b cos Δφ) / I0(b), I0e = e^{-b} I0


def lobe(Dn, wi, wo):
    """f_c = D(μi) D(μo) / (π D̄) · exp(b cos Δφ) / I0(b) (Kulla & Conty 2017's form with the
    table's D, shaped toward the mirror azimuth by :func:`azimuthal`)."""
    Dbar = average(Dn)
    # A lobe of D̄ ≤ 1e-12 is none: a thick absorbing layer's e^{-2τ/cos θt} underflows, and
    # D̄² with it in float32 (the gradient of the division would be 0/0)
    ok = Dbar > 1e-12
    iso = at_mu(Dn, wi[..., 2]) * at_mu(Dn, wo[..., 2]) / (jnp.pi * jnp.where(ok, Dbar, 1.0))
    return jnp.where(ok, iso, 0.0) * azimuthal(wi, wo)
