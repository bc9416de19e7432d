"""SpongeCake: layered volumetric BSDFs without interfaces (Wang, Jin, Hašan, Yan 2022).

``spongecake(LAYER[,LAYER...][,substrate=MODEL][,delta=true|false])`` stacks homogeneous
layers from the top, each ``surface`` or ``fiber`` (SGGX microflakes, eq. 7, about a free axis),
``surface_z`` or ``fiber_z`` (the same with the axis along the macro normal: no orientation
parameters, an isotropic layer) or ``hg`` (Henyey–Greenstein), over an optional substrate, any
registry BSDF. There are no interfaces:
light keeps its direction across the layers' boundaries (§3.4), so the model is the exact
single scattering of the stack (§4) and the substrate seen through it.

Layer i (1 = top) has parameters, suffixed with i:

* ``alpha`` (flakes): flake roughness α; S = diag(α², α², 1) for surface-like and
  diag(1, 1, α²) for fiber-like flakes (§3.3) in the frame whose z is the axis ωp;
* ``theta_p``, ``phi_p`` (surface, fiber; not the _z kinds): the axis ωp (flake normal / fiber direction) in
  degrees; flakes are two-sided, so ωp and -ωp are the same layer;
* ``g`` (hg): the mean cosine of the Henyey–Greenstein phase function;
* ``albedo``: the constant part γ of the reflectance term F(h) = γ · Schlick(f0, |h·ωi|) of
  eq. 5 (Table 2: f0 = 1 means no Fresnel term); for hg, F = γ, the single-scattering albedo;
* ``f0`` (flakes; named ``f0_i``): the flakes' Schlick reflectance at normal incidence;
* ``tau``: the effective thickness Tρ (thickness × flake density, unitless; §4.1 after eq. 12).
  The extinction along ω is ρσ(ω), σ(ω) = sqrt(ωᵀSω) the flakes' projected area (eq. 3),
  so the optical depth of the layer along ω is Tρ σ(ω)/|cos θ|; for hg, σ = 1.

With Λ(ω) = σ(ω)/cos θ (signed: negative below the horizon) the single scattering of one layer
is eq. 10, f = f̄p/(ρ |cos θi cos θo|) · G, with the reduced phase function f̄p = σt(ωi) F fp
(eq. 5), so f̄p/ρ = F D(h)/4 for microflakes (eqs 4, 11) and γ p_HG for hg, and

    G = (1 − e^{−Tρ(Λi+Λo)}) / (Λi + Λo)                     reflection      (eq. 12)
    G = (1 − e^{−Tρ(Λi+Λo)}) / (Λi + Λo) · e^{TρΛo}           transmission    (eq. 14)

Both are evaluated in a form that cannot overflow or divide 0 by 0: with the optical depths
d = Tρσ/|cos θ| > 0 of the two directions, G/Tρ = φ(di + do) for reflection and
e^{−min(di, do)} φ(|di − do|) for transmission, φ(x) = (1 − e^{−x})/x = −expm1(−x)/x (a series
near 0). Layer i's term is attenuated by the layers the two directions cross outside it (§4.3):
those above it for a direction above the stack, below it for one below. The substrate's f is
attenuated by every layer for each of its directions above the stack (§4.4); with a substrate
the layers scatter only light that arrives from above and leaves upward (paths through the
substrate and a layer scatter twice).

The unscattered transmission (§4.4) is a Dirac delta e^{−Σ di} δ(ωo + ωi) and is never part of
``eval``/``pdf``/``sample``: with ``delta=true`` (the default without a substrate) the model
declares it (``capabilities.delta``, :func:`delta_transmittance` gives its weight), with
``delta=false`` the material has none (the paper's flag: thicker fabrics, leaves). ``sample``
(§4.5) picks a layer with the probability that ωi's light first scatters in it (attenuation of
the layers above, 1 − e^{−di}, times its albedo) or the substrate (the light that reaches it),
then samples that layer's phase function (exactly: the SGGX visible normals, Heitz et al. 2015)
or the substrate; the pdf is the mixture's.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from fitlab._jax import jnp
from fitlab.fresnel import fresnel_schlick
from fitlab.frame import dot, normalize, reflect
from fitlab.models.base import (OUTSIDE, Capabilities, Model, Parameter, Term, choose_branch,
                                layered_scene, sample_result)
from fitlab.models.syntax import Call
from fitlab.numerics import safe_div
from fitlab.phase import (eval_hg, sample_hg, sample_sggx_vndf, sggx_axial_D, sggx_axial_sigma,
                          sggx_matrix)

NAME = "spongecake"
#: surface / fiber: SGGX flakes about a free axis ωp (parameters theta_p, phi_p: anisotropic);
#: surface_z / fiber_z: the axis is the macro normal (no orientation parameters: isotropic);
#: hg: Henyey–Greenstein.
KINDS = ("surface", "fiber", "surface_z", "fiber_z", "hg")
MAX_LAYERS = 6
#: |cos θ| below this is taken as this: the optical depth Tρσ/|cos θ| stays ≤ 1e9, and its
#: derivative finite in float32, on the horizon itself.
MU_MIN = 1e-7
#: φ(x) = −expm1(−x)/x is its series 1 − x/2 + x²/6 − x³/24 below this (error < x⁴/120).
_PHI_SERIES = 1e-3
#: A layer (or the substrate) is sampled with at least this share of the layer-choice mass.
_P_FLOOR = 0.05

USAGE = (f"{NAME}(LAYER[,LAYER...][,substrate=MODEL][,delta=true|false]"
         f"[,multiple=none|lobe|only|learned]) "
         f"with LAYER one of "
         f"{', '.join(KINDS)} from the top, e.g. {NAME}(fiber,surface,substrate=lambertian)")


class Layer(NamedTuple):
    kind: str  # one of KINDS
    index: int  # 1 = top

    @property
    def flakes(self) -> str | None:
        """"surface" or "fiber" for SGGX layers, None for hg."""
        return None if self.kind == "hg" else self.kind.removesuffix("_z")

    @property
    def oriented(self) -> bool:
        """The axis ωp is a parameter (else the macro normal, or no flakes)."""
        return self.kind in ("surface", "fiber")

    def name(self, base: str) -> str:
        return f"{base}_{self.index}" if base == "f0" else f"{base}{self.index}"


def layer_parameters(layer: Layer) -> tuple[Parameter, ...]:
    """The parameters of one layer (the module docstring says what each means)."""
    i, kind = layer.index, layer.flakes
    own = []
    if kind is None:
        own.append(Parameter(layer.name("g"), -0.95, 0.95, 0.0, "1",
                             f"layer {i}: Henyey–Greenstein mean cosine g", "other"))
    else:
        where = "" if layer.oriented else " (axis: the macro normal)"
        own.append(Parameter(layer.name("alpha"), 1e-3, 1.0, 0.3 if kind == "surface" else 0.5,
                             "1", f"layer {i}: SGGX {kind} flake roughness α (SpongeCake "
                             f"§3.3){where}", "roughness"))
    if layer.oriented:
        own += [
            Parameter(layer.name("theta_p"), 0.0, 90.0, 0.0 if kind == "surface" else 90.0,
                      "deg", f"layer {i}: polar angle of the {kind} axis ωp "
                      f"({'flake normal' if kind == 'surface' else 'fiber direction'})", "other"),
            Parameter(layer.name("phi_p"), -180.0, 180.0, 0.0, "deg",
                      f"layer {i}: azimuth of the axis ωp", "other"),
        ]
    own.append(Parameter(layer.name("albedo"), 0.0, 1.0, 0.8, "1",
                         f"layer {i}: albedo γ of the reflectance term (eq. 5, Table 2)", "albedo"))
    if kind is not None:
        own.append(Parameter(layer.name("f0"), 0.0, 1.0, 1.0, "1",
                             f"layer {i}: Schlick reflectance f0 of the flakes (1 = no Fresnel "
                             "term, Table 2)", "albedo"))
    own.append(Parameter(layer.name("tau"), 1e-4, 100.0, 1.0, "1",
                         f"layer {i}: effective thickness Tρ (thickness × density, §4.1)",
                         "optical_depth"))
    return tuple(own)


def axis(theta_p_deg, phi_p_deg):
    """The unit axis ωp from its angles in degrees."""
    t, p = jnp.radians(theta_p_deg), jnp.radians(phi_p_deg)
    st = jnp.sin(t)
    return jnp.stack([st * jnp.cos(p), st * jnp.sin(p), jnp.cos(t) * jnp.ones_like(p)], axis=-1)


def _axis_of(layer, params, w):
    """ωp of the layer, broadcast against directions w."""
    if layer.oriented:
        return axis(params[layer.name("theta_p")], params[layer.name("phi_p")])
    return jnp.zeros_like(w).at[..., 2].set(1.0)


def projected_area(layer: Layer, params, w):
    """σ(w) of the layer's flakes (eq. 3, SGGX eq. 7); 1 for hg."""
    if layer.flakes is None:
        return jnp.ones_like(w[..., 2])
    return sggx_axial_sigma(layer.flakes, params[layer.name("alpha")],
                            _axis_of(layer, params, w), w)


