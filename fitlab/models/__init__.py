"""The model registry: every BSDF fitlab can evaluate, sample, fit and tabulate, by name."""

from __future__ import annotations

import functools

from fitlab.models import diffuse, rough_conductor, rough_dielectric
from fitlab.models.base import Model, Option, Parameter
from fitlab.models.composite import SEPARATOR, make_sum
from fitlab.models import coated, weidlich_wilkie  # noqa: E402  (layered: built from the above)
from fitlab.models.syntax import parse_call, split_top_level

MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        rough_dielectric.MODEL,
        rough_conductor.MODEL,
        diffuse.LAMBERTIAN,
        diffuse.OREN_NAYAR,
    )
}


#: Layered constructors, ``name(MODEL[,key=value])`` (syntax: fitlab/models/syntax.py).
CONSTRUCTORS = {coated.NAME: coated.from_call, weidlich_wilkie.NAME: weidlich_wilkie.from_call}


def get_model(name: str) -> Model:
    """A registry model by name; ``"a+b"`` is the sum of registry models a and b;
    ``coated(INNER)`` and ``weidlich_wilkie(BASE[,layers=K])`` are layered models."""
    parts = split_top_level(name, SEPARATOR)
    if len(parts) > 1:
        return _sum_of(tuple(parts))
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
def _sum_of(names: tuple[str, ...]) -> Model:
    return make_sum(tuple(get_model(n) for n in names))


#: Representative layered models, listed by ``fitlab models`` (any inner or base works by name).
for _name in ("coated(lambertian)", "coated(rough_conductor)", "weidlich_wilkie(lambertian)",
              "weidlich_wilkie(oren_nayar)", "weidlich_wilkie(rough_conductor)"):
    MODELS[_name] = get_model(_name)

__all__ = ["MODELS", "Model", "Option", "Parameter", "get_model"]
