"""What every knob of ``fitlab tradeoffs`` shares: the material and the directions it is scored
on (:class:`Context`), one measured setting (:class:`Variant`), scoring an evaluator against
the reference in the quantities a user sees (:func:`score`), and timing (:func:`seconds`).

Errors are measured on the **measured directions** (the rows of the fit's data file, when the
material comes from a fit whose data file is found) or else on the standard hemisphere grid of
the glTF conversion (``fitlab.export.gltf_material.conversion_pairs``): relative RMS and
largest relative error of f·|cos θo| (values below ``ERROR_FLOOR`` of a channel's peak left
out), the largest albedo difference at θi = 0, 30, 60, 80° (deterministic quadrature, so two
evaluators compare without sampling noise), and the smallest PSNR and SSIM of the lobe images at
θi = 0, 30, 60° (scikit-image).
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple

import numpy as np

from fitlab.lobe_metrics import (ERROR_FLOOR, albedo_quadrature, image_errors, lobe_image,
                                 model_evaluator, relative_errors)

#: Incidences of the albedo comparison and of the lobe images (degrees).
ALBEDO_THETA = (0.0, 30.0, 60.0, 80.0)
IMAGE_THETA = (0.0, 30.0, 60.0)
#: Gauss–Legendre order of the albedo quadrature used for scoring (the quadrature knob shows
#: what lower orders cost).
ALBEDO_ORDER = 128
#: Direction pairs per timed evaluation.
TIMING_PAIRS = 100_000


class Variant(NamedTuple):
    """One measured setting of a knob."""

    knob: str  # e.g. "precision"
    group: str  # evaluation | layered physics | tables | monte carlo
    setting: str  # e.g. "float32"
    reference: str  # what the errors are measured against
    errors: dict  # f_rel_rms, f_rel_max, albedo_abs_max, psnr_db, ssim, ... (None: not measured)
    seconds: float  # measured time, per ``time_unit``
    time_unit: str  # "per 1e5 evaluations", "per bake", "per fit", ...
    cost: dict = {}  # other costs: table bytes, samples, steps
    current: bool = False  # the material's own setting
    note: str = ""

    def as_dict(self) -> dict:
        return {"knob": self.knob, "group": self.group, "setting": self.setting,
                "reference": self.reference, "errors": self.errors,
                "seconds": self.seconds, "time_unit": self.time_unit, "cost": self.cost,
                "current": self.current, "note": self.note}


class NotApplicable(Exception):
    """A knob that does not apply to this material; the message says why."""


class Context(NamedTuple):
    """The material and what scoring needs, computed once per run."""

    material: object  # fitlab.export.material.Material
    model: object  # its registry Model
    wi: np.ndarray  # (N, 3) direction pairs errors are measured on
    wo: np.ndarray
    directions: str  # where those pairs come from
    fit: object | None  # the FitResult, when the material is a fit
    data: object | None  # its Measurement, when the data file was found
    seed: int
    quick: bool
    progress: Callable  # progress(message)
    cache: dict  # reference values by key

    @property
    def transmission(self) -> bool:
        return bool(self.model.capabilities.transmission)

    def evaluator(self, model=None, options=None, channels=None, dtype=np.float64):
        m = self.material
        return model_evaluator(model or m.model, channels or m.channels,
                               m.options if options is None else options, dtype)


def seconds(fn, *, repeat: int = 3, min_total: float = 0.05) -> float:
    """The best of ``repeat`` timings of ``fn()`` after a warm-up call (compilation excluded);
    fast calls are looped until ``min_total`` seconds so the clock's resolution does not
    matter."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_total or n >= 1000:
                break
        best = min(best, dt / n)
    return best


