"""Weidlich–Wilkie layered BRDF, as reviewed by Elek 2010 section 2.2 (eqs 2-4) and section 3.

``weidlich_wilkie(BASE)`` is the paper's two-layer stack (Algorithm 1): one microfacet interface
(layer 1) over a base (layer 2), any registry BRDF (a model without transmission: the paper's
``lambertian``, ``oren_nayar`` and ``rough_conductor``, and others);
``weidlich_wilkie(BASE,layers=K)`` stacks K-1 interfaces over the base. Layer i (1 = top) has a
Torrance–Sparrow / Walter microfacet BRDF (Walter eq. 20, GGX or Beckmann) with complex index
(n_i, k_i) relative to vacuum (n_0 = 1 outside) and the optical depth τ_i = σ_i d_i of eq. 3.
The recursion (eq. 2), evaluated from the top with L, V the directions above layer i, with the
two changes that make it conserve energy (below):

    f^(i)(L, V) = f_ri(L, V) + T_i(L) T_i(V) (n_{i-1}/n_i)² · f^(i+1)(L', V') · a_i · t_i

* f_ri: microfacet reflection of interface i with Fresnel of the relative index
  (n_i + i k_i)/n_{i-1} (Elek's shader uses the absolute (n_i, κ_i); relative is what the
  interface sees and reduces to it for the top layer);
* T_i(L) T_i(V), T_i(w) = 1 - F_i(N·w): the light crosses the interface down along L and back up
  along V, each crossing transmitting 1 - F at the macro normal (fitlab's change 1; Algorithm 1
  lines 23-24 use one T_12 = T_21 = 1 - F_i(L·H) at the half vector of L and V, which at grazing
  L lets nearly all of the light through to the layer below while f_ri already reflects nearly
  all of it: 1.34-1.38 times the incident energy at 89.9° over a white Lambertian base);
* (n_{i-1}/n_i)²: the solid-angle compression of the crossing down and back up, as in the coated
  model's derivation (fitlab's change 2; eq. 2 as printed omits it, and the lower lobe, widened
  by refraction, is then integrated over the outside hemisphere up to η² too bright: 2.05 times
  the incident energy for a smooth coat over a near-perfect mirror; tests/models/test_layered.py);
* L', V': Snell refraction through the macro normal with n_i/n_{i-1} (lines 7-8); a ray that
  cannot enter (or leave) the layer contributes nothing below;
* a_i = exp(-τ_i (1/N·L' + 1/N·V')), eq. 3;
* t_i = (1 - G_i) + T_i G_i, eq. 4, G_i the Smith shadowing G1(L)G1(V) of layer i and T_i =
  1 - F_i(L·H) as in Algorithm 1.

With both changes the stack's directional albedo is at most f_r1's plus T_1(L) times the
albedo of the layer below (∫ T(V) f' cos θV dωV / η² = ∫ T f' cos θV' dωV'), so at most 1 by
induction; the registry contract's white furnace checks it to 89.9°.

Option ``roughness_clamp=clamp`` applies section 3's fix m_{i+1} ≥ m_i (α of every layer, and
of a rough-conductor base, at least the largest α above it; Algorithm 1 line 21).
The base's parameters are the registry model's, numbered as layer K: albedoK, sigmaK (Oren–Nayar)
or alphaK, nK, kK (rough conductor). A base parameter whose role is ``index`` or ``extinction``
is relative to vacuum like the interfaces' and evaluated relative to n_{K-1}; one whose role is
``roughness`` (a microfacet width) takes part in the roughness clamp.
"""

from __future__ import annotations

import functools

from fitlab._jax import jnp
from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS
from fitlab.frame import dot, normalize
from fitlab.interface import beer_lambert, refract_down, refract_up
from fitlab import microfacet
from fitlab.models import rough_conductor
from fitlab.models.base import (OUTSIDE, Capabilities, Model, Option, Parameter,
                                absorbing_slab, interface, layered_scene, sample_result)
from fitlab.models.syntax import call_arguments
from fitlab.numerics import safe_div

NAME = "weidlich_wilkie"
MAX_LAYERS = 6

#: sample() reflects at interface i with probability clip(F_i(cos θ_L), 0.1, 0.9).
_P_MIN, _P_MAX = 0.1, 0.9

