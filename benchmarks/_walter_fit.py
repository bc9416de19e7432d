"""Shared by the fit benchmarks: the Walter example fit problem exactly as ``fitlab fit`` builds
it, and an independent plain-NumPy version of the same model, parameter transforms and
residuals for the peers (SciPy least squares, NumPy log-probability in emcee).

The problem is ``fitlab fit data_formats/examples/walter_rough_glass.csv --model
rough_dielectric --fit-subset 'theta_i == 0'`` at the least-squares level: GGX rough dielectric,
eta fixed to 1.51 from the file, free alpha (log transform over [1e-4, 1]) and the relative
scale (log transform over [1e-4, 1e4] times a reference scale), relative loss, 69 rows.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from importlib import metadata
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
WALTER_CSV = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"
SUBSET = "theta_i == 0"


# --------------------------------------------------------------------------------------------
# Machine description
# --------------------------------------------------------------------------------------------


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def machine() -> dict:
    out = {"cpu": cpu_model(), "cpus": len(os.sched_getaffinity(0)),
           "python": platform.python_version()}
    for pkg in ("jax", "jaxlib", "numpy", "scipy", "emcee", "nlopt"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def machine_line(info: dict) -> str:
    vers = ", ".join(f"{k} {info[k]}" for k in ("python", "jax", "jaxlib", "numpy",
                                                 "scipy", "emcee", "nlopt") if info.get(k))
    return f"{info['cpu']}, {info['cpus']} CPUs usable; {vers}"


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def median(xs):
    return statistics.median(xs)


# --------------------------------------------------------------------------------------------
# The problem as fitlab builds it
# --------------------------------------------------------------------------------------------


class Problem:
    """Everything both sides need: fitlab's space, data and start; plain arrays for NumPy."""

    def __init__(self, subset: str | None = SUBSET):
        from fitlab.fitting import channel
        from fitlab.fitting.subset import subset_mask
        from fitlab.io.measurement import read_measurement

        m = read_measurement(WALTER_CSV)
        rows = (m.channel == 0) & (subset_mask(subset, m) if subset else True)
        self.subset = subset
        prep = channel.prepare_channel(m, "rough_dielectric", rows=rows, channel=0)
        self.measurement, self.rows = m, rows
        self.space, self.data, self.loss = prep["space"], prep["data"], prep["loss"]
        self.start_native = np.asarray(prep["start_native"], dtype=float)
        assert self.space.names == ("alpha", "scale"), self.space.names
        assert self.loss == "relative"
        self.eta = float(self.space.fixed["eta"])
        self.lo = np.array([p.lower for p in self.space.free])
        self.hi = np.array([p.upper for p in self.space.free])
        assert all(p.log for p in self.space.free)
        self.wi, self.wo = np.asarray(m.wi[rows]), np.asarray(m.wo[rows])
        self.value = np.asarray(m.value[rows])
        self.weight = np.asarray(self.data.consts["w"])
        # The peer's own weights, from the loss definition (data_formats: relative loss).
        floor = 0.01 * np.max(np.abs(self.value))
        np.testing.assert_allclose(self.weight, 1.0 / np.maximum(np.abs(self.value), floor))


# --------------------------------------------------------------------------------------------
# Plain NumPy: the GGX rough-dielectric BSDF (Walter 2007 eqs 13-23, 33-34), transforms, residuals
# --------------------------------------------------------------------------------------------


def np_rough_dielectric_ggx(alpha, eta, wi, wo):
    """f_r + f_t of Walter et al. 2007 (eqs 20, 21) with GGX D (eq. 33), separable Smith G
    (eqs 23, 34) and exact dielectric Fresnel (eq. 22), in 1/sr without the cosine; wi, wo
    (n, 3) unit vectors, normal +z, eta = n_inside / n_outside (inside = -z)."""
    ix, iy, iz = wi[:, 0], wi[:, 1], wi[:, 2]
    ox, oy, oz = wo[:, 0], wo[:, 1], wo[:, 2]
    s = np.where(iz < 0, -1.0, 1.0)  # mirror so that the light is on the +z side
    ci, co = iz * s, oz * s
    eta = np.where(s > 0, eta, 1.0 / eta)
    is_r = co > 0
    e = np.where(is_r, 1.0, eta)  # h = wi + wo (eq. 13) or wi + eta wo (eq. 16) ...
    hx, hy, hz = ix + e * ox, iy + e * oy, ci + e * co
    t = np.where(hz < 0, -1.0, 1.0)  # ... turned toward +z
    hx, hy, hz = hx * t, hy * t, hz * t
    h2 = hx * hx + hy * hy + hz * hz
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(h2 > 0, 1.0 / np.sqrt(h2), 0.0)
        i_h = (ix * hx + iy * hy + ci * hz) * inv
        o_h = (ox * hx + oy * hy + co * hz) * inv
        # Fresnel, eq. 22
        c = np.abs(i_h)
        g2 = eta * eta - 1.0 + c * c
        g = np.sqrt(np.maximum(g2, 0.0))
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        F = np.where(g2 <= 0, 1.0, np.clip(0.5 * a * a * (1.0 + b * b), 0.0, 1.0))
        # GGX D, eq. 33, on the unnormalized h
        a2 = alpha * alpha
        s2, c2 = hx * hx + hy * hy, hz * hz
        q = (s2 + a2 * c2) / (s2 + c2)
        D = np.where(hz > 0, a2 / (np.pi * q * q), 0.0)
        # separable Smith G, eqs 23 and 34, with the sidedness factors
        aci, aco = np.abs(ci), np.abs(co)
        g1i = 2.0 * aci / (aci + np.sqrt(ci * ci + a2 * (ix * ix + iy * iy)))
        g1o = 2.0 * aco / (aco + np.sqrt(co * co + a2 * (ox * ox + oy * oy)))
        G = np.where((i_h * ci > 0) & (o_h * co > 0), g1i * g1o, 0.0)
        cos_prod = ci * aco
        f_r = F * G * D / (4.0 * cos_prod)
        f_t = np.abs(i_h * o_h) * eta * eta * (1.0 - F) * G * D / (cos_prod * h2)
        f = np.where(is_r, f_r, f_t)
    return np.where((ci > 0) & (cos_prod > 0) & np.isfinite(f), f, 0.0)


def np_native_from_unit(u, lo, hi):
    """Log transform of the unit box (both free parameters span decades)."""
    return lo * (hi / lo) ** u


def np_unit_from_native(x, lo, hi):
    return np.log(x / lo) / np.log(hi / lo)


def np_residuals_native(theta, p: Problem):
    alpha, scale = theta
    f = np_rough_dielectric_ggx(alpha, p.eta, p.wi, p.wo)
    return (scale * f - p.value) * p.weight


def np_residuals_z(z, p: Problem):
    u = 1.0 / (1.0 + np.exp(-np.asarray(z)))
    return np_residuals_native(np_native_from_unit(u, p.lo, p.hi), p)


def np_cost_unit(u, p: Problem):
    r = np_residuals_native(np_native_from_unit(np.asarray(u), p.lo, p.hi), p)
    return 0.5 * float(r @ r)
