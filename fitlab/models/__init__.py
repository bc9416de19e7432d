"""The model registry: every BSDF fitlab can evaluate, sample, fit and tabulate, by name.

A model declares what it is (``Model.capabilities``: lobes, isotropy, reciprocity, a delta
component left out of f; a role for each parameter); code that needs to know asks the model.
Adding a model is one file that defines a :class:`Model` and one line in ``_builtin`` below
(or, from outside the package, :func:`register_model`). See CONTRIBUTING.md.

The registries :data:`MODELS` and :data:`CONSTRUCTORS` are built at their first use (PEP 562:
``fitlab.models.MODELS``, :func:`get_model`), which imports every model's module; a submodule
(``fitlab.models.presets``, ``fitlab.models.base``) loads without them. No model needs JAX to be
built: JAX is imported when a model first computes (fitlab/_jax.py).
"""

from __future__ import annotations

import functools
import threading
from typing import Callable

from fitlab.models.base import ROLES, Capabilities, Model, Option, Parameter
from fitlab.models.composite import SEPARATOR, make_sum
from fitlab.models.syntax import parse_call, split_top_level
from fitlab.registry import Registry

_LOCK = threading.RLock()


def _builtin() -> tuple[Model, ...]:
    from fitlab.models import diffuse, gltf_pbr, openpbr, rough_conductor, rough_dielectric

    return (
        rough_dielectric.MODEL,
        rough_dielectric.ANISOTROPIC,
        rough_conductor.MODEL,
        rough_conductor.ANISOTROPIC,
        diffuse.LAMBERTIAN,
        diffuse.OREN_NAYAR,
        gltf_pbr.MODEL,
        gltf_pbr.CLEARCOAT_MODEL,
        gltf_pbr.ANISOTROPIC_MODEL,
        gltf_pbr.TRANSMISSION_MODEL,
        openpbr.MODEL,
    )


def _constructors() -> dict[str, Callable]:
    """Layered constructors, ``name(MODEL[,key=value])`` (syntax: fitlab/models/syntax.py)."""
    from fitlab.models import coated, spongecake, thin_layer, weidlich_wilkie

    return {coated.NAME: coated.from_call, weidlich_wilkie.NAME: weidlich_wilkie.from_call,
            thin_layer.NAME: thin_layer.from_call, spongecake.NAME: spongecake.from_call}


def _load() -> None:
    """Build MODELS (``Registry[Model]``: every registry model by name, the listed layered
    examples included) and CONSTRUCTORS (``Registry[Callable]``), once."""
    global MODELS, CONSTRUCTORS
    with _LOCK:
        if "MODELS" in globals():
            return
        CONSTRUCTORS = Registry("layered model", _constructors())
        MODELS = Registry("model", {m.name: m for m in _builtin()}, listing="`fitlab models`")
        _add_layered_examples()


def __getattr__(name):
    if name in ("MODELS", "CONSTRUCTORS"):
        _load()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Representative layered models, listed by ``fitlab models`` (any inner or base works by name).
LAYERED_EXAMPLES = ("coated(lambertian)", "coated(rough_conductor)", "weidlich_wilkie(lambertian)",
                    "weidlich_wilkie(oren_nayar)", "weidlich_wilkie(rough_conductor)",
                    "thin_layer(rough_conductor)", "thin_layer(rough_dielectric)",
                    "spongecake(surface)", "spongecake(fiber,surface)", "spongecake(hg)",
                    "spongecake(fiber_z,surface_z)", "spongecake(surface_z,substrate=lambertian)",
                    "spongecake(surface,multiple=lobe)", "spongecake(hg,multiple=only)",
                    "spongecake(surface_z,substrate=lambertian,multiple=lobe)",
                    "spongecake(fiber,multiple=learned)",
                    "spongecake(fiber,surface,multiple=learned)")


def get_model(name: str) -> Model:
    """A registry model by name; ``"a+b"`` is the sum of registry models a and b;
    ``coated(INNER)``, ``weidlich_wilkie(BASE[,layers=K])`` and
    ``thin_layer(BOTTOM[,roughness=kappa|alpha])`` and
    ``spongecake(LAYER[,LAYER...][,substrate=MODEL][,delta=true|false][,multiple=MODE])`` are
    layered models."""
    _load()
    parts = split_top_level(name, SEPARATOR)
    if len(parts) > 1:
        return _sum_of(tuple(get_model(n) for n in parts))
    name = parts[0]
    call = parse_call(name) if name not in MODELS else None
    if call is not None:
        if call.func not in CONSTRUCTORS:
            raise ValueError(f"unknown layered model {call.func!r} in {name!r}; use "
                             f"{', '.join(f'{c}(...)' for c in CONSTRUCTORS)}")
        return CONSTRUCTORS[call.func](call, get_model)
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(
            f"unknown model {name!r}; run `fitlab models` to list them ({', '.join(MODELS)}), "
            f"or sum them with '{SEPARATOR}' (e.g. lambertian+rough_conductor)"
        ) from None


@functools.lru_cache(maxsize=None)
def _sum_of(components: tuple[Model, ...]) -> Model:
    # keyed on the component models themselves: a re-registered component makes a new sum
    return make_sum(components)


def _add_layered_examples() -> None:
    _load()
    for name in LAYERED_EXAMPLES:
        MODELS.register(name, get_model(name), replace=True)


def variant_name(model: Model, key: str, value: str | None) -> str | None:
    """The name of ``model`` with its layered constructor's keyword ``key`` set to ``value``
    (None: left out), or None for a model no constructor made."""
    call = parse_call(model.name)
    if call is None:
        return None
    args = list(call.args) + [f"{k}={v}" for k, v in call.kwargs if k != key]
    if value is not None:
        args.append(f"{key}={value}")
    return f"{call.func}({','.join(args)})"


def register_model(model: Model, *, replace: bool = False) -> Model:
    """Add ``model`` to the registry under ``model.name`` (``replace=True`` to redefine one).

    Every cache of compiled kernels and derived models (sums, layered models) is keyed on the
    model object itself, so a redefined model is never served from code compiled for the old
    one; the listed layered examples are rebuilt from the new registry."""
    if not isinstance(model, Model):
        raise TypeError(f"register_model needs a fitlab.models.Model, got {type(model).__name__}")
    if any(ch in model.name for ch in f"(),{SEPARATOR}= "):
        raise ValueError(f"model name {model.name!r}: use letters, digits and '_' only")
    _load()
    for p in model.parameters:
        if p.role not in ROLES:
            raise ValueError(f"parameter {p.name} of {model.name!r} has unknown role "
                             f"{p.role!r}; roles: {', '.join(ROLES)}")
    MODELS.register(model.name, model, replace=replace)
    _add_layered_examples()
    return model


__all__ = ["MODELS", "Model", "Option", "Parameter", "Capabilities", "ROLES", "get_model",
           "register_model"]
