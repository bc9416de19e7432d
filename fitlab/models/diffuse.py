"""Diffuse reflectors: Lambertian and Oren–Nayar (qualitative model, Oren & Nayar 1994, the
form used by the Weidlich–Wilkie layers of Elek 2010). Both one-sided (wi.z > 0, wo.z > 0) and
sampled with a cosine-weighted hemisphere."""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.models.base import OUTSIDE, Capabilities, Model, Parameter, clear_film
from fitlab.numerics import safe_div

ALBEDO = Parameter("albedo", 0.0, 1.0, 0.5, "1", "diffuse reflectance ρ", "albedo")


def _upper(wi, wo):
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def sample_cosine_hemisphere(u):
    """Malley's method: p(ω) = cos θ / π."""
    r = jnp.sqrt(u[..., 0])
    phi = 2.0 * jnp.pi * u[..., 1]
    z = jnp.sqrt(jnp.maximum(1.0 - u[..., 0], 0.0))
    return jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi), z], axis=-1)


def pdf_cosine(params, wi, wo):
    return jnp.where(_upper(wi, wo), wo[..., 2] / jnp.pi, 0.0)


def eval_lambertian(params, wi, wo):
    """f = ρ / π."""
    rho = params["albedo"] * jnp.ones_like(wi[..., 2])
    return jnp.where(_upper(wi, wo), rho / jnp.pi, 0.0)


def sample_lambertian(params, wi, u):
    wo = sample_cosine_hemisphere(u)
    valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    weight = jnp.where(valid, params["albedo"], 0.0)
    return wo, weight, jnp.where(valid, wo[..., 2] / jnp.pi, 0.0)


def oren_nayar_AB(sigma):
    """Oren & Nayar 1994 qualitative model: A = 1 - σ²/(2(σ²+0.33)), B = 0.45σ²/(σ²+0.09)."""
    s2 = sigma * sigma
    return 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)


def eval_oren_nayar(params, wi, wo):
    """f = ρ/π (A + B max(0, cos(φi - φo)) sin α tan β), α = max(θi, θo), β = min(θi, θo).

    cos(φi-φo) sinθi sinθo = i_x o_x + i_y o_y and sin α tan β = sinθi sinθo / max(cosθi, cosθo),
    so the angular term is max(0, i_x o_x + i_y o_y) / max(cos θi, cos θo): no trigonometry and
    no singularity at the normal."""
    A, B = oren_nayar_AB(params["sigma"])
    proj = jnp.maximum(wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1], 0.0)
    term = safe_div(proj, jnp.maximum(wi[..., 2], wo[..., 2]))
    f = params["albedo"] / jnp.pi * (A + B * term)
    return jnp.where(_upper(wi, wo), f, 0.0)


def sample_oren_nayar(params, wi, u):
    wo = sample_cosine_hemisphere(u)
    p = wo[..., 2] / jnp.pi
    valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    weight = safe_div(eval_oren_nayar(params, wi, wo) * wo[..., 2], p)
    return wo, jnp.where(valid, weight, 0.0), jnp.where(valid, p, 0.0)


def scene_of_lambertian(params, options):
    """A Lambertian substrate of albedo ρ under the outside, behind the clear film an opaque
    substrate needs. (Oren–Nayar has no scene: the simulator has no such substrate.)"""
    return {"outside": dict(OUTSIDE), "stack": [clear_film(OUTSIDE["index"])],
            "substrate": {"type": "lambertian", "albedo": float(params["albedo"])},
            "effects": {"delta": False}}


LAMBERTIAN = Model(
    name="lambertian",
    summary="Lambertian reflector, f = ρ/π",
    parameters=(ALBEDO,),
    options=(),
    eval=eval_lambertian,
    sample=sample_lambertian,
    pdf=pdf_cosine,
    reference="Lambert; cosine-weighted hemisphere sampling",
    capabilities=Capabilities(lambertian=True),
    scene_of=scene_of_lambertian,
    translations=(("mitsuba", "diffuse"),),
)

OREN_NAYAR = Model(
    name="oren_nayar",
    summary="Oren–Nayar rough diffuse reflector (qualitative model)",
    parameters=(
        ALBEDO,
        Parameter("sigma", 0.0, 1.5707963267948966, 0.3, "rad",
                  "standard deviation of the facet slope angle σ"),
    ),
    options=(),
    eval=eval_oren_nayar,
    sample=sample_oren_nayar,
    pdf=pdf_cosine,
    reference="Oren & Nayar 1994 qualitative model (as in Elek 2010 section 2); cosine sampling",
)
