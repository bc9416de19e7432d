"""The model registry: every BSDF fitlab can evaluate, sample, fit and tabulate, by name."""

from __future__ import annotations

import functools

from fitlab.models import diffuse, rough_conductor, rough_dielectric
from fitlab.models.base import Model, Option, Parameter
from fitlab.models.composite import SEPARATOR, make_sum

MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        rough_dielectric.MODEL,
        rough_conductor.MODEL,
        diffuse.LAMBERTIAN,
        diffuse.OREN_NAYAR,
    )
}


def get_model(name: str) -> Model:
    """A registry model by name; ``"a+b"`` is the sum of registry models a and b."""
    if SEPARATOR in name:
        return _sum_of(tuple(part.strip() for part in name.split(SEPARATOR)))
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


__all__ = ["MODELS", "Model", "Option", "Parameter", "get_model"]
