"""Interchangeable lobes in a fit: one labelling of a sum that repeats a component.

``lambertian+rough_conductor+rough_conductor`` gives the same f when the two conductor lobes
trade places (``alpha, n, k`` ↔ ``alpha_2, n_2, k_2``): its cost has two equal optima and its
posterior two mirror-image modes (label switching). The model declares such lobes
(``Model.exchangeable``, fitlab/models/base.py); the fit keeps one labelling, **the lobes
ordered by their ordering value, ascending** (the first roughness parameter: lobe 1 is the
narrowest, α ≤ α_2 ≤ α_3 ...):

* least squares: every Levenberg–Marquardt end is relabelled before the starts are compared, so
  two starts that found the same lobes under swapped names agree, and the reported values,
  standard errors and covariance are those of the ordered labelling (an exact symmetry of the
  cost: nothing is approximated);
* MCMC: the prior is the uniform box restricted to the ordered region (u_α ≤ u_α2 in the
  unit-box coordinate, the same order as α ≤ α_2 because the lobes' bounds and transforms are
  equal), the walkers start relabelled into it. The posterior of the ordered labelling is the
  symmetric posterior folded once: nothing is lost, and the chain cannot switch labels.

Lobes are interchangeable in a fit only where the swap is a symmetry of the fit as posed:
corresponding parameters free in both lobes or fixed at equal values in both (``--fix k=0 --fix
k_2=0`` keeps the lobes interchangeable, ``--fix alpha_2=0.3`` alone tells them apart), the
lobes' options equal (``distribution`` and ``distribution_2`` both ggx), their bounds equal,
and, in a joint fit over channels (fitlab/fitting/joint.py), corresponding parameters shared
alike. The ordering value is the declared one (the lobe's first roughness parameter) if it is
free, else the lobe's first free parameter. A lobe set whose lobes are all per-channel is ordered in each channel separately; one
with a shared parameter is ordered once for all channels, by its ordering value in the first
channel (shared, if the ordering value itself is shared).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab._jax import jnp


class Swap(NamedTuple):
    """Lobes that may trade places, as coordinates of the fit's free vector."""

    blocks: tuple[tuple[int, ...], ...]  # per lobe: its coordinates, in corresponding order
    keys: tuple[int, ...]  # per lobe: the coordinate of its ordering value


def _coordinates(static, name) -> tuple:
    """The free-vector coordinate of ``name`` in each channel of the fit (None if fixed)."""
    if hasattr(static, "coordinates"):  # a joint space over channels
        return static.coordinates(name)
    return (static.names.index(name) if name in static.names else None,)


def swaps(static, fixed: dict) -> tuple[Swap, ...]:
    """The Swaps of a fit: its static structure (StaticSpace or a joint space) and its fixed
    values (a lobe parameter fixed in every lobe at equal values does not tell them apart)."""
    model = static.model
    options = dict(static.options)
    out = []
    for ex in model.exchangeable:
        groups = {}
        for params, opts in zip(ex.parameters, ex.options):
            coords = [_coordinates(static, n) for n in params]
            if any((None in c) and any(i is not None for i in c) for c in coords):
                continue
            is_free = tuple(None not in c for c in coords)
            if not any(is_free):
                continue
            signature = (tuple(options.get(o) for o in opts), is_free,
                         tuple(None if f else float(fixed[n]) for n, f in zip(params, is_free)),
                         tuple((model.parameter(n).lower, model.parameter(n).upper)
                               for n in params),
                         tuple(len(set(c)) == 1 for c, f in zip(coords, is_free) if f))
            groups.setdefault(signature, []).append(
                [c for c, f in zip(coords, is_free) if f])
        for signature, group in groups.items():
            if len(group) < 2:
                continue
            is_free = signature[1]
            # the ordering value: the declared one if free, else the lobe's first free parameter
            key = (sum(is_free[:ex.order_by]) if is_free[ex.order_by] else 0)
            n_chan = len(group[0][0])
            per_channel = all(len(set(c)) == n_chan for coords in group for c in coords)
            if per_channel and n_chan > 1:
                for ch in range(n_chan):
                    out.append(Swap(tuple(tuple(c[ch] for c in coords) for coords in group),
                                    tuple(coords[key][ch] for coords in group)))
            else:
                out.append(Swap(tuple(tuple(dict.fromkeys(i for c in coords for i in c))
                                      for coords in group),
                                tuple(coords[key][0] for coords in group)))
    return tuple(out)


def permutation(swap_list, x) -> np.ndarray:
    """Index arrays ``perm`` (..., d) such that ``x[..., perm]`` (``np.take_along_axis``) is
    ``x`` (..., d) with each Swap's lobes in ascending order of their ordering values (stable:
    equal values keep their order)."""
    x = np.asarray(x, dtype=float)
    perm = np.broadcast_to(np.arange(x.shape[-1]), x.shape).copy()
    for sw in swap_list:
        cur = np.take_along_axis(x, perm, -1)
        order = np.argsort(cur[..., list(sw.keys)], axis=-1, kind="stable")
        blocks = np.asarray(sw.blocks)  # (K, B)
        old = perm.copy()
        for j in range(len(sw.blocks)):
            src = blocks[order[..., j]]  # (..., B): the lobe that goes to place j
            perm[..., blocks[j]] = np.take_along_axis(old, src, -1)
    return perm


def canonical(space, x) -> np.ndarray:
    """``x`` (..., d), points of the fit space's free vector (native or unit-box coordinates),
    relabelled into the ordered labelling."""
    sw = swaps(space.static, space.fixed)
    if not sw:
        return np.asarray(x)
    return np.take_along_axis(np.asarray(x, dtype=float), permutation(sw, x), -1)


def canonical_runs(space, runs: dict) -> dict:
    """The Levenberg–Marquardt ends of ``least_squares.local_fits`` relabelled (z, u, native
    and the Jacobian's columns), by the order of their native values."""
    sw = swaps(space.static, space.fixed)
    if not sw:
        return runs
    perm = permutation(sw, runs["native"])
    out = dict(runs)
    for key in ("z", "u", "native"):
        out[key] = np.take_along_axis(runs[key], perm, -1)
    out["jacobian"] = np.take_along_axis(runs["jacobian"], perm[:, None, :], -1)
    return out


def order_keys(space) -> tuple[tuple[int, ...], ...]:
    """Per Swap, the coordinates whose unit-box values must not decrease (hashable: the MCMC
    kernel is compiled for them)."""
    return tuple(sw.keys for sw in swaps(space.static, space.fixed))


def ordered(keys, u):
    """True where the unit-box point(s) ``u`` (..., d) lie in the ordered labelling (the MCMC
    prior's support); ``keys`` from :func:`order_keys`. Traced by JAX."""
    ok = jnp.ones(u.shape[:-1], dtype=bool)
    for k in keys:
        for a, b in zip(k[:-1], k[1:]):
            ok = ok & (u[..., a] <= u[..., b])
    return ok


__all__ = ["Swap", "swaps", "permutation", "canonical", "canonical_runs", "order_keys", "ordered"]