def _half(wi, wo):
    """The flake normal h = (ωi + ωo)/|ωi + ωo| and where it exists (not for ωo = -ωi)."""
    h = wi + wo
    ok = dot(h, h) > 1e-12
    return normalize(jnp.where(ok[..., None], h, jnp.ones_like(h))), ok


def reduced_phase(layer: Layer, params, wi, wo):
    """f̄p/ρ of eq. 5: F(h) D(h)/4 for flakes (eq. 4; F = γ Schlick(f0, |h·ωi|)), γ p_HG for hg.
    0 for ωo = -ωi, where a flake's half vector is undefined."""
    gamma = params[layer.name("albedo")]
    if layer.flakes is None:
        return gamma * eval_hg({"g": params[layer.name("g")]}, wi, wo)
    h, ok = _half(wi, wo)
    D = sggx_axial_D(layer.flakes, params[layer.name("alpha")], _axis_of(layer, params, h), h)
    F = gamma * fresnel_schlick(dot(h, wi), params[layer.name("f0")])
    return jnp.where(ok, 0.25 * F * D, 0.0)


def phase_pdf(layer: Layer, params, wi, wo):
    """The density of the layer's phase-function sample: D(h)/(4σ(ωi)) (eq. 4), p_HG."""
    if layer.flakes is None:
        return eval_hg({"g": params[layer.name("g")]}, wi, wo)
    h, ok = _half(wi, wo)
    a = _axis_of(layer, params, h)
    alpha = params[layer.name("alpha")]
    p = safe_div(sggx_axial_D(layer.flakes, alpha, a, h),
                 4.0 * sggx_axial_sigma(layer.flakes, alpha, a, wi))
    return jnp.where(ok, p, 0.0)


