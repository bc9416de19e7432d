"""The thin layer's energy-compensation table, made from the simulator (fitlab's addition to
Guo et al. 2015; the runtime side is fitlab/models/thin_layer_compensation.py).

For every node of the table's axes (:mod:`fitlab.models.thin_layer_compensation`: incidence,
κ1, κ2, η and the bottom's descriptor, one table per bottom kind) it simulates the stack the
model stands for (``Model.scene_of``, all bounce orders, no absorption) and records its
directional albedo A (the flux leaving upward, with its standard error), computes the paper's
model's own albedo E (``compensation=none``, K = 1, the mean weight of its importance sampler
over a fixed Sobol point set). Where the paper's model returns more light than the stack, its f
is scaled by g(μi) g(μo) with g ≤ 1 found by a fixed point over the sampler's exit directions
(:func:`scale_and_missing`); the light still missing, D, is what the compensation lobe returns.
The table holds g and D per node.

Resumable: the simulations are kept per node in ``--work`` (one .npz per chunk of nodes);
a rerun skips what is there. Then::

    python -m fitlab.learn.compensation --work DIR [--samples 40000] [--write]

``--write`` writes the shipped table (fitlab/models/data/thin_layer_compensation.npz) and its
provenance (.json) atomically.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from fitlab.models.thin_layer_compensation import (
    BOTTOM_KINDS, DATA_PATH, LOG10_KAPPA_NODES, ETA_NODES, THETA_NODES_DEG, bottom_of_node,
)

#: paths per incidence and node (standard error of A about 0.002)
SAMPLES = 40_000
#: Sobol points per incidence and node for the model's albedo
MODEL_POINTS = 1024
#: nodes per chunk of work (a checkpoint file each)
CHUNK = 45


def nodes(kind: str) -> np.ndarray:
    """(N, 4) indices (κ1, κ2, η, bottom) of every parameter node of a bottom kind."""
    shape = (len(LOG10_KAPPA_NODES), len(LOG10_KAPPA_NODES), len(ETA_NODES),
             len(BOTTOM_KINDS[kind]["nodes"]))
    return np.stack(np.unravel_index(np.arange(int(np.prod(shape))), shape), axis=-1)


def node_params(kind: str, idx) -> dict:
    """The model's parameters at a node (τ = 0)."""
    eta = float(ETA_NODES[idx[2]])
    return {"kappa1": float(10.0 ** LOG10_KAPPA_NODES[idx[0]]),
            "kappa2": float(10.0 ** LOG10_KAPPA_NODES[idx[1]]),
            "eta": eta, "tau": 0.0, **bottom_of_node(kind, idx[3], eta)}


def simulate_node(model, params, samples, seed):
    """(A, σ_A) per incidence node: the stack's upward flux, every order, no delta."""
    from fitlab.simulate import scene_from_dict, simulate

    scene = model.scene_of(params, {})
    scene.update({"name": "thin layer compensation node",
                  "effects": {"max_bounces": "all", "delta": False, "color": "mono"},
                  "illumination": {"theta_i": [float(t) for t in THETA_NODES_DEG]},
                  "detector": {"type": "hemisphere", "theta_bins": 1, "phi_bins": 1}})
    res = simulate(scene_from_dict(scene), samples=samples, seed=seed)
    return res.energy[:, 0, 0], res.energy_sigma[:, 0, 0]


def exit_samples(model, plist, points=MODEL_POINTS):
    """(w, μo), each (len(plist), T, points): the paper's model's sampler (compensation=none)
    at every node's incidences: the weights f cos θo / pdf and the exit cosines."""
    from fitlab._jax import jax, jnp
    from fitlab.models.directional_albedo import points as sobol

    u = np.asarray(sobol(points))
    th = np.radians(np.asarray(THETA_NODES_DEG))
    wi = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    n, T = len(plist), len(th)
    rows = {k: np.repeat(np.asarray([p[k] for p in plist]), T * points) for k in plist[0]}
    W = np.tile(np.repeat(wi, points, axis=0), (n, 1))
    U = np.tile(u, (n * T, 1))

    @jax.jit
    def draw(p, w, v):
        wo, weight, _ = model.sample(p, w, v, compensation="none")
        return weight, wo[..., 2]

    w, mu = draw({k: jnp.asarray(v) for k, v in rows.items()}, jnp.asarray(W), jnp.asarray(U))
    return (np.asarray(w).reshape(n, T, points), np.asarray(mu).reshape(n, T, points))


def _at_mu(g, mu):
    """g (n, T) at the incidence nodes, read at mu (n, T, P) as the runtime reads it
    (:func:`fitlab.models.thin_layer_compensation.at_mu`)."""
    from fitlab._jax import jnp
    from fitlab.models.thin_layer_compensation import at_mu

    return np.asarray(at_mu(jnp.asarray(g)[:, None, None, :], jnp.asarray(mu)))


def scale_and_missing(A, w, mu, iterations=30):
    """(g, D) per node, (n, T): the scale g ≤ 1 of the paper's f, f · g(μi) g(μo), such that
    its albedo ∫ g(μi) g(μo) f cos θo dωo (the mean of g(μi) g(μo) w over the sampler's exits)
    does not exceed the simulated A, by a fixed-point iteration from g = 1; and the light still
    missing, D = max(A − that albedo, 0), which the compensation lobe returns."""
    A = np.asarray(A, float)
    g = np.ones_like(A)
    for _ in range(iterations):
        S = g * np.mean(w * _at_mu(g, mu), axis=-1)
        g = np.minimum(1.0, g * np.sqrt(np.where(S > 0, A / np.maximum(S, 1e-300), 1.0)))
    S = g * np.mean(w * _at_mu(g, mu), axis=-1)
    return g, np.maximum(A - S, 0.0)


