"""SpongeCake against the simulator, bin by bin (issue 16, item 4): χ² per point of

* the simulator's single scattering with another seed against itself: how far χ²/dof strays
  from 1 when nothing but Monte Carlo noise differs (the points are correlated: every path
  contributes a next-event estimate to every point),
* the model's single scattering (plus, over a substrate, the substrate seen through the stack)
  against the simulator's single scattering (``volume_scattering = "single"``, the stack alone)
  plus, over a substrate, its unscattered substrate (``"none"``, the stack over the substrate):
  exactly what §4.1–4.4 compute (the simulator's "single" over a substrate would also count
  paths that scatter once and meet the substrate, which the model leaves to the lobe),
* the same single scattering against the simulator's full result (every order): what is left
  without a multiple-scattering term,
* single scattering + the multiple-scattering lobe fitted to this stack (``multiple=lobe``,
  :func:`fitlab.learn.lobe.fit_lobe` on the stack alone, from a simulation with its own
  seed; over a substrate the stack's lobe sits above it) against the full result,
* single scattering + the lobe the shipped network predicts (``multiple=learned``: one or two
  flake layers, no substrate) against the full result,

for one and two layers, surface and fiber flakes, with and without a Lambertian substrate,
reflection and transmission each on its own. The validation simulation is independent of the
one the lobe was fitted to (another seed, more paths). Point estimates at the centres of a
6 × 12 grid per side; χ²/dof = mean of ((f − v)/σ)² over the points the simulation reached, σ
its Monte Carlo standard error. "RMS rel." is the RMS relative error over points above 1e-3 of
the largest value. Run: ``python benchmarks/spongecake_validation.py`` (about 10 min here).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from fitlab.models import get_model
from fitlab.simulate import scene_from_dict, simulate
from fitlab.learn.lobe import fit_lobe, lobe_parameters, stack_scene

jax.config.update("jax_enable_x64", True)

THETA_I = (0.0, 30.0, 60.0, 75.0)
SAMPLES_FIT, SAMPLES_CHECK = 20_000, 200_000
SUBSTRATE = {"type": "lambertian", "albedo": 0.6}
SURFACE = {"alpha1": 0.3, "theta_p1": 20.0, "phi_p1": 30.0, "albedo1": 0.9, "f0_1": 0.6,
           "tau1": 2.0}
FIBER = {"alpha1": 0.5, "theta_p1": 90.0, "phi_p1": 0.0, "albedo1": 0.95, "f0_1": 0.8,
         "tau1": 1.5}
TWO = {**FIBER, "alpha2": 0.2, "theta_p2": 10.0, "phi_p2": 60.0, "albedo2": 0.8, "f0_2": 0.5,
       "tau2": 3.0}
#: (layer kinds, their parameters, with the substrate?)
CASES = [
    (("surface",), SURFACE, False),
    (("fiber",), FIBER, False),
    (("fiber", "surface"), TWO, False),
    (("surface",), SURFACE, True),
    (("fiber", "surface"), TWO, True),
]


def check_scene(kinds, params, substrate, scattering="multiple"):
    d = stack_scene(kinds, {"Y": params}, theta_i=THETA_I)
    d["effects"]["volume_scattering"] = scattering
    if substrate:
        d["substrate"] = dict(SUBSTRATE)
        d["detector"]["sides"] = ["reflection"]
    return scene_from_dict(d)


def single_scattering(kinds, params, substrate, seed=2):
    """(measurement, value, sigma): the simulator's counterpart of the model's single
    scattering (+ unscattered substrate), on the grid of :func:`check_scene`."""
    m = simulate(check_scene(kinds, params, False, "single"), SAMPLES_CHECK, seed=seed)
    m = m.to_measurement()
    if not substrate:
        return m, m.value, m.sigma
    s = simulate(check_scene(kinds, params, True, "none"), SAMPLES_CHECK, seed=seed + 1)
    s = s.to_measurement()
    # the same reflection grid; the stack alone also fills the transmission side
    up = m.wo[:, 2] > 0
    key = lambda w: tuple(np.round(w, 9).ravel())  # noqa: E731
    at = {key(np.r_[a, b]): j for j, (a, b) in enumerate(zip(s.wi, s.wo))}
    idx = np.asarray([at.get(key(np.r_[a, b]), -1) for a, b in zip(m.wi[up], m.wo[up])])
    ok = idx >= 0
    m = m._replace(**{k: getattr(m, k)[up][ok] for k in ("wi", "wo", "value", "sigma")})
    return m, m.value + s.value[idx[ok]], np.hypot(m.sigma, s.sigma[idx[ok]])


def stats(f, v, s):
    """χ²/dof over the points with σ > 0, RMS relative error over points above 1e-3 of the
    largest, and the points' count."""
    keep = s > 0
    chi2 = float(np.mean(((f - v)[keep] / s[keep]) ** 2))
    big = v > 1e-3 * np.max(np.abs(v))
    rms = float(np.sqrt(np.mean(((f - v)[big] / v[big]) ** 2)))
    return chi2, rms, int(keep.sum())