def sample_phase(layer: Layer, params, wi, u):
    """ωo from the layer's phase function (u[..., :2])."""
    if layer.flakes is None:
        return sample_hg({"g": params[layer.name("g")]}, wi, u)[0]
    S = sggx_matrix(layer.flakes, params[layer.name("alpha")], _axis_of(layer, params, wi))
    return reflect(wi, sample_sggx_vndf(S, wi, u))


def phi(x):
    """(1 − e^{−x})/x for x ≥ 0, 1 at 0: −expm1(−x)/x, its series below _PHI_SERIES."""
    small = x < _PHI_SERIES
    xs = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 - x * (0.5 - x * (1.0 / 6.0 - x / 24.0)), -jnp.expm1(-xs) / xs)


def depths(layers, params, w):
    """Optical depths d_i = Tρ_i σ_i(w)/|cos θ| of every layer along w, (L, ...)."""
    mu = jnp.maximum(jnp.abs(w[..., 2]), MU_MIN)
    return jnp.stack([params[L.name("tau")] * projected_area(L, params, w) / mu for L in layers])


def _outside(d, up):
    """Σ of the depths a direction crosses outside each layer to reach it: the layers above it
    for a direction above the stack (``up``), below it otherwise; (L, ...)."""
    above = jnp.cumsum(d, axis=0) - d
    below = jnp.sum(d, axis=0) - above - d
    return jnp.where(up, above, below)


