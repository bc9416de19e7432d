"""Baking the directional-albedo table E(μ, α) (32 × 32, GGX, F = 1): fitlab's deterministic
quadrature against Monte Carlo importance-sampled baking in the Filament / Cycles style, at equal
error, in the same run.

* Reference: fitlab's quadrature at high order (n_u = 48 Gauss–Legendre nodes per θm panel,
  n_phi = 24 per φm panel), far beyond the orders compared (its own convergence is printed).
* Quadrature: ``fitlab.lut.albedo_integrals`` at the order given (default n_u = 8, n_phi = 4:
  the lower of the two orders a stored table uses, max error about 1e-3).
* Monte Carlo, as Filament's DFG precompute (``DFG.cpp``: Hammersley points, GGX importance
  sampling of the half-vector, weight G·(v·h)/((n·v)(n·h))) and Cycles' precompute (uniform
  random numbers, same estimator): for each texel N samples u → m by Walter eq. 35-36
  (fitlab.microfacet.sample_m_GGX), o = reflect(i, m), weight = G1(i)G1(o)(i·m)/((i·n)(m·n)) for
  o above the horizon (Walter eq. 41) — the separable Smith G of the table. Same JAX, same jit,
  chunked like the quadrature.

Equal error: the max |E − E_ref| over the 1024 texels. MC is run at sample counts doubling from
64 until its max error is at most the quadrature's; that count's time is compared. Every timing
is the median of --repeat warm runs (the first call compiles and is excluded). Prints the error
and time of each, and the ratio t_MC / t_quadrature (target: ≥ 20).

Usage: python benchmarks/bench_lut_bake.py [--n-u 8] [--n-phi 4] [--repeat 3] [--max-samples 524288]
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import fitlab  # noqa: F401  (x64)
from fitlab import lut
from fitlab.frame import reflect
from fitlab.microfacet import G1_GGX, sample_m_GGX

SIZE = 32


def grid():
    mu = np.linspace(0.0, 1.0, SIZE)
    alpha = lut.ALPHA_MIN + (1.0 - lut.ALPHA_MIN) * np.linspace(0.0, 1.0, SIZE)
    A, M = np.meshgrid(alpha, mu, indexing="ij")
    return M.ravel(), A.ravel()


def radical_inverse(i):
    """Van der Corput radical inverse in base 2 (the second Hammersley coordinate)."""
    i = np.asarray(i, dtype=np.uint32)
    i = ((i << 16) | (i >> 16)).astype(np.uint32)
    i = (((i & 0x55555555) << 1) | ((i & 0xAAAAAAAA) >> 1)).astype(np.uint32)
    i = (((i & 0x33333333) << 2) | ((i & 0xCCCCCCCC) >> 2)).astype(np.uint32)
    i = (((i & 0x0F0F0F0F) << 4) | ((i & 0xF0F0F0F0) >> 4)).astype(np.uint32)
    i = (((i & 0x00FF00FF) << 8) | ((i & 0xFF00FF00) >> 8)).astype(np.uint32)
    return i.astype(np.float64) / 2.0**32


def samples(n, kind, seed=0):
    if kind == "hammersley":
        k = np.arange(n)
        return np.stack([(k + 0.5) / n, radical_inverse(k)], axis=-1)
    return np.random.default_rng(seed).random((n, 2))


def _mc_texel(mu, alpha, u):
    ci = jnp.maximum(mu, lut.MU_MIN)
    wi = jnp.stack([jnp.sqrt(jnp.maximum(1 - ci * ci, 0.0)), 0.0 * ci, ci])
    m = sample_m_GGX(u[:, 0], u[:, 1], alpha)  # Walter eqs 35-36
    o = reflect(jnp.broadcast_to(wi, m.shape), m)
    c = m @ wi
    ok = (c > 0) & (o[:, 2] > 0)
    w = G1_GGX(wi, alpha) * G1_GGX(o, alpha) * c / (ci * m[:, 2])  # Walter eq. 41, F = 1
    return jnp.mean(jnp.where(ok, w, 0.0))


@functools.lru_cache(maxsize=None)
def _mc_kernel(n):
    @jax.jit
    def run(mu, alpha, u):
        return jax.lax.map(lambda a: _mc_texel(a[0], a[1], u), (mu, alpha),
                           batch_size=max(1, min(256, (1 << 22) // n)))

    return run


def bake_mc(mu, alpha, n, kind):
    u = jnp.asarray(samples(n, kind))
    return np.asarray(_mc_kernel(n)(jnp.asarray(mu), jnp.asarray(alpha), u))


def bake_quadrature(mu, alpha, n_u, n_phi):
    return lut.albedo_integrals(mu, alpha, mode="conductor", n_u=n_u, n_phi=n_phi)[:, 0]


def timed(fn, repeat):
    fn()  # compile
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return out, statistics.median(ts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-u", type=int, default=8)
    ap.add_argument("--n-phi", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--max-samples", type=int, default=1 << 19)
    a = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"{platform.platform()}; jax {jax.__version__}", file=sys.stderr)
    mu, alpha = grid()
    ref = bake_quadrature(mu, alpha, 48, 24)
    ref2 = bake_quadrature(mu, alpha, 32, 16)
    print(f"reference: quadrature n_u=48, n_phi=24; |ref - (32, 16)| max {np.abs(ref - ref2).max():.2e}")
    q, tq = timed(lambda: bake_quadrature(mu, alpha, a.n_u, a.n_phi), a.repeat)
    eq = np.abs(q - ref).max()
    print(f"quadrature n_u={a.n_u}, n_phi={a.n_phi}: max error {eq:.2e}, RMS "
          f"{np.sqrt(np.mean((q - ref) ** 2)):.2e}, {tq * 1e3:.1f} ms")
    results = {}
    for kind in ("hammersley", "random"):
        n = 64
        while True:
            e, tm = timed(lambda: bake_mc(mu, alpha, n, kind), a.repeat)
            em = np.abs(e - ref).max()
            print(f"  MC {kind:10s} N={n:6d}: max error {em:.2e}, RMS "
                  f"{np.sqrt(np.mean((e - ref) ** 2)):.2e}, {tm * 1e3:.1f} ms")
            if em <= eq or n >= a.max_samples:
                break
            n *= 2
        results[kind] = (n, em, tm, em <= eq)
    for kind, (n, em, tm, met) in results.items():
        ratio = tm / tq
        if met:
            print(f"{kind}: equal error needs N = {n} samples per texel; time ratio MC / "
                  f"quadrature = {ratio:.1f}x (target >= 20x: {'met' if ratio >= 20 else 'NOT met'})")
        else:
            print(f"{kind}: N = {n} (the --max-samples cap) still has max error {em:.2e} > "
                  f"{eq:.2e}; at that N the time ratio is already {ratio:.1f}x (a lower bound)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
