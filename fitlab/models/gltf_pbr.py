"""glTF 2.0's metallic-roughness BRDF, as its specification fixes it (glTF 2.0 Specification,
Appendix B "BRDF Implementation"), with the extensions KHR_materials_ior and
KHR_materials_specular (``gltf_pbr``), and each of KHR_materials_clearcoat
(``gltf_pbr_clearcoat``), KHR_materials_anisotropy (``gltf_pbr_anisotropic``) and
KHR_materials_transmission (``gltf_pbr_transmission``) on top.

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
  reciprocal (the extension's own choice, stated in its "Discussion");
* ``gltf_pbr_anisotropic`` (KHR_materials_anisotropy, "Anisotropy" and "Implementation"): the
  width along the anisotropy direction (the tangent +x turned by ``anisotropy_rotation``
  counter-clockwise) is α_t = mix(α, 1, strength²), across it α_b = α; Burley's anisotropic
  GGX D and the anisotropic height-correlated ν = 0.5 / (N·L |(α_t T·V, α_b B·V, N·V)| +
  N·V |(α_t T·L, α_b B·L, N·L)|);
* ``gltf_pbr_transmission`` (KHR_materials_transmission, "Transmission BTDF" and
  "Implementation Notes"): the dielectric's base becomes mix(diffuse_brdf, specular_btdf ·
  baseColor, transmission); specular_btdf = ν_T D_T of the *thin-walled* surface (no
  refraction on average): H_T is the half vector of V and L mirrored through the surface
  (normalize(V − 2(N·L)N + L), with N on the viewer's side), D_T GGX and ν_T the *separable*
  Smith visibility (as that README writes it). The README does not say which half vector the
  fresnel_mix of a transmitted pair uses; fitlab uses H_T (the microfacet of the thin prism),
  so reflection and transmission share one Fresnel per microfacet.

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

from fitlab._jax import jnp
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

ANISOTROPY_STRENGTH = Parameter(
    "anisotropy_strength", 0.0, 1.0, 0.0, "1",
    "KHR_materials_anisotropyStrength: α_t = mix(α, 1, strength²) along the anisotropy "
    "direction")
ANISOTROPY_ROTATION = Parameter(
    "anisotropy_rotation", -90.0, 90.0, 0.0, "deg",
    "KHR_materials_anisotropy anisotropyRotation in degrees (radians in the file), counter-"
    "clockwise from the tangent +x to the direction of α_t")
TRANSMISSION = Parameter("transmission", 0.0, 1.0, 0.0, "1",
                         "KHR_materials_transmission transmissionFactor: share of the "
                         "dielectric base that is transmitted (thin-walled)")

#: Schlick f0 of the clear coat (ior 1.5, fixed by KHR_materials_clearcoat).
COAT_F0 = 0.04
#: Smallest share of the diffuse and specular branches in sampling (every lobe stays reachable).
_P_MIN = 0.05


def alpha_of(roughness_factor):
    """GGX width α = r² of glTF's perceptual roughness (Appendix B, "Microfacet Surfaces")."""
    return roughness_factor * roughness_factor


def visibility_height_correlated(wi, wo, alpha, alpha_b=None):
    """ν = G/(4|N·L||N·V|) with the height-correlated Smith G of GGX (Appendix B, "Specular
    BRDF"; Heitz 2014 eq. 99), without the χ⁺ factors (the caller's). Anisotropic (widths
    ``alpha`` along +x, ``alpha_b`` along +y): KHR_materials_anisotropy's V_GGX_anisotropic,
    0.5 / (N·L |(α_t T·V, α_b B·V, N·V)| + N·V |(α_t T·L, α_b B·L, N·L)|), the same function
    (√(α² + (1 − α²)c²) = |(α s, c)| for a unit vector)."""
    ab = alpha if alpha_b is None else alpha_b

    def length(w):
        return jnp.sqrt((alpha * w[..., 0]) ** 2 + (ab * w[..., 1]) ** 2 + w[..., 2] ** 2)

    nl, nv = jnp.abs(wi[..., 2]), jnp.abs(wo[..., 2])
    return safe_div(0.5, nl * length(wo) + nv * length(wi))


