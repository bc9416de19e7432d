"""The Python API of fitting: ``fitlab.read``, ``fitlab.fit``, ``fitlab.load_fit``. The
``fitlab fit`` command is a thin layer over these (its options map one to one onto the
arguments of :func:`fit`).

>>> import fitlab
>>> m = fitlab.read("data_formats/examples/walter_rough_glass.csv")
>>> m.n, m.channel_names, round(m.eta(), 2)
(276, ('Y',), 1.51)
>>> r = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", starts=2)
>>> r.model, r.channels
('rough_dielectric', ('Y',))
>>> round(r.parameters["Y"]["alpha"], 2), r.fixed["Y"]["eta"]
(0.4, 1.51)
>>> r.stderr["Y"]["alpha"] < 0.01
True
>>> import numpy as np
>>> wi = np.array([0.0, 0.0, 1.0]); wo = np.array([0.0, 0.0, -1.0])
>>> float(r.predict(wi, wo)) > 0     # scale × f at normal transmission
True
>>> "fitlab-fit" in r.to_json()
True
"""

from __future__ import annotations

import numpy as np

from fitlab.errors import FitlabError


def read(path, format: str | None = None):
    """Read any measurement file fitlab knows (format detected from the content unless given:
    see ``fitlab info``) into a validated :class:`fitlab.io.measurement.Measurement`."""
    from fitlab.io.formats import read_any

    return read_any(path, format)


