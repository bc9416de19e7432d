"""The knobs ``fitlab tradeoffs`` measures, one function each, in :data:`KNOBS`: each takes the
:class:`~fitlab.tradeoffs.core.Context` and returns the measured :class:`Variant`s, or raises
:class:`NotApplicable` saying why the knob does not apply to this material.

Which model options are approximations of which is stated once, in :data:`OPTION_KNOBS`, by
option name (any registry model that offers the option is measured; no model names here).
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple

import numpy as np

from fitlab.registry import Registry
from fitlab.tradeoffs.core import (ALBEDO_ORDER, ALBEDO_THETA, Context, NotApplicable, Variant,
                                   evaluation_seconds, reference_values, score, seconds,
                                   with_reflection)

EVAL_UNIT = "per 1e5 evaluations"


class OptionKnob(NamedTuple):
    """A model option whose values trade accuracy for speed: ``reference`` is the most exact
    value, ``approximations`` the others measured against it; ``applies_to``: the values the
    material must have for the knob to apply (None: any)."""

    knob: str
    option: str
    reference: str
    approximations: tuple
    description: str
    applies_to: tuple | None = None


#: Approximations offered as model options (fitlab models lists them per model).
OPTION_KNOBS = (
    OptionKnob("Fresnel", "fresnel", "exact", ("schlick", "lazanyi"),
               "exact Fresnel vs Schlick's and Lazányi–Szirmay-Kalos' approximations"),
    OptionKnob("G1 (Beckmann)", "distribution", "beckmann", ("beckmann_rational",),
               "Beckmann masking: exact erf G1 vs Walter's rational approximation (eq. 27)",
               applies_to=("beckmann", "beckmann_rational")),
    OptionKnob("masking correlation", "shadowing", "height_correlated", ("separable",),
               "separable vs height-correlated Smith masking-shadowing"),
    OptionKnob("thin-layer masking", "masking", "exact", ("approx",),
               "the extended NDF's masking: eq. 7 integrated vs its eq. 8 approximation"),
    OptionKnob("coat inter-reflections", "interreflection", "closed_form", ("single",),
               "every bounce between coat and Lambertian base (closed form) vs one bounce"),
    OptionKnob("thin-layer bounces K", "bounces", "4", ("1", "2", "3"),
               "subsurface orders 1..K of the thin layer"),
)


def _option_variants(ctx: Context, ok: OptionKnob, group: str) -> list[Variant]:
    opt = {o.name: o for o in ctx.model.options}.get(ok.option)
    if opt is None:
        raise NotApplicable(f"{ctx.model.name} has no option {ok.option!r} ({ok.description})")
    current = str(ctx.material.options.get(ok.option, opt.default))
    if ok.applies_to is not None and current not in ok.applies_to:
        raise NotApplicable(f"the material uses {ok.option} = {current}, not one of "
                            f"{', '.join(ok.applies_to)}")
    values = [v for v in (ok.reference, *ok.approximations) if v in map(str, opt.choices)]
    if len(values) < 2:
        raise NotApplicable(f"{ctx.model.name}'s option {ok.option} offers "
                            f"{', '.join(map(str, opt.choices))}")
    ref_opts = {**ctx.material.options, ok.option: values[0]}
    ref_eval = ctx.evaluator(options=ref_opts)
    ref = reference_values(ctx, ref_eval, ("option", ok.option))
    out = []
    for v in values:
        ev = ctx.evaluator(options={**ctx.material.options, ok.option: v})
        out.append(Variant(
            ok.knob, group, f"{ok.option}={v}", f"{ok.option}={values[0]} at the same parameters",
            score(ctx, ev, ref), evaluation_seconds(ev, ctx.transmission), EVAL_UNIT,
            current=(v == current),
            note=ok.description + ("; the material's parameters were fitted with "
                                   f"{ok.option}={current}" if ctx.fit is not None else "")))
    return out


def option_knob(ok: OptionKnob) -> Callable:
    def run(ctx: Context) -> list[Variant]:
        return _option_variants(ctx, ok, "evaluation")
    run.__doc__ = ok.description
    return run


def precision(ctx: Context) -> list[Variant]:
    """float32 vs float64 evaluation of the same model and parameters."""
    out = []
    ref_eval = ctx.evaluator()
    ref = reference_values(ctx, ref_eval, "float64")
    for name, dtype in (("float64", np.float64), ("float32", np.float32)):
        ev = ctx.evaluator(dtype=dtype)
        out.append(Variant("precision", "evaluation", name, "float64 evaluation",
                           score(ctx, ev, ref), evaluation_seconds(ev, ctx.transmission, dtype),
                           EVAL_UNIT, current=(name == "float64"),
                           note="directions and parameters cast to the precision; fitlab fits "
                           "and bakes in float64"))
    return out


# --------------------------------------------------------------------------------------------
# Tables and quadrature
# --------------------------------------------------------------------------------------------

TABLE_SIZES = (32, 64, 128, 256)
TABLE_SIZES_QUICK = (32, 128)
TABLE_DTYPES = ("half", "float")
#: (cos θh, cos θd, φd) tables: exact for any isotropic BRDF up to interpolation.
TABLE_SHAPES_3D = ((32, 32, 8), (64, 64, 16), (128, 128, 32))
TABLE_SHAPES_3D_QUICK = ((32, 32, 8), (64, 64, 16))


def shape_text(shape) -> str:
    return f"{shape[0]}²" if len(shape) == 2 else "×".join(map(str, shape))
TABLE_MAPPINGS = ("u8", "linear")


def tables(ctx: Context) -> list[Variant]:
    """The material's table (``fitlab lut model``): 2D (cos θh, cos θd) at φd = 90° or 3D with
    φd, size × storage (half, float) × the cos θh axis mapping (u8, linear), against the exact
    model on the reflection side (a table holds the BRDF only)."""
    from fitlab.lut.axes import lookup
    from fitlab.lut.baking import bake
    from fitlab.lut.kinds import model_coordinates, spec_model

    if not ctx.model.capabilities.isotropic:
        raise NotApplicable(f"{ctx.model.name} is anisotropic; a (cos θh, cos θd) table holds "
                            "isotropic BRDFs only")
    if not ctx.model.capabilities.reflection:
        raise NotApplicable("the material reflects nothing; a model table holds the BRDF")
    ctx = with_reflection(ctx)
    ref_eval = ctx.evaluator()
    ref = reference_values(ctx, ref_eval, "float64", reflection_only=True)
    out = []
    sizes = TABLE_SIZES_QUICK if ctx.quick else TABLE_SIZES
    shapes = [(n, n) for n in sizes] + list(TABLE_SHAPES_3D_QUICK if ctx.quick
                                              else TABLE_SHAPES_3D)
    for mapping in TABLE_MAPPINGS:
        for shape in shapes:
            spec = spec_model(ctx.model.name, ctx.material.channels, ctx.material.options,
                              size=shape, mappings=(mapping, "linear", "linear"))
            for dtype in TABLE_DTYPES:
                ctx.progress(f"tables: baking {shape_text(shape)} {dtype}, cos θh {mapping}")
                try:
                    table = bake(spec, dtype, check_points=0)  # compiles; timed below
                    t0 = time.perf_counter()
                    table = bake(spec, dtype, check_points=0)
                except ValueError as exc:  # values beyond half's range
                    out.append(Variant("tables", "tables",
                                       f"{shape_text(shape)} {dtype} {mapping}",
                                       "exact evaluation (reflection)", {}, float("nan"),
                                       "per bake", {"bytes": None}, note=str(exc)))
                    continue
                bake_s = time.perf_counter() - t0

                def ev(wi, wo, table=table):
                    v = lookup(table, model_coordinates(table.axes, wi, wo))
                    return np.where((wi[:, 2:3] > 0) & (wo[:, 2:3] > 0), v, 0.0)
                nbytes = int(np.prod(shape)) * len(table.channels) * (2 if dtype == "half"
                                                                      else 4)
                out.append(Variant("tables", "tables", f"{shape_text(shape)} {dtype} {mapping}",
                                   "exact evaluation (reflection), on " + ctx.directions,
                                   score(ctx, ev, ref, reflection_only=True), bake_s, "per bake",
                                   {"bytes": nbytes, "shape": list(shape), "dtype": dtype,
                                    "mapping": mapping},
                                   note="bilinear (trilinear with φd) lookup as the generated "
                                   "shader reads it; a 2D table assumes φd = 90° (its "
                                   "parameterization error is part of the figures)"))
    return out


QUADRATURE_ORDERS = (4, 8, 16, 32, 64)


def quadrature(ctx: Context) -> list[Variant]:
    """The directional albedo by a Gauss–Legendre × trapezoid product rule of order n against
    order 256."""
    from fitlab.lobe_metrics import albedo_quadrature

    ev = ctx.evaluator()
    ref = {t: albedo_quadrature(ev, t, 256, ctx.transmission) for t in ALBEDO_THETA}
    out = []
    for n in QUADRATURE_ORDERS + (ALBEDO_ORDER,):
        got = {t: albedo_quadrature(ev, t, n, ctx.transmission) for t in ALBEDO_THETA}
        err = max(float(np.max(np.abs(got[t] - ref[t]))) for t in ALBEDO_THETA)
        rel = max(float(np.max(np.abs(got[t] - ref[t]) / np.maximum(np.abs(ref[t]), 1e-12)))
                  for t in ALBEDO_THETA)
        out.append(Variant("albedo quadrature", "tables", f"order {n}", "order 256",
                           {"albedo_abs_max": err, "albedo_rel_max": rel},
                           seconds(lambda n=n: albedo_quadrature(ev, 30.0, n, ctx.transmission),
                                   repeat=2),
                           "per albedo", {"evaluations": 2 * n * n * (2 if ctx.transmission else 1)},
                           current=(n == ALBEDO_ORDER),
                           note="what a baked albedo table or an energy-compensation term pays "
                           "per texel"))
    return out


# --------------------------------------------------------------------------------------------
# Monte Carlo
# --------------------------------------------------------------------------------------------

MC_SAMPLES = (1_000, 10_000, 100_000, 1_000_000)


def sampled_albedo(ctx: Context) -> list[Variant]:
    """The albedo by the model's importance sampler (what an MC-baked table does per texel)
    with N samples, against the quadrature of order 256."""
    from fitlab.lobe_metrics import albedo_quadrature, albedo_sampled

    m = ctx.material
    ev = ctx.evaluator()
    ref = {t: albedo_quadrature(ev, t, 256, ctx.transmission) for t in ALBEDO_THETA}
    out = []
    for n in MC_SAMPLES[:3] if ctx.quick else MC_SAMPLES:
        def run(n=n):
            got = {}
            for t in ALBEDO_THETA:
                a = albedo_sampled(m.model, m.channels, m.options, t, n=n, seed=ctx.seed)
                if ctx.transmission:
                    a = a + albedo_sampled(m.model, m.channels, m.options, t, n=n,
                                           seed=ctx.seed, side=-1)
                got[t] = a
            return got
        got = run()
        err = max(float(np.max(np.abs(got[t] - ref[t]))) for t in ALBEDO_THETA)
        rel = max(float(np.max(np.abs(got[t] - ref[t]) / np.maximum(np.abs(ref[t]), 1e-12)))
                  for t in ALBEDO_THETA)
        t_one = seconds(lambda n=n: albedo_sampled(m.model, m.channels, m.options, 30.0, n=n,
                                                   seed=ctx.seed), repeat=2)
        out.append(Variant("sampled albedo", "monte carlo", f"{n:,} samples",
                           "quadrature of order 256", {"albedo_abs_max": err,
                                                       "albedo_rel_max": rel},
                           t_one, "per albedo", {"samples": n},
                           note="fitlab's importance sampler (sample_bsdf weights)"))
    return out


SIM_SAMPLES = (2_000, 8_000, 32_000, 128_000)
SIM_SAMPLES_QUICK = (2_000, 16_000)
SIM_THETA_I = (0.0, 30.0, 60.0)
SIM_ARC = tuple(float(t) for t in np.arange(-85.0, 85.1, 5.0) if abs(t) > 1e-9) + (0.5,)
SIM_ARC_T = tuple(float(s * t) for t in np.arange(95.0, 180.0, 10.0) for s in (1, -1))


def _scene_dicts(ctx: Context, model=None, options=None, channels=None) -> dict:
    """{channel: scene dict} of the material's stack with every effect traced
    (fitlab.simulate.model_stack.stack_scene); NotApplicable without a stack the simulator
    traces."""
    from fitlab.models import get_model
    from fitlab.simulate.model_stack import stack_scene

    mdl = ctx.model if model is None else get_model(model)
    out = {}
    for ch, p in (channels or ctx.material.channels).items():
        try:
            out[ch] = stack_scene(mdl, p, ctx.material.options if options is None else options)
        except ValueError as exc:
            raise NotApplicable(str(exc)) from None
    return out


def _simulation(ctx: Context, samples: int, again: bool = False):
    """{channel: SimulationResult} of the material's stack at SIM_THETA_I on an in-plane arc
    (point estimates, or cones where the stack allows none:
    fitlab.simulate.model_stack.with_detector); cached unless ``again`` (a second run: its
    time_s is without compilation)."""
    from fitlab.simulate import simulate
    from fitlab.simulate.model_stack import with_detector

    key = ("simulation", samples)
    if key in ctx.cache and not again:
        return ctx.cache[key]
    arc = SIM_ARC + (SIM_ARC_T if ctx.transmission else ())
    res = {}
    for ch, s in _scene_dicts(ctx).items():
        scene = with_detector({**s, "illumination": {"theta_i": list(SIM_THETA_I)}},
                              {"type": "inplane", "theta_o": list(arc)})
        res[ch] = simulate(scene, samples, ctx.seed)
    ctx.cache[key] = res
    return res


def simulator_samples(ctx: Context) -> list[Variant]:
    """The simulator's paths per incidence: its own standard error (1σ, relative RMS over the
    arc) and its time, against no other reference (the simulation is the ground truth)."""
    out = []
    for n in SIM_SAMPLES_QUICK if ctx.quick else SIM_SAMPLES:
        ctx.progress(f"simulator: {n:,} paths per incidence (twice: the second run is timed, "
                     "without compilation)")
        _simulation(ctx, n)
        sims = _simulation(ctx, n, again=True)
        rel = []
        for r in sims.values():
            v, s = r.value[:, 0], r.sigma[:, 0]
            keep = v > 0.01 * v.max()
            rel.append(s[keep] / v[keep])
        rel = np.concatenate(rel)
        out.append(Variant("simulator paths", "monte carlo", f"{n:,} paths",
                           "its own standard error (1σ)",
                           {"f_rel_rms": float(np.sqrt(np.mean(rel ** 2))),
                            "f_rel_max": float(rel.max())},
                           sum(r.time_s for r in sims.values()), "per simulation",
                           {"samples": n, "incidences": len(SIM_THETA_I),
                            "rows": int(sum(len(r.value) for r in sims.values()))},
                           note="fitlab simulate of the material's stack (Model.scene_of), "
                           "in-plane arc at θi = 0, 30, 60°"))
    return out


#: Options of layered models that choose how the stack's physics is approximated: every value
#: is measured against the simulator (the coat's inter-reflections, the thin layer's bounces
#: and masking, Weidlich–Wilkie's roughness clamp).
LAYERED_OPTIONS = ("interreflection", "bounces", "masking", "roughness_clamp")
#: Keyword arguments of layered model names that switch an approximation of the same stack on
#: or off: a material without the keyword is also measured with each value given (when that
#: model takes the same parameters), one with it also without (SpongeCake's multiple-scattering
#: lobe: ``multiple=learned`` needs no fitted parameters).
KEYWORD_VARIANTS = {"multiple": ("learned",)}


def _model_variants(ctx: Context) -> list[tuple[str, str, dict, dict]]:
    """(label, model, options, channels) of the material and its layered-physics variants:
    every other value of its LAYERED_OPTIONS, and the model with or without a KEYWORD_VARIANTS
    keyword (parameters restricted to the other model's)."""
    from fitlab.models import get_model, variant_name

    m = ctx.material
    out = [(f"{m.model} (the material)", m.model, dict(m.options), m.channels)]
    for o in ctx.model.options:
        if o.name not in LAYERED_OPTIONS:
            continue
        current = str(m.options.get(o.name, o.default))
        for v in map(str, o.choices):
            if v != current:
                out.append((f"{o.name}={v}", m.model, {**m.options, o.name: v}, m.channels))
    for kw, values in KEYWORD_VARIANTS.items():
        current = ctx.model.argument(kw)
        if current is not None:
            tries = [(f"without {kw}={current}", variant_name(ctx.model, kw, None))]
        else:
            tries = [(f"with {kw}={v}", variant_name(ctx.model, kw, v)) for v in values]
        for label, name in tries:
            if name is None:  # no layered constructor made this model
                continue
            try:
                other = get_model(name)
            except ValueError:
                continue
            names = set(other.parameter_names)
            if not names <= set(ctx.model.parameter_names):
                continue  # it needs parameters the material does not have
            valid = {o.name for o in other.options}
            out.append((label, name, {k: v for k, v in m.options.items() if k in valid},
                        {c: {k: v for k, v in p.items() if k in names}
                         for c, p in m.channels.items()}))
    return out


SIM_REFERENCE_SAMPLES = 200_000
SIM_REFERENCE_SAMPLES_QUICK = 32_000


def layered_physics(ctx: Context) -> list[Variant]:
    """The material's layered model and its variants against the simulator of the same stack
    with every bounce and scattering order traced, at a stated standard error: relative RMS of
    f over the arc (rows above 1 % of the peak), the simulation's own relative RMS error beside
    it."""
    from fitlab.simulate.model_stack import model_at_rows

    _scene_dicts(ctx)  # NotApplicable early
    n = SIM_REFERENCE_SAMPLES_QUICK if ctx.quick else SIM_REFERENCE_SAMPLES
    ctx.progress(f"layered physics: simulating the stack, {n:,} paths per incidence")
    sims = _simulation(ctx, n)
    sim_time = sum(r.time_s for r in sims.values())
    out = []
    for label, model, options, channels in _model_variants(ctx):
        ev = ctx.evaluator(model=model, options=options, channels=channels)
        rel, noise = [], []
        for k, (ch, r) in enumerate(sims.items()):
            mm = r.to_measurement()
            pred = model_at_rows(ev, mm)[:, k]
            v, s = mm.value, mm.sigma
            keep = v > 0.01 * v.max()
            rel.append((pred[keep] - v[keep]) / v[keep])
            noise.append(s[keep] / v[keep])
        rel, noise = np.concatenate(rel), np.concatenate(noise)
        out.append(Variant(
            "layered physics", "layered physics", label,
            f"fitlab simulate, {n:,} paths per incidence (its relative RMS error "
            f"{np.sqrt(np.mean(noise ** 2)):.2g})",
            {"f_rel_rms": float(np.sqrt(np.mean(rel ** 2))),
             "f_rel_max": float(np.max(np.abs(rel))),
             "simulation_rel_rms": float(np.sqrt(np.mean(noise ** 2)))},
            evaluation_seconds(ev, ctx.transmission), EVAL_UNIT,
            {"simulation_seconds": sim_time}, current=label.endswith("(the material)"),
            note="the simulator took "
            f"{sim_time:.1f} s for its {n:,} paths per incidence at {len(SIM_THETA_I)} "
            "incidences"))
    return out


MCMC_STEPS = (250, 500, 1000, 2000)
MCMC_STEPS_QUICK = (200, 800)


def mcmc_length(ctx: Context) -> list[Variant]:
    """emcee chains of N steps on the fit's data: the 68 % interval width of each parameter
    against the longest chain's, and the width's Monte Carlo error estimated from the chain's
    effective sample size (≈ 1.07 / sqrt(ESS) relative, a Gaussian posterior's quantiles)."""
    from fitlab.fitting.api import fit as fit_data

    if ctx.fit is None or ctx.data is None:
        raise NotApplicable("needs a fit with its data file (FIT.json whose data is found, or "
                            "--data FILE)")
    fit = ctx.fit
    subset = fit.record["data"].get("fit_subset")
    chans = list(fit.channels) if fit.shared else [fit.channels[0]]
    fixed = {k: v for k, v in fit.fixed.get(chans[0], {}).items()}
    steps = MCMC_STEPS_QUICK if ctx.quick else MCMC_STEPS

    def run(s):
        return fit_data(ctx.data, fit.model, fix=fixed or None, options=dict(fit.options),
                        loss=fit.loss, subset=subset, channels=chans, share=fit.shared,
                          mcmc=True, mcmc_steps=s, seed=ctx.seed, bootstrap=0)
    ctx.progress("MCMC length: a first short fit compiles the kernels (not timed)")
    run(100)
    runs = {}
    for s in steps:
        ctx.progress(f"MCMC length: emcee, {s} steps")
        t0 = time.perf_counter()
        r = run(s)
        runs[s] = (r, time.perf_counter() - t0)
    longest = runs[steps[-1]][0]

    def widths(r):
        out = {}
        for ch in chans:
            post = r.record["fits"][r.channels.index(ch)]["parameters"]
            for name, p in post.items():
                q = p.get("posterior")
                if q:
                    out[f"{ch}.{name}"] = q["p84"] - q["p16"]
        return out
    ref_w = widths(longest)
    out = []
    for s, (r, wall) in runs.items():
        w = widths(r)
        dev = max(abs(w[k] - ref_w[k]) / ref_w[k] for k in ref_w if ref_w[k] > 0)
        mc = [r.record["fits"][r.channels.index(ch)].get("mcmc") or {} for ch in chans]
        ess = min(float(x.get("effective_sample_size") or np.nan) for x in mc)
        trusted = all(bool(x.get("trustworthy")) for x in mc)
        out.append(Variant("MCMC length", "monte carlo", f"{s} steps",
                           f"68 % interval widths of the {steps[-1]}-step chain",
                           {"interval_width_rel_dev": float(dev),
                            "interval_width_mc_rel_error": float(1.07 / np.sqrt(ess))
                            if np.isfinite(ess) and ess > 0 else None,
                            "ess": ess, "trustworthy": trusted},
                           wall, "per fit", {"steps": s, "channels": len(chans)},
                           note=f"fitlab.fit with emcee on {', '.join(chans)}"
                           + (" (joint)" if fit.shared else "")))
    return out


class Knob(NamedTuple):
    name: str
    group: str
    run: Callable
    description: str


#: Every knob, in the report's order.
KNOBS: Registry[Knob] = Registry("knob", {k.name: k for k in (
    Knob("precision", "evaluation", precision, precision.__doc__),
    *(Knob(ok.knob, "evaluation", option_knob(ok), ok.description) for ok in OPTION_KNOBS),
    Knob("layered physics", "layered physics", layered_physics, layered_physics.__doc__),
    Knob("tables", "tables", tables, tables.__doc__),
    Knob("albedo quadrature", "tables", quadrature, quadrature.__doc__),
    Knob("sampled albedo", "monte carlo", sampled_albedo, sampled_albedo.__doc__),
    Knob("simulator paths", "monte carlo", simulator_samples, simulator_samples.__doc__),
    Knob("MCMC length", "monte carlo", mcmc_length, mcmc_length.__doc__),
)})
GROUPS = ("evaluation", "layered physics", "tables", "monte carlo")

__all__ = ["GROUPS", "KNOBS", "Knob", "OPTION_KNOBS", "OptionKnob"]
