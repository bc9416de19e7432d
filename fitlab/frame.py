"""Local shading frame helpers.

Frame: normal = +z. Directions are unit vectors pointing away from the surface (Walter's
convention): ``wi`` toward the light, ``wo`` toward the detector. θ is measured from +z (θ > 90°
is the transmission side), φ from +x. Radians in code; degrees only at the file edges.
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.fresnel import fresnel_dielectric
from fitlab.numerics import safe_rsqrt, sign_nonzero


def cos_theta(w):
    return w[..., 2]


def sin2_theta(w):
    """sin²θ from the tangential components (exact near the normal, unlike 1 - cos²θ)."""
    return w[..., 0] ** 2 + w[..., 1] ** 2


def dot(a, b):
    """a·b over the last axis, written on components: it stays inside the surrounding elementwise
    XLA fusion (a sum over the size-3 axis compiles to a separate reduction kernel)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def normalize(v):
    """v / |v|; the zero vector maps to zero with finite gradients."""
    return v * safe_rsqrt(dot(v, v))[..., None]


def flip_z(w, s):
    """Multiply the z component by s (±1): maps a configuration seen from below to one from above."""
    return jnp.concatenate([w[..., :2], (w[..., 2] * s)[..., None]], axis=-1)


def spherical_to_cartesian(theta, phi):
    """Unit direction from θ (from +z) and φ (from +x), both in radians."""
    st = jnp.sin(theta)
    return jnp.stack([st * jnp.cos(phi), st * jnp.sin(phi), jnp.cos(theta)], axis=-1)


def cartesian_to_spherical(w):
    """(θ, φ) in radians of unit directions; φ in (-π, π]."""
    theta = jnp.arctan2(jnp.sqrt(sin2_theta(w)), w[..., 2])
    phi = jnp.arctan2(w[..., 1], w[..., 0])
    return theta, phi


def reflect(w, m):
    """Mirror w about the microfacet normal m (Walter eq. 39 for i·m > 0): 2(w·m)m - w."""
    return 2.0 * dot(w, m)[..., None] * m - w


def refract(w, m, eta):
    """Refract w (pointing away from the surface, w·m > 0) through a facet with normal m.

    ``eta`` = η_t / η_i, the index on the transmitted side over the incident side. Returns the
    refracted direction (Walter eq. 40 with η = η_i/η_t) and a mask that is False under total
    internal reflection. Snell's law and the mask come from
    :func:`fitlab.fresnel.fresnel_dielectric`.
    """
    c = dot(w, m)
    _, cos_t, _, eta_ti = fresnel_dielectric(jnp.abs(c), eta)
    ok = cos_t < 0  # cos θt = 0: total internal reflection
    # under total internal reflection the direction is a placeholder with cos θt = -1 (finite,
    # off the horizon), so that callers that evaluate both branches stay finite
    return refracted(w, m, jnp.where(ok, cos_t, -1.0), eta_ti), ok


def refracted(w, m, cos_theta_t, eta_ti):
    """The refracted direction of w through a facet with normal m, from what
    :func:`fitlab.fresnel.fresnel_dielectric` returned for this crossing (Mitsuba's
    ``refract(wi, m, cos_theta_t, eta_ti)``): Walter eq. 40,
    wt = (η_i/η_t (w·m) + cos θt) m - η_i/η_t w, with cos θt signed opposite to w·m."""
    eta_ti = jnp.asarray(eta_ti)
    return (eta_ti * dot(w, m) + cos_theta_t)[..., None] * m - eta_ti[..., None] * w


def half_vector_reflection(wi, wo):
    """Unnormalized reflection half-vector, Walter eq. 13 (callers work with wi.z >= 0)."""
    return wi + wo


def half_vector_transmission(wi, wo, eta):
    """Unnormalized generalized half-vector for refraction (Walter eq. 16) with η_i = 1, η_o = eta,
    turned to the +z hemisphere (pbrt's face-forward). Degree-0 homogeneous quantities built from it
    need no normalization."""
    h = wi + eta[..., None] * wo
    return h * sign_nonzero(h[..., 2])[..., None]
