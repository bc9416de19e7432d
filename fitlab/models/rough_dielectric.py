"""Rough dielectric interface: Walter et al. 2007 microfacet BRDF + BTDF (eqs 13-21, 37-41),
isotropic (``rough_dielectric``, width α) and anisotropic (``rough_dielectric_anisotropic``,
widths α_x, α_y along the tangent +x, +y; Mitsuba's ``roughdielectric`` with alpha_u, alpha_v).

Parameter ``eta`` is the relative index n_inside / n_outside, "inside" being the -z side.
Either side may be the denser one (eta < 1: denser outside medium). For incidence from inside
(wi.z < 0) the configuration is mirrored through the tangent plane and eta inverted, which is
exact for these heightfield distributions (the mirror keeps x and y, so the anisotropic widths
too); after the flip η_i = 1 and η_o = eta, with ``eta`` = η_o/η_i, the incident side being +z.

The BTDF is eq. 21 (radiance transport): f_t(i,o)/η_o² = f_t(o,i)/η_i².

Option ``fresnel``: ``exact`` (Walter eq. 22, the default) or ``schlick`` (Schlick's
approximation, F0 = ((η-1)/(η+1))², the real-time shortcut; for light from the denser side it
takes the cosine of the transmitted direction, so F = 1 under total internal reflection and the
reflectance of a crossing equals that of its reverse: ``fitlab.fresnel.fresnel_dielectric_Schlick``).
Either F weighs reflection (eq. 20) and 1 - F transmission (eq. 21) and the sampler's choice
between them (section 5.3), so R + T = 1 per microfacet whichever is chosen.
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.fresnel import DIELECTRIC_FRESNEL_METHODS, fresnel_dielectric
from fitlab.frame import dot, flip_z, half_vector_transmission, normalize, reflect, refracted
from fitlab.models import roughness
from fitlab.models.base import (OUTSIDE, Capabilities, Model, Option, Parameter, clear_film,
                                interface)
from fitlab.numerics import safe_div, safe_rsqrt, sign_nonzero

ETA = Parameter("eta", 0.2, 5.0, 1.5, "1", "relative index n_inside / n_outside (inside = -z side)",
                "index")

FRESNEL = Option("fresnel", tuple(DIELECTRIC_FRESNEL_METHODS), "exact",
                 "dielectric Fresnel: exact (Walter eq. 22) or schlick (F0 = ((η-1)/(η+1))²; "
                 "from the denser side with the transmitted cosine, so total internal "
                 "reflection stays 1)")


def _to_upper_frame(wi, wo, eta):
    """Mirror so that wi.z >= 0; the relative index becomes η_o/η_i for that incident side."""
    s = sign_nonzero(wi[..., 2])
    return flip_z(wi, s), flip_z(wo, s), jnp.where(s > 0, eta, 1.0 / eta), s


def _half_vector(wi, wo, eta):
    """Unnormalized half-vector (eq. 13 for reflection, eq. 16 for refraction) in the upper frame."""
    is_r = wo[..., 2] > 0
    h = jnp.where(is_r[..., None], wi + wo, half_vector_transmission(wi, wo, eta))
    return h, is_r


#: ``force`` codes of :func:`walter_sample`: choose by F, reflect, refract
CHOOSE, REFLECT, REFRACT = 0, 1, 2


def walter_sample(dist, params, wi, u, sampling="standard", force=None, fresnel="exact"):
    """Walter section 5.3 with NDF ``dist``: sample m ~ D(m)|m·n| (or its widened or visible
    variant), choose reflection with probability F(i,m) (``u[..., 2] < F``), reflect (eq. 39) or
    refract (eq. 40); weight by eq. 41. Returns (wo, weight, pdf) as a registry ``sample``.

    ``force`` (optional, int array broadcasting with wi's batch shape): per sample, CHOOSE (the
    Fresnel choice above), REFLECT or REFRACT: the branch is taken with probability 1 and the
    weight carries its probability F or 1 − F instead (branch forcing: unbiased for whatever
    the other branch would not have reached). The returned density stays that of the unforced
    sampling (``pdf``), so that multiple-importance weights built from it still sum to 1.
    ``fresnel``: a name in ``DIELECTRIC_FRESNEL_METHODS`` for F (the refracted direction is
    Snell's either way)."""
    wi, _, eta, s = _to_upper_frame(wi, wi, params["eta"])
    ci = wi[..., 2]
    m = roughness.sample_normal(dist, wi, u, sampling)
    c = dot(wi, m)
    # one Fresnel evaluation gives F and the refracted cosine (c > 0 on valid samples)
    F, cos_t, _, eta_ti = fresnel_dielectric(c, eta)
    if fresnel != "exact":
        F = DIELECTRIC_FRESNEL_METHODS[fresnel](c, eta)
    choose_r = u[..., 2] < F
    if force is not None:
        choose_r = jnp.where(force == CHOOSE, choose_r, force == REFLECT)
    wo_r = reflect(wi, m)  # Walter eq. 39
    wo_t = refracted(wi, m, cos_t, eta_ti)  # Walter eq. 40 (TIR: F = 1, never chosen)
    wo = jnp.where(choose_r[..., None], wo_r, wo_t)
    co = wo[..., 2]
    valid = (ci > 0) & (c > 0) & jnp.where(choose_r, co > 0, co < 0)
    weight = roughness.sample_weight(dist, wi, wo, m, sampling)  # Walter eq. 41
    if force is not None:
        weight = weight * jnp.where(force == CHOOSE, 1.0, jnp.where(choose_r, F, 1.0 - F))
    p_m = roughness.normal_pdf(dist, wi, m, sampling)
    o_m = dot(wo, m)
    h2 = (c + eta * o_m) ** 2
    p = p_m * jnp.where(choose_r, F * safe_div(1.0, 4.0 * jnp.abs(o_m)),
                        (1.0 - F) * safe_div(eta**2 * jnp.abs(o_m), h2))
    weight = jnp.where(valid, weight, 0.0)
    p = jnp.where(valid, p, 0.0)
    return flip_z(wo, s), weight, p


def make(anisotropic: bool) -> Model:
    """The rough dielectric model, isotropic or anisotropic."""

    def ndf(params, distribution="ggx", **_):
        return roughness.ndf(params, distribution, anisotropic)

    def eval(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
        """f_r (Walter eq. 20) + f_t (eq. 21), in 1/sr without the cosine.

        Written on vector components (no size-3 reductions or concatenations of intermediates), so
        that XLA compiles the whole evaluation into one elementwise loop; the steps are those of
        ``_to_upper_frame`` and ``_half_vector`` (see ``benchmarks/bench_btdf_eval.py``)."""
        dist = ndf(params, distribution)
        ix, iy, iz = wi[..., 0], wi[..., 1], wi[..., 2]
        ox, oy, oz = wo[..., 0], wo[..., 1], wo[..., 2]
        # Mirror to the upper frame (wi.z >= 0); eta becomes η_o/η_i for that incident side.
        s = sign_nonzero(iz)
        ci, co = iz * s, oz * s
        eta = jnp.where(s > 0, params["eta"], 1.0 / params["eta"])
        is_r = co > 0
        # Unnormalized half-vector: wi + wo (eq. 13) or wi + eta wo (eq. 16), turned to +z.
        e = jnp.where(is_r, 1.0, eta)
        t = sign_nonzero(ci + e * co)
        hx, hy, hz = (ix + e * ox) * t, (iy + e * oy) * t, (ci + e * co) * t
        h2 = hx * hx + hy * hy + hz * hz
        r = safe_rsqrt(h2)  # 1/|h|: i·ĥ and o·ĥ without normalizing h itself
        i_h = (ix * hx + iy * hy + ci * hz) * r
        o_h = (ox * hx + oy * hy + co * hz) * r
        F = DIELECTRIC_FRESNEL_METHODS[fresnel](i_h, eta)  # Walter eq. 22 or Schlick
        D = dist.D(jnp.stack([hx, hy, hz], axis=-1))  # degree-0 homogeneous in h
        # Walter eq. 23: separable Smith G; the sidedness factors discard backfacing microfacets.
        G = dist.smith_G(jnp.stack([ix, iy, ci], axis=-1), jnp.stack([ox, oy, co], axis=-1),
                         i_h * ci > 0, o_h * co > 0)
        cos_prod = ci * jnp.abs(co)
        # Walter eq. 20, f_r = F G D / (4 |i·n| |o·n|), and eq. 21 with η_i = 1, η_o = eta,
        # f_t = |i·h||o·h| eta² (1 - F) G D / (|i·n||o·n| |h_t|²) ((η_i(i·h) + η_o(o·h))² = |h_t|² for
        # the unnormalized h_t), sharing one division.
        num = jnp.where(is_r, F, jnp.abs(i_h * o_h) * eta**2 * (1.0 - F)) * G * D
        f = safe_div(num, cos_prod * jnp.where(is_r, 4.0, h2))
        return jnp.where(ci > 0, f, 0.0)

    def pdf(params, wi, wo, distribution="ggx", fresnel="exact", sampling="standard"):
        """Density of ``sample``: p_m(h)|∂ω_h/∂ω_o| times the Fresnel choice (Walter eqs 14, 17,
        24, 38; Heitz 2018 eq. 1 for visible normals)."""
        dist = ndf(params, distribution)
        wi, wo, eta, _ = _to_upper_frame(wi, wo, params["eta"])
        ci = wi[..., 2]
        h, is_r = _half_vector(wi, wo, eta)
        hh = normalize(h)
        i_h, o_h = dot(wi, hh), dot(wo, hh)
        F = DIELECTRIC_FRESNEL_METHODS[fresnel](i_h, eta)
        p_m = roughness.normal_pdf(dist, wi, hh, sampling, h)  # Walter eq. 24
        jac_r = safe_div(1.0, 4.0 * jnp.abs(o_h))  # Walter eq. 14
        jac_t = safe_div(eta**2 * jnp.abs(o_h), dot(h, h))  # Walter eq. 17
        p = p_m * jnp.where(is_r, F * jac_r, (1.0 - F) * jac_t)
        # Only microfacets facing both directions can be sampled (Mitsuba does the same).
        facing = (i_h > 0) & (o_h * wo[..., 2] > 0) & (ci > 0)
        return jnp.where(facing, p, 0.0)

    def sample(params, wi, u, distribution="ggx", fresnel="exact", sampling="standard"):
        """Walter section 5.3: sample m ~ D(m)|m·n|, choose reflection with probability F(i,m),
        reflect (eq. 39) or refract (eq. 40); weight by eq. 41 (times D/D† for widened sampling;
        G1(o, m) for visible normals)."""
        return walter_sample(ndf(params, distribution), params, wi, u, sampling,
                             fresnel=fresnel)

    def scene_of(params, options):
        """One rough interface between the outside (index 1) and the medium below of index η
        (``eta`` = n_inside / n_outside). η = 1 is no interface: a clear film stands in, since
        a scene needs one item. The simulator's Fresnel is the exact one whatever ``fresnel``
        says."""
        eta = float(params["eta"])
        rough = roughness.scene_roughness(params, options.get("distribution", "ggx"),
                                          anisotropic)
        stack = interface(OUTSIDE["index"], eta, **rough) or [clear_film(OUTSIDE["index"])]
        return {"outside": dict(OUTSIDE), "stack": stack, "below": {"index": eta},
                "effects": {"delta": False}}

    kind = "anisotropic " if anisotropic else ""
    return Model(
        name="rough_dielectric_anisotropic" if anisotropic else "rough_dielectric",
        summary=f"Walter 2007 {kind}rough dielectric interface: microfacet BRDF + BTDF",
        parameters=roughness.parameters(anisotropic) + (ETA,),
        options=(roughness.distribution_option(
            anisotropic, "microfacet distribution (beckmann: exact erf G1; beckmann_rational: "
            "eq. 27 G1)"), FRESNEL, roughness.SAMPLING),
        eval=eval,
        sample=sample,
        pdf=pdf,
        reference="Walter et al. 2007 eqs 13-22 (BSDF), 23-36 (D, G1), 37-41 (sampling); "
        "separable Smith G; BTDF for radiance transport (eq. 21); Schlick's Fresnel "
        "(fresnel=schlick) with the transmitted cosine from the denser side"
        + ("; anisotropic D and G1 by slope stretching (Heitz 2014 eqs 80-86)" if anisotropic
           else ""),
        # f_t(i,o)/η_o² = f_t(o,i)/η_i²: reciprocal on the reflection side, generalized
        # reciprocity in transmission (Walter eq. 21)
        capabilities=Capabilities(transmission=True, isotropic=not anisotropic),
        microfacet=ndf,
        scene_of=scene_of,
        translations=(("mitsuba", "roughdielectric"),),
    )


MODEL = make(anisotropic=False)
ANISOTROPIC = make(anisotropic=True)
