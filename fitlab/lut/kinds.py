"""The table kinds: the evaluator behind each (the direct evaluation the accuracy is measured
against), and the registry :data:`KINDS`, whose entries carry what a kind needs from a model's or
fit's parameters (``prepare``) and its table maker (``make``). :func:`make_spec` dispatches
through it; nothing here compares a kind's name.
"""

from __future__ import annotations

import functools
import time
from typing import Callable, NamedTuple

import numpy as np

from fitlab._jax import jnp
from fitlab.registry import Registry
import fitlab.api
from fitlab.api import eval_bsdf
from fitlab.models import get_model
from fitlab.fresnel import (
    CONDUCTOR_FRESNEL_METHODS, CONDUCTOR_PRESETS, fresnel_dielectric_Walter2007,
)
from fitlab.lut.albedo import ALBEDO_DISTRIBUTIONS, QUAD_ORDERS, albedo_with_error, average_over_mu
from fitlab.lut.axes import (
    MU_MIN, Axis, Spec, Table, alpha_axis, lookup, make_axis, mu_axis,
)
from fitlab.lut.baking import REL_FLOOR, bake, error_stats, relative_error
from fitlab.microfacet import DISTRIBUTIONS, get_distribution
from fitlab.numerics import ALPHA_MIN

#: The distribution a table uses when option ``distribution`` is not given.
DEFAULT_DISTRIBUTION = "ggx"
#: Default range of the albedo_dielectric table's η axis.
ETA_RANGE = (1.05, 3.0)


# --------------------------------------------------------------------------------------------
# Table kinds: the evaluator behind each
# --------------------------------------------------------------------------------------------


