"""``fitlab.tradeoffs``: measure every knob of :data:`fitlab.tradeoffs.knobs.KNOBS` for one
material, in one run on this machine, and say what each use case should choose.

The material: a fit (``FIT.json`` or a :class:`fitlab.FitResult`; its data file, when found,
gives the measured directions and the MCMC-length study) or a registry model with parameters.
"""

from __future__ import annotations

import platform
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.tradeoffs.core import Context, NotApplicable, Variant
from fitlab.tradeoffs.knobs import KNOBS

FORMAT = "fitlab-tradeoffs"
VERSION = 1


class Tradeoffs(NamedTuple):
    """The run's measurements: ``variants`` (every measured setting), ``skipped`` ({knob:
    why}), ``recommendations`` (per use case), and what was measured on what."""

    material: dict
    directions: str
    pairs: int
    variants: tuple
    skipped: dict
    recommendations: dict
    machine: dict
    seconds: float
    quick: bool

    def as_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "material": self.material,
                "directions": self.directions, "pairs": self.pairs, "quick": self.quick,
                "machine": self.machine, "seconds": self.seconds,
                "thresholds": THRESHOLDS, "recommendations": self.recommendations,
                "variants": [v.as_dict() for v in self.variants], "skipped": self.skipped}


#: What each use case accepts (relative RMS of f·cos, SSIM of the lobe images, interval
#: widths); the recommendation is the cheapest setting within these.
THRESHOLDS = {
    "offline render": {"f_rel_rms": 1e-3, "ssim": 0.999},
    "real-time shader": {"f_rel_rms": 0.02, "ssim": 0.99},
    "fitting": {"f_rel_rms": 1e-6, "interval_width_rel_dev": 0.05,
                "interval_width_mc_rel_error": 0.05},
}


def _machine() -> dict:
    import os

    from fitlab._jax import jax

    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "jax": jax.__version__,
            "device": str(jax.devices()[0].platform)}


def _context(material, fit, data, seed, quick, progress) -> Context:
    from fitlab.models import get_model
    from fitlab.tradeoffs.core import standard_pairs

    model = get_model(material.model)
    if data is not None:
        wi, wo = data.wi, data.wo
        where = f"the {data.n} measured direction pairs of {Path(data.path).name}"
    else:
        wi, wo, where = standard_pairs(model)
    return Context(material, model, np.asarray(wi, float), np.asarray(wo, float), where, fit,
                   data, seed, quick, progress, {})


def _best(variants, ok) -> Variant | None:
    fine = [v for v in variants if ok(v) and np.isfinite(v.seconds)]
    return min(fine, key=lambda v: v.seconds) if fine else None


def _within(v: Variant, limits: dict) -> bool:
    e = v.errors
    for k, lim in limits.items():
        x = e.get(k)
        if k in ("ssim",):
            if x is not None and x < lim:
                return False
        elif x is not None and x > lim:
            return False
    return bool(e)


