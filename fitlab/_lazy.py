"""A package's public names imported at their first use (PEP 562): a package whose
submodules need JAX, the simulator or matplotlib exposes their names without loading them
until one is used (``fitlab.simulate``, ``fitlab.atlas``)."""

from __future__ import annotations

import importlib
import sys


def exports(package: str, sources: dict):
    """(``__getattr__``, ``__dir__``) of ``package``, whose public names are defined in its
    submodules ``sources`` (name -> submodule, relative to the package)."""

    def getattr_(name):
        if name in sources:
            return getattr(importlib.import_module(f"{package}.{sources[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def dir_():
        return sorted(set(vars(sys.modules[package])) | set(sources))

    return getattr_, dir_
