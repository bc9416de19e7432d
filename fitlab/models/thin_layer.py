"""The extended-NDF thin transparent layer of Guo, Qian and Pan 2015 ("Practical rendering of
thin layered materials with extended microfacet normal distributions"), ``thin_layer(BOTTOM)``.

A transparent layer of index η (relative to the outside) between a rough top boundary (a vMF
NDF of concentration κ1, eqs 5-6) and a rough, opaque bottom boundary of concentration κ2:
``thin_layer(rough_conductor)`` (a conductor n2 + i k2) or ``thin_layer(rough_dielectric)`` (a
dielectric substrate of index eta2 whose transmitted light is lost). The bottom's index is
relative to vacuum and evaluated relative to the layer (n2/η, k2/η, eta2/η). Absorption in the
layer: the optical depth τ = σa·d per channel (eq. 27). ``thin_layer(BOTTOM,roughness=alpha)``
takes widths α1, α2 instead, with the stated mapping κ = 2/α² (fitlab's vMF axis, where
e^{κ(cos θ - 1)} ≈ e^{-θ²/α²} matches Beckmann's lobe).

Components (eq. 25), each on its own with option ``component``:

* ``surface``: Walter's BRDF of the top boundary, F(i·h) G D(h; κ1) / (4 cos θi cos θo)
  (eqs 1-2, 9; D by eq. 6, G by eq. 8);
* order k = 1..K (option ``bounces``, default 1 as the paper argues from its Fig. 13): light
  refracted in, reflected k times off the bottom (and k - 1 times internally off the top),
  refracted out. Its lobe is the NDF tree of eq. 26, extended by the same rules: the exit
  distribution D(i2) is the spherical convolution (eq. 18) of the top roughness at entry and at
  exit (each warped by refraction, eq. 13, and carried to the exit by the macro-normal
  refractions, ‖∂t/∂i‖ = cos θ_out/(η² cos θ_in), eq. 21), and the bottom roughness warped by
  reflection (eq. 12: κ/(4 cos θt)) k times (the internal top reflections k - 1 times). The
  moment-matched lobe κ̂ becomes an ENDF over the virtual half vector, κ_m = 4 cos θ κ̂ (eq. 19).
  Its weight is the "remaining terms" Mt·Mr·Mt at the mean directions (section 5.1) as energy
  factors: the Fresnel transmittances in and out, the bottom reflectance (and the internal top
  reflectance) and the masking G = G1 G1 of every crossing, times the absorption of eq. 27
  per round trip. The lobe itself is a microfacet BRDF with the ENDF:
  f_k = E_k D(h; κ_m) G1(i; κ_m) G1(o; κ_m) / (4 cos θi cos θo).

fitlab's addition (option ``compensation``, default ``table``; ``none`` is the paper's model):
the light the K orders and the mean-direction weights lose, or gain, restored from a table made
by the simulator: f = g(μi) g(μo) f_paper + f_c (fitlab/models/thin_layer_compensation.py;
``component=compensation`` is f_c alone).

Decisions where the paper is silent (data_formats/layered_models.md states them with their
measured errors):

* The mean path runs through the macro normal (µm = n, as the paper assumes). The remaining
  terms use the incoming side's refracted direction on the way in and the outgoing side's on
  the way out, and the bottom's Fresnel at the inside half vector of the two; the tree is
  evaluated for the incidence the virtual half vector h sees, cos θd = wi·h = wo·h. On the
  specular path both are the paper's choice exactly (it traces from the eye); off it f stays
  reciprocal, f(i, o) = f(o, i). (A geometric mean of the trees from both sides is reciprocal
  too, but its lobe widens with θo fast enough to add 11% energy at normal incidence.)
* The Jacobians inside Mt and Mr (η²|t·m|/(o·m + η t·m)², 1/(4|o·n||i·n|)) are not multiplied
  in again: they are what the warping already put into κ̂. Multiplying the paper's Mt·Mr·Mt as
  printed would scale the lobe by about 36 at normal incidence (η = 1.5) and break energy
  conservation; with energy factors the lobe integrates to its weight E_k (white furnace).
* The vMF NDFs are normalized exactly over the upper hemisphere (fitlab.vmf.D), which is eq. 6's
  1/A3 normalization for κ ≥ 100 and the correct one below (the paper advises its 1/A3 there).
* Masking: the integral of eq. 7 by quadrature (``masking=exact``, the default), or the
  paper's approximation eq. 8 (``masking=approx``). Eq. 8 is close for κ ≤ 100 away from the
  horizon but overestimates G1 near it (κ = 1e6 at 89.994°: 0.995 against 0.215) and makes the
  model gain energy there (directional albedo 14 at 89.99° for κ1 = 1000, κ2 = 100): the
  default keeps every hard case at albedo ≤ 1.
"""