def recommend(variants) -> dict:
    """One line per use case, chosen from the measured variants by :data:`THRESHOLDS`."""
    by = {}
    for v in variants:
        by.setdefault(v.knob, []).append(v)
    lines = {}

    off = THRESHOLDS["offline render"]
    parts = []
    for knob in [k for k in by if by[k][0].group == "evaluation"]:
        b = _best(by[knob], lambda v: _within(v, {"f_rel_rms": off["f_rel_rms"],
                                                   "ssim": off["ssim"]}))
        if b is not None:
            parts.append(f"{b.setting} ({knob}: f error {b.errors['f_rel_rms']:.2g}, "
                         f"{b.seconds * 1e3:.3g} ms {b.time_unit})")
    lay = by.get("layered physics")
    if lay:
        cur = [v for v in lay if v.current][0]
        best = min(lay, key=lambda v: v.errors["f_rel_rms"])
        parts.append(f"layered model vs the simulator: the material's model is "
                     f"{cur.errors['f_rel_rms']:.2g} off (relative RMS; simulation noise "
                     f"{cur.errors['simulation_rel_rms']:.2g})"
                     + (f"; {best.setting} comes closest ({best.errors['f_rel_rms']:.2g})"
                        if best is not cur else ""))
    lines["offline render"] = "; ".join(parts) or "no evaluation knob applies"

    rt = THRESHOLDS["real-time shader"]
    parts = []
    tabs = [v for v in by.get("tables", []) if v.errors]
    fine = [v for v in tabs if _within(v, rt)]
    if fine:
        b = min(fine, key=lambda v: (v.cost["bytes"], v.seconds))
        parts.append(f"a {b.setting} table ({b.cost['bytes'] / 1024:.0f} KiB; f error "
                     f"{b.errors['f_rel_rms']:.2g}, SSIM {b.errors['ssim']:.4f})")
    elif tabs:
        b = min(tabs, key=lambda v: v.errors["f_rel_rms"])
        parts.append(f"no table reaches f error {rt['f_rel_rms']:g} with SSIM ≥ {rt['ssim']:g} "
                     f"(best {b.setting}: {b.errors['f_rel_rms']:.2g}); evaluate the model in "
                     "the shader")
    for knob in ("Fresnel", "precision"):
        b = _best(by.get(knob, []), lambda v: _within(v, rt))
        if b is not None and not b.current:
            parts.append(f"{b.setting} is within budget ({knob}: f error "
                         f"{b.errors['f_rel_rms']:.2g})")
    lines["real-time shader"] = "; ".join(parts) or "no table or approximation applies"

    ft = THRESHOLDS["fitting"]
    parts = []
    prec = {v.setting: v for v in by.get("precision", [])}
    if "float32" in prec:
        e = prec["float32"].errors["f_rel_rms"]
        parts.append("float64 (float32 changes f by a relative RMS of "
                     f"{e:.2g}, {'below' if e <= ft['f_rel_rms'] else 'above'} the "
                     f"{ft['f_rel_rms']:g} a converged fit resolves)")
    mc = sorted(by.get("MCMC length", []), key=lambda v: v.cost["steps"])
    if mc:
        # the longest chain is the reference: a length is chosen only when a shorter one
        # already agrees with it
        ok = [v for v in mc[:-1]
              if v.errors.get("interval_width_rel_dev", 1) <= ft["interval_width_rel_dev"]
              and (v.errors.get("interval_width_mc_rel_error") or 1)
              <= ft["interval_width_mc_rel_error"] and v.errors.get("trustworthy")]
        if ok:
            b = ok[0]
            parts.append(f"MCMC {b.setting} ({b.seconds:.1f} s per fit; 68 % interval widths "
                         f"within {b.errors['interval_width_rel_dev']:.1%} of the "
                         f"{mc[-1].setting} chain's, Monte Carlo error "
                         f"{b.errors['interval_width_mc_rel_error']:.1%})")
        else:
            parts.append(f"MCMC: no length shorter than {mc[-1].setting} gives trustworthy "
                         f"68 % interval widths within {ft['interval_width_rel_dev']:.0%} of its "
                         f"own with a Monte Carlo error below "
                         f"{ft['interval_width_mc_rel_error']:.0%}; run {mc[-1].setting} or more")
    lines["fitting"] = "; ".join(parts) or "no fitting knob applies"
    return lines


def material_record(material, preset=None) -> dict:
    rec = {"model": material.model, "options": dict(material.options),
           "parameters": {c: dict(p) for c, p in material.channels.items()}}
    if preset is not None:
        rec["preset"] = preset
    return rec


def fit_errors(fit) -> dict:
    """{channel: the fit's stored error (statistics.fit_error: rms_relative_error, rows,
    floor_rule) and its sentence (text)}: how far the material is from its own data, the
    scale against which the knobs' approximation errors are read."""
    from fitlab.metrics import fit_error_of, fit_error_text

    out = {}
    for ch in fit.channels:
        fe = fit_error_of(fit.statistics(ch))
        if fe is not None:
            out[ch] = {"rms_relative_error": fe["rms_relative_error"], "rows": fe["rows"],
                       "floor_rule": fe["floor_rule"], "text": fit_error_text(fe)}
    return out