def single_scattering_terms(layers, params, wi, wo, only=None):
    """Each layer's term of eq. 10 with G of eq. 12 (same side) or 14 (opposite sides),
    attenuated outside its layer (§4.3), (L, ...); the stable forms of the module docstring.
    ``only``: the index of the one layer wanted (its term alone, (...))."""
    di, do = depths(layers, params, wi), depths(layers, params, wo)
    up_i, up_o = wi[..., 2] > 0, wo[..., 2] > 0
    att = jnp.exp(-(_outside(di, up_i) + _outside(do, up_o)))
    pick = range(len(layers)) if only is None else (only,)
    tau = jnp.stack([params[layers[j].name("tau")] * jnp.ones_like(wi[..., 2]) for j in pick])
    di, do, att = (x[jnp.asarray(pick)] for x in (di, do, att))
    G = tau * jnp.where(up_i == up_o, phi(di + do),
                        jnp.exp(-jnp.minimum(di, do)) * phi(jnp.abs(di - do)))
    fp = jnp.stack([reduced_phase(layers[j], params, wi, wo) for j in pick])
    mu = (jnp.maximum(jnp.abs(wi[..., 2]), MU_MIN) * jnp.maximum(jnp.abs(wo[..., 2]), MU_MIN))
    terms = fp * G * att / mu
    return terms if only is None else terms[0]


def single_scattering(layers, params, wi, wo):
    """Σ over the layers of :func:`single_scattering_terms`."""
    return jnp.sum(single_scattering_terms(layers, params, wi, wo), axis=0)


def single_scattering_albedo_weights(layers, params, wi, u, upward_only=False):
    """Per point u, Σ over the layers of layer i's term at ωo drawn from its own phase function
    (u[..., :2]) times |cos θo| over that phase function's pdf: an estimator of the stack's
    single-scattering albedo ∫ f_ss |cos θo| dωo whose weights are smooth and bounded (F σ(ωi)
    G att/|cos θi| for flakes), cheaper than the model's mixture. ``upward_only``: count only
    ωo above the surface (the layers over a substrate)."""
    total = 0.0
    for j, L in enumerate(layers):
        wo = sample_phase(L, params, wi, u)
        term = single_scattering_terms(layers, params, wi, wo, only=j)
        w = safe_div(term * jnp.abs(wo[..., 2]), phase_pdf(L, params, wi, wo))
        if upward_only:
            w = jnp.where(wo[..., 2] > 0, w, 0.0)
        total = total + w
    return total


def first_scattering(layers, params, wi):
    """(L, ...): the probability that ωi's light first scatters in each layer (the layers it
    crosses before, then 1 − e^{−d}) times the layer's albedo: §4.5's layer-choice weights."""
    d = depths(layers, params, wi)
    first = jnp.exp(-_outside(d, wi[..., 2] > 0)) * -jnp.expm1(-d)
    gamma = jnp.stack([params[L.name("albedo")] * jnp.ones_like(wi[..., 2]) for L in layers])
    return first * gamma


def delta_transmittance(layers, params, wi):
    """Weight e^{−Σ d_i(ωi)} of the unscattered transmission δ(ωo + ωi) (§4.4)."""
    return jnp.exp(-jnp.sum(depths(layers, params, wi), axis=0))


def seen_through(layers, params, w):
    """Transmittance of the whole stack along w for a direction above it, 1 below (§4.4)."""
    return jnp.where(w[..., 2] > 0, delta_transmittance(layers, params, w), 1.0)


