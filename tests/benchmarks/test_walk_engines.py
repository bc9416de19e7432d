"""The walk engines of benchmarks/walk_engines.py (issue 15, item 3): the fastest one that is
installed (Dr.Jit's LLVM backend, else Numba) traces the walk of benchmarks/numpy_walk.py's
``simulate_numpy`` on the benchmark scene (HG slab between GGX interfaces, light at 30°, both
hemispheres in 9 × 12 bins, every order) and agrees with it statistically at 2^15 paths:
reflected and transmitted flux within 4 combined standard errors, per-bin χ² over the bins
expecting >= 100 paths with p > 1e-3 (independent walks, fixed seeds).

Skips when no engine is importable; with FITLAB_REQUIRE_ALL=1 a missing engine faster than
the one tested (or none at all) fails instead."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest

from conftest import STRICT_ENV, skip_or_fail

_SPEC = importlib.util.spec_from_file_location(
    "walk_engines", Path(__file__).resolve().parents[2] / "benchmarks" / "walk_engines.py")
we = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(we)

N = 1 << 15


def _fastest():
    """(engine name or None, reasons the faster engines are missing)."""
    missing = []
    for name in we.BY_SPEED:
        if name == "drjit":
            if we.dr is not None:
                return name, missing
            missing.append(f"drjit is not importable ({we.DRJIT_ERROR})")
        elif name.startswith("numba"):
            if we.numba is not None:
                return name, missing
            if f"numba is not importable ({we.NUMBA_ERROR})" not in missing:
                missing.append(f"numba is not importable ({we.NUMBA_ERROR})")
    return None, missing


def test_fastest_engine_agrees_with_numpy():
    name, missing = _fastest()
    if name is None:
        skip_or_fail("no walk engine is importable: " + "; ".join(missing))
    if missing and os.environ.get(STRICT_ENV, "") not in ("", "0"):
        pytest.fail(f"{'; '.join(missing)} (and {STRICT_ENV} is set, so this is an error)")
    args = (we.REGIONS, we.BOUNDARIES, we.WI, N, we.T_BINS, we.P_BINS)
    if name == "drjit":
        out = we.simulate_drjit(*args, seed=1)
    else:
        out = we.simulate_numba(*args, seed=1,
                                dtype=np.float32 if name == "numba32" else np.float64)
    ref = we.simulate_numpy(*args, seed=2)
    a = we.agreement(out, ref, N, N)
    assert np.all(np.abs(a["z"]) < 4.0), (name, a["flux_a"], a["flux_b"], a["z"])
    assert a["dof"] >= 20, (name, a["dof"])
    assert a["p"] > 1e-3, (name, a["chi2"], a["dof"], a["p"])
    # the same walk: the same number of events per path (3.73 here) within a few percent
    ev_a, ev_b = out[3]["events"] / N, ref[3]["events"] / N
    assert abs(ev_a - ev_b) < 0.05 * ev_b, (name, ev_a, ev_b)