def specular_brdf(wi, wo, h, alpha, alpha_b=None):
    """ν D of GGX at the half vector ``h`` (unnormalized L + V); anisotropic with ``alpha``
    along +x and ``alpha_b`` along +y (Burley's D: fitlab.microfacet.D_GGX)."""
    return (visibility_height_correlated(wi, wo, alpha, alpha_b)
            * get_distribution("ggx")(alpha, alpha_b).D(h))


def rotate_z(w, degrees):
    """``w`` turned by -``degrees`` about the normal: into the frame whose +x is the tangent
    turned counter-clockwise by ``degrees`` (KHR_materials_anisotropy's direction)."""
    r = jnp.radians(degrees)
    c, s_ = jnp.cos(r), jnp.sin(r)
    x, y = c * w[..., 0] + s_ * w[..., 1], -s_ * w[..., 0] + c * w[..., 1]
    # z broadcast too: parameters stacked per channel, (C, 1), widen x and y to (C, N)
    return jnp.stack([x, y, jnp.broadcast_to(w[..., 2], x.shape)], axis=-1)


def unrotate_z(w, degrees):
    """The inverse of :func:`rotate_z`."""
    return rotate_z(w, -degrees)


def anisotropic_widths(params):
    """(α_t, α_b) of KHR_materials_anisotropy: mix(α, 1, strength²) and α = r²."""
    a = alpha_of(params["roughness_factor"])
    s2 = params["anisotropy_strength"] ** 2
    return a + (1.0 - a) * s2, a


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


def dielectric_fresnel(params, w):
    """f0 + (f90 − f0) w with KHR_materials_specular's f0 and f90 = specular."""
    s = params["specular"]
    f0 = dielectric_f0(params) * s
    return f0 + (s - f0) * w


def core_brdf(params, wi, wo, widths=None, transmission=None):
    """The metallic-roughness material with KHR_materials_ior and _specular (reflection side);
    ``widths``: (α_t, α_b) of an anisotropic lobe (directions in its frame); ``transmission``:
    the transmitted share of the dielectric base (its reflection side keeps 1 − it)."""
    h = wi + wo
    hh = normalize(h)
    w = schlick_weight(dot(wo, hh))
    a_t, a_b = widths if widths is not None else (alpha_of(params["roughness_factor"]), None)
    spec = specular_brdf(wi, wo, h, a_t, a_b)
    base = params["base_color"]
    F_d = dielectric_fresnel(params, w)
    diffuse = base / jnp.pi if transmission is None else (1.0 - transmission) * base / jnp.pi
    dielectric = F_d * spec + (1.0 - F_d) * diffuse
    metal = (base + (1.0 - base) * w) * spec
    m = params["metallic"]
    return (1.0 - m) * dielectric + m * metal


def mirror_z(w):
    """``w`` mirrored through the surface plane."""
    return w * jnp.asarray([1.0, 1.0, -1.0], dtype=w.dtype)


def thin_btdf(params, wi, wo):
    """The transmitted side of ``gltf_pbr_transmission``: (1 − metallic) transmission (1 − F)
    baseColor ν_T D_T (KHR_materials_transmission), for wi and wo on opposite sides. With L
    mirrored through the surface onto V's side, H_T is their half vector and the BTDF is the
    reflection lobe's shape with the separable visibility."""
    side = jnp.sign(wo[..., 2])[..., None]
    v = wo * side  # the viewer's side up
    l_m = mirror_z(wi) * side
    h = v + l_m
    hh = normalize(h)
    a = alpha_of(params["roughness_factor"])
    dist = get_distribution("ggx")(a)
    nu_t = safe_div(dist.G1(l_m) * dist.G1(v), 4.0 * jnp.abs(l_m[..., 2]) * jnp.abs(v[..., 2]))
    F = dielectric_fresnel(params, schlick_weight(dot(v, hh)))
    return ((1.0 - params["metallic"]) * params["transmission"] * (1.0 - F)
            * params["base_color"] * nu_t * dist.D(h))


