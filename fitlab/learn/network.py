"""SpongeCake's parameter-mapping network (Wang et al. 2022, §5): the multiple-scattering lobe's
parameters for any one-layer flake stack at once, learned from simulated stacks.

The paper's network maps a layer's parameters (α, γ, T, f0, the flake type k, the axis ωp) to
the lobe's (α', γ', T', f0', W1, W2), an MLP of three hidden layers of 128, trained with the MAE
between the simulated multiple scattering and the lobe evaluated with its output, through a
differentiable single-scattering model. fitlab does the same for one layer of SGGX flakes:

* **inputs** (6): α, γ, log10 Tρ, f0, k (0 surface, 1 fiber), cos θp. The lobe keeps the axis,
  so its azimuth φp does not enter (the stack's multiple scattering turns with it);
* **outputs** (6): α' ∈ [1e-3, 1], f0' ∈ [0, 1], log Tρ' ∈ [log 1e-4, log 100] through
  sigmoids, W1 ≤ 10 and W2, W2T ≤ 1 as smoothly capped exponentials, and γ' = 1 (only W1·γ'
  is determined: the per-material fit holds the same, fitlab.learn.lobe);
* **loss**: per stack, the mean absolute difference between the simulated multiple-scattering
  part (simulation minus the model's exact single scattering) and §5's approximation at the
  network's output (:func:`fitlab.models.spongecake_multiple.approximation`, the
  ``multiple=only`` model before its energy budget: the budget binds only where a lobe would
  return more light than arrives, and tabulating it per stack and step would cost some 10⁵
  samples each), divided by the stack's mean |part| (so dim stacks count as much as bright
  ones); Adam (optax), minibatches of 32 stacks.

The dataset is made by the simulator, one file per stack (``stack_00042.npz``, written
atomically; the stack's parameters and seed follow from its index, so a rerun makes only what is
missing). :func:`mlp_apply` evaluates the network in plain JAX from the weight arrays, inside the
model (``spongecake(K,multiple=learned)``), differentiable; equinox and optax are needed only to
train (``pip install 'fitlab[learn]'``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from fitlab.models.spongecake_multiple import approximation
from fitlab.models.spongecake_network import (DEPTH, LAYERS, LOG_TAU, WIDTH, input_names,
                                              lobe_from_outputs, mlp_apply, n_inputs, n_outputs,
                                              network_inputs, output_names)

#: parameter ranges of the training stacks
ALPHA_RANGE = (0.05, 1.0)
ALBEDO_RANGE = (0.2, 1.0)
TAU_RANGE = (0.1, 10.0)
F0_RANGE = (0.02, 1.0)
KINDS = ("surface", "fiber")
#: simulation of each stack: incidences, grid per side, paths per incidence
THETA_I = (0.0, 30.0, 55.0, 75.0)
GRID = (4, 8)
SAMPLES = 10_000
#: stacks in a dataset by its number of layers: the paper's 4,000 one-layer and 12,000
#: two-layer stacks (SpongeCake §5), and the shipped weights'
STACKS = {1: 4000, 2: 12000}
def _logit(p):
    return math.log(p / (1.0 - p))


def start_logits(layers: int) -> tuple:
    """The output layer's initial bias: α' 0.5, f0' 0.5, Tρ' 1 per layer, γ' 0.5 below the
    first, W1 1, W2 0.05, W2T 0.05."""
    per_layer = (_logit((0.5 - 1e-3) / (1 - 1e-3)), 0.0,
                 _logit((0.0 - LOG_TAU[0]) / (LOG_TAU[1] - LOG_TAU[0])))
    return per_layer * layers + (0.0,) * (layers - 1) + (0.0, math.log(0.05), math.log(0.05))


# --------------------------------------------------------------------------------------------
# The stacks
# --------------------------------------------------------------------------------------------


def stack_parameters(index: int, seed: int, layers: int = 1) -> tuple[tuple[str, ...], dict]:
    """(kinds, parameters of ``spongecake(KIND[,KIND])``) of training stack ``index``: per
    layer log-uniform α and Tρ, uniform γ, f0 and cos θp; φp = 0 for the first layer, uniform
    in [0°, 180°) below it; the same for every run with this seed."""
    rng = np.random.default_rng([seed, index] if layers == 1 else [seed, index, layers])
    log_u = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
    kinds, p = [], {}
    for i in range(1, layers + 1):
        kinds.append(KINDS[int(rng.integers(2))])
        p.update({f"alpha{i}": log_u(*ALPHA_RANGE),
                  f"theta_p{i}": float(np.degrees(np.arccos(rng.uniform()))),
                  f"phi_p{i}": 0.0 if i == 1 else float(rng.uniform(0.0, 180.0)),
                  f"albedo{i}": float(rng.uniform(*ALBEDO_RANGE)),
                  f"f0_{i}": float(rng.uniform(*F0_RANGE)), f"tau{i}": log_u(*TAU_RANGE)})
    return tuple(kinds), p


def make_stack(directory, index: int, seed: int, samples: int = SAMPLES, layers: int = 1) -> Path:
    """Simulate training stack ``index`` and write its file (skipped when it exists)."""
    from fitlab.export.paramfile import chain_bytes
    from fitlab.io.atomic import atomic_open
    from fitlab.learn.lobe import multiple_scattering_part

    path = Path(directory) / f"stack_{index:05d}.npz"
    if path.exists():
        return path
    kinds, p = stack_parameters(index, seed, layers)
    ms, _ = multiple_scattering_part(f"spongecake({','.join(kinds)})", {"Y": p},
                                     samples=samples, seed=seed * 1_000_003 + index,
                                     theta_i=THETA_I, theta_bins=GRID[0], phi_bins=GRID[1])
    per = lambda key: [p[f"{key}{i}"] for i in range(1, layers + 1)]  # noqa: E731
    layer = dict(kind_is_fiber=[float(k == "fiber") for k in kinds], alpha=per("alpha"),
                 albedo=per("albedo"), tau=per("tau"), f0=per("f0_"),
                 cos_theta_p=[math.cos(math.radians(t)) for t in per("theta_p")],
                 theta_p=per("theta_p"))
    if layers == 1:   # one layer: scalars (the shipped dataset's files)
        layer = {k: v[0] for k, v in layer.items()}
    else:
        layer["phi_p"] = per("phi_p")
    arrays = dict(**layer, wi=ms.wi, wo=ms.wo, value=ms.value, sigma=ms.sigma,
                  samples=samples, seed=seed)
    with atomic_open(path, "wb") as fh:
        fh.write(chain_bytes(arrays))
    return path


def make_dataset(directory, n_stacks: int, seed: int = 0, samples: int = SAMPLES,
                 progress=None, layers: int = 1, shard: tuple[int, int] = (0, 1)) -> list[Path]:
    """Every stack 0..n_stacks-1 in ``directory``, making only the missing ones;
    ``progress(done, n_stacks, made)`` after each (``made``: how many this call simulated).
    ``shard`` (k, n): make only the indices ≡ k mod n (n processes share the work; the files
    are the same whichever process makes them)."""
    Path(directory).mkdir(parents=True, exist_ok=True)
    out, made = [], 0
    for k in range(n_stacks):
        path = Path(directory) / f"stack_{k:05d}.npz"
        existed = path.exists()
        if k % shard[1] == shard[0]:
            make_stack(directory, k, seed, samples, layers)
            made += not existed
        out.append(path)
        if progress is not None:
            progress(k + 1, n_stacks, made)
    return out


#: the members that hold one value per layer
LAYER_KEYS = ("kind_is_fiber", "alpha", "albedo", "tau", "f0", "cos_theta_p", "theta_p")


def load_dataset(paths) -> dict:
    """Stack files → arrays (S, ...) of the layer parameters, wi, wo, value, sigma; ``index``:
    each kept stack's position in ``paths``, ``skipped``: stacks left out for empty cells."""
    from fitlab.errors import InputFileError
    from fitlab.io.validate import read_npz

    keys = LAYER_KEYS + ("wi", "wo", "value", "sigma")
    rows = []
    for p in paths:
        r = read_npz(p, what="a SpongeCake training stack",
                     hint="delete the file; `fitlab learn-lobe` makes it again")
        missing = [k for k in keys if k not in r]
        if missing:
            raise InputFileError(p, f"has no {', '.join(missing)}",
                                 hint="delete the file; `fitlab learn-lobe` makes it again")
        if not all(np.all(np.isfinite(np.asarray(r[k], dtype=float))) for k in keys):
            raise InputFileError(p, "holds values that are not finite",
                                 hint="delete the file; `fitlab learn-lobe` makes it again")
        rows.append(r)
    # a stack some of whose cells no path reached has fewer rows (the simulator leaves empty
    # cells out): it is skipped, and counted
    sizes = [len(r["value"]) for r in rows]
    R = max(set(sizes), key=sizes.count)
    for p, r in zip(paths, rows):
        if r["wi"].shape != (len(r["value"]), 3) or r["wo"].shape != r["wi"].shape \
                or r["sigma"].shape != r["value"].shape:
            raise InputFileError(p, "holds arrays of inconsistent shapes",
                                 hint="delete the file; `fitlab learn-lobe` makes it again")
    layers = {np.asarray(r["alpha"]).size for r in rows}
    if len(layers) > 1:
        raise InputFileError(paths[0], f"the folder mixes stacks of {sorted(layers)} layers",
                             hint="give each number of layers its own --dir")
    kept = [i for i, n in enumerate(sizes) if n == R]
    rows = [rows[i] for i in kept]
    cat = lambda k: np.stack([np.asarray(r[k], dtype=float) for r in rows])  # noqa: E731
    out = {k: cat(k) for k in keys}
    # per-layer members as (S, L); one-layer files hold scalars and no φp (it is 0)
    for k in LAYER_KEYS:
        out[k] = out[k].reshape(len(rows), -1)
    L = out["alpha"].shape[1]
    out["phi_p"] = (np.stack([np.asarray(r["phi_p"], dtype=float).reshape(L) for r in rows])
                    if L > 1 else np.zeros((len(rows), 1)))
    out["index"] = np.asarray(kept)
    out["skipped"] = len(paths) - len(kept)
    return out


