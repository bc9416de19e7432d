"""SpongeCake's parameter-mapping network (§5): the plain-JAX evaluation against equinox, the
dataset (deterministic, resumable, validated on reading), training, the shipped weights and
`fitlab learn-lobe`."""

from __future__ import annotations

import hashlib
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitlab  # noqa: F401  (x64)
from fitlab import spongecake_learned as sl
from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.models import get_model


def test_plain_jax_network_equals_equinox():
    """mlp_apply (what the model evaluates, without equinox) gives the equinox MLP's outputs."""
    eqx = pytest.importorskip("equinox")
    m = eqx.nn.MLP(sl.N_IN, sl.N_OUT, sl.WIDTH, sl.DEPTH, activation=jax.nn.relu,
                   key=jax.random.PRNGKey(3))
    x = jax.random.normal(jax.random.PRNGKey(4), (50, sl.N_IN))
    mean, scale = np.full(sl.N_IN, 0.3), np.full(sl.N_IN, 2.0)
    w = {k: jnp.asarray(v) for k, v in sl.to_weights(m, mean, scale).items()}
    np.testing.assert_allclose(np.asarray(sl.mlp_apply(w, x)),
                               np.asarray(jax.vmap(m)((x - mean) / scale)), rtol=1e-6, atol=1e-6)


def test_outputs_map_into_the_lobe_bounds():
    y = jnp.asarray(np.random.default_rng(0).normal(0, 30, (2000, sl.N_OUT)))
    lobe = sl.lobe_from_outputs(y)
    model = get_model("spongecake(surface,multiple=only)")
    bounds = {p.name: (p.lower, p.upper) for p in model.parameters}
    for k, v in lobe.items():
        v = np.asarray(v)
        assert np.all(np.isfinite(v)) and np.all(v >= bounds[k][0]) and np.all(v <= bounds[k][1]), k


def test_training_stacks_are_deterministic_and_in_range():
    a = [sl.stack_parameters(i, 0) for i in range(200)]
    assert a == [sl.stack_parameters(i, 0) for i in range(200)]
    assert a != [sl.stack_parameters(i, 1) for i in range(200)]
    assert {k for k, _ in a} == set(sl.KINDS)
    for _, p in a:
        assert sl.ALPHA_RANGE[0] <= p["alpha1"] <= sl.ALPHA_RANGE[1]
        assert sl.TAU_RANGE[0] <= p["tau1"] <= sl.TAU_RANGE[1]
        assert 0 <= p["theta_p1"] <= 90
    assert sl.held_out(np.arange(100)).sum() == 10