def coat_weight(params, wo):
    """clearcoat · F_c with F_c = 0.04 + 0.96 (1 - |N·V|)⁵ (KHR_materials_clearcoat)."""
    return params["clearcoat"] * (COAT_F0 + (1.0 - COAT_F0) * schlick_weight(wo[..., 2]))


def _upper(wi, wo):
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


def make(extension: str | None = None) -> Model:
    """``gltf_pbr`` (core + ior + specular), or with one more extension: ``clearcoat``,
    ``anisotropy`` or ``transmission``."""
    coat = extension == "clearcoat"
    aniso = extension == "anisotropy"
    trans = extension == "transmission"

    def frame(params, w):
        return rotate_z(w, params["anisotropy_rotation"]) if aniso else w

    def widths(params):
        return anisotropic_widths(params) if aniso else None

    def eval(params, wi, wo):
        wi_f, wo_f = frame(params, wi), frame(params, wo)
        f = core_brdf(params, wi_f, wo_f, widths(params),
                      params["transmission"] if trans else None)
        if coat:
            c = coat_weight(params, wo)
            lobe = specular_brdf(wi, wo, wi + wo,
                                 alpha_of(params["clearcoat_roughness_factor"]))
            f = (1.0 - c) * f + c * lobe
        f = jnp.where(_upper(wi, wo), f, 0.0)
        if trans:
            crossing = (wi[..., 2] > 0) & (wo[..., 2] < 0)
            f = jnp.where(crossing, thin_btdf(params, wi, wo), f)
        return f

    def lobes(params, like):
        """Branch probabilities (diffuse, specular[, coat | transmission]) of the sampling
        mixture."""
        one = jnp.ones_like(like)
        diffuse = (1.0 - params["metallic"]) * params["base_color"] * one
        ws = [diffuse + _P_MIN, one]
        if coat:
            ws.append(params["clearcoat"] * one)
        if trans:
            ws[0] = ws[0] * (1.0 - params["transmission"]) + _P_MIN
            ws.append((1.0 - params["metallic"]) * params["transmission"] * one)
        W = jnp.stack(ws)
        return W / jnp.sum(W, axis=0)

    def specular_dist(params):
        a = widths(params)
        return get_distribution("ggx")(*a) if aniso else \
            get_distribution("ggx")(alpha_of(params["roughness_factor"]))

    def reflection_dists(params):
        out = [specular_dist(params)]
        if coat:
            out.append(get_distribution("ggx")(alpha_of(params["clearcoat_roughness_factor"])))
        return out

    def lobe_pdf(dist, wi, wo):
        return roughness.reflection_pdf(dist, wi, wo, "visible")

    def pdf(params, wi, wo):
        P = lobes(params, wi[..., 2])
        up = _upper(wi, wo)
        p = P[0] * jnp.maximum(wo[..., 2], 0.0) / jnp.pi
        wi_f, wo_f = frame(params, wi), frame(params, wo)
        dists = reflection_dists(params)
        p = p + P[1] * lobe_pdf(dists[0], wi_f, wo_f)
        if coat:
            p = p + P[2] * lobe_pdf(dists[1], wi, wo)
        p = jnp.where(up, p, 0.0)
        if trans:  # the specular lobe's density, mirrored through the surface
            crossing = (wi[..., 2] > 0) & (wo[..., 2] < 0)
            p = jnp.where(crossing, P[2] * lobe_pdf(dists[0], wi, mirror_z(wo)), p)
        return p

    def sample(params, wi, u):
        P = lobes(params, wi[..., 2])
        pick, u = choose_branch(P, u)
        wo = sample_cosine_hemisphere(u)
        wi_f = frame(params, wi)
        dists = reflection_dists(params)
        m = roughness.sample_normal(dists[0], wi_f, u, "visible")
        spec_wo = unrotate_z(reflect(wi_f, m), params["anisotropy_rotation"]) if aniso \
            else reflect(wi_f, m)
        wo = jnp.where((pick == 1)[..., None], spec_wo, wo)
        # a microfacet sample is valid when its reflection leaves above the surface
        valid = (wi[..., 2] > 0) & ((pick == 0) | (spec_wo[..., 2] > 0))
        if coat:
            coat_wo = reflect(wi, roughness.sample_normal(dists[1], wi, u, "visible"))
            wo = jnp.where((pick == 2)[..., None], coat_wo, wo)
            valid = (wi[..., 2] > 0) & jnp.where(pick == 2, coat_wo[..., 2] > 0,
                                                  (pick == 0) | (spec_wo[..., 2] > 0))
        if trans:  # the thin BTDF: the specular lobe mirrored through the surface
            wo = jnp.where((pick == 2)[..., None], mirror_z(spec_wo), wo)
        return sample_result(wo, eval(params, wi, wo), pdf(params, wi, wo), valid)

    params = (BASE_COLOR, METALLIC, ROUGHNESS_FACTOR, IOR, SPECULAR, SPECULAR_COLOR)
    params += {"clearcoat": (CLEARCOAT, CLEARCOAT_ROUGHNESS),
               "anisotropy": (ANISOTROPY_STRENGTH, ANISOTROPY_ROTATION),
               "transmission": (TRANSMISSION,), None: ()}[extension]
    ext_name = {"clearcoat": "KHR_materials_clearcoat", "anisotropy": "KHR_materials_anisotropy",
                "transmission": "KHR_materials_transmission", None: ""}[extension]
    return Model(
        name="gltf_pbr" + (f"_{'anisotropic' if aniso else extension}" if extension else ""),
        summary="glTF 2.0 metallic-roughness BRDF (Appendix B) with KHR_materials_ior and "
        "_specular" + (f" and {ext_name}" if extension else ""),
        parameters=params,
        options=(),
        eval=eval,
        sample=sample,
        pdf=pdf,
        reference="glTF 2.0 Specification Appendix B (specular_brdf: GGX D, height-correlated "
        "Smith visibility; diffuse_brdf; Schlick Fresnel; metal and dielectric BRDFs); "
        "KHR_materials_specular and KHR_materials_ior (dielectric f0, f90, max_value "
        "weighting)" + {"clearcoat": "; KHR_materials_clearcoat (fresnel_coat with N·V)",
                        "anisotropy": "; KHR_materials_anisotropy (α_t = mix(α, 1, s²), "
                        "Burley's D, anisotropic height-correlated V)",
                        "transmission": "; KHR_materials_transmission (thin-walled "
                        "specular_btdf: mirrored half vector, separable visibility)",
                        None: ""}[extension]
        + "; sampling: cosine hemisphere + GGX visible normals (Heitz 2018)",
        # KHR_materials_clearcoat's Fresnel uses N·V alone: f(i, o) != f(o, i). Appendix B's
        # fresnel_mix weighs the diffuse term by 1 - F(V·H) per half vector, which is not an
        # energy balance: a white base_color reflects 1.115 of the light at 85° incidence
        # (tests/models/test_gltf_model.py measures it).
        capabilities=Capabilities(reciprocal=not coat, energy_conserving=False,
                                  isotropic=not aniso, transmission=trans),
    )


MODEL = make()
CLEARCOAT_MODEL = make("clearcoat")
ANISOTROPIC_MODEL = make("anisotropy")
TRANSMISSION_MODEL = make("transmission")