from __future__ import annotations

import functools

from fitlab._jax import jnp
from fitlab import vmf
from fitlab.models import thin_layer_compensation as compensation_table
from fitlab.fresnel import (CONDUCTOR_FRESNEL_METHODS, fresnel_dielectric,
                            fresnel_dielectric_Walter2007)
from fitlab.frame import dot, normalize, reflect
from fitlab.interface import beer_lambert, refract_down, transmittance
from fitlab.models.base import (OUTSIDE, Capabilities, Model, Option, Parameter,
                                absorbing_slab, interface, sample_result)
from fitlab.models.syntax import call_arguments
from fitlab.numerics import safe_div

NAME = "thin_layer"
MAX_BOUNCES = 4
ROUGHNESS_CHOICES = ("kappa", "alpha")

#: sample() gives every included lobe at least this share before normalizing (a lobe whose
#: estimated weight is 0 at this incidence can still be reached).
_P_FLOOR = 0.05

KAPPA_LO, KAPPA_HI = 1e-2, 1e7
ALPHA_LO, ALPHA_HI = float((2.0 / KAPPA_HI) ** 0.5), 1.0


def _concentration(i, default, what):
    return Parameter(f"kappa{i}", KAPPA_LO, KAPPA_HI, default, "1",
                     f"vMF concentration κ{i} of the {what} boundary's NDF (eqs 5-6; "
                     f"κ ≈ 2/α²)", "concentration")


def _width(i, default, what):
    return Parameter(f"alpha{i}", ALPHA_LO, ALPHA_HI, default, "1",
                     f"width α{i} of the {what} boundary's vMF NDF, κ{i} = 2/α{i}²", "roughness")


ETA = Parameter("eta", 0.5, 3.0, 1.5, "1", "index of the layer relative to the outside η", "index")
TAU = Parameter("tau", 0.0, 20.0, 0.0, "1",
                "optical depth of the layer at normal incidence τ = σa·d (eq. 27); 0 = clear",
                "optical_depth")

OPTIONS = (
    Option("bounces", tuple(str(k) for k in range(1, MAX_BOUNCES + 1)), "1",
           "K: subsurface orders 1..K included (the paper keeps 1: Fig. 13)"),
    Option("component", ("all", "surface", "subsurface", "compensation")
           + tuple(str(k) for k in range(1, MAX_BOUNCES + 1)), "all",
           "all: surface + orders 1..K (with the compensation); surface: the top boundary's "
           "reflection; subsurface: orders 1..K; compensation: fitlab's compensation lobe "
           "alone (all = g(μi) g(μo) (surface + subsurface) + compensation); a number k: "
           "subsurface order k alone"),
    Option("masking", ("exact", "approx"), "exact",
           "exact: eq. 7's integral (quadrature; energy conserving); approx: eq. 8, which "
           "overestimates G1 at grazing angles (albedo up to 14 at 89.99° measured)"),
    Option("compensation", ("table", "none"), "table",
           "table: fitlab's energy compensation (a lobe carrying the light the paper's model "
           "loses, tabulated from the simulator: fitlab/models/thin_layer_compensation.py); "
           "none: the paper's model as published", absent="none"),
)
DEFAULT_OPTIONS = {o.name: o.default for o in OPTIONS}


def _included(opts):
    """(surface included?, the subsurface orders included, compensation included?)."""
    c, K = opts["component"], int(opts["bounces"])
    table = opts["compensation"] == "table"
    if c == "all":
        return True, tuple(range(1, K + 1)), table
    if c == "surface":
        return True, (), False
    if c == "subsurface":
        return False, tuple(range(1, K + 1)), False
    if c == "compensation":
        return False, (), table
    return False, (int(c),), False


