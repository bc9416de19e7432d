"""The extended-NDF paper's figures as numbers (it gives only pictures): Fig. 2 (eq. 8's masking
against the integral of eq. 7), Fig. 5 (one vMF lobe for the reflected and refracted
distributions D(r), D(t) of a collimated beam, eqs 12-13, against the exact warped densities)
and Figs 6-8 (joint spherical warping, eqs 18 and 21, against Monte Carlo of eqs 16 and 20).

Writes reports/thin_layer_figures/README.md and results.json:

    .venv/bin/python benchmarks/thin_layer_figures.py [--samples 2000000] [--seed 0]

Conventions as the paper's: M(x; µ, κ) = κ e^{κ(µ·x - 1)} / (2π (1 - e^{-2κ})) is the vMF
density on the whole sphere; the NDF is M(m; n, κm) as a distribution of normals m.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from fitlab import vmf  # noqa: E402
from fitlab.io.atomic import atomic_write_text  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "reports" / "thin_layer_figures"


def vmf_density(x, mu, kappa):
    """M(x; µ, κ) on the whole sphere (paper eq. 5, C3 = κ/(4π sinh κ), written stably)."""
    return kappa * np.exp(kappa * (x @ mu - 1.0)) / (2.0 * np.pi * -np.expm1(-2.0 * kappa))


def sample_vmf(rng, n, mu, kappa):
    """Wood's algorithm in 3D: w = 1 + log(u + (1 - u) e^{-2κ})/κ, azimuth uniform."""
    u = rng.random(n)
    w = 1.0 + np.log(u + (1.0 - u) * np.exp(-2.0 * kappa)) / kappa
    phi = 2.0 * np.pi * rng.random(n)
    s = np.sqrt(np.clip(1.0 - w * w, 0.0, None))
    local = np.stack([s * np.cos(phi), s * np.sin(phi), w], -1)
    mu = np.asarray(mu, float) / np.linalg.norm(mu)
    a = np.array([1.0, 0.0, 0.0]) if abs(mu[2]) > 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(a, mu)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(mu, e1)
    return local[:, :1] * e1 + local[:, 1:2] * e2 + local[:, 2:] * mu


def reflect(o, m):
    return 2.0 * np.sum(o * m, -1, keepdims=True) * m - o


def refract(o, m, eta):
    """Paper eq. 11: Ψ(o; m, η), o above the facet; NaN rows under total internal reflection."""
    c = np.sum(o * m, -1, keepdims=True)
    k = 1.0 - (1.0 - c * c) / (eta * eta)
    t = (c / eta - np.sqrt(np.where(k > 0, k, np.nan))) * m - o / eta
    return t


def kappa_from_mean_length(R):
    return 1.0 / float(vmf.nu_of_log_A3(jnp.log(jnp.asarray(R))))


def fitted_lobe(x):
    """Mean direction and moment-matched κ (A3(κ) = mean resultant length) of unit vectors x."""
    s = x.mean(0)
    R = np.linalg.norm(s)
    return s / R, kappa_from_mean_length(R)


def fig2(thetas=(0, 30, 60, 75, 85, 89), kappas=(1, 10, 100, 1000, 1e4)):
    """G1 of eq. 8 against eq. 7's integral (400-node quadrature) per κ and θv."""
    old = vmf._GL_NODES
    vmf._GL_NODES = 400
    try:
        rows = []
        for k in kappas:
            t = np.radians(np.array(thetas, float))
            v = jnp.asarray(np.stack([np.sin(t), 0 * t, np.cos(t)], -1))
            approx = np.asarray(vmf.G1_approx(v, k))
            exact = np.asarray(vmf.G1_exact(v, k))
            rows.append({"kappa": k, "theta_deg": list(thetas), "eq8": approx.tolist(),
                         "exact": exact.tolist()})
    finally:
        vmf._GL_NODES = old
    return rows


