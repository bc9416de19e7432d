"""What SpongeCake's approximations cost and buy (issue 16, item 7): per stack, the error each
multiple-scattering option leaves against an independent full simulation, the time of one
model evaluation per direction pair, and the simulator's time to the same error.

Options: single scattering alone (``spongecake(...)``) and single scattering + the lobe fitted
per material (``multiple=lobe``, ``fitlab.learn.lobe.fit_lobe`` on its own simulation:
20,000 paths, seed 7), and for one or two flake layers the lobe the shipped networks predict
(``multiple=learned``; none for the plant leaf's hg layer).

Peer, in the same run: the simulator (``fitlab simulate``), every order, point estimates at the
centres of the 6 × 12 grid per side at θi = 0, 20, 40, 60, 75° (the lobe fit's grid), 100,000
paths per incidence, another seed (11) — the reference the errors are measured against, and the
cost of computing the same numbers directly. Errors: RMS relative error over the rows above
1e-3 of the largest (``layered_validation.compare``). "Simulator time for the model's error":
the warm simulation's time per incidence × (its RMS relative noise / the model's RMS relative
error)², the time until the simulation is as accurate as the model; per pair, divided by the
rows it estimates at once (144 per incidence). Model times: jitted, float64, 10⁵ random pairs,
best of 5 (``layered_validation.eval_time_us``).

Run: ``python benchmarks/spongecake_cost.py``.
"""

from __future__ import annotations

import time

import jax
import numpy as np
from layered_validation import _machine, compare, eval_time_us

from fitlab.models import get_model
from fitlab.models.presets import preset_params
from fitlab.simulate import scene_from_dict, simulate
from fitlab.learn.lobe import (THETA_I, fit_lobe, lobe_model_name, lobe_parameters,
                                    stack_scene)

jax.config.update("jax_enable_x64", True)

STACKS = {
    "bright surface layer": ("spongecake(surface_z)",
                             {"alpha1": 0.3, "albedo1": 0.95, "f0_1": 1.0, "tau1": 3.0}),
    "fabric preset (R)": ("spongecake(fiber,surface_z)", preset_params("fabric", "R")),
    "plant leaf preset (G)": ("spongecake(surface_z,hg,surface_z)",
                              preset_params("plant_leaf", "G")),
    "low-roughness fibers (Fig. 20)": ("spongecake(fiber)",
                                       {"alpha1": 0.05, "theta_p1": 90.0, "phi_p1": 0.0,
                                        "albedo1": 0.95, "f0_1": 1.0, "tau1": 3.0}),
}
N_REF = 100_000


def reference(name, params):
    """(measurement of the full simulation, warm seconds per incidence)."""
    kinds = tuple(name[name.index("(") + 1:-1].split(","))
    d = stack_scene(kinds, {"Y": params})
    warm = dict(d, illumination={"theta_i": [THETA_I[0]]})
    simulate(scene_from_dict(warm), N_REF, seed=1)  # compiles the walk for these shapes
    t0 = time.perf_counter()
    res = simulate(scene_from_dict(d), N_REF, seed=11)
    return res.to_measurement(), (time.perf_counter() - t0) / len(THETA_I)


def errors(model, params, ref):
    """{rms_rel_error, rms_rel_noise, ...} of ``model`` against the reference rows."""
    from layered_validation import _eval

    f = np.asarray(_eval(model, params, {}, ref.wi, ref.wo))
    return compare(ref.value, ref.sigma, f, ref.theta_o)


def main():
    print(f"# {_machine()}; reference {N_REF:,} paths per incidence, {len(THETA_I)} incidences")
    print("| stack | option | RMS rel. error vs simulation | eval µs / pair | simulator s / "
          "incidence (warm) | simulator s for the model's error, per incidence | per pair (µs) "
          "| simulator / model per pair |")
    print("|---|---|---|---|---|---|---|---|")
    for label, (name, params) in STACKS.items():
        t0 = time.perf_counter()
        fit, _ = fit_lobe(name, {"Y": params}, seed=7)
        with_lobe = lobe_parameters(fit, {"Y": params})["Y"]
        ref, t_inc = reference(name, params)
        rows = ref.n // len(THETA_I)
        options = [("single", name, params),
                   ("single + fitted lobe", lobe_model_name(name, "lobe"), with_lobe)]
        try:  # the shipped network: one flake layer
            get_model(lobe_model_name(name, "learned"))
            options.append(("single + learned lobe", lobe_model_name(name, "learned"), params))
        except ValueError:
            pass
        for option, model, p in options:
            e = errors(model, p, ref)
            t_eval = eval_time_us(model, p, {})
            t_sim = t_inc * (e["rms_rel_noise"] / max(e["rms_rel_error"], 1e-12)) ** 2
            per_pair = 1e6 * t_sim / rows
            print(f"| {label} `{name}` | {option} | {e['rms_rel_error']:.3f} (noise "
                  f"{e['rms_rel_noise']:.3f}) | {t_eval:.3f} | {t_inc:.1f} | {t_sim:.3g} | "
                  f"{per_pair:.3g} | {per_pair / t_eval:.3g} |")
        print(f"<!-- {label}: {time.perf_counter() - t0:.0f} s -->")


if __name__ == "__main__":
    main()
