"""`fitlab lut`: from command-line values or a fit file to a baked table, its EXR and its shader
snippets. The CLI (fitlab/cli/lut.py) parses the arguments shared with other commands (model,
--param, --option) and prints; what is particular to tables (sizes, axis mappings, ranges, which
parameters a kind needs) is checked here, testable without argparse. Output is written only
after every input has been validated and the table baked: nothing is written on error, and the
EXR is removed again if a snippet cannot be written.
"""

from __future__ import annotations

from pathlib import Path

from fitlab.models import get_model
from fitlab import lut
from fitlab.errors import FitlabError


def parse_size(text: str, kind: lut.Kind) -> tuple:
    """'512x512', '32x32x16' or one number for every (required) axis; a kind with optional
    axes (the model table's phi_d) takes more sizes for them: '256x256x16'."""
    parts = text.lower().split("x")
    try:
        sizes = tuple(int(p) for p in parts)
    except ValueError:
        raise FitlabError(f"--size {text!r}: give integers like "
                          f"{'x'.join(map(str, kind.default_size))}") from None
    if len(sizes) == 1:
        sizes = sizes * kind.n_axes
    if len(sizes) not in kind.axis_counts:
        names = kind.all_axis_names
        if kind.extra_axes:
            raise FitlabError(
                f"--size {text!r}: a {kind.name} table has {kind.n_axes} axes "
                f"({', '.join(kind.axis_names)}) or {len(names)} ({', '.join(names)}); give "
                f"{' or '.join(str(c) for c in kind.axis_counts)} sizes, e.g. "
                f"{'x'.join(map(str, kind.default_size + tuple(e[1] for e in kind.extra_axes)))}")
        raise FitlabError(f"--size {text!r}: a {kind.name} table has {kind.n_axes} axes "
                          f"({', '.join(kind.axis_names)}); give {kind.n_axes} sizes")
    for s in sizes:
        if not lut.SIZE_MIN <= s <= lut.SIZE_MAX:
            raise FitlabError(f"--size {text!r}: every axis needs {lut.SIZE_MIN} to {lut.SIZE_MAX} "
                              "samples")
    return sizes


def parse_mappings(items, kind: lut.Kind) -> tuple:
    """The mapping of every axis, optional ones included (AXIS=MAPPING items over defaults)."""
    names = kind.all_axis_names
    mappings = list(kind.all_default_mappings)
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise FitlabError(f"--mapping {item!r} must look like AXIS=MAPPING, e.g. "
                              f"{kind.axis_names[0]}=linear")
        if name not in names:
            raise FitlabError(f"--mapping {item!r}: a {kind.name} table has the axes "
                              f"{', '.join(names)}")
        if value not in lut.MAPPINGS:
            raise FitlabError(f"--mapping {item!r}: mappings are {', '.join(lut.MAPPINGS)}")
        mappings[names.index(name)] = value
    return tuple(mappings)


#: --phi-d choices: the model table's φd axis (see build_table); the first is the default.
PHI_D_CHOICES = ("auto", "slice", "axis")


def parse_range(text, what):
    if text is None:
        return None
    lo, sep, hi = text.partition(":")
    try:
        r = (float(lo), float(hi))
    except ValueError:
        raise FitlabError(f"--{what}-range {text!r} must look like LO:HI") from None
    if not sep or not r[0] < r[1]:
        raise FitlabError(f"--{what}-range {text!r} must look like LO:HI with LO < HI")
    return r


def from_fit(path, channel=None):
    """(model name, options, {channel: {name: value}}) of a parameter file; ``scale`` (the
    unknown factor of relative data) is not part of the model and is left out."""
    from fitlab.export.paramfile import read_fit
    from fitlab.io.fitfile import fit_parameters

    rec = read_fit(path)
    params = fit_parameters(rec, source=path, channel=channel, scale=False)
    return get_model(rec["model"]["name"]).name, dict(rec["model"].get("options") or {}), \
        params