def fig5(kappa_m=100.0, eta=1.5, thetas=(0, 30, 45, 60), n_grid=800):
    """Single-lobe vMF approximations of D(r) (eq. 12) and D(t) (eq. 13) against the exact
    warped densities, on a grid of the sphere around each lobe: the total-variation distance
    ½∫|D - D_vMF| dω and the ratio of the peak values."""
    n = np.array([0.0, 0.0, 1.0])
    out = []
    for th in thetas:
        t = np.radians(th)
        o = np.array([np.sin(t), 0.0, np.cos(t)])
        for kind in ("reflection", "refraction"):
            if kind == "reflection":
                mu = reflect(o[None], n[None])[0]
                k_approx = kappa_m / (4.0 * abs(o @ n))
            else:
                mu = refract(o[None], n[None], eta)[0]
                mu /= np.linalg.norm(mu)
                ct = abs(mu @ n)
                k_approx = eta**2 * ct / (o @ n - eta * ct) ** 2 * kappa_m  # eq. 13, µm = n
            # grid in a cap of half-angle 8/sqrt(κ) around µ
            half = min(np.pi, 8.0 / np.sqrt(k_approx))
            a = np.linspace(0, half, n_grid)
            p = np.linspace(0, 2 * np.pi, n_grid, endpoint=False)
            A, P = np.meshgrid(a, p, indexing="ij")
            loc = np.stack([np.sin(A) * np.cos(P), np.sin(A) * np.sin(P), np.cos(A)], -1)
            e1 = np.cross([0.0, 1.0, 0.0], mu)
            e1 = e1 / np.linalg.norm(e1) if np.linalg.norm(e1) > 1e-9 else np.array([1.0, 0, 0])
            e2 = np.cross(mu, e1)
            x = loc[..., :1] * e1 + loc[..., 1:2] * e2 + loc[..., 2:] * mu
            dw = np.sin(A) * (a[1] - a[0]) * (2 * np.pi / n_grid)
            if kind == "reflection":
                h = x + o
                h /= np.linalg.norm(h, axis=-1, keepdims=True)
                exact = vmf_density(h, n, kappa_m) / (4.0 * np.abs(np.sum(o * h, -1)))
            else:
                # generalized half vector of o (outside, index 1) and x (inside, η)
                h = -(o + eta * x)
                h /= np.linalg.norm(h, axis=-1, keepdims=True)
                h *= np.sign(h[..., 2:3])
                oh, xh = np.sum(o * h, -1), np.sum(x * h, -1)
                jac = eta**2 * np.abs(xh) / (oh + eta * xh) ** 2
                exact = np.where((oh > 0) & (xh < 0), vmf_density(h, n, kappa_m) * jac, 0.0)
            approx = vmf_density(x, mu, k_approx)
            out.append({"theta_o_deg": th, "kind": kind, "kappa_approx": k_approx,
                        "tv_distance": float(0.5 * np.sum(np.abs(exact - approx) * dw)),
                        "exact_mass_in_cap": float(np.sum(exact * dw)),
                        "peak_ratio_vmf_over_exact": float(approx.max() / exact.max())})
    return out


def figs678(samples, seed, eta=1.5):
    """Joint warping (eqs 16-18, 20-21) against Monte Carlo: draw o ~ M(µo, κo), m ~ M(n, κm),
    warp, and moment-match the result; compare its κ and mean direction with eqs 18 and 21."""
    rng = np.random.default_rng(seed)
    n = np.array([0.0, 0.0, 1.0])
    cases = [(1.0, 50.0, 200.0), (0.707, 100.0, 100.0), (0.5, 200.0, 50.0)]
    out = []
    for cos_om, k_o, k_m in cases:
        th = np.arccos(cos_om)
        mu_o = np.array([np.sin(th), 0.0, np.cos(th)])
        o = sample_vmf(rng, samples, mu_o, k_o)
        m = sample_vmf(rng, samples, n, k_m)
        for kind in ("reflection", "refraction"):
            if kind == "reflection":
                x = reflect(o, m)
                mu_hat = reflect(mu_o[None], n[None])[0]
                j_m = 1.0 / (4.0 * abs(mu_o @ n))  # ‖∂m/∂r‖, eq. 12
                j_o = 1.0  # ‖∂o/∂r‖ = 1 (eq. 18's remark)
            else:
                x = refract(o, m, eta)
                keep = np.all(np.isfinite(x), -1) & (np.sum(o * m, -1) > 0)
                x = x[keep] / np.linalg.norm(x[keep], axis=-1, keepdims=True)
                mu_hat = refract(mu_o[None], n[None], eta)[0]
                mu_hat /= np.linalg.norm(mu_hat)
                ct = abs(mu_hat @ n)
                j_m = eta**2 * ct / (mu_o @ n - eta * ct) ** 2  # ‖∂m/∂t‖, eq. 21
                j_o = eta**2 * ct / abs(mu_o @ n)  # ‖∂o/∂t‖, eq. 21
            nu_hat = float(vmf.convolve_nu(jnp.asarray(1.0 / (j_m * k_m)),
                                           jnp.asarray(1.0 / (j_o * k_o))))
            mu_mc, k_mc = fitted_lobe(x)
            out.append({"mu_o_dot_mu_m": cos_om, "kappa_o": k_o, "kappa_m": k_m, "kind": kind,
                        "kappa_hat_eq": 1.0 / nu_hat, "kappa_moment_mc": k_mc,
                        "mean_direction_error_deg": float(np.degrees(np.arccos(
                            np.clip(mu_mc @ mu_hat, -1, 1)))),
                        "samples": int(len(x))})
    return out