def _bottom_kind(bottom: Model) -> str:
    """'conductor' or 'dielectric' from what the bottom model declares (never its name)."""
    roles = [p.role for p in bottom.parameters]
    if (not bottom.capabilities.isotropic or roles.count("roughness") != 1
            or roles.count("index") != 1 or bottom.capabilities.lambertian):
        raise ValueError(
            f"{NAME}({bottom.name}): the bottom boundary must be an isotropic rough conductor "
            f"(rough_conductor) or rough dielectric (rough_dielectric): one microfacet width, "
            f"one index (and an extinction for a conductor)")
    if bottom.capabilities.transmission:
        return "dielectric"
    if roles.count("extinction") != 1:
        raise ValueError(f"{NAME}({bottom.name}): an opaque bottom needs an extinction "
                         f"coefficient (a conductor: rough_conductor)")
    return "conductor"


class _Side:
    """What one side (incoming or outgoing) contributes: the direction above, its cosine, the
    refracted direction in the layer and its cosine, and whether it refracts in."""

    def __init__(self, w, eta, up):
        self.w = w
        self.c = jnp.where(up, w[..., 2], 1.0)
        self.t, ok = refract_down(w, eta)
        self.ok = up & ok
        self.ct = jnp.where(self.ok, self.t[..., 2], 1.0)
        self.T = transmittance(self.c, eta)


class _Incidence:
    """The tree's view of one incidence: cos θ above, cos θt inside (Snell through the macro
    normal) and whether it refracts in; :class:`_Side` is one, with its direction."""

    def __init__(self, c, eta):
        _, cos_t, _, _ = fresnel_dielectric(c, eta)
        self.c = c
        self.ok = cos_t < 0
        self.ct = jnp.where(self.ok, -cos_t, 1.0)


def _dispersions(side, eta, k1, k2):
    """The exit-space dispersions ν = 1/κ of the tree's branches seen from ``side`` (eq. 26):
    top roughness at entry or exit (eq. 13 × the macro-normal refraction, both
    (c - η c_t)²/(c κ1)), one bottom reflection (eq. 12, 4 η² c_t²/(c κ2)), one internal top
    reflection (4 η² c_t²/(c κ1))."""
    c, ct = side.c, side.ct
    nu_top = (c - eta * ct) ** 2 / (c * k1)
    nu_bottom = 4.0 * eta * eta * ct * ct / (c * k2)
    nu_internal = 4.0 * eta * eta * ct * ct / (c * k1)
    return nu_top, nu_bottom, nu_internal


def _lobe_nu(side, eta, k1, k2, order):
    """Dispersion of order ``order``'s ENDF over the virtual half vector, from ``side``: the
    convolution (eq. 18) of the branches, then κ_m = 4 c κ̂ (eq. 19)."""
    nu_top, nu_bottom, nu_internal = _dispersions(side, eta, k1, k2)
    L = (2.0 * vmf.log_A3_of_nu(nu_top) + order * vmf.log_A3_of_nu(nu_bottom)
         + (order - 1) * vmf.log_A3_of_nu(nu_internal))
    return vmf.nu_of_log_A3(L) / (4.0 * side.c)


def _broadcast(params, wi, wo):
    """Parameters and directions broadcast to one leading shape (the masking is evaluated for
    several directions at once, stacked on a new axis)."""
    lead = jnp.broadcast_shapes(wi.shape[:-1], wo.shape[:-1],
                                *(jnp.shape(v) for v in params.values()))
    return ({k: jnp.broadcast_to(v, lead) for k, v in params.items()},
            jnp.broadcast_to(wi, lead + (3,)), jnp.broadcast_to(wo, lead + (3,)))


def _half_vector(a, b, ok):
    """normalize(a + b) where ``ok`` (both above), +z elsewhere: a + b = 0 (wo = -wi) would
    make the gradient of the dead branch NaN."""
    e_z = jnp.zeros_like(a) + jnp.asarray([0.0, 0.0, 1.0], a.dtype)
    return normalize(jnp.where(ok[..., None], a + b, e_z))


def _kappa_of_nu(nu):
    return 1.0 / jnp.clip(nu, 1.0 / vmf.KAPPA_MAX, 1.0 / vmf.KAPPA_MIN)


def scene_effects(options) -> dict:
    """max_bounces = the highest subsurface order the model includes (``component=surface``:
    0). The simulator's total then holds orders 0..K; ``component=subsurface`` or ``k`` is to
    be compared with the simulated bounce orders 1..K or k (``by_order``). No delta."""
    _, orders, with_table = _included({**DEFAULT_OPTIONS, **options})
    return {"max_bounces": "all" if with_table else max(orders, default=0), "delta": False}


