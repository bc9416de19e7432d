"""SpongeCake's multiple-scattering approximation (Wang et al. 2022, §5).

The multiple-scattering part of a SpongeCake stack is approximated by "a second single-scattering
lobe with modified parameters, as well as a Lambertian term" (§5): the exact single scattering
of the same layers (same number, kinds and axes ωp) with their own roughness α', albedo γ',
Schlick f0' (flakes) or g' (hg) and thickness Tρ', weighted W1, plus a Lambertian lobe W2/π.
fitlab adds a Lambertian transmission lobe W2T/π where the stack transmits (the paper's Fig. 9
shows both hemispheres; one Lambertian reflection lobe cannot carry the diffuse transmission of
a thick layer), so

    f = f_ss(p) + W1 · f_ss(p') + W2/π [same side] + W2T/π [other side].

``multiple=lobe`` is that sum; ``multiple=only`` is the approximation alone, f_ss(p') terms and
Lambertian lobes without the exact single scattering: the model a simulation's
multiple-scattering component (all orders minus the first) is fitted with
(:mod:`fitlab.learn.lobe`). Its parameters carry the same names, so a fitted lobe plugs
into ``multiple=lobe``. Layer i's modified parameters are its own names with ``_ms``
(``alpha1_ms``, ``albedo1_ms``, ``f0_1_ms``, ``tau1_ms``, ``g1_ms``); the axes are the layer's
(unmodified in the paper). With a substrate the lobe is the stack's alone (the substrate's
interreflections with the layers are part of what it approximates) and applies, like the
layers' single scattering, to light from above leaving upward.

f_ss is linear in each layer's albedo (the attenuation does not depend on γ), so W1 and the
albedos γ' are determined only as products W1·γ'ᵢ; a fit holds one of them (the lobe fit holds
``albedo1_ms`` = 1).

**Energy (fitlab's addition; §5 leaves it open).** The paper fits W1, W2 and the modified
parameters per stack, or maps them with its network, and bounds nothing: W1 ≥ 0 is free, and
the lobe, a second single-scattering lobe, grows toward grazing as the exact one does, so
``ss + lobe`` can reflect more light than arrives (1.05 at θi = 85°, 1.38 at 89.9° with the
registry's example parameters). fitlab scales the approximation by a reciprocal factor

    c(ωi, ωo) = min(s(ωi), s(ωo)),   s(ω) = clip((1 − E_base(ω)) / E_lobe(ω), 0, 1),

where E_lobe is the approximation's directional albedo (W1 E_ss(p') + W2 [+ W2T]) and E_base
that of the exact model it is added to (single scattering and the substrate seen through the
layers; 0 for ``multiple=only``): the whole model's albedo is at most 1, and c = 1 (the paper's
lobe unchanged) wherever the sum fits within it. The budget is 1, not the light the stack p can
return at all (what survives its first scattering): fits to measured data treat the stack as
phenomenological, and the Satine fabric fits in fits/ carry lobes beyond that physical budget at
every direction (by up to 99% of the lobe) while their albedo stays below 1. E_base and E_lobe
are tabulated per parameter set by quasi-Monte Carlo over a grid of directions
(:mod:`fitlab.models.directional_albedo`) and read as the greatest value of the nodes around ω
(an upper envelope: s errs low between nodes, never high; a thin fibre layer's albedo changes
within a few degrees of azimuth near grazing). The tables are held constant under
differentiation: gradients are exact wherever c = 1, and where the budget binds they leave out
its own dependence on the parameters.

Sampling: the paper samples single scattering alone (§4.5, "for simplicity"); fitlab samples
the mixture of the exact lobe (§4.5), the modified lobe (the same sampler at p') and cosine
lobes on each side with probabilities from their first-scattering masses and the weights W,
each with at least :data:`_P_FLOOR`, so the pdf is positive wherever f is.
"""

from __future__ import annotations

