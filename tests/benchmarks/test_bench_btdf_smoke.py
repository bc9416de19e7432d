"""Smoke test of benchmarks/bench_btdf_eval.py: it runs end to end on a small batch and fitlab
agrees with Mitsuba 3 (llvm_ad_rgb) there. Not a timing test: no figure is checked."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from conftest import skip_or_fail

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_btdf_eval.py"


def test_bench_btdf_eval_runs_and_agrees():
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--pairs", "20000", "--repeat", "2", "--block", "2"],
        capture_output=True, text=True, timeout=600, env=env,
    )
    if proc.returncode == 2:  # Mitsuba or libLLVM missing
        skip_or_fail(proc.stderr.strip().splitlines()[-1])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "ratio fitlab/Mitsuba throughput" in proc.stdout
    assert "-> OK" in proc.stdout