# --------------------------------------------------------------------------------------------
# The network (plain JAX: evaluated inside the model without equinox)
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# Training (equinox + optax)
# --------------------------------------------------------------------------------------------


def held_out(index) -> np.ndarray:
    """Which stacks (by their index) are held out: every tenth (index % 10 == 9), 10% as in
    the paper."""
    return np.asarray(index) % 10 == 9


def _stacks(layers: int):
    """{kinds: the plain stack ``spongecake(KINDS,delta=false)``, whose single scattering at
    the modified parameters is the lobe} for every combination of flake kinds."""
    import itertools

    from fitlab.models import get_model

    return {kinds: get_model(f"spongecake({','.join(kinds)},delta=false)")
            for kinds in itertools.product(KINDS, repeat=layers)}


def _inputs(data, idx):
    from fitlab._jax import jnp

    d = {k: jnp.asarray(data[k][idx]) for k in LAYER_KEYS + ("phi_p",)}
    cos_dphi = jnp.cos(jnp.radians(d["phi_p"][:, 1:] - d["phi_p"][:, :1]))
    return network_inputs(d["kind_is_fiber"], d["alpha"], d["albedo"], d["tau"], d["f0"],
                          d["cos_theta_p"], cos_dphi), d


def predict(weights, data, idx):
    """The learned lobe's f (S, R) at stacks ``idx`` of ``data`` (load_dataset)."""
    from fitlab._jax import jnp

    x, d = _inputs(data, idx)
    layers = d["alpha"].shape[1]
    lobe = lobe_from_outputs(mlp_apply(weights, x), layers)
    params = {k: v[:, None] for k, v in lobe.items()}
    for i in range(layers):
        params[f"theta_p{i + 1}"] = d["theta_p"][:, i, None]
        params[f"phi_p{i + 1}"] = d["phi_p"][:, i, None]
    wi, wo = jnp.asarray(data["wi"][idx]), jnp.asarray(data["wo"][idx])
    fiber = d["kind_is_fiber"] > 0.5
    f = 0.0
    for kinds, stack in _stacks(layers).items():
        mask = jnp.all(fiber == jnp.asarray([k == "fiber" for k in kinds]), axis=-1)
        f = f + jnp.where(mask[:, None], approximation(stack, params, wi, wo, True), 0.0)
    return f