def test_dataset_is_resumable_byte_identical_and_validated(tmp_path):
    d = tmp_path / "stacks"
    paths = sl.make_dataset(d, 2, seed=0, samples=300)
    first = [p.read_bytes() for p in paths]
    mtime = paths[0].stat().st_mtime_ns
    sl.make_dataset(d, 3, seed=0, samples=300)  # resumes: makes stack 2 only
    assert paths[0].stat().st_mtime_ns == mtime and (d / "stack_00002.npz").exists()
    paths[1].unlink()
    sl.make_dataset(d, 3, seed=0, samples=300)
    assert [p.read_bytes() for p in paths] == first  # same seed, same bytes
    data = sl.load_dataset(sorted(d.glob("*.npz")))
    assert data["value"].shape[0] == 3 and data["wi"].shape[-1] == 3
    # hostile files: truncated, and a stack without its values
    bad = d / "stack_00001.npz"
    bad.write_bytes(first[1][: len(first[1]) // 2])
    with pytest.raises(InputFileError, match="stack_00001"):
        sl.load_dataset(sorted(d.glob("*.npz")))
    from fitlab.export.paramfile import chain_bytes
    bad.write_bytes(chain_bytes({"alpha": np.array(0.3)}))
    with pytest.raises(InputFileError, match="has no"):
        sl.load_dataset(sorted(d.glob("*.npz")))


def _synthetic(n=60, rows=96, seed=0):
    """Stacks whose 'multiple scattering' is the only-model at a known smooth mapping of the
    layer's parameters: a problem the network can learn exactly."""
    rng = np.random.default_rng(seed)
    only = {k: get_model(f"spongecake({k},multiple=only)") for k in sl.KINDS}
    out = {k: [] for k in ("kind_is_fiber", "alpha", "albedo", "tau", "f0", "cos_theta_p",
                           "theta_p", "wi", "wo", "value", "sigma")}
    for i in range(n):
        kind, p = sl.stack_parameters(i, seed)
        mu = rng.uniform(0.05, 1, (2, rows))
        ph = rng.uniform(0, 2 * np.pi, (2, rows))
        sgn = np.where(rng.uniform(size=rows) < 0.5, 1.0, -1.0)
        d = np.stack([np.sqrt(1 - mu**2) * np.cos(ph), np.sqrt(1 - mu**2) * np.sin(ph), mu], -1)
        wi, wo = d[0], d[1] * np.array([1, 1, 1.0])
        wo[:, 2] *= sgn
        truth = {"theta_p1": p["theta_p1"], "phi_p1": 0.0, "alpha1_ms": 0.3 + 0.5 * p["alpha1"],
                 "albedo1_ms": 1.0, "f0_1_ms": p["f0_1"], "tau1_ms": 2 * p["tau1"],
                 "W1": 0.5 * p["albedo1"], "W2": 0.1 * p["albedo1"], "W2T": 0.05}
        v = np.asarray(only[kind].eval({k: jnp.asarray(x) for k, x in truth.items()},
                                       jnp.asarray(wi), jnp.asarray(wo)))
        for k, x in (("kind_is_fiber", float(kind == "fiber")), ("alpha", p["alpha1"]),
                     ("albedo", p["albedo1"]), ("tau", p["tau1"]), ("f0", p["f0_1"]),
                     ("cos_theta_p", np.cos(np.radians(p["theta_p1"]))),
                     ("theta_p", p["theta_p1"]), ("wi", wi), ("wo", wo), ("value", v),
                     ("sigma", 0.01 * v)):
            out[k].append(x)
    data = {k: np.asarray(v, dtype=float) for k, v in out.items()}
    data["index"], data["skipped"] = np.arange(n), 0
    return data


@pytest.mark.slow
def test_training_learns_a_known_mapping():
    """On stacks made by a known mapping, training lowers the loss from its start by far and the
    held-out stacks follow."""
    pytest.importorskip("equinox")
    data = _synthetic()
    losses = []
    _, report = sl.train(data, steps=600, seed=1,
                         progress=lambda k, n, loss: losses.append(loss))
    assert losses[-1] < 0.3 * losses[0], losses
    assert report["held_out_loss"] < 0.3 and report["train_loss"] < 0.3, report


def test_shipped_weights_match_their_provenance():
    prov = sl.provenance()
    assert hashlib.sha256(sl.WEIGHTS.read_bytes()).hexdigest() == prov["weights_sha256"]
    assert prov["dataset"]["stacks"] >= 1000 and prov["errors"]["held_out_stacks"] > 0
    w = sl.load_weights()
    assert w["W0"].shape == (sl.WIDTH, sl.N_IN) and w[f"W{sl.DEPTH}"].shape == (sl.N_OUT, sl.WIDTH)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_learned_model_values_and_gradients_are_finite(dtype):
    """multiple=learned: the network inside the model, differentiable, on the hard cases."""
    m = get_model("spongecake(fiber,multiple=learned)")
    assert m.parameter_names == get_model("spongecake(fiber)").parameter_names
    rng = np.random.default_rng(2)
    t_i, t_o = rng.uniform(0, 89.99, 64), rng.uniform(0, 179.99, 64)
    from fitlab.io.directions import degrees_to_direction
    wi = jnp.asarray(degrees_to_direction(t_i, 0 * t_i), dtype=dtype)
    wo = jnp.asarray(degrees_to_direction(t_o, rng.uniform(-180, 180, 64)), dtype=dtype)
    for alpha, tau in ((1e-3, 1e-4), (0.3, 1.0), (1.0, 100.0)):
        p = {"alpha1": alpha, "theta_p1": 60.0, "phi_p1": 10.0, "albedo1": 0.9, "f0_1": 0.5,
             "tau1": tau}
        p = {k: jnp.asarray(v, dtype=dtype) for k, v in p.items()}
        f = m.eval(p, wi, wo)
        g = jax.grad(lambda q: jnp.sum(m.eval(q, wi, wo)))(p)
        assert np.all(np.isfinite(np.asarray(f))) and np.all(np.asarray(f) >= 0)
        assert all(np.all(np.isfinite(np.asarray(v))) for v in g.values())
        assert np.any(np.asarray(g["albedo1"]) != 0)  # the lobe follows the layer


@pytest.mark.parametrize("name", ["spongecake(hg,multiple=learned)",
                                  "spongecake(surface,surface,multiple=learned)",
                                  "spongecake(surface,substrate=lambertian,multiple=learned)"])
def test_learned_refuses_what_it_was_not_trained_on(name):
    with pytest.raises(ValueError, match="trained for one layer of flakes"):
        get_model(name)


@pytest.mark.parametrize("argv, fragment", [
    (["--stacks", "5"], "at least 10"),
    (["--steps", "0"], "--steps"),
    (["--out-ext"], ".npz"),
])
def test_cli_bad_arguments_exit_2(tmp_path, capsys, argv, fragment):
    out = tmp_path / "w.npz"
    if argv == ["--out-ext"]:
        argv, out = [], tmp_path / "w.txt"
    assert main(["learn-lobe", "--dir", str(tmp_path / "d"), "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err and not out.exists()


@pytest.mark.slow
def test_cli_learns_resumes_and_repeats_byte_for_byte(tmp_path, capsys):
    d, a, b = tmp_path / "d", tmp_path / "a.npz", tmp_path / "b.npz"
    args = ["learn-lobe", "--dir", str(d), "--stacks", "10", "--samples", "300", "--steps", "30"]
    assert main([*args, "--out", str(a)]) == 0
    assert "held-out loss" in capsys.readouterr().err
    stamp = {p.name: p.stat().st_mtime_ns for p in d.glob("*.npz")}
    assert main([*args, "--out", str(b), "--quiet"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in d.glob("*.npz")} == stamp  # nothing remade
    assert a.read_bytes() == b.read_bytes()
    prov = json.loads(a.with_suffix(".json").read_text())
    assert prov["dataset"]["stacks"] == 10 and prov["errors"]["held_out_stacks"] == 1
    assert str(tmp_path) not in a.with_suffix(".json").read_text()