def write_report(res, args):
    lines = ["# The extended-NDF paper's figures as numbers", "",
             "Guo, Qian, Pan 2015 shows these only as plots. Command:", "",
             "```", f".venv/bin/python benchmarks/thin_layer_figures.py --samples {args.samples} "
             f"--seed {args.seed}", "```", "",
             f"Machine: {platform.machine()}, Python {platform.python_version()}.", "",
             "## Fig. 2: eq. 8's masking against the integral of eq. 7", "",
             "G1 at θv (eq. 8 / exact, 400-node quadrature):", "",
             "| κ | " + " | ".join(f"{t}°" for t in res["fig2"][0]["theta_deg"]) + " |",
             "|---|" + "---|" * len(res["fig2"][0]["theta_deg"])]
    for r in res["fig2"]:
        lines.append(f"| {r['kappa']:g} | " + " | ".join(
            f"{a:.4f} / {e:.4f}" for a, e in zip(r["eq8"], r["exact"])) + " |")
    lines += ["", "\"Exact\" is eq. 7 with fitlab's vMF normalized over the upper hemisphere "
              "(G1 = 1 at normal incidence); the paper normalizes M over the whole sphere, which "
              "agrees for κ ≥ 100 and explains the κ = 1 row's gap at 0°. Eq. 8's error grows "
              "toward the horizon for sharp lobes (κ = 1000 at 89°: 0.971 against 0.752). "
              "fitlab's thin layer uses the exact form by default "
              "(data_formats/layered_models.md).", "",
              "## Fig. 5: one vMF lobe for D(r) and D(t) of a collimated beam (κm = 100, η = 1.5)",
              "", "Total-variation distance ½∫|D − D_vMF| dω between the exact warped density and "
              "the lobe of eqs 12-13, and the ratio of their peaks:", "",
              "| θo | kind | κ of the lobe | TV distance | peak ratio (vMF / exact) |",
              "|---|---|---|---|---|"]
    for r in res["fig5"]:
        lines.append(f"| {r['theta_o_deg']}° | {r['kind']} | {r['kappa_approx']:.1f} | "
                     f"{r['tv_distance']:.4f} | {r['peak_ratio_vmf_over_exact']:.3f} |")
    lines += ["", "## Figs 6-8: joint spherical warping against Monte Carlo", "",
              f"{args.samples:,} samples of (o, m) per case; κ moment-matched to the samples' "
              "mean resultant length (A3⁻¹), against eqs 18 (reflection) and 21 (refraction, "
              "η = 1.5):", "",
              "| µo·µm, κo, κm | kind | κ̂ (eq.) | κ (Monte Carlo moments) | ratio | mean direction "
              "error |", "|---|---|---|---|---|---|"]
    for r in res["figs678"]:
        lines.append(f"| {r['mu_o_dot_mu_m']}, {r['kappa_o']:g}, {r['kappa_m']:g} | {r['kind']} | "
                     f"{r['kappa_hat_eq']:.2f} | {r['kappa_moment_mc']:.2f} | "
                     f"{r['kappa_hat_eq'] / r['kappa_moment_mc']:.3f} | "
                     f"{r['mean_direction_error_deg']:.3f}° |")
    lines += ["", "Not here yet: the Table 2 analogue (ENDF evaluation against the simulator's "
              "time to equal error per bounce count).", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=2_000_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    res = {"fig2": fig2(), "fig5": fig5(), "figs678": figs678(args.samples, args.seed)}
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "results.json", json.dumps(res, indent=1, sort_keys=True) + "\n")
    atomic_write_text(args.out / "README.md", write_report(res, args))
    print(f"wrote {args.out / 'README.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
