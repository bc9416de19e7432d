"""A fit request: everything a fit needs besides the data, checked once.

:class:`FitRequest` is frozen and validated when it is made: the model resolved (a registry name
or a Model), its options, the parameters fixed, freed and started, the loss, the shared
parameters, the sampler and every step budget. ``fitlab.fit``, ``fitlab.compare`` (one request
per candidate), ``fitlab.fit_many``, the Dask runner and the ``fitlab fit`` / ``fitlab compare``
commands all build one and hand it down; nothing below them checks these settings again. What
depends on the data (the subset expression, the channel names, ``eta`` from the file, the
default loss) is resolved against each measurement by :mod:`fitlab.fitting.subset` and
:func:`fitlab.fitting.channel.resolve_fit`.

>>> from fitlab.fitting.request import FitRequest
>>> r = FitRequest("rough_dielectric", fix={"eta": 1.5}, lm_maxiter=50)
>>> r.model.name, dict(r.fix), r.lm_maxiter, r.sampler
('rough_dielectric', {'eta': 1.5}, 50, 'emcee')
>>> FitRequest("rough_dielectric", mcmc=True, mcmc_steps=10)
Traceback (most recent call last):
...
fitlab.errors.FitlabError: mcmc_steps must be at least 100, got 10
>>> FitRequest("rough_dielectric", mcmc=True, mcmc_steps=10, spelling="cli")
Traceback (most recent call last):
...
fitlab.errors.FitlabError: --mcmc-steps must be at least 100, got 10

``spelling="cli"`` names the settings as the command line's options in messages.
"""

from __future__ import annotations

import dataclasses
from dataclasses import InitVar, dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.samplers import MCMC_STEPS
from fitlab.fitting.space import SCALE
from fitlab.models.base import Model

#: The fit's default step budgets (fitlab.fit; fit_many has its own MCMC default; each
#: sampler's default steps are its registry entry's ``steps``, emcee's MCMC_STEPS).
MIN_MCMC_STEPS = 100
STARTS = 8


def _name(field_name: str, spelling: str) -> str:
    """A setting as a message names it: ``lm_maxiter`` or ``--lm-maxiter``."""
    return "--" + field_name.replace("_", "-") if spelling == "cli" else field_name