def stack_errors(f, value):
    """Per stack: the relative mean absolute error (the training loss) and the RMS relative error
    over the rows above 1e-3 of the stack's largest |value|."""
    from fitlab._jax import jnp

    scale = jnp.mean(jnp.abs(value), axis=-1) + 1e-12
    mae = jnp.mean(jnp.abs(f - value), axis=-1) / scale
    keep = jnp.abs(value) > 1e-3 * jnp.max(jnp.abs(value), axis=-1, keepdims=True)
    rel = jnp.where(keep, (f - value) / jnp.where(keep, value, 1.0), 0.0)
    rms = jnp.sqrt(jnp.sum(rel**2, axis=-1)
                   / jnp.maximum(jnp.sum(keep, axis=-1, dtype=rel.dtype), 1.0))
    return mae, rms


def to_weights(model, x_mean, x_scale) -> dict:
    """An equinox MLP's arrays as the dict :func:`mlp_apply` evaluates."""
    w = {"x_mean": np.asarray(x_mean), "x_scale": np.asarray(x_scale)}
    for i, layer in enumerate(model.layers):
        w[f"W{i}"] = np.asarray(layer.weight)
        w[f"b{i}"] = np.asarray(layer.bias)
    return w


def train(data: dict, *, steps: int = 4000, batch: int = 32, learning_rate: float = 1e-3,
          seed: int = 0, progress=None):
    """Train the network on the stacks not held out. Returns (weights dict, {"train_loss",
    "held_out_loss", "held_out_rms_median", ...})."""
    import equinox as eqx
    from fitlab._jax import jax, jnp
    import optax

    test = held_out(data["index"])
    train_idx = np.flatnonzero(~test)
    layers = data["alpha"].shape[1]
    x_all = np.asarray(_inputs(data, np.arange(len(data["alpha"])))[0])
    x_mean = x_all[train_idx].mean(axis=0)
    x_scale = x_all[train_idx].std(axis=0) + 1e-6
    key = jax.random.PRNGKey(seed)
    key, init = jax.random.split(key)
    model = eqx.nn.MLP(n_inputs(layers), n_outputs(layers), WIDTH, DEPTH,
                       activation=jax.nn.relu, key=init)
    # start near a plausible lobe (α' 0.5, f0' 0.5, Tρ' 1, W1 1, W2 = W2T = 0.05) with small
    # output weights: from sigmoid(0) everywhere (W1 = 5) the first steps' huge losses drove
    # the outputs into saturation, where the gradient vanishes
    last = model.layers[-1]
    model = eqx.tree_at(lambda m: (m.layers[-1].weight, m.layers[-1].bias), model,
                        (0.1 * last.weight, jnp.asarray(start_logits(layers))))
    opt = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(learning_rate))
    state = opt.init(eqx.filter(model, eqx.is_array))
    jdata = {k: jnp.asarray(v) for k, v in data.items() if k != "skipped"}

    def loss_fn(m, idx):
        w = {"x_mean": jnp.asarray(x_mean), "x_scale": jnp.asarray(x_scale)}
        w.update({f"W{i}": L.weight for i, L in enumerate(m.layers)})
        w.update({f"b{i}": L.bias for i, L in enumerate(m.layers)})
        f = predict(w, jdata, idx)
        mae, _ = stack_errors(f, jdata["value"][idx])
        return jnp.mean(mae)

    @eqx.filter_jit
    def step(m, s, idx):
        loss, grads = eqx.filter_value_and_grad(loss_fn)(m, idx)
        updates, s = opt.update(grads, s, eqx.filter(m, eqx.is_array))
        return eqx.apply_updates(m, updates), s, loss

    rng = np.random.default_rng(seed)
    losses = []
    for k in range(steps):
        idx = jnp.asarray(rng.choice(train_idx, size=min(batch, len(train_idx)), replace=False))
        # optax's Adam adds a Python float to its int32 step count: it needs JAX's standard
        # type promotion, also where a caller (fitlab's tests) made it strict
        with jax.numpy_dtype_promotion("standard"):
            model, state, loss = step(model, state, idx)
        losses.append(float(loss))
        if progress is not None and (k + 1) % 100 == 0:
            progress(k + 1, steps, float(np.mean(losses[-100:])))
    weights = to_weights(model, x_mean, x_scale)
    report = evaluate(weights, data)
    report["train_loss_last_100_steps"] = float(np.mean(losses[-100:]))
    return weights, report


