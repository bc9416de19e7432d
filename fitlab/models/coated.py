"""Any registry BSDF seen through a smooth dielectric coating (``coated(INNER)``), after
``bsdf_under_smooth_interface`` (the blog post "BSDF under a smooth refractive interface"):

    f(ωi, ωo) = T(θi) T(θo) (η0²/η1²) f_inner(ωi', ωo') a(ωi', ωo')          (single bounce)

ωi', ωo' are the refracted directions (Snell through the macro normal), T = 1 - F the Fresnel
transmittances of the smooth interface, η0²/η1² = 1/η² the solid-angle (de)compression of the
crossing down and back up, and a = exp(-τ (1/cos θi' + 1/cos θo')) the Beer–Lambert absorption
of the coat along both refracted paths (Elek 2010 eq. 3 with optical depth τ = σa·d; only the
product enters the single-point model, so it is one parameter). Only paths that bounce once off
the inner BSDF are kept (the blog's single-scattering-event simplification) and light leaves at
the point it entered (single-point simplification).

The interface's own reflection is a Dirac delta F(θi) δ(ωo - mirror(ωi)). It is *not* part of
``eval``/``pdf``/``sample``: fits exclude the measured rows within a stated cone of the mirror
direction and tables hold the non-delta part (data_formats/layered_models.md);
:func:`specular_reflectance` gives its weight. ``coated(INNER,specular=lobe)`` instead adds a
narrow GGX reflection lobe of width ``coat_alpha`` with the coat's dielectric Fresnel (Walter
eq. 20), for measurements whose "specular" peak is resolved by the instrument.

Option ``interreflection=closed_form`` (Lambertian inner only) sums the multiple reflections
between the interface and the base in closed form (see :func:`_closed_form_factor`); the default
``single`` is the paper's single-bounce model.

The inner BSDF's transmission (if it has one) leaves the stack through the bottom: the coated
model is a BRDF (lobes = reflection), zero for wi.z <= 0 or wo.z <= 0.
"""

from __future__ import annotations

import functools

from fitlab._jax import jnp
from fitlab.fresnel import fresnel_dielectric_Walter2007
from fitlab.interface import (beer_lambert, internal_diffuse_reflectance, refract_down,
                              refract_up, solid_angle_compression, transmittance)
from fitlab.models import rough_conductor
from fitlab.models.base import (OUTSIDE, Capabilities, Model, Option, Parameter, Term,
                                absorbing_slab, interface, layered_scene, sample_result)
from fitlab.models.syntax import call_arguments
from fitlab.numerics import safe_div

NAME = "coated"
SPECULAR_CHOICES = ("delta", "lobe")

COAT_ETA = Parameter("coat_eta", 1.0, 3.0, 1.5, "1",
                     "relative index of the coat over the outside medium η = η1/η0", "index")
COAT_TAU = Parameter("coat_tau", 0.0, 20.0, 0.0, "1",
                     "optical depth of the coat at normal incidence τ = σa·d (thickness times "
                     "absorption coefficient of the channel); 0 = clear coat", "optical_depth")
COAT_ALPHA = Parameter("coat_alpha", 1e-4, 1.0, 0.02, "1",
                       "GGX width α of the coat's specular lobe (specular=lobe only)", "roughness")

INTERREFLECTION = Option(
    "interreflection", ("single", "closed_form"), "single",
    "single: one bounce off the base (the paper's model); closed_form: every bounce between the "
    "interface and the Lambertian base, summed as a geometric series")

#: Probabilities with which sample() picks the coat's lobe (specular=lobe) are F(θi) clipped here.
_P_LOBE_MIN, _P_LOBE_MAX = 0.1, 0.9


def specular_reflectance(params, wi):
    """Weight F(θi) of the smooth coat's delta reflection (Walter eq. 22), 0 for wi.z <= 0."""
    F = fresnel_dielectric_Walter2007(wi[..., 2], params["coat_eta"])
    return jnp.where(wi[..., 2] > 0, F, 0.0)


def mirror(wi):
    """Direction of the delta reflection about the macro normal."""
    return wi * jnp.asarray([-1.0, -1.0, 1.0], dtype=wi.dtype)


def _closed_form_factor(params, albedo):
    """1 / (1 - ρ r): the geometric series of the reflections between a Lambertian base of
    albedo ρ and the interface. Each round trip returns the fraction ρ r of the upward diffuse
    flux, r = ∫ F_inside(μ) exp(-2τ/μ) 2μ dμ (``internal_diffuse_reflectance``): the base
    re-emits every returning photon diffusely, so the series is exact under the model's
    assumptions (smooth interface, non-scattering coat, Lambertian base)."""
    r = internal_diffuse_reflectance(params["coat_eta"], params["coat_tau"])
    return 1.0 / (1.0 - albedo * r)


