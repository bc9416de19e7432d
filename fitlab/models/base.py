"""What every registry model declares: parameters with bounds, units and roles, static options,
its capabilities, and the three pure functions eval / sample / pdf.

Code that needs to know what a model is asks it (``model.capabilities.transmission``,
``model.capabilities.isotropic``, ``model.parameters_with_role("roughness")``), never its name.

Signatures (all batched over any leading shape; ``params`` is a dict of arrays that broadcast
against the directions' leading shape)::

    eval(params, wi, wo, **options)  -> f            BSDF in 1/sr, without the cosine
    pdf(params, wi, wo, **options)   -> p            solid-angle density of ``sample``'s wo
    sample(params, wi, u, **options) -> (wo, weight, pdf)
        u: (..., 3) uniforms in [0, 1); weight = f(wi, wo)|cos θo| / pdf (Walter eq. 37),
        0 for an invalid sample (its wo is then meaningless but finite).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

#: What a parameter is, for code that needs to know (clamps, exporters, renderers, reports).
ROLES = {
    "roughness": "microfacet width α (or α_x, α_y), on the shared α axis of fitlab.microfacet",
    "concentration": "vMF concentration κ of an NDF (sharper as it grows; κ = 2/α² on the α axis)",
    "index": "real refractive index (relative to the medium above)",
    "extinction": "imaginary part k of a complex index",
    "albedo": "reflectance or single-scattering albedo in [0, 1]",
    "optical_depth": "thickness × attenuation coefficient (τ = σ d)",
    "scale": "overall scale of the values (relative measurements)",
    "other": "none of the above",
}


class Parameter(NamedTuple):
    name: str
    lower: float
    upper: float
    default: float
    unit: str
    description: str
    #: one of ROLES
    role: str = "other"


class Capabilities(NamedTuple):
    """What a model is: the sides it scatters to, its symmetries, what ``eval`` leaves out."""

    reflection: bool = True
    transmission: bool = False
    #: f is unchanged by a rotation of both directions about the normal
    isotropic: bool = True
    #: f(wi, wo) = f(wo, wi) on the reflection side (Helmholtz reciprocity)
    reciprocal: bool = True
    #: a Dirac delta component that ``eval``/``pdf``/``sample`` leave out, described; "" if none
    delta: str = ""
    #: f is the constant albedo/π (an ideal diffuse reflector; the ``albedo`` role parameter)
    lambertian: bool = False
    #: ∫ f |cos θo| dωo <= 1 for every parameter value inside the bounds (a sum of lobes is not:
    #: its components' albedos may add up to more than one)
    energy_conserving: bool = True

    @property
    def lobes(self) -> str:
        """"reflection", "transmission" or "reflection+transmission" (the fit files' text)."""
        return "+".join(s for s, on in (("reflection", self.reflection),
                                        ("transmission", self.transmission)) if on)

    def combined(self, other: "Capabilities") -> "Capabilities":
        """Capabilities of the sum f = f_self + f_other."""
        return Capabilities(
            reflection=self.reflection or other.reflection,
            transmission=self.transmission or other.transmission,
            isotropic=self.isotropic and other.isotropic,
            reciprocal=self.reciprocal and other.reciprocal,
            delta="; ".join(d for d in (self.delta, other.delta) if d),
            lambertian=False,
            energy_conserving=False,
        )


class Exchangeable(NamedTuple):
    """Lobes of a model that can trade places without changing f: a sum that repeats a
    component (``rough_conductor+rough_conductor``). ``parameters[j]`` and ``options[j]`` are the
    names of lobe j's parameters and options, in corresponding order across the lobes; swapping
    two lobes' values (parameters and options together) leaves ``eval``, ``pdf`` and ``sample``'s
    distribution unchanged. ``order_by`` is the position (in a lobe's parameters) of the value
    that orders the lobes of a fit (the first ``roughness`` parameter, else the first), so
    that the fitter reports one labelling: lobe 1 the narrowest (fitlab/fitting/exchange.py)."""

    parameters: tuple[tuple[str, ...], ...]
    options: tuple[tuple[str, ...], ...]
    order_by: int = 0

    def renamed(self, parameter_names: dict, option_names: dict) -> "Exchangeable":
        return Exchangeable(tuple(tuple(parameter_names[n] for n in lobe)
                                  for lobe in self.parameters),
                            tuple(tuple(option_names[n] for n in lobe) for lobe in self.options),
                            self.order_by)


class Option(NamedTuple):
    name: str
    choices: tuple
    default: str
    description: str
    #: the choice a parameter file written before this option existed meant (its fits were made
    #: without it); None: the default (an option that changed nothing old files computed)
    absent: str | None = None


class Term(NamedTuple):
    """A model inside another, with the names its parameters and options carry there: a sum's
    term (fitlab/models/composite.py renames repeated ones) or a layered model's inner model."""

    model: "Model"
    parameter_names: tuple[str, ...]
    option_names: tuple[str, ...]

    @classmethod
    def same_names(cls, model: "Model") -> "Term":
        return cls(model, model.parameter_names, tuple(o.name for o in model.options))


class Model(NamedTuple):
    name: str
    summary: str
    parameters: tuple[Parameter, ...]
    options: tuple[Option, ...]
    eval: Callable
    sample: Callable
    pdf: Callable
    #: free text: which equations, which conventions (shown by ``fitlab models``)
    reference: str
    capabilities: Capabilities = Capabilities()
    #: for a single microfacet interface: (params, **options) -> its MicrofacetDistribution
    #: (Walter's empirical-D diagnostic, the exporters); None for other models
    microfacet: Callable | None = None
    #: sets of interchangeable lobes (a sum that repeats a component); () for most models
    exchangeable: tuple[Exchangeable, ...] = ()
    #: (params: {name: float}, options: dict) -> dict: the layer stack this model approximates,
    #: as the parts of a simulator scene dict (data_formats/scene_toml.md): ``outside``,
    #: ``stack``, ``substrate`` and/or ``below``, and ``effects`` (e.g. max_bounces,
    #: volume_scattering, delta=false); no ``illumination`` or ``detector`` (the caller adds
    #: them); None when the model describes no stack the simulator traces. It raises ValueError
    #: for parameter values the simulator cannot express (data_formats/layered_models.md, "The
    #: simulator's scene of a model").
    scene_of: Callable | None = None
    #: a sum's terms, each with its renamed parameters and options (() for other models)
    terms: tuple[Term, ...] = ()
    #: a layered model's inner models: a coat's inner model, Weidlich–Wilkie's base, the thin
    #: layer's bottom, SpongeCake's substrate (() for other models)
    inner: tuple[Term, ...] = ()
    #: a layered constructor's arguments, (key, value) pairs: its keywords as written, and
    #: SpongeCake's layer kinds under "kinds" (a tuple): code asks this instead of parsing names
    arguments: tuple[tuple[str, object], ...] = ()
    #: (renderer, its native plugin that evaluates this same f) pairs, e.g. ("mitsuba",
    #: "roughconductor"); an exporter translates by plugin, never by model name
    translations: tuple[tuple[str, str], ...] = ()
    #: samples each call draws per parameter set besides its rows (SpongeCake's energy budget
    #: tabulates albedos per call: fitlab/models/directional_albedo.py); 0 for most models.
    #: Code that evaluates many parameter sets at once (a fit's global scan) sizes its blocks
    #: by it: :func:`call_work`
    work_per_parameter_set: int = 0

    def translation(self, renderer: str) -> str | None:
        """The native plugin of ``renderer`` that evaluates this model's f, or None."""
        return dict(self.translations).get(renderer)

    def argument(self, key: str, default=None):
        """A layered constructor's keyword argument (``default`` where not written)."""
        return dict(self.arguments).get(key, default)

    @property
    def lobes(self) -> str:
        """Which side(s) the model scatters to: "reflection" or "reflection+transmission"."""
        return self.capabilities.lobes

    def parameters_with_role(self, role: str) -> tuple[Parameter, ...]:
        if role not in ROLES:
            raise KeyError(f"unknown parameter role {role!r}; roles: {', '.join(ROLES)}")
        return tuple(p for p in self.parameters if p.role == role)

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def default_options(self) -> dict:
        return {o.name: o.default for o in self.options}


def call_work(model: Model) -> int:
    """The samples a call of ``model`` draws per parameter set besides its rows: its own
    ``work_per_parameter_set`` and its terms' and inner models'."""
    return (model.work_per_parameter_set + sum(call_work(t.model) for t in model.terms)
            + sum(call_work(t.model) for t in model.inner))


def choose_branch(P, u):
    """The branch k of a mixture with probabilities ``P`` (K, ...) that ``u[..., 2]`` picks, and
    ``u`` with u[2] rescaled to [0, 1] within that branch's interval (a fresh uniform number
    for the branch's own sampler). Branches of probability 0 are never picked."""
    from fitlab._jax import jnp

    from fitlab.numerics import safe_div

    cdf = jnp.cumsum(P, axis=0)
    pick = jnp.minimum(jnp.sum((u[..., 2] >= cdf[:-1]).astype(jnp.int32), axis=0),
                       P.shape[0] - 1)
    lo = jnp.where(pick > 0, jnp.take_along_axis(cdf, jnp.maximum(pick - 1, 0)[None], 0)[0],
                   0.0)
    width = jnp.take_along_axis(P, pick[None], 0)[0]
    u2 = jnp.clip(safe_div(u[..., 2] - lo, width), 0.0, 1.0)
    return pick, jnp.concatenate([u[..., :2], u2[..., None]], axis=-1)


def sample_result(wo, f, pdf, valid):
    """What ``sample`` returns for directions ``wo`` drawn with density ``pdf``: (wo, weight,
    pdf) with weight = f|cos θo|/pdf (Walter eq. 37), and weight = pdf = 0 where ``valid`` is
    False or the pdf is 0 (the model's own draws that failed)."""
    from fitlab._jax import jnp

    from fitlab.numerics import safe_div

    valid = valid & (pdf > 0)
    weight = safe_div(f * jnp.abs(wo[..., 2]), pdf)
    return wo, jnp.where(valid, weight, 0.0), jnp.where(valid, pdf, 0.0)


# ----------------------------------------------------------------------------------------------
# Simulator scenes of models (``Model.scene_of``; data_formats/scene_toml.md). Indices in a
# model's scene are relative to its outside, index 1, as the model's own parameters are.
# ----------------------------------------------------------------------------------------------

#: The outside of every model's scene: the models' indices are relative to the medium above.
OUTSIDE = {"index": 1.0}


def clear_film(index: float) -> dict:
    """A clear medium of thickness 0: what the simulator needs between an opaque substrate and
    the outside (scene_toml.md, "Stack rules"); it changes nothing optically."""
    return {"type": "medium", "index": float(index), "thickness": 0.0}


def absorbing_slab(index: float, tau: float) -> dict:
    """A medium of thickness 1 with σa = τ: the layered models' optical depth τ = σa·d (Elek
    2010 eq. 3), of which only the product enters."""
    return {"type": "medium", "index": float(index), "thickness": 1.0, "sigma_a": float(tau)}


def interface(index_above: float, index_below: float, **roughness) -> list[dict]:
    """The ``[[stack]]`` interface between media of these indices (``roughness``: distribution,
    alpha or kappa, masking), as a list: empty where the indices are equal, since such an
    interface neither reflects nor refracts (F = 0, Snell the identity) and the simulator
    refuses it."""
    if float(index_above) == float(index_below):
        return []
    return [{"type": "interface", **roughness}]


def immersed(scene: dict, index: float) -> dict:
    """The stack and substrate (or below) of ``scene``, a model's ``scene_of``, moved under a
    medium of index ``index``: a model inside a layer has its indices relative to that layer
    (coated's inner, a Weidlich–Wilkie base), so every medium's index, a conductor's n and k
    (n + ik relative to the medium above), a dielectric substrate's index and the index below
    are multiplied by ``index`` over the scene's own outside index. One channel (numbers)."""
    outside = float(scene.get("outside", OUTSIDE)["index"])
    ratio = float(index) / outside
    out = {"stack": [dict(item, index=item["index"] * ratio) if item["type"] == "medium"
                     else dict(item) for item in scene.get("stack", [])]}
    if "substrate" in scene:
        out["substrate"] = {k: v * ratio if k in ("n", "k", "index") else v
                            for k, v in scene["substrate"].items()}
    else:
        out["below"] = {"index": float(scene.get("below", {"index": outside})["index"]) * ratio}
    return out


def layered_scene(items: list, index: float, inner: dict, effects: dict) -> dict:
    """A scene over an outside of index 1: the ``[[stack]]`` ``items`` (from the top, the last a
    medium of index ``index``) over the stack of ``inner`` (a model's ``scene_of``, relative to
    its outside: :func:`immersed`), whose leading clear film is dropped where it repeats that
    medium. ``effects`` override the inner scene's."""
    under = immersed(inner, index)
    stack = under.pop("stack")
    if stack and stack[0] == clear_film(index):
        stack = stack[1:]
    return {"outside": dict(OUTSIDE), "stack": list(items) + stack, **under,
            "effects": {**inner.get("effects", {}), **effects}}
