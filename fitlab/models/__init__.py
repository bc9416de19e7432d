"""The model registry: every BSDF fitlab can evaluate, sample, fit and tabulate, by name."""

from __future__ import annotations

from fitlab.models import diffuse, rough_conductor, rough_dielectric
from fitlab.models.base import Model, Option, Parameter

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
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(
            f"unknown model {name!r}; run `fitlab models` to list them ({', '.join(MODELS)})"
        ) from None


__all__ = ["MODELS", "Model", "Option", "Parameter", "get_model"]
