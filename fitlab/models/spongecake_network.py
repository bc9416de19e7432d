"""SpongeCake's parameter-mapping network (Wang et al. 2022, §5) as the model evaluates it: the
multiple-scattering lobe's parameters from a flake stack's, an MLP in plain JAX from the shipped
weight arrays (``spongecake(K,multiple=learned)``, fitlab/models/spongecake.py), differentiable.
Its inputs and outputs are described in fitlab/learn/network.py, which makes the training
stacks with the simulator and trains it (equinox and optax, ``pip install 'fitlab[learn]'``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

#: where the shipped weights and their provenance live, per number of layers
WEIGHTS = {n: Path(__file__).parent / "data" / f"spongecake_ms_{n}layer.npz" for n in (1, 2)}

#: the networks: one per number of layers (the paper's Figs. 5 and 6)
LAYERS = tuple(WEIGHTS)

WIDTH, DEPTH = 128, 3

#: inputs per layer: α, γ, log10 Tρ, f0, k, cos θp
PER_LAYER_IN = 6

LOG_TAU = (math.log(1e-4), math.log(100.0))


def n_inputs(layers: int) -> int:
    """Per layer (α, γ, log10 Tρ, f0, k, cos θp), then cos Δφp of each layer below the first
    against the first (the stack's turn about the normal does not enter)."""
    return PER_LAYER_IN * layers + layers - 1


def n_outputs(layers: int) -> int:
    """Per layer (α', f0', log Tρ'), then γ' of each layer below the first (the first's is 1),
    then W1, W2, W2T."""
    return 3 * layers + (layers - 1) + 3


def network_inputs(kind_is_fiber, alpha, albedo, tau, f0, cos_theta_p, cos_dphi=None):
    """The network's input vector (..., n_inputs(L)) from per-layer arrays (..., L) and
    ``cos_dphi`` (..., L - 1), cos(φp_i − φp_1) of the layers below the first."""
    from fitlab._jax import jnp

    dtype = jnp.result_type(alpha, albedo, tau, f0, cos_theta_p)  # the parameters' precision
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    parts = [alpha, albedo, jnp.log10(jnp.asarray(tau, dtype)), f0, kind_is_fiber, cos_theta_p]
    parts = jnp.broadcast_arrays(*[jnp.asarray(x, dtype=dtype) for x in parts])
    x = jnp.stack(parts, axis=-1)                    # (..., L, 6)
    x = x.reshape(x.shape[:-2] + (x.shape[-2] * PER_LAYER_IN,))
    if x.shape[-1] > PER_LAYER_IN:
        x = jnp.concatenate([x, jnp.broadcast_to(jnp.asarray(cos_dphi, dtype),
                                                 x.shape[:-1] + (x.shape[-1] // PER_LAYER_IN
                                                                 - 1,))], axis=-1)
    return x


def mlp_apply(weights: dict, x):
    """The MLP of ``weights`` ({"W0", "b0", ..., "W3", "b3"}; ReLU hidden layers) at inputs
    x (..., 6), standardized by ``weights["x_mean"]``, ``["x_scale"]``."""
    from fitlab._jax import jax, jnp

    w = {k: jnp.asarray(v, dtype=x.dtype) for k, v in weights.items()}  # evaluated in x's
    h = (x - w["x_mean"]) / w["x_scale"]                                 # precision
    for i in range(DEPTH + 1):
        h = h @ w[f"W{i}"].T + w[f"b{i}"]
        if i < DEPTH:
            h = jax.nn.relu(h)
    return h


def lobe_from_outputs(y, layers: int = 1):
    """Network outputs (..., n_outputs(layers)) → the lobe parameters ({"alpha1_ms", ...};
    albedo1_ms = 1, only W1·γ'₁ being determined)."""
    from fitlab._jax import jax, jnp

    s = jax.nn.sigmoid(y)
    out = {}
    for i in range(1, layers + 1):
        j = 3 * (i - 1)
        out[f"alpha{i}_ms"] = 1e-3 + (1.0 - 1e-3) * s[..., j]
        out[f"f0_{i}_ms"] = s[..., j + 1]
        out[f"tau{i}_ms"] = jnp.clip(jnp.exp(LOG_TAU[0] + (LOG_TAU[1] - LOG_TAU[0])
                                             * s[..., j + 2]), 1e-4, 100.0)
        out[f"albedo{i}_ms"] = (jnp.ones_like(s[..., 0]) if i == 1
                                else s[..., 3 * layers + i - 2])
    w = 3 * layers + layers - 1
    out.update(W1=_soft_exp(y[..., w], 10.0), W2=_soft_exp(y[..., w + 1], 1.0),
               W2T=_soft_exp(y[..., w + 2], 1.0))
    return out


def _soft_exp(y, upper):
    """e^y below ``upper``, smoothly capped at it: upper · exp(−softplus(log upper − y)). The
    weights span decades between dim and bright stacks; a sigmoid saturated at 0 in training
    (its gradient vanishes), a log parameter does not."""
    from fitlab._jax import jax

    return upper * jax.numpy.exp(-jax.nn.softplus(math.log(upper) - y))


def load_weights(layers: int = 1, path=None) -> dict:
    """The weight arrays (as jax arrays) of a weights file (default: the shipped ones for
    ``layers`` layers)."""
    from fitlab._jax import jnp

    return {k: jnp.asarray(v) for k, v in weight_arrays(layers, path).items()}


def weight_arrays(layers: int = 1, path=None) -> dict:
    """The weight arrays of a weights file as NumPy arrays: what a model holds (no JAX until
    it computes; :func:`mlp_apply` takes them in its inputs' precision)."""
    with np.load(path or WEIGHTS[layers]) as z:
        return {k: z[k] for k in z.files}


def provenance(layers: int = 1, path=None) -> dict:
    """The provenance record beside a weights file (default: the shipped ones)."""
    return json.loads(Path(path or WEIGHTS[layers]).with_suffix(".json")
                      .read_text(encoding="utf-8"))


def input_names(layers: int) -> list[str]:
    one = ["alpha", "albedo", "log10 tau", "f0", "k (1 = fiber)", "cos theta_p"]
    if layers == 1:
        return one
    return ([f"{n} of layer {i}" for i in range(1, layers + 1) for n in one]
            + [f"cos(phi_p{i} - phi_p1)" for i in range(2, layers + 1)])


def output_names(layers: int) -> list[str]:
    if layers == 1:
        return ["alpha_ms", "f0_ms", "log tau_ms", "W1", "W2", "W2T"]
    return ([n for i in range(1, layers + 1) for n in (f"alpha{i}_ms", f"f0_{i}_ms",
                                                       f"log tau{i}_ms")]
            + [f"albedo{i}_ms" for i in range(2, layers + 1)] + ["W1", "W2", "W2T"])
