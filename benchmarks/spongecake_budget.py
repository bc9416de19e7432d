"""What the energy budget of SpongeCake's multiple-scattering approximation costs (issue 36,
item 1; data_formats/layered_models.md): the time of one evaluation, and of its gradient, of
every ``multiple=`` model of the registry contract at 2,000 random direction pairs with one
parameter set (the registry's defaults), float64, jitted, best of 5, and the time to compile
them.

Peer, in the same run: the paper's sum without the budget (the exact single scattering plus
:func:`fitlab.models.spongecake_multiple.approximation`), whose values the model equals wherever
the approximation fits within the energy that arrives; the ratio is printed.

Run: ``python benchmarks/spongecake_budget.py``.
"""

from __future__ import annotations

import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

from fitlab.models import get_model  # noqa: E402
from fitlab.models.spongecake_multiple import approximation  # noqa: E402

NAMES = ("spongecake(surface,multiple=lobe)", "spongecake(fiber,surface,multiple=lobe)",
         "spongecake(surface_z,substrate=lambertian,multiple=lobe)",
         "spongecake(hg,multiple=only)", "spongecake(fiber,multiple=learned)",
         "spongecake(fiber,surface,multiple=learned)")
PAIRS = 2000


def _pairs(n=PAIRS, seed=0):
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wo = rng.normal(size=(n, 3))
    return (jnp.asarray(wi / np.linalg.norm(wi, axis=1, keepdims=True)),
            jnp.asarray(wo / np.linalg.norm(wo, axis=1, keepdims=True)))


def _timed(fn, *args, repeat=5):
    """(first call's seconds, compile included; best of ``repeat`` warm calls)."""
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return first, best


def peer(name):
    """The paper's sum for ``name``: f_ss(p) [+ substrate] + §5's approximation (for
    ``multiple=only``, the approximation alone; for ``multiple=learned``, at the network's
    lobe, which the model computes inside)."""
    model = get_model(name)
    kinds = name[len("spongecake("):].split(",multiple=")[0]
    plain = [k for k in kinds.split(",") if not k.startswith("substrate=")]
    stack = get_model(f"spongecake({','.join(plain)},delta=false)")
    only = "multiple=only" in name
    base = None if only else get_model(f"spongecake({kinds})")
    transmits = "substrate=" not in kinds
    if "multiple=learned" in name:
        return None  # its lobe parameters come from the network inside the model
    return lambda p, wi, wo: (
        approximation(stack, p, wi, wo, transmits, above_only=not transmits)
        + (0.0 if base is None else base.eval({k: p[k] for k in base.parameter_names}, wi, wo)))


def main():
    wi, wo = _pairs()
    print(f"# {PAIRS:,} direction pairs, one parameter set, float64; ms per call (best of 5), "
          "compile+first call in s")
    print("| model | eval ms | gradient ms | compile eval s | compile gradient s | "
          "the paper's sum ms | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in NAMES:
        model = get_model(name)
        p = {q.name: jnp.float64(q.default) for q in model.parameters}
        ev = jax.jit(model.eval)
        gr = jax.jit(jax.grad(lambda q: jnp.sum(model.eval(q, wi, wo))))
        c_e, t_e = _timed(ev, p, wi, wo)
        c_g, t_g = _timed(gr, p)
        fn = peer(name)
        if fn is None:
            peer_cell, ratio = "(network inside)", ""
        else:
            _, t_p = _timed(jax.jit(fn), p, wi, wo)
            peer_cell, ratio = f"{t_p * 1e3:.2f}", f"{t_e / t_p:.0f}x"
        print(f"| `{name}` | {t_e * 1e3:.2f} | {t_g * 1e3:.2f} | {c_e:.2f} | {c_g:.2f} | "
              f"{peer_cell} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