def make_thin_layer(bottom: Model, roughness: str = "kappa") -> Model:
    kind = _bottom_kind(bottom)
    if roughness not in ROUGHNESS_CHOICES:
        raise ValueError(f"{NAME}(...,roughness={roughness}): choose "
                         f"{' or '.join(ROUGHNESS_CHOICES)}")
    if roughness == "kappa":
        top_r, bottom_r = _concentration(1, 1000.0, "top"), _concentration(2, 100.0, "bottom")
    else:
        top_r, bottom_r = _width(1, 0.045, "top"), _width(2, 0.14, "bottom")
    bottom_params = tuple(
        p._replace(name=f"{p.name}2", description=f"{p.description} of the bottom boundary "
                   "(relative to vacuum; evaluated relative to the layer)")
        for p in bottom.parameters if p.role in ("index", "extinction"))
    parameters = (top_r, ETA, TAU, bottom_r) + bottom_params
    index_name = next(p.name for p in bottom_params if p.role == "index")
    extinction_name = next((p.name for p in bottom_params if p.role == "extinction"), None)

    def concentrations(params):
        if roughness == "kappa":
            k1, k2 = params["kappa1"], params["kappa2"]
        else:
            k1, k2 = 2.0 / params["alpha1"] ** 2, 2.0 / params["alpha2"] ** 2
        return (jnp.clip(k1, vmf.KAPPA_MIN, vmf.KAPPA_MAX),
                jnp.clip(k2, vmf.KAPPA_MIN, vmf.KAPPA_MAX))

    def bottom_reflectance(params, eta, cos_b):
        n_rel = params[index_name] / eta
        if kind == "conductor":
            return CONDUCTOR_FRESNEL_METHODS["exact"](cos_b, n_rel, params[extinction_name] / eta)
        return fresnel_dielectric_Walter2007(cos_b, n_rel)

    def setup(params, wi, wo, opts):
        """The pieces every component shares, with the masking G1 evaluated in two batched
        calls (κ1 at wi, t_i, t_o, wo; κ2 at t_i, t_o): one quadrature each when exact."""
        k1, k2 = concentrations(params)
        eta = params["eta"]
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        G1 = vmf.MASKING[opts["masking"]]
        si, so = _Side(wi, eta, up), _Side(wo, eta, up)
        g1 = G1(jnp.stack([wi, si.t, so.t, wo], axis=-2), k1[..., None])
        g2 = G1(jnp.stack([si.t, so.t], axis=-2), k2[..., None])
        masks = {"top": [g1[..., j] for j in range(4)], "bottom": [g2[..., 0], g2[..., 1]]}
        return k1, k2, eta, up, G1, si, so, masks

    def surface(params, wi, wo, opts, shared):
        """Walter eq. 20 with the vMF NDF of the top (eqs 1-2, 6, 8, 9)."""
        k1, _, eta, up, _, si, so, masks = shared
        g_wi, _, _, g_wo = masks["top"]
        h = _half_vector(wi, wo, up)
        F = fresnel_dielectric_Walter2007(dot(wi, h), eta)
        f = F * g_wi * g_wo * vmf.D(h, k1) / (4.0 * si.c * so.c)
        return jnp.where(up, f, 0.0)

    def order_weight(params, shared, order):
        """E_k: the remaining terms of section 5.1 as energy factors, with eq. 27 per round trip."""
        _, _, eta, _, _, si, so, masks = shared
        g_wi, g_ti, g_to, g_wo = masks["top"]
        b_ti, b_to = masks["bottom"]
        ok = si.ok & so.ok
        hb = _half_vector(si.t, so.t, ok)  # the bottom's (inside) half vector
        cos_b = jnp.clip(dot(si.t, hb), 0.0, 1.0)
        R_bottom = bottom_reflectance(params, eta, cos_b) * b_ti * b_to
        R_top_inside = fresnel_dielectric_Walter2007(cos_b, 1.0 / eta) * g_ti * g_to
        A = beer_lambert(params["tau"], si.ct, so.ct)  # eq. 27
        crossing = si.T * so.T * g_wi * g_ti * g_to * g_wo
        E = crossing * (R_bottom * A) ** order * R_top_inside ** (order - 1)
        return jnp.where(ok, E, 0.0)

    def subsurface(params, wi, wo, shared, order):
        k1, k2, eta, up, G1, si, so, _ = shared
        E = order_weight(params, shared, order)
        h = _half_vector(wi, wo, up)
        # The tree from the incidence the virtual half vector sees, cos θd = wi·h = wo·h:
        # symmetric in (wi, wo), and cos θi on the specular path (the paper's evaluation).
        sd = _Incidence(jnp.clip(dot(wi, h), 1e-6, 1.0), eta)
        km = _kappa_of_nu(_lobe_nu(sd, eta, k1, k2, order))
        gm = G1(jnp.stack([wi, wo], axis=-2), km[..., None])
        f = E * vmf.D(h, km) * gm[..., 0] * gm[..., 1] / (4.0 * si.c * so.c)
        return jnp.where(up & si.ok & so.ok & sd.ok, f, 0.0)

    def compensation_of(params, opts):
        """(D, g) at the table's incidence nodes (..., T) for the parameters as given (their
        own shape, before any broadcast against directions: a scalar set reads the table once,
        not per row) (thin_layer_compensation): the missing light D less the weights of the
        orders 2..K the model adds itself, scaled by the absorption of four crossings, and the
        scale g of the paper's f where it returns more light than the stack."""
        ct = compensation_table
        lead = jnp.broadcast_shapes(*(jnp.shape(v) for v in params.values()))
        params = {k: jnp.broadcast_to(jnp.asarray(v), lead) for k, v in params.items()}
        k1, k2 = concentrations(params)
        eta = params["eta"]
        if kind == "conductor":
            b = ct.rbar_conductor(params[index_name] / eta, params[extinction_name] / eta)
        else:
            b = jnp.log(params[index_name] / eta)
        D, g = ct.nodes_Dg(kind, k1, k2, eta, b)
        mu = jnp.asarray(ct.mu_nodes(), D.dtype)
        # cos θt of the nodes, kept from 0 (and its gradient finite) past the critical angle
        cos_t = jnp.sqrt(jnp.clip(1.0 - (1.0 - mu * mu) / (eta[..., None] ** 2), 0.0025, 1.0))
        K = int(opts["bounces"])
        if K > 1:
            wn = jnp.stack([jnp.sqrt((1.0 - mu) * (1.0 + mu)), jnp.zeros_like(mu), mu], -1)
            pn = {k: v[..., None] for k, v in params.items()}
            pn, wn, wm = _broadcast(pn, wn, wn * jnp.asarray([-1.0, -1.0, 1.0], wn.dtype))
            shared = setup(pn, wn, wm, opts)
            D = jnp.maximum(D - sum(order_weight(pn, shared, k) for k in range(2, K + 1)), 0.0)
        return D * jnp.exp(-2.0 * params["tau"][..., None] / cos_t), g

    def compensation_albedo(params, mu, **opts):
        """(D(μ), D̄, g(μ)) of the compensation at cos θ = ``mu``: the added lobe's albedo, the
        normalization of f_c = D(μi) D(μo) / (π D̄) · (azimuthal shape), and the scale of the
        paper's f, g(μi) g(μo) (what the compensation table kind bakes)."""
        opts = {**DEFAULT_OPTIONS, **opts}
        Dn, gn = compensation_of(params, opts)
        lead = jnp.broadcast_shapes(jnp.shape(mu), Dn.shape[:-1])
        mu = jnp.broadcast_to(mu, lead)
        return (compensation_table.at_mu(Dn, mu),
                jnp.broadcast_to(compensation_table.average(Dn), lead),
                compensation_table.at_mu(gn, mu))

    def paper(params, wi, wo, opts, shared, with_surface, orders):
        total = surface(params, wi, wo, opts, shared) if with_surface else 0.0
        for k in orders:
            total = total + subsurface(params, wi, wo, shared, k)
        return total

    def eval(params, wi, wo, **opts):
        opts = {**DEFAULT_OPTIONS, **opts}
        with_surface, orders, with_table = _included(opts)
        given = params
        params, wi, wo = _broadcast(params, wi, wo)
        shared = setup(params, wi, wo, opts)
        total = paper(params, wi, wo, opts, shared, with_surface, orders)
        if with_table:
            up = shared[3]
            Dn, gn = compensation_of(given, opts)
            ci, co = jnp.where(up, wi[..., 2], 1.0), jnp.where(up, wo[..., 2], 1.0)
            e_z = jnp.asarray([0.0, 0.0, 1.0], wi.dtype)
            f_c = compensation_table.lobe(Dn, jnp.where(up[..., None], wi, e_z),
                                          jnp.where(up[..., None], wo, e_z))
            g = compensation_table.at_mu(gn, ci) * compensation_table.at_mu(gn, co)
            total = (f_c if opts["component"] == "compensation" else g * total + f_c)
            total = jnp.where(up, total, 0.0)
        return jnp.zeros(wi.shape[:-1], wi.dtype) + total

    def lobes(params, wi, opts):
        """Per included lobe: (κ over the half vector, estimated weight) from wi alone (the
        weights on the specular path: F for the surface, E_k for order k; the compensation's
        cosine lobe, κ None, its albedo D(μi))."""
        opts = {**DEFAULT_OPTIONS, **opts}
        with_surface, orders, with_table = _included(opts)
        given = params
        params, wi, _ = _broadcast(params, wi, wi)
        wm = wi * jnp.asarray([-1.0, -1.0, 1.0], wi.dtype)  # the mirror direction
        shared = setup(params, wi, wm, opts)
        k1, k2, eta, _, _, si, _, _ = shared
        out = []
        if with_surface:
            out.append((k1, fresnel_dielectric_Walter2007(si.c, eta)))
        for k in orders:
            out.append((_kappa_of_nu(_lobe_nu(si, eta, k1, k2, k)),
                        order_weight(params, shared, k)))
        if with_table:
            out.append((None, compensation_table.at_mu(compensation_of(given, opts)[0], si.c)))
        total = sum(w for _, w in out)
        n = len(out)
        probs = [(1.0 - n * _P_FLOOR) * safe_div(w, total, 1.0 / n) + _P_FLOOR for _, w in out]
        return [(kappa, p) for (kappa, _), p in zip(out, probs)]

    def pdf(params, wi, wo, **opts):
        """Σ_lobes P_j D(h; κ_j) cos θh / (4 |wo·h|) (+ P_c cos θo / π for the compensation's
        cosine lobe): the mixture ``sample`` draws from."""
        return mixture_pdf(lobes(params, wi, opts), wi, wo)

    def mixture_pdf(ls, wi, wo):
        """:func:`pdf` of the lobes ``ls`` (:func:`lobes` at wi), which ``sample`` has made."""
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        h = _half_vector(wi, wo, ok)
        jac = safe_div(1.0, 4.0 * jnp.abs(dot(wo, h)))
        total = 0.0
        for kappa, p in ls:
            if kappa is None:
                total = total + p * jnp.maximum(wo[..., 2], 0.0) / jnp.pi
            else:
                total = total + p * vmf.pdf_m(h, kappa) * jac
        return jnp.where(ok, total, 0.0)

    def sample(params, wi, u, **opts):
        """Pick a lobe by its estimated weight (u[2]), sample its NDF or ENDF once (section 5.4)
        and reflect wi about the sampled normal (the compensation: a cosine-distributed
        direction); weight = f|cos θo| / pdf of the mixture."""
        ls = lobes(params, wi, opts)
        cum = jnp.zeros_like(wi[..., 2])
        m = jnp.zeros_like(wi)
        cosine = jnp.zeros(wi.shape[:-1], bool)
        for j, (kappa, p) in enumerate(ls):
            lo = cum
            cum = cum + p
            chosen = (u[..., 2] >= lo) & ((u[..., 2] < cum) | (j == len(ls) - 1))
            if kappa is None:
                cosine = chosen
                continue
            mj = vmf.sample_m(u[..., 0], u[..., 1], kappa)
            m = jnp.where(chosen[..., None], mj, m)
        r, phi = jnp.sqrt(u[..., 0]), 2.0 * jnp.pi * u[..., 1]
        wc = jnp.stack([r * jnp.cos(phi), r * jnp.sin(phi),
                        jnp.sqrt(jnp.maximum(1.0 - u[..., 0], 0.0))], -1)
        wo = jnp.where(cosine[..., None], wc, reflect(wi, m))
        p = mixture_pdf(ls, wi, wo)
        f = eval(params, wi, wo, **opts)
        return sample_result(wo, f, p, (wi[..., 2] > 0) & (wo[..., 2] > 0))

    def vmf_roughness(params, i, masking):
        """Boundary i's vMF NDF as the simulator's keys: κ_i, or α_i (κ = 2/α², the same
        mapping in the scene), with the masking option (exact: eq. 7, approx: eq. 8)."""
        key = "kappa" if roughness == "kappa" else "alpha"
        return {"distribution": "vmf", key: float(params[f"{key}{i}"]), "masking": masking}

    def scene_of(params, options):
        """The layer of index η (relative to the outside, index 1) with optical depth τ
        (eq. 27: thickness 1, σa = τ) between the vMF top (κ1) and the vMF bottom (κ2): a
        conductor substrate (n2, k2), or a dielectric substrate of index eta2, both relative to
        vacuum as in the scene (an eta2 equal to η is no boundary: the stack ends on a medium
        below of that index); :func:`scene_effects`."""
        masking = {**DEFAULT_OPTIONS, **options}["masking"]
        eta = float(params["eta"])
        items = (interface(OUTSIDE["index"], eta, **vmf_roughness(params, 1, masking))
                 + [absorbing_slab(eta, params["tau"])])
        n2 = float(params[index_name])
        if kind == "conductor":
            bottom_part = {"substrate": {"type": "conductor", "n": n2,
                                         "k": float(params[extinction_name]),
                                         **vmf_roughness(params, 2, masking)}}
        elif n2 == eta:
            bottom_part = {"below": {"index": n2}}
        else:
            bottom_part = {"substrate": {"type": "dielectric", "index": n2,
                                         **vmf_roughness(params, 2, masking)}}
        return {"outside": dict(OUTSIDE), "stack": items, **bottom_part,
                "effects": scene_effects(options)}

    r_note = "" if roughness == "kappa" else ", widths α with κ = 2/α²"
    model = Model(
        name=canonical_name(bottom.name, roughness),
        summary=(f"extended-NDF thin layer (Guo et al. 2015): rough vMF top over a rough "
                 f"{kind} bottom, surface + subsurface orders by joint spherical warping{r_note}"),
        parameters=parameters,
        options=OPTIONS,
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=Capabilities(),
        scene_of=scene_of,
        reference=("Guo, Qian, Pan 2015: eqs 5-6 (vMF NDF), 7-8 (masking), 9 (Fresnel), 12-13 "
                   "(warping), 18, 21 (joint warping), 19 (ENDF), 25-26 (components, NDF tree), "
                   "27 (absorption), section 5.4 (sampling); Walter 2007 eq. 20 (surface); "
                   "fitlab's energy compensation (Kulla & Conty 2017's form)"),
    )
    _COMPENSATION_ALBEDO[model.name] = compensation_albedo
    return model


