"""Posteriors one chain per core (issue 35 item 4): the whole ``fitlab fit --mcmc`` of a
multi-channel measurement, by each posterior sampler, in one run, against emcee (the reference).

Default case: the RGL three-channel Weidlich–Wilkie fit,

    fitlab fit DATA --model 'weidlich_wilkie(lambertian)' --fix k1=0 --fix tau1=0 --mcmc
        --sampler S --mcmc-steps N --timings --chain C.npz

with DATA the RGL aurora white measurement (``aurora_white_rgb.bsdf``, 4,291 rows per channel,
R, G, B). Each sampler's fit runs as a user runs it: a fresh ``fitlab`` process (cold: it
compiles what it needs; the persistent compilation cache off, so that the order of the runs
does not matter), everything at its defaults but the sampler and its steps (least squares, the
MCMC, the bootstrap). Timed: the process's wall clock, and the fit's own ``timings_s``.

Effective sample size, the same rule for both samplers: ArviZ's bulk ESS of every free
parameter (the noise scale ``log_noise`` left out), each emcee walker counted as a chain after
emcee's burn-in, each NUTS chain after its adaptation; the smallest over parameters and
channels is the figure. Target: the whole fit within 60 s at emcee's smallest bulk ESS or better,
naming the sampler that meets it.

    python benchmarks/bench_posterior.py DATA [--samplers emcee nuts] [--emcee-steps 4000]
        [--nuts-steps 800] [--model M] [--fix NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _walter_fit import machine, machine_line

MODEL = "weidlich_wilkie(lambertian)"
FIXED = ("k1=0", "tau1=0")
TARGET_S = 60.0


def run_fit(data: str, sampler: str, steps: int, model: str, fixed, out: Path) -> dict:
    """One ``fitlab fit --mcmc`` in a fresh process: wall seconds, the record, the chains."""
    fit, chain = out / f"{sampler}.json", out / f"{sampler}.npz"
    cmd = [sys.executable, "-m", "fitlab.cli", "fit", data, "--model", model,
           *[a for f in fixed for a in ("--fix", f)], "--mcmc", "--sampler", sampler,
           "--mcmc-steps", str(steps), "--timings", "--out", str(fit), "--chain", str(chain),
           "--quiet"]
    env = dict(os.environ, FITLAB_NO_CACHE="1")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{sampler}: fitlab fit exited {proc.returncode}:\n{proc.stderr}")
    record = json.loads(fit.read_text())
    with np.load(chain) as z:
        chains = {k: z[k] for k in z.files}
    return {"wall": wall, "record": record, "chains": chains}


def bulk_ess(run: dict) -> dict:
    """{channel: {parameter: ArviZ bulk ESS}} of a fit's chains (module text)."""
    import arviz as az

    out = {}
    for f in run["record"]["fits"]:
        ch, mc = f["channel"], f["mcmc"]
        chain = run["chains"][f"chain_{ch}"][int(mc.get("burn", 0)):]  # (draws, chains, dim)
        names = [str(n) for n in run["chains"][f"coordinates_{ch}"]]
        data = az.convert_to_dataset({n: np.swapaxes(chain[..., k], 0, 1)
                                      for k, n in enumerate(names) if n != "log_noise"})
        ess = az.ess(data, method="bulk")
        out[ch] = {n: float(ess[n]) for n in ess.data_vars}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", help="the measurement (the RGL aurora white .bsdf)")
    ap.add_argument("--samplers", nargs="+", default=["emcee", "nuts"])
    ap.add_argument("--emcee-steps", type=int, default=4000)
    ap.add_argument("--nuts-steps", type=int, default=800)
    ap.add_argument("--model", default=MODEL)
    ap.add_argument("--fix", action="append", default=None)
    args = ap.parse_args(argv)
    fixed = args.fix if args.fix is not None else list(FIXED)
    print(machine_line(machine()))
    print(f"fitlab fit {Path(args.data).name} --model '{args.model}' "
          + " ".join(f"--fix {f}" for f in fixed) + " --mcmc (cold, one process per sampler)")
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.samplers:
            steps = args.emcee_steps if s == "emcee" else args.nuts_steps
            run = run_fit(args.data, s, steps, args.model, fixed, Path(tmp))
            ess = bulk_ess(run)
            low = min(min(v.values()) for v in ess.values())
            t = run["record"].get("timings_s", {})
            rows[s] = {"wall": run["wall"], "ess": low, "steps": steps, "timings": t,
                       "per_channel": {c: min(v.values()) for c, v in ess.items()}}
            print(f"  {s:6s} {steps:5d} steps: wall {run['wall']:6.1f} s; smallest bulk ESS "
                  f"{low:7.0f} (" + ", ".join(f"{c} {e:.0f}" for c, e in
                                           rows[s]["per_channel"].items())
                  + "); timings " + json.dumps({k: round(v, 1) for k, v in t.items()
                                                if isinstance(v, (int, float))}), flush=True)
    if "emcee" in rows:
        ref = rows["emcee"]
        for s, r in rows.items():
            if s == "emcee":
                continue
            print(f"  {s} / emcee: {ref['wall'] / r['wall']:.2f}x faster, ESS "
                  f"{r['ess'] / ref['ess']:.2f}x")
        met = [s for s, r in rows.items() if r["wall"] <= TARGET_S and r["ess"] >= ref["ess"]]
        print(f"target (whole fit <= {TARGET_S:.0f} s at emcee's smallest bulk ESS "
              f"{ref['ess']:.0f} or better): " + (f"met by {', '.join(met)}" if met else
                                                   "not met"))


if __name__ == "__main__":
    main()
