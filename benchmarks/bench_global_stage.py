"""The single fit's least-squares stage at scale (issue 35, item 2): ``fitlab.fit`` with its
defaults (the global scan, then Levenberg–Marquardt from 9 starts, covariance) and with
``global_search="mlsl"`` (nlopt's search, the default before), against one SciPy
``least_squares`` start (the named peer), in one run.

The data: Lambert + GGX rough conductor (albedo 0.3, α 0.15, n 1.5, k 3; fitlab's model
``lambertian+rough_conductor``, 4 free parameters), synthetic with 2% Gaussian noise of known
sigma (the chi2 loss), at 4 incidences (0°, 20°, 40°, 60°) and an outgoing grid of N θo × N/4
φo per incidence, so the row counts grow with ``--sizes``. Both sides fit every row.

* fitlab: the least-squares seconds of ``fitlab.fit`` (``result.seconds["least_squares"]``;
  bootstrap off, so the figure is the fit itself), cold (the process's first fit of that shape,
  compilation included, with an empty compilation cache) and warm (the median of ``--repeat``
  fits of the same shape with other seeds: a second fit of one instrument's files).
* SciPy: ``scipy.optimize.least_squares(method="trf")`` on the same chi2 residuals with a NumPy
  model (the GGX conductor with the exact Fresnel equations of a conductor, Smith G1 of Walter
  2007 eq. 34, plus Lambert), in native units within the bounds, from the model's defaults: one
  local solve, no global stage. The median of ``--repeat`` runs.

Target (issue 35): the warm default fit within 3x one SciPy start at >= 10,000 rows, and its
cost linear in rows beyond that. The fitted parameters of both sides are printed, and the
largest relative difference between them.

    python benchmarks/bench_global_stage.py [--sizes 30 100 200] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import machine, machine_line  # noqa: E402

TRUTH = {"albedo": 0.3, "alpha": 0.15, "n": 1.5, "k": 3.0}
MODEL = "lambertian+rough_conductor"
THETA_I = (0.0, 20.0, 40.0, 60.0)


def measurement(n_o: int, seed: int = 1):
    """The benchmark's Measurement: 4 incidences x n_o θo x n_o/4 φo, 2% noise, sigma known."""
    import fitlab
    from fitlab.io.directions import degrees_to_direction
    from fitlab.io.measurement import Measurement, check_measurement

    t_o, p_o = np.linspace(0.0, 85.0, n_o), np.arange(0.0, 360.0, 360.0 / max(n_o // 4, 1))
    rows = np.array([(ti, 0.0, to, po) for ti in THETA_I for to in t_o for po in p_o
                     if not (to == 0 and po != 0)])
    wi = degrees_to_direction(rows[:, 0], rows[:, 1])
    wo = degrees_to_direction(rows[:, 2], rows[:, 3])
    f = np.asarray(fitlab.eval_bsdf(MODEL, TRUTH, wi, wo))
    rng = np.random.default_rng(seed)
    sigma = 0.02 * f + 1e-3 * f.max()
    value = f + sigma * rng.standard_normal(f.shape)
    n = len(f)
    return check_measurement(Measurement(
        path="<benchmark>", sha256="", theta_i=rows[:, 0], phi_i=rows[:, 1],
        theta_o=rows[:, 2], phi_o=rows[:, 3], wi=wi, wo=wo, value=value, sigma=sigma,
        channel=np.zeros(n, dtype=int), channel_names=("Y",), wavelength_nm=None,
        quantity="bsdf", file_quantity="bsdf", metadata={"scatter": "brdf"},
        lines=np.arange(n)))


# ---- the peer: NumPy model and one SciPy start ---------------------------------------------


def _fresnel_conductor(cos_i, n, k):
    """Unpolarized Fresnel reflectance of a conductor n + ik from air (exact)."""
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    a = n * n - k * k - s2
    b = np.sqrt(a * a + 4.0 * n * n * k * k)
    a2b2 = b
    a_ = np.sqrt(np.maximum(0.5 * (b + a), 0.0))
    rs = (a2b2 + c2 - 2.0 * a_ * cos_i) / (a2b2 + c2 + 2.0 * a_ * cos_i)
    rp = rs * (a2b2 * c2 + s2 * s2 - 2.0 * a_ * cos_i * s2) / (
        a2b2 * c2 + s2 * s2 + 2.0 * a_ * cos_i * s2)
    return 0.5 * (rs + rp)


def _ggx_g1(cos_v, alpha):
    """Smith G1 of GGX (Walter 2007 eq. 34), for cos_v > 0."""
    t2 = (1.0 - cos_v * cos_v) / (cos_v * cos_v)
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * t2))