def make_spongecake(kinds: tuple[str, ...], substrate: Model | None = None,
                    delta: bool | None = None) -> Model:
    """The SpongeCake model of layers ``kinds`` (top first) over ``substrate`` (None: none)."""
    if not kinds:
        raise ValueError(f"{NAME}(...) needs at least one layer: {USAGE}")
    if len(kinds) > MAX_LAYERS:
        raise ValueError(f"{NAME}(...) takes at most {MAX_LAYERS} layers, got {len(kinds)}")
    for k in kinds:
        if k not in KINDS:
            raise ValueError(f"{NAME}(...): unknown layer {k!r}; layers are "
                             f"{', '.join(KINDS)} (a substrate is given as substrate=MODEL)")
    if delta is None:
        delta = substrate is None
    if delta and substrate is not None:
        raise ValueError(f"{NAME}(...,substrate=...): the layers sit on the substrate, so no "
                         "light leaves unscattered below them; drop delta=true")
    layers = tuple(Layer(k, i + 1) for i, k in enumerate(kinds))
    own = tuple(p for L in layers for p in layer_parameters(L))
    sub_names = substrate.parameter_names if substrate is not None else ()
    clash = {p.name for p in own} & set(sub_names)
    if clash:
        raise ValueError(f"{NAME}(...,substrate={substrate.name}): the substrate already has "
                         f"parameter(s) {', '.join(sorted(clash))}")
    sub_options = tuple(o.name for o in substrate.options) if substrate is not None else ()

    def split(params, opts):
        return ({k: params[k] for k in sub_names},
                {k: v for k, v in opts.items() if k in sub_options})

    def layers_on(wi, wo):
        """Where the layers' single scattering applies (above a substrate: both up)."""
        if substrate is None:
            return jnp.ones(wi.shape[:-1], bool)
        return (wi[..., 2] > 0) & (wo[..., 2] > 0)

    def eval(params, wi, wo, **opts):
        f = jnp.where(layers_on(wi, wo), single_scattering(layers, params, wi, wo), 0.0)
        if substrate is not None:
            p_s, o_s = split(params, opts)
            f = f + (substrate.eval(p_s, wi, wo, **o_s)
                     * seen_through(layers, params, wi) * seen_through(layers, params, wo))
        return f

    def choice(params, wi):
        """Probabilities (L [+1], ...) of sampling each layer [and the substrate] for ωi."""
        up = wi[..., 2] > 0
        mass = first_scattering(layers, params, wi)
        if substrate is not None:  # light from below meets the substrate alone
            mass = jnp.concatenate([jnp.where(up, mass, 0.0),
                                    jnp.where(up, delta_transmittance(layers, params, wi),
                                              1.0)[None]])
        n = mass.shape[0]
        p = safe_div(mass, jnp.sum(mass, axis=0), 1.0 / n) + _P_FLOOR
        if substrate is not None:
            p = jnp.where(up, p, (jnp.arange(n) == n - 1).astype(wi.dtype).reshape(
                (n,) + (1,) * up.ndim))
        return p / jnp.sum(p, axis=0)

    def pdf(params, wi, wo, **opts):
        P = choice(params, wi)
        on = layers_on(wi, wo)
        p = sum(P[j] * jnp.where(on, phase_pdf(L, params, wi, wo), 0.0)
                for j, L in enumerate(layers))
        if substrate is not None:
            p_s, o_s = split(params, opts)
            p = p + P[-1] * substrate.pdf(p_s, wi, wo, **o_s)
        return p

    def sample(params, wi, u, **opts):
        """A layer (or the substrate) chosen with u[2] by :func:`choice`, then its phase
        function (u[0:2]) or the substrate's sample (u with u[2] rescaled); weight = f|cos|/pdf
        of the mixture (§4.5)."""
        pick, uu = choose_branch(choice(params, wi), u)
        wo = jnp.zeros_like(wi)
        valid = jnp.zeros(wi.shape[:-1], bool)
        for j, L in enumerate(layers):
            w_j = sample_phase(L, params, wi, u)
            wo = jnp.where((pick == j)[..., None], w_j, wo)
            valid = valid | (pick == j)
        valid = valid & layers_on(wi, wo)
        if substrate is not None:
            p_s, o_s = split(params, opts)
            w_s, _, p_sub = substrate.sample(p_s, wi, uu, **o_s)
            is_sub = pick == len(layers)
            wo = jnp.where(is_sub[..., None], w_s, wo)
            valid = jnp.where(is_sub, p_sub > 0, valid)
        return sample_result(wo, eval(params, wi, wo, **opts), pdf(params, wi, wo, **opts), valid)

    def scene_of(params, options):
        """The layers as index-matched media (:func:`stack_scene`) over the substrate's own
        scene, if any. The model is the stack's exact single scattering (§4): it matches the
        simulation with volume_scattering = "single" and the delta transmission dropped
        (delta = false; the model declares it apart). Over a substrate the simulated single
        scattering also holds the paths that scatter once in the layers and reflect off the
        substrate, which the model leaves out (§4.4: they scatter twice)."""
        sub = None
        if substrate is not None:
            p_s, o_s = split(params, options)
            sub = substrate.scene_of(p_s, {**substrate.default_options(), **o_s})
            if sub is None:
                return None
        scene = stack_scene(kinds, {"": params}, sub)
        return {**scene, "effects": {**scene.get("effects", {}), "volume_scattering": "single",
                                     "delta": False}}

    has_delta = "the unscattered transmission e^{−Σ Tρ σ(ωi)/|cos θi|} δ(ωo + ωi) " \
        "(spongecake.delta_transmittance)" if delta else ""
    sub_caps = substrate.capabilities if substrate is not None else Capabilities()
    oriented = any(L.oriented for L in layers)
    return Model(
        name=canonical_name(kinds, substrate.name if substrate is not None else None, delta),
        summary=(f"SpongeCake: {len(layers)} volumetric layer(s) ({', '.join(kinds)}) without "
                 f"interfaces, exact single scattering"
                 + (f", over {substrate.name}" if substrate is not None else "")),
        parameters=own + (substrate.parameters if substrate is not None else ()),
        options=substrate.options if substrate is not None else (),
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=Capabilities(
            reflection=True,
            transmission=substrate is None or sub_caps.transmission,
            isotropic=not oriented and sub_caps.isotropic,
            reciprocal=sub_caps.reciprocal,
            delta="; ".join(d for d in (has_delta, sub_caps.delta if substrate else "") if d),
        ),
        scene_of=scene_of if substrate is None or substrate.scene_of is not None else None,
        reference=("SpongeCake (Wang et al. 2022): eqs 3-5, 7 (SGGX microflakes), eq. 10 with "
                   "G of eqs 12 and 14 (single scattering), §4.3 (layers), §4.4 (substrate, "
                   "delta transmission), §4.5 (sampling)"
                   + (f"; substrate: {substrate.reference}" if substrate is not None else "")),
    )