#: model name -> its compensation_albedo(params, mu, **options) (filled as models are built)
_COMPENSATION_ALBEDO: dict = {}


def compensation_albedo(model: Model):
    """``fn(params, mu, **options) -> (D(μ), D̄, g(μ))`` of a thin_layer model's compensation
    (ValueError for any other model)."""
    try:
        return _COMPENSATION_ALBEDO[model.name]
    except KeyError:
        raise ValueError(f"{model.name} has no thin-layer energy compensation (a thin_layer(...) "
                         f"model has)") from None


def canonical_name(bottom_name: str, roughness: str = "kappa") -> str:
    return f"{NAME}({bottom_name})" if roughness == "kappa" else \
        f"{NAME}({bottom_name},roughness={roughness})"


def from_call(call, get_model) -> Model:
    """Build from the parsed name ``thin_layer(BOTTOM[,roughness=kappa|alpha])``."""
    bottom, kwargs = call_arguments(
        call, f"{NAME}(rough_conductor) (bottom: rough_conductor or rough_dielectric)",
        {"roughness": "roughness=kappa|alpha"})
    return _cached(get_model(bottom), kwargs.get("roughness", "kappa"))


@functools.lru_cache(maxsize=None)
def _cached(bottom: Model, roughness: str) -> Model:
    return make_thin_layer(bottom, roughness)


def exit_concentration(cos_theta, eta, kappa1, kappa2, order: int = 1):
    """κ̂ of subsurface order ``order``'s lobe over outgoing directions for incidence cos θ: the
    joint warping of eq. 18 through the NDF tree of eq. 26 (the ENDF's κ_m = 4 cos θ κ̂, eq. 19).
    What a pre-filtered environment map is read with (section 5.5)."""
    side = _Incidence(jnp.asarray(cos_theta), eta)
    k1 = jnp.clip(kappa1, vmf.KAPPA_MIN, vmf.KAPPA_MAX)
    k2 = jnp.clip(kappa2, vmf.KAPPA_MIN, vmf.KAPPA_MAX)
    return _kappa_of_nu(4.0 * side.c * _lobe_nu(side, eta, k1, k2, order))