def _integer(value, name: str, lo: int, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo or (
            hi is not None and value > hi):
        span = f"from {lo} to {hi}" if hi is not None else f"of at least {lo}"
        raise FitlabError(f"{name} must be an integer {span}, got {value!r}")
    return int(value)


def parameter_values(model: Model, values, what: str) -> dict:
    """``values`` ({parameter: number or numeric text}, or None) checked against ``model``: known
    names, finite numbers inside the bounds; a :class:`FitlabError` names the first that is not
    (``what``: "fix", "start", "--fix", … as the message calls it)."""
    from fitlab.api import check_params

    out = {}
    for name, value in (values or {}).items():
        if name not in model.parameter_names:
            raise FitlabError(f"{what} {name}: model {model.name!r} has no parameter {name!r} "
                              f"(its parameters: {', '.join(model.parameter_names)})")
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            raise FitlabError(f"{what} {name}={value!r}: the value must be a number") from None
    try:
        check_params(model, {**{p.name: p.default for p in model.parameters}, **out})
    except ValueError as exc:
        raise FitlabError(f"{what}: {exc}") from None
    return out


def check_share(model: Model, share, fixed: dict) -> tuple[str, ...]:
    """The parameters shared across channels (fitlab.fitting.joint), checked: model parameters,
    not fixed, not ``scale``."""
    share = tuple(dict.fromkeys(share or ()))
    for name in share:
        if name == SCALE:
            raise ValueError(f"share {SCALE}: the scale of relative data is per channel (each "
                             "channel has its own unknown units); share model parameters")
        if name not in model.parameter_names:
            raise ValueError(f"share {name}: model {model.name!r} has no parameter {name!r} "
                             f"(its parameters: {', '.join(model.parameter_names)})")
        if name in fixed:
            raise ValueError(f"share {name}: {name} is fixed (it is the same in every channel "
                             "already); share free parameters")
    return share


@dataclass(frozen=True, eq=False)
class FitRequest:
    """One fit's settings, validated on creation (see the module text; the meaning of each is
    :func:`fitlab.fit`'s). ``subset`` and ``channels`` stay as given (an expression or a mask,
    names): they are checked against each measurement. ``dataclasses.replace`` makes a checked
    variant (compare's candidates)."""

    model: Any
    fix: Mapping[str, float] = field(default_factory=dict)
    free: tuple[str, ...] = ()
    options: Mapping[str, str] = field(default_factory=dict)
    loss: str | None = None
    subset: Any = None
    channels: tuple[str, ...] | None = None
    share: tuple[str, ...] = ()
    mcmc: bool = False
    #: None: the sampler's default (fitlab.fitting.samplers.SAMPLERS: emcee 3000, nuts 1000)
    mcmc_steps: int | None = None
    walkers: int | None = None
    sampler: str = "emcee"
    starts: int = STARTS
    global_search: str = "scan"
    local_solver: str = "fitlab"
    seed: int = 0
    aperture_order: int | None = None
    bootstrap: int | None = None
    lm_maxiter: int | None = None
    start: Mapping[str, float] = field(default_factory=dict)
    walter_diagnostics: bool = False
    progress: bool = False
    #: the illuminant of a spectral fit's colour block (a colour-science name; None: D65)
    illuminant: str | None = None
    #: the model check against the fitted stack's simulation (fitlab.fitting.model_check):
    #: "auto", "on" or "off"
    check_model: str = "auto"
    spelling: InitVar[str] = "python"

    def __post_init__(self, spelling: str) -> None:
        set_ = object.__setattr__
        set_(self, "_spelling", spelling)
        name = (lambda f: _name(f, spelling))
        for f in ("fix", "options", "start"):
            if getattr(self, f) is not None and not isinstance(getattr(self, f), Mapping):
                raise FitlabError(f"{name(f)} must be a mapping of names to values, got "
                                  f"{getattr(self, f)!r}")
        if self.channels is not None and not isinstance(self.channels, str) and (
                not isinstance(self.channels, (list, tuple))
                or not all(isinstance(c, str) for c in self.channels)):
            raise FitlabError(f"{name('channels')} must be channel names, got {self.channels!r}")
        from fitlab.api import resolve_options
        from fitlab.models import get_model

        try:
            mdl = get_model(self.model) if isinstance(self.model, str) else self.model
            if not isinstance(mdl, Model):
                raise ValueError(f"model must be a registry name or a Model, got {mdl!r}")
            options = resolve_options(mdl, dict(self.options or {}))
        except ValueError as exc:
            raise FitlabError(f"{exc} (see `fitlab models`)") from None
        set_(self, "model", mdl)
        set_(self, "options", MappingProxyType(options))
        fixed = parameter_values(mdl, self.fix, name("fix"))
        start = parameter_values(mdl, self.start, name("start"))
        both = sorted(set(fixed) & set(start))
        if both:
            raise FitlabError(f"{name('start')} {both[0]}: the parameter is also fixed; a start "
                              "is for a parameter the fit moves (drop one of the two)")
        set_(self, "fix", MappingProxyType(fixed))
        set_(self, "start", MappingProxyType(start))
        free = (self.free,) if isinstance(self.free, str) else tuple(self.free or ())
        for p in free:
            if p not in mdl.parameter_names:
                raise FitlabError(f"{name('free')} {p}: model {mdl.name!r} has no parameter "
                                  f"{p!r} (its parameters: {', '.join(mdl.parameter_names)})")
        set_(self, "free", tuple(dict.fromkeys(free)))
        from fitlab.fitting.losses import LOSSES

        if self.loss is not None and self.loss not in LOSSES:
            raise FitlabError(f"{name('loss')} {self.loss}: {LOSSES.unknown(self.loss)}")
        if isinstance(self.subset, str) or self.subset is None:
            pass
        else:
            mask = np.array(self.subset, dtype=bool)
            mask.setflags(write=False)
            set_(self, "subset", mask)
        if self.channels is not None:
            set_(self, "channels", (self.channels,) if isinstance(self.channels, str)
                 else tuple(self.channels))
        share = (self.share,) if isinstance(self.share, str) else tuple(self.share or ())
        if share:
            try:
                share = check_share(mdl, share, fixed)
            except ValueError as exc:
                raise FitlabError(str(exc)) from None
        set_(self, "share", share)
        from fitlab.fitting.samplers import SAMPLERS

        if self.sampler not in SAMPLERS:
            raise FitlabError(f"{name('sampler')}: {SAMPLERS.unknown(self.sampler)}")
        set_(self, "mcmc", bool(self.mcmc))
        if self.mcmc_steps is None:
            set_(self, "mcmc_steps", SAMPLERS[self.sampler].steps)
        steps = self.mcmc_steps
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or (
                self.mcmc and steps < MIN_MCMC_STEPS):
            raise FitlabError(f"{name('mcmc_steps')} must be at least {MIN_MCMC_STEPS}, got "
                              f"{steps!r}")
        set_(self, "mcmc_steps", int(self.mcmc_steps))
        if self.walkers is not None:
            set_(self, "walkers", _integer(self.walkers, name("walkers"), 2))
        set_(self, "starts", _integer(self.starts, name("starts"), 0))
        from fitlab.fitting.searches import GLOBAL_SEARCHES

        if self.global_search not in GLOBAL_SEARCHES:
            raise FitlabError(f"{name('global_search')}: "
                              f"{GLOBAL_SEARCHES.unknown(self.global_search)}")
        from fitlab.fitting.solvers import LOCAL_SOLVERS

        if self.local_solver not in LOCAL_SOLVERS:
            raise FitlabError(f"{name('local_solver')}: "
                              f"{LOCAL_SOLVERS.unknown(self.local_solver)}")
        set_(self, "seed", _integer(self.seed, name("seed"), 0))
        if self.aperture_order is not None:
            from fitlab.aperture import MAX_ORDER, check_order

            try:
                set_(self, "aperture_order", check_order(self.aperture_order))
            except (TypeError, ValueError):
                raise FitlabError(f"{name('aperture_order')} must be an integer from 1 to "
                                  f"{MAX_ORDER}, got {self.aperture_order!r}") from None
        if self.bootstrap is not None:
            from fitlab.fitting.resampling import MIN_REFITS

            b = self.bootstrap
            if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or not (
                    b == 0 or b >= MIN_REFITS):
                raise FitlabError(f"{name('bootstrap')} must be 0 (off) or a number of refits of "
                                  f"at least {MIN_REFITS}, got {b!r}")
            set_(self, "bootstrap", int(b))
        from fitlab.fitting.least_squares import LM_MAXITER, MAX_LM_MAXITER

        set_(self, "lm_maxiter", _integer(LM_MAXITER if self.lm_maxiter is None
                                          else self.lm_maxiter, name("lm_maxiter"), 1,
                                          MAX_LM_MAXITER))
        set_(self, "walter_diagnostics", bool(self.walter_diagnostics))
        set_(self, "progress", bool(self.progress))
        if self.illuminant is not None:
            from fitlab.colorimetry import illuminant_table

            if not isinstance(self.illuminant, str):
                raise FitlabError(f"{name('illuminant')} must be an illuminant's name such as "
                                  f"D65, got {self.illuminant!r}")
            try:
                illuminant_table(self.illuminant)
            except ValueError as exc:
                raise FitlabError(f"{name('illuminant')}: {exc}") from None
        from fitlab.fitting.model_check import MODES

        if self.check_model not in MODES:
            raise FitlabError(f"{name('check_model')} must be one of {', '.join(MODES)}, got "
                              f"{self.check_model!r}")

    def replace(self, **changes) -> "FitRequest":
        """A variant with ``changes``, checked again (messages spelt as this one's)."""
        return dataclasses.replace(self, spelling=self._spelling, **changes)

    def name_of(self, field_name: str) -> str:
        """A setting as this request's messages name it (``lm_maxiter`` or ``--lm-maxiter``)."""
        return _name(field_name, self._spelling)

    def single_only(self) -> list[str]:
        """The settings set here that only a single fit offers (a batched fit of many datasets
        does not): ``share``, ``bootstrap``, ``aperture_order``, ``start``, ``channels``,
        ``walter_diagnostics``, a ``global_search`` other than the scan and a
        ``local_solver`` other than fitlab's (a batched fit always scans and runs fitlab's
        solver with a fixed budget, fitlab.fitting.batch)."""
        return [f for f in ("share", "bootstrap", "aperture_order", "start", "channels",
                            "walter_diagnostics") if getattr(self, f)] + (
            ["global_search"] if self.global_search != "scan" else []) + (
            ["local_solver"] if self.local_solver != "fitlab" else [])


def as_request(model, settings: dict) -> FitRequest:
    """``model`` if it is a FitRequest already (then ``settings`` must be empty), else a
    FitRequest of ``model`` and ``settings``."""
    if isinstance(model, FitRequest):
        if settings:
            raise FitlabError(f"give the settings in the FitRequest, not also as keywords "
                              f"({', '.join(sorted(settings))})")
        return model
    return FitRequest(model, **settings)


__all__ = ["FitRequest", "as_request", "check_share", "parameter_values", "MCMC_STEPS", "MIN_MCMC_STEPS",
           "STARTS"]