from fitlab._jax import jax, jnp
from fitlab.frame import flip_z
from fitlab.models import directional_albedo as da
from fitlab.models.base import Capabilities, Model, Parameter, choose_branch, sample_result
from fitlab.models.diffuse import sample_cosine_hemisphere
from fitlab.numerics import safe_div

MODES = ("none", "lobe", "only", "learned")
#: each branch of the sampling mixture gets at least this share
_P_FLOOR = 0.05
#: the modified parameters of a layer: its own with this suffix
SUFFIX = "_ms"


def modified_parameters(layer_params: tuple[Parameter, ...]) -> tuple[Parameter, ...]:
    """Layer parameters' ``_ms`` copies (not the axis, which the lobe keeps)."""
    return tuple(p._replace(name=p.name + SUFFIX,
                            description=f"multiple-scattering lobe: {p.description}")
                 for p in layer_params if not p.name.startswith(("theta_p", "phi_p")))


def weight_parameters(transmits: bool) -> tuple[Parameter, ...]:
    """W1 (the modified single-scattering lobe), W2 (Lambertian reflection), W2T (Lambertian
    transmission, where the stack transmits)."""
    w = [Parameter("W1", 0.0, 10.0, 1.0, "1", "weight W1 of the modified single-scattering lobe "
                   "(SpongeCake §5)", "weight"),
         Parameter("W2", 0.0, 1.0, 0.05, "1", "weight W2 of the Lambertian reflection lobe W2/π "
                   "(SpongeCake §5)", "weight")]
    if transmits:
        w.append(Parameter("W2T", 0.0, 1.0, 0.05, "1", "weight of the Lambertian transmission "
                           "lobe W2T/π (fitlab's addition to SpongeCake §5)", "weight"))
    return tuple(w)


def lobe_params(params, names):
    """The plain stack's parameters for the modified lobe: each ``name`` from ``name_ms`` where
    that exists (the axes keep their own names)."""
    return {n: params[n + SUFFIX] if n + SUFFIX in params else params[n] for n in names}


