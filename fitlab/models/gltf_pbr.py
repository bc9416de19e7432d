"""glTF 2.0's metallic-roughness BRDF, as its specification fixes it (glTF 2.0 Specification,
Appendix B "BRDF Implementation"), with the extensions KHR_materials_ior and
KHR_materials_specular (``gltf_pbr``) and KHR_materials_clearcoat (``gltf_pbr_clearcoat``).

With L = wi (toward the light), V = wo (toward the viewer), H = normalize(L + V), α = r²
(``roughness_factor`` r is glTF's perceptual roughness, *not* fitlab's width α):

* ``specular_brdf(α)`` = ν D (Appendix B, "Specular BRDF"): GGX D = α² χ⁺(N·H) /
  (π ((N·H)²(α² − 1) + 1)²) and the **height-correlated** Smith visibility
  ν = χ⁺(H·L) χ⁺(H·V) / (2 (|N·V| √(α² + (1 − α²)(N·L)²) + |N·L| √(α² + (1 − α²)(N·V)²)))
  (fitlab's Walter models use the separable G1(i)G1(o); CONVENTIONS.md);
* ``diffuse_brdf`` = baseColor/π; Schlick's Fresnel with the weight (1 − |V·H|)⁵
  ("Fresnel");
* metal_brdf = (baseColor + (1 − baseColor)(1 − |V·H|)⁵) specular_brdf;
* dielectric_brdf (KHR_materials_specular, "Implementation", with KHR_materials_ior):
  f0 = min(((ior − 1)/(ior + 1))² specularColor, 1) specular, f90 = specular,
  F = f0 + (f90 − f0)(1 − |V·H|)⁵, dielectric_brdf = F specular_brdf + (1 − max_value(F))
  diffuse_brdf; with the defaults (ior 1.5, specular 1, specularColor 1) this is Appendix B's
  fresnel_mix with f0 = 0.04;
* material = mix(dielectric_brdf, metal_brdf, metallic) ("Metal BRDF and Dielectric BRDF");
* ``gltf_pbr_clearcoat`` (KHR_materials_clearcoat, "Implementation"): coated =
  mix(material, specular_brdf(α_c), clearcoat F_c) with F_c = 0.04 + 0.96 (1 − |N·V|)⁵ on the
  macro normal: the coat's Fresnel uses the *view* direction only, so this model is not
  reciprocal (the extension's own choice, stated in its "Discussion").

One value per colour channel of ``base_color`` (fitlab fits channels separately); the
specular colour enters max_value(F) over R, G, B, so here it is one grey value
(``specular_color``), the same for every channel, which keeps each channel's f exactly the
spec's. Not energy conserving at grazing angles (Appendix B's fresnel_mix weighs the
diffuse term per half vector: a white base colour reflects 1.115 of the light at 85°
incidence), as the specification's sample implementation says of itself ("non-physical
simplifications that break energy-conservation and reciprocity"). One-sided: zero unless
wi.z > 0 and wo.z > 0. Sampling: a mixture of the cosine
hemisphere (diffuse), GGX visible normals of α (Heitz 2018) and, with the coat, of α_c.
"""

from __future__ import annotations

import jax.numpy as jnp

from fitlab.frame import dot, normalize, reflect
from fitlab.microfacet import get_distribution
from fitlab.models import roughness
from fitlab.models.base import Capabilities, Model, Parameter, choose_branch, sample_result
from fitlab.models.diffuse import sample_cosine_hemisphere
from fitlab.numerics import safe_div

BASE_COLOR = Parameter("base_color", 0.0, 1.0, 0.5, "1",
                       "baseColorFactor (linear): diffuse colour of a dielectric, F0 of a metal",
                       "albedo")
METALLIC = Parameter("metallic", 0.0, 1.0, 0.0, "1", "metallicFactor: 0 dielectric, 1 metal")
ROUGHNESS_FACTOR = Parameter(
    "roughness_factor", 0.01, 1.0, 0.5, "1",
    "roughnessFactor, glTF's perceptual roughness r: the GGX width is α = r² (role other: "
    "fitlab's roughness role is α itself)")
