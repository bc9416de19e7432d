"""A persistent cache of compiled fit kernels, so that a new ``fitlab fit`` process does not
compile again what an earlier one compiled (JAX's persistent compilation cache).

``fitlab fit`` turns it on. The cache lives in ``$FITLAB_CACHE_DIR`` if set, else
``$XDG_CACHE_HOME/fitlab/xla``, else ``~/.cache/fitlab/xla``; ``FITLAB_NO_CACHE=1`` turns it off.
An entry is keyed by the computation, the JAX/jaxlib version, the XLA flags and the CPU, so a
stale entry is never used; the first fit of a given structure (model, options, free parameters,
loss, and the row count rounded up to a ladder of sizes 2^(1/4) apart: least_squares.padded_size)
still compiles, later ones load. The directory can be deleted at any time.
Library users can call :func:`enable_compilation_cache` themselves before their first fit.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_DIR = "FITLAB_CACHE_DIR"
ENV_OFF = "FITLAB_NO_CACHE"


def cache_dir() -> Path | None:
    """Where compiled kernels are kept, or None when the cache is turned off."""
    if os.environ.get(ENV_OFF, "").strip() not in ("", "0"):
        return None
    if os.environ.get(ENV_DIR, "").strip():
        return Path(os.environ[ENV_DIR]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or Path.home() / ".cache"
    return Path(base) / "fitlab" / "xla"


def enable_compilation_cache() -> str | None:
    """Keep every compiled kernel of this process on disk (see the module text). Call it before
    the first computation; returns the directory, or None when off or not writable (the fit then
    simply compiles, as without a cache)."""
    path = cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK):
            return None
    except OSError:
        return None
    from fitlab._jax import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # Cache every kernel: the fit's kernels compile in well under JAX's default 1 s threshold
    # each, yet together they are most of a cold fit's time.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(path)
