"""What the microfacet models (rough conductor, rough dielectric) share: the roughness
parameters of their isotropic and anisotropic variants, the ``distribution`` and ``sampling``
options, and the sampling of a microfacet normal with its density and weight.

Isotropic variants have one width ``alpha``; anisotropic ones ``alpha_x`` and ``alpha_y``, the
widths along the tangent frame's +x and +y (Mitsuba's ``alpha_u``, ``alpha_v``). Directions
given to the functions here are on the incident side's upper frame (wi.z >= 0).
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab import microfacet
from fitlab.frame import dot, normalize
from fitlab.models.base import Option, Parameter
from fitlab.numerics import safe_div

ALPHA = Parameter("alpha", 1e-4, 1.0, 0.1, "1", "microfacet width α (Walter α_b / α_g)",
                  "roughness")
ALPHA_X = Parameter("alpha_x", 1e-4, 1.0, 0.1, "1",
                    "microfacet width α_x along the tangent +x (Mitsuba alpha_u)", "roughness")
ALPHA_Y = Parameter("alpha_y", 1e-4, 1.0, 0.1, "1",
                    "microfacet width α_y along the tangent +y (Mitsuba alpha_v)", "roughness")

SAMPLING = Option(
    "sampling", ("standard", "widened", "visible"), "standard",
    "sample D(m)|m·n| with α (standard), with Walter's widened α(1.2 - 0.2 sqrt|i·n|) "
    "(widened), or the visible normals D_wi(m) (visible: ggx by Heitz 2018, beckmann by Heitz & "
    "d'Eon 2014; not beckmann_rational, whose approximate G1 is not the visible density's)")


def parameters(anisotropic: bool) -> tuple[Parameter, ...]:
    return (ALPHA_X, ALPHA_Y) if anisotropic else (ALPHA,)


def distribution_option(anisotropic: bool, description: str) -> Option:
    """The ``distribution`` option: Walter's distributions from the registry (those that
    support α_x ≠ α_y for an anisotropic model)."""
    return Option("distribution", microfacet.names(anisotropic=True if anisotropic else None),
                  "ggx", description)


def ndf(params, distribution: str, anisotropic: bool) -> microfacet.MicrofacetDistribution:
    """The model's microfacet distribution with the widths in ``params``."""
    family = microfacet.get_distribution(distribution)
    if anisotropic:
        return family(params["alpha_x"], params["alpha_y"])
    return family(params["alpha"])


def scene_roughness(params, distribution: str, anisotropic: bool) -> dict:
    """The roughness keys of a simulator interface or substrate (data_formats/scene_toml.md):
    the distribution and the width α, or α_x, α_y (the same axis: Walter's α). An isotropic
    distribution with α_x, α_y raises ValueError, as the model's own evaluation does."""
    if anisotropic and not microfacet.get_distribution(distribution).anisotropic:
        raise ValueError(f"the {distribution} distribution is isotropic only: anisotropic "
                         f"widths need {' or '.join(microfacet.names(anisotropic=True))}")
    keys = ("alpha_x", "alpha_y") if anisotropic else ("alpha",)
    return {"distribution": distribution, **{k: float(params[k]) for k in keys}}


def check_sampling(dist: microfacet.MicrofacetDistribution, sampling: str) -> None:
    if sampling == "visible" and not dist.has_visible_sampling:
        raise ValueError(f"option sampling=visible needs a distribution with visible-normal "
                         f"sampling (ggx or beckmann); {dist.family.name} has none: use "
                         "sampling=standard")


def sampling_ndf(dist, cos_i, sampling):
    """The distribution whose D(m)|m·n| is sampled: Walter's widened one for ``widened``."""
    return dist.scaled(microfacet.widening_factor(cos_i)) if sampling == "widened" else dist


def sample_normal(dist, wi, u, sampling):
    """A microfacet normal for incidence wi (upper frame) from u[..., 0:2]."""
    check_sampling(dist, sampling)
    if sampling == "visible":
        return dist.sample_visible(wi, u)
    return sampling_ndf(dist, wi[..., 2], sampling).sample_m(u)


def normal_pdf(dist, wi, m, sampling, h=None):
    """Density of :func:`sample_normal`'s m (unit) given wi: D†(m)|m·n| (Walter eq. 24) or
    D_wi(m) (Heitz 2018 eq. 1). ``h``: the same normal unnormalized, where D is better
    evaluated on it (the models' half-vectors)."""
    h = m if h is None else h
    if sampling == "visible":
        return safe_div(dist.G1(wi) * jnp.maximum(dot(wi, m), 0.0) * dist.D(h), wi[..., 2])
    return sampling_ndf(dist, wi[..., 2], sampling).D(h) * jnp.abs(m[..., 2])


def reflection_pdf(dist, wi, wo, sampling):
    """Density of o = reflect(i, m) for m from :func:`sample_normal`: p_m(h_r) / (4|o·h_r|)
    (Walter eqs 14, 24, 38; Heitz 2018 for visible normals), 0 where o·h_r <= 0."""
    h = wi + wo
    hh = normalize(h)
    o_h = dot(wo, hh)
    p = safe_div(normal_pdf(dist, wi, hh, sampling, h), 4.0 * o_h)
    return jnp.where(o_h > 0, p, 0.0)


def sample_weight(dist, wi, wo, m, sampling):
    """f|cos θo|/pdf of a sampled normal without the Fresnel factor and its choice: Walter
    eq. 41, (i·m) G(i, o, m) / (|i·n||m·n|) (times D/D† when widened); for visible normals
    G(i, o, m)/G1(i) = G1(o, m)."""
    if sampling == "visible":
        return jnp.where(dot(wi, m) > 0, dist.smith_G1(wo, m), 0.0)
    ci, c, mz = wi[..., 2], dot(wi, m), m[..., 2]
    G = dist.smith_G1(wi, m) * dist.smith_G1(wo, m)
    weight = safe_div(c * G, ci * mz)
    if sampling == "widened":
        weight = weight * safe_div(dist.D(m), sampling_ndf(dist, ci, sampling).D(m))
    return weight
