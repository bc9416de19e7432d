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
  is determined: the per-material fit holds the same, fitlab.spongecake_lobe);
* **loss**: per stack, the mean absolute difference between the simulated multiple-scattering
  part (simulation minus the model's exact single scattering) and ``spongecake(K,multiple=only)``
  at the network's output, divided by the stack's mean |part| (so dim stacks count as much as
  bright ones); Adam (optax), minibatches of 32 stacks.

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

#: where the shipped weights and their provenance live
WEIGHTS = Path(__file__).parent / "models" / "data" / "spongecake_ms_1layer.npz"
N_IN, N_OUT, WIDTH, DEPTH = 6, 6, 128, 3
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
LOG_TAU = (math.log(1e-4), math.log(100.0))


def _logit(p):
    return math.log(p / (1.0 - p))


#: the output layer's initial bias: α' 0.5, f0' 0.5, Tρ' 1, W1 1, W2 0.05, W2T 0.05
START_LOGITS = (_logit((0.5 - 1e-3) / (1 - 1e-3)), 0.0,
                _logit((0.0 - LOG_TAU[0]) / (LOG_TAU[1] - LOG_TAU[0])), 0.0,
                math.log(0.05), math.log(0.05))


# --------------------------------------------------------------------------------------------
# The stacks
# --------------------------------------------------------------------------------------------


def stack_parameters(index: int, seed: int) -> tuple[str, dict]:
    """(kind, parameters of ``spongecake(KIND)``) of training stack ``index``: log-uniform α and
    Tρ, uniform γ, f0 and cos θp, φp = 0; the same for every run with this seed."""
    rng = np.random.default_rng([seed, index])
    kind = KINDS[int(rng.integers(2))]
    log_u = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
    p = {"alpha1": log_u(*ALPHA_RANGE), "theta_p1": float(np.degrees(np.arccos(rng.uniform()))),
         "phi_p1": 0.0, "albedo1": float(rng.uniform(*ALBEDO_RANGE)),
         "f0_1": float(rng.uniform(*F0_RANGE)), "tau1": log_u(*TAU_RANGE)}
    return kind, p


def network_inputs(kind_is_fiber, alpha, albedo, tau, f0, cos_theta_p):
    """The network's input vector (..., 6)."""
    import jax.numpy as jnp

    dtype = jnp.result_type(alpha, albedo, tau, f0, cos_theta_p)  # the parameters' precision
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    parts = [alpha, albedo, jnp.log10(jnp.asarray(tau, dtype)), f0, kind_is_fiber, cos_theta_p]
    parts = jnp.broadcast_arrays(*[jnp.asarray(x, dtype=dtype) for x in parts])
    return jnp.stack(parts, axis=-1)


def make_stack(directory, index: int, seed: int, samples: int = SAMPLES) -> Path:
    """Simulate training stack ``index`` and write its file (skipped when it exists)."""
    from fitlab.export.paramfile import chain_bytes
    from fitlab.io.atomic import atomic_open
    from fitlab.spongecake_lobe import multiple_scattering_part

    path = Path(directory) / f"stack_{index:05d}.npz"
    if path.exists():
        return path
    kind, p = stack_parameters(index, seed)
    ms, _ = multiple_scattering_part(f"spongecake({kind})", {"Y": p}, samples=samples,
                                     seed=seed * 1_000_003 + index, theta_i=THETA_I,
                                     theta_bins=GRID[0], phi_bins=GRID[1])
    arrays = dict(kind_is_fiber=float(kind == "fiber"), alpha=p["alpha1"], albedo=p["albedo1"],
                  tau=p["tau1"], f0=p["f0_1"], cos_theta_p=math.cos(math.radians(p["theta_p1"])),
                  theta_p=p["theta_p1"], wi=ms.wi, wo=ms.wo, value=ms.value, sigma=ms.sigma,
                  samples=samples, seed=seed)
    with atomic_open(path, "wb") as fh:
        fh.write(chain_bytes(arrays))
    return path


def make_dataset(directory, n_stacks: int, seed: int = 0, samples: int = SAMPLES,
                 progress=None) -> list[Path]:
    """Every stack 0..n_stacks-1 in ``directory``, making only the missing ones;
    ``progress(done, n_stacks, made)`` after each (``made``: how many this call simulated)."""
    Path(directory).mkdir(parents=True, exist_ok=True)
    out, made = [], 0
    for k in range(n_stacks):
        existed = (Path(directory) / f"stack_{k:05d}.npz").exists()
        out.append(make_stack(directory, k, seed, samples))
        made += not existed
        if progress is not None:
            progress(k + 1, n_stacks, made)
    return out


def load_dataset(paths) -> dict:
    """Stack files → arrays (S, ...) of the layer parameters, wi, wo, value, sigma; ``index``:
    each kept stack's position in ``paths``, ``skipped``: stacks left out for empty cells."""
    from fitlab.errors import InputFileError
    from fitlab.io.validate import read_npz

    keys = ("kind_is_fiber", "alpha", "albedo", "tau", "f0", "cos_theta_p", "theta_p", "wi", "wo",
            "value", "sigma")
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
    kept = [i for i, n in enumerate(sizes) if n == R]
    rows = [rows[i] for i in kept]
    cat = lambda k: np.stack([np.asarray(r[k], dtype=float) for r in rows])  # noqa: E731
    out = {k: cat(k) for k in keys}
    out["index"] = np.asarray(kept)
    out["skipped"] = len(paths) - len(kept)
    return out


# --------------------------------------------------------------------------------------------
# The network (plain JAX: evaluated inside the model without equinox)
# --------------------------------------------------------------------------------------------


def mlp_apply(weights: dict, x):
    """The MLP of ``weights`` ({"W0", "b0", ..., "W3", "b3"}; ReLU hidden layers) at inputs
    x (..., 6), standardized by ``weights["x_mean"]``, ``["x_scale"]``."""
    import jax
    import jax.numpy as jnp

    w = {k: jnp.asarray(v, dtype=x.dtype) for k, v in weights.items()}  # evaluated in x's
    h = (x - w["x_mean"]) / w["x_scale"]                                 # precision
    for i in range(DEPTH + 1):
        h = h @ w[f"W{i}"].T + w[f"b{i}"]
        if i < DEPTH:
            h = jax.nn.relu(h)
    return h


def lobe_from_outputs(y):
    """Network outputs (..., 6) → the lobe parameters ({"alpha1_ms", ...} with albedo1_ms = 1)."""
    import jax
    import jax.numpy as jnp

    s = jax.nn.sigmoid(y)
    return {"alpha1_ms": 1e-3 + (1.0 - 1e-3) * s[..., 0], "albedo1_ms": jnp.ones_like(s[..., 0]),
            "f0_1_ms": s[..., 1],
            "tau1_ms": jnp.clip(jnp.exp(LOG_TAU[0] + (LOG_TAU[1] - LOG_TAU[0]) * s[..., 2]),
                                1e-4, 100.0),
            "W1": _soft_exp(y[..., 3], 10.0), "W2": _soft_exp(y[..., 4], 1.0),
            "W2T": _soft_exp(y[..., 5], 1.0)}


def _soft_exp(y, upper):
    """e^y below ``upper``, smoothly capped at it: upper · exp(−softplus(log upper − y)). The
    weights span decades between dim and bright stacks; a sigmoid saturated at 0 in training
    (its gradient vanishes), a log parameter does not."""
    import jax

    return upper * jax.numpy.exp(-jax.nn.softplus(math.log(upper) - y))


def load_weights(path=None) -> dict:
    """The weight arrays (as jax arrays) of a weights file (default: the shipped ones)."""
    import jax.numpy as jnp

    with np.load(path or WEIGHTS) as z:
        return {k: jnp.asarray(z[k]) for k in z.files}


def provenance(path=None) -> dict:
    """The provenance record beside a weights file (default: the shipped ones)."""
    return json.loads(Path(path or WEIGHTS).with_suffix(".json").read_text(encoding="utf-8"))


# --------------------------------------------------------------------------------------------
# Training (equinox + optax)
# --------------------------------------------------------------------------------------------


def held_out(index) -> np.ndarray:
    """Which stacks (by their index) are held out: every tenth (index % 10 == 9), 10% as in
    the paper."""
    return np.asarray(index) % 10 == 9


def _only_models():
    from fitlab.models import get_model

    return {k: get_model(f"spongecake({k},multiple=only)") for k in KINDS}


def predict(weights, data, idx):
    """The learned lobe's f (S, R) at stacks ``idx`` of ``data`` (load_dataset)."""
    import jax.numpy as jnp

    x = network_inputs(*(jnp.asarray(data[k][idx]) for k in
                         ("kind_is_fiber", "alpha", "albedo", "tau", "f0", "cos_theta_p")))
    lobe = lobe_from_outputs(mlp_apply(weights, x))
    params = {k: v[:, None] for k, v in lobe.items()}
    params["theta_p1"] = jnp.asarray(data["theta_p"][idx])[:, None]
    params["phi_p1"] = jnp.zeros_like(params["theta_p1"])
    wi, wo = jnp.asarray(data["wi"][idx]), jnp.asarray(data["wo"][idx])
    models = _only_models()
    f_s = models["surface"].eval(params, wi, wo)
    f_f = models["fiber"].eval(params, wi, wo)
    return jnp.where(jnp.asarray(data["kind_is_fiber"][idx])[:, None] > 0.5, f_f, f_s)


def stack_errors(f, value):
    """Per stack: the relative mean absolute error (the training loss) and the RMS relative error
    over the rows above 1e-3 of the stack's largest |value|."""
    import jax.numpy as jnp

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
    import jax
    import jax.numpy as jnp
    import optax

    test = held_out(data["index"])
    train_idx = np.flatnonzero(~test)
    x_all = np.asarray(network_inputs(*(data[k] for k in ("kind_is_fiber", "alpha", "albedo",
                                                          "tau", "f0", "cos_theta_p"))))
    x_mean = x_all[train_idx].mean(axis=0)
    x_scale = x_all[train_idx].std(axis=0) + 1e-6
    key = jax.random.PRNGKey(seed)
    key, init = jax.random.split(key)
    model = eqx.nn.MLP(N_IN, N_OUT, WIDTH, DEPTH, activation=jax.nn.relu, key=init)
    # start near a plausible lobe (α' 0.5, f0' 0.5, Tρ' 1, W1 1, W2 = W2T = 0.05) with small
    # output weights: from sigmoid(0) everywhere (W1 = 5) the first steps' huge losses drove
    # the outputs into saturation, where the gradient vanishes
    last = model.layers[-1]
    model = eqx.tree_at(lambda m: (m.layers[-1].weight, m.layers[-1].bias), model,
                        (0.1 * last.weight, jnp.asarray(START_LOGITS)))
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
    import jax.numpy as jnp

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


def learn(directory, out, *, stacks: int = 4000, samples: int = SAMPLES, steps: int = 8000,
          seed: int = 0, progress=None) -> dict:
    """The one command (``fitlab learn-lobe``): make the missing training stacks in
    ``directory``, train, write the weights ``out`` (.npz) and their provenance (``out`` with
    .json) atomically. Returns the provenance."""
    import hashlib

    import equinox
    import jax
    import optax

    from fitlab.export.paramfile import chain_bytes
    from fitlab.io.atomic import atomic_open, atomic_write_text

    say = progress or (lambda *a: None)
    paths = make_dataset(directory, stacks, seed, samples,
                         progress=lambda k, n, made: say("dataset", k, n, made))
    data = load_dataset(paths)
    weights, report = train(data, steps=steps, seed=seed,
                            progress=lambda k, n, loss: say("training", k, n, k, loss))
    blob = chain_bytes(weights)
    prov = {
        "format": "fitlab-spongecake-network", "version": 1,
        "network": {"inputs": ["alpha", "albedo", "log10 tau", "f0", "k (1 = fiber)",
                               "cos theta_p"],
                    "outputs": ["alpha_ms", "f0_ms", "log tau_ms", "W1", "W2", "W2T"],
                    "hidden_layers": [WIDTH] * DEPTH, "activation": "relu",
                    "reference": "SpongeCake (Wang et al. 2022) §5, Fig. 5"},
        "dataset": {"stacks": int(len(data["value"])), "skipped_empty_cells": int(data["skipped"]),
                    "held_out": int(held_out(data["index"]).sum()), "seed": seed,
                    "samples_per_incidence": samples, "theta_i_deg": list(THETA_I),
                    "grid_per_side": list(GRID), "rows_per_stack": int(data["value"].shape[1]),
                    "ranges": {"alpha": ALPHA_RANGE, "albedo": ALBEDO_RANGE, "tau": TAU_RANGE,
                               "f0": F0_RANGE, "cos_theta_p": [0, 1], "kinds": list(KINDS)},
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