def spec_D(distribution="ggx", size=(512, 512), mappings=("u8", "log"),
           alpha_range=(ALPHA_MIN, 1.0)):
    dist = get_distribution(distribution)
    axes = (make_axis("cos_theta_h", 0.0, 1.0, size[0], mappings[0],
                  "cos θh = n·h of the microfacet normal (half vector)"),
            alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        c = np.clip(coords[:, 0], 0.0, 1.0)
        a = coords[:, 1]
        m = np.stack([np.sqrt((1.0 - c) * (1.0 + c)), np.zeros_like(c), c], axis=-1)
        D = np.asarray(dist.D(jnp.asarray(m), jnp.asarray(a)))
        return (np.pi * a * a * D)[:, None], None

    return Spec("D", ("pi_alpha2_D",), axes, evaluate,
                f"π α² D(cos θh; α) of the {distribution} distribution ({dist.reference}); "
                "D in 1/sr = value / (π α²)",
                {"name": None, "options": {"distribution": distribution}}, {},
                "exact evaluation at the sample points (float64)")


def _conductor_channels(params):
    out = {}
    for ch, p in params.items():
        missing = [k for k in ("n", "k") if k not in p]
        if missing:
            raise ValueError(f"a conductor Fresnel table needs n and k; channel {ch} lacks "
                             f"{', '.join(missing)}")
        out[ch] = (float(p["n"]), float(p["k"]))
    return out


def spec_fresnel(params, size=128, mapping="linear", fresnel="exact"):
    """``params``: {channel: {"n": .., "k": ..}} (conductor) or {channel: {"eta": ..}}
    (dielectric, η = n_inside / n_outside)."""
    axes = (make_axis("cos_theta", 0.0, 1.0, size, mapping,
                  "cos θ between the direction and the (micro)surface normal"),)
    if not params:
        raise ValueError("a Fresnel table needs a material: conductor n and k (or a preset) or "
                         "a dielectric eta")
    if all("eta" in p for p in params.values()):
        etas = {ch: float(p["eta"]) for ch, p in params.items()}
        for ch, e in etas.items():
            if not (np.isfinite(e) and e > 0):
                raise ValueError(f"eta must be a positive number, got {e!r} (channel {ch})")
        single = list(etas) == ["Y"]
        channels = tuple(f"{'' if single else ch + '.'}F_{side}" for ch in etas
                         for side in ("outside", "inside"))

        def evaluate(coords):
            c = jnp.asarray(np.clip(coords[:, 0], 0.0, 1.0))
            cols = []
            for e in etas.values():
                cols.append(np.asarray(fresnel_dielectric_Walter2007(c, jnp.full_like(c, e))))
                cols.append(np.asarray(fresnel_dielectric_Walter2007(c, jnp.full_like(c, 1.0 / e))))
            return np.stack(cols, axis=-1), None

        quantity = ("unpolarized dielectric Fresnel reflectance F(cos θ) (Walter eq. 22) for "
                    "incidence from outside (relative index η) and from inside (1/η, total "
                    "internal reflection = 1)")
        return Spec("fresnel", channels, axes, evaluate, quantity,
                    {"name": None, "options": {}}, {ch: {"eta": e} for ch, e in etas.items()},
                    "exact evaluation at the sample points (float64)")
    nk = _conductor_channels(params)
    method = CONDUCTOR_FRESNEL_METHODS[fresnel]

    def evaluate(coords):
        c = jnp.asarray(np.clip(coords[:, 0], 0.0, 1.0))
        cols = [np.asarray(method(c, jnp.full_like(c, n), jnp.full_like(c, k)))
                for n, k in nk.values()]
        return np.stack(cols, axis=-1), None

    return Spec("fresnel", tuple(nk), axes, evaluate,
                f"conductor Fresnel reflectance F(cos θ), method {fresnel!r} "
                "(exact: unpolarized average of Rs and Rp for complex index n + ik)",
                {"name": None, "options": {"fresnel": fresnel}},
                {ch: {"n": n, "k": k} for ch, (n, k) in nk.items()},
                "exact evaluation at the sample points (float64)")


def _quad_note(orders):
    return (f"quadrature over microfacet normals in the sampling's coordinates (Walter eqs 28/35, "
            f"weight eq. 41): Gauss-Legendre panels with smoothed ends in theta_m (as tan t = "
            f"tan theta_m / alpha) and phi_m, split at the analytic breakpoints and graded "
            f"towards the horizons, {2 * orders['n_u']} nodes per theta_m panel and "
            f"{2 * orders['n_phi']} per phi_m panel; averages over mu by Gauss-Legendre with "
            f"{2 * orders['n_mu']} nodes; error estimate = |Q(n) - Q(2n)| at the orders n in "
            f"accuracy.quadrature.orders")


def _quadrature_spec(kind, channels, axes, evaluate, quantity, model, distribution, orders,
                     n_check):
    """The Spec of a table integrated by :mod:`fitlab.lut.albedo` (``model``: the registry model
    whose albedo the table holds)."""
    return Spec(kind, channels, axes, evaluate, quantity,
                {"name": model, "options": {"distribution": distribution}}, {},
                _quad_note(orders), n_check=n_check, orders=orders)


def spec_albedo_conductor(distribution="ggx", size=(32, 32), mappings=("linear", "linear"),
                          alpha_range=(ALPHA_MIN, 1.0), orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    axes = (mu_axis(size[0], mappings[0]), alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        E, dE = albedo_with_error(coords[:, 0], coords[:, 1], None, distribution, "conductor",
                                  orders)
        Ea, dEa = average_over_mu(coords[:, 1], None, distribution, "conductor", orders)
        return np.concatenate([E, Ea], axis=1), np.concatenate([dE, dEa], axis=1)

    return _quadrature_spec(
        "albedo_conductor", ("E", "E_avg"), axes, evaluate,
        f"directional albedo E(μ, α) = ∫ f cos θo dωo of the {distribution} microfacet BRDF with "
        "F = 1 and separable Smith G (Walter eqs 20, 23), and E_avg(α) = 2 ∫ E(μ) μ dμ (constant "
        "along μ); energy compensation as in Kulla & Conty 2017",
        "rough_conductor", distribution, orders, n_check=128)


def spec_dfg(distribution="ggx", size=(64, 64), mappings=("linear", "linear"),
             alpha_range=(ALPHA_MIN, 1.0), orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    axes = (mu_axis(size[0], mappings[0]), alpha_axis(size[1], mappings[1], alpha_range))

    def evaluate(coords):
        return albedo_with_error(coords[:, 0], coords[:, 1], None, distribution, "dfg", orders)

    return _quadrature_spec(
        "dfg", ("scale", "bias"), axes, evaluate,
        f"split-sum DFG terms of the {distribution} microfacet BRDF (separable Smith G): "
        "∫ f cos θo dωo = F0 · scale + bias under Schlick's Fresnel "
        "F = F0 + (1 - F0)(1 - v·h)^5 (Karis 2013); scale + bias = E with F = 1",
        "rough_conductor", distribution, orders, n_check=256)


def spec_albedo_dielectric(distribution="ggx", size=(32, 32, 16),
                           mappings=("linear", "linear", "linear"), alpha_range=(ALPHA_MIN, 1.0),
                           eta_range=ETA_RANGE, orders=None):
    orders = {**QUAD_ORDERS, **(orders or {})}
    lo, hi = eta_range
    if lo < 1.0 + 1e-3 or hi > 5.0:
        raise ValueError(f"axis eta: the range must lie within [1.001, 5] (incidence from inside "
                         f"covers 1/eta), got [{lo:g}, {hi:g}]")
    axes = (mu_axis(size[0], mappings[0]), alpha_axis(size[1], mappings[1], alpha_range),
            make_axis("eta", lo, hi, size[2], mappings[2],
                      "relative index η = n_inside / n_outside (inside = -z side)"))

    def evaluate(coords):
        mu, a, e = coords[:, 0], coords[:, 1], coords[:, 2]
        out, err = albedo_with_error(mu, a, e, distribution, "dielectric", orders)
        inn, ierr = albedo_with_error(mu, a, 1.0 / e, distribution, "dielectric", orders)
        avg_o, davg_o = average_over_mu(a, e, distribution, "dielectric", orders)
        avg_i, davg_i = average_over_mu(a, 1.0 / e, distribution, "dielectric", orders)
        return (np.concatenate([out, inn, avg_o, avg_i], axis=1),
                np.concatenate([err, ierr, davg_o, davg_i], axis=1))

    channels = ("R_outside", "T_outside", "R_inside", "T_inside",
                "Ravg_outside", "Tavg_outside", "Ravg_inside", "Tavg_inside")
    return _quadrature_spec(
        "albedo_dielectric", channels, axes, evaluate,
        f"rough dielectric ({distribution}, separable Smith G, Walter eqs 20-22) directional "
        "albedos: R = ∫ f_r cos θo dωo, T = ∫ f_t |cos θo| dωo (BTDF for radiance, eq. 21) for "
        "incidence from outside (relative index η) and from inside (1/η); *avg = 2 ∫ (.)(μ) μ "
        "dμ, constant along μ",
        "rough_dielectric", distribution, orders, n_check=48)


#: What ``--phi-d auto`` asks of a model table's parameterization error (lookup at the
#: coordinates of random direction pairs vs the model there): RMS relative error at most
#: ``rms_rel`` and max relative error at most ``max_rel``. A 2D (θh, θd) table that misses
#: either is replaced by the table with a φd axis (unless that one measures worse).
PHI_D_TARGET = {"rms_rel": 0.01, "max_rel": 0.05}
#: φd samples of the 3D candidate when the size gives none.
PHI_D_SIZE = 16
#: Name of the model table's optional third axis (Rusinkiewicz's difference azimuth).
PHI_D = "phi_d"
#: Largest number of direction pairs one model evaluation is given (memory of a 3D bake).
MODEL_CHUNK = 1 << 16


def _cos_sin_phi_d(phi_d):
    """cos φd, sin φd of φd in degrees, exact at φd = 90° (cos 0, sin 1)."""
    r = np.radians(90.0 - np.asarray(phi_d, float))
    return np.sin(r), np.cos(r)


def halfdiff_directions(cos_theta_h, cos_theta_d, phi_d=90.0):
    """Directions of Rusinkiewicz's (θh, θd, φd) at φh = 0 (φd in degrees):
    h = (sin θh, 0, cos θh); the difference vector d = (sin θd cos φd, sin θd sin φd, cos θd) in
    h's frame (x axis R_y(θh) x, y axis y); wi = R_y(θh) d, wo = reflect(wi, h) = 2 (wi·h) h - wi:

        wi = (sin θh cos θd + cos θh sin θd cos φd,  sin θd sin φd,
              cos θh cos θd - sin θh sin θd cos φd)
        wo = (sin θh cos θd - cos θh sin θd cos φd, -sin θd sin φd,
              cos θh cos θd + sin θh sin θd cos φd)

    At φd = 90° (the default, the 2D table's slice) wi = (sin θh cos θd, sin θd, cos θh cos θd).
    Cosines are clamped to [MU_MIN, 1]: at 0 both directions lie in the horizon, where a model
    returns 0 although its limit (the table's first texel) is finite. Likewise |cos φd| is
    clamped to where both directions keep z >= MU_MIN: a (θh, θd, φd) whose wi or wo would lie
    below the horizon holds the value at the horizon (the same φd side), so interpolation next to
    the horizon stays continuous; no direction pair of the upper hemisphere maps there."""
    ch = np.clip(np.asarray(cos_theta_h, float), MU_MIN, 1.0)
    cd = np.clip(np.asarray(cos_theta_d, float), MU_MIN, 1.0)
    sh, sd = np.sqrt((1 - ch) * (1 + ch)), np.sqrt((1 - cd) * (1 + cd))
    cp, sp = _cos_sin_phi_d(phi_d)
    # both z = cos θh cos θd ∓ sin θh sin θd cos φd >= MU_MIN
    ss = sh * sd
    bound = np.clip((ch * cd - MU_MIN) / np.where(ss > 0, ss, 1.0), 0.0, 1.0)
    clamped = (ss > 0) & (np.abs(cp) > bound)
    cp = np.where(clamped, np.copysign(bound, cp), cp)
    sp = np.where(clamped, np.sqrt((1 - bound) * (1 + bound)), sp)  # φd in [0°, 180°]: sin >= 0
    wi = np.stack([sh * cd + ch * sd * cp, sd * sp, ch * cd - sh * sd * cp], axis=-1)
    wo = np.stack([sh * cd - ch * sd * cp, -sd * sp, ch * cd + sh * sd * cp], axis=-1)
    return wi, wo


def halfdiff_coordinates(wi, wo):
    """(cos θh, cos θd) of direction pairs: h = normalize(wi + wo), cos θh = h.z, cos θd = wi·h."""
    h = np.asarray(wi, float) + np.asarray(wo, float)
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    return np.clip(h[..., 2], 0.0, 1.0), np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)


def phi_d_of(wi, wo, reciprocal=True):
    """Rusinkiewicz's φd (degrees) of direction pairs, folded as a model table reads it: the
    azimuth of wi about h = normalize(wi + wo), from t = R_z(φh) R_y(θh) x, is taken as |φd|
    (f(φd) = f(-φd): mirror symmetry of an isotropic BRDF) in [0°, 180°] and, if ``reciprocal``,
    as min(φd, 180° - φd) in [0°, 90°] (f(φd) = f(φd + 180°): swapping wi and wo). With
    s = sin θh: s·(wi·t) = h.z (wi.x h.x + wi.y h.y) - s² wi.z and s·(wi·b) = h.x wi.y - h.y wi.x
    (b = R_z(φh) y); at h = n (s = 0) φd is undefined and an isotropic f does not depend on it:
    90°."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    s2 = h[..., 0] ** 2 + h[..., 1] ** 2
    dx = h[..., 2] * (wi[..., 0] * h[..., 0] + wi[..., 1] * h[..., 1]) - s2 * wi[..., 2]
    dy = h[..., 0] * wi[..., 1] - h[..., 1] * wi[..., 0]
    both = (np.abs(dx) + np.abs(dy)) > 0
    phi = np.where(both, np.degrees(np.arctan2(np.abs(dy), dx)), 90.0)
    return np.minimum(phi, 180.0 - phi) if reciprocal else phi


def phi_d_folds_by_reciprocity(axis: Axis) -> bool:
    """A φd axis over [0°, 90°] is read with the reciprocity fold, one over [0°, 180°] without."""
    return axis.hi <= 90.0


def model_coordinates(axes, wi, wo) -> np.ndarray:
    """Axis coordinates (P, 2 or 3) of direction pairs in a model table with ``axes``, exactly
    as the generated shader computes them: (cos θh, cos θd) and, with a third axis, folded φd."""
    ch, cd = halfdiff_coordinates(wi, wo)
    cols = [ch, cd]
    if len(axes) == 3:
        cols.append(phi_d_of(wi, wo, phi_d_folds_by_reciprocity(axes[2])))
    return np.stack(cols, axis=-1)


def _eval_in_chunks(name, p, wi, wo, opts):
    """The model at many direction pairs, MODEL_CHUNK at a time (the last chunk padded, so one
    compiled shape serves a whole bake)."""
    n = len(wi)
    if n <= MODEL_CHUNK:
        return np.asarray(eval_bsdf(name, p, wi, wo, opts))
    pad = -n % MODEL_CHUNK
    wi = np.concatenate([wi, np.repeat(wi[:1], pad, axis=0)])
    wo = np.concatenate([wo, np.repeat(wo[:1], pad, axis=0)])
    out = [np.asarray(eval_bsdf(name, p, wi[i:i + MODEL_CHUNK], wo[i:i + MODEL_CHUNK],
                                opts)) for i in range(0, len(wi), MODEL_CHUNK)]
    return np.concatenate(out)[:n]


def spec_model(model_name, params, options=None, size=(256, 256),
               mappings=("u8", "linear", "linear")):
    """``params``: {channel: {parameter: value}} of a registry model (every parameter given).
    Two sizes: the (cos θh, cos θd) table at φd = 90°; three: with a φd axis over [0°, 90°]
    (reciprocal model) or [0°, 180°] (otherwise)."""
    model = get_model(model_name)
    if not model.capabilities.isotropic:
        raise ValueError(f"model {model.name!r} is anisotropic: a (cos θh, cos θd) table "
                         "holds isotropic BRDFs only (it has no azimuth of the half vector, with "
                         "or without the φd axis); tabulate it as a Zemax file with fitlab "
                         "convert (Asymmetrical), or fit an isotropic model")
    if len(size) not in (2, 3):
        raise ValueError(f"a model table has 2 axes (cos_theta_h, cos_theta_d) or 3 (with "
                         f"phi_d); got {len(size)} sizes")
    opts = fitlab.api.resolve_options(model, options)
    clean = {}
    for ch, p in params.items():
        p = {k: float(v) for k, v in p.items() if k in model.parameter_names}
        fitlab.api.check_params(model, p)
        clean[ch] = p
    three = len(size) == 3
    reciprocal = model.capabilities.reciprocal
    axes = (make_axis("cos_theta_h", 0.0, 1.0, size[0], mappings[0],
                      "cos θh = n·h, h = normalize(wi + wo)"),
            make_axis("cos_theta_d", 0.0, 1.0, size[1], mappings[1],
                      "cos θd = wi·h (Rusinkiewicz's difference angle)"
                      + ("" if three else ", at φd = 90°")))
    if three:
        hi = 90.0 if reciprocal else 180.0
        axes += (make_axis(
            PHI_D, 0.0, hi, size[2], mappings[2],
            "φd in degrees, Rusinkiewicz's difference azimuth: the azimuth of wi about h from "
            "t = R_z(φh) R_y(θh) x, read as |φd| (mirror symmetry of an isotropic BRDF)"
            + (" and folded into [0°, 90°] by min(φd, 180° - φd) (reciprocity: f(φd) = "
               "f(φd + 180°))" if reciprocal else " in [0°, 180°] (the model does not declare "
               "reciprocity)")),)

    def evaluate(coords):
        phi = coords[:, 2] if three else 90.0
        wi, wo = halfdiff_directions(coords[:, 0], coords[:, 1], phi)
        cols = [_eval_in_chunks(model.name, p, wi, wo, opts) for p in clean.values()]
        return np.stack(cols, axis=-1), None

    if three:
        notes = ("3D (θh, θd, φd) table: exact for every isotropic BRDF up to interpolation; "
                 "φd of a direction pair is folded as the phi_d axis describes; "
                 "accuracy.parameterization gives the error over random direction pairs",)
    else:
        notes = ("2D (θh, θd) tables are exact for BRDFs that depend on θh and θd only; other "
                 "isotropic BRDFs (G and Oren–Nayar depend on φd) are represented at φd = 90°: "
                 "accuracy.parameterization gives the error this makes over random direction "
                 "pairs",)
    if model.capabilities.transmission:
        notes += ("the model also transmits; the table holds its reflection (wo.z > 0) only",)
    where = "(cos θh, cos θd, φd)" if three else "(cos θh, cos θd, φd = 90°)"
    return Spec("model", tuple(clean), axes, evaluate,
                f"BRDF f(wi, wo) in 1/sr (without the cosine) of {model.name} at {where}",
                {"name": model.name, "options": opts}, clean,
                "exact evaluation at the sample points (float64)", notes,
                checks=(("parameterization", parameterization_error),))


def _hemisphere(u):
    z = u[:, 0]
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z], -1)


def parameterization_error(table, spec, n, seed=1):
    """Table lookup at the coordinates of random upper-hemisphere direction pairs ((cos θh,
    cos θd) and, for a 3D table, folded φd: :func:`model_coordinates`) vs the model at those
    pairs (a 2D table includes the φd = 90° assumption), and whether it meets
    :data:`PHI_D_TARGET`.

    The relative-error floor is REL_FLOOR × the largest |f| over these pairs, not over the
    table: models that grow at grazing (Oren–Nayar's tan β, a microfacet lobe's 1/(4 cos θi
    cos θo) at θh = 0, θd → 90°) hold values up to 10⁷ at horizon texels no direction pair
    reaches, and a floor from those would hide every error."""
    rng = np.random.default_rng(seed)
    wi, wo = _hemisphere(rng.random((n, 2))), _hemisphere(rng.random((n, 2)))
    approx = lookup(table, model_coordinates(table.axes, wi, wo))
    name = spec.model["name"]
    ref = np.stack([_eval_in_chunks(name, p, wi, wo, spec.model["options"])
                    for p in spec.params.values()], -1)
    scale = np.abs(ref).max(axis=0)
    err = relative_error(approx, ref, scale)
    stats = error_stats(err)
    return {"points": n, "seed": seed, "reference": "the model at random direction pairs of the "
            "upper hemisphere (uniform in solid angle)",
            "floor": f"{REL_FLOOR:g} x the largest |f| over these pairs", **stats,
            "per_channel": {ch: error_stats(err[:, k]) for k, ch in enumerate(table.channels)},
            "target": dict(PHI_D_TARGET), "meets_target": meets_phi_d_target(stats)}


def meets_phi_d_target(stats) -> bool:
    return bool(stats["rms_rel"] <= PHI_D_TARGET["rms_rel"]
                and stats["max_rel"] <= PHI_D_TARGET["max_rel"])


#: Default range of the thin_layer table's κ1 and κ2 axes (the validation grid's: 1 to 1e6).
KAPPA_RANGE = (1.0, 1e6)
#: Points per call of the thin-layer lobe quadrature (each with ORDERS nodes of wo).
LOBE_CHUNK = 64


def _thin_layer_roughness(model):
    """(κ1, κ2) → the model's roughness parameters: κ (thin_layer(...)) or α = sqrt(2/κ)
    (thin_layer(...,roughness=alpha)); a model with neither has no thin-layer lobe."""
    names = set(model.parameter_names)
    if {"kappa1", "kappa2"} <= names:
        return lambda k1, k2: {"kappa1": k1, "kappa2": k2}
    if {"alpha1", "alpha2"} <= names:
        return lambda k1, k2: {"alpha1": jnp.sqrt(2.0 / k1), "alpha2": jnp.sqrt(2.0 / k2)}
    raise ValueError(f"a thin_layer table needs a thin_layer(...) model (two boundaries, kappa1 "
                     f"and kappa2 or alpha1 and alpha2); {model.name} has neither")


def _thin_layer_inputs(model, rough, params, kappa_range, size, mappings, kind):
    """(per-channel parameters without the roughnesses, checked; the (μ, κ1, κ2) axes) of a
    thin-layer table kind."""
    from fitlab.models.thin_layer import KAPPA_HI, KAPPA_LO

    lo, hi = kappa_range
    if lo < KAPPA_LO or hi > KAPPA_HI:
        raise ValueError(f"axes kappa1, kappa2: the range must lie within [{KAPPA_LO:g}, "
                         f"{KAPPA_HI:g}], got [{lo:g}, {hi:g}]")
    free = set(rough(1.0, 1.0))
    clean = {}
    for ch, p in params.items():
        p = {k: float(v) for k, v in p.items() if k in model.parameter_names and k not in free}
        fitlab.api.check_params(model, {**p, **{k: float(v) for k, v in
                                                rough(100.0, 100.0).items()}})
        clean[ch] = p
    if not clean:
        raise ValueError(f"a {kind} table needs the model's parameters (eta, tau and the "
                         "bottom's index) for at least one channel")
    axes = (mu_axis(size[0], mappings[0]),
            make_axis("kappa1", lo, hi, size[1], mappings[1],
                      "vMF concentration κ1 of the top boundary (κ ≈ 2/α²)"),
            make_axis("kappa2", lo, hi, size[2], mappings[2],
                      "vMF concentration κ2 of the bottom boundary (κ ≈ 2/α²)"))
    return clean, axes


def spec_thin_layer(model_name, params, options=None, size=(16, 16, 16),
                    mappings=("linear", "log", "log"), kappa_range=KAPPA_RANGE, orders=None):
    """The real-time form of the thin layer (Guo et al. 2015 section 5.5): over (μ = cos θi,
    κ1, κ2) for the fit's η, bottom and absorption, the subsurface lobe's mean direction
    (sin θ toward the mirror azimuth), log10 of its concentration κ̂ (moment-matched: A3(κ̂) =
    |mean resultant|, eq. 18) and its albedo E per channel (the remaining terms), integrated
    over outgoing directions by :mod:`fitlab.lut.lobe`. ``params`` {channel: parameters
    without the roughnesses}."""
    from fitlab.lut.lobe import ORDERS, lobe_moments, vmf_lobe_error
    from fitlab.models.thin_layer import exit_concentration

    model = get_model(model_name)
    rough = _thin_layer_roughness(model)
    opts = dict(fitlab.api.resolve_options(model, options))
    choices = {o.name: o.choices for o in model.options}
    if "subsurface" not in choices.get("component", ()):
        raise ValueError(f"a thin_layer table needs a model with subsurface orders; "
                         f"{model.name} has none")
    opts["component"] = "subsurface"
    orders = {**ORDERS, **(orders or {})}
    clean, axes = _thin_layer_inputs(model, rough, params, kappa_range, size, mappings,
                                     "thin_layer")
    etas = {p["eta"] for p in clean.values()}
    if len(etas) != 1:
        raise ValueError(f"a thin_layer table is made for one η (its lobe's direction and "
                         f"concentration are shared by the channels); the channels have "
                         f"{', '.join(f'{e:g}' for e in sorted(etas))}")
    eta = etas.pop()
    channels = ("sin_theta_mean", "log10_kappa") + tuple(f"E_{ch}" for ch in clean)
    const = [{k: jnp.asarray(v) for k, v in p.items()} for p in clean.values()]

    def f(pq, wi, wo):
        r = rough(pq["kappa1"], pq["kappa2"])
        return jnp.stack([model.eval({**c, **r}, wi, wo, **opts) for c in const], axis=-1)

    def geometry(coords):
        mu = np.clip(coords[:, 0], MU_MIN, 1.0)
        s = np.sqrt((1.0 - mu) * (1.0 + mu))
        wi = np.stack([s, np.zeros_like(s), mu], axis=-1)
        mirror = wi * np.array([-1.0, 1.0, 1.0])
        k0 = np.asarray(exit_concentration(jnp.asarray(mu), eta, jnp.asarray(coords[:, 1]),
                                           jnp.asarray(coords[:, 2])))
        return wi, mirror, k0

    def chunks(*arrays):
        """(rows, the arrays' rows padded to LOBE_CHUNK: one compiled shape) per chunk."""
        for start in range(0, len(arrays[0]), LOBE_CHUNK):
            parts = [a[start:start + LOBE_CHUNK] for a in arrays]
            pad = LOBE_CHUNK - len(parts[0])
            yield len(parts[0]), [np.concatenate([q, np.repeat(q[-1:], pad, 0)])
                                         for q in parts]

    def evaluate(coords):
        coords = np.asarray(coords, float)
        vals, errs = [], []
        for m, (part,) in chunks(coords):
            wi, mirror, k0 = geometry(part)
            kap = {"kappa1": part[:, 1], "kappa2": part[:, 2]}
            E, mean, k, (dE, dm, dk) = lobe_moments(f, wi, mirror, k0, kap, orders)
            vals.append(np.column_stack([-mean[:, 0], np.log10(k), E])[:m])
            errs.append(np.column_stack([dm, dk, dE])[:m])
        return np.concatenate(vals), np.concatenate(errs)

    def vmf_check(table, spec, n, seed=2):
        """The real-time form's own error: the model's subsurface lobe against its albedo times
        the vMF of the table's mean and κ̂, at random (μ, κ1, κ2) of the table's range."""
        rng = np.random.default_rng(seed)
        t = rng.random((n, len(table.axes)))
        coords = np.stack([a.to_x(t[:, j]) for j, a in enumerate(table.axes)], axis=-1)
        look = lookup(table, coords)
        errs = []
        for m, (part, v) in chunks(coords, look):
            wi, mirror, k0 = geometry(part)
            sn = np.clip(v[:, 0], -1.0, 1.0)
            mean = np.stack([-sn, np.zeros_like(sn), np.sqrt((1 - sn) * (1 + sn))], axis=-1)
            kap = {"kappa1": part[:, 1], "kappa2": part[:, 2]}
            errs.append(vmf_lobe_error(f, wi, mirror, k0, kap, v[:, 2:].sum(axis=1), mean,
                                       10.0 ** v[:, 1], orders)[:m])
        e = np.concatenate(errs)
        return {"points": n, "seed": seed,
                "measure": "sqrt(∫ (g - ĝ)² dω / ∫ g² dω), g = Σ_c f_c cos θo of the model's "
                "subsurface lobe, ĝ = (Σ_c E_c) vMF(ωo; mean, κ̂) from the table",
                "median": float(np.median(e)), "p90": float(np.quantile(e, 0.9)),
                "max": float(e.max())}

    return Spec("thin_layer", channels, axes, evaluate,
                f"real-time form of the subsurface lobe of {model.name} (Guo et al. 2015 "
                f"section 5.5) for η = {eta:g}: sin_theta_mean = sine of the lobe's mean "
                "direction's polar angle, positive toward the mirror azimuth (the mean lies in "
                "the plane of incidence); log10_kappa = log10 κ̂, the vMF concentration over "
                "outgoing directions with A3(κ̂) = |mean resultant| (eq. 18); E_<channel> = "
                "∫ f cos θo dωo, the lobe's albedo (the remaining terms). Integrals of the "
                "subsurface component of f cos θo over the upper hemisphere",
                {"name": model.name, "options": opts}, clean,
                f"quadrature over outgoing directions adapted to the tree's vMF (fitlab.lut.lobe:"
                f" {orders['n_u']} Gauss-Legendre nodes in the inverse-CDF coordinate × "
                f"{orders['n_phi']} midpoint nodes in azimuth); error estimate = the difference "
                "from 2/3 of those orders",
                ("a shader reads a pre-filtered environment map at the mean direction with a "
                 "vMF of κ̂ and multiplies by E (section 5.5); accuracy.vmf_lobe gives the error "
                 "of that single-vMF form against the model's lobe",),
                n_check=64, orders=orders, checks=(("vmf_lobe", vmf_check),))


#: Default range of the compensation table's κ axes: the range of the shipped table's nodes.
COMPENSATION_KAPPA_RANGE = (10.0, 1e4)


def spec_thin_layer_compensation(model_name, params, options=None, size=(16, 16, 16),
                                 mappings=("linear", "log", "log"),
                                 kappa_range=COMPENSATION_KAPPA_RANGE):
    """fitlab's energy compensation of the thin layer for shaders: over (μ = cos θ, κ1, κ2) for
    the fit's η, τ and bottom, D_<channel> = D(μ), the compensation lobe's albedo, and
    Dbar_<channel> = D̄ (constant along μ), so that f_c(ωi, ωo) = D(μi) D(μo) / (π D̄)
    (fitlab/models/thin_layer_compensation.py). ``params`` {channel: parameters without the
    roughnesses}."""
    from fitlab.models.thin_layer import compensation_albedo

    model = get_model(model_name)
    rough = _thin_layer_roughness(model)
    fn = compensation_albedo(model)
    opts = dict(fitlab.api.resolve_options(model, options))
    if opts.get("compensation") == "none":
        raise ValueError("a thin_layer_compensation table is the compensation's: drop "
                         "compensation=none")
    clean, axes = _thin_layer_inputs(model, rough, params, kappa_range, size, mappings,
                                     "thin_layer_compensation")
    channels = tuple(f"{q}_{ch}" for q in ("D", "Dbar", "g") for ch in clean)

    def evaluate(coords):
        coords = np.asarray(coords, float)
        mu = jnp.asarray(np.clip(coords[:, 0], MU_MIN, 1.0))
        r = rough(jnp.asarray(coords[:, 1]), jnp.asarray(coords[:, 2]))
        cols = [fn({**{k: jnp.asarray(v) for k, v in c.items()}, **r}, mu, **opts)
                for c in clean.values()]
        return np.column_stack([np.asarray(col[q]) for q in range(3) for col in cols]), None

    return Spec("thin_layer_compensation", channels, axes, evaluate,
                f"fitlab's energy compensation of {model.name} (not in Guo et al. 2015): "
                "D_<channel> = D(μ), the albedo of the lobe that carries the light the paper's "
                "model loses (tabulated from the simulator), Dbar_<channel> = D̄ = 2∫D(μ)μ dμ, "
                "g_<channel> = g(μ), the scale of the paper's f where it returns more light "
                "than the stack (f_paper · g(μi) g(μo)); "
                "f_c(ωi, ωo) = D(μi) D(μo) / (π D̄) · exp(b cos Δφ) / I0(b) in 1/sr (b = b0 "
                "sin θi sin θo, Δφ from the mirror azimuth; fitlab.models."
                "thin_layer_compensation.azimuthal): f = g(μi) g(μo) f_paper + f_c",
                {"name": model.name, "options": opts}, clean,
                "exact evaluation of the model's compensation at the sample points (float64)",
                ("f_c(wi, wo) = D(mu_i) D(mu_o) / (pi Dbar) * exp(b cos dphi) / I0(b): "
                 "reciprocal, albedo D(mu) exactly",))


# --------------------------------------------------------------------------------------------
# What a kind needs from a model's or fit's parameters
# --------------------------------------------------------------------------------------------


def _one_of(names):
    names = list(names)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def _distribution(kind, options, supported):
    """The distribution named by option ``distribution`` (default ggx), checked against the
    registry (fitlab.microfacet.DISTRIBUTIONS) and the distributions the kind supports."""
    name = options.get("distribution", DEFAULT_DISTRIBUTION)
    if name not in DISTRIBUTIONS:
        raise ValueError(f"option distribution={name!r} is unknown; use {_one_of(DISTRIBUTIONS)}")
    if name not in supported:
        raise ValueError(f"{kind} tables support the distributions {_one_of(supported)}, not "
                         f"{name!r} (its sampling has no closed-form inverse CDF here)")
    return name


def _prepare_distribution(kind, supported, model, options, params):
    """Distribution tables read option distribution only (a fit's other options and its
    parameters do not enter)."""
    return {"distribution": _distribution(kind, options, supported)}, {}


def _prepare_fresnel(model, options, params):
    """The Fresnel material of each channel: (n, k) or eta, under plain or sum-qualified names
    (``base.n`` of a composite model)."""
    out = {}
    for ch, p in params.items():
        def pick(name):
            hits = [v for k, v in p.items() if k == name or k.endswith("." + name)]
            return hits[0] if len(hits) == 1 else None

        n, k, eta = pick("n"), pick("k"), pick("eta")
        if n is not None and k is not None:
            out[ch] = {"n": n, "k": k}
        elif eta is not None:
            out[ch] = {"eta": eta}
        else:
            what = f"model {model!r}" if model else "the given parameters"
            raise ValueError(f"a fresnel table needs conductor n and k (or --preset) or a "
                             f"dielectric eta; {what} has {', '.join(p) or 'none'} "
                             f"(channel {ch})")
    return options, out


def _prepare_model(model, options, params):
    """A model table evaluates the model itself: every parameter (checked by spec_model)."""
    if not model:
        raise ValueError("a model table needs --from-fit FILE.json or --model NAME --param ...")
    return options, params


def conductor_preset(name: str) -> dict:
    """{R, G, B: {n, k}} of a CONDUCTOR_PRESETS entry (Elek 2010 appendix A)."""
    try:
        p = CONDUCTOR_PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(CONDUCTOR_PRESETS)}") \
            from None
    return {ch: {"n": p["n"][i], "k": p["k"][i]} for i, ch in enumerate("RGB")}


# --------------------------------------------------------------------------------------------
# Table makers: make(size, mappings, *, model, params, options, alpha_range, eta_range, orders)
# --------------------------------------------------------------------------------------------


def _make_D(size, mappings, *, options, alpha_range, **_):
    return spec_D(_distribution("D", options, D_DISTRIBUTIONS), size, mappings, alpha_range)


def _make_fresnel(size, mappings, *, params, options, **_):
    return spec_fresnel(params, size[0], mappings[0], options.get("fresnel", "exact"))


def _make_albedo_conductor(size, mappings, *, options, alpha_range, orders, **_):
    return spec_albedo_conductor(_distribution("albedo_conductor", options, ALBEDO_DISTRIBUTIONS),
                                 size, mappings, alpha_range, orders)


def _make_dfg(size, mappings, *, options, alpha_range, orders, **_):
    return spec_dfg(_distribution("dfg", options, ALBEDO_DISTRIBUTIONS), size, mappings,
                    alpha_range, orders)


def _make_albedo_dielectric(size, mappings, *, options, alpha_range, eta_range, orders, **_):
    return spec_albedo_dielectric(
        _distribution("albedo_dielectric", options, ALBEDO_DISTRIBUTIONS), size, mappings,
        alpha_range, eta_range, orders)


def _prepare_thin_layer(model, options, params):
    if not model:
        raise ValueError("a thin_layer table needs a thin_layer model: --from-fit FILE.json or "
                         "--model 'thin_layer(rough_conductor)' --param eta=... --param n2=...")
    return options, params


def _make_thin_layer(size, mappings, *, model, params, options, orders, kappa_range=None, **_):
    return spec_thin_layer(model, params, options, size, mappings,
                           kappa_range or KAPPA_RANGE, orders)


def _make_thin_layer_compensation(size, mappings, *, model, params, options, kappa_range=None,
                                  **_):
    return spec_thin_layer_compensation(model, params, options, size, mappings,
                                        kappa_range or COMPENSATION_KAPPA_RANGE)


def _make_model(size, mappings, *, model, params, options, **_):
    if model is None:
        raise ValueError("a model table needs a model (--model NAME --param ... or --from-fit)")
    return spec_model(model, params, options, size, mappings)


# --------------------------------------------------------------------------------------------
# Kinds registry and the one entry point
# --------------------------------------------------------------------------------------------


class Kind(NamedTuple):
    """A table kind: what it holds, its axes and their defaults, what it needs from a model's or
    fit's parameters and how it makes its :class:`Spec`."""

    name: str
    summary: str
    n_axes: int
    default_size: tuple
    default_mappings: tuple
    needs: str  # which parameters the table needs from a model / fit (for help texts)
    axis_names: tuple
    #: make(size, mappings, *, model, params, options, alpha_range, eta_range, orders,
    #: kappa_range) -> Spec
    make: Callable
    #: prepare(model name or None, options, {channel: params}) -> (options, params): the
    #: table's inputs from a model's or fit's (ValueError when they lack what the table needs)
    prepare: Callable
    #: the registry distributions the table supports (option distribution); () if it reads none
    distributions: tuple = ()
    #: preset(name) -> {channel: params}: named materials (``--preset``); None if the kind has none
    preset: Callable | None = None
    #: optional trailing axes, each (name, default size, default mapping): a table has n_axes
    #: to n_axes + len(extra_axes) axes (more sizes, e.g. --size 256x256x16)
    extra_axes: tuple = ()
    #: the accuracy entry (a Spec check returning rms_rel, max_rel, meets_target) by which
    #: :func:`bake_auto` decides whether a table needs its extra axes; None: no auto choice
    auto_check: str | None = None
    #: ``--preset`` names a layered model preset (fitlab.models.presets): the model and all
    #: three channels' parameters come from it
    model_presets: bool = False

    @property
    def all_axis_names(self) -> tuple:
        return tuple(self.axis_names) + tuple(e[0] for e in self.extra_axes)

    @property
    def axis_counts(self) -> tuple:
        """The numbers of axes a table of this kind may have."""
        return tuple(range(self.n_axes, self.n_axes + len(self.extra_axes) + 1))

    @property
    def all_default_mappings(self) -> tuple:
        return tuple(self.default_mappings) + tuple(e[2] for e in self.extra_axes)


#: Distributions of the D table: every one of the registry.
D_DISTRIBUTIONS = tuple(DISTRIBUTIONS)


def _distribution_kind(name, summary, n_axes, default_size, default_mappings, axis_names, make,
                       distributions):
    return Kind(name, summary, n_axes, default_size, default_mappings,
                "none (option distribution)", axis_names, make,
                functools.partial(_prepare_distribution, name, distributions), distributions)


KINDS: Registry[Kind] = Registry("table kind", {k.name: k for k in (
    _distribution_kind("D", "microfacet distribution π α² D(cos θh; α) (Elek 2010 section 3.1)",
                       2, (512, 512), ("u8", "log"), ("cos_theta_h", "alpha"), _make_D,
                       D_DISTRIBUTIONS),
    Kind("fresnel", "Fresnel reflectance F(cos θ) of one material per channel", 1, (128,),
         ("linear",), "conductor n, k (or --preset) or dielectric eta", ("cos_theta",),
         _make_fresnel, _prepare_fresnel, preset=conductor_preset),
    _distribution_kind("albedo_conductor", "E(μ, α) and E_avg(α) of a microfacet conductor with "
                       "F = 1 (energy compensation)", 2, (32, 32), ("linear", "linear"),
                       ("mu", "alpha"), _make_albedo_conductor, ALBEDO_DISTRIBUTIONS),
    _distribution_kind("albedo_dielectric", "R and T albedos of a rough dielectric over "
                       "(μ, α, η), from outside and inside, and their averages", 3, (32, 32, 16),
                       ("linear", "linear", "linear"), ("mu", "alpha", "eta"),
                       _make_albedo_dielectric, ALBEDO_DISTRIBUTIONS),
    _distribution_kind("dfg", "split-sum DFG scale and bias over (μ, α)", 2, (64, 64),
                       ("linear", "linear"), ("mu", "alpha"), _make_dfg, ALBEDO_DISTRIBUTIONS),
    Kind("model", "a model's or fit's BRDF over (cos θh, cos θd) at φd = 90°, or with a third "
         "size over (cos θh, cos θd, φd)", 2, (256, 256), ("u8", "linear"),
         "every parameter of the model", ("cos_theta_h", "cos_theta_d"), _make_model,
         _prepare_model, extra_axes=((PHI_D, PHI_D_SIZE, "linear"),),
         auto_check="parameterization", model_presets=True),
    Kind("thin_layer", "the thin layer's subsurface lobe for a pre-filtered environment map "
         "(Guo et al. 2015 section 5.5): mean direction, log10 κ̂ and albedo per channel over "
         "(μ, κ1, κ2)", 3, (16, 16, 16), ("linear", "log", "log"),
         "a thin_layer model's eta, tau and bottom index (κ1, κ2 are the axes)",
         ("mu", "kappa1", "kappa2"), _make_thin_layer, _prepare_thin_layer),
    Kind("thin_layer_compensation", "fitlab's energy compensation of the thin layer: the "
         "compensation lobe's albedo D(μ), its average D̄ and the paper's scale g(μ) per channel "
         "over (μ, κ1, κ2); f = g(μi) g(μo) f_paper + D(μi) D(μo) / (π D̄) · shape", 3, (16, 16, 16), ("linear", "log", "log"),
         "a thin_layer model's eta, tau and bottom index (κ1, κ2 are the axes)",
         ("mu", "kappa1", "kappa2"), _make_thin_layer_compensation, _prepare_thin_layer),
)})


def get_kind(name: str) -> Kind:
    return KINDS.get_entry(name)


def make_spec(kind: str, *, size=None, mappings=None, model=None, params=None, options=None,
              alpha_range=None, eta_range=None, orders=None, kappa_range=None) -> Spec:
    """The :class:`Spec` of a table kind from uniform arguments (what the CLI and the EXR
    reader use): ``model`` a registry name or None, ``params`` {channel: {name: value}},
    ``options`` the model options (``distribution``, ``fresnel``). Each kind's ``make`` takes
    what it needs from these."""
    k = get_kind(kind)
    size = tuple(int(s) for s in (size or k.default_size))
    if len(size) not in k.axis_counts:
        counts = _one_of(map(str, k.axis_counts))
        raise ValueError(f"table {kind} has {_axes_text(k)}; give {counts} sizes "
                         f"({'x'.join(map(str, k.default_size))} by default), got {len(size)}")
    mappings = tuple(mappings or k.all_default_mappings)
    if len(mappings) not in (len(size), len(k.all_axis_names)):
        raise ValueError(f"table {kind} with {len(size)} axes needs {len(size)} mappings, got "
                         f"{len(mappings)}")
    mappings = mappings[:len(size)]
    return k.make(size, mappings, model=model, params=params or {}, options=dict(options or {}),
                  alpha_range=tuple(alpha_range or (ALPHA_MIN, 1.0)),
                  eta_range=tuple(eta_range or ETA_RANGE), orders=orders,
                  kappa_range=tuple(kappa_range) if kappa_range else None)


def _axes_text(k: Kind) -> str:
    text = f"{k.n_axes} axes ({', '.join(k.axis_names)})"
    if k.extra_axes:
        text += f" or {len(k.all_axis_names)} (with {', '.join(e[0] for e in k.extra_axes)})"
    return text


def spec_of_table(table: Table) -> Spec:
    """Rebuild the evaluator of a baked (or read) table from its description, to re-measure it."""
    ax = table.axes
    by = {a.name: a for a in ax}
    orders = (table.accuracy.get("quadrature") or {}).get("orders")
    model = table.model or {}
    return make_spec(table.kind, size=[a.size for a in ax], mappings=[a.mapping for a in ax],
                     model=model.get("name"), params=table.params, options=model.get("options"),
                     alpha_range=(by["alpha"].lo, by["alpha"].hi) if "alpha" in by else None,
                     eta_range=(by["eta"].lo, by["eta"].hi) if "eta" in by else None,
                     kappa_range=(by["kappa1"].lo, by["kappa1"].hi) if "kappa1" in by else None,
                     orders=orders)


# --------------------------------------------------------------------------------------------
# Let the measured error choose the axes (fitlab lut model --phi-d auto)
# --------------------------------------------------------------------------------------------


def _size_text(axes) -> str:
    return "x".join(str(a.size) for a in axes)


def bake_auto(kind: str, *, size=None, mappings=None, dtype="float", check_points=None,
              source_fit=None, progress=None, **spec_args) -> Table:
    """Bake a table of ``kind`` with its required axes; if that table misses the target of the
    kind's accuracy check (``Kind.auto_check``, e.g. the model table's parameterization error
    against :data:`PHI_D_TARGET`), bake it with its extra axes (e.g. φd) too, measured at the
    same points, and keep that one unless it measures a larger RMS error. ``size`` and
    ``mappings`` may give every axis (the extra ones are the candidate's; default
    ``Kind.extra_axes``) or the required ones only. The table's ``accuracy["auto"]`` holds both
    measurements, the rule, the reason and whether the table kept meets the target
    (``meets_target``: when false, no candidate met it and the table is the closer one;
    ``fitlab lut`` then writes nothing, fitlab.export.lut_files.build_table); a note says the
    same in words."""
    k = get_kind(kind)
    if k.auto_check is None:
        raise ValueError(f"{kind} tables have no optional axis to choose by measurement")
    if check_points is not None and check_points <= 0:
        raise ValueError("choosing the axes by measurement needs the accuracy check "
                         "(check points > 0)")
    n, full = k.n_axes, len(k.all_axis_names)
    size = tuple(int(s) for s in (size or k.default_size))
    if len(size) == n:
        size += tuple(e[1] for e in k.extra_axes)
    if len(size) != full:
        raise ValueError(f"table {kind}: give {n} or {full} sizes, got {len(size)}")
    mappings = tuple(mappings or k.all_default_mappings)
    if len(mappings) == n:
        mappings += tuple(e[2] for e in k.extra_axes)
    if len(mappings) != full:
        raise ValueError(f"table {kind}: give {n} or {full} mappings, got {len(mappings)}")

    def one(sz, mp):
        t0 = time.perf_counter()
        spec = make_spec(kind, size=sz, mappings=mp, **spec_args)
        if progress:
            progress(f"auto: baking the {len(sz)}-axis candidate {'x'.join(map(str, sz))}")
        table = bake(spec, dtype, check_points=check_points, source_fit=source_fit,
                     progress=progress)
        if progress:  # the time goes to the terminal only: the header holds no clock time
            progress(f"auto: {'x'.join(map(str, sz))} baked and checked in "
                     f"{time.perf_counter() - t0:.2f} s")
        acc = table.accuracy[k.auto_check]
        return table, {"size": _size_text(table.axes), "axes": [a.name for a in table.axes],
                       "rms_rel": acc["rms_rel"], "max_rel": acc["max_rel"],
                       "meets_target": acc["meets_target"]}

    small, m_small = one(size[:n], mappings[:n])
    target = small.accuracy[k.auto_check]["target"]
    extra = ", ".join(e[0] for e in k.extra_axes)
    rule = (f"bake the {n}-axis table; if its {k.auto_check} error misses the target (RMS "
            f"relative <= {target['rms_rel']:g} and max relative <= {target['max_rel']:g}), "
            f"bake the table with {extra} too and keep it unless its RMS error is larger")
    record = {"rule": rule, "check": k.auto_check, "target": target, "candidates": [m_small]}
    if m_small["meets_target"]:
        chosen, reason = small, (f"the {n}-axis table meets the target (RMS "
                                 f"{m_small['rms_rel']:.2g}, max {m_small['max_rel']:.2g})")
    else:
        big, m_big = one(size, mappings)
        record["candidates"].append(m_big)
        better = m_big["rms_rel"] <= m_small["rms_rel"]
        chosen = big if better else small
        reason = (f"the {n}-axis table misses the target (RMS {m_small['rms_rel']:.2g}, max "
                  f"{m_small['max_rel']:.2g}); with {extra} ({m_big['size']}) RMS "
                  f"{m_big['rms_rel']:.2g}, max {m_big['max_rel']:.2g}: "
                  + ("kept" if better else f"larger, the {n}-axis table kept")
                  + ("" if m_big["meets_target"] else
                     f"; the {len(size)}-axis table misses the target too (raise its sizes)"))
    record["chosen"] = _size_text(chosen.axes)
    record["reason"] = reason
    record["meets_target"] = bool(chosen.accuracy[k.auto_check]["meets_target"])
    accuracy = {**chosen.accuracy, "auto": record}
    note = f"axes chosen by measurement (auto): {reason}"
    return chosen._replace(accuracy=accuracy, notes=tuple(chosen.notes) + (note,))
