"""fitlab models: the registry's models with their parameters, bounds, units, options, presets
and sources, and the conventions they share. The models are built without JAX (their JAX is
imported when they first compute: fitlab/_jax.py), so this listing starts in a fraction of a
second."""

from __future__ import annotations

import json

from fitlab.cli.common import add_json, get_model
from fitlab.io.conventions import conventions_text
from fitlab.models.presets import CHANNELS, presets_of


def add_parser(sub):
    p = sub.add_parser("models", help="list the models with their parameters, bounds and conventions",
                       description="List every registry model: parameters (bounds, units), "
                       "options, source equations, and the conventions all models share.")
    p.add_argument("name", nargs="?", help="show only this model")
    add_json(p)
    return p


def _model_record(model, atlas=None):
    return {
        "name": model.name,
        "summary": model.summary,
        "lobes": model.lobes,
        "capabilities": {k: v for k, v in model.capabilities._asdict().items()},
        "parameters": [p._asdict() for p in model.parameters],
        "options": [{"name": o.name, "choices": list(o.choices), "default": o.default,
                     "description": o.description} for o in model.options],
        "reference": model.reference,
        "atlas": atlas,
    }


def _capabilities_text(c) -> str:
    words = [c.lobes, "isotropic" if c.isotropic else "anisotropic"]
    words += [w for w, on in (("reciprocal", c.reciprocal), ("lambertian", c.lambertian),
                              ("not energy conserving", not c.energy_conserving)) if on]
    if c.delta:
        words.append(f"delta left out of f: {c.delta}")
    return ", ".join(words)




def _atlas_line(a) -> str:
    """The validation atlas's entry of a layered model: where it is within 5% of the simulator
    and the page (a path in fitlab's source tree)."""
    held = ", ".join(f"{k}={v:g}" for k, v in a["fixed"].items())
    opts = ", ".join(f"{k}={v}" for k, v in a["options"].items())
    return (f"  atlas: within {a['threshold']:.0%} of the simulation of its stack: "
            f"{a['region']} (other parameters {held or 'typical'}"
            f"{'; options ' + opts if opts else ''}); {a['page']}")


def run(args):
    from fitlab.atlas.region import summary
    from fitlab.models import MODELS

    names = [args.name] if args.name else list(MODELS)
    models = [get_model(n) for n in names]
    atlas = {m.name: summary(m) for m in models}
    if args.json:
        print(json.dumps({"conventions": conventions_text(),
                          "models": [_model_record(m, atlas[m.name]) for m in models]},
                         indent=2))
        return 0
    print(f"Conventions: {conventions_text()}\n")
    if not args.name:
        print("Models add up with '+': e.g. lambertian+rough_conductor is f_lambertian + "
              "f_rough_conductor (`fitlab models lambertian+rough_conductor` lists its "
              "parameters).\n")
        print("Layered models take a model as argument: coated(INNER) puts any model (sums "
              "too) under a smooth dielectric coat, coated(INNER,specular=lobe) adds a narrow "
              "coat lobe; weidlich_wilkie(BASE[,layers=K]) stacks K-1 microfacet interfaces "
              "over any BRDF base (lambertian, oren_nayar, rough_conductor ...); "
              "thin_layer(rough_conductor|rough_dielectric) is a transparent layer between two "
              "rough vMF boundaries (Guo et al. 2015) (data_formats/layered_models.md). "
              "Where each is within 5% of the simulation of its own stack: `atlas:` below, "
              "reports/layered_atlas/README.md (`fitlab atlas`).\n")
    for m in models:
        print(f"{m.name}: {m.summary}  [{_capabilities_text(m.capabilities)}]")
        for p in m.parameters:
            print(f"  --param {p.name}=VALUE   {p.description}; bounds [{p.lower:g}, {p.upper:g}], "
                  f"unit {p.unit}, typical {p.default:g}, role {p.role}")
        for o in m.options:
            print(f"  --option {o.name}={'|'.join(o.choices)}   {o.description} "
                  f"(default {o.default})")
        for pr in presets_of(m):
            values = ", ".join(f"{k}={'/'.join(f'{x:g}' for x in v) if isinstance(v, tuple) else f'{v:g}'}"
                               for k, v in pr.params.items())
            print(f"  --preset {pr.name} --channel {'|'.join(CHANNELS)}   {values} "
                  f"({'/'.join(CHANNELS)})\n"
                  f"      {pr.description}")
        if atlas[m.name]:
            print(_atlas_line(atlas[m.name]))
        print(f"  source: {m.reference}\n")
    return 0