def np_model(x, wi, wo):
    albedo, alpha, n, k = x
    h = wi + wo
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    ci, co, ch = wi[:, 2], wo[:, 2], h[:, 2]
    a2 = alpha * alpha
    d = a2 / (np.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)
    f = _fresnel_conductor(np.clip(np.sum(wi * h, axis=1), 0.0, 1.0), n, k)
    spec = f * d * _ggx_g1(ci, alpha) * _ggx_g1(co, alpha) / (4.0 * ci * co)
    return albedo / np.pi + spec


def scipy_fit(m, bounds, x0):
    from scipy.optimize import least_squares

    def resid(x):
        return (np_model(x, m.wi, m.wo) - m.value) / m.sigma

    return least_squares(resid, x0, bounds=bounds, method="trf")


# ---- the run ----------------------------------------------------------------------------------


def fit_seconds(m, search, seed):
    import fitlab

    r = fitlab.fit(m, MODEL, bootstrap=0, global_search=search, seed=seed)
    return r.seconds["least_squares"], r.parameters["Y"]


def run(sizes, repeat):
    import fitlab

    model = fitlab.get_model(MODEL)
    names = [p.name for p in model.parameters]
    lo = [p.lower for p in model.parameters]
    hi = [p.upper for p in model.parameters]
    x0 = [p.default for p in model.parameters]
    print(machine_line(machine()))
    print(f"{'rows':>7} | {'SciPy 1 start':>13} | {'fitlab scan cold':>16} | {'scan warm':>9} | "
          f"{'mlsl warm':>9} | {'scan/SciPy':>10} | {'mlsl/SciPy':>10} | max |Δx|/x")
    for n_o in sizes:
        m = measurement(n_o)
        t_cold, _ = fit_seconds(m, "scan", 0)
        warm = {s: [] for s in ("scan", "mlsl")}
        fit_seconds(m, "mlsl", 0)  # its own kernels compiled, untimed
        for seed in range(1, repeat + 1):
            for s in warm:
                t, params = fit_seconds(m, s, seed)
                warm[s].append(t)
        peer = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            sol = scipy_fit(m, (lo, hi), x0)
            peer.append(time.perf_counter() - t0)
        t_peer = float(np.median(peer))
        ts, tm = float(np.median(warm["scan"])), float(np.median(warm["mlsl"]))
        diff = max(abs(params[nm] - v) / abs(v) for nm, v in zip(names, sol.x))
        print(f"{m.n:7d} | {t_peer:12.3f}s | {t_cold:15.2f}s | {ts:8.3f}s | {tm:8.3f}s | "
              f"{ts / t_peer:9.1f}x | {tm / t_peer:9.1f}x | {diff:.1e}")
        print(f"{'':7}   fitlab {', '.join(f'{k}={params[k]:.5g}' for k in names)}; SciPy "
              f"{', '.join(f'{k}={v:.5g}' for k, v in zip(names, sol.x))} ({sol.nfev} "
              "evaluations)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[30, 100, 200],
                    help="θo samples per incidence (rows = 4 x N x N/4)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as cache:
        os.environ["FITLAB_CACHE_DIR"] = cache  # cold means cold: an empty cache
        run(args.sizes, args.repeat)


if __name__ == "__main__":
    main()