IOR = Parameter("ior", 1.0, 3.0, 1.5, "1", "KHR_materials_ior ior (dielectric f0 = "
                "((ior - 1)/(ior + 1))²); 1.5 is glTF's default", "index")
SPECULAR = Parameter("specular", 0.0, 1.0, 1.0, "1",
                     "KHR_materials_specular specularFactor: strength of the dielectric "
                     "specular layer (and its f90)")
SPECULAR_COLOR = Parameter("specular_color", 0.0, 5.0, 1.0, "1",
                           "KHR_materials_specular specularColorFactor (grey): scales the "
                           "dielectric f0, clamped so f0 <= 1 (the spec allows values above 1)")
CLEARCOAT = Parameter("clearcoat", 0.0, 1.0, 0.0, "1",
                      "KHR_materials_clearcoat clearcoatFactor: strength of the coat")
CLEARCOAT_ROUGHNESS = Parameter(
    "clearcoat_roughness_factor", 0.01, 1.0, 0.1, "1",
    "KHR_materials_clearcoat clearcoatRoughnessFactor (perceptual; α_c = r_c²)")

#: Schlick f0 of the clear coat (ior 1.5, fixed by KHR_materials_clearcoat).
COAT_F0 = 0.04
#: Smallest share of the diffuse and specular branches in sampling (every lobe stays reachable).
_P_MIN = 0.05


def alpha_of(roughness_factor):
    """GGX width α = r² of glTF's perceptual roughness (Appendix B, "Microfacet Surfaces")."""
    return roughness_factor * roughness_factor


def visibility_height_correlated(wi, wo, alpha):
    """ν = G/(4|N·L||N·V|) with the height-correlated Smith G of GGX (Appendix B, "Specular
    BRDF"; Heitz 2014 eq. 99), without the χ⁺ factors (the caller's)."""
    a2 = alpha * alpha
    nl, nv = jnp.abs(wi[..., 2]), jnp.abs(wo[..., 2])
    den = nv * jnp.sqrt(a2 + (1.0 - a2) * nl * nl) + nl * jnp.sqrt(a2 + (1.0 - a2) * nv * nv)
    return safe_div(0.5, den)


def specular_brdf(wi, wo, h, alpha):
    """ν D of GGX at the half vector ``h`` (unnormalized L + V)."""
    return visibility_height_correlated(wi, wo, alpha) * get_distribution("ggx")(alpha).D(h)


def schlick_weight(c):
    """(1 - |c|)⁵, Schlick's Fresnel weight (Appendix B, "Fresnel")."""
    x = 1.0 - jnp.clip(jnp.abs(c), 0.0, 1.0)
    x2 = x * x
    return x2 * x2 * x


def dielectric_f0(params):
    """min(((ior - 1)/(ior + 1))² specularColor, 1) (KHR_materials_specular with
    KHR_materials_ior), before the specular factor."""
    ior = params["ior"]
    r = safe_div(ior - 1.0, ior + 1.0)
    return jnp.minimum(r * r * params["specular_color"], 1.0)


def core_brdf(params, wi, wo):
    """The metallic-roughness material with KHR_materials_ior and _specular (reflection side)."""
    h = wi + wo
    hh = normalize(h)
    w = schlick_weight(dot(wo, hh))
    spec = specular_brdf(wi, wo, h, alpha_of(params["roughness_factor"]))
    base = params["base_color"]
    s = params["specular"]
    F_d = dielectric_f0(params) * s + (s - dielectric_f0(params) * s) * w  # f0 + (f90 - f0) w
    dielectric = F_d * spec + (1.0 - F_d) * base / jnp.pi
    metal = (base + (1.0 - base) * w) * spec
    m = params["metallic"]
    return (1.0 - m) * dielectric + m * metal


def coat_weight(params, wo):
    """clearcoat · F_c with F_c = 0.04 + 0.96 (1 - |N·V|)⁵ (KHR_materials_clearcoat)."""
    return params["clearcoat"] * (COAT_F0 + (1.0 - COAT_F0) * schlick_weight(wo[..., 2]))