OPTIONS = (
    Option("distribution", microfacet.names(), "ggx",
           "microfacet distribution of every interface and of a rough-conductor base"),
    Option("fresnel", tuple(CONDUCTOR_FRESNEL_METHODS), "exact",
           "Fresnel of the interfaces (complex index): exact, schlick (F0 from n, k; also "
           "Elek appendix B's shader formula) or lazanyi (Lazányi–Szirmay-Kalos 2005: "
           "Schlick minus a·μ(1-μ)^6, a fitted to the exact F at μ = 1/7, Hoffman 2019)"),
    Option("roughness_clamp", ("none", "clamp"), "none",
           "clamp: alpha of each lower layer at least the alpha above it (Elek section 3, "
           "m2 >= m1)"),
)

DEFAULT_OPTIONS = {o.name: o.default for o in OPTIONS}


def layer_parameters(i: int) -> tuple[Parameter, ...]:
    return (
        Parameter(f"alpha{i}", 1e-4, 1.0, 0.05, "1", f"microfacet width α of interface {i} (m_{i})",
                  "roughness"),
        Parameter(f"n{i}", 1.0, 5.0, 1.5, "1", f"refractive index of layer {i} (real part, vacuum = 1)",
                  "index"),
        Parameter(f"k{i}", 0.0, 5.0, 0.0, "1", f"extinction coefficient κ_{i} of layer {i} (Fresnel only)",
                  "extinction"),
        Parameter(f"tau{i}", 0.0, 20.0, 0.0, "1",
                  f"optical depth of layer {i} at normal incidence τ = σ_{i} d_{i} (eq. 3)",
                  "optical_depth"),
    )


def layer_items(params, K: int, distribution: str) -> list[dict]:
    """Interfaces 1..K-1 and their layers as simulator ``[[stack]]`` items: interface i with the
    stack's microfacet distribution and width α_i (unclamped: roughness_clamp is the model's
    fix, Elek section 3, not the stack's), layer i of index n_i (relative to vacuum, the
    outside) with optical depth τ_i (eq. 3: thickness 1, σa = τ_i). The simulator's
    interfaces are dielectric: an extinction k_i > 0 (Fresnel of a complex index) has no
    scene, and raises ValueError."""
    items, n_above = [], OUTSIDE["index"]
    for i in range(1, K):
        n, k = float(params[f"n{i}"]), float(params[f"k{i}"])
        if k != 0.0:
            raise ValueError(f"{NAME}: k{i} = {k:g} > 0; the simulator's interfaces are "
                             f"dielectric (a real index): set k{i} = 0 to compare the model "
                             "with `fitlab simulate`")
        items += interface(n_above, n, distribution=distribution,
                           alpha=float(params[f"alpha{i}"]))
        items.append(absorbing_slab(n, params[f"tau{i}"]))
        n_above = n
    return items


def canonical_name(base_name: str, layers: int = 2) -> str:
    return f"{NAME}({base_name})" if layers == 2 else f"{NAME}({base_name},layers={layers})"