def fit(measurement, model, *, fix: dict | None = None, free=(), options: dict | None = None,
        loss: str | None = None, subset=None, channels=None, share=(), mcmc: bool = False,
        mcmc_steps: int = 3000, walkers: int | None = None, starts: int = 8, seed: int = 0,
        walter_diagnostics: bool = False, progress: bool = False,
        aperture_order: int | None = None, bootstrap: int | None = None,
        lm_maxiter: int | None = None, start: dict | None = None, sampler: str = "emcee",
        throw: bool = False):
    """Fit ``model`` (a registry name such as ``"rough_dielectric"``, ``"lambertian+
    rough_conductor"`` or ``"coated(lambertian)"``, or a Model) to ``measurement`` (a
    Measurement or a path) and return an immutable :class:`FitResult`.

    fix: {parameter: value} held fixed; free: parameters to fit that the data file would fix
    (``eta`` from its indices); options: model options (``{"distribution": "beckmann"}``);
    loss: ``chi2`` (default with sigma), ``relative`` (default without), ``log``, ``cos_l2``;
    subset: rows to fit (an expression such as ``"theta_i == 0"`` or a boolean mask), the rest
    predicted; channels: channel names to fit (default all); share: parameters shared by every
    channel (``["alpha"]``: one geometry, the rest per channel; the channels are then fitted
    as one problem, see ``fitlab.fitting.joint``); mcmc: also sample the posterior
    with emcee (``mcmc_steps``, ``walkers``); starts: Levenberg–Marquardt starts besides the
    global search's best; seed: every random choice; walter_diagnostics: add Walter 2007 §6.1's
    empirical D; progress: report progress on stderr; aperture_order: the quadrature order over
    the rows' apertures (data that declare a detector cone, bin or source divergence: the fit
    predicts the aperture-averaged model), None to choose it from the measured quadrature
    error (see ``fitlab.fitting.aperture``; the order and the error are in the result's
    ``diagnostics()["aperture"]``); bootstrap: refits of the block bootstrap over incidence
    directions, an uncertainty that accounts for misfit (``result.bootstrap()``; None: 100 on
    channels with at least 3 fitted incidences, 0: off); lm_maxiter: each Levenberg–Marquardt
    run's step limit (None: 200; raise it when a fit warns that its run stopped at the limit);
    start: {parameter: value} for one more Levenberg–Marquardt start, at these values and the
    model's defaults elsewhere (a basin the global search may miss: ``{"kappa1": 3000}`` starts
    a thin layer with a sharp coat; every start is in ``result.record["fits"][c]["starts"]``);
    sampler: the posterior sampler with ``mcmc`` (``fitlab.fitting.samplers.SAMPLERS``: ``emcee``,
    the default and reference, or ``nuts``, blackjax's NUTS with ``walkers`` chains).
    Every fit is also checked for goodness of fit (``result.goodness()``; a failed check adds a
    warning). What limits trust in the fit is ``result.statuses(channel)`` (a
    :class:`fitlab.fitting.status.Status` each, with its advice); throw: raise a
    :class:`fitlab.errors.FitlabError` naming them instead of returning a fit that is not ``ok``.
    Raises :class:`fitlab.errors.FitlabError` with a message saying what to do."""
    from fitlab.models import get_model
    from fitlab.api import resolve_options
    from fitlab.export.paramfile import build_record, chains_payload, run_timings
    from fitlab.fitting.driver import fit_measurement
    from fitlab.fitting.result import FitResult
    from fitlab.fitting.subset import channel_ids, rows_of
    from fitlab.io.measurement import one_dataset, sanity_warnings

    m = one_dataset(read(measurement) if not hasattr(measurement, "value") else measurement)
    try:
        mdl = get_model(model) if isinstance(model, str) else model
        options = resolve_options(mdl, options or {})
    except ValueError as exc:
        raise FitlabError(f"{exc} (see `fitlab models`)") from None
    fixed = parameter_values(mdl, fix, "fix")
    start = parameter_values(mdl, start, "start")
    both = sorted(set(fixed) & set(start))
    if both:
        raise FitlabError(f"start {both[0]}: the parameter is also fixed; a start is for a "
                          "parameter the fit moves (drop one of the two)")
    for name in free or ():
        if name not in mdl.parameter_names:
            raise FitlabError(f"free {name}: model {mdl.name!r} has no parameter {name!r}")
    from fitlab.fitting.samplers import SAMPLERS

    if sampler not in SAMPLERS:
        raise FitlabError(str(SAMPLERS.unknown(sampler)))
    if mcmc and mcmc_steps < 100:
        raise FitlabError("mcmc_steps must be at least 100")
    share = (share,) if isinstance(share, str) else tuple(share or ())
    if share:
        from fitlab.fitting.joint import check_share

        try:
            share = check_share(mdl, share, fixed)
        except ValueError as exc:
            raise FitlabError(str(exc)) from None
    if aperture_order is not None:
        from fitlab.aperture import MAX_ORDER, check_order

        try:
            aperture_order = check_order(aperture_order)
        except (TypeError, ValueError):
            raise FitlabError(f"aperture_order must be an integer from 1 to {MAX_ORDER}, got "
                              f"{aperture_order!r}") from None
    if bootstrap is not None:
        from fitlab.fitting.resampling import MIN_REFITS

        if isinstance(bootstrap, bool) or not isinstance(bootstrap, (int, np.integer)) or not (
                bootstrap == 0 or bootstrap >= MIN_REFITS):
            raise FitlabError(f"bootstrap must be 0 (off) or a number of refits of at least "
                              f"{MIN_REFITS}, got {bootstrap!r}")
    from fitlab.fitting.least_squares import LM_MAXITER, MAX_LM_MAXITER

    lm_maxiter = LM_MAXITER if lm_maxiter is None else lm_maxiter
    if isinstance(lm_maxiter, bool) or not isinstance(lm_maxiter, (int, np.integer)) or \
            not 1 <= lm_maxiter <= MAX_LM_MAXITER:
        raise FitlabError(f"lm_maxiter must be an integer from 1 to {MAX_LM_MAXITER}, got "
                          f"{lm_maxiter!r}")
    expr, mask = rows_of(subset, m)
    mask = None if subset is None else mask
    chan_ids = channel_ids(channels, m)
    try:
        result = fit_measurement(m, mdl, options=options, fixed=fixed, free=tuple(free or ()),
                                 loss=loss, subset=mask, mcmc=mcmc, mcmc_steps=mcmc_steps,
                                 mcmc_walkers=walkers, seed=seed, n_starts=starts, share=share,
                                 quiet=not progress, channels=chan_ids, warn=False,
                                 aperture_order=aperture_order,
                                 bootstrap=None if bootstrap is None else int(bootstrap),
                                 lm_maxiter=int(lm_maxiter), start=start, sampler=sampler)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    result["notes"] = list(result["notes"]) + sanity_warnings(m)
    record = build_record(result, m, subset_expr=expr)
    if walter_diagnostics:
        from fitlab.fitting.walter import add_empirical_D

        add_empirical_D(record, result, m)
    chains = chains_payload(result) if mcmc else {}
    seconds = {k: v for k, v in run_timings(result, 0.0, 0.0).items() if k not in ("read", "total")}
    out = FitResult.from_record(record, chains, None, m, seconds)
    if throw:
        out.raise_for_status()
    return out


def parameter_values(model, values, what: str) -> dict:
    """``values`` ({parameter: number}, or None) checked against ``model``: known names, finite
    numbers inside the bounds; a :class:`FitlabError` names the first that is not (``what``:
    "fix" or "start", as the message calls it)."""
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


__all__ = ["read", "fit"]
