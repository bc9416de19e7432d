"""The fit's parameter space: which parameters are free, their bounded transforms, and the
overall scale of relative data.

Each free parameter θ_k has bounds [lo, hi] from the model registry (or the data, for the scale)
and a unit-box coordinate u_k ∈ [0, 1]: linear, θ = lo + (hi - lo) u, or logarithmic,
θ = lo (hi/lo)^u, for positive parameters spanning two decades or more (α ∈ [1e-4, 1]).
The least-squares solver works in unconstrained z = logit(u), the global search and the MCMC
prior in u (a uniform prior over the bounds in that coordinate).

A FitSpace splits into a hashable static part (model, options, names, transforms: what the
compiled kernels depend on) and arrays (bounds, fixed values: arguments of those kernels), so
one compilation serves every dataset and every bound of the same shape.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.models import Model, get_model

SCALE = "scale"


class FreeParameter(NamedTuple):
    name: str
    lower: float
    upper: float
    log: bool
    unit: str


class StaticSpace(NamedTuple):
    """What a compiled kernel depends on (hashable). Holds the model object itself, so that
    kernels cached on it are never reused for a model redefined under the same name."""

    model: Model
    options: tuple  # sorted (name, value) pairs
    names: tuple[str, ...]  # free parameters in order, the scale last if relative
    log: tuple[bool, ...]
    fixed_names: tuple[str, ...]
    relative: bool

    @property
    def model_name(self) -> str:
        return self.model.name

    #: The kernels take any number of rows (least_squares.pad_rows pads them to a ladder).
    rows_fixed = False


class FitSpace(NamedTuple):
    static: StaticSpace
    free: tuple[FreeParameter, ...]
    fixed: dict  # name -> value (native units)

    @property
    def names(self) -> tuple[str, ...]:
        return self.static.names

    @property
    def ndim(self) -> int:
        return len(self.free)

    @property
    def relative(self) -> bool:
        return self.static.relative

    @property
    def model(self):
        return self.static.model

    @property
    def options(self) -> dict:
        return dict(self.static.options)

    def arrays(self) -> dict:
        """The kernels' array arguments: bounds and fixed values."""
        return {"lo": np.array([p.lower for p in self.free]),
                "hi": np.array([p.upper for p in self.free]),
                "fixed": {k: np.float64(v) for k, v in self.fixed.items()}}

    def to_native(self, u):
        """Unit-box coordinates (..., ndim) → native values, in NumPy (host side; the kernels use
        the module-level ``to_native``)."""
        u = np.asarray(u, dtype=float)
        out = np.empty_like(u)
        for k, p in enumerate(self.free):
            if p.log:
                out[..., k] = np.exp(np.log(p.lower) + (np.log(p.upper) - np.log(p.lower))
                                     * u[..., k])
            else:
                out[..., k] = p.lower + (p.upper - p.lower) * u[..., k]
        return out

    def to_unit(self, native):
        """Native values (..., ndim) → unit-box coordinates, clipped to [0, 1] (NumPy)."""
        return to_unit(self.static, native, np.array([p.lower for p in self.free]),
                       np.array([p.upper for p in self.free]))

    def predict(self, native, wi, wo):
        """scale · f(wi, wo) at native parameter values, as a NumPy array (one jitted call)."""
        params = dict(self.fixed)
        scale = 1.0
        for name, v in zip(self.names, np.asarray(native, dtype=float)):
            if name == SCALE:
                scale = float(v)
            else:
                params[name] = v
        f = model_values(self.static.model, self.static.options, params, wi, wo)
        return scale * f


def to_native(static: StaticSpace, u, lo, hi):
    """u (..., ndim) in [0,1] → native parameter values (..., ndim)."""
    is_log = jnp.asarray(static.log)
    lin = lo + (hi - lo) * u
    safe_lo = jnp.where(is_log, lo, 1.0)
    safe_hi = jnp.where(is_log, hi, 1.0)
    logv = jnp.exp(jnp.log(safe_lo) + (jnp.log(safe_hi) - jnp.log(safe_lo)) * u)
    return jnp.where(is_log, logv, lin)