def make_weidlich_wilkie(base: Model, layers: int = 2) -> Model:
    if base.capabilities.transmission:
        raise ValueError(f"{NAME}({base.name}): the base must be a BRDF (a model without "
                         f"transmission, e.g. lambertian, oren_nayar, rough_conductor); "
                         f"{base.name} transmits")
    if not 2 <= layers <= MAX_LAYERS:
        raise ValueError(f"{NAME}(...,layers={layers}): layers counts the base too and must be "
                         f"2..{MAX_LAYERS}")
    n_if = layers - 1
    K = layers
    base_params = tuple(p._replace(name=f"{p.name}{K}",
                                   description=f"{p.description} (base, layer {K})")
                        for p in base.parameters)
    parameters = sum((layer_parameters(i) for i in range(1, K)), ()) + base_params

    def stack(params, opts):
        """Per interface: (α, n_rel, k_rel, η = n_i/n_{i-1}, τ); and the base's parameters."""
        out, n_above, a_max = [], 1.0, None
        for i in range(1, K):
            alpha = params[f"alpha{i}"]
            if opts["roughness_clamp"] == "clamp":
                a_max = alpha if a_max is None else jnp.maximum(a_max, alpha)
                alpha = a_max
            n = params[f"n{i}"]
            out.append((alpha, n / n_above, params[f"k{i}"] / n_above, n / n_above,
                        params[f"tau{i}"]))
            n_above = n
        pb = {}
        for p in base.parameters:
            v = params[f"{p.name}{K}"]
            if p.role in ("index", "extinction"):  # relative to the layer above
                v = v / n_above
            elif p.role == "roughness" and opts["roughness_clamp"] == "clamp":
                v = jnp.maximum(v, a_max)
            pb[p.name] = v
        return out, pb

    def base_options(opts):
        """The stack's options that the base declares too (distribution, fresnel)."""
        return {o.name: opts[o.name] for o in base.options if o.name in opts}

    def interface_terms(layer, L, V, opts):
        """f_ri (Walter eq. 20), the crossings' T_i(L) T_i(V) (change 1 of the module docstring)
        and t_i (eq. 4, with Algorithm 1's T_i = 1 - F_i(L·H)) of one interface."""
        alpha, n_rel, k_rel, _, _ = layer
        dist = microfacet.get_distribution(opts["distribution"])(alpha)
        lp = {"alpha": alpha, "n": n_rel, "k": k_rel}
        f = rough_conductor.MODEL.eval(lp, L, V, distribution=opts["distribution"],
                                 fresnel=opts["fresnel"])
        H = normalize(L + V)
        F = CONDUCTOR_FRESNEL_METHODS[opts["fresnel"]](dot(L, H), n_rel, k_rel)
        T = 1.0 - F
        G = dist.smith_G1(L, H) * dist.smith_G1(V, H)
        t = (1.0 - G) + T * G  # eq. 4
        fresnel = CONDUCTOR_FRESNEL_METHODS[opts["fresnel"]]
        crossings = (1.0 - fresnel(L[..., 2], n_rel, k_rel)) * (1.0 - fresnel(V[..., 2], n_rel, k_rel))
        return f, crossings, t

    def eval(params, wi, wo, **opts):
        opts = {**DEFAULT_OPTIONS, **opts}
        layers_, pb = stack(params, opts)
        L, V = wi, wo
        total = 0.0
        carry = jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), 1.0, 0.0)
        for layer in layers_:
            f, T, t = interface_terms(layer, L, V, opts)
            total = total + carry * f
            eta, tau = layer[3], layer[4]
            Lp, ok_l = refract_down(L, eta)
            Vp, ok_v = refract_down(V, eta)
            a = beer_lambert(tau, Lp[..., 2], Vp[..., 2])  # eq. 3
            # eq. 2 with the crossings' transmittances and the solid-angle compression
            carry = jnp.where(ok_l & ok_v, carry * T * a * t / (eta * eta), 0.0)
            L, V = Lp, Vp
        f_base = base.eval(pb, L, V, **base_options(opts))
        return total + carry * f_base

    def levels(params, wi, opts):
        """Incoming direction at each level, probability of choosing each level, validity."""
        opts = {**DEFAULT_OPTIONS, **opts}
        layers_, pb = stack(params, opts)
        Ls, probs, oks = [wi], [], [wi[..., 2] > 0]
        remaining = jnp.ones_like(wi[..., 2])
        L = wi
        for layer in layers_:
            alpha, n_rel, k_rel, eta, _ = layer
            F = CONDUCTOR_FRESNEL_METHODS[opts["fresnel"]](L[..., 2], n_rel, k_rel)
            P = jnp.clip(F, _P_MIN, _P_MAX)
            L, ok = refract_down(L, eta)
            P = jnp.where(ok, P, 1.0)  # nothing enters: always the interface's own lobe
            probs.append(remaining * P)
            remaining = remaining * (1.0 - P)
            Ls.append(L)
            oks.append(oks[-1] & ok)
        probs.append(remaining)
        return layers_, pb, Ls, probs, oks

    def pdf(params, wi, wo, **opts):
        """Σ_levels P(level) p_level(V_level) |dω_level/dω_o|, with
        dω'/dω = cos θ / (η² cos θ') per crossing (Snell)."""
        opts = {**DEFAULT_OPTIONS, **opts}
        layers_, pb, Ls, probs, oks = levels(params, wi, opts)
        V = wo
        jac = jnp.ones_like(wo[..., 2])
        okv = wo[..., 2] > 0
        total = 0.0
        for j, layer in enumerate(layers_):
            lp = {"alpha": layer[0], "n": layer[1], "k": layer[2]}
            p = rough_conductor.MODEL.pdf(lp, Ls[j], V, distribution=opts["distribution"])
            total = total + jnp.where(okv & oks[j], probs[j] * p * jac, 0.0)
            eta = layer[3]
            Vp, ok = refract_down(V, eta)
            jac = jac * safe_div(V[..., 2], eta * eta * Vp[..., 2])
            okv = okv & ok
            V = Vp
        p = base.pdf(pb, Ls[-1], V, **base_options(opts))
        total = total + jnp.where(okv & oks[-1], probs[-1] * p * jac, 0.0)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), total, 0.0)

    def sample(params, wi, u, **opts):
        """Choose a level with u[2] (interface i with probability P_i ∏_{j<i}(1-P_j), the base
        with the rest), sample its lobe at the refracted incoming direction, refract the result
        up through the interfaces above it; weight = f|cos θo|/pdf of the whole mixture."""
        opts = {**DEFAULT_OPTIONS, **opts}
        layers_, pb, Ls, probs, oks = levels(params, wi, opts)
        cum = jnp.zeros_like(wi[..., 2])
        wo = jnp.zeros_like(wi)
        valid = jnp.zeros(wi.shape[:-1], dtype=bool)
        n_levels = len(layers_) + 1
        for j in range(n_levels):
            lo = cum
            cum = cum + probs[j]
            chosen = (u[..., 2] >= lo) & ((u[..., 2] < cum) | (j == n_levels - 1))
            u3 = jnp.clip(safe_div(u[..., 2] - lo, probs[j]), 0.0, 1.0)
            uu = jnp.concatenate([u[..., :2], u3[..., None]], axis=-1)
            if j < len(layers_):
                lp = {"alpha": layers_[j][0], "n": layers_[j][1], "k": layers_[j][2]}
                w, _, p_s = rough_conductor.MODEL.sample(lp, Ls[j], uu,
                                                   distribution=opts["distribution"])
            else:
                w, _, p_s = base.sample(pb, Ls[j], uu, **base_options(opts))
            ok = oks[j] & (p_s > 0)
            for layer in reversed(layers_[:j]):  # back out through the interfaces above
                w, ok_up = refract_up(w, layer[3])
                ok = ok & ok_up
            wo = jnp.where(chosen[..., None], w, wo)
            valid = jnp.where(chosen, ok, valid)
        p = pdf(params, wi, wo, **opts)
        f = eval(params, wi, wo, **opts)
        return sample_result(wo, f, p, valid)

    def scene_of(params, options):
        """The interfaces and layers (:func:`layer_items`) over the base's own scene: its
        ``index`` and ``extinction`` parameters divided by n_{K-1} as the model evaluates them,
        the scene moved back into layer K-1 (:func:`fitlab.models.base.immersed`), so a
        conductor base's (n_K, k_K) appear as given. The model approximates every bounce:
        max_bounces = "all"; no delta."""
        opts = {**DEFAULT_OPTIONS, **options}
        n_above = float(params[f"n{K - 1}"])
        pb = {p.name: float(params[f"{p.name}{K}"]) / (n_above if p.role in
                                                         ("index", "extinction") else 1.0)
              for p in base.parameters}
        base_scene = base.scene_of(pb, {**base.default_options(), **base_options(opts)})
        if base_scene is None:
            return None
        return layered_scene(layer_items(params, K, opts["distribution"]), n_above, base_scene,
                             {"max_bounces": "all", "delta": False})

    return Model(
        name=canonical_name(base.name, layers),
        summary=(f"Weidlich–Wilkie layered BRDF: {n_if} microfacet interface"
                 f"{'s' if n_if > 1 else ''} over a {base.name} base (Elek 2010 eqs 2-4)"),
        parameters=parameters,
        options=OPTIONS,
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=Capabilities(isotropic=base.capabilities.isotropic,
                                  reciprocal=base.capabilities.reciprocal,
                                  delta=base.capabilities.delta),
        scene_of=scene_of if base.scene_of is not None else None,
        reference=("Elek 2010 section 2.2 eqs 2 (recursion), 3 (absorption), 4 (TIR term), "
                   "section 3 (m2 >= m1 clamp), Algorithm 1; interfaces: Walter 2007 eq. 20 "
                   f"with complex Fresnel; base: {base.reference}"),
    )


def from_call(call, get_model) -> Model:
    """Build from the parsed name ``weidlich_wilkie(BASE[,layers=K])`` (models/syntax.py)."""
    base, kwargs = call_arguments(
        call, f"{NAME}(rough_conductor) (base: any BRDF, e.g. lambertian, oren_nayar)",
        {"layers": "layers=K (interfaces + base, default 2)"})
    try:
        layers = int(kwargs.get("layers", "2"))
    except ValueError:
        raise ValueError(f"{NAME}(...,layers={kwargs['layers']}): layers must be an integer") \
            from None
    return _cached(get_model(base), layers)


@functools.lru_cache(maxsize=None)
def _cached(base: Model, layers: int) -> Model:
    return make_weidlich_wilkie(base, layers)