def canonical_name(kinds, substrate_name=None, delta=None, multiple="none") -> str:
    args = list(kinds)
    if substrate_name is not None:
        args.append(f"substrate={substrate_name}")
    default_delta = substrate_name is None and multiple != "only"
    if delta is not None and delta != default_delta:
        args.append(f"delta={'true' if delta else 'false'}")
    if multiple != "none":
        args.append(f"multiple={multiple}")
    return f"{NAME}({','.join(args)})"


_BOOL = {"true": True, "false": False}


def from_call(call: Call, get_model) -> Model:
    """Build from the parsed name (models/syntax.py); see :data:`USAGE`."""
    from fitlab.models.spongecake_multiple import MODES

    kwargs = dict(call.kwargs)
    unknown = set(kwargs) - {"substrate", "delta", "multiple"}
    if unknown:
        raise ValueError(f"{NAME}(...): unknown keyword(s) {', '.join(sorted(unknown))}; "
                         "accepted: substrate=MODEL, delta=true|false, "
                         f"multiple=none|lobe|only|learned. "
                         f"{USAGE}")
    delta = kwargs.get("delta")
    if delta is not None:
        if delta.lower() not in _BOOL:
            raise ValueError(f"{NAME}(...,delta={delta}): delta must be true or false")
        delta = _BOOL[delta.lower()]
    multiple = kwargs.get("multiple", "none").lower()
    if multiple not in MODES:
        raise ValueError(f"{NAME}(...,multiple={kwargs['multiple']}): multiple must be none "
                         "(single scattering), lobe (with the multiple-scattering lobe, §5), "
                         "only (that lobe alone, to fit a simulated multiple-scattering part) or "
                         "learned (the lobe from the parameter-mapping network)")
    if multiple == "only" and delta:
        raise ValueError(f"{NAME}(...,multiple=only): the multiple-scattering lobe has no "
                         "unscattered transmission; drop delta=true")
    substrate = get_model(kwargs["substrate"]) if "substrate" in kwargs else None
    return _cached(tuple(call.args), substrate, delta, multiple)


@functools.lru_cache(maxsize=None)
def _cached(kinds, substrate, delta, multiple="none") -> Model:
    return _structured(_built(kinds, substrate, delta, multiple), kinds, substrate, delta,
                       multiple)


def _built(kinds, substrate, delta, multiple) -> Model:
    base = make_spongecake(kinds, substrate, False if multiple == "only" else delta)
    if multiple == "none":
        return base
    if multiple == "learned":
        model = _with_learned(kinds, substrate, base, delta)
    else:
        model = _with_multiple(kinds, substrate, base, delta, multiple)
    # multiple=only has no scene: its parameters are the fitted lobe's, not the stack's
    return model if multiple == "only" else \
        model._replace(scene_of=with_multiple_scattering(base.scene_of))


def _structured(model: Model, kinds, substrate, delta, multiple) -> Model:
    """``model`` carrying its call's structure: the layer kinds (``kinds``), the substrate
    (``inner``), delta and multiple as written."""
    args = [("kinds", tuple(kinds))]
    if substrate is not None:
        args.append(("substrate", substrate.name))
    if delta is not None:
        args.append(("delta", "true" if delta else "false"))
    if multiple != "none":
        args.append(("multiple", multiple))
    return model._replace(inner=(Term.same_names(substrate),) if substrate is not None else (),
                          arguments=tuple(args))


