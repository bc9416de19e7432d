"""Sums of registry models: ``"lambertian+rough_conductor"`` is f = f_lambertian + f_rough_conductor,
the diffuse-plus-specular lobe pair measured surfaces usually need.

Parameter and option names are the components' own when they are unique across the sum; a name
two components share is prefixed with its component, ``component.name`` (e.g.
``lambertian.albedo`` and ``oren_nayar.albedo``). Sampling is a one-sample mixture: component
k is chosen with probability 1/K using u[2], whose remainder is rescaled to [0, 1) for the
component's own sampler; the pdf is the mixture pdf Σ pdf_k / K and the weight f|cos θo|/pdf.

A sum may repeat a component (two GGX lobes: ``lambertian+rough_conductor+rough_conductor``).
The j-th occurrence (j ≥ 2) of a component suffixes each of its parameter and option names with
``_j`` before the rule above is applied: ``albedo, alpha, n, k`` (first lobe), ``alpha_2, n_2,
k_2`` (second), options ``distribution`` and ``distribution_2``. (Weidlich–Wilkie numbers its
layers without the underscore, ``alpha1``, ``alpha2``: the two schemes never collide.) The
repeated lobes are declared :class:`~fitlab.models.base.Exchangeable`: f is unchanged when their
values trade places, and the fitter reports the labelling in which the first lobe has the
smallest α (fitlab/fitting/exchange.py).
"""

from __future__ import annotations

import functools
from collections import Counter

from fitlab._jax import jnp
from fitlab.models.base import Exchangeable, Model, Option, Parameter, Term
from fitlab.numerics import safe_div

SEPARATOR = "+"


def occurrence_suffixes(components) -> list[str]:
    """"" for a component's first occurrence in the sum, "_j" for its j-th (j >= 2)."""
    seen = Counter()
    out = []
    for m in components:
        seen[m.name] += 1
        out.append("" if seen[m.name] == 1 else f"_{seen[m.name]}")
    return out


def _names(components, attr, suffixes):
    own = [[x.name + s for x in getattr(m, attr)] for m, s in zip(components, suffixes)]
    counts = Counter(n for names in own for n in names)
    out = [[(n if counts[n] == 1 else f"{m.name}.{n}") for n in names]
           for m, names in zip(components, own)]
    flat = [n for names in out for n in names]
    if len(set(flat)) != len(flat):
        dup = sorted(n for n, c in Counter(flat).items() if c > 1)
        raise ValueError(f"the sum {SEPARATOR.join(m.name for m in components)} would have two "
                         f"{attr} named {', '.join(dup)}; rename the registered model's "
                         f"{attr}")
    return out


def _exchangeable(components, pnames, onames) -> tuple[Exchangeable, ...]:
    """The repeated components (one Exchangeable per component that occurs more than once) and
    the components' own interchangeable lobes under their names in the sum."""
    out = []
    for m, pn, on in zip(components, pnames, onames):
        out += [e.renamed(dict(zip(m.parameter_names, pn)),
                          dict(zip((o.name for o in m.options), on))) for e in m.exchangeable]
    for name in dict.fromkeys(m.name for m in components):
        idx = [i for i, m in enumerate(components) if m.name == name]
        if len(idx) < 2:
            continue
        m = components[idx[0]]
        roles = [p.role for p in m.parameters]
        order_by = roles.index("roughness") if "roughness" in roles else 0
        if m.parameters:
            out.append(Exchangeable(tuple(tuple(pnames[i]) for i in idx),
                                    tuple(tuple(onames[i]) for i in idx), order_by))
    return tuple(out)


def sum_names(components) -> tuple[list[list[str]], list[list[str]]]:
    """The names of each component's parameters and options in the sum of ``components``
    (the rule of this module's docstring), component by component, in declaration order."""
    suffixes = occurrence_suffixes(components)
    return (_names(components, "parameters", suffixes),
            _names(components, "options", suffixes))


def make_sum(components: tuple[Model, ...]) -> Model:
    pnames, onames = sum_names(components)
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
        exchangeable=_exchangeable(components, pnames, onames),
        terms=tuple(Term(m, tuple(pn), tuple(on)) for m, pn, on in zip(components, pnames, onames)),
        reference="; ".join(f"{m.name}: {m.reference}" for m in components)
        + "; one-sample mixture sampling with equal probabilities",
    )


__all__ = ["make_sum", "sum_names", "occurrence_suffixes", "SEPARATOR", "Parameter", "Option"]
