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

from fitlab.errors import FitlabError


def read(path, format: str | None = None, *, angles: str | None = None, accept=(),
         quantity: str | None = None):
    """Read any measurement file fitlab knows (format detected from the content unless given:
    see ``fitlab info``) into a validated :class:`fitlab.io.measurement.Measurement`.

    The sanity gates (:mod:`fitlab.io.gates`) refuse a valid but implausible file with an
    InputFileError naming the fix: angles that look like radians, values that look like another
    quantity, negative values beyond detector noise, a stored total integrated scatter the data
    disagree with. ``accept``: gate names (``"radians"``, ``"quantity"``, ``"negative"``,
    ``"tis"``) to read the file anyway (each accepted finding is kept in ``m.accepted`` and a
    fit's notes); ``angles="radians"``: the file's angles are radians, converted to degrees;
    ``quantity``: what the values are (``bsdf``, ``bsdf_cos``, ``radiance_factor``,
    ``relative``), replacing the file's ``# quantity:`` line. ``angles`` and ``quantity`` apply to
    fitlab's measurement CSV (data_formats/measurement_csv.md, "Sanity gates"); ``quantity``
    also to the spectral scan CSV, which requires it (data_formats/spectral_scan_csv.md)."""
    from fitlab.io.formats import read_any

    return read_any(path, format, angles=angles, accept=accept, quantity=quantity)


def measurement_of(measurement, what: str = "measurement", **read_options):
    """``measurement`` if it is a Measurement, else the file it names read with
    ``read_options`` (:func:`read`'s ``format``, ``angles``, ``accept``, ``quantity``); options
    given with a Measurement are refused (it was read already)."""
    given = {k: v for k, v in read_options.items() if v not in (None, (), [])}
    if hasattr(measurement, "value"):
        if given:
            raise FitlabError(f"{', '.join(sorted(given))}: options of reading a file; this "
                              f"{what} is a Measurement read already (pass them to "
                              "fitlab.read, or give the path)")
        return measurement
    return read(measurement, **given)