def applies(wi, wo, above_only: bool):
    """Where the approximation scatters: everywhere, or (``above_only``: a substrate below)
    for ωi and ωo both above the surface."""
    if above_only:
        return (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return jnp.ones(jnp.broadcast_shapes(wi.shape[:-1], wo.shape[:-1]), bool)


def approximation(stack: Model, params, wi, wo, transmits: bool, above_only: bool = False):
    """§5's approximation before fitlab's energy budget: W1 f_ss(p') + W2/π on the same side
    + W2T/π on the other (where the stack transmits); ``above_only``: only for ωi and ωo above
    the surface (a substrate below)."""
    on = applies(wi, wo, above_only)
    same = wi[..., 2] * wo[..., 2] > 0
    lamb = jnp.where(same, params["W2"], params["W2T"] if transmits else 0.0) / jnp.pi
    f_ms = stack.eval(lobe_params(params, stack.parameter_names), wi, wo)
    return jnp.where(on, params["W1"] * f_ms + lamb, 0.0)


def with_multiple(base: Model | None, stack: Model, mode: str, name: str, transmits: bool,
                  above_only: bool, extra: tuple[Parameter, ...], stack_mass, base_mass,
                  capabilities: Capabilities, stack_albedo, base_albedo) -> Model:
    """The model of ``mode`` ("lobe": base + approximation; "only": the approximation alone).
    ``stack``: the plain layers (no substrate, no delta) whose single scattering is the lobe;
    ``stack_mass(params, wi)`` / ``base_mass(params, wi)``: the sampling masses of the stack's
    single scattering and of the base model (the light that first scatters in it);
    ``above_only``: the lobes apply to light from above leaving upward (a substrate below);
    ``extra``: the parameters of ``mode`` besides the base's (axes for "only", ``_ms`` copies,
    weights); ``capabilities``: the single-scattering model's (its delta is the result's only
    for "lobe")."""
    stack_names = stack.parameter_names
    has_T = transmits
    params = (base.parameters if base is not None else ()) + extra
    names = tuple(p.name for p in params)

    nodes = da.grid(capabilities.isotropic, both_sides=not above_only)

    def albedos(params, opts, dtype):
        """E_base and E_lobe of the module docstring at the grid's nodes, per parameter set:
        (..., 2 × nodes)."""
        def make(p):
            e_ss = da.tabulate(lambda q, w, u: stack_albedo(lobe_params(q, stack_names), w, u),
                               p, nodes, dtype)
            lamb = jnp.asarray(p["W2"] + (p["W2T"] if has_T else 0.0), dtype)[..., None]
            e_lobe = jnp.asarray(p["W1"], dtype)[..., None] * e_ss + lamb
            e_base = (jnp.zeros_like(e_lobe) if base is None else
                      da.tabulate(lambda q, w, u: base_albedo(q, w, u, opts), p, nodes, dtype))
            return jnp.concatenate([e_base, e_lobe], axis=-1)

        return da.per_parameter_set(make, {k: params[k] for k in names})

    def headroom(tables, w):
        """s(ω) = clip((1 − E_base(ω)) / E_lobe(ω), 0, 1) at directions w, both albedos read as
        upper envelopes of their tables around ω (so s errs low between the nodes, never
        high)."""
        G = nodes.size
        e_base = da.lookup_max(tables._replace(values=tables.values[..., :G]), nodes, w)
        e_lobe = da.lookup_max(tables._replace(values=tables.values[..., G:]), nodes, w)
        return jnp.clip(safe_div(1.0 - e_base, e_lobe, 1.0), 0.0, 1.0)

    def scale_of(params, wi, wo, opts_items):
        opts = dict(opts_items)
        tables = albedos(params, opts, wi.dtype)
        tables = tables._replace(values=jax.lax.stop_gradient(tables.values))
        return jnp.minimum(headroom(tables, wi), headroom(tables, wo))

    compiled = []  # made at the first call: listing the registry must not import JAX

    def scale(params, wi, wo, opts):
        """c(ωi, ωo) = min(s(ωi), s(ωo)): reciprocal, and ≤ s(ωi) for every ωo. The tables
        are held constant under differentiation (see the module docstring). One compiled
        function: called outside jit (a test, a script), the tables' hundreds of operations
        would otherwise each compile on their own."""
        if not compiled:
            compiled.append(jax.jit(scale_of, static_argnums=3))
        return compiled[0]({k: params[k] for k in names}, wi, wo, tuple(sorted(opts.items())))

    def approx(params, wi, wo, opts):
        return (approximation(stack, params, wi, wo, has_T, above_only)
                * scale(params, wi, wo, opts))

    def eval(params, wi, wo, **opts):
        f = approx(params, wi, wo, opts)
        return f if base is None else f + base.eval(params, wi, wo, **opts)

    def masses(params, wi):
        """Unnormalized branch probabilities: (base, lobe, cosine same side, cosine other)."""
        one = jnp.ones_like(wi[..., 2])
        up = wi[..., 2] > 0
        live = up if above_only else jnp.ones_like(up)
        m_lobe = params["W1"] * stack_mass(lobe_params(params, stack_names), wi)
        m = [jnp.where(live, m_lobe, 0.0), jnp.where(live, params["W2"] * one, 0.0)]
        m.append(jnp.where(live, params["W2T"] * one, 0.0) if has_T else 0.0 * one)
        if base is not None:
            m.insert(0, base_mass(params, wi))
        return jnp.stack(m)

    def choice(params, wi):
        m = masses(params, wi)
        n = m.shape[0]
        avail = jnp.ones((n,) + wi.shape[:-1], bool)
        if not has_T:
            avail = avail.at[-1].set(False)
        if base is not None and above_only:
            # light from below meets the substrate alone: the base branch only
            avail = jnp.where(wi[..., 2] > 0, avail, (jnp.arange(n) == 0).reshape(
                (n,) + (1,) * (wi.ndim - 1)))
        p = jnp.where(avail, safe_div(m, jnp.sum(m, axis=0), 1.0) + _P_FLOOR, 0.0)
        return p / jnp.sum(p, axis=0)

    def branch_pdfs(params, wi, wo, **opts):
        same = wi[..., 2] * wo[..., 2] > 0
        cos_o = jnp.abs(wo[..., 2]) / jnp.pi
        pd = [jnp.where(applies(wi, wo, above_only), stack.pdf(lobe_params(params, stack_names), wi, wo), 0.0),
              jnp.where(same & applies(wi, wo, above_only), cos_o, 0.0),
              jnp.where(~same & applies(wi, wo, above_only), cos_o, 0.0)]
        if base is not None:
            pd.insert(0, base.pdf(params, wi, wo, **opts))
        return jnp.stack(pd)

    def pdf(params, wi, wo, **opts):
        return jnp.sum(choice(params, wi) * branch_pdfs(params, wi, wo, **opts), axis=0)

    def sample(params, wi, u, **opts):
        """A branch chosen with u[2] by :func:`choice` (u[2] then rescaled into the branch),
        that branch's sample; weight = f|cos|/pdf of the mixture."""
        pick, uu = choose_branch(choice(params, wi), u)
        k0 = 0 if base is None else 1
        w_l, _, p_l = stack.sample(lobe_params(params, stack_names), wi, uu)
        cos = sample_cosine_hemisphere(u[..., :2])
        w_r = flip_z(cos, jnp.sign(wi[..., 2]))
        w_t = flip_z(cos, -jnp.sign(wi[..., 2]))
        wo, ok = w_l, p_l > 0
        for k, (w_k, ok_k) in enumerate(((w_r, True), (w_t, True)), start=k0 + 1):
            wo = jnp.where((pick == k)[..., None], w_k, wo)
            ok = jnp.where(pick == k, ok_k, ok)
        if base is not None:
            w_b, _, p_b = base.sample(params, wi, uu, **opts)
            wo = jnp.where((pick == 0)[..., None], w_b, wo)
            ok = jnp.where(pick == 0, p_b > 0, ok)
        return sample_result(wo, eval(params, wi, wo, **opts), pdf(params, wi, wo, **opts), ok)

    return Model(
        name=name,
        summary=(("SpongeCake with its multiple-scattering lobe (§5): "
                  + (base.summary if base is not None else ""))
                 if mode == "lobe" else
                 f"SpongeCake's multiple-scattering approximation alone (§5): the lobe of "
                 f"{stack.name} and Lambertian lobes"),
        parameters=params,
        options=base.options if base is not None else (),
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=capabilities,
        # the budget's tables: N_POINTS samples per node, E_lobe and (with a base) E_base
        work_per_parameter_set=da.N_POINTS * nodes.size * (1 if base is None else 2),
        reference=((base.reference if base is not None else stack.reference)
                   + "; multiple scattering: §5, a single-scattering lobe with modified "
                   "parameters weighted W1 and a Lambertian lobe W2 (+ W2T, transmission)"),
    )


def with_learned(lobe: Model, base: Model, name: str, lobe_of, provenance: str) -> Model:
    """``lobe`` (the ``multiple=lobe`` model) with its lobe parameters computed from the layer's
    own by ``lobe_of(params)`` (the parameter-mapping network, fitlab.learn.network): the
    parameters are the single-scattering model's (``base``)."""

    def full(params):
        return {**params, **lobe_of(params)}

    return Model(
        name=name,
        summary=f"SpongeCake with its learned multiple-scattering lobe (§5): {base.summary}",
        parameters=base.parameters,
        options=base.options,
        eval=lambda params, wi, wo, **o: lobe.eval(full(params), wi, wo, **o),
        sample=lambda params, wi, u, **o: lobe.sample(full(params), wi, u, **o),
        pdf=lambda params, wi, wo, **o: lobe.pdf(full(params), wi, wo, **o),
        capabilities=lobe.capabilities,
        work_per_parameter_set=lobe.work_per_parameter_set,
        reference=lobe.reference + f"; lobe parameters from the network ({provenance})",
    )