def stack_kinds(model: Model) -> tuple[str, ...]:
    """The layer kinds of a single-scattering SpongeCake stack without substrate (what the
    simulator can trace and the lobe fit takes); ValueError for any other model."""
    kinds = model.argument("kinds")
    if kinds is None:
        raise ValueError(f"{model.name!r} is not a SpongeCake model; the lobe fit takes "
                         f"{NAME}(LAYER[,LAYER...])")
    if model.inner:
        raise ValueError(f"{model.name}: the simulator's media have no substrate, so the lobe of "
                         "a stack over a substrate cannot be simulated; fit the stack alone")
    if model.argument("multiple", "none") != "none":
        raise ValueError(f"{model.name}: give the single-scattering model (without multiple=)")
    return tuple(kinds)


def with_multiple_scattering(scene_of):
    """``scene_of`` of the single-scattering model with every volume scattering order
    (volume_scattering = "multiple"): the same physical stack, the whole of which the
    ``multiple=lobe`` and ``multiple=learned`` models approximate (§5). None stays None."""
    if scene_of is None:
        return None

    def scene(params, options):
        s = scene_of(params, options)
        return None if s is None else \
            {**s, "effects": {**s["effects"], "volume_scattering": "multiple"}}

    return scene


def _with_learned(kinds, substrate, base, delta) -> Model:
    """``base`` with the multiple-scattering lobe from the shipped parameter-mapping network
    (fitlab/models/spongecake_network.py): one or two flake layers, no substrate (what it was trained
    on; the paper trains one network per number of layers, its Figs. 5 and 6)."""
    from fitlab.models import spongecake_network as sl
    from fitlab.models import spongecake_multiple as ms

    if len(kinds) not in sl.LAYERS or "hg" in kinds or substrate is not None:
        raise ValueError(f"{NAME}(...,multiple=learned): the networks are trained for one or two "
                         "layers of flakes (surface, fiber, surface_z or fiber_z) without a "
                         "substrate; for other stacks fit the lobe (multiple=lobe, "
                         "`fitlab multiple-lobe`)")
    layers = tuple(Layer(k, i + 1) for i, k in enumerate(kinds))
    weights = sl.weight_arrays(len(layers))
    is_fiber = np.asarray([float(L.flakes == "fiber") for L in layers])

    def lobe_of(params):
        one = jnp.ones_like(jnp.asarray(params["alpha1"]))
        per = lambda key: jnp.stack([jnp.asarray(params[f"{key}{L.index}"]) * one  # noqa: E731
                                     for L in layers], axis=-1)
        cos_p = jnp.stack([jnp.cos(jnp.radians(params[f"theta_p{L.index}"])) * one
                           if L.oriented else one for L in layers], axis=-1)
        # a layer whose axis is the normal has no azimuth: cos Δφ = 1 stands for any
        phi = [jnp.radians(params[f"phi_p{L.index}"]) * one if L.oriented else None
               for L in layers]
        cos_dphi = jnp.stack([one if phi[0] is None or phi[i] is None
                              else jnp.cos(phi[i] - phi[0]) for i in range(1, len(layers))]
                             + [one], axis=-1)[..., :len(layers) - 1]
        x = sl.network_inputs(is_fiber, per("alpha"), per("albedo"), per("tau"), per("f0_"),
                              cos_p, cos_dphi)
        return sl.lobe_from_outputs(sl.mlp_apply(weights, x), len(layers))

    lobe = _with_multiple(kinds, substrate, base, delta, "lobe")
    name = canonical_name(kinds, None, delta, "learned")
    p = sl.provenance(len(layers))
    return ms.with_learned(lobe, base, name, lobe_of,
                           f"{p['dataset']['stacks']} simulated {len(layers)}-layer stacks, "
                           f"held-out relative MAE {p['errors']['held_out_loss']:.3g}")