def fit(measurement, model, *, throw: bool = False, angles: str | None = None, accept=(),
        quantity: str | None = None, **settings):
    """Fit ``model`` (a registry name such as ``"rough_dielectric"``, ``"lambertian+
    rough_conductor"`` or ``"coated(lambertian)"``, a Model, or a whole
    :class:`~fitlab.fitting.request.FitRequest`) to ``measurement`` (a Measurement or a path) and
    return an immutable :class:`FitResult`.

    settings (the fields of :class:`~fitlab.fitting.request.FitRequest`, checked once there):
    fix: {parameter: value} held fixed; free: parameters to fit that the data file would fix
    (``eta`` from its indices); options: model options (``{"distribution": "beckmann"}``);
    loss: ``chi2`` (default with sigma), ``relative`` (default without), ``log``, ``cos_l2``;
    subset: rows to fit (an expression such as ``"theta_i == 0"`` or a boolean mask), the rest
    predicted; channels: channel names to fit (default all); share: parameters shared by every
    channel (``["alpha"]``: one geometry, the rest per channel; the channels are then fitted
    as one problem, see ``fitlab.fitting.joint``); mcmc: also sample the posterior
    with emcee (``mcmc_steps``, default the sampler's: emcee 3000, nuts 1000; ``walkers``); starts: Levenberg–Marquardt
    starts besides the global search's best (default 8); global_search: how the first start is
    found (``"scan"``, the default: the cost at a few hundred low-discrepancy points in one
    compiled call; ``"mlsl"``: nlopt's MLSL, slower, for basins narrower than the scan's grid;
    ``fitlab.fitting.searches.GLOBAL_SEARCHES``); local_solver: the Levenberg–Marquardt
    implementation (``"fitlab"``, the default: one forward-mode pass a step; ``"jaxopt"``:
    jaxopt's, the reference, about 3x slower; ``fitlab.fitting.solvers.LOCAL_SOLVERS``);
    seed: every random choice;
    walter_diagnostics: add Walter 2007 §6.1's empirical D; progress: report progress on
    stderr; aperture_order: the quadrature order over the rows' apertures (data that declare a
    detector cone, bin or source divergence: the fit predicts the aperture-averaged model), None
    to choose it from the measured quadrature error (see ``fitlab.fitting.aperture``; the order
    and the error are in the result's ``diagnostics()["aperture"]``); bootstrap: refits of the
    block bootstrap over incidence directions, an uncertainty that accounts for misfit
    (``result.bootstrap()``; None: on channels with at least 3 fitted incidences, until its
    intervals settle, at most 100; N: exactly N; 0: off; skipped where least squares ended at a
    bound or its iteration limit);
    lm_maxiter: each Levenberg–Marquardt run's step limit (None: 200; raise it when a fit warns
    that its run stopped at the limit); start: {parameter: value} for one more
    Levenberg–Marquardt start, at these values and the model's defaults elsewhere (a basin the
    global search may miss: ``{"kappa1": 3000}`` starts a thin layer with a sharp coat; every
    start is in ``result.record["fits"][c]["starts"]``); sampler: the posterior sampler with
    ``mcmc`` (``fitlab.fitting.samplers.SAMPLERS``: ``emcee``, the default and reference, or
    ``nuts``, blackjax's NUTS with ``walkers`` chains); illuminant: for a spectral fit (channels
    that are wavelengths spanning 380-780 nm), the CIE illuminant of the colour block that
    reduces its colour parameters to CIE XYZ and linear sRGB (a colour-science name such as
    ``"D65"``, the default, ``"D50"``, ``"A"``; ``result.colour``; data_formats/fit_json.md);
    check_model: a layered model's check against the Monte Carlo simulation of its own fitted
    stack at the fitted directions, to a relative standard error of 2% (``"auto"``, the
    default: when its estimated cost is at most max(20% of the fit's time, 10 s), else the
    record says why it skipped it; ``"on"``; ``"off"``; the record
    ``result.record["fits"][c]["model_check"]``, fitlab.fitting.model_check).
    angles, accept, quantity: how a path is read (:func:`read`; not with a Measurement).
    Every fit is also checked for goodness of fit (``result.goodness()``; a failed check adds a
    warning). What limits trust in the fit is ``result.statuses(channel)`` (a
    :class:`fitlab.fitting.status.Status` each, with its advice); throw: raise a
    :class:`fitlab.errors.FitlabError` naming them instead of returning a fit that is not ``ok``.
    Raises :class:`fitlab.errors.FitlabError` with a message saying what to do."""
    from fitlab.export.paramfile import build_record, chains_payload, run_timings
    from fitlab.fitting.driver import fit_measurement
    from fitlab.fitting.request import as_request
    from fitlab.fitting.result import FitResult
    from fitlab.fitting.subset import rows_of
    from fitlab.io.gates import notes
    from fitlab.io.measurement import one_dataset

    request = as_request(model, settings)
    m = one_dataset(measurement_of(measurement, angles=angles, accept=accept,
                                   quantity=quantity))
    expr, _ = rows_of(request.subset, m)
    try:
        result = fit_measurement(m, request, warn=False)
    except ValueError as exc:  # every message names the file it is about
        text = str(exc)
        raise FitlabError(text if text.startswith(f"{m.path}:") else f"{m.path}: {text}") \
            from None
    result["notes"] = list(result["notes"]) + notes(m)
    record = build_record(result, m, subset_expr=expr, illuminant=request.illuminant)
    if request.walter_diagnostics:
        from fitlab.fitting.walter import add_empirical_D

        add_empirical_D(record, result, m)
    chains = chains_payload(result) if request.mcmc else {}
    seconds = {k: v for k, v in run_timings(result, 0.0, 0.0).items() if k not in ("read", "total")}
    out = FitResult.from_record(record, chains, None, m, seconds)
    if throw:
        out.raise_for_status()
    return out


__all__ = ["read", "fit", "measurement_of"]