def _upper(wi, wo):
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def make(clearcoat: bool) -> Model:
    """``gltf_pbr`` (core + ior + specular) or ``gltf_pbr_clearcoat`` (+ the clear coat)."""

    def eval(params, wi, wo):
        f = core_brdf(params, wi, wo)
        if clearcoat:
            c = coat_weight(params, wo)
            coat = specular_brdf(wi, wo, wi + wo,
                                 alpha_of(params["clearcoat_roughness_factor"]))
            f = (1.0 - c) * f + c * coat
        return jnp.where(_upper(wi, wo), f, 0.0)

    def lobes(params, like):
        """Branch probabilities (diffuse, specular[, coat]) of the sampling mixture."""
        one = jnp.ones_like(like)
        diffuse = (1.0 - params["metallic"]) * params["base_color"] * one
        spec = one
        ws = [diffuse + _P_MIN, spec]
        if clearcoat:
            ws.append(params["clearcoat"] * one)
        W = jnp.stack(ws)
        return W / jnp.sum(W, axis=0)

    def dists(params):
        out = [get_distribution("ggx")(alpha_of(params["roughness_factor"]))]
        if clearcoat:
            out.append(get_distribution("ggx")(alpha_of(params["clearcoat_roughness_factor"])))
        return out

    def pdf(params, wi, wo):
        P = lobes(params, wi[..., 2])
        h = wi + wo
        hh = normalize(h)
        o_h = dot(wo, hh)
        p = P[0] * jnp.maximum(wo[..., 2], 0.0) / jnp.pi
        for k, dist in enumerate(dists(params), start=1):
            p = p + P[k] * safe_div(roughness.normal_pdf(dist, wi, hh, "visible", h), 4.0 * o_h)
        return jnp.where(_upper(wi, wo) & (o_h > 0), p, 0.0)

    def sample(params, wi, u):
        P = lobes(params, wi[..., 2])
        pick, u = choose_branch(P, u)
        wo = sample_cosine_hemisphere(u)
        for k, dist in enumerate(dists(params), start=1):
            m = roughness.sample_normal(dist, wi, u, "visible")
            wo = jnp.where((pick == k)[..., None], reflect(wi, m), wo)
        return sample_result(wo, eval(params, wi, wo), pdf(params, wi, wo), _upper(wi, wo))

    params = (BASE_COLOR, METALLIC, ROUGHNESS_FACTOR, IOR, SPECULAR, SPECULAR_COLOR)
    if clearcoat:
        params += (CLEARCOAT, CLEARCOAT_ROUGHNESS)
    return Model(
        name="gltf_pbr_clearcoat" if clearcoat else "gltf_pbr",
        summary="glTF 2.0 metallic-roughness BRDF (Appendix B) with KHR_materials_ior and "
        "_specular" + (", under KHR_materials_clearcoat's coat" if clearcoat else ""),
        parameters=params,
        options=(),
        eval=eval,
        sample=sample,
        pdf=pdf,
        reference="glTF 2.0 Specification Appendix B (specular_brdf: GGX D, height-correlated "
        "Smith visibility; diffuse_brdf; Schlick Fresnel; metal and dielectric BRDFs); "
        "KHR_materials_specular and KHR_materials_ior (dielectric f0, f90, max_value "
        "weighting)" + ("; KHR_materials_clearcoat (fresnel_coat with N·V)" if clearcoat
                        else "") + "; sampling: cosine hemisphere + GGX visible normals "
        "(Heitz 2018)",
        # KHR_materials_clearcoat's Fresnel uses N·V alone: f(i, o) != f(o, i). Appendix B's
        # fresnel_mix weighs the diffuse term by 1 - F(V·H) per half vector, which is not an
        # energy balance: a white base_color reflects 1.115 of the light at 85° incidence
        # (tests/test_gltf_model.py measures it).
        capabilities=Capabilities(reciprocal=not clearcoat, energy_conserving=False),
    )


MODEL = make(clearcoat=False)
CLEARCOAT_MODEL = make(clearcoat=True)