def coat_items(params, specular: str = "delta") -> list[dict]:
    """The coat as simulator ``[[stack]]`` items: its top interface, smooth (or, with
    specular=lobe, GGX of width ``coat_alpha``: the rough coat whose reflection the lobe is;
    the model still refracts through the macro normal), over the coat medium of index η
    (relative to the outside, index 1) with optical depth τ = σa·d (thickness 1, σa = τ)."""
    eta = float(params["coat_eta"])
    rough = ({"distribution": "ggx", "alpha": float(params["coat_alpha"])}
             if specular == "lobe" else {"distribution": "smooth"})
    return (interface(OUTSIDE["index"], eta, **rough)
            + [absorbing_slab(eta, params["coat_tau"])])


def coated_effects(options) -> dict:
    """single (the blog's one bounce off the inner BSDF) ↔ max_bounces = 1; closed_form (every
    bounce between the coat and a Lambertian base) ↔ "all". The coat's delta reflection is not
    in f: delta = false."""
    closed = options.get("interreflection", "single") == "closed_form"
    return {"max_bounces": "all" if closed else 1, "delta": False}


def make_coated(inner: Model, specular: str = "delta") -> Model:
    """The coated model of registry model ``inner`` (any, including sums; not another coated
    model, whose coat parameters would clash: use weidlich_wilkie for several layers)."""
    if specular not in SPECULAR_CHOICES:
        raise ValueError(f"coated(...,specular={specular}): specular must be one of "
                         f"{', '.join(SPECULAR_CHOICES)}")
    own = (COAT_ETA, COAT_TAU) + ((COAT_ALPHA,) if specular == "lobe" else ())
    clash = {p.name for p in own} & set(inner.parameter_names)
    if clash:
        raise ValueError(f"coated({inner.name}): the inner model already has parameter(s) "
                         f"{', '.join(sorted(clash))}")
    # the closed form needs a base that re-emits every photon diffusely (f = albedo/π)
    lambertian = inner.capabilities.lambertian
    own_options = (INTERREFLECTION,) if lambertian else ()
    albedo_name = inner.parameters_with_role("albedo")[0].name if lambertian else None
    inner_names = inner.parameter_names
    inner_option_names = tuple(o.name for o in inner.options)

    def split(params, opts):
        p_in = {k: params[k] for k in inner_names}
        o_in = {k: v for k, v in opts.items() if k in inner_option_names}
        return p_in, o_in

    def inner_term(params, wi, wo, opts):
        """T(θi)T(θo)/η² f_inner(ωi', ωo') a (· 1/(1 - ρ r) for closed_form): the blog's result."""
        eta = params["coat_eta"]
        p_in, o_in = split(params, opts)
        wi_p, ok_i = refract_down(wi, eta)
        wo_p, ok_o = refract_down(wo, eta)
        f_in = inner.eval(p_in, wi_p, wo_p, **o_in)
        f = (transmittance(wi[..., 2], eta) * transmittance(wo[..., 2], eta)
             * solid_angle_compression(eta) * f_in
             * beer_lambert(params["coat_tau"], wi_p[..., 2], wo_p[..., 2]))
        if opts.get("interreflection", "single") == "closed_form":
            f = f * _closed_form_factor(params, p_in[albedo_name])
        return jnp.where(ok_i & ok_o, f, 0.0)

    def lobe_params(params):
        # the dielectric Fresnel of the coat is the conductor formula with k = 0
        return {"alpha": params["coat_alpha"], "n": params["coat_eta"],
                "k": jnp.zeros_like(params["coat_eta"])}

    def p_lobe(params, wi):
        F = fresnel_dielectric_Walter2007(wi[..., 2], params["coat_eta"])
        return jnp.clip(F, _P_LOBE_MIN, _P_LOBE_MAX)

    def eval(params, wi, wo, **opts):
        f = inner_term(params, wi, wo, opts)
        if specular == "lobe":
            f = f + rough_conductor.MODEL.eval(lobe_params(params), wi, wo)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)

    def pdf_inner(params, wi, wo, opts):
        """Density of the inner sampler's ωo' carried out of the coat: p'(ωo') |dωo'/dωo|,
        dωo'/dωo = cos θo / (η² cos θo') (Snell: η0² cos θ dω = η1² cos θ' dω')."""
        eta = params["coat_eta"]
        p_in, o_in = split(params, opts)
        wi_p, ok_i = refract_down(wi, eta)
        wo_p, ok_o = refract_down(wo, eta)
        p = inner.pdf(p_in, wi_p, wo_p, **o_in)
        jac = safe_div(wo[..., 2], eta * eta * wo_p[..., 2])
        return jnp.where(ok_i & ok_o, p * jac, 0.0)

    def pdf(params, wi, wo, **opts):
        p = pdf_inner(params, wi, wo, opts)
        if specular == "lobe":
            P = p_lobe(params, wi)
            p = P * rough_conductor.MODEL.pdf(lobe_params(params), wi, wo) + (1.0 - P) * p
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), p, 0.0)

    def sample(params, wi, u, **opts):
        """Refract ωi in, sample the inner BSDF, refract its ωo' out (invalid under total
        internal reflection); with specular=lobe first pick the coat's lobe with probability
        clip(F(θi), 0.1, 0.9) using u[2]. weight = f|cos θo|/pdf of the full mixture."""
        eta = params["coat_eta"]
        p_in, o_in = split(params, opts)
        uu = u
        if specular == "lobe":
            P = p_lobe(params, wi)
            choose_lobe = u[..., 2] < P
            u2 = jnp.where(choose_lobe, safe_div(u[..., 2], P), safe_div(u[..., 2] - P, 1.0 - P))
            uu = jnp.concatenate([u[..., :2], jnp.clip(u2, 0.0, 1.0)[..., None]], axis=-1)
        wi_p, ok_i = refract_down(wi, eta)
        wo_p, _, p_s = inner.sample(p_in, wi_p, uu, **o_in)
        wo, ok_o = refract_up(wo_p, eta)
        valid = ok_i & ok_o & (p_s > 0)
        if specular == "lobe":
            wo_l, _, p_l = rough_conductor.MODEL.sample(lobe_params(params), wi, uu)
            wo = jnp.where(choose_lobe[..., None], wo_l, wo)
            valid = jnp.where(choose_lobe, p_l > 0, valid)
        p = pdf(params, wi, wo, **opts)
        f = eval(params, wi, wo, **opts)
        return sample_result(wo, f, p, valid & (wi[..., 2] > 0))

    def scene_of(params, options):
        """The coat (:func:`coat_items`) over the inner model's own scene, whose indices are
        relative to the coat (:func:`fitlab.models.base.immersed`: a conductor's n, k relative
        to the coat become η n, η k in the scene), with :func:`coated_effects`."""
        p_in, o_in = split(params, options)
        inner_scene = inner.scene_of(p_in, {**inner.default_options(), **o_in})
        if inner_scene is None:
            return None
        return layered_scene(coat_items(params, specular), float(params["coat_eta"]),
                             inner_scene, coated_effects(options))

    name = canonical_name(inner.name, specular)
    lobe_note = ("; narrow coat lobe: Walter eq. 20 with GGX (eq. 33) and the coat's dielectric "
                 "Fresnel (eq. 22)" if specular == "lobe" else
                 "; the coat's delta reflection F(θi) is not in f (see data_formats/"
                 "layered_models.md)")
    return Model(
        name=name,
        summary=(f"{inner.name} under a smooth dielectric coat (single bounce, Fresnel "
                 f"transmittances, 1/η², Beer–Lambert)"
                 + (" plus a narrow GGX coat lobe" if specular == "lobe" else "")),
        parameters=own + inner.parameters,
        options=own_options + inner.options,
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=Capabilities(
            isotropic=inner.capabilities.isotropic, reciprocal=inner.capabilities.reciprocal,
            delta="; ".join(d for d in (
                "" if specular == "lobe" else
                "the smooth coat's mirror reflection F(θi) δ(ωo - mirror(ωi)) "
                "(coated.specular_reflectance)", inner.capabilities.delta) if d)),
        exchangeable=inner.exchangeable,  # f_inner's repeated lobes still trade places
        scene_of=scene_of if inner.scene_of is not None else None,
        inner=(Term.same_names(inner),),
        arguments=(("specular", specular),),
        # Mitsuba's plastic: a Lambertian under a smooth coat (export/mitsuba.py checks the rest)
        translations=(("mitsuba", "plastic"),) if lambertian else (),
        reference=("bsdf_under_smooth_interface (f = T(θi)T(θo) η0²/η1² f_inner(ωi', ωo')); "
                   "Elek 2010 eq. 3 (absorption); Walter 2007 eq. 22 (Fresnel)" + lobe_note
                   + f"; inner: {inner.reference}"),
    )


def canonical_name(inner_name: str, specular: str = "delta") -> str:
    return f"{NAME}({inner_name})" if specular == "delta" else \
        f"{NAME}({inner_name},specular={specular})"


def from_call(call, get_model) -> Model:
    """Build from the parsed name ``coated(INNER[,specular=delta|lobe])`` (models/syntax.py)."""
    inner, kwargs = call_arguments(call, f"{NAME}(rough_conductor)",
                                   {"specular": "specular=delta|lobe"})
    return _cached(get_model(inner), kwargs.get("specular", "delta"))


@functools.lru_cache(maxsize=None)
def _cached(inner: Model, specular: str) -> Model:
    return make_coated(inner, specular)
