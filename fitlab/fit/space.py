"""The fit's parameter space: which parameters are free, their bounded transforms, and the
overall scale of relative data.

Each free parameter θ_k has bounds [lo, hi] from the model registry (or the data, for the scale)
and a unit-box coordinate u_k ∈ [0, 1]: linear, θ = lo + (hi - lo) u, or logarithmic,
θ = lo (hi/lo)^u, for positive parameters spanning two decades or more (α ∈ [1e-4, 1]).
The least-squares solver works in unconstrained z = logit(u), the global search and the MCMC
prior in u (a uniform prior over the bounds in that coordinate).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fitlab.models import Model

SCALE = "scale"


class FreeParameter(NamedTuple):
    name: str
    lower: float
    upper: float
    log: bool
    unit: str


class FitSpace(NamedTuple):
    model: Model
    options: dict
    free: tuple[FreeParameter, ...]
    fixed: dict  # name -> value (native units)
    relative: bool  # a free overall scale multiplies the model

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.free)

    @property
    def ndim(self) -> int:
        return len(self.free)

    def to_native(self, u):
        """u (..., ndim) in [0,1] → native parameter values (..., ndim)."""
        lo = jnp.asarray([p.lower for p in self.free])
        hi = jnp.asarray([p.upper for p in self.free])
        is_log = jnp.asarray([p.log for p in self.free])
        lin = lo + (hi - lo) * u
        safe_lo = jnp.where(is_log, lo, 1.0)
        safe_hi = jnp.where(is_log, hi, 1.0)
        logv = jnp.exp(jnp.log(safe_lo) + (jnp.log(safe_hi) - jnp.log(safe_lo)) * u)
        return jnp.where(is_log, logv, lin)

    def to_unit(self, native):
        native = np.asarray(native, dtype=float)
        out = np.empty_like(native)
        for k, p in enumerate(self.free):
            v = native[..., k]
            if p.log:
                out[..., k] = np.log(v / p.lower) / np.log(p.upper / p.lower)
            else:
                out[..., k] = (v - p.lower) / (p.upper - p.lower)
        return np.clip(out, 0.0, 1.0)

    def params_dict(self, native):
        """Model parameter dict (without the scale) from a native vector (..., ndim)."""
        d = {k: v for k, v in self.fixed.items()}
        for k, p in enumerate(self.free):
            if p.name != SCALE:
                d[p.name] = native[..., k]
        return d

    def scale_of(self, native):
        if not self.relative:
            return 1.0
        return native[..., self.names.index(SCALE)]

    def predict(self, native, wi, wo):
        """Model prediction for one native parameter vector: scale · f(wi, wo)."""
        f = self.model.eval(self.params_dict(native), wi, wo, **self.options)
        return self.scale_of(native) * f


def make_space(model: Model, options: dict, fixed: dict, relative: bool,
               scale_bounds: tuple[float, float] | None = None) -> FitSpace:
    free = []
    for p in model.parameters:
        if p.name in fixed:
            continue
        log = p.lower > 0 and p.upper / p.lower >= 100.0
        free.append(FreeParameter(p.name, float(p.lower), float(p.upper), log, p.unit))
    if relative:
        lo, hi = scale_bounds
        free.append(FreeParameter(SCALE, float(lo), float(hi), True, "data units per 1/sr"))
    if not free:
        raise ValueError("every parameter is fixed: nothing to fit")
    return FitSpace(model, dict(options), tuple(free), dict(fixed), relative)


def unit_from_z(z):
    return jax.nn.sigmoid(z)


def z_from_unit(u, eps=1e-9):
    u = np.clip(np.asarray(u, dtype=float), eps, 1.0 - eps)
    return np.log(u) - np.log1p(-u)
