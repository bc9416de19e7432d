"""Cold ``fitlab fit`` end to end: a new process, from its start to the parameter file written,
on the Walter example (``fitlab fit data_formats/examples/walter_rough_glass.csv --model
rough_dielectric --fit-subset 'theta_i == 0' --out FIT.json --quiet``). Target: 5 s or less on
a 2-core machine.

Each run is a fresh ``subprocess`` (the ``fitlab`` console script next to this Python, else
``python -m fitlab.cli``); wall time from spawning it to its exit, after which the parameter
file must exist and hold the fit. Scenarios, each the median of ``--repeat`` runs:

* first run: an empty compilation cache (``FITLAB_CACHE_DIR`` = a new empty folder per run),
  so every kernel is compiled (and written to the cache), as on a machine's very first fit;
* cached: a cache folder filled by one earlier, untimed run of the same command, as for every
  later fit of the same structure (model, options, free parameters, loss, number of rows);
* no cache: ``FITLAB_NO_CACHE=1`` (compiles, writes nothing);

each without and (``--mcmc``, default 3000 steps x 32 walkers) with posterior sampling. The
time of ``python -c "import fitlab.cli"`` (the fixed start-up cost) is reported alongside, and
the CPU time (user + system) of the runs, which a busy machine inflates less than wall time.

Usage: python benchmarks/bench_cold_fit.py [--repeat 5] [--no-mcmc] [--mcmc-steps 3000]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import (  # noqa: E402
    ROOT, SUBSET, WALTER_CSV, load_average, machine, machine_line, median,
)

TARGET_S = 5.0


def fitlab_command() -> list[str]:
    script = Path(sys.executable).with_name("fitlab")
    return [str(script)] if script.exists() else [sys.executable, "-m", "fitlab.cli"]


def timed_process(cmd, env) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def fit_command(out: Path, mcmc: bool, mcmc_steps: int) -> list[str]:
    cmd = fitlab_command() + ["fit", str(WALTER_CSV), "--model", "rough_dielectric",
                              "--fit-subset", SUBSET, "--out", str(out), "--quiet", "--timings"]
    return cmd + (["--mcmc", "--mcmc-steps", str(mcmc_steps)] if mcmc else [])


def run(repeat=5, mcmc=True, mcmc_steps=3000, quiet=False):
    say = (lambda *a, **k: None) if quiet else print
    info = machine()
    base_env = {k: v for k, v in os.environ.items() if k not in ("FITLAB_CACHE_DIR",
                                                                  "FITLAB_NO_CACHE")}
    res = {**info, "repeat": repeat, "mcmc_steps": mcmc_steps, "target_s": TARGET_S,
           "load_before": load_average()}
    say(f"machine : {machine_line(info)}; load avg {res['load_before']}")
    shown = fit_command(Path("FIT.json"), False, mcmc_steps)
    shown = ["fitlab"] + [str(WALTER_CSV.relative_to(ROOT)) if a == str(WALTER_CSV) else
                          (f"'{a}'" if " " in a else a) for a in shown[shown.index("fit"):]]
    say(f"command : {' '.join(shown)}")
    with tempfile.TemporaryDirectory(prefix="fitlab-bench-") as tmp:
        tmp = Path(tmp)
        walls = [timed_process([sys.executable, "-c", "import fitlab.cli"], base_env)[0]
                 for _ in range(repeat)]
        res["import_s"] = median(walls)
        say(f"start-up: python -c 'import fitlab.cli' {res['import_s']:.2f} s (median of {repeat})")
        for with_mcmc in ((False, True) if mcmc else (False,)):
            tag = "mcmc" if with_mcmc else "ls"
            warm_cache = tmp / f"cache-{tag}"
            out = tmp / f"fit-{tag}.json"
            timed_process(fit_command(out, with_mcmc, mcmc_steps),
                          dict(base_env, FITLAB_CACHE_DIR=str(warm_cache)))  # fill it, untimed
            scenarios = {
                "first": lambda i: dict(base_env, FITLAB_CACHE_DIR=str(tmp / f"empty-{tag}-{i}")),
                "cached": lambda i: dict(base_env, FITLAB_CACHE_DIR=str(warm_cache)),
                "nocache": lambda i: dict(base_env, FITLAB_NO_CACHE="1"),
            }
            for name, env_of in scenarios.items():
                walls, cpus = [], []
                for i in range(repeat):
                    out.unlink(missing_ok=True)
                    w, c = timed_process(fit_command(out, with_mcmc, mcmc_steps), env_of(i))
                    record = json.loads(out.read_text())  # the parameter file is there and whole
                    assert record["fits"][0]["parameters"]["alpha"]["value"] > 0
                    walls.append(w)
                    cpus.append(c)
                key = f"{tag}_{name}"
                res[f"{key}_s"] = median(walls)
                res[f"{key}_all_s"] = walls
                res[f"{key}_cpu_s"] = median(cpus)
                res[f"{key}_in_process_s"] = record["timings_s"]["total"]
                say(f"{'with --mcmc' if with_mcmc else 'least squares':>14}, {name:>8}: "
                    f"{res[key + '_s']:5.2f} s wall (runs {', '.join(f'{w:.2f}' for w in walls)}), "
                    f"{res[key + '_cpu_s']:5.2f} s CPU; fitlab's own timer "
                    f"{res[key + '_in_process_s']:.2f} s"
                    + ("" if name == "nocache" else
                       f"  -> target {TARGET_S:g} s "
                       f"{'met' if res[key + '_s'] <= TARGET_S else 'NOT met'}"))
    res["load_after"] = load_average()
    say(f"load avg after: {res['load_after']}")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-mcmc", action="store_true", help="skip the --mcmc runs")
    ap.add_argument("--mcmc-steps", type=int, default=3000)
    args = ap.parse_args(argv)
    run(repeat=args.repeat, mcmc=not args.no_mcmc, mcmc_steps=args.mcmc_steps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
