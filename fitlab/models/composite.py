"""Sums of registry models: ``"lambertian+rough_conductor"`` is f = f_lambertian + f_rough_conductor,
the diffuse-plus-specular lobe pair measured surfaces usually need.

Parameter and option names are the components' own when they are unique across the sum; a name
two components share is prefixed with its component, ``component.name`` (e.g.
``lambertian.albedo`` and ``oren_nayar.albedo``). Sampling is a one-sample mixture: component
k is chosen with probability 1/K using u[2], whose remainder is rescaled to [0, 1) for the
component's own sampler; the pdf is the mixture pdf Σ pdf_k / K and the weight f|cos θo|/pdf.
"""

from __future__ import annotations

import functools
from collections import Counter

import jax.numpy as jnp

from fitlab.models.base import Model, Option, Parameter
from fitlab.numerics import safe_div

SEPARATOR = "+"


def _names(components, attr):
    counts = Counter(x.name for m in components for x in getattr(m, attr))
    return [[(x.name if counts[x.name] == 1 else f"{m.name}.{x.name}") for x in getattr(m, attr)]
            for m in components]


def make_sum(components: tuple[Model, ...]) -> Model:
    if len({m.name for m in components}) != len(components):
        raise ValueError("a sum of models cannot repeat a component: "
                         f"{SEPARATOR.join(m.name for m in components)}")
    pnames = _names(components, "parameters")
    onames = _names(components, "options")
    parameters = tuple(p._replace(name=n) for m, names in zip(components, pnames)
                       for p, n in zip(m.parameters, names))
    options = tuple(o._replace(name=n) for m, names in zip(components, onames)
                    for o, n in zip(m.options, names))
    K = len(components)

    def split(params, opts):
        for m, pn, on in zip(components, pnames, onames):
            yield (m, {p.name: params[n] for p, n in zip(m.parameters, pn)},
                   {o.name: opts[n] for o, n in zip(m.options, on) if n in opts})

    def eval(params, wi, wo, **opts):
        return sum(m.eval(p, wi, wo, **o) for m, p, o in split(params, opts))

    def pdf(params, wi, wo, **opts):
        return sum(m.pdf(p, wi, wo, **o) for m, p, o in split(params, opts)) / K

    def sample(params, wi, u, **opts):
        k_float = u[..., 2] * K
        k = jnp.clip(jnp.floor(k_float), 0, K - 1)
        u_k = jnp.concatenate([u[..., :2], (k_float - k)[..., None]], axis=-1)
        wo = None
        for j, (m, p, o) in enumerate(split(params, opts)):
            wo_j, _, _ = m.sample(p, wi, u_k, **o)
            wo = wo_j if wo is None else jnp.where((k == j)[..., None], wo_j, wo)
        p_mix = pdf(params, wi, wo, **opts)
        f = eval(params, wi, wo, **opts)
        weight = safe_div(f * jnp.abs(wo[..., 2]), p_mix)
        valid = p_mix > 0
        return wo, jnp.where(valid, weight, 0.0), jnp.where(valid, p_mix, 0.0)

    capabilities = functools.reduce(lambda a, b: a.combined(b),
                                    (m.capabilities for m in components))
    return Model(
        name=SEPARATOR.join(m.name for m in components),
        summary="sum of " + " and ".join(m.name for m in components),
        parameters=parameters,
        options=options,
        eval=eval,
        sample=sample,
        pdf=pdf,
        capabilities=capabilities,
        reference="; ".join(f"{m.name}: {m.reference}" for m in components)
        + "; one-sample mixture sampling with equal probabilities",
    )


__all__ = ["make_sum", "SEPARATOR", "Parameter", "Option"]