def timing_pairs(transmission: bool, n: int = TIMING_PAIRS, seed: int = 11):
    """(wi, wo) random pairs over the hemisphere(s) for timing an evaluation."""
    rng = np.random.default_rng(seed)

    def hemi(k, lower=False):
        u = rng.random((k, 2))
        z = u[:, 0]
        s = np.sqrt(1 - z * z)
        d = np.stack([s * np.cos(2 * np.pi * u[:, 1]), s * np.sin(2 * np.pi * u[:, 1]), z], -1)
        if lower:
            d[:, 2] = -d[:, 2]
        return d
    wi = hemi(n)
    wo = hemi(n)
    if transmission:
        wo[n // 2:, 2] = -wo[n // 2:, 2]
    return wi, wo


def evaluation_seconds(evaluate, transmission: bool, dtype=np.float64) -> float:
    """Seconds per :data:`TIMING_PAIRS` evaluations (every channel) of ``evaluate``."""
    wi, wo = timing_pairs(transmission)
    wi, wo = wi.astype(dtype), wo.astype(dtype)
    return seconds(lambda: evaluate(wi, wo), repeat=3)


def standard_pairs(model):
    """The standard hemisphere grid of the glTF conversion (both sides for a transmitting
    model), without pairs in the surface plane, and its description."""
    from fitlab.export.gltf_material import conversion_pairs

    wi, wo = conversion_pairs(isotropic=model.capabilities.isotropic,
                              transmission=model.capabilities.transmission)
    keep = wo[:, 2] != 0
    return wi[keep], wo[keep], (
        f"{int(keep.sum())} pairs of the standard hemisphere grid (θi = 0, 15, 30, 45, 60, 75, "
        "85°; θo, φo every 5° × 10° and rings around the mirror direction)")


def with_reflection(ctx: Context) -> Context:
    """``ctx``, or, when its pairs hold no reflection, the same on the standard grid."""
    if np.any((ctx.wi[:, 2] > 0) & (ctx.wo[:, 2] > 0)):
        return ctx
    wi, wo, where = standard_pairs(ctx.model)
    return ctx._replace(wi=wi, wo=wo, directions=where + " (the measured directions hold no "
                        "reflection)", cache={})


def _reference(ctx: Context, key, make):
    if key not in ctx.cache:
        ctx.cache[key] = make()
    return ctx.cache[key]


def reference_values(ctx: Context, evaluate, key, reflection_only: bool = False) -> dict:
    """The reference's values on the scoring pairs, albedos and lobe images (cached by key)."""
    def make():
        wi, wo = pairs(ctx, reflection_only)
        return {"f": evaluate(wi, wo),
                "albedo": {t: albedo_quadrature(evaluate, t, ALBEDO_ORDER,
                                                ctx.transmission and not reflection_only)
                           for t in ALBEDO_THETA},
                "images": {t: lobe_image(evaluate, t) for t in IMAGE_THETA}}
    return _reference(ctx, (key, reflection_only), make)


def pairs(ctx: Context, reflection_only: bool = False):
    if not reflection_only:
        return ctx.wi, ctx.wo
    keep = (ctx.wi[:, 2] > 0) & (ctx.wo[:, 2] > 0)
    return ctx.wi[keep], ctx.wo[keep]


def score(ctx: Context, evaluate, ref: dict, reflection_only: bool = False) -> dict:
    """Errors of ``evaluate`` against the reference values ``ref`` (:func:`reference_values`)."""
    wi, wo = pairs(ctx, reflection_only)
    err = relative_errors(ref["f"], evaluate(wi, wo), wo[:, 2], ERROR_FLOOR)
    alb_abs, alb_rel = 0.0, 0.0
    for t in ALBEDO_THETA:
        a = ref["albedo"][t]
        b = albedo_quadrature(evaluate, t, ALBEDO_ORDER, ctx.transmission and not reflection_only)
        alb_abs = max(alb_abs, float(np.max(np.abs(b - a))))
        alb_rel = max(alb_rel, float(np.max(np.abs(b - a) / np.maximum(np.abs(a), 1e-12))))
    psnr, ssim = None, 1.0
    for t in IMAGE_THETA:
        im = image_errors(ref["images"][t], lobe_image(evaluate, t))
        if im["psnr_db"] is not None:
            psnr = im["psnr_db"] if psnr is None else min(psnr, im["psnr_db"])
        ssim = min(ssim, im["ssim"])
    return {"f_rel_rms": err["relative_rms"], "f_rel_max": err["relative_max"],
            "albedo_abs_max": alb_abs, "albedo_rel_max": alb_rel, "psnr_db": psnr,
            "ssim": ssim}


__all__ = ["ALBEDO_ORDER", "ALBEDO_THETA", "Context", "IMAGE_THETA", "NotApplicable",
           "TIMING_PAIRS", "Variant", "evaluation_seconds", "pairs", "reference_values",
           "score", "seconds", "timing_pairs"]
