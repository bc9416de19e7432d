"""What the subcommands share: the parser class, the arguments several of them declare (with
help derived from the registries) and turning those arguments into a model, its parameters and
its options, with errors that say what to do."""

from __future__ import annotations

import argparse
import sys

from fitlab.assignments import parse_assignments
from fitlab.errors import FitlabError
from fitlab.models.presets import CHANNELS as PRESET_CHANNELS

#: Colour channels of the RGB forms (--param NAME=R,G,B, --preset ... --channel C).
RGB = PRESET_CHANNELS


class Parser(argparse.ArgumentParser):
    """fitlab's argument parser: no abbreviated options (``--mcmc-step`` is not taken for
    ``--mcmc-steps``), usage errors with exit status 2 under the (sub)command's name."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(self, args=None, namespace=None):
        self._seen = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message):  # argparse's own usage errors keep exit status 2
        import difflib
        import re

        choice = re.match(r"argument .*: invalid choice: '([^']*)' \(choose from (.*)\)$", message)
        if choice:
            close = difflib.get_close_matches(
                choice.group(1), re.findall(r"'([^']*)'", choice.group(2)), n=1, cutoff=0.5)
            message += f"; did you mean {close[0]}?" if close else ""
        elif message.startswith("the following arguments are required"):
            hints = self._hints(getattr(self, "_seen", ()))
            message += f" ({'; '.join(hints)})" if hints else ""
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")

    def _hints(self, args) -> list[str]:
        """'--modle: did you mean --model?' for each option in ``args`` this parser does not
        have but has one close to."""
        import difflib

        known = [s for action in self._actions for s in action.option_strings]
        hints = []
        for arg in args:
            name = arg.split("=", 1)[0]
            if name.startswith("-") and name not in known:
                close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
                if close:
                    hints.append(f"{name}: did you mean {close[0]}?")
        return hints

    def subcommand(self, name) -> "Parser":
        """The parser of subcommand ``name`` (this one when there is none of that name)."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction) and name in action.choices:
                return action.choices[name]
        return self

    def unrecognized(self, extras):
        """Arguments this (sub)command does not take: its usage, and for each unknown option
        the closest one it has."""
        hints = self._hints(extras)
        self.error(f"unrecognized arguments: {' '.join(extras)}"
                   + (f" ({'; '.join(hints)})" if hints else f" (see `{self.prog} --help`)"))


# --------------------------------------------------------------------------------------------
# Arguments declared by several subcommands
# --------------------------------------------------------------------------------------------


def add_model(p, help="registry model (see `fitlab models`)", **kwargs):
    p.add_argument("--model", help=help, **kwargs)


def add_param(p, help, metavar="NAME=VALUE"):
    p.add_argument("--param", action="append", metavar=metavar, help=help)


def add_option(p, help="a model option, e.g. distribution=beckmann"):
    p.add_argument("--option", action="append", metavar="NAME=VALUE", help=help)


def add_channel(p, help, choices=None):
    p.add_argument("--channel", choices=choices, help=help)


def add_quiet(p, help="no progress or summary on the terminal"):
    p.add_argument("--quiet", action="store_true", help=help)


def add_verbose(p, help="the whole account on the terminal: every progress line, the "
                "per-incidence errors, every warning with its advice (by default a few lines "
                "per channel; the output files hold everything either way)"):
    p.add_argument("-v", "--verbose", action="store_true", help=help)


def add_json(p):
    p.add_argument("--json", action="store_true", help="machine-readable output")


def add_format(p, help="input format"):
    from fitlab.io.formats import formats

    p.add_argument("--format", metavar="FORMAT",
                   help=f"{help}: {', '.join(formats())} (default: detected from the content)")


def add_read_options(p):
    """--angles, --accept and --quantity: how a command reads a measurement file (the sanity
    gates of fitlab.io.gates; data_formats/measurement_csv.md, "Sanity gates"). One definition
    for every command that reads measurements; :func:`read_kwargs` turns them into the keyword
    arguments of fitlab.read."""
    from fitlab.io.gates import ANGLES, GATES, QUANTITIES

    p.add_argument("--angles", choices=ANGLES,
                   help="the unit of the file's angles (fitlab's CSV): radians are converted to "
                   "degrees on reading (default degrees; a file whose angles look like radians "
                   "is refused)")
    p.add_argument("--accept", action="append", choices=list(GATES), metavar="GATE",
                   help="read the file although this sanity gate trips (repeatable): "
                   + "; ".join(f"{g.name}: {g.title}" for g in GATES.values())
                   + " (`fitlab info FILE` shows what each finds)")
    p.add_argument("--quantity", choices=QUANTITIES,
                   help="what the values are, replacing the file's '# quantity:' line "
                   "(fitlab's CSV; required for a spectral scan CSV, which does not state it): "
                   "bsdf (f, 1/sr), bsdf_cos (f|cos theta_o|), radiance_factor (pi f), relative "
                   "(f up to a scale)")