def build_table(kind_name, *, fit=None, channel=None, model=None, params=None, options=None,
                preset=None, size=None, mapping_items=None, alpha_range=None, eta_range=None,
                dtype="half", check_points=None, progress=None, phi_d=None, kappa_range=None):
    """Validate the inputs of `fitlab lut` and bake the table (nothing written). ``model`` is a
    registry name, ``params`` {channel: {name: value}} and ``options`` the model's options
    (the command line parses them: fitlab.cli.common); ``fit`` a parameter file instead.

    ``phi_d`` (model tables, the kind's optional axis; None is ``"auto"`` for them):

    - ``"auto"`` (the default): bake the 2D (θh, θd) table and measure its parameterization
      error; if it misses fitlab.lut.PHI_D_TARGET, bake the table with the φd axis (φd
      samples: the third size, else the kind's default) and keep it if it meets the target
      (fitlab.lut.bake_auto). When no table meets the target a :class:`FitlabError` gives both
      measured figures and what to try: nothing is returned, so nothing is written.
    - ``"slice"``: the 2D table at φd = 90° whatever its error (measured and stored).
    - ``"axis"``: the table with the φd axis whatever its error.
    """
    try:
        kind = lut.get_kind(kind_name)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if fit and (model or params or preset):
        raise FitlabError("give either --from-fit or --model/--param/--preset, not both")
    optional = [e[0] for e in kind.extra_axes]
    if phi_d is not None:
        if phi_d not in PHI_D_CHOICES:
            raise FitlabError(f"--phi-d {phi_d!r}: choose {', '.join(PHI_D_CHOICES)}")
        if lut.PHI_D not in optional:
            with_phi = [k.name for k in lut.KINDS.values()
                        if lut.PHI_D in (e[0] for e in k.extra_axes)]
            raise FitlabError(f"--phi-d applies to {' and '.join(with_phi)} tables only")
    elif lut.PHI_D in optional:
        phi_d = PHI_D_CHOICES[0]
    sizes = parse_size(size, kind) if size else None
    if phi_d == "slice" and sizes and len(sizes) > kind.n_axes:
        raise FitlabError(f"--phi-d slice asks for the 2D φd = 90° table, but --size {size!r} "
                          "gives a φd size; drop one of them")
    if phi_d == "axis" and (sizes is None or len(sizes) == kind.n_axes):
        # the φd axis always, of the kind's default size unless --size gives one
        sizes = (sizes or tuple(kind.default_size)) + tuple(e[1] for e in kind.extra_axes)
    mappings = parse_mappings(mapping_items, kind)
    n_axes = len(sizes) if sizes else kind.n_axes
    if phi_d != "auto":
        given = {item.partition("=")[0] for item in mapping_items or []}
        unused = [a for a in kind.all_axis_names[n_axes:] if a in given]
        if unused:
            raise FitlabError(f"--mapping {unused[0]}=...: this {kind.name} table has no "
                              f"{unused[0]} axis (--phi-d slice); drop the mapping or give "
                              "--phi-d auto or axis")
        mappings = mappings[:n_axes]
    if check_points == 0 and phi_d == "auto":
        raise FitlabError("--phi-d auto (the default) chooses the table by its measured error: "
                          "it needs the accuracy check (--check-points > 0); to skip the check "
                          "choose the table yourself: --phi-d slice (2D) or --phi-d axis (3D)")
    if fit:
        model, options, params = from_fit(fit, channel)
    else:
        if channel:
            raise FitlabError("--channel applies to --from-fit only")
        params, options = dict(params or {}), dict(options or {})
    try:
        if preset and kind.model_presets:
            model, options, params = _model_preset(preset, model, options, params)
        elif preset:
            if kind.preset is None:
                with_presets = [k.name for k in lut.KINDS.values() if k.preset is not None]
                raise ValueError(f"--preset applies to {' and '.join(with_presets)} tables "
                                 "(conductors) and model tables (layered presets) only")
            params = kind.preset(preset)
        # what the kind needs from the model's or fit's parameters and options
        options, params = kind.prepare(model, options, params)
        spec_args = dict(model=model, params=params, options=options,
                         alpha_range=parse_range(alpha_range, "alpha"),
                         eta_range=parse_range(eta_range, "eta"),
                         kappa_range=parse_range(kappa_range, "kappa"))
        source = str(fit) if fit else None
        if phi_d == "auto":
            table = lut.bake_auto(kind.name, size=sizes, mappings=mappings, dtype=dtype,
                                  check_points=check_points, source_fit=source,
                                  progress=progress, **spec_args)
            if not table.accuracy["auto"]["meets_target"]:
                raise FitlabError(missed_target_text(table.accuracy["auto"]))
            return table
        spec = lut.make_spec(kind.name, size=sizes, mappings=mappings, **spec_args)
        return lut.bake(spec, dtype, check_points=check_points, source_fit=source,
                        progress=progress)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None


