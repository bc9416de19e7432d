"""fitlab multiple-lobe: a SpongeCake stack's multiple-scattering lobe (§5), fitted per material
to the simulator (fitlab.learn.lobe)."""

from __future__ import annotations

import sys

import numpy as np

from fitlab.cli.common import add_param, add_quiet, channel_params, get_model
from fitlab.errors import FitlabError


def add_parser(sub):
    from fitlab.models.presets import spongecake_presets
    from fitlab.learn.lobe import PHI_BINS, SAMPLES, THETA_BINS, THETA_I

    sponge = list(spongecake_presets())
    p = sub.add_parser(
        "multiple-lobe", help="fit a SpongeCake stack's multiple-scattering lobe to the simulator",
        description="Simulate a SpongeCake stack (no substrate) on a hemisphere grid of both "
        "sides, take its multiple-scattering part (the simulation minus the model's exact single "
        "scattering) and fit the lobe of SpongeCake §5 to it: spongecake(LAYERS,multiple=only), "
        "a single-scattering lobe with modified parameters weighted W1 and Lambertian lobes W2 "
        "(reflection) and W2T (transmission), each channel on its own, the axes held at the "
        "stack's and albedo1_ms at 1. Writes the lobe's parameter file (data_formats/"
        "fit_json.md); its parameters go with the stack's into spongecake(LAYERS,multiple=lobe) "
        "(data_formats/layered_models.md, 'Multiple scattering').",
        epilog="examples: fitlab multiple-lobe --preset fabric --out fabric_lobe.json; "
        "fitlab multiple-lobe 'spongecake(surface_z)' --param alpha1=0.3 --param albedo1=0.9 "
        "--param tau1=3 --out lobe.json --data-out ms.csv",
    )
    p.add_argument("model", nargs="?", help="a SpongeCake model without substrate, e.g. "
                   "'spongecake(fiber,surface_z)'; optional with --preset")
    p.add_argument("--preset", metavar="NAME", choices=sponge,
                   help=f"a SpongeCake preset ({', '.join(sponge)}), all three channels")
    add_param(p, "a stack parameter, one value or R,G,B (with --preset: overrides the "
              "preset's); parameters not given take the model's defaults")
    p.add_argument("--samples", type=int, default=SAMPLES,
                   help=f"paths per incidence (default {SAMPLES})")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation and the fit")
    p.add_argument("--theta-i", default=",".join(f"{t:g}" for t in THETA_I), metavar="DEG,...",
                   help="incidence angles in degrees (default %(default)s)")
    p.add_argument("--grid", default=f"{THETA_BINS}x{PHI_BINS}", metavar="THETAxPHI",
                   help="the hemisphere grid on each side, θo × φo cells whose centres are "
                   "observed (default %(default)s)")
    p.add_argument("--starts", type=int, default=8, help="Levenberg-Marquardt starts besides "
                   "the global search's best (default 8)")
    p.add_argument("--out", required=True, metavar="FIT.json", help="the lobe's parameter file")
    p.add_argument("--data-out", metavar="FILE.csv", help="also write the multiple-scattering "
                   "part as a measurement CSV (data_formats/measurement_csv.md), which `fitlab "
                   "fit --model 'spongecake(LAYERS,multiple=only)'` fits again")
    add_quiet(p)
    return p


def _stack(args):
    """(model name, {channel: parameters}) from --preset / the model argument and --param."""
    from fitlab.models.presets import check_preset_model, rgb_preset

    if args.preset:
        try:
            check_preset_model(args.preset, args.model)
        except ValueError as exc:
            raise FitlabError(str(exc)) from None
        name, _, base = rgb_preset(args.preset)
    elif args.model:
        name, base = args.model, {}
    else:
        raise FitlabError("give a SpongeCake model, e.g. 'spongecake(surface_z)', or --preset")
    model = get_model(name)
    given = channel_params(args.param)
    channels = list(base) or list(given) or ["Y"]
    if base and given and "Y" in given:
        given = {c: given["Y"] for c in channels}
    if base and given and set(given) != set(channels):
        raise FitlabError("--param values must be one value or R,G,B")
    defaults = {p.name: p.default for p in model.parameters}
    params = {c: {**defaults, **base.get(c, {}), **given.get(c, {})} for c in channels}
    unknown = {k for c in params for k in params[c]} - set(defaults)
    if unknown:
        raise FitlabError(f"{model.name} has no parameter(s) {', '.join(sorted(unknown))} "
                          f"(see `fitlab models '{model.name}'`)")
    for c, p in params.items():
        try:
            from fitlab.api import check_params

            check_params(model, p)
        except ValueError as exc:
            raise FitlabError(f"channel {c}: {exc}") from None
    return model.name, params


def _numbers(text, what):
    try:
        return [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise FitlabError(f"{what} {text!r}: give numbers separated by commas") from None


def run(args):
    from fitlab.learn import lobe as sl
    from fitlab.io.atomic import atomic_write_text
    from fitlab.io.measurement import format_measurement_csv

    name, params = _stack(args)
    theta_i = _numbers(args.theta_i, "--theta-i")
    if not theta_i or any(not 0 <= t < 90 for t in theta_i):
        raise FitlabError(f"--theta-i {args.theta_i}: angles in [0, 90) degrees")
    try:
        tb, pb = (int(x) for x in args.grid.lower().split("x"))
    except ValueError:
        raise FitlabError(f"--grid {args.grid!r}: give THETAxPHI, e.g. 6x12") from None
    if not (1 <= tb <= 90 and 1 <= pb <= 360):
        raise FitlabError(f"--grid {args.grid}: 1..90 θ cells by 1..360 φ cells")
    if args.samples < 2:
        raise FitlabError("--samples must be at least 2")
    try:
        sl.stack_call(name)
        ms, full = sl.multiple_scattering_part(
            name, params, samples=args.samples, seed=args.seed, theta_i=theta_i,
            theta_bins=tb, phi_bins=pb, progress=not args.quiet)
        fit, _ = sl.fit_lobe(name, params, seed=args.seed, starts=args.starts,
                             progress=not args.quiet, measurement=ms)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if args.data_out:
        atomic_write_text(args.data_out, format_measurement_csv(ms))
    fit.save(args.out)
    if not args.quiet:
        print(f"multiple-scattering lobe of {name} ({args.samples} paths per incidence, "
              f"{len(theta_i)} incidences, {tb}x{pb} cells per side):", file=sys.stderr)
        for c, cname in enumerate(fit.channels):
            rows = ms.channel == c
            share = float(np.sum(ms.value[rows]) / max(np.sum(full.value[:, c]), 1e-300))
            st = fit.statistics(cname)
            p = fit.parameters[cname]
            w2t = f", W2T {p['W2T']:.4g}" if "W2T" in p else ""
            print(f"  {cname}: multiple scattering {100 * share:.1f}% of the simulated f; lobe "
                  f"chi2/dof {st['chi2_per_dof']:.3g}, RMS relative error "
                  f"{st['fit_error']['rms_relative_error']:.3g}; W1 {p['W1']:.4g}, W2 {p['W2']:.4g}{w2t}",
                  file=sys.stderr)
        print(f"wrote {args.out}" + (f" and {args.data_out}" if args.data_out else ""),
              file=sys.stderr)
    return 0
