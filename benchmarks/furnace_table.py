"""White-furnace table of the registry (issue 36, item 1): the directional albedo (mean sample
weight ± its standard error) of every model the registry contract covers
(``tests/models/test_model_contract.py``: the registry, every layered constructor over every
plain model it accepts, the layered examples), with default options, albedo parameters at their
upper bound and the worst of the contract's four furnace parameter sets (default, rough,
smooth, anisotropic), at θi = 0, 60, 85, 89 and 89.9° (φi = 10°), N_SAMPLES samples per row,
float64. One compiled call per model.

Run: ``python benchmarks/furnace_table.py [SUBSTRING ...]`` (only the models whose name holds
one of the substrings). The contract's limit is a mean of at most 1.01 with a standard error of
at most 0.003.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from fitlab._jax import jax

jax.config.update("jax_enable_x64", True)

THETAS = (0.0, 60.0, 85.0, 89.0, 89.9)
N_SAMPLES = 30_000
SETS = ("default", "rough", "smooth", "anisotropic")


def _clip(p, x):
    return float(min(max(x, p.lower), p.upper))


def parameter_set(model, name):
    """The contract's furnace sets (its PARAMETER_SETS), albedos at their upper bound."""
    out, k = {}, 0
    for p in model.parameters:
        v = p.default
        if p.role == "roughness":
            v = {"rough": p.upper, "smooth": p.lower,
                 "anisotropic": _clip(p, (0.03, 0.6)[k % 2])}.get(name, v)
            k += name == "anisotropic"
        elif p.role == "concentration":
            v = {"rough": p.lower, "smooth": p.upper}.get(name, v)
        elif p.role == "index" and name == "smooth":
            v = _clip(p, 1.5)
        if p.role == "albedo":
            v = p.upper
        out[p.name] = v
    return out


def names():
    from fitlab.models import CONSTRUCTORS, MODELS, get_model

    plain = [n for n in MODELS if "(" not in n]
    out = list(MODELS)
    for ctor in CONSTRUCTORS:
        for inner in plain:
            try:
                get_model(f"{ctor}({inner})")
            except ValueError:
                continue
            out.append(f"{ctor}({inner})")
    out += ["lambertian+rough_conductor", "coated(lambertian,specular=lobe)",
            "weidlich_wilkie(oren_nayar,layers=3)"]
    return list(dict.fromkeys(out))


def furnace(name, n=N_SAMPLES, thetas=THETAS, seed=11):
    """(mean, standard error) arrays of shape (len(SETS), len(thetas))."""
    from fitlab.models import get_model

    model = get_model(name)
    rows = [(s, t) for s in SETS for t in thetas]
    sets = {s: parameter_set(model, s) for s in SETS}
    params = {p.name: np.repeat([sets[s][p.name] for s, _ in rows], n) for p in model.parameters}
    t = np.radians([t for _, t in rows])
    wi = np.repeat(np.stack([np.sin(t) * np.cos(np.radians(10.0)),
                             np.sin(t) * np.sin(np.radians(10.0)), np.cos(t)], -1), n, axis=0)
    u = np.random.default_rng(seed).random((len(rows) * n, 3))
    w = np.asarray(jax.jit(lambda p, a, b: model.sample(p, a, b)[1])(params, wi, u))
    w = w.reshape(len(SETS), len(thetas), n)
    return w.mean(-1), w.std(-1) / np.sqrt(n)


def main(argv):
    from fitlab.models import get_model

    picked = [n for n in names() if not argv or any(a in n for a in argv)]
    print(f"# {N_SAMPLES:,} samples per row, float64; the worst of the sets {', '.join(SETS)}")
    print("| model | declared | " + " | ".join(f"θi = {t:g}°" for t in THETAS) + " |")
    print("|---|---|" + "---|" * len(THETAS))
    for name in picked:
        t0 = time.perf_counter()
        mean, se = furnace(name)
        worst = mean.argmax(axis=0)
        cells = [f"{mean[s, j]:.4f} ± {se[s, j]:.4f}" for j, s in enumerate(worst)]
        mark = "yes" if get_model(name).capabilities.energy_conserving else "no"
        print(f"| `{name}` | {mark} | " + " | ".join(cells) + f" |  <!-- {time.perf_counter() - t0:.0f} s -->",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
