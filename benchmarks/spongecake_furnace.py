"""White furnace of SpongeCake stacks (issue 16, item 4): the albedo R + T per incidence angle
of non-absorbing stacks (γ = 1, f0 = 1: every photon leaves), for

* the model's single scattering alone, plus its declared delta transmission
  (mean sample weight of ``model.sample`` + ``delta_transmittance``),
* the simulator's single scattering (``volume_scattering = "single"``), the same quantity
  traced independently,
* the model with its multiple-scattering lobe (§5, ``multiple=lobe``) fitted to this stack by
  ``fitlab.learn.lobe.fit_lobe`` (the simulator's multiple-scattering part on a 6 × 12
  grid per side at 5 incidences, 20,000 paths each, its own seed), plus the delta,
* the model with the lobe the shipped networks predict (``multiple=learned``; one or two flake
  layers), plus the delta,
* the simulator's full result (every order), which is 1 up to Monte Carlo error.

The gap between the first and the last column is what the multiple-scattering lobe has to
supply; the lobe's own fit (χ²/dof and RMS relative error over the multiple-scattering part)
says how well its shape does. The last stack is the paper's Fig. 20 failure case, fibers of
low roughness. Run: ``python benchmarks/spongecake_furnace.py``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from fitlab.models import get_model
from fitlab.models.spongecake import Layer, delta_transmittance, simulator_stack
from fitlab.simulate import simulate
from fitlab.simulate.scene import scene_from_dict
from fitlab.learn.lobe import fit_lobe, lobe_model_name, lobe_parameters, stack_call

jax.config.update("jax_enable_x64", True)

THETA_I = (0.0, 30.0, 60.0, 80.0)
STACKS = {
    "spongecake(surface_z)": {"alpha1": 0.3, "albedo1": 1.0, "f0_1": 1.0, "tau1": 1.0},
    "spongecake(fiber_z,surface_z)": {"alpha1": 0.5, "albedo1": 1.0, "f0_1": 1.0, "tau1": 1.0,
                                      "alpha2": 0.8, "albedo2": 1.0, "f0_2": 1.0, "tau2": 3.0},
    "spongecake(fiber_z)": {"alpha1": 0.1, "albedo1": 1.0, "f0_1": 1.0, "tau1": 3.0},
    "spongecake(fiber)": {"alpha1": 0.05, "theta_p1": 90.0, "phi_p1": 0.0, "albedo1": 1.0,
                          "f0_1": 1.0, "tau1": 3.0},
}
N_MODEL, N_SIM = 400_000, 200_000


def model_albedo(name, params, theta, kinds):
    m = get_model(name)
    t = np.radians(theta)
    wi = jnp.tile(jnp.asarray([np.sin(t), 0.0, np.cos(t)]), (N_MODEL, 1))
    u = jax.random.uniform(jax.random.PRNGKey(0), (N_MODEL, 3), jnp.float64)
    _, w, _ = m.sample({k: jnp.asarray(v) for k, v in params.items()}, wi, u)
    layers = tuple(Layer(k, i + 1) for i, k in enumerate(kinds))
    delta = float(delta_transmittance(layers, params, wi[0]))
    return float(jnp.mean(w)), float(jnp.std(w) / np.sqrt(N_MODEL)), delta


def simulated_albedo(kinds, params, scattering):
    d = {"stack": simulator_stack(kinds, {"Y": params}),
         "illumination": {"theta_i": list(THETA_I)},
         "detector": {"type": "hemisphere", "sides": ["reflection", "transmission"],
                      "theta_bins": 3, "phi_bins": 4},
         "effects": {"volume_scattering": scattering}}
    res = simulate(scene_from_dict(d), samples=N_SIM, seed=1)
    e = res.energy[:, :, 0].sum(axis=1)
    s = np.sqrt((res.energy_sigma[:, :, 0] ** 2).sum(axis=1))
    return e, s


def main():
    print(f"# paths: model {N_MODEL:,} samples, simulator {N_SIM:,} per incidence")
    print("| stack | θi | model single + delta | simulator single (+ delta) | model single + "
          "fitted lobe + delta | model single + learned lobe + delta | simulator, every order | "
          "missing from single scattering |")
    print("|---|---|---|---|---|---|---|---|")
    fits = []
    for name, params in STACKS.items():
        t0 = time.perf_counter()
        kinds = stack_call(name)
        fit, _ = fit_lobe(name, {"Y": params}, seed=7)
        lobe = lobe_parameters(fit, {"Y": params})["Y"]
        st = fit.statistics("Y")
        fits.append((name, st["chi2_per_dof"], st["fit_error"]["rms_relative_error"], fit.parameters["Y"]))
        rows = [model_albedo(name, params, th, kinds) for th in THETA_I]
        with_lobe = [model_albedo(lobe_model_name(name, "lobe"), lobe, th, kinds)
                     for th in THETA_I]
        learned = [model_albedo(lobe_model_name(name, "learned"), params, th, kinds)
                   for th in THETA_I]
        single, s_single = simulated_albedo(kinds, params, "single")
        full, s_full = simulated_albedo(kinds, params, "multiple")
        for j, th in enumerate(THETA_I):
            a, sa, delta = rows[j]
            b, sb, _ = with_lobe[j]
            c = f"{learned[j][0] + delta:.4f} ± {learned[j][1]:.4f}"
            print(f"| `{name}` | {th:.0f}° | {a + delta:.4f} ± {sa:.4f} | {single[j]:.4f} ± "
                  f"{s_single[j]:.4f} | {b + delta:.4f} ± {sb:.4f} | {c} | {full[j]:.4f} ± "
                  f"{s_full[j]:.4f} | {full[j] - a - delta:.4f} |")
        print(f"<!-- {name}: {time.perf_counter() - t0:.1f} s -->")
    print()
    print("| stack | lobe fit χ²/dof | RMS relative error of the lobe over the multiple-"
          "scattering part | W1 | W2 | W2T |")
    print("|---|---|---|---|---|---|")
    for name, chi2, rms, p in fits:
        print(f"| `{name}` | {chi2:.3g} | {rms:.3g} | {p['W1']:.3g} | {p['W2']:.3g} | "
              f"{p['W2T']:.3g} |")


if __name__ == "__main__":
    main()