def _with_multiple(kinds, substrate, base, delta, multiple) -> Model:
    """``base`` with SpongeCake's multiple-scattering lobe (§5;
    :mod:`fitlab.models.spongecake_multiple`), or that lobe alone."""
    from fitlab.models import spongecake_multiple as ms

    layers = tuple(Layer(k, i + 1) for i, k in enumerate(kinds))
    stack = _cached(kinds, None, False)
    extra = tuple(p for L in layers for p in layer_parameters(L)
                  if multiple == "only" and p.name.startswith(("theta_p", "phi_p")))
    extra += tuple(p for L in layers for p in ms.modified_parameters(layer_parameters(L)))
    extra += ms.weight_parameters(transmits=substrate is None)

    def stack_mass(p, wi):
        return jnp.sum(first_scattering(layers, p, wi), axis=0)

    def base_mass(p, wi):
        m = stack_mass(p, wi)
        return m if substrate is None else m + delta_transmittance(layers, p, wi)

    def stack_albedo(p, wi, u):
        return single_scattering_albedo_weights(layers, p, wi, u,
                                                upward_only=substrate is not None)

    def base_albedo(p, wi, u, opts):
        """The layers' single scattering, and the substrate's sample weights seen through the
        layers both ways (§4.4)."""
        w = stack_albedo(p, wi, u)
        if substrate is None:
            return w
        names = set(o.name for o in substrate.options)
        wo, w_s, _ = substrate.sample({k: p[k] for k in substrate.parameter_names}, wi, u,
                                      **{k: v for k, v in opts.items() if k in names})
        return w + w_s * seen_through(layers, p, wi) * seen_through(layers, p, wo)

    name = canonical_name(kinds, substrate.name if substrate is not None else None,
                          None if multiple == "only" else delta, multiple)
    return ms.with_multiple(None if multiple == "only" else base, stack, multiple, name,
                            transmits=substrate is None, above_only=substrate is not None,
                            extra=extra, stack_mass=stack_mass, base_mass=base_mass,
                            capabilities=base.capabilities, stack_albedo=stack_albedo,
                            base_albedo=base_albedo)


def simulator_stack(kinds, channel_params) -> list[dict]:
    """The layers as the ``[[stack]]`` items of a simulator scene (data_formats/scene_toml.md):
    index-matched media of thickness Tρ with σs = γ and σa = 1 − γ per channel, so that the
    extinction along ω is Tρσ(ω)/|cos θ| and the scattering albedo γ as in the model (§3.2),
    flakes with their roughness, axis and Schlick f0. ``channel_params``: one parameter dict
    per channel (R, G, B or one); Tρ, α, g and the axis must not differ between channels."""
    chans = list(channel_params)
    items = []
    for L in (Layer(k, i + 1) for i, k in enumerate(kinds)):
        def grey(base):
            vals = {float(channel_params[c][L.name(base)]) for c in chans}
            if len(vals) != 1:
                raise ValueError(f"{L.name(base)} differs between channels: the simulator's "
                                 "media take it as one value")
            return vals.pop()

        def per_channel(base, f=lambda x: x):
            vals = [f(float(channel_params[c][L.name(base)])) for c in chans]
            return vals[0] if len(set(vals)) == 1 else vals

        item = {"type": "medium", "index": 1.0, "thickness": grey("tau"),
                "sigma_s": per_channel("albedo"), "sigma_a": per_channel("albedo", lambda g: round(1.0 - g, 12))}
        if L.flakes is None:
            item.update(phase="hg", g=grey("g"))
        else:
            if L.oriented:
                a = axis(jnp.asarray(grey("theta_p")), jnp.asarray(grey("phi_p")))
                orientation = [round(float(x), 12) + 0.0 for x in a]
            else:
                orientation = [0.0, 0.0, 1.0]
            item.update(phase=f"sggx_{L.flakes}", roughness=grey("alpha"),
                        orientation=orientation, flake_f0=per_channel("f0"))
        items.append(item)
    return items


def stack_scene(kinds, channel_params, substrate_scene: dict | None = None) -> dict:
    """The ``outside``, ``stack`` and ``substrate`` or ``below`` of a simulator scene: the layers
    (:func:`simulator_stack`; ``channel_params`` as there) under an outside of index 1, over
    ``substrate_scene`` (a substrate model's ``scene_of``; the layers are index-matched, so it
    sits at the outside's index) or, without one, over the outside's index again. The model's
    ``scene_of`` and :func:`fitlab.models.presets.preset_scene` both build on it."""
    items = simulator_stack(kinds, channel_params)
    if substrate_scene is None:
        return {"outside": dict(OUTSIDE), "stack": items}
    return layered_scene(items, OUTSIDE["index"], substrate_scene, {})
