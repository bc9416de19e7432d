"""Residuals for each loss; the fit minimizes ½ Σ r². Documented in data_formats/fit_json.md.

    chi2      r = (m - v) / σ                       needs sigma; a true χ²
    relative  r = (m - v) / max(|v|, floor)         floor = 1% of the channel's max |v|
    log       r = log(1 + m |cos θo|) - log(1 + v |cos θo|)   (compresses peaks)
    cos_l2    r = (m - v) |cos θo|                  cosine-weighted L2 (the reflected flux)

m is the model (scale · f), v the data (both f, in 1/sr or relative units). Only chi2 has
residuals in units of the data's own uncertainty; for the others the MCMC samples a noise
scale σ_r as a nuisance parameter (Jeffreys prior), so their posteriors are still calibrated
for homoscedastic residuals.

Each loss is one entry of the registry :data:`LOSSES`: its per-row constants (``weights``,
computed once in NumPy outside the JIT region), its residual (``residual``, traced by JAX) and
whether its residuals are in units of the data's σ (``absolute_noise``). The fitter and the CLI
(``--loss`` choices and help) ask the registry, never a loss's name.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab._jax import jnp
from fitlab.registry import Registry


class Loss(NamedTuple):
    """One loss: what it is, the constants its residual needs and the residual itself."""

    name: str
    description: str  # one line, for --help and the docs
    weights: Callable  # (value, sigma, cos_o) -> dict of per-row NumPy arrays
    residual: Callable  # (model_value, value, consts) -> r (JAX arrays)
    absolute_noise: bool  # residuals already in units of the data's σ (no nuisance scale)
    #: the residual is (m - v) · w with w the constant "w": the cost ½ Σ w² (m - v)² is then a
    #: quadratic form in m, which the batched scan evaluates by matrix products
    #: (fitlab.fitting.batch ``shared_scan_costs``)
    weighted: bool = False


def _weighted_residual(model_value, value, consts):
    return (model_value - value) * consts["w"]


def _chi2_weights(value, sigma, cos_o):
    if sigma is None:
        raise ValueError("the chi2 loss needs a sigma column in the data; "
                         "use --loss relative, log or cos_l2 for data without uncertainties")
    return {"w": 1.0 / np.asarray(sigma, dtype=float)}


def _relative_weights(value, sigma, cos_o):
    # the floor of each dataset: rows on the last axis
    floor = (0.01 * np.max(np.abs(value), axis=-1, keepdims=True) if value.shape[-1]
             else np.ones(value.shape[:-1] + (1,)))
    return {"w": 1.0 / np.maximum(np.abs(value), np.maximum(floor, 1e-300))}


def _log_weights(value, sigma, cos_o):
    c = np.abs(np.asarray(cos_o, dtype=float))
    return {"c": c, "log_v": np.log1p(np.maximum(value * c, -1 + 1e-12))}


def _log_residual(model_value, value, consts):
    return jnp.log1p(jnp.maximum(model_value * consts["c"], -1 + 1e-12)) - consts["log_v"]


def _cos_l2_weights(value, sigma, cos_o):
    return {"w": np.abs(np.asarray(cos_o, dtype=float))}


#: The losses, by name (the order is the CLI's order of choices; chi2 and relative are the
#: defaults with and without sigma).
LOSSES: Registry[Loss] = Registry("loss", {
    loss.name: loss for loss in (
        Loss("chi2", "(m - v)/sigma: data with absolute uncertainties, a true chi-square",
             _chi2_weights, _weighted_residual, True, True),
        Loss("relative", "(m - v)/max(|v|, 1% of max |v|): multiplicative noise",
             _relative_weights, _weighted_residual, False, True),
        Loss("log", "log(1 + m|cos theta_o|) - log(1 + v|cos theta_o|): compresses peaks",
             _log_weights, _log_residual, False),
        Loss("cos_l2", "(m - v)|cos theta_o|: cosine-weighted L2 (the reflected flux)",
             _cos_l2_weights, _weighted_residual, False, True),
    )
})


def get_loss(name: str) -> Loss:
    return LOSSES.get_entry(name)


def loss_weights(loss: str, value, sigma, cos_o):
    """Per-row constants a residual needs (computed once, outside the JIT region). ``value``
    (and ``sigma``) may hold many datasets on the same rows, the rows on the last axis
    (``cos_o`` then broadcasts against them): the constants of each, at once."""
    entry = get_loss(loss)
    return entry.weights(np.asarray(value, dtype=float), sigma, cos_o)


def residuals(loss: str, model_value, value, consts):
    return get_loss(loss).residual(model_value, value, consts)


def is_weighted(loss: str) -> bool:
    """True when the residual is (m - v) · w (the constant ``w``): :attr:`Loss.weighted`."""
    return get_loss(loss).weighted


def has_absolute_noise(loss: str) -> bool:
    """True when residuals are already in units of the data's σ (no nuisance noise scale)."""
    return get_loss(loss).absolute_noise
