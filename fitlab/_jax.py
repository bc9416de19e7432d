"""fitlab's one way to JAX: ``from fitlab._jax import jax, jnp`` (``jsp_special`` for
``jax.scipy.special``, ``jsp_linalg`` for ``jax.scipy.linalg``). No other fitlab module imports JAX (tests/project/test_layers.py checks
it), so fitlab's two JAX settings below are in place before any fitlab code uses JAX.

The three names stand for the JAX modules and import JAX at their first use (an attribute,
e.g. ``jnp.where``), not when a module imports them: what only *declares* things (the model
registry and its models, the command line's parsers, ``fitlab models``) loads without JAX,
which takes a second. A module that needs JAX at import time (``@jax.jit`` on a function)
loads it then. The first use applies the settings:

* ``jax_enable_x64``: fitlab fits in float64; float32 inputs still evaluate in float32 (see
  data_formats/CONVENTIONS.md). The package root imports this module, which sets
  JAX_ENABLE_X64 in the environment while JAX is not loaded yet, so that JAX code beside
  fitlab computes in float64 too, as it did when ``import fitlab`` imported JAX.
* ``jax_cpu_enable_async_dispatch=False``: CPU computations run on the calling thread. fitlab's
  fits make thousands of small calls whose results are needed at once, and the hand-off to a
  worker thread cost more than the work (about 50 us a call on a 2-core VM). Large evaluations
  still use every core. Takes effect only if JAX's CPU backend has not started yet: the
  package root's public names (``fitlab.fit`` ...) apply it when first used.

And one XLA setting, in XLA_FLAGS while JAX is not loaded yet (as JAX_ENABLE_X64; a user's
own value is kept): ``--xla_force_host_platform_device_count`` = the cores this process may
use, so that JAX's CPU backend has one device per core. Independent work that must not be
vmapped, NUTS's chains, runs one chain per core on them (fitlab/fitting/nuts.py); everything
else computes on the first device as before, with every core's threads.
"""

from __future__ import annotations

import importlib
import os
import sys
import types

#: fitlab's JAX settings (see above).
SETTINGS = {"jax_enable_x64": True, "jax_cpu_enable_async_dispatch": False}

#: XLA's flag for the number of host (CPU) devices.
HOST_DEVICES_FLAG = "--xla_force_host_platform_device_count"

_configured = False


def host_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS and Windows
        return os.cpu_count() or 1


def host_device_flags(flags: str, cores: int) -> str:
    """XLA_FLAGS ``flags`` with one host device per core, unless they already set a count."""
    if HOST_DEVICES_FLAG in flags:
        return flags
    return f"{flags} {HOST_DEVICES_FLAG}={max(int(cores), 1)}".strip()


def load():
    """JAX, imported, with fitlab's settings applied."""
    global _configured
    import jax

    if not _configured:
        for name, value in SETTINGS.items():
            jax.config.update(name, value)
        _configured = True
    return jax


class _LazyModule(types.ModuleType):
    """A JAX module imported (after :func:`load`) at its first attribute use; its names are
    then this object's own, so a use costs what a module attribute does."""

    def __init__(self, name: str):
        super().__init__(name)
        self.__dict__["_lazy_target"] = name

    def __getattr__(self, attr):
        module = self.__dict__.get("_lazy_module")
        if module is None:
            load()
            module = importlib.import_module(self.__dict__["_lazy_target"])
            self.__dict__.update(vars(module))
            self.__dict__["_lazy_module"] = module
        return getattr(module, attr)

    def __repr__(self):
        state = "" if "_lazy_module" in self.__dict__ else " (not imported yet)"
        return f"<module {self.__dict__['_lazy_target']!r} through fitlab._jax{state}>"


jax = _LazyModule("jax")
jnp = _LazyModule("jax.numpy")
jsp_special = _LazyModule("jax.scipy.special")
jsp_linalg = _LazyModule("jax.scipy.linalg")

if "jax" in sys.modules:  # JAX came first: the settings now, as at a first use
    load()
else:
    os.environ["JAX_ENABLE_X64"] = "true"
    os.environ["XLA_FLAGS"] = host_device_flags(os.environ.get("XLA_FLAGS", ""), host_cores())

__all__ = ["HOST_DEVICES_FLAG", "SETTINGS", "host_cores", "host_device_flags", "jax", "jnp",
           "jsp_linalg", "jsp_special", "load"]
