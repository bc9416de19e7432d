"""fitlab: BSDF measurement fitting and tabulation in JAX.

The stable entry points for scripts: :func:`read` (any measurement file), :func:`fit` (→ an
immutable :class:`FitResult`; its settings are a :class:`FitRequest`, checked once), :func:`fit_many` (many datasets at once, batched),
:func:`load_fit` (a parameter file and its chain), :func:`compare` (candidate models ranked by
held-out error → a :class:`CompareResult`), :func:`export_material` (a fit for Mitsuba 3 or
glTF 2.0), :func:`write_report` (the HTML report of a fit or of a comparison), and
:func:`eval_bsdf`, :func:`sample_bsdf`, :func:`pdf_bsdf` for models; the model registry is
:data:`fitlab.models.MODELS`. Conventions (frame, directions, units) are written down in
``data_formats/CONVENTIONS.md``.
"""

import jax as _jax

# fitlab fits in float64; float32 inputs still evaluate in float32 (see data_formats/CONVENTIONS.md).
_jax.config.update("jax_enable_x64", True)
# Run CPU computations on the calling thread: fitlab's fits make thousands of small calls whose
# results are needed at once, and the hand-off to a worker thread cost more than the work
# (about 50 us a call on a 2-core VM). Large evaluations still use every core. Takes effect only
# if fitlab is imported before JAX's CPU backend starts.
_jax.config.update("jax_cpu_enable_async_dispatch", False)

from fitlab.version import __version__  # noqa: E402
from fitlab.api import eval_bsdf, pdf_bsdf, sample_bsdf  # noqa: E402
from fitlab.models import MODELS, get_model, register_model  # noqa: E402
from fitlab.fitting.api import fit, read  # noqa: E402
from fitlab.fitting.request import FitRequest  # noqa: E402
from fitlab.fitting.result import FitResult, load_fit  # noqa: E402
from fitlab.fitting.compare import Candidate, CompareResult, compare  # noqa: E402
from fitlab.export.renderers import export_material  # noqa: E402
from fitlab.fitting.many import ManyResult, fit_many  # noqa: E402
from fitlab.tradeoffs import Tradeoffs, tradeoffs  # noqa: E402

__all__ = ["__version__", "read", "fit", "FitRequest", "load_fit", "FitResult", "compare", "CompareResult",
           "Candidate", "export_material", "fit_many", "ManyResult", "eval_bsdf", "sample_bsdf",
           "pdf_bsdf", "MODELS", "get_model", "register_model", "tradeoffs", "Tradeoffs",
           "write_report"]


def __getattr__(name):
    # write_report loads the report package (matplotlib): on first use, not with `import fitlab`
    if name == "write_report":
        from fitlab.report.api import write_report

        return write_report
    raise AttributeError(f"module 'fitlab' has no attribute {name!r}")
