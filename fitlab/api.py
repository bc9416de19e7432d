"""Stable functional entry points for scripts: evaluate, sample and pdf any registry model.

One JIT region per (model, options): the whole model is compiled as one XLA computation.
Directions are arrays of unit vectors of shape (..., 3) in the local frame (normal = +z,
directions pointing away from the surface); parameter values broadcast against their leading
shape and are cast to the directions' dtype, so float32 directions give a float32 evaluation.
"""

from __future__ import annotations

import functools
import numbers

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.models import Model, get_model


def resolve_options(model: Model, options: dict | None) -> dict:
    """The model's default options updated with ``options``; unknown names or values raise."""
    resolved = model.default_options()
    for name, value in (options or {}).items():
        declared = {o.name: o for o in model.options}
        if name not in declared:
            known = ", ".join(declared) or "none"
            raise ValueError(f"model {model.name!r} has no option {name!r} (options: {known})")
        if value not in declared[name].choices:
            raise ValueError(
                f"option {name}={value!r} of model {model.name!r} must be one of "
                f"{', '.join(declared[name].choices)}"
            )
        resolved[name] = value
    return resolved


def check_params(model: Model, params: dict) -> None:
    """Every declared parameter present, no unknown ones, concrete values inside their bounds."""
    names = set(model.parameter_names)
    unknown = sorted(set(params) - names)
    if unknown:
        raise ValueError(
            f"model {model.name!r} has no parameter {', '.join(map(repr, unknown))}; "
            f"its parameters are {', '.join(model.parameter_names)}"
        )
    missing = [p for p in model.parameters if p.name not in params]
    if missing:
        need = "; ".join(f"{p.name} in [{p.lower:g}, {p.upper:g}] {p.unit}" for p in missing)
        raise ValueError(f"model {model.name!r} needs values for: {need}")
    for p in model.parameters:
        value = params[p.name]
        if isinstance(value, jax.core.Tracer):
            continue  # under jit/grad: bounds are the caller's business (the fitter transforms them)
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"parameter {p.name} of {model.name!r} must be finite, got {value!r}")
        if np.any(arr < p.lower) or np.any(arr > p.upper):
            raise ValueError(
                f"parameter {p.name}={value!r} of {model.name!r} is outside its bounds "
                f"[{p.lower:g}, {p.upper:g}] ({p.description}); choose a value inside them"
            )


@functools.lru_cache(maxsize=256)
def _jitted(model: Model, which: str, options: tuple):
    """One compiled function per (model, eval|sample|pdf, options), keyed on the model object
    itself: a model redefined with ``fitlab.register_model`` gets fresh code."""
    return jax.jit(functools.partial(getattr(model, which), **dict(options)))


def _prepare(model_name, params, options, *dirs):
    model = get_model(model_name)
    opts = resolve_options(model, options)
    check_params(model, params)
    dirs = [d if isinstance(d, jax.Array) else jnp.asarray(d) for d in dirs]
    dtype = jnp.result_type(*dirs)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    dirs = [d if d.dtype == dtype else d.astype(dtype) for d in dirs]
    for d in dirs:
        if d.shape[-1:] != (3,):
            raise ValueError(f"directions must have shape (..., 3), got {d.shape}")
    # Host values stay NumPy: the jitted call transfers them with the arguments (a jnp.asarray
    # each would be a separate device transfer, about as long as evaluating 10^5 pairs).
    cast = {
        k: np.asarray(v, dtype=dtype) if isinstance(v, (numbers.Number, np.ndarray, np.generic))
        else jnp.asarray(v, dtype=dtype)
        for k, v in params.items()
    }
    return model, tuple(sorted(opts.items())), cast, dirs


def eval_bsdf(model_name: str, params: dict, wi, wo, options: dict | None = None):
    """The BSDF f(wi, wo) in 1/sr, without the cosine, of a registry model.

    >>> eval_bsdf("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, wi, wo)  # doctest: +SKIP
    """
    model, opts, p, (wi, wo) = _prepare(model_name, params, options, wi, wo)
    return _jitted(model, "eval", opts)(p, wi, wo)


def pdf_bsdf(model_name: str, params: dict, wi, wo, options: dict | None = None):
    """Solid-angle density (1/sr) with which :func:`sample_bsdf` generates wo given wi."""
    model, opts, p, (wi, wo) = _prepare(model_name, params, options, wi, wo)
    return _jitted(model, "pdf", opts)(p, wi, wo)


def sample_bsdf(model_name: str, params: dict, wi, u, options: dict | None = None):
    """Importance-sample wo given wi from uniforms u (..., 3) in [0, 1).

    Returns (wo, weight, pdf) with weight = f(wi, wo)|cos θo| / pdf (Walter eq. 37); invalid
    samples have weight 0 and pdf 0."""
    if isinstance(u, numbers.Integral):
        raise TypeError("u must be an array of uniforms of shape (..., 3)")
    model, opts, p, (wi,) = _prepare(model_name, params, options, wi)
    u = jnp.asarray(u, dtype=wi.dtype)
    if u.shape[-1:] != (3,):
        raise ValueError(f"u must have shape (..., 3), got {u.shape}")
    return _jitted(model, "sample", opts)(p, wi, u)
