"""fitlab: BSDF measurement fitting and tabulation in JAX.

The stable entry points for scripts: :func:`read` (any measurement file), :func:`fit` (→ an
immutable :class:`FitResult`; its settings are a :class:`FitRequest`, checked once), :func:`fit_many` (many datasets at once, batched), :func:`fit_maps` (a capture stack
fitted texel by texel into texture maps; :func:`render_maps_gltf`: its glTF hand-off rendered by
three.js beside the input images),
:func:`load_fit` (a parameter file and its chain), :func:`compare` (candidate models ranked by
held-out error → a :class:`CompareResult`), :func:`export_material` (a fit for Mitsuba 3,
glTF 2.0 or MaterialX's OpenPBR), :func:`complete_measurement` (a measurement with its missing readings filled by a
fit, ``fitlab convert --complete``), :func:`write_report` (the HTML report of a fit or of a comparison), and
:func:`eval_bsdf`, :func:`sample_bsdf`, :func:`pdf_bsdf` for models, :func:`atlas` (the layered
models' validation atlas, ``fitlab atlas``); the model registry is
:data:`fitlab.models.MODELS`. Conventions (frame, directions, units) are written down in
``data_formats/CONVENTIONS.md``.

``import fitlab`` is quick: each name below is imported at its first use (PEP 562), so the
command line's ``--help`` and ``fitlab models`` never load JAX. A first use of a name loads JAX
with fitlab's settings (float64, no asynchronous dispatch on the CPU: fitlab/_jax.py), as
``import fitlab`` used to; subpackages (``fitlab.models``, ``fitlab.io`` ...) are imported on
first use too.
"""

import importlib as _importlib
import sys as _sys
import types as _types

from fitlab import _jax  # noqa: F401  (JAX_ENABLE_X64 before anything imports JAX)
from fitlab.version import __version__

#: Public name -> the module that defines it (``__all__``, in its order).
_SOURCES = {
    "read": "fitlab.fitting.api", "fit": "fitlab.fitting.api",
    "FitRequest": "fitlab.fitting.request",
    "load_fit": "fitlab.fitting.result", "FitResult": "fitlab.fitting.result",
    "compare": "fitlab.fitting.compare", "CompareResult": "fitlab.fitting.compare",
    "Candidate": "fitlab.fitting.compare",
    "export_material": "fitlab.export.renderers",
    "complete_measurement": "fitlab.export.completion",
    "fit_many": "fitlab.fitting.many", "ManyResult": "fitlab.fitting.many",
    "fit_maps": "fitlab.fitting.maps", "MapsResult": "fitlab.fitting.maps",
    "render_maps_gltf": "fitlab.export.gltf_maps_render",
    "eval_bsdf": "fitlab.api", "sample_bsdf": "fitlab.api", "pdf_bsdf": "fitlab.api",
    "MODELS": "fitlab.models", "get_model": "fitlab.models", "register_model": "fitlab.models",
    "tradeoffs": "fitlab.tradeoffs", "Tradeoffs": "fitlab.tradeoffs",
    "atlas": "fitlab.atlas.run",
    "write_report": "fitlab.report.api",  # matplotlib: only when a report is written
}

__all__ = ["__version__", *_SOURCES]


def __getattr__(name):
    if name in _SOURCES:
        _jax.load()  # fitlab's JAX settings before the library's first computation
        value = getattr(_importlib.import_module(_SOURCES[name]), name)
        globals()[name] = value  # the next use is a plain attribute
        return value
    if not name.startswith("_"):  # a subpackage or module: fitlab.models, fitlab.io ...
        try:
            return _importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(_types.ModuleType):
    """The package root: importing a subpackage named like a public name (``fitlab.tradeoffs``,
    the package, and ``fitlab.tradeoffs``, the function) leaves the public name as it is."""

    def __setattr__(self, name, value):
        if name in _SOURCES and isinstance(value, _types.ModuleType):
            return
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
