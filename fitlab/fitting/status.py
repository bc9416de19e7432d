"""What happened to a fit: one :class:`Status` type for the solvers, the samplers and the fit as
a whole. Each member carries its advice; the Python API can raise on a status that is not
``ok`` (``fitlab.fit(..., throw=True)``), the CLI prints the advice, and files keep the member's
value, the same strings they always held (``"converged"``, ``"max_iterations"``, ...).

A fit's statuses are read from its record (:func:`channel_statuses`): the solver's stopping
reason, the starts, the parameters at a bound, the chain, the goodness of fit, the bootstrap and
the aperture quadrature, as ``fits[k]`` of data_formats/fit_json.md holds them.
"""

from __future__ import annotations

from enum import StrEnum

from fitlab.errors import FitlabError


class Status(StrEnum):
    """Why a solver or a sampler stopped, or what limits a fit's trust (value: the string files
    keep)."""

    #: the stopping rule was met: nothing to report
    CONVERGED = "converged"
    #: Levenberg–Marquardt ran out of iterations before its stopping rule was met
    MAX_ITERATIONS = "max_iterations"
    #: the cost was NaN or inf where the solver ended
    NON_FINITE = "non_finite"
    #: some starts ended at NaN or inf and were left out (the others gave the fit)
    STARTS_LOST = "starts_lost"
    #: starts reached costs as good as the best at other parameters
    STARTS_DISAGREE = "starts_disagree"
    #: a fitted parameter ended at a bound of its range
    AT_BOUND = "at_bound"
    #: the MCMC chain is too short, or its diagnostics fail
    CHAIN_UNTRUSTED = "chain_untrusted"
    #: the residuals do not look like the noise: the model does not describe the data
    MISFIT = "misfit"
    #: too few bootstrap refits ended at finite values
    BOOTSTRAP_FAILED = "bootstrap_failed"
    #: the aperture quadrature moves the optimum by more than its tolerance
    APERTURE_INACCURATE = "aperture_inaccurate"
    #: a cross-validation fold of a comparison could not be fitted (the model is ranked last)
    FOLDS_FAILED = "folds_failed"
    #: nothing to fit: a texel of a capture stack with no reading (NaN in every image), too few
    #: readings for its free parameters, or only zeros (fitlab fit-maps)
    NO_DATA = "no_data"

    @property
    def ok(self) -> bool:
        """Whether a fit with this status can be used as it stands."""
        return self is Status.CONVERGED

    @property
    def code(self) -> int:
        """The status as a number (``status.exr`` of ``fitlab fit-maps``): 0 converged, then
        the members in the order above, 1, 2, …; a new member goes last, so codes never
        change (data_formats/stack.md, "Status codes")."""
        return list(Status).index(self)

    @property
    def advice(self) -> str:
        """What to do about it."""
        return _ADVICE[self]


_ADVICE = {
    Status.CONVERGED: "nothing to do",
    Status.MAX_ITERATIONS: "refit with more iterations (--lm-maxiter, lm_maxiter in Python) or "
                           "a better start (--start)",
    Status.NON_FINITE: "check the data (zero or negative values with the log loss, zero sigma) "
                       "and the fixed parameters: the model or the loss is not finite there",
    Status.STARTS_LOST: "nothing needs doing if the fit is good; otherwise give a start "
                        "(--start) where the model is not zero at every measured direction",
    Status.STARTS_DISAGREE: "the data do not pin the parameters down: fix one of them (--fix), "
                            "measure more directions, or read the posterior (--mcmc)",
    Status.AT_BOUND: "widen the parameter's range if the model allows it, or fix it at the "
                     "bound; its uncertainty is not meaningful",
    Status.CHAIN_UNTRUSTED: "run a longer chain (--mcmc-steps, the warning gives a length) or "
                            "another sampler (--sampler)",
    Status.MISFIT: "the model does not describe the data within their noise: compare models "
                   "(fitlab compare), or trust the bootstrap interval over the least-squares one",
    Status.BOOTSTRAP_FAILED: "read the least-squares uncertainty with care, or refit with "
                             "fewer free parameters",
    Status.APERTURE_INACCURATE: "refit with a higher aperture order (--aperture-order)",
    Status.NO_DATA: "nothing was fitted there: check the images at that texel (NaN is no "
                     "reading), or fit fewer parameters (--fix)",
    Status.FOLDS_FAILED: "read the fold's error in the comparison's warnings; give the candidate "
                         "a start (--start inside its --model) or fix a parameter (--fix)",
}


def channel_statuses(fit: dict) -> tuple[Status, ...]:
    """The statuses of one channel's entry of a parameter file (``fits[k]``): the solver's
    stopping reason first, then each thing that limits trust in the fit; ``(CONVERGED,)`` when
    nothing does."""
    out = []
    stopped = (fit.get("solver") or {}).get("stopped")
    if stopped in (Status.MAX_ITERATIONS, Status.NON_FINITE):
        out.append(Status(stopped))
    if stopped != Status.NON_FINITE and any(
            (s or {}).get("lm_stopped") == Status.NON_FINITE for s in fit.get("starts") or ()):
        out.append(Status.STARTS_LOST)
    if fit.get("starts_disagree"):
        out.append(Status.STARTS_DISAGREE)
    if any(p.get("at_bound") for p in (fit.get("parameters") or {}).values()):
        out.append(Status.AT_BOUND)
    mcmc = fit.get("mcmc")
    if mcmc and not mcmc.get("trustworthy", True):
        out.append(Status.CHAIN_UNTRUSTED)
    goodness = fit.get("goodness")
    if goodness and goodness.get("describes_data") is False:
        out.append(Status.MISFIT)
    boot = fit.get("bootstrap")
    if (boot and boot.get("requested") and not boot.get("skipped")
            and (boot.get("replicates") or 0) < 2):
        out.append(Status.BOOTSTRAP_FAILED)
    err = (fit.get("aperture") or {}).get("quadrature_error") or {}
    if err and err.get("within_tolerance") is False:
        out.append(Status.APERTURE_INACCURATE)
    return tuple(out) or (Status.CONVERGED,)


def trusted(result, headline: str, bad):
    """``result`` when ``bad`` (``(where, Status)`` pairs: what is not ``ok``) is empty, else a
    FitlabError that starts with ``headline`` and names each status and what to do about it:
    every result type's ``raise_for_status``."""
    if bad:
        raise FitlabError(f"{headline}: " + "; ".join(
            f"{where}: {s.value} ({s.advice})" for where, s in bad))
    return result

