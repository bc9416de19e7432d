"""Shared test set-up: float64 on, strict dtype promotion, and skips that CI turns into failures."""

from __future__ import annotations

import os

import jax
import pytest

# Tests never write to the user's compilation cache (fitlab fit keeps one by default).
os.environ.setdefault("FITLAB_NO_CACHE", "1")

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

#: Set by .ci/run: a test that would skip for a missing system package fails instead.
STRICT_ENV = "FITLAB_REQUIRE_ALL"


def skip_or_fail(reason: str):
    """Skip with ``reason`` on a developer machine; fail in CI (FITLAB_REQUIRE_ALL=1)."""
    if os.environ.get(STRICT_ENV, "") not in ("", "0"):
        pytest.fail(f"{reason} (and {STRICT_ENV} is set, so this is an error)")
    pytest.skip(reason)


@pytest.fixture(params=["float32", "float64"])
def dtype(request):
    import jax.numpy as jnp

    return jnp.dtype(request.param)


@pytest.fixture(scope="module")
def mitsuba_scalar():
    """Mitsuba 3 in its ``scalar_rgb`` variant (float32, needs no LLVM), the independent
    implementation the agreement tests compare with; the previous variant is restored after."""
    try:
        import mitsuba
    except ImportError as exc:
        skip_or_fail(f"mitsuba is not importable ({exc}); install the test extra: "
                     "pip install -e '.[test]'")
    previous = mitsuba.variant()
    try:
        mitsuba.set_variant("scalar_rgb")
    except Exception as exc:  # noqa: BLE001 - whatever the reason, there is nothing to compare
        skip_or_fail(f"mitsuba variant scalar_rgb unavailable ({exc})")
    yield mitsuba
    if previous is not None and previous != "scalar_rgb":
        mitsuba.set_variant(previous)
