"""SpongeCake's multiple-scattering lobe two ways on the same held-out stacks (issue 16, item 3):
(a) fitted per material (``fitlab.learn.lobe.fit_lobe``: global search + Levenberg–Marquardt
on the stack's own simulated multiple-scattering part) and (b) predicted by the shipped network
(``spongecake(K[,K2],multiple=learned)``, fitlab/models/data/spongecake_ms_1layer.npz or
spongecake_ms_2layer.npz, by the dataset's number of layers), which never saw these stacks.

Errors per stack against its simulated multiple-scattering part: the training loss (mean
|f − data| / mean |data|) and the RMS relative error over rows above 1e-3 of the largest; the
data's own noise in the same measure (mean σ·sqrt(2/π) / mean |data|) beside them, with the
fit's and the network's time per stack.

Run: ``python benchmarks/spongecake_learned_vs_fit.py DIR [--stacks 20]`` (DIR: the dataset
the weights were trained on, made by ``fitlab learn-lobe``; the held-out stacks are its indices
9, 19, 29, …).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fitlab.learn import network as sl
from fitlab.models import spongecake_network as net
from fitlab.io.measurement import Measurement
from fitlab.io.directions import direction_to_degrees
from fitlab.learn.lobe import fit_lobe

jax.config.update("jax_enable_x64", True)


def measurement(d, j):
    """Stack j of dataset arrays ``d`` as a Measurement of its multiple-scattering part."""
    wi, wo = d["wi"][j], d["wo"][j]
    ti, pi_ = direction_to_degrees(wi)
    to, po = direction_to_degrees(wo)
    n = len(wi)
    return Measurement(path="<stack>", sha256="", theta_i=ti, phi_i=pi_, theta_o=to, phi_o=po,
                       wi=wi, wo=wo, value=d["value"][j], sigma=d["sigma"][j],
                       channel=np.zeros(n, int), channel_names=("Y",), wavelength_nm=None,
                       quantity="bsdf", file_quantity="bsdf", metadata={},
                       lines=np.zeros(n, int))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--stacks", type=int, default=20)
    a = ap.parse_args(argv)
    paths = sorted(Path(a.dir).glob("stack_*.npz"))
    d = sl.load_dataset(paths)
    held = np.flatnonzero(sl.held_out(d["index"]))[: a.stacks]
    layers = d["alpha"].shape[1]
    w = net.load_weights(layers)
    np.asarray(sl.predict(w, d, held))  # compiled once
    t0 = time.perf_counter()
    f_net = np.asarray(sl.predict(w, d, held))
    t_net = (time.perf_counter() - t0) / len(held)
    mae_b, rms_b = (np.asarray(x) for x in sl.stack_errors(jnp.asarray(f_net),
                                                          jnp.asarray(d["value"][held])))
    print("| stack | kinds | α | γ | Tρ | f0 | θp | noise | (a) fit: loss, RMS rel. | "
          "(b) network: loss, RMS rel. | fit s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for n, j in enumerate(held):
        kinds = ["fiber" if x > 0.5 else "surface" for x in d["kind_is_fiber"][j]]
        p = {}
        for i in range(layers):
            p.update({f"alpha{i + 1}": d["alpha"][j, i], f"theta_p{i + 1}": d["theta_p"][j, i],
                      f"phi_p{i + 1}": d["phi_p"][j, i], f"albedo{i + 1}": d["albedo"][j, i],
                      f"f0_{i + 1}": d["f0"][j, i], f"tau{i + 1}": d["tau"][j, i]})
        t1 = time.perf_counter()
        fit, m = fit_lobe(f"spongecake({','.join(kinds)})", {"Y": p},
                          measurement=measurement(d, j))
        t_fit = time.perf_counter() - t1
        f_fit = np.asarray(fit.predict(m.wi, m.wo, "Y"))
        mae_a, rms_a = (float(np.asarray(x)[0]) for x in sl.stack_errors(
            jnp.asarray(f_fit)[None], jnp.asarray(d["value"][j])[None]))
        noise = float(np.mean(d["sigma"][j]) * np.sqrt(2 / np.pi) / np.mean(np.abs(d["value"][j])))
        rows.append((noise, mae_a, rms_a, mae_b[n], rms_b[n], t_fit))
        per = lambda key, fmt: ", ".join(format(p[f"{key}{i + 1}"], fmt)  # noqa: E731
                                         for i in range(layers))
        print(f"| {int(d['index'][j])} | {','.join(kinds)} | {per('alpha', '.3f')} | "
              f"{per('albedo', '.2f')} | {per('tau', '.2f')} | {per('f0_', '.2f')} | "
              f"{per('theta_p', '.0f')}° | {noise:.3f} | "
              f"{mae_a:.3f}, {rms_a:.3f} | {mae_b[n]:.3f}, {rms_b[n]:.3f} | {t_fit:.1f} |")
    r = np.array(rows)
    print(f"\nmedian over {len(held)} held-out stacks: noise {np.median(r[:, 0]):.3f}; (a) fit loss "
          f"{np.median(r[:, 1]):.3f}, RMS rel. {np.median(r[:, 2]):.3f}; (b) network loss "
          f"{np.median(r[:, 3]):.3f}, RMS rel. {np.median(r[:, 4]):.3f}; time per stack: fit "
          f"{np.median(r[:, 5]):.1f} s, network {1e3 * t_net:.2f} ms (warm; all stacks' rows in one "
          "call)")


if __name__ == "__main__":
    main()
