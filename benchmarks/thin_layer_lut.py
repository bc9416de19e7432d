"""What the thin layer's real-time table (``fitlab lut thin_layer``, Guo et al. 2015 section 5.5)
costs and how accurate it is, per size (issue 17, item 6).

For one material — a clear layer (η 1.5, absorption τ 0.05 / 0.9 / 1.2 per R / G / B) over
rough chromium (n2 3.84 / 3.18 / 1.99, k2 4.37 / 4.41 / 4.22; the metallic car paint preset's
values) — bake the table at several sizes (half, the CLI's default type) and report:

* the bake time on this machine (the quadrature of every texel);
* the interpolation error (the table read as the shader reads it vs a fresh quadrature at
  random points, ``accuracy.interpolation``): absolute for ``sin_theta_mean`` and
  ``log10_kappa`` (their natural units: a sine, decades), relative for the albedos E;
* the quadrature's own error estimate (``accuracy.quadrature``);
* the real-time form's error (``accuracy.vmf_lobe``): the model's subsurface lobe against its
  albedo times one vMF of the table's mean and κ̂ (relative L2 over outgoing directions).

Run: ``python benchmarks/thin_layer_lut.py [--sizes 8x8x8,16x16x16] [--points 256]``.
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import numpy as np

from fitlab import lut

jax.config.update("jax_enable_x64", True)

MODEL = "thin_layer(rough_conductor)"
PARAMS = {c: {"eta": 1.5, "tau": t, "n2": n, "k2": k} for c, t, n, k in
          (("R", 0.05, 3.84, 4.37), ("G", 0.9, 3.18, 4.41), ("B", 1.2, 1.99, 4.22))}


def _abs_err(table, spec, n, seed=0):
    """Absolute errors of every channel at n random points (uniform in texture coordinates)."""
    rng = np.random.default_rng(seed)
    t = rng.random((n, len(table.axes)))
    x = np.stack([a.to_x(t[:, k]) for k, a in enumerate(table.axes)], axis=-1)
    direct, _ = spec.evaluate(x)
    return np.abs(lut.lookup(table, x) - direct), direct, x


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="8x8x8,16x16x16,32x16x16,16x24x24")
    ap.add_argument("--points", type=int, default=256)
    args = ap.parse_args(argv)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    print(f"# {platform.processor() or platform.machine()}, jax {jax.__version__}; {MODEL}, "
          f"{args.points} random points per check")
    print("| size | texels | bake s | s / texel | sin_theta_mean abs. RMS / max | log10_kappa abs. "
          "RMS / max (decades) | E rel. RMS / max (R, G, B pooled) | the same at μ ≥ 0.05 (θi ≤ "
          "87°): sin, log10 κ̂ abs. RMS; E rel. RMS / max | quadrature estimate max: E abs. / "
          "mean dir. / log10 κ̂ | vMF lobe error median / p90 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for size in sizes:
        spec = lut.make_spec("thin_layer", model=MODEL, params=PARAMS, size=size)
        t0 = time.perf_counter()
        table = lut.bake(spec, "half", check_points=0)
        t_bake = time.perf_counter() - t0
        n_tex = int(np.prod(size))
        err, direct, x = _abs_err(table, spec, args.points)
        away = x[:, 0] >= 0.05
        E = slice(2, None)
        rel = err[:, E] / np.maximum(np.abs(direct[:, E]),
                                     lut.REL_FLOOR * np.abs(direct[:, E]).max(axis=0))
        q = table.accuracy["quadrature"]["per_channel_max_abs"]
        qE = max(v for k, v in q.items() if k.startswith("E_"))
        check = dict(spec.checks)["vmf_lobe"](table, spec, args.points)
        rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
        print(f"| {'x'.join(map(str, size))} | {n_tex} | {t_bake:.0f} | {t_bake / n_tex * 1e3:.1f} ms "
              f"| {rms(err[:, 0]):.3g} / {err[:, 0].max():.3g} "
              f"| {rms(err[:, 1]):.3g} / {err[:, 1].max():.3g} "
              f"| {rms(rel):.3g} / {rel.max():.3g} "
              f"| {rms(err[away, 0]):.3g}, {rms(err[away, 1]):.3g}; {rms(rel[away]):.3g} / "
              f"{rel[away].max():.3g} "
              f"| {qE:.2g} / {q['sin_theta_mean']:.2g} / {q['log10_kappa']:.2g} "
              f"| {check['median']:.3g} / {check['p90']:.3g} |", flush=True)


if __name__ == "__main__":
    main()
