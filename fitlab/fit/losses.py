"""Residuals for each loss; the fit minimizes ½ Σ r². Documented in data_formats/fit_json.md.

    chi2      r = (m - v) / σ                       needs sigma; a true χ²
    relative  r = (m - v) / max(|v|, floor)         floor = 1% of the channel's max |v|
    log       r = log(1 + m |cos θo|) - log(1 + v |cos θo|)   (compresses peaks)
    cos_l2    r = (m - v) |cos θo|                  cosine-weighted L2 (the reflected flux)

m is the model (scale · f), v the data (both f, in 1/sr or relative units). Only chi2 has
residuals in units of the data's own uncertainty; for the others the MCMC samples a noise
scale σ_r as a nuisance parameter (Jeffreys prior), so their posteriors are still calibrated
for homoscedastic residuals.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

LOSSES = ("chi2", "relative", "log", "cos_l2")


def loss_weights(loss: str, value, sigma, cos_o):
    """Per-row constants a residual needs (computed once, outside the JIT region)."""
    value = np.asarray(value, dtype=float)
    if loss == "chi2":
        if sigma is None:
            raise ValueError("the chi2 loss needs a sigma column in the data; "
                             "use --loss relative, log or cos_l2 for data without uncertainties")
        return {"w": 1.0 / np.asarray(sigma, dtype=float)}
    if loss == "relative":
        floor = 0.01 * np.max(np.abs(value)) if value.size else 1.0
        return {"w": 1.0 / np.maximum(np.abs(value), max(floor, 1e-300))}
    if loss == "log":
        c = np.abs(np.asarray(cos_o, dtype=float))
        return {"c": c, "log_v": np.log1p(np.maximum(value * c, -1 + 1e-12))}
    if loss == "cos_l2":
        return {"w": np.abs(np.asarray(cos_o, dtype=float))}
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def residuals(loss: str, model_value, value, consts):
    if loss == "log":
        return jnp.log1p(jnp.maximum(model_value * consts["c"], -1 + 1e-12)) - consts["log_v"]
    return (model_value - value) * consts["w"]


def has_absolute_noise(loss: str) -> bool:
    """True when residuals are already in units of the data's σ (no nuisance noise scale)."""
    return loss == "chi2"