def model_f(name, params, m):
    model = get_model(name)
    p = {k: jnp.asarray(v) for k, v in params.items() if k in model.parameter_names}
    return np.asarray(model.eval(p, jnp.asarray(m.wi), jnp.asarray(m.wo)))


def main():
    print(f"# lobe fits: {SAMPLES_FIT:,} paths per incidence (seed 0); validation: "
          f"{SAMPLES_CHECK:,} paths per incidence (seed 1), incidences {THETA_I}")
    print("| stack | side | points | simulated SS, seed 2 vs seed 4: χ²/dof | SS vs simulated SS: "
          "χ²/dof (max \\|z\\|) | SS vs every order: χ²/dof (RMS rel.) "
          "| SS + fitted lobe: χ²/dof (RMS rel.) | SS + learned lobe: χ²/dof (RMS rel.) |")
    print("|---|---|---|---|---|---|---|---|")
    lobes = {}
    for kinds, params, substrate in CASES:
        t0 = time.perf_counter()
        if kinds not in lobes:
            fit, _ = fit_lobe(f"spongecake({','.join(kinds)})", {"Y": params},
                              samples=SAMPLES_FIT, seed=0)
            lobes[kinds] = lobe_parameters(fit, {"Y": params})["Y"]
        full = simulate(check_scene(kinds, params, substrate), SAMPLES_CHECK,
                        seed=1).to_measurement()
        single, v1, s1 = single_scattering(kinds, params, substrate)
        _, v2, s2 = single_scattering(kinds, params, substrate, seed=4)
        k = ",".join(kinds)
        sub = ",substrate=lambertian" if substrate else ""
        p = {**params, "albedo": SUBSTRATE["albedo"]}
        names = {"SS": f"spongecake({k}{sub})",
                 "fitted": f"spongecake({k}{sub},multiple=lobe)",
                 "learned": None if substrate else f"spongecake({k},multiple=learned)"}
        f_ss1 = model_f(names["SS"], p, single)
        f = {key: (model_f(n, {**p, **lobes[kinds]}, full) if n else None)
             for key, n in names.items()}
        for side, sign in (("reflection", 1.0), ("transmission", -1.0)):
            rows = full.wo[:, 2] * sign > 0
            rows1 = single.wo[:, 2] * sign > 0
            if not rows.any():
                continue
            c1 = stats(f_ss1[rows1], v1[rows1], s1[rows1])
            both = rows1 & (s2 > 0)
            c0 = stats(v2[both], v1[both], np.hypot(s1, s2)[both])
            z1 = np.abs(f_ss1 - v1)[rows1 & (s1 > 0)] / s1[rows1 & (s1 > 0)]
            cells = []
            for key in ("SS", "fitted", "learned"):
                if f[key] is None:
                    cells.append("n/a (substrate)")
                    continue
                chi2, rms, _ = stats(f[key][rows], full.value[rows], full.sigma[rows])
                cells.append(f"{chi2:.3g} ({rms:.3g})")
            label = f"`spongecake({k}{sub})`"
            print(f"| {label} | {side} | {int(rows.sum())} | {c0[0]:.3g} | {c1[0]:.3g} "
                  f"({z1.max():.2g}) | " + " | ".join(cells)
                  + " |", flush=True)
        print(f"#   {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
