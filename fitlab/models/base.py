"""What every registry model declares: parameters with bounds and units, static options, and
the three pure functions eval / sample / pdf.

Signatures (all batched over any leading shape; ``params`` is a dict of arrays that broadcast
against the directions' leading shape)::

    eval(params, wi, wo, **options)  -> f            BSDF in 1/sr, without the cosine
    pdf(params, wi, wo, **options)   -> p            solid-angle density of ``sample``'s wo
    sample(params, wi, u, **options) -> (wo, weight, pdf)
        u: (..., 3) uniforms in [0, 1); weight = f(wi, wo)|cos θo| / pdf (Walter eq. 37),
        0 for an invalid sample (its wo is then meaningless but finite).
"""

from __future__ import annotations

from typing import Callable, NamedTuple


class Parameter(NamedTuple):
    name: str
    lower: float
    upper: float
    default: float
    unit: str
    description: str


class Option(NamedTuple):
    name: str
    choices: tuple
    default: str
    description: str


class Model(NamedTuple):
    name: str
    summary: str
    parameters: tuple[Parameter, ...]
    options: tuple[Option, ...]
    eval: Callable
    sample: Callable
    pdf: Callable
    #: which side(s) of the surface the model scatters to: "reflection" or "reflection+transmission"
    lobes: str
    #: free text: which equations, which conventions (shown by ``fitlab models``)
    reference: str

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def default_options(self) -> dict:
        return {o.name: o.default for o in self.options}