def run_chunk(kind, chunk_idx, samples):
    from fitlab.models import get_model

    model = get_model(BOTTOM_KINDS[kind]["model"])
    plist = [node_params(kind, i) for i in chunk_idx]
    A, S = zip(*(simulate_node(model, p, samples, seed=1 + j) for j, p in enumerate(plist)))
    E = exit_samples(model, plist)[0].mean(-1)  # the mean weight of the model's sampler
    return np.asarray(A), np.asarray(S), E


def collect(work: Path, kind: str, samples: int, log=print):
    """Every chunk of a kind, simulated where its checkpoint is missing; (A, σ, E) over the
    kind's node grid (κ1, κ2, η, bottom, θ)."""
    idx = nodes(kind)
    parts = []
    t0 = time.perf_counter()
    chunks = range(0, len(idx), CHUNK)
    paths = [work / f"{kind}_{start:05d}_{samples}.npz" for start in chunks]
    missing = [p for p in paths if not p.exists()]
    for start, path in zip(chunks, paths):
        if not path.exists():
            A, S, E = run_chunk(kind, idx[start:start + CHUNK], samples)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, A=A, S=S, E=E)
            tmp.replace(path)
            done = missing.index(path) + 1  # the estimate counts only what this run simulates
            eta_s = (time.perf_counter() - t0) / done * (len(missing) - done)
            log(f"{kind}: chunk {done}/{len(missing)} to simulate ({time.perf_counter() - t0:.0f}"
                f" s, about {eta_s:.0f} s left)")
        with np.load(path) as z:
            parts.append((z["A"], z["S"], z["E"]))
    A, S, E = (np.concatenate(x) for x in zip(*parts))
    shape = (len(LOG10_KAPPA_NODES), len(LOG10_KAPPA_NODES), len(ETA_NODES),
             len(BOTTOM_KINDS[kind]["nodes"]), len(THETA_NODES_DEG))
    return A.reshape(shape), S.reshape(shape), E.reshape(shape)


def scale_tables(kind, A, log=print):
    """(g, D) over a kind's node grid from its simulated A (:func:`scale_and_missing`, the
    model's exits drawn per chunk of nodes)."""
    from fitlab.models import get_model

    model = get_model(BOTTOM_KINDS[kind]["model"])
    idx = nodes(kind)
    flatA = A.reshape(len(idx), -1)
    g, D = np.empty_like(flatA), np.empty_like(flatA)
    for start in range(0, len(idx), CHUNK):
        part = idx[start:start + CHUNK]
        w, mu = exit_samples(model, [node_params(kind, i) for i in part])
        g[start:start + len(part)], D[start:start + len(part)] = \
            scale_and_missing(flatA[start:start + len(part)], w, mu)
        log(f"{kind}: scales of nodes {start + len(part)}/{len(idx)}")
    return g.reshape(A.shape), D.reshape(A.shape)


def write_table(tables: dict, samples: int, path: Path = DATA_PATH, log=print):
    from fitlab.io.atomic import atomic_open, atomic_write_text

    arrays = {}
    for kind, (A, S, E) in tables.items():
        g, D = scale_tables(kind, A, log)
        arrays[f"{kind}_D"] = D.astype(np.float32)
        arrays[f"{kind}_g"] = g.astype(np.float32)
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    meta = {
        "what": "per node g, the scale of the paper's f (compensation=none, bounces=1), f g(mu_i) "
                "g(mu_o), that keeps its albedo within the simulated A (fitlab simulate, all "
                "orders, no delta, tau = 0), and D = A minus that albedo, the light the "
                "compensation lobe returns",
        "axes": "kappa1, kappa2, eta, bottom descriptor, theta_i (fitlab/models/"
                "thin_layer_compensation.py)",
        "samples_per_incidence": samples, "model_points": MODEL_POINTS,
        "stats": {kind: {"max_A_minus_E": float(np.max(A - E)),
                         "min_A_minus_E": float(np.min(A - E)),
                         "max_sigma_A": float(S.max()),
                         "median_sigma_A": float(np.median(S))}
                  for kind, (A, S, E) in tables.items()},
    }
    atomic_write_text(path.with_suffix(".json"), json.dumps(meta, indent=1, sort_keys=True)
                      + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m fitlab.learn.compensation",
        description="Make the thin layer's energy-compensation table from the simulator "
                    "(resumable: checkpoints in --work).")
    ap.add_argument("--work", type=Path, required=True, help="folder for the checkpoints")
    ap.add_argument("--samples", type=int, default=SAMPLES, help="paths per incidence and node")
    ap.add_argument("--kinds", default=",".join(BOTTOM_KINDS),
                    help="bottom kinds to make (comma separated)")
    ap.add_argument("--write", action="store_true",
                    help="write the shipped table once every kind is complete")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    tables = {k: collect(a.work, k, a.samples, log) for k in a.kinds.split(",")}
    if a.write:
        write_table(tables, a.samples, log=log)
        log(f"wrote {DATA_PATH.name} ({DATA_PATH.stat().st_size} bytes) in "
            f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