def tradeoffs(fit=None, *, model: str | None = None, params: dict | None = None,
              options: dict | None = None, preset: str | None = None, data=None, knobs=None,
              quick: bool = False, seed: int = 0, progress: bool = False,
              out=None) -> Tradeoffs:
    """Measure what each knob costs in accuracy and saves in time for one material: a fit
    (``fit``: FIT.json or a FitResult; ``data``: its data file when not found beside it) or
    registry ``model`` with ``params`` and ``options``, or a SpongeCake ``preset`` (its R, G, B
    parameters; ``data``: a file or Measurement whose directions the errors are measured on). ``knobs``: names to measure (default
    all); ``quick``: fewer sizes, samples and steps. With ``out`` the report is written there
    (``index.html``, ``tradeoffs.json``, figures; fitlab.report.tradeoffs)."""
    from fitlab.fitting.api import read
    from fitlab.fitting.result import load_fit
    from fitlab.errors import FitlabError
    from fitlab.export.renderers import material_of

    t_start = time.perf_counter()
    say = (lambda msg: print(f"tradeoffs: {msg}", file=sys.stderr, flush=True)) if progress \
        else (lambda msg: None)
    fit_path, measurement = None, None
    if preset is not None:
        from fitlab.models.presets import rgb_preset

        if fit is not None or model is not None or params:
            raise FitlabError("a preset brings its model and parameters; give it alone")
        try:
            model, options, params = rgb_preset(preset)
        except ValueError as exc:
            raise FitlabError(str(exc)) from None
    if fit is not None:
        if not hasattr(fit, "record"):
            fit_path = Path(fit)
            fit = load_fit(fit)
        material = material_of(fit)
        measurement = _data_of(fit, fit_path, data)
    else:
        if data is not None:
            measurement = data if hasattr(data, "value") else read(data)
        material = material_of(model=model, params=params, options=options)
    wanted = list(KNOBS) if knobs is None else list(knobs)
    for k in wanted:
        if k not in KNOBS:
            raise FitlabError(str(KNOBS.unknown(k)))
    ctx = _context(material, fit, measurement, seed, quick, say)
    variants, skipped = [], {}
    todo = [k for k in KNOBS.values() if k.name in wanted]
    for i, knob in enumerate(todo):
        elapsed = time.perf_counter() - t_start
        eta = "" if i == 0 else f", about {elapsed / i * (len(todo) - i):.0f} s left"
        say(f"[{i + 1}/{len(todo)}] {knob.name}{eta}")
        try:
            variants += knob.run(ctx)
        except NotApplicable as exc:
            skipped[knob.name] = str(exc)
    record = material_record(material, preset)
    if fit is not None:  # the fit's own error beside the knobs' (the parameter file's figure)
        record["fit_error"] = fit_errors(fit)
    res = Tradeoffs(record, ctx.directions, int(len(ctx.wi)),
                    tuple(variants), skipped, recommend(variants), _machine(),
                    time.perf_counter() - t_start, quick)
    if out is not None:
        from fitlab.report.tradeoffs import write_report

        if fit_path is not None:
            from fitlab.io.files import path_for_record

            res = res._replace(material={**res.material,
                                         "fit": path_for_record(fit_path, Path(out) / "x")})
        write_report(res, out)
    say(f"done in {time.perf_counter() - t_start:.0f} s: {len(variants)} settings of "
        f"{len(todo) - len(skipped)} knobs measured, {len(skipped)} not applicable")
    return res


def _data_of(fit, fit_path, data):
    """The fit's measurement (the dataset it was fitted to), or None when its file is not
    found (then errors are measured on the standard grid)."""
    from fitlab.errors import InputFileError
    from fitlab.report.inputs import load_data

    if data is None and fit_path is None:
        return None
    try:
        m, _ = load_data(dict(fit.record), Path(fit_path or "."), data)
    except InputFileError:
        if data is not None:
            raise
        return None
    return m


__all__ = ["THRESHOLDS", "Tradeoffs", "recommend", "tradeoffs"]