def to_unit(static: StaticSpace, native, lo, hi) -> np.ndarray:
    """Native values (..., ndim) → unit-box coordinates in [0, 1], in NumPy, with bounds
    ``lo``, ``hi`` broadcasting against them (one dataset's, or one per dataset of a batch)."""
    native = np.asarray(native, dtype=float)
    lo, hi = np.broadcast_to(lo, native.shape), np.broadcast_to(hi, native.shape)
    out = np.empty_like(native)
    for k, log in enumerate(static.log):
        v = native[..., k]
        if log:
            out[..., k] = np.log(v / lo[..., k]) / np.log(hi[..., k] / lo[..., k])
        else:
            out[..., k] = (v - lo[..., k]) / (hi[..., k] - lo[..., k])
    return np.clip(out, 0.0, 1.0)


def predict(static: StaticSpace, theta, fixed: dict, wi, wo):
    """Model prediction scale · f(wi, wo) for one native parameter vector ``theta``."""
    if hasattr(static, "row_parameters"):  # one problem over channels (fitting/joint.py)
        params, scale = static.row_parameters(theta, fixed, wi)
        return scale * static.model.eval(params, wi, wo, **dict(static.options))
    params = dict(fixed)
    scale = 1.0
    for k, name in enumerate(static.names):
        if name == SCALE:
            scale = theta[k]
        else:
            params[name] = theta[k]
    return scale * static.model.eval(params, wi, wo, **dict(static.options))


@functools.lru_cache(maxsize=64)
def model_kernel(model: Model, options: tuple):
    """The model's ``eval(params, wi, wo)`` jitted for one set of options (sorted pairs), cached
    on the model object."""
    return jax.jit(functools.partial(model.eval, **dict(options)))


def model_values(model: Model | str, options: tuple, params: dict, wi, wo) -> np.ndarray:
    """f(wi, wo) for parameter values ``params`` (name -> number), in float64, as NumPy."""
    model = get_model(model) if isinstance(model, str) else model
    params = {k: np.float64(v) for k, v in params.items()}
    return np.asarray(model_kernel(model, tuple(options))(params, np.asarray(wi, float),
                                                           np.asarray(wo, float)))


def make_space(model, options: dict, fixed: dict, relative: bool,
               scale_bounds: tuple[float, float] | None = None) -> FitSpace:
    static, free = _space_parts(model, tuple(sorted(options.items())), tuple(sorted(fixed)),
                                bool(relative))
    if relative:
        lo, hi = scale_bounds
        free = free + (FreeParameter(SCALE, float(lo), float(hi), True, "data units per 1/sr"),)
    return FitSpace(static, free, dict(fixed))


@functools.lru_cache(maxsize=256)
def _space_parts(model, options: tuple, fixed_names: tuple, relative: bool):
    """(StaticSpace, the free parameters but a relative fit's scale) of :func:`make_space`:
    the same for every dataset of a batched fit, made once."""
    free = []
    for p in model.parameters:
        if p.name in fixed_names:
            continue
        log = p.lower > 0 and p.upper / p.lower >= 100.0
        free.append(FreeParameter(p.name, float(p.lower), float(p.upper), log, p.unit))
    if not free and not relative:
        raise ValueError("every parameter is fixed: nothing to fit")
    names = tuple(p.name for p in free) + ((SCALE,) if relative else ())
    logs = tuple(p.log for p in free) + ((True,) if relative else ())
    static = StaticSpace(model, options, names, logs, fixed_names, relative)
    return static, tuple(free)


def unit_from_z(z):
    return jax.nn.sigmoid(z)


def z_from_unit(u, eps=1e-9):
    u = np.clip(np.asarray(u, dtype=float), eps, 1.0 - eps)
    return np.log(u) - np.log1p(-u)