def evaluate(weights: dict, data: dict) -> dict:
    """Held-out and training errors of ``weights`` on ``data`` (load_dataset)."""
    from fitlab._jax import jnp

    w = {k: jnp.asarray(v) for k, v in weights.items()}
    out = {}
    test = held_out(data["index"])
    for name, mask in (("held_out", test), ("train", ~test)):
        idx = np.flatnonzero(mask)
        maes, rmss = [], []
        for chunk in np.array_split(idx, max(1, len(idx) // 256)):
            mae, rms = stack_errors(predict(w, data, chunk), jnp.asarray(data["value"][chunk]))
            maes.append(np.asarray(mae))
            rmss.append(np.asarray(rms))
        mae, rms = np.concatenate(maes), np.concatenate(rmss)
        out[f"{name}_stacks"] = int(len(idx))
        out[f"{name}_loss"] = float(np.mean(mae))
        out[f"{name}_rms_median"] = float(np.median(rms))
        out[f"{name}_rms_p90"] = float(np.quantile(rms, 0.9))
    return out


def make_dataset_parallel(directory, n_stacks: int, seed: int = 0, samples: int = SAMPLES,
                          progress=None, layers: int = 1, jobs: int = 1) -> list[Path]:
    """:func:`make_dataset` in ``jobs`` processes (each a shard of the indices; the files do not
    depend on which process makes them). ``progress(done, n_stacks, made)`` counts the files
    present, from this process."""
    import multiprocessing

    if jobs <= 1:
        return make_dataset(directory, n_stacks, seed, samples, progress, layers)
    Path(directory).mkdir(parents=True, exist_ok=True)
    names = [Path(directory) / f"stack_{k:05d}.npz" for k in range(n_stacks)]
    before = sum(p.exists() for p in names)
    ctx = multiprocessing.get_context("spawn")     # JAX's threads do not survive a fork
    workers = [ctx.Process(target=make_dataset, args=(directory, n_stacks, seed, samples, None,
                                                      layers, (k, jobs)), daemon=True)
               for k in range(1, jobs)]
    for w in workers:
        w.start()
    try:
        def mine(k, n, made):
            if progress is not None:
                done = sum(p.exists() for p in names)
                progress(min(done, n_stacks - 1), n_stacks, done - before)
        make_dataset(directory, n_stacks, seed, samples, mine, layers, (0, jobs))
        for w in workers:
            w.join()
    finally:
        for w in workers:
            if w.is_alive():
                w.terminate()
    if any(w.exitcode != 0 for w in workers):
        raise RuntimeError(f"a dataset worker failed (exit status "
                           f"{[w.exitcode for w in workers]}); rerun: the stacks made are kept")
    if progress is not None:
        progress(n_stacks, n_stacks, sum(p.exists() for p in names) - before)
    return names


def learn(directory, out, *, stacks: int | None = None, samples: int = SAMPLES,
          steps: int = 8000, seed: int = 0, progress=None, layers: int = 1,
          jobs: int = 1) -> dict:
    """The one command (``fitlab learn-lobe``): make the missing training stacks of ``layers``
    layers in ``directory`` (``stacks`` of them, default :data:`STACKS` [layers]; in ``jobs``
    processes), train, write the weights ``out`` (.npz) and their provenance (``out`` with
    .json) atomically. Returns the provenance."""
    import hashlib

    import equinox
    from fitlab._jax import jax
    import optax

    from fitlab.export.paramfile import chain_bytes
    from fitlab.io.atomic import atomic_open, atomic_write_text

    if layers not in LAYERS:
        raise ValueError(f"layers must be one of {', '.join(map(str, LAYERS))}")
    stacks = STACKS[layers] if stacks is None else stacks
    say = progress or (lambda *a: None)
    paths = make_dataset_parallel(directory, stacks, seed, samples,
                                  progress=lambda k, n, made: say("dataset", k, n, made),
                                  layers=layers, jobs=jobs)
    data = load_dataset(paths)
    if data["alpha"].shape[1] != layers:
        raise ValueError(f"{directory} holds stacks of {data['alpha'].shape[1]} layer(s), not "
                         f"{layers}; give each number of layers its own --dir")
    weights, report = train(data, steps=steps, seed=seed,
                            progress=lambda k, n, loss: say("training", k, n, k, loss))
    blob = chain_bytes(weights)
    prov = {
        "format": "fitlab-spongecake-network", "version": 1,
        "network": {"inputs": input_names(layers), "outputs": output_names(layers),
                    "hidden_layers": [WIDTH] * DEPTH, "activation": "relu",
                    "reference": f"SpongeCake (Wang et al. 2022) §5, Fig. {4 + layers}"},
        "dataset": {"layers": layers, "stacks": int(len(data["value"])),
                    "skipped_empty_cells": int(data["skipped"]),
                    "held_out": int(held_out(data["index"]).sum()), "seed": seed,
                    "samples_per_incidence": samples, "theta_i_deg": list(THETA_I),
                    "grid_per_side": list(GRID), "rows_per_stack": int(data["value"].shape[1]),
                    "ranges": {"alpha": ALPHA_RANGE, "albedo": ALBEDO_RANGE, "tau": TAU_RANGE,
                               "f0": F0_RANGE, "cos_theta_p": [0, 1], "kinds": list(KINDS),
                               **({"phi_p_below_first_deg": [0, 180]} if layers > 1
                                  else {})},
                    "paper": "4,000 one-layer and 12,000 two-layer stacks, 32 x 32 directions, "
                             "100K paths per direction"},
        "training": {"steps": steps, "batch": 32, "learning_rate": 1e-3,
                     "optimizer": "Adam (optax) after global-norm clipping at 1",
                     "loss": "per stack mean |f - data| / mean |data|, averaged", "seed": seed,
                     "equinox": equinox.__version__, "optax": optax.__version__,
                     "jax": jax.__version__},
        "errors": report,
        "weights_sha256": hashlib.sha256(blob).hexdigest(),
    }
    out = Path(out)
    with atomic_open(out, "wb") as fh:
        fh.write(blob)
    atomic_write_text(out.with_suffix(".json"), json.dumps(prov, indent=2) + "\n")
    return prov