def missed_target_text(auto: dict) -> str:
    """Why `fitlab lut model` (``--phi-d auto``) wrote nothing: every table it baked, its
    measured error and what to try (``auto``: a table's ``accuracy["auto"]`` record)."""
    t = auto["target"]
    tried = "; ".join(f"{c['size']} RMS {c['rms_rel']:.2g}, max {c['max_rel']:.2g}"
                      for c in auto["candidates"])
    last = [int(n) for n in auto["candidates"][-1]["size"].split("x")]
    if len(last) == 2:
        last.append(lut.PHI_D_SIZE)
    more = "x".join(str(min(2 * n, lut.SIZE_MAX)) for n in last)
    c = auto["candidates"]
    hint = ""
    if len(c) == 2 and c[1]["rms_rel"] > 0.5 * c[0]["rms_rel"]:
        hint = ("; the phi_d axis hardly lowers the error, so it lies within the cells (a sharp "
                "lobe, or f growing toward the horizon, which no size tabulates: "
                "data_formats/lut_exr.md)")
    return (f"no table meets the target (lookup vs the model at random direction pairs: RMS "
            f"relative <= {t['rms_rel']:g} and max <= {t['max_rel']:g}); measured {tried}"
            f"{hint}; nothing written. Try more samples (e.g. --size {more}), or write a table "
            "that misses the target knowingly: --phi-d axis (with phi_d) or --phi-d slice (2D, "
            "phi_d = 90 deg)")


def _model_preset(name, model, options, params):
    """(model, options, {R, G, B: parameters}) of a layered preset (fitlab/models/presets.py);
    --param values override the preset's (one value: every channel)."""
    from fitlab.models.presets import check_preset_model, rgb_preset

    check_preset_model(name, model)
    p_model, p_options, p_params = rgb_preset(name)
    given = params.get("Y", {})
    return p_model, {**p_options, **options}, {
        c: {**v, **given, **params.get(c, {})} for c, v in p_params.items()}


def write_outputs(table, out, *, shader=True, hlsl=False):
    """Write OUT.exr and (beside it) OUT.glsl / OUT.hlsl; on any failure nothing is left."""
    from fitlab.export import exr, shader as sh
    from fitlab.io.atomic import atomic_write_text

    out = Path(out)
    if out.suffix.lower() != ".exr":
        raise FitlabError(f"--out {out}: the table file must end in .exr")
    texts = {}
    if shader:
        texts[out.with_suffix(".glsl")] = sh.glsl(table, source=out.name)
    if hlsl:
        texts[out.with_suffix(".hlsl")] = sh.hlsl(table, source=out.name)
    exr.write_exr(out, table)
    written = [out]
    try:
        for path, text in texts.items():
            atomic_write_text(path, text)
            written.append(path)
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return written


__all__ = ["build_table", "write_outputs", "parse_size", "parse_mappings", "parse_range",
           "from_fit", "missed_target_text", "PHI_D_CHOICES"]
