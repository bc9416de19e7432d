"""A flat (macro-normal) interface between two layers of a stack: Snell refraction, Fresnel
transmittance, the radiance (solid-angle) compression factor and Beer–Lambert absorption.

Shared by the layered models (``models/coated.py``, ``models/weidlich_wilkie.py``). Both use the
single-point simplification of their sources: light enters and leaves a layer at the same point
and every layer is refracted through the macro normal +z.

Directions follow fitlab's convention (pointing away from the surface); a direction *inside* a
layer points away from the layer below, i.e. upward (+z) for a reflection path. ``eta`` is the
index below the interface over the index above it.
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.fresnel import cos_theta_critical, fresnel_dielectric
from fitlab.numerics import safe_div
from fitlab.quadrature import gauss_legendre

#: Optical paths beyond this (in units of 1/σa) transmit exp(-L) < 1e-300: treated as 0 so that
#: neither the value nor the gradient of exp(-L) over-/underflows (thick absorbing layers).
OPTICAL_PATH_MAX = 690.0


def refract_down(w, eta):
    """Snell's law through the flat interface: the upward direction inside the lower medium whose
    refraction out of it is ``w`` (an upward direction above, w.z > 0).

    sin θ' = sin θ / η with the same azimuth: w' = (w_x/η, w_y/η, cos θ'), cos θ' from
    :func:`fitlab.fresnel.fresnel_dielectric` (incidence from above). Returns (w', ok); ok is
    False where no such direction exists (η < 1 beyond the critical angle; the light is totally
    reflected above the interface). The gradient stays finite at the critical angle."""
    _, cos_t, _, eta_ti = fresnel_dielectric(jnp.abs(w[..., 2]), eta)
    ok = (cos_t < 0) & (w[..., 2] > 0)
    wp = jnp.stack([w[..., 0] * eta_ti, w[..., 1] * eta_ti, -cos_t], axis=-1)
    return wp, ok


def refract_up(wp, eta):
    """Inverse of :func:`refract_down`: the direction above for the upward direction ``wp`` in
    the lower medium, w = (η w'_x, η w'_y, cos θ), cos θ from
    :func:`fitlab.fresnel.fresnel_dielectric` (incidence from below); ok is False under total
    internal reflection (η sin θ' ≥ 1: the light stays inside)."""
    _, cos_t, _, eta_ti = fresnel_dielectric(-jnp.abs(wp[..., 2]), eta)
    ok = (cos_t > 0) & (wp[..., 2] > 0)
    w = jnp.stack([wp[..., 0] * eta_ti, wp[..., 1] * eta_ti, cos_t], axis=-1)
    return w, ok


def transmittance(cos_above, eta):
    """Fresnel transmittance T = 1 - F of a smooth dielectric interface (Walter eq. 22 for F),
    seen from above at cos θ = ``cos_above``; equal from both sides along the same refracted
    pair (the blog's T(θo) = T(-θo'))."""
    return 1.0 - fresnel_dielectric(jnp.abs(cos_above), eta)[0]


def solid_angle_compression(eta):
    """η_above² / η_below² = 1/η²: the radiance scaling of a crossing down and back up
    (bsdf_under_smooth_interface: "the solid angle (de-)compression compensation factor η0²/η1²")."""
    return 1.0 / (eta * eta)


def beer_lambert(tau, cos_i, cos_o):
    """Absorption along both refracted paths of a layer, Elek 2010 eq. 3:
    a = exp(-σ l), l = d (1/(N·L') + 1/(N·V')), with the optical depth τ = σ d.

    cos_i, cos_o are the refracted cosines (> 0 on valid paths). Paths longer than
    OPTICAL_PATH_MAX transmit exactly 0 (double-where: finite value and gradient)."""
    # safe_div is 0 at cos = 0, where the mask below gives 0 anyway: no inf * 0 in the gradient
    path = tau * (safe_div(1.0, cos_i) + safe_div(1.0, cos_o))
    ok = (path < OPTICAL_PATH_MAX) & (cos_i > 0) & (cos_o > 0)
    return jnp.where(ok, jnp.exp(-jnp.where(ok, path, 0.0)), 0.0)


# Gauss–Legendre nodes and weights on [0, 1] for the hemispherical integrals below.
_GL_X, _GL_W = gauss_legendre(24, 0.0, 1.0)


def internal_diffuse_reflectance(eta, tau):
    """Fraction of an upward Lambertian (cosine-distributed) flux leaving the base of an
    absorbing coat that the interface reflects back down *and* that reaches the base again:

        r = ∫_0^1 F(μ, 1/η) exp(-2τ/μ) 2μ dμ

    (F: Fresnel reflectance from inside, Walter eq. 22 with relative index 1/η; μ = cos θ inside;
    exp(-2τ/μ): Beer–Lambert up to the interface and back down, Elek eq. 3). For η > 1 the
    integrand is split at the critical cosine μc = sqrt(1 - 1/η²) (F = 1 below it) and each part
    is integrated with 24-point Gauss–Legendre; exact for τ = 0 below μc."""
    eta = jnp.asarray(eta)
    mu_c = cos_theta_critical(1.0 / eta)  # 0 for η <= 1: no total internal reflection
    x = jnp.asarray(_GL_X, dtype=eta.dtype)
    w = jnp.asarray(_GL_W, dtype=eta.dtype)
    mc = mu_c[..., None]
    tau_ = jnp.asarray(tau, dtype=eta.dtype)[..., None]
    # [0, μc]: total internal reflection, F = 1
    mu1 = mc * x
    part1 = mu_c * jnp.sum(w * 2.0 * mu1 * _attenuation2(tau_, mu1), axis=-1)
    # [μc, 1]: Fresnel from inside (relative index 1/η)
    mu2 = mc + (1.0 - mc) * x
    F = fresnel_dielectric(-mu2, eta[..., None])[0]  # incidence from below: relative index 1/η
    part2 = (1.0 - mu_c) * jnp.sum(w * F * 2.0 * mu2 * _attenuation2(tau_, mu2), axis=-1)
    return part1 + part2


def _attenuation2(tau, mu):
    """exp(-2τ/μ) for μ in (0, 1], as beer_lambert(τ, μ, μ)."""
    return beer_lambert(tau, mu, mu)

