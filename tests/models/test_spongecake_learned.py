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
from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.learn import network as sl
from fitlab.models import get_model
from fitlab.models import spongecake_network as net
from fitlab.models.spongecake_multiple import approximation


@pytest.mark.parametrize("layers", net.LAYERS)
def test_plain_jax_network_equals_equinox(layers):
    """mlp_apply (what the model evaluates, without equinox) gives the equinox MLP's outputs."""
    eqx = pytest.importorskip("equinox")
    n_in, n_out = net.n_inputs(layers), net.n_outputs(layers)
    m = eqx.nn.MLP(n_in, n_out, net.WIDTH, net.DEPTH, activation=jax.nn.relu,
                   key=jax.random.PRNGKey(3))
    x = jax.random.normal(jax.random.PRNGKey(4), (50, n_in))
    mean, scale = np.full(n_in, 0.3), np.full(n_in, 2.0)
    w = {k: jnp.asarray(v) for k, v in sl.to_weights(m, mean, scale).items()}
    np.testing.assert_allclose(np.asarray(net.mlp_apply(w, x)),
                               np.asarray(jax.vmap(m)((x - mean) / scale)), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("layers", net.LAYERS)
def test_outputs_map_into_the_lobe_bounds(layers):
    y = jnp.asarray(np.random.default_rng(0).normal(0, 30, (2000, net.n_outputs(layers))))
    lobe = net.lobe_from_outputs(y, layers)
    model = get_model(f"spongecake({','.join(['surface'] * layers)},multiple=only)")
    bounds = {p.name: (p.lower, p.upper) for p in model.parameters}
    held = {"theta_p", "phi_p"}
    assert set(lobe) == {p.name for p in model.parameters
                         if not p.name.rstrip("0123456789") in held}
    assert len(net.input_names(layers)) == net.n_inputs(layers)
    assert len(net.output_names(layers)) == net.n_outputs(layers)
    for k, v in lobe.items():
        v = np.asarray(v)
        assert np.all(np.isfinite(v)) and np.all(v >= bounds[k][0]) and np.all(v <= bounds[k][1]), k


@pytest.mark.parametrize("layers", net.LAYERS)
def test_training_stacks_are_deterministic_and_in_range(layers):
    a = [sl.stack_parameters(i, 0, layers) for i in range(200)]
    assert a == [sl.stack_parameters(i, 0, layers) for i in range(200)]
    assert a != [sl.stack_parameters(i, 1, layers) for i in range(200)]
    assert {k for k, _ in a} == set(__import__("itertools").product(sl.KINDS, repeat=layers))
    for _, p in a:
        for i in range(1, layers + 1):
            assert sl.ALPHA_RANGE[0] <= p[f"alpha{i}"] <= sl.ALPHA_RANGE[1]
            assert sl.TAU_RANGE[0] <= p[f"tau{i}"] <= sl.TAU_RANGE[1]
            assert 0 <= p[f"theta_p{i}"] <= 90
        assert p["phi_p1"] == 0
    if layers == 2:
        assert 0 < np.std([p["phi_p2"] for _, p in a]) and max(p["phi_p2"] for _, p in a) < 180
    assert sl.held_out(np.arange(100)).sum() == 10


def test_one_layer_stacks_are_the_shipped_datasets():
    """Adding two-layer stacks left the one-layer draws (the shipped weights' dataset) as they
    were: stack 0 of seed 0."""
    kinds, p = sl.stack_parameters(0, 0)
    assert kinds in {("surface",), ("fiber",)} and set(p) == {
        "alpha1", "theta_p1", "phi_p1", "albedo1", "f0_1", "tau1"}
    rng = np.random.default_rng([0, 0])
    assert kinds == (sl.KINDS[int(rng.integers(2))],)
    assert p["alpha1"] == float(np.exp(rng.uniform(np.log(0.05), np.log(1.0))))


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


def test_two_layer_stacks_read_per_layer_and_do_not_mix(tmp_path):
    d = tmp_path / "two"
    paths = sl.make_dataset(d, 2, seed=0, samples=200, layers=2)
    data = sl.load_dataset(paths)
    kinds, p = sl.stack_parameters(1, 0, 2)
    assert data["alpha"].shape == (2, 2) and data["phi_p"].shape == (2, 2)
    np.testing.assert_allclose(data["alpha"][1], [p["alpha1"], p["alpha2"]])
    np.testing.assert_allclose(data["phi_p"][1], [0.0, p["phi_p2"]])
    np.testing.assert_allclose(data["kind_is_fiber"][1], [k == "fiber" for k in kinds])
    one = sl.make_dataset(tmp_path / "one", 1, seed=0, samples=200)
    with pytest.raises(InputFileError, match="mixes stacks"):
        sl.load_dataset(paths + one)


@pytest.mark.parametrize("layers", net.LAYERS)
def test_predict_evaluates_each_stack_with_its_own_kinds(layers):
    """A network whose output is a constant (zero weights, a known bias) gives each stack §5's
    approximation of its own kinds (``spongecake(ITS KINDS,multiple=only)`` before the energy
    budget) at the constant's parameters."""
    rng = np.random.default_rng(7)
    n_in, n_out = net.n_inputs(layers), net.n_outputs(layers)
    bias = rng.normal(0, 1, n_out)
    w = {"x_mean": np.zeros(n_in), "x_scale": np.ones(n_in)}
    for i in range(net.DEPTH + 1):
        shape = (n_out if i == net.DEPTH else net.WIDTH, n_in if i == 0 else net.WIDTH)
        w[f"W{i}"], w[f"b{i}"] = np.zeros(shape), np.zeros(shape[0])
    w[f"b{net.DEPTH}"] = bias
    w = {k: jnp.asarray(v) for k, v in w.items()}
    data = _synthetic(n=8, rows=20, layers=layers)
    f = np.asarray(sl.predict(w, data, np.arange(8)))
    lobe = {k: float(v) for k, v in net.lobe_from_outputs(jnp.asarray(bias), layers).items()}
    for s_ in range(8):
        kinds = tuple("fiber" if x > 0.5 else "surface" for x in data["kind_is_fiber"][s_])
        stack = get_model(f"spongecake({','.join(kinds)},delta=false)")
        p = dict(lobe)
        for i in range(layers):
            p[f"theta_p{i + 1}"], p[f"phi_p{i + 1}"] = data["theta_p"][s_, i], data["phi_p"][s_, i]
        want = approximation(stack, {k: jnp.asarray(v) for k, v in p.items()},
                             jnp.asarray(data["wi"][s_]), jnp.asarray(data["wo"][s_]), True)
        np.testing.assert_allclose(f[s_], np.asarray(want), rtol=1e-10, atol=1e-14)


def _synthetic(n=60, rows=96, seed=0, layers=1):
    """Stacks whose 'multiple scattering' is the only-model at a known smooth mapping of the
    layers' parameters: a problem the network can learn exactly."""
    rng = np.random.default_rng(seed)
    out = {k: [] for k in sl.LAYER_KEYS + ("phi_p", "wi", "wo", "value", "sigma")}
    for i in range(n):
        kinds, p = sl.stack_parameters(i, seed, layers)
        stack = get_model(f"spongecake({','.join(kinds)},delta=false)")
        mu = rng.uniform(0.05, 1, (2, rows))
        ph = rng.uniform(0, 2 * np.pi, (2, rows))
        sgn = np.where(rng.uniform(size=rows) < 0.5, 1.0, -1.0)
        d = np.stack([np.sqrt(1 - mu**2) * np.cos(ph), np.sqrt(1 - mu**2) * np.sin(ph), mu], -1)
        wi, wo = d[0], d[1] * np.array([1, 1, 1.0])
        wo[:, 2] *= sgn
        truth = {"W1": 0.5 * p["albedo1"], "W2": 0.1 * p["albedo1"], "W2T": 0.05}
        for j in range(1, layers + 1):
            truth.update({f"theta_p{j}": p[f"theta_p{j}"], f"phi_p{j}": p[f"phi_p{j}"],
                          f"alpha{j}_ms": 0.3 + 0.5 * p[f"alpha{j}"],
                          f"albedo{j}_ms": 1.0 if j == 1 else 0.5 * p[f"albedo{j}"],
                          f"f0_{j}_ms": p[f"f0_{j}"], f"tau{j}_ms": 2 * p[f"tau{j}"]})
        v = np.asarray(approximation(stack, {k: jnp.asarray(x) for k, x in truth.items()},
                                     jnp.asarray(wi), jnp.asarray(wo), True))
        per = lambda key: [p[f"{key}{j}"] for j in range(1, layers + 1)]  # noqa: E731
        for k, x in (("kind_is_fiber", [float(k == "fiber") for k in kinds]),
                     ("alpha", per("alpha")), ("albedo", per("albedo")), ("tau", per("tau")),
                     ("f0", per("f0_")), ("cos_theta_p", np.cos(np.radians(per("theta_p")))),
                     ("theta_p", per("theta_p")), ("phi_p", per("phi_p")), ("wi", wi),
                     ("wo", wo), ("value", v), ("sigma", 0.01 * v)):
            out[k].append(x)
    data = {k: np.asarray(v, dtype=float) for k, v in out.items()}
    data["index"], data["skipped"] = np.arange(n), 0
    return data


@pytest.mark.slow
@pytest.mark.parametrize("layers", net.LAYERS)
def test_training_learns_a_known_mapping(layers):
    """On stacks made by a known mapping, training lowers the loss from its start by far and the
    held-out stacks follow."""
    pytest.importorskip("equinox")
    data = _synthetic(layers=layers)
    losses = []
    _, report = sl.train(data, steps=600, seed=1,
                         progress=lambda k, n, loss: losses.append(loss))
    assert losses[-1] < 0.3 * losses[0], losses
    assert report["held_out_loss"] < 0.3 and report["train_loss"] < 0.3, report


@pytest.mark.parametrize("layers", net.LAYERS)
def test_shipped_weights_match_their_provenance(layers):
    prov = net.provenance(layers)
    assert hashlib.sha256(net.WEIGHTS[layers].read_bytes()).hexdigest() == prov["weights_sha256"]
    assert prov["dataset"]["stacks"] >= 1000 and prov["errors"]["held_out_stacks"] > 0
    assert prov["dataset"]["layers"] == layers
    assert prov["network"]["inputs"] == net.input_names(layers)
    w = net.load_weights(layers)
    assert w["W0"].shape == (net.WIDTH, net.n_inputs(layers))
    assert w[f"W{net.DEPTH}"].shape == (net.n_outputs(layers), net.WIDTH)


# The one-layer network in float64 in the quick tier (the registry contract's multiple=learned
# models, oriented layers under the lobe's energy budget, run in the whole suite only); its
# float32 copy (8 s, a second compilation of the same code) and the two-layer networks, 9-10 s
# each to compile with the budget's tables, in the whole suite, as the contract's float32
# layered cases (tests/models/test_model_contract.py: QUICK_FLOAT32_LAYERED).
@pytest.mark.parametrize("kinds", ["fiber", pytest.param("surface,fiber", marks=pytest.mark.slow),
                                   pytest.param("fiber_z,surface", marks=pytest.mark.slow)])
@pytest.mark.parametrize("dtype", [pytest.param("float32", marks=pytest.mark.slow), "float64"])
def test_learned_model_values_and_gradients_are_finite(dtype, kinds):
    """multiple=learned: the network inside the model, differentiable, on the hard cases."""
    m = get_model(f"spongecake({kinds},multiple=learned)")
    assert m.parameter_names == get_model(f"spongecake({kinds})").parameter_names
    rng = np.random.default_rng(2)
    t_i, t_o = rng.uniform(0, 89.99, 64), rng.uniform(0, 179.99, 64)
    from fitlab.io.directions import degrees_to_direction
    wi = jnp.asarray(degrees_to_direction(t_i, 0 * t_i), dtype=dtype)
    wo = jnp.asarray(degrees_to_direction(t_o, rng.uniform(-180, 180, 64)), dtype=dtype)
    # one compiled call for every parameter set (op by op it compiled each operation: 3x slower)
    values_and_gradients = jax.jit(lambda q: (m.eval(q, wi, wo), jax.grad(
        lambda r: jnp.sum(m.eval(r, wi, wo)))(q)))
    for alpha, tau in ((1e-3, 1e-4), (0.3, 1.0), (1.0, 100.0)):
        p = {"alpha1": alpha, "theta_p1": 60.0, "phi_p1": 10.0, "albedo1": 0.9, "f0_1": 0.5,
             "tau1": tau, "alpha2": 0.5, "theta_p2": 0.0, "phi_p2": 100.0, "albedo2": 0.7,
             "f0_2": 0.3, "tau2": 2.0}
        p = {k: jnp.asarray(v, dtype=dtype) for k, v in p.items() if k in m.parameter_names}
        f, g = values_and_gradients(p)
        assert np.all(np.isfinite(np.asarray(f))) and np.all(np.asarray(f) >= 0)
        assert all(np.all(np.isfinite(np.asarray(v))) for v in g.values())
        assert np.any(np.asarray(g["albedo1"]) != 0)  # the lobe follows the layer


@pytest.mark.parametrize("name", ["spongecake(hg,multiple=learned)",
                                  "spongecake(surface,hg,multiple=learned)",
                                  "spongecake(surface,surface,fiber,multiple=learned)",
                                  "spongecake(surface,substrate=lambertian,multiple=learned)"])
def test_learned_refuses_what_it_was_not_trained_on(name):
    with pytest.raises(ValueError, match="trained for one or two layers of flakes"):
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
    # two processes remake what is missing, byte for byte
    stacks = {p.name: p.read_bytes() for p in d.glob("*.npz")}
    for name in ("stack_00003.npz", "stack_00004.npz", "stack_00008.npz"):
        (d / name).unlink()
    assert main([*args, "--out", str(b), "--quiet", "--jobs", "2"]) == 0
    assert {p.name: p.read_bytes() for p in d.glob("*.npz")} == stacks
    assert a.read_bytes() == b.read_bytes()
    prov = json.loads(a.with_suffix(".json").read_text())
    assert prov["dataset"]["stacks"] == 10 and prov["errors"]["held_out_stacks"] == 1
    assert str(tmp_path) not in a.with_suffix(".json").read_text()