def read_kwargs(args) -> dict:
    """The keyword arguments of fitlab.read (and fitlab.fit, compare, fit_many from a path)
    of the options :func:`add_read_options` declared: only those given."""
    out = {}
    if getattr(args, "angles", None):
        out["angles"] = args.angles
    if getattr(args, "accept", None):
        out["accept"] = tuple(dict.fromkeys(args.accept))
    if getattr(args, "quantity", None):
        out["quantity"] = args.quantity
    return out


# --------------------------------------------------------------------------------------------
# From arguments to a model, its parameters and options
# --------------------------------------------------------------------------------------------


def get_model(name: str):
    """The registry model ``name`` (sums and layered models too)."""
    from fitlab.models import get_model as get_registry_model

    try:
        return get_registry_model(name)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None


def param_values(items, *, rgb: bool = False) -> dict[str, list[float]]:
    """--param NAME=VALUE items → {name: [value]}; with ``rgb`` also NAME=R,G,B (three values)."""
    out = {}
    for name, text in parse_assignments(items, "param").items():
        try:
            out[name] = [float(v) for v in text.split(",")] if rgb else [float(text)]
        except ValueError:
            if rgb:
                raise FitlabError(f"--param {name}={text}: values must be numbers (one value, "
                                  "or three as R,G,B)") from None
            raise FitlabError(f"--param {name}={text!r}: the value must be a number") from None
    if rgb and {len(v) for v in out.values()} - {1, 3}:
        raise FitlabError("--param takes one value or three (R,G,B) per parameter")
    return out


def model_params(model, items, base=None) -> dict:
    """--param items of ``model``, checked against its registry entry (``base``: values they
    override, e.g. a preset's)."""
    from fitlab.api import check_params

    params = dict(base or {})
    params.update({name: v[0] for name, v in param_values(items).items()})
    try:
        check_params(model, params)
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None
    return params


def channel_params(items) -> dict:
    """--param NAME=V or NAME=R,G,B → {channel: {name: value}} (channel Y, or R G B)."""
    raw = param_values(items, rgb=True)
    if any(len(v) == 3 for v in raw.values()):
        return {ch: {n: (v[i] if len(v) == 3 else v[0]) for n, v in raw.items()}
                for i, ch in enumerate(RGB)}
    return {"Y": {n: v[0] for n, v in raw.items()}} if raw else {}


def material_arguments(args, sources=("fit", "model")) -> tuple[dict | None, dict | None]:
    """(params, options) of a command that takes FIT.json or --model NAME with --param and
    --option (or one of the other ``sources``, e.g. --preset): exactly one source, and
    --param/--option only with --model."""
    given = [s for s in sources if getattr(args, s, None) is not None]
    if len(given) != 1:
        names = {"fit": "FIT.json", "model": "--model NAME with --param", "preset": "--preset NAME"}
        raise FitlabError(f"give {' or '.join(names.get(s, s) for s in sources)}"
                          + ((", not both" if len(given) == 2 else ", not several") if given
                             else ""))
    if args.model is None and (args.param or args.option):
        raise FitlabError("--param and --option go with --model; a fit brings its own values")
    if args.model is None:
        return None, None
    return channel_params(args.param), parse_assignments(args.option, "option")


def model_options(model, items, base=None) -> dict:
    """--option items of ``model`` with its defaults filled in (``base``: options they override)."""
    from fitlab.api import resolve_options

    try:
        return resolve_options(model, {**(base or {}),
                                                  **parse_assignments(items, "option")})
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models {model.name}`)") from None


def _preset(args):
    """(model name, parameters, options) of --preset NAME --channel C, or the model argument."""
    if not getattr(args, "preset", None):
        return args.model, {}, {}
    from fitlab.models.presets import check_preset_model, preset_params

    try:
        preset = check_preset_model(args.preset, args.model)
        if not args.channel:
            raise FitlabError(f"--preset {args.preset} needs --channel R, G or B (its values "
                              "differ per channel; `fitlab models` lists them)")
        return preset.model, preset_params(args.preset, args.channel), dict(preset.options)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None


def model_from_args(args):
    """(model, params, options) from the model argument (or --preset/--channel), --param and
    --option."""
    name, base_params, base_options = _preset(args)
    if not name:
        raise FitlabError("give a model name (see `fitlab models`) or --preset NAME")
    model = get_model(name)
    return model, model_params(model, args.param, base_params), \
        model_options(model, args.option, base_options)


__all__ = ["Parser", "RGB", "add_model", "add_param", "add_option", "add_channel", "add_quiet",
           "add_verbose",
           "add_json", "add_format", "add_read_options", "read_kwargs", "get_model",
           "param_values", "model_params",
           "channel_params", "material_arguments", "model_options", "model_from_args"]
