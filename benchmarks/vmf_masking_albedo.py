"""How much the vMF masking changes the simulator's reflectance (issue 15, item 5): the directional
albedo (flux leaving upward, ``SimulationResult.energy``) of thin-layer stacks traced with the
exact masking of the vMF NDF (the extended-NDF paper's eq. 7 integrated, ``masking = "exact"``,
the scenes' default) against the paper's eq. 8 (``masking = "approx"``).

Stacks: a rough vMF top interface (κ1) over a clear layer of index 1.5 (thickness 0) over a rough
vMF substrate (κ2): dielectric of index η2 (what it transmits is lost, as in
``thin_layer(rough_dielectric)``) or chromium (n, k = 3.18, 4.41), both boundaries with the same
masking; κ1, κ2 ∈ {10, 100, 1000}; θi = 0, 30, 60°.

Both maskings run with the same seeds, so their paths share every random number (the walk's
uniforms are a function of seed, iteration, lane and slot; the microfacet normals are sampled
from D alone): they are the same paths with other weights, and Russian roulette is off so that
no weight-dependent decision separates them. The difference's standard error is the spread of
the per-seed differences over ``--seeds`` independent seeds.

    .venv/bin/python benchmarks/vmf_masking_albedo.py [--samples 262144] [--seeds 8]
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from fitlab.simulate import scene_from_dict, simulate  # noqa: E402

KAPPAS = (10.0, 100.0, 1000.0)
THETAS_I = (0.0, 30.0, 60.0)
#: substrates: (label, [substrate] table without distribution and kappa)
SUBSTRATES = (("η2 = 1.3", {"type": "dielectric", "index": 1.3}),
              ("η2 = 2", {"type": "dielectric", "index": 2.0}),
              ("chromium", {"type": "conductor", "n": 3.18, "k": 4.41}))


def scene(k1, k2, substrate, masking):
    return scene_from_dict({
        "name": "vmf masking albedo",
        "stack": [{"type": "interface", "distribution": "vmf", "kappa": k1, "masking": masking},
                  {"type": "medium", "index": 1.5, "thickness": 0.0}],
        "substrate": {**substrate, "distribution": "vmf", "kappa": k2, "masking": masking},
        "illumination": {"theta_i": list(THETAS_I)},
        "detector": {"type": "hemisphere", "sides": ["reflection"], "theta_bins": 1,
                     "phi_bins": 1},
        "effects": {"russian_roulette": False}})


def albedos(k1, k2, substrate, masking, samples, seeds):
    """(seeds, θi) upward flux fractions and the runs' paths lost to the event cap."""
    out, truncated = [], 0
    for seed in range(seeds):
        r = simulate(scene(k1, k2, substrate, masking), samples, seed=seed)
        out.append(r.energy[:, 0, 0])
        truncated += r.truncated
    return np.array(out), truncated


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=1 << 18, help="paths per seed and incidence")
    ap.add_argument("--seeds", type=int, default=8, help="independent seeds (paired)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    print(f"{args.seeds} seeds x {args.samples} paths per incidence and masking; R = upward "
          "flux fraction; diff = R_exact / R_approx - 1 with its standard error\n")
    print("| substrate | κ1 | κ2 | θi | R exact | R approx | diff | ± |")
    print("|---|---|---|---|---|---|---|---|")
    diffs = []
    for (label, sub), k1, k2 in itertools.product(SUBSTRATES, KAPPAS, KAPPAS):
        ex, te = albedos(k1, k2, sub, "exact", args.samples, args.seeds)
        ap_, ta = albedos(k1, k2, sub, "approx", args.samples, args.seeds)
        if te or ta:
            print(f"warning: {te + ta} paths truncated", file=sys.stderr)
        n = args.seeds
        for j, ti in enumerate(THETAS_I):
            re_, ra = ex[:, j].mean(), ap_[:, j].mean()
            se_e, se_a = ex[:, j].std(ddof=1) / np.sqrt(n), ap_[:, j].std(ddof=1) / np.sqrt(n)
            d = ex[:, j] / ap_[:, j] - 1.0
            rel, se = re_ / ra - 1.0, d.std(ddof=1) / np.sqrt(n)
            diffs.append(rel)
            print(f"| {label} | {k1:g} | {k2:g} | {ti:g}° | {re_:.5f} ± {se_e:.5f} | "
                  f"{ra:.5f} ± {se_a:.5f} | {100 * rel:+.3f}% | {100 * se:.4f}% |", flush=True)
    print(f"\nrange of diff: {100 * min(diffs):+.3f}% .. {100 * max(diffs):+.3f}%; "
          f"{time.perf_counter() - t0:.0f} s, JAX {jax.__version__} on {jax.default_backend()}")


if __name__ == "__main__":
    main()
