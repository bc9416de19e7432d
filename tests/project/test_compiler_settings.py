"""The suite compiles with fast-compile XLA settings (tests/conftest.py: TEST_XLA_FLAGS); users
get XLA's defaults. This runs the numerics that depend most on code generation — the registry
contract (values and gradients on the hard cases in float32 and float64, sampling weights and
pdfs, reciprocity, white furnace), the hard-case tests and the sampling tests — in a child
session under XLA's defaults. A session that runs this test (the whole suite) runs those quick
cases there only, under the settings users get; the quick tier, without it, runs them at the
fast-compile settings (conftest.pytest_collection_modifyitems)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import (DEFAULTS_CHECKED_MODULES, NO_OPTIMIZATION_ENV, TEST_XLA_FLAGS, XLA_DEFAULTS_ENV,
                      _release_compiled_code, user_environment, xla_default_flags)

ROOT = Path(__file__).resolve().parents[2]

#: The modules run under XLA's defaults (their quick cases; a session that runs this test runs
#: them only there: conftest.pytest_collection_modifyitems).
MODULES = DEFAULTS_CHECKED_MODULES


def test_default_flags_strip_only_the_test_settings():
    flags = "--xla_force_host_platform_device_count=2 --xla_cpu_use_fusion_emitters=false"
    assert xla_default_flags(flags) == "--xla_force_host_platform_device_count=2"
    assert NO_OPTIMIZATION_ENV not in user_environment()
    if os.environ.get(XLA_DEFAULTS_ENV, "").strip() in ("", "0"):  # this session's own settings
        assert all(f"--{k}=" in os.environ["XLA_FLAGS"] for k in TEST_XLA_FLAGS)
        assert os.environ[NO_OPTIMIZATION_ENV] in ("0", "1")  # 0 while a test is `optimized`


@pytest.mark.optimized
def test_a_marked_test_compiles_at_the_default_optimization_level():
    import jax

    if os.environ.get(XLA_DEFAULTS_ENV, "").strip() in ("", "0"):
        assert jax.config.values["jax_disable_most_optimizations"] is False
        assert os.environ[NO_OPTIMIZATION_ENV] == "0"


def test_an_unmarked_test_compiles_without_most_optimizations():
    import jax

    if os.environ.get(XLA_DEFAULTS_ENV, "").strip() in ("", "0"):
        assert jax.config.values["jax_disable_most_optimizations"] is True
        assert os.environ[NO_OPTIMIZATION_ENV] == "1"


@pytest.mark.slow
def test_contract_holds_under_xla_default_settings():
    # this worker waits for the child session: it gives back its compiled code first, so the
    # two sessions' memory does not add up (the suite's 3 GB budget)
    _release_compiled_code()
    env = {**user_environment(), XLA_DEFAULTS_ENV: "1"}
    cmd = [sys.executable, "-m", "pytest", *MODULES, "-m", "not slow", "-n", "0", "-q",
           "-p", "no:cacheprovider", "-o", "addopts="]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1500)
    tail = "\n".join(proc.stdout.splitlines()[-30:])
    assert proc.returncode == 0, f"under XLA's default settings:\n{tail}\n{proc.stderr[-2000:]}"
    assert " passed" in tail and "failed" not in tail, tail
