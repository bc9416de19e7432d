"""Rough conductor: Walter 2007 microfacet BRDF (eq. 20) with conductor Fresnel (complex n + ik),
isotropic (``rough_conductor``, width α) and anisotropic (``rough_conductor_anisotropic``,
widths α_x, α_y along the tangent +x, +y; Mitsuba's ``roughconductor`` with alpha_u, alpha_v).

One-sided: scatters only when both directions are above the surface (wi.z > 0, wo.z > 0), like
Mitsuba's ``roughconductor``. (n, k) are relative to the outside medium.
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS
from fitlab.frame import dot, normalize, reflect
from fitlab.models import roughness
from fitlab.models.base import OUTSIDE, Capabilities, Model, Option, Parameter, clear_film
from fitlab.numerics import safe_div

INDEX = (
    Parameter("n", 0.01, 10.0, 0.2, "1", "real part of the conductor's relative index", "index"),
    Parameter("k", 0.0, 20.0, 3.9, "1", "imaginary part (extinction coefficient)", "extinction"),
)

FRESNEL = Option("fresnel", tuple(CONDUCTOR_FRESNEL_METHODS), "exact",
                 "conductor Fresnel: exact, schlick (F0 from n, k) or lazanyi (Lazányi–"
                 "Szirmay-Kalos 2005: Schlick minus a·μ(1-μ)^6, a fitted to the exact F at "
                 "μ = 1/7 as Hoffman 2019's F82)")


def make(anisotropic: bool) -> Model:
    """The rough conductor model, isotropic or anisotropic."""

    def ndf(params, distribution="ggx", **_):
        return roughness.ndf(params, distribution, anisotropic)

    def eval(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
        """Walter eq. 20: F(i,h_r) G(i,o,h_r) D(h_r) / (4|i·n||o·n|)."""
        dist = ndf(params, distribution)
        ci, co = wi[..., 2], wo[..., 2]
        h = wi + wo  # Walter eq. 13 (wi.z > 0 here)
        hh = normalize(h)
        F = CONDUCTOR_FRESNEL_METHODS[fresnel](dot(wi, hh), params["n"], params["k"])
        G = dist.smith_G1(wi, hh) * dist.smith_G1(wo, hh)
        f = safe_div(F * G * dist.D(h), 4.0 * ci * co)
        return jnp.where((ci > 0) & (co > 0), f, 0.0)

    def pdf(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
        """p_m(h_r) / (4|o·h_r|) (Walter eqs 14, 24, 38; Heitz 2018 for visible normals)."""
        dist = ndf(params, distribution)
        p = roughness.reflection_pdf(dist, wi, wo, sampling)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), p, 0.0)

    def sample(params, wi, u, distribution="ggx", fresnel="exact", sampling="standard"):
        """m ~ D(m)|m·n| (or D_wi(m)), o = reflect(i, m) (eq. 39); weight = F · eq. 41."""
        dist = ndf(params, distribution)
        ci = wi[..., 2]
        m = roughness.sample_normal(dist, wi, u, sampling)
        c = dot(wi, m)
        wo = reflect(wi, m)
        co = wo[..., 2]
        valid = (ci > 0) & (c > 0) & (co > 0)
        F = CONDUCTOR_FRESNEL_METHODS[fresnel](c, params["n"], params["k"])
        weight = F * roughness.sample_weight(dist, wi, wo, m, sampling)
        p = safe_div(roughness.normal_pdf(dist, wi, m, sampling), 4.0 * c)
        return wo, jnp.where(valid, weight, 0.0), jnp.where(valid, p, 0.0)

    def scene_of(params, options):
        """A rough conductor substrate under the outside (index 1, so (n, k) relative to it are
        the scene's, which are relative to vacuum), behind the clear film an opaque substrate
        needs. The simulator's Fresnel is the exact one whatever ``fresnel`` says."""
        sub = {"type": "conductor", "n": float(params["n"]), "k": float(params["k"]),
               **roughness.scene_roughness(params, options.get("distribution", "ggx"),
                                           anisotropic)}
        return {"outside": dict(OUTSIDE), "stack": [clear_film(OUTSIDE["index"])],
                "substrate": sub, "effects": {"delta": False}}

    kind = "anisotropic " if anisotropic else ""
    return Model(
        name="rough_conductor_anisotropic" if anisotropic else "rough_conductor",
        summary=f"Walter 2007 {kind}microfacet BRDF of a rough conductor with complex index (n, k)",
        parameters=roughness.parameters(anisotropic) + INDEX,
        options=(roughness.distribution_option(anisotropic, "microfacet distribution"), FRESNEL,
                 roughness.SAMPLING),
        eval=eval,
        sample=sample,
        pdf=pdf,
        reference="Walter et al. 2007 eqs 13-14, 20, 23-36, 37-41; exact conductor Fresnel "
        "(unpolarized), Schlick, or Lazányi–Szirmay-Kalos 2005 with Hoffman 2019's fit of a"
        + ("; anisotropic D and G1 by slope stretching (Heitz 2014 eqs 80-86)" if anisotropic
           else ""),
        capabilities=Capabilities(isotropic=not anisotropic),
        microfacet=ndf,
        scene_of=scene_of,
        translations=(("mitsuba", "roughconductor"),),
    )


MODEL = make(anisotropic=False)
ANISOTROPIC = make(anisotropic=True)
