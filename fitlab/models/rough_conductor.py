"""Rough conductor: Walter 2007 microfacet BRDF (eq. 20) with conductor Fresnel (complex n + ik).

One-sided: scatters only when both directions are above the surface (wi.z > 0, wo.z > 0), like
Mitsuba's ``roughconductor``. (n, k) are relative to the outside medium.
"""

from __future__ import annotations

import jax.numpy as jnp

from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS
from fitlab.frame import dot, normalize, reflect
from fitlab.microfacet import get_distribution, smith_G1, widened_alpha
from fitlab.models.base import Model, Option, Parameter
from fitlab.numerics import safe_div

PARAMETERS = (
    Parameter("alpha", 1e-4, 1.0, 0.1, "1", "microfacet width α (Walter α_b / α_g)"),
    Parameter("n", 0.01, 10.0, 0.2, "1", "real part of the conductor's relative index"),
    Parameter("k", 0.0, 20.0, 3.9, "1", "imaginary part (extinction coefficient)"),
)

OPTIONS = (
    Option("distribution", ("ggx", "beckmann", "beckmann_rational", "phong"), "ggx",
           "microfacet distribution"),
    Option("fresnel", tuple(CONDUCTOR_FRESNEL_METHODS), "exact",
           "conductor Fresnel: exact, schlick (F0 from n, k) or lazanyi (Elek appendix B)"),
    Option("sampling", ("standard", "widened"), "standard",
           "sample D(m)|m·n| with α (standard) or Walter's widened α"),
)


def _alpha_s(alpha, ci, sampling):
    return widened_alpha(alpha, ci) if sampling == "widened" else alpha


def eval(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
    """Walter eq. 20: F(i,h_r) G(i,o,h_r) D(h_r) / (4|i·n||o·n|)."""
    dist = get_distribution(distribution)
    alpha = params["alpha"]
    ci, co = wi[..., 2], wo[..., 2]
    h = wi + wo  # Walter eq. 13 (wi.z > 0 here)
    hh = normalize(h)
    F = CONDUCTOR_FRESNEL_METHODS[fresnel](dot(wi, hh), params["n"], params["k"])
    G = smith_G1(dist, wi, hh, alpha) * smith_G1(dist, wo, hh, alpha)
    f = safe_div(F * G * dist.D(h, alpha), 4.0 * ci * co)
    return jnp.where((ci > 0) & (co > 0), f, 0.0)


def pdf(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
    """p_m(h_r) / (4|o·h_r|) (Walter eqs 14, 24, 38)."""
    dist = get_distribution(distribution)
    ci, co = wi[..., 2], wo[..., 2]
    h = wi + wo
    hh = normalize(h)
    o_h = dot(wo, hh)
    p = safe_div(dist.D(h, _alpha_s(params["alpha"], ci, sampling)) * hh[..., 2], 4.0 * o_h)
    return jnp.where((ci > 0) & (co > 0) & (o_h > 0), p, 0.0)


def sample(params, wi, u, distribution="ggx", fresnel="exact", sampling="standard"):
    """m ~ D(m)|m·n|, o = reflect(i, m) (eq. 39); weight = F · eq. 41 (· D/D† when widened)."""
    dist = get_distribution(distribution)
    alpha = params["alpha"]
    ci = wi[..., 2]
    alpha_s = _alpha_s(alpha, ci, sampling)
    m = dist.sample_m(u[..., 0], u[..., 1], alpha_s)
    c = dot(wi, m)
    wo = reflect(wi, m)
    co = wo[..., 2]
    mz = m[..., 2]
    valid = (ci > 0) & (c > 0) & (co > 0)
    F = CONDUCTOR_FRESNEL_METHODS[fresnel](c, params["n"], params["k"])
    G = smith_G1(dist, wi, m, alpha) * smith_G1(dist, wo, m, alpha)
    ratio = safe_div(dist.D(m, alpha), dist.D(m, alpha_s)) if sampling == "widened" else 1.0
    weight = F * safe_div(c * G, ci * mz) * ratio
    p = safe_div(dist.D(m, alpha_s) * mz, 4.0 * c)
    return wo, jnp.where(valid, weight, 0.0), jnp.where(valid, p, 0.0)


MODEL = Model(
    name="rough_conductor",
    summary="Walter 2007 microfacet BRDF of a rough conductor with complex index (n, k)",
    parameters=PARAMETERS,
    options=OPTIONS,
    eval=eval,
    sample=sample,
    pdf=pdf,
    lobes="reflection",
    reference="Walter et al. 2007 eqs 13-14, 20, 23-36, 37-41; exact conductor Fresnel "
    "(unpolarized), Schlick, or Lazányi–Szirmay-Kalos as in Elek 2010 appendix B",
)
