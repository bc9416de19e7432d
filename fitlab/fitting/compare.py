"""Model comparison: ``fitlab.compare`` (and ``fitlab compare``) fits every candidate model to one
measurement with :func:`fitlab.fit` and ranks them, per channel, by how well they predict data
they were not fitted to (data_formats/compare.md).

Leave-one-incidence-out cross-validation (CV). For each incidence direction (θi, φi) among the
fitted rows, the whole fitting procedure (global search and multi-start Levenberg–Marquardt, the
same loss, starts and seed) is repeated without that incidence's rows, and the refitted model
predicts them. Score: the RMS relative error (model − data)/data of the held-out rows, per
incidence and pooled over every held-out row (rows below 1% of their incidence's maximum are not
counted, as in the fit statistics). A fold keeps the data's shape: the rows it leaves out get a
zero residual through a row mask (``least_squares.ROW_MASK``), so one compilation serves every
fold of a model (brown vinyl, Lambert + GGX dielectric: 0.3-0.4 s a fold after one compile of
about 15-20 s, where a new shape per fold compiled for about 15 s each time; over five models
on the shared 2-core machine 1-11 s a fold).

PSIS-LOO and WAIC (ArviZ) from the MCMC posterior. The pointwise log-likelihood of a posterior
sample is the fit's own likelihood (fitlab/fitting/mcmc.py) row by row, written as a density of
the measured value: a Gaussian in the loss's residual r_i with the noise scale σ_r (sampled for
every loss but chi2, where it is 1),

    log p(v_i | θ, σ_r) = −½ (r_i/σ_r)² − log σ_r − ½ log 2π + log |∂r_i/∂v_i|

(the loss's per-row constants held fixed, as the fit holds them). Summed over the rows without
the last two terms it is the chain's stored log-posterior, which is checked for every sample.
ArviZ's relative efficiency comes from fitlab's own effective sample size (emcee's
autocorrelation time: the walkers of an ensemble are not independent chains).

How much better: for CV, Δ = held-out RMS of a model − that of the best, with a delete-one-
incidence jackknife standard error (incidences, not rows, are the independent units: the rows of
one incidence share its misfit), and Δ over the per-row noise scale (RMS σ/|value| where the
data give σ; otherwise the smallest in-sample RMS relative error among the candidates, which
includes that model's misfit: an upper bound of the noise). For PSIS-LOO and WAIC, ΔELPD and the
standard error of the pointwise differences (ArviZ ``compare``). A difference is called
decisive beyond :data:`DECISIVE_SE` standard errors (and, for ELPD, beyond :data:`SMALL_ELPD`).

>>> import fitlab
>>> r = fitlab.compare("data_formats/examples/walter_rough_glass.csv",
...                    ["rough_dielectric", "rough_dielectric --option distribution=beckmann "
...                     "--label beckmann"], mcmc=False, starts=2)
>>> r.winner(), r.ranking(by="cv")
('rough_dielectric', ('rough_dielectric', 'beckmann'))
>>> round(r.table()[1]["cv_rms_rel"], 2), r.record["channels"][0]["verdict"]["cv"]["decisive"]
(0.61, True)
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import re
import shlex
import sys
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.result import _freeze, thaw
from fitlab.fitting.status import Status


def relative_errors(pred, value):
    """(model − data)/data of the rows above the floor, and which rows those are (the fit
    statistics' rule, fitlab.fitting.driver; imported when used, so that ``import fitlab``
    does not load the fitting engine)."""
    from fitlab.fitting.channel import relative_errors as rel

    return rel(pred, value)

SCHEMA = "fitlab-compare"
SCHEMA_VERSION = 1
#: A difference is decisive beyond this many standard errors ...
DECISIVE_SE = 2.0
#: ... and, for an ELPD difference, beyond this many nats (below it the normal approximation of
#: its standard error is unreliable: Sivula, Magnusson and Vehtari 2020).
SMALL_ELPD = 4.0
#: Posterior samples per call of the log-likelihood kernel (one compile per model).
LOGLIK_CHUNK = 256
#: The files ``CompareResult.save`` writes into the output folder (the report adds index.html).
TABLE_JSON, TABLE_CSV, INCIDENCE_CSV, FITS_DIR = ("compare.json", "compare.csv",
                                                  "compare_incidences.csv", "fits")
CANDIDATE_FLAGS = ("--fix", "--option", "--free", "--start", "--label")


# --------------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------------


class Candidate(NamedTuple):
    """One model to compare: a registry name (sums and layered models too), parameters held
    fixed, model options, parameters to fit that the data file would fix, and the label of its
    row in the table (default: the model's name, or its whole spec where two candidates share a
    model)."""

    model: str
    fix: dict | None = None
    options: dict | None = None
    free: tuple = ()
    label: str | None = None
    start: dict | None = None


def parse_candidate(text: str) -> Candidate:
    """A candidate written as on the command line: ``NAME [--fix P=V]... [--option O=V]...
    [--free P]... [--start P=V]... [--label TEXT]`` (shell quoting), e.g. ``"coated(lambertian,specular=lobe)
    --option interreflection=closed_form --fix coat_eta=1.5"``."""
    from fitlab.assignments import parse_assignments

    where = f"--model {text!r}"
    try:
        tokens = shlex.split(text)
    except ValueError as exc:
        raise FitlabError(f"{where}: {exc}; quote the candidate as one argument, e.g. "
                          "--model 'coated(lambertian) --fix coat_eta=1.5'") from None
    k = next((i for i, t in enumerate(tokens) if t.startswith("--")), len(tokens))
    name = " ".join(tokens[:k])
    if not name:
        raise FitlabError(f"{where}: give a model name first (see `fitlab models`), then its "
                          f"{', '.join(CANDIDATE_FLAGS)}")
    got = {flag: [] for flag in CANDIDATE_FLAGS}
    rest = tokens[k:]
    i = 0
    while i < len(rest):
        flag, eq, value = rest[i].partition("=")
        if flag not in got:
            raise FitlabError(f"{where}: unexpected {rest[i]!r}; after the model name a "
                              f"candidate takes {', '.join(CANDIDATE_FLAGS)}")
        if not eq:
            if i + 1 >= len(rest) or rest[i + 1].startswith("--"):
                raise FitlabError(f"{where}: {flag} needs a value")
            value, i = rest[i + 1], i + 2
        else:
            i += 1
        got[flag].append(value)
    if len(got["--label"]) > 1:
        raise FitlabError(f"{where}: --label is given twice")
    fix = {}
    for pname, v in parse_assignments(got["--fix"], "fix").items():
        try:
            fix[pname] = float(v)
        except ValueError:
            raise FitlabError(f"{where}: --fix {pname}={v!r}: the value must be a number") \
                from None
    return Candidate(name, fix, parse_assignments(got["--option"], "option"),
                     tuple(got["--free"]), got["--label"][0] if got["--label"] else None,
                     parse_assignments(got["--start"], "start") or None)


class Resolved(NamedTuple):
    label: str
    spec: str  # the candidate as the command line writes it (its own settings)
    model: object  # fitlab.models.Model
    fix: dict  # its own fixed values and the global ones that apply to it
    options: dict  # resolved (defaults filled in)
    free: tuple
    start: dict  # its extra Levenberg–Marquardt start (fitlab.fit's ``start``)


def _spec(name, fix, options, free, start) -> str:
    parts = [name] + [f"--option {k}={v}" for k, v in options.items()]
    parts += [f"--fix {k}={v:g}" for k, v in fix.items()] + [f"--free {p}" for p in free]
    parts += [f"--start {k}={v:g}" for k, v in start.items()]
    return " ".join(parts)


def resolve_candidates(models, fix=None, options=None, free=()) -> list[Resolved]:
    """Every candidate checked before anything is fitted (model names, options, parameters and
    their values); ``fix``, ``options`` and ``free`` apply to each candidate that has that
    parameter or option (a candidate's own settings win), and each must apply to one at least."""
    from fitlab.models import get_model
    from fitlab.api import check_params, resolve_options
    from fitlab.fitting.api import parameter_values

    fix, options, free = dict(fix or {}), dict(options or {}), tuple(free or ())
    if isinstance(models, (str, Candidate)):
        models = [models]
    cands = []
    for item in models:
        if isinstance(item, str):
            item = parse_candidate(item) if "--" in item else Candidate(item)
        elif isinstance(item, dict):
            item = Candidate(**item)
        elif not isinstance(item, Candidate):
            raise FitlabError(f"models: {item!r} is not a model name or a Candidate")
        cands.append(item)
    if len(cands) < 2:
        raise FitlabError(f"give at least two models to compare (got {len(cands)}): repeat "
                          "--model, e.g. --model lambertian+rough_conductor --model "
                          "'weidlich_wilkie(lambertian)'")
    used_fix, used_opt, used_free = set(), set(), set()
    out = []
    for c in cands:
        where = f"--model {c.model!r}"
        try:
            mdl = get_model(c.model)
        except ValueError as exc:
            raise FitlabError(f"{where}: {exc} (see `fitlab models`)") from None
        names = mdl.parameter_names
        own_fix = {k: float(v) for k, v in (c.fix or {}).items()}
        own_opt = dict(c.options or {})
        opt_names = {o.name for o in mdl.options}
        glob_fix = {k: v for k, v in fix.items() if k in names}
        glob_opt = {k: v for k, v in options.items() if k in opt_names}
        glob_free = tuple(p for p in free if p in names)
        used_fix |= set(glob_fix)
        used_opt |= set(glob_opt)
        used_free |= set(glob_free)
        for k in own_fix:
            if k not in names:
                raise FitlabError(f"{where}: --fix {k}: model {mdl.name!r} has no parameter "
                                  f"{k!r} (its parameters: {', '.join(names)})")
        for k in c.free or ():
            if k not in names:
                raise FitlabError(f"{where}: --free {k}: model {mdl.name!r} has no parameter "
                                  f"{k!r} (its parameters: {', '.join(names)})")
        fixed = {**glob_fix, **own_fix}
        try:
            opts = resolve_options(mdl, {**glob_opt, **own_opt})
            check_params(mdl, {**{p.name: p.default for p in mdl.parameters}, **fixed})
        except ValueError as exc:
            raise FitlabError(f"{where}: {exc} (see `fitlab models`)") from None
        freed = tuple(dict.fromkeys(tuple(c.free or ()) + glob_free))
        try:
            start = parameter_values(mdl, c.start, "--start")
        except FitlabError as exc:
            raise FitlabError(f"{where}: {exc}") from None
        out.append(Resolved(c.label, _spec(mdl.name, own_fix, own_opt, tuple(c.free or ()),
                                           start), mdl, fixed, opts, freed, start))
    for what, given, used in (("--fix", fix, used_fix), ("--option", options, used_opt),
                              ("--free", free, used_free)):
        unused = [k for k in given if k not in used]
        if unused:
            raise FitlabError(f"{what} {', '.join(unused)}: no candidate model has "
                              f"{'an option' if what == '--option' else 'a parameter'} of that "
                              "name; check the spelling, or give it to one candidate inside its "
                              "--model '...'")
    counts = {}
    for r in out:
        counts[r.model.name] = counts.get(r.model.name, 0) + 1
    out = [r._replace(label=r.label or (r.model.name if counts[r.model.name] == 1 else r.spec))
           for r in out]
    labels = [r.label for r in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise FitlabError(f"--model: two candidates are both {dup[0]!r}; give each a different "
                          "setting or a --label")
    return out


# --------------------------------------------------------------------------------------------
# Incidences, relative errors, the jackknife
# --------------------------------------------------------------------------------------------


def incidence_keys(m) -> np.ndarray:
    """(θi, φi mod 360) of every row, degrees (the fit statistics' grouping)."""
    return np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)


def incidences_of(m, rows) -> list[tuple[float, float]]:
    keys = incidence_keys(m)[rows]
    return [(float(t), float(p)) for t, p in np.unique(keys, axis=0)] if keys.size else []


def _rel_err_floor() -> float:
    from fitlab.fitting.channel import REL_ERR_FLOOR

    return REL_ERR_FLOOR


def _rms(x) -> float | None:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else None


def jackknife_difference(sq_a, sq_b, counts) -> tuple[float, float]:
    """(Δ, its standard error) of Δ = RMS_a − RMS_b, where fold k holds ``counts[k]`` rows whose
    squared errors sum to ``sq_a[k]`` and ``sq_b[k]``: the delete-one-fold jackknife."""
    sq_a, sq_b, n = (np.asarray(x, float) for x in (sq_a, sq_b, counts))
    full = math.sqrt(sq_a.sum() / n.sum()) - math.sqrt(sq_b.sum() / n.sum())
    k = n.size
    if k < 2:
        return full, float("nan")
    rest = n.sum() - n
    ok = rest > 0
    d = np.sqrt((sq_a.sum() - sq_a[ok]) / rest[ok]) - np.sqrt((sq_b.sum() - sq_b[ok]) / rest[ok])
    se = math.sqrt((k - 1) / k * float(np.sum((d - d.mean()) ** 2)))
    return full, se


# --------------------------------------------------------------------------------------------
# Cross-validation
# --------------------------------------------------------------------------------------------


def _masked(data_all, data_kept, kept):
    """``data_all`` (every row of the fit) with the loss constants of a fit to the ``kept``
    rows, and the row mask that zeroes the others (their constants are a kept row's: finite)."""
    import jax

    from fitlab.fitting.least_squares import ROW_MASK

    consts = {}
    for key, v in data_kept.consts.items():
        v = np.asarray(v)
        full = np.empty(kept.shape + v.shape[1:], v.dtype)
        full[kept] = v
        full[~kept] = v[0]
        consts[key] = full
    consts[ROW_MASK] = kept.astype(np.float64)
    return jax.device_put(data_all._replace(consts=consts))


def aperture_order(result, channel_name):
    """The aperture quadrature order a fit used for a channel (data with an aperture), or None."""
    return (result._fit(channel_name).get("aperture") or {}).get("order")


def _predict(space, native, m, in_chan, order=None):
    """The model at every row of a channel, as the fit predicts them (fitlab.fitting.driver):
    at the rows' directions, or averaged over their apertures."""
    if order is None:
        return space.predict(native, m.wi[in_chan], m.wo[in_chan])
    from fitlab.fitting.aperture import predict_rows

    return predict_rows(space, native, m, in_chan, order)


def _channel_problem(m, base, rows, order):
    from fitlab.fitting.channel import channel_problem

    extra = {} if order is None else {"aperture_order": order}
    return channel_problem(m, base["model"], base["options"], base["fixed"], base["loss"],
                           base["start"], rows, m.channel_names[base["channel"]],
                           base["in_chan"], **extra)


def _problem(m, cand: Resolved, loss, rows, channel, order=None):
    """(model, options, fixed, loss, start, space, data) of a fit of ``rows`` of a channel,
    exactly as fitlab.fit builds it (``order``: its aperture quadrature order, if any)."""
    from fitlab.fitting.channel import resolve_fit

    mdl, options, fixed, _, loss, start = resolve_fit(m, cand.model.name, options=cand.options,
                                                      fixed=cand.fix, free=cand.free, loss=loss,
                                                      start=cand.start)
    base = {"model": mdl, "options": options, "fixed": fixed, "loss": loss, "start": start,
            "channel": channel, "in_chan": m.channel == channel, "order": order}
    space, data, start_native = _channel_problem(m, base, rows, order)
    return {**base, "space": space, "data": data, "start_native": start_native}


def cross_validate(m, cand: Resolved, loss, rows, channel, *, seed=0, starts=8, order=None,
                   on_fold=None):
    """Leave-one-incidence-out CV of one candidate on one channel's ``rows`` (bool, all rows of
    the measurement; ``order``: the fit's aperture quadrature order, if any). Returns one dict
    per incidence: theta_i, phi_i, rel (held-out relative errors of the counted rows),
    parameters (the fold's fit), warnings, error (a fold that could not be fitted)."""
    from fitlab.fitting.channel import least_squares_warnings
    from fitlab.fitting.least_squares import fit_least_squares

    base = _problem(m, cand, loss, rows, channel, order)
    in_chan = base["in_chan"]
    keys = incidence_keys(m)
    folds = []
    for ti, pi in incidences_of(m, rows):
        held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        kept = rows & ~held
        fold = {"theta_i": ti, "phi_i": pi, "rel": np.zeros(0), "parameters": None,
                "warnings": [], "error": None}
        try:
            space, data_k, start_native = _channel_problem(m, base, kept, order)
            data = _masked(base["data"], data_k, kept[rows])
            ls = fit_least_squares(space, data, base["loss"], start_native=start_native,
                                   n_starts=starts, seed=seed)
            if ls.solver["stopped"] == Status.NON_FINITE:
                raise ValueError("no start reached a finite cost")
            pred = _predict(space, ls.native, m, in_chan, order)[held[in_chan]]
            fold["rel"], _ = relative_errors(pred, m.value[held])
            fold["parameters"] = {n: float(v) for n, v in zip(space.names, ls.native)}
            fold["warnings"] = least_squares_warnings(ls)
        except (ValueError, FitlabError) as exc:
            fold["error"] = str(exc)
        folds.append(fold)
        if on_fold is not None:
            on_fold(fold)
    return folds


def in_sample_errors(m, cand: Resolved, result, loss, rows, channel):
    """Relative errors of the full fit at each incidence's counted rows (the CV's rule)."""
    name = m.channel_names[channel]
    order = aperture_order(result, name)
    base = _problem(m, cand, loss, rows, channel, order)
    space, in_chan = base["space"], base["in_chan"]
    params = result.parameters[name]
    pred = _predict(space, np.array([params[n] for n in space.names]), m, in_chan, order)
    keys = incidence_keys(m)
    out = []
    for ti, pi in incidences_of(m, rows):
        held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        out.append(relative_errors(pred[held[in_chan]], m.value[held])[0])
    return out


# --------------------------------------------------------------------------------------------
# Pointwise log-likelihood, PSIS-LOO and WAIC
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def _loglik_kernel(static, loss: str):
    """Jitted (samples (S, P), problem) → (pointwise log-likelihood (S, n), the chain's
    log-posterior recomputed (S,)). P: the unit-box coordinates, then log σ_r if sampled."""
    import jax
    import jax.numpy as jnp

    from fitlab.fitting.least_squares import residuals_native
    from fitlab.fitting.losses import has_absolute_noise
    from fitlab.fitting.space import to_native

    nuisance = not has_absolute_noise(loss)
    ndim = len(static.names)
    half_log_2pi = 0.5 * math.log(2.0 * math.pi)

    def one(x, problem):
        theta = to_native(static, x[:ndim], problem["lo"], problem["hi"])
        d = problem["data"]

        def r_of(v):  # the residual as a function of the measured values, constants held
            return residuals_native(static, loss, theta, {**problem, "data": d._replace(value=v)})

        r, dr_dv = jax.jvp(r_of, (d.value,), (jnp.ones_like(d.value),))  # elementwise loss
        log_s = x[ndim] if nuisance else jnp.zeros(())
        z = r * jnp.exp(-log_s)
        core = -0.5 * z * z - log_s
        return core - half_log_2pi + jnp.log(jnp.abs(dr_dv)), jnp.sum(core)

    return jax.jit(jax.vmap(one, in_axes=(0, None)))


def pointwise_log_likelihood(m, cand: Resolved, result, loss, rows, channel) -> dict:
    """The log-likelihood of every fitted row at every stored posterior sample of a fit made by
    ``fitlab.fit(..., mcmc=True)``: ``loglik`` (walkers, draws, rows), ``reff`` (effective over
    stored samples), ``samples``, ``informative`` (rows whose residual depends on the value:
    the others carry no likelihood and are left out)."""
    import jax

    from fitlab.fitting.least_squares import problem_of

    name = m.channel_names[channel]
    base = _problem(m, cand, loss, rows, channel, aperture_order(result, name))
    fit = result._fit(name)
    mc = fit.get("mcmc")
    chain = result.chains.get(f"chain_{name}")
    if not mc or chain is None:
        raise FitlabError(f"{cand.label}: channel {name} has no MCMC chain to compute PSIS-LOO "
                          "and WAIC from")
    lp_stored = np.asarray(result.chains[f"log_prob_{name}"])[mc["burn_in"]::mc["thin"]]
    x = np.asarray(chain)[mc["burn_in"]::mc["thin"]]  # (draws, walkers, P)
    draws, walkers, ncoord = x.shape
    flat = x.reshape(-1, ncoord)
    kernel = _loglik_kernel(base["space"].static, base["loss"])
    problem = problem_of(base["space"], base["data"])
    lls, lps = [], []
    for i in range(0, flat.shape[0], LOGLIK_CHUNK):
        part = flat[i:i + LOGLIK_CHUNK]
        pad = LOGLIK_CHUNK - part.shape[0]
        if pad:  # every call the same shape: one compile
            part = np.concatenate([part, np.repeat(part[:1], pad, axis=0)])
        ll, lp = jax.device_get(kernel(part, problem))
        lls.append(np.asarray(ll)[:LOGLIK_CHUNK - pad])
        lps.append(np.asarray(lp)[:LOGLIK_CHUNK - pad])
    ll, lp = np.concatenate(lls), np.concatenate(lps)
    want = lp_stored.reshape(-1)
    if not np.allclose(lp, want, rtol=1e-8, atol=1e-8 * max(1.0, float(np.max(np.abs(want))))):
        raise FitlabError(
            f"internal error: {cand.label}, channel {name}: the pointwise log-likelihood does not "
            f"sum to the chain's log-posterior (largest difference "
            f"{float(np.max(np.abs(lp - want))):.3g}); the fit's likelihood has changed without "
            "fitlab.fitting.compare; please report this")
    informative = np.all(np.isfinite(ll), axis=0)
    ess = float(mc.get("effective_sample_size") or 0.0)
    reff = min(1.0, ess / flat.shape[0]) if ess > 0 else 1.0
    ll = ll[:, informative]
    above = int(np.sum(np.var(ll, axis=0) > 0.4))  # ArviZ's WAIC criterion, per row
    ll = ll.reshape(draws, walkers, -1).transpose(1, 0, 2)
    return {"loglik": ll, "reff": reff, "samples": int(flat.shape[0]), "informative": informative,
            "rows_variance_above_0_4": above,
            "trustworthy": bool(mc.get("trustworthy")), "mcmc_warnings": list(mc.get("warnings")
                                                                              or [])}


def _arviz():
    try:
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore")  # ArviZ announces its refactor on import
            import arviz
    except ImportError:
        raise FitlabError("PSIS-LOO and WAIC need ArviZ, which is not installed: pip install "
                          "'fitlab[compare]' (or 'arviz>=0.23,<0.24'), or rank by "
                          "cross-validation alone with --no-mcmc (mcmc=False)") from None
    return arviz


def information_criteria(loglik, reff):
    """(PSIS-LOO, WAIC) ArviZ ELPDData (pointwise) of a (chains, draws, rows) log-likelihood."""
    az = _arviz()
    with _warnings.catch_warnings():
        # Their content is in warning / pareto_k, worded by compare; an emcee ensemble may have
        # more walkers (ArviZ's chains) than stored draws, which ArviZ warns about.
        _warnings.simplefilter("ignore")
        idata = az.from_dict(log_likelihood={"value": loglik})
        loo = az.loo(idata, pointwise=True, reff=reff)
        waic = az.waic(idata, pointwise=True)
    return loo, waic


WEIGHT_DECIMALS = 6


def _compare_ic(elpds: dict, ic: str) -> dict:
    """{label: {rank, elpd_diff, dse, weight}} from ArviZ's compare (stacking weights).

    The weights come from SciPy's SLSQP (tolerance 1e-6 on the log score) and are written to
    WEIGHT_DECIMALS places: their last binary digits follow BLAS's rounding, which depends on
    how the process's memory happens to be aligned, and would make the record differ between two
    runs of the same command."""
    az = _arviz()
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        table = az.compare(elpds, ic=ic, method="stacking")
    return {str(label): {"rank": int(row["rank"]) + 1, "elpd_diff": float(row["elpd_diff"]),
                         "dse": float(row["dse"]),
                         "weight": round(float(row["weight"]), WEIGHT_DECIMALS)}
            for label, row in table.iterrows()}


# --------------------------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------------------------


def _progress(enabled, total):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="compare", unit="fit", file=sys.stderr, dynamic_ncols=True,
                mininterval=0.5, bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} fits "
                "[{elapsed}<{remaining}] {postfix}")


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def compare(measurement, models, *, fix: dict | None = None, free=(), options: dict | None = None,
            loss: str | None = None, subset=None, channels=None, cv: bool = True,
            mcmc: bool = True, mcmc_steps: int = 3000, walkers: int | None = None,
            starts: int = 8, seed: int = 0, progress: bool = False) -> "CompareResult":
    """Fit each of ``models`` to ``measurement`` (a Measurement or a path) and rank them by
    leave-one-incidence-out cross-validation (``cv``) and by PSIS-LOO and WAIC from the MCMC
    posterior (``mcmc``, needs ArviZ); returns an immutable :class:`CompareResult`.

    models: model names, :class:`Candidate` objects, dicts of Candidate's fields, or strings
    written as on the command line (``"NAME --fix P=V --option O=V --free P --label TEXT"``).
    fix, options, free: apply to every candidate that has the parameter or option (a
    candidate's own settings win). loss, subset, channels, mcmc_steps, walkers, starts, seed:
    as in :func:`fitlab.fit` (one loss for all: the ELPDs of different losses are not the same
    likelihood). progress: a bar with the time left on stderr."""
    from fitlab.fitting.api import fit, read
    from fitlab.fitting.subset import subset_mask

    m = read(measurement) if not hasattr(measurement, "value") else measurement
    cands = resolve_candidates(models, fix, options, free)
    if not cv and not mcmc:
        raise FitlabError("nothing to rank by: keep cross-validation (cv=True, drop --no-cv) "
                          "or the posterior's PSIS-LOO and WAIC (mcmc=True, drop --no-mcmc)")
    if mcmc:
        _arviz()
        if mcmc_steps < 100:
            raise FitlabError("--mcmc-steps must be at least 100")
    from fitlab.fitting.losses import LOSSES

    if loss is not None and loss not in LOSSES:
        raise FitlabError(f"--loss {loss}: {LOSSES.unknown(loss)}")
    loss = loss or ("chi2" if m.sigma is not None else "relative")
    expr = subset if isinstance(subset, str) else None
    if isinstance(subset, str):
        rows_fit = subset_mask(subset, m)
    elif subset is not None:
        rows_fit = np.asarray(subset, dtype=bool)
        if rows_fit.shape != (m.n,):
            raise FitlabError(f"subset: a mask of {m.n} rows is needed, got {rows_fit.shape}")
    else:
        rows_fit = np.ones(m.n, dtype=bool)
    if channels is None:
        chan_ids = list(range(len(m.channel_names)))
    else:
        channels = [channels] if isinstance(channels, str) else list(channels)
        unknown = [c for c in channels if c not in m.channel_names]
        if unknown:
            raise FitlabError(f"--channel {', '.join(unknown)}: {m.path} has channels "
                              f"{', '.join(m.channel_names)}")
        chan_ids = [m.channel_names.index(c) for c in channels]
    chan_ids = [c for c in chan_ids if np.any(rows_fit & (m.channel == c))]
    if not chan_ids:
        raise FitlabError(f"{m.path}: no row is left to fit (check --fit-subset and --channel)")
    incs = {c: incidences_of(m, rows_fit & (m.channel == c)) for c in chan_ids}
    if cv:
        few = [m.channel_names[c] for c in chan_ids if len(incs[c]) < 2]
        if few:
            raise FitlabError(f"{m.path}: channel {few[0]} has one incidence direction among the "
                              "fitted rows: leave-one-incidence-out cross-validation needs two "
                              "or more; rank by PSIS-LOO and WAIC alone with --no-cv")
    total = len(cands) * (1 + sum((len(incs[c]) if cv else 0) + (1 if mcmc else 0)
                                  for c in chan_ids))
    bar = _progress(progress, total)
    say = (lambda s: (bar.write(s, file=sys.stderr) if bar is not None else None))
    fits, per = [], {c: [] for c in chan_ids}
    run_warnings = []
    try:
        for cand in cands:
            if bar is not None:
                bar.set_postfix_str(f"{cand.label}: fit" + (" + MCMC" if mcmc else ""))
            try:
                res = fit(m, cand.model, fix=cand.fix, free=cand.free, start=cand.start,
                          options=cand.options, loss=loss, subset=rows_fit,
                          channels=[m.channel_names[c] for c in chan_ids], mcmc=mcmc,
                          mcmc_steps=mcmc_steps, walkers=walkers, starts=starts,
                          seed=seed, progress=False,
                          # the fits' block bootstrap does not enter the ranking (the
                          # cross-validation is its misfit-aware measure): left out
                          bootstrap=0)
            except FitlabError as exc:
                raise FitlabError(f"--model {cand.label!r}: {exc}") from None
            res = res.with_record({**thaw(res.record),
                                   "data": {**thaw(res.record["data"]), "fit_subset": expr}})
            fits.append(res)
            if bar is not None:
                bar.update(1)
            for c in chan_ids:
                name = m.channel_names[c]
                rows = rows_fit & (m.channel == c)
                entry = {"in_sample": in_sample_errors(m, cand, res, loss, rows, c),
                         "folds": None, "ic": None, "fit": res._fit(name)}
                if cv:
                    def on_fold(fold, _label=cand.label):
                        if bar is not None:
                            bar.set_postfix_str(f"{_label}: CV without θi = "
                                                f"{fold['theta_i']:g}°")
                            bar.update(1)
                    entry["folds"] = cross_validate(m, cand, loss, rows, c, seed=seed,
                                                    starts=starts, on_fold=on_fold,
                                                    order=aperture_order(res, name))
                if mcmc:
                    if bar is not None:
                        bar.set_postfix_str(f"{cand.label}: PSIS-LOO, WAIC")
                    ll = pointwise_log_likelihood(m, cand, res, loss, rows, c)
                    loo, waic = information_criteria(ll["loglik"], ll["reff"])
                    entry["ic"] = {"loo": loo, "waic": waic, **{k: v for k, v in ll.items()
                                                               if k != "loglik"}}
                    del ll
                    if bar is not None:
                        bar.update(1)
                per[c].append(entry)
            say(f"compare: {cand.label} done")
    finally:
        if bar is not None:
            bar.close()
    record = _record(m, cands, fits, per, chan_ids, incs, rows_fit, expr, loss, cv, mcmc,
                     mcmc_steps, walkers, starts, seed, fix, options, free, run_warnings)
    return CompareResult.from_record(record, fits, m)


# --------------------------------------------------------------------------------------------
# The record (data_formats/compare.md)
# --------------------------------------------------------------------------------------------


def _fmt(x, digits=3):
    return "n/a" if x is None else f"{x:.{digits}g}"


def _cv_block(entries, labels, noise):
    """CV scores, ranks and differences to the best for one channel's candidates."""
    out = {}
    complete = {}
    for lab, e in zip(labels, entries):
        folds = e["folds"]
        failed = [f for f in folds if f["error"]]
        rel = np.concatenate([f["rel"] for f in folds]) if folds else np.zeros(0)
        out[lab] = {
            "rms_relative_error": None if failed else _rms(rel),
            "per_incidence": [_rms(f["rel"]) for f in folds],
            "failed_folds": [{"theta_i": f["theta_i"], "phi_i": f["phi_i"], "error": f["error"]}
                             for f in failed],
            "fold_parameters": [f["parameters"] for f in folds],
            "fold_warnings": sorted({w for f in folds for w in f["warnings"]}),
        }
        if not failed and rel.size:
            complete[lab] = (np.array([np.sum(f["rel"] ** 2) for f in folds]),
                             np.array([f["rel"].size for f in folds]))
    order = sorted(complete, key=lambda lab: (out[lab]["rms_relative_error"], labels.index(lab)))
    order += [lab for lab in labels if lab not in complete]
    best = order[0] if order and order[0] in complete else None
    for rank, lab in enumerate(order, start=1):
        block = out[lab]
        block["rank"] = rank
        if lab in complete and best is not None:
            d, se = jackknife_difference(complete[lab][0], complete[best][0], complete[lab][1])
            block["delta"] = d
            block["delta_se"] = _num(se)
            block["delta_over_noise"] = _num(d / noise) if noise else None
        else:
            block["delta"] = block["delta_se"] = block["delta_over_noise"] = None
    return out, order


def _pareto_summary(loo, informative_rows, keys) -> dict:
    k = np.asarray(loo["pareto_k"].values, float)
    good_k = float(loo["good_k"])
    bad = k > good_k
    where = {}
    for (ti, pi) in keys[informative_rows][bad]:
        where[(float(ti), float(pi))] = where.get((float(ti), float(pi)), 0) + 1
    worst = sorted(where.items(), key=lambda kv: (-kv[1], kv[0]))[:5]
    return {"good_k": good_k, "good": int(np.sum(~bad)),
            "bad": int(np.sum(bad & (k <= 1.0))), "very_bad": int(np.sum(k > 1.0)),
            "max": _num(np.max(k)) if k.size else None,
            "worst_incidences": [{"theta_i": t, "phi_i": p, "rows": n} for (t, p), n in worst]}


def _ic_block(entries, labels, m, rows, kind):
    elpds = {lab: e["ic"][kind] for lab, e in zip(labels, entries)}
    ranks = _compare_ic(elpds, kind)
    keys = incidence_keys(m)[rows]
    out = {}
    for lab, e in zip(labels, entries):
        d = e["ic"][kind]
        block = {"elpd": float(d[f"elpd_{kind}"]), "se": float(d["se"]), "p": float(d[f"p_{kind}"]),
                 **ranks[lab], "warning": bool(d["warning"])}
        inf = e["ic"]["informative"]
        block["rows"] = int(inf.sum())
        block["trustworthy"] = e["ic"]["trustworthy"]
        if kind == "loo":
            block["pareto_k"] = _pareto_summary(d, inf, keys)
            k = np.asarray(d["pareto_k"].values, float)
            block["pareto_k_per_incidence"] = [
                _num(np.max(k[sel])) if sel.any() else None
                for sel in ((keys[inf][:, 0] == t) & (keys[inf][:, 1] == p)
                            for t, p in incidences_of(m, rows))]
        else:  # ArviZ's criterion: the posterior variance of log p above 0.4 at a row
            block["rows_variance_above_0_4"] = e["ic"]["rows_variance_above_0_4"]
        block["elpd_per_row"] = block["elpd"] / max(block["rows"], 1)
        out[lab] = block
    order = sorted(labels, key=lambda lab: out[lab]["rank"])
    return out, order


def _verdict_cv(cv, order, noise, noise_source):
    best = order[0]
    b = cv[best]
    if b["rms_relative_error"] is None:
        return {"winner": None, "text": "Cross-validation: no candidate completed every fold."}
    text = (f"{best} wins by leave-one-incidence-out cross-validation: held-out RMS relative "
            f"error {b['rms_relative_error']:.4f}")
    v = {"winner": best, "runner_up": None, "delta": None, "delta_se": None,
         "standard_errors": None, "delta_over_noise": None, "decisive": None}
    if len(order) > 1 and cv[order[1]]["rms_relative_error"] is not None:
        second = order[1]
        s = cv[second]
        z = s["delta"] / s["delta_se"] if s["delta_se"] else None
        decisive = bool(z is not None and z > DECISIVE_SE)
        v.update(runner_up=second, delta=s["delta"], delta_se=s["delta_se"],
                 standard_errors=_num(z), delta_over_noise=s["delta_over_noise"],
                 decisive=decisive)
        text += (f" against {s['rms_relative_error']:.4f} for {second}: Δ = {s['delta']:.4f} ± "
                 f"{_fmt(s['delta_se'], 2)} (jackknife over incidences"
                 + (f", {z:.1f} standard errors" if z is not None else "") + ")"
                 + (f", {s['delta_over_noise']:.2f} × the per-row noise scale {noise:.3g}"
                    if s["delta_over_noise"] is not None else "")
                 + (". Decisive." if decisive else
                    f". Not decisive (within {DECISIVE_SE:g} standard errors)."))
    else:
        text += "."
    v["text"] = text
    return v


def _verdict_ic(block, order, kind):
    name = {"loo": "PSIS-LOO", "waic": "WAIC"}[kind]
    best = order[0]
    b = block[best]
    v = {"winner": best, "runner_up": None, "elpd_diff": None, "dse": None,
         "standard_errors": None, "decisive": None}
    text = f"{best} wins by {name}: ELPD {b['elpd']:.1f} ± {b['se']:.1f}"
    if len(order) > 1:
        second = order[1]
        s = block[second]
        z = s["elpd_diff"] / s["dse"] if s["dse"] > 0 else None
        decisive = bool(s["elpd_diff"] > SMALL_ELPD and z is not None and z > DECISIVE_SE)
        v.update(runner_up=second, elpd_diff=s["elpd_diff"], dse=s["dse"],
                 standard_errors=_num(z), decisive=decisive)
        text += (f", ΔELPD = {s['elpd_diff']:.1f} ± {s['dse']:.1f} over {second}"
                 + (f" ({z:.1f} standard errors, {s['elpd_diff'] / max(b['rows'], 1):.3g} per "
                    "row)" if z is not None else "")
                 + (". Decisive." if decisive else
                    f". Not decisive (ΔELPD within {SMALL_ELPD:g} or {DECISIVE_SE:g} standard "
                    "errors)."))
    else:
        text += "."
    short = [lab for lab in order if not block[lab]["trustworthy"]]
    if short:
        text += (f" The MCMC chain of {', '.join(short)} is too short to trust (see the "
                 "warnings): rerun with more --mcmc-steps.")
    if any(block[lab]["warning"] for lab in order):
        text += (" Some of these estimates are flagged unreliable (see the warnings)."
                 if kind == "loo" else " ArviZ flags WAIC as possibly failing (see the "
                 "warnings); prefer PSIS-LOO.")
    v["text"] = text
    return v


def _record(m, cands, fits, per, chan_ids, incs, rows_fit, expr, loss, cv, mcmc, mcmc_steps,
            walkers, starts, seed, fix, options, free, run_warnings) -> dict:
    from fitlab.export.paramfile import software_versions

    labels = [c.label for c in cands]
    warnings = list(run_warnings)
    pareto_flagged = False
    channels = []
    for c in chan_ids:
        name = m.channel_names[c]
        rows = rows_fit & (m.channel == c)
        entries = per[c]
        keys = incidence_keys(m)
        counted = []
        for ti, pi in incs[c]:
            held = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
            counted.append(relative_errors(m.value[held], m.value[held])[1])
        in_sample = {lab: _rms(np.concatenate(e["in_sample"])) for lab, e in zip(labels, entries)}
        if m.sigma is not None:
            sig = np.concatenate([m.sigma[rows & (keys[:, 0] == t) & (keys[:, 1] == p)][k]
                                  / np.abs(m.value[rows & (keys[:, 0] == t) & (keys[:, 1] == p)]
                                           [k]) for (t, p), k in zip(incs[c], counted)])
            noise, source = _rms(sig), "RMS of sigma/|value| over the counted rows"
        else:
            best_in = min((v for v in in_sample.values() if v is not None), default=None)
            noise = best_in
            source = ("no sigma in the data: the smallest in-sample RMS relative error of the "
                      "candidates, an upper bound of the noise")
        models = []
        for cand, e in zip(cands, entries):
            fit = e["fit"]
            free_names = [k for k, p in fit["parameters"].items() if not p["fixed"]]
            models.append({
                "label": cand.label,
                "n_free": len(free_names),
                "free_parameters": free_names,
                "parameters": {k: p["value"] for k, p in fit["parameters"].items()},
                "stderr": {k: p.get("stderr") for k, p in fit["parameters"].items()
                           if not p["fixed"]},
                "in_sample": {"rms_relative_error": in_sample[cand.label],
                              "per_incidence": [_rms(x) for x in e["in_sample"]]},
                "fit_warnings": list(fit.get("warnings") or []),
            })
        ch = {"channel": name, "rows_fitted": int(rows.sum()),
              "noise_scale": {"relative": noise, "source": source},
              "incidences": [{"theta_i": t, "phi_i": p,
                              "rows": int(np.sum(rows & (keys[:, 0] == t) & (keys[:, 1] == p))),
                              "rows_counted": int(k.sum())}
                             for (t, p), k in zip(incs[c], counted)],
              "models": models, "ranking": {}, "verdict": {}}
        if cv:
            block, order = _cv_block(entries, labels, noise)
            for mod in models:
                mod["cv"] = block[mod["label"]]
                for f in block[mod["label"]]["failed_folds"]:
                    warnings.append(f"channel {name}: {mod['label']}: the cross-validation "
                                    f"fold without θi = {f['theta_i']:g}°, φi = "
                                    f"{f['phi_i']:g}° could not be fitted ({f['error']}); this "
                                    "model is ranked last by CV")
            ch["ranking"]["cv"] = order
            ch["verdict"]["cv"] = _verdict_cv(block, order, noise, source)
        if mcmc:
            for kind in ("loo", "waic"):
                block, order = _ic_block(entries, labels, m, rows, kind)
                for mod in models:
                    mod[kind] = block[mod["label"]]
                ch["ranking"][kind] = order
                ch["verdict"][kind] = _verdict_ic(block, order, kind)
            for mod, e in zip(models, entries):
                ic = e["ic"]
                mod["mcmc"] = {"samples": ic["samples"], "relative_efficiency": ic["reff"],
                               "trustworthy": ic["trustworthy"], "warnings": ic["mcmc_warnings"]}
                loo = mod["loo"]
                pk = loo["pareto_k"]
                if pk["bad"] + pk["very_bad"]:
                    at = ", ".join(f"θi = {w['theta_i']:g}° ({w['rows']})"
                                   for w in pk["worst_incidences"])
                    warnings.append(
                        f"channel {name}: {mod['label']}: PSIS-LOO is unreliable at "
                        f"{pk['bad'] + pk['very_bad']} of {loo['rows']} rows (Pareto k > "
                        f"{pk['good_k']:.2f}, up to {pk['max']:.2f}; most at {at})")
                    pareto_flagged = True
                if mod["waic"]["warning"]:
                    warnings.append(f"channel {name}: {mod['label']}: WAIC may be failing (the "
                                    "posterior variance of the log predictive density exceeds "
                                    f"0.4 at {mod['waic']['rows_variance_above_0_4']} of "
                                    f"{mod['waic']['rows']} rows, ArviZ's criterion): prefer "
                                    "PSIS-LOO")
        for mod in models:  # the full sentences are in the candidates' fit warnings
            heads = [re.split(r" \(|: ", w, maxsplit=1)[0].rstrip(".")
                     for w in mod["fit_warnings"]]
            if heads:
                warnings.append(f"channel {name}: {mod['label']}: its fit warns: "
                                + "; ".join(dict.fromkeys(heads))
                                + " (in full with the candidates' fits)")
        ch["verdict"]["text"] = " ".join(ch["verdict"][k]["text"] for k in ("cv", "loo")
                                         if k in ch["verdict"])
        if cv and mcmc:
            a, b = ch["verdict"]["cv"]["winner"], ch["verdict"]["loo"]["winner"]
            ch["verdict"]["agree"] = a == b
            if a != b:
                ch["verdict"]["text"] += (
                    " The two measures disagree: PSIS-LOO scores single rows under the fit's "
                    "noise model (independent residuals of one scale), the cross-validation "
                    "whole incidences the model was not fitted to; where the residuals are "
                    "structured by incidence (see the goodness warnings) the cross-validation is "
                    "the more honest measure of how a model predicts a new incidence angle.")
        channels.append(ch)
    software = software_versions()
    if mcmc:
        software["arviz"] = _arviz().__version__
    if pareto_flagged:
        warnings.append("Rows with Pareto k above the threshold: leaving one of them out moves the "
                        "posterior more than importance sampling can follow, so the ELPD of "
                        "that model is uncertain beyond its standard error; trust the "
                        "cross-validation for it, or use a model that describes those rows")
    fixed_rec = []
    for cand, res in zip(cands, fits):
        fixed = {}
        for f in res.record["fits"]:
            fixed.update({k: p["value"] for k, p in f["parameters"].items() if p["fixed"]})
        fixed_rec.append(fixed)
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "data": {"path": m.path, "sha256": m.sha256, "rows": m.n,
                 "rows_fitted": int(rows_fit.sum()), "fit_subset": expr,
                 "quantity": m.quantity, "channels": [m.channel_names[c] for c in chan_ids],
                 "sample": m.metadata.get("sample")},
        "settings": {"loss": loss, "seed": seed, "starts": starts,
                     "cross_validation": "leave-one-incidence-out" if cv else None,
                     "mcmc": {"steps": mcmc_steps, "walkers": walkers} if mcmc else None,
                     "relative_error_floor": _rel_err_floor(), "decisive_standard_errors":
                     DECISIVE_SE, "small_elpd": SMALL_ELPD,
                     "fix": dict(fix or {}), "options": dict(options or {}),
                     "free": list(free or ())},
        "candidates": [{"label": c.label, "spec": c.spec, "model": c.model.name,
                        "options": dict(c.options), "fixed": fx,
                        "free_parameters": list(res.record["fits"][0]["covariance"]
                                                ["parameters"]),
                        "parameter_file": None}
                       for c, res, fx in zip(cands, fits, fixed_rec)],
        "channels": channels,
        "warnings": warnings,
        "software": software,
    }


# --------------------------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------------------------


SUMMARY_COLUMNS = (
    "channel", "label", "model", "n_free", "in_sample_rms_rel", "cv_rank", "cv_rms_rel",
    "cv_delta", "cv_delta_se", "cv_delta_over_noise", "loo_rank", "elpd_loo", "elpd_loo_se",
    "p_loo", "loo_elpd_diff", "loo_dse", "loo_weight", "pareto_k_max", "pareto_k_bad_rows",
    "waic_rank", "elpd_waic", "elpd_waic_se", "p_waic", "waic_elpd_diff", "waic_dse",
    "waic_weight")
INCIDENCE_COLUMNS = ("channel", "label", "theta_i", "phi_i", "rows", "rows_counted",
                     "in_sample_rms_rel", "cv_rms_rel", "pareto_k_max")


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _csv(columns, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_cell(row.get(c)) for c in columns])
    return buf.getvalue()


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:60] or "model"


@dataclass(frozen=True)
class CompareResult:
    """A comparison: ``record`` (what compare.json holds, read-only), the candidates' fits
    (:class:`FitResult`, in the candidates' order) and the measurement."""

    record: MappingProxyType
    fits: tuple = ()
    measurement: object = None
    path: str | None = field(default=None)

    @classmethod
    def from_record(cls, record, fits=(), measurement=None, path=None):
        return cls(_freeze(thaw(record)), tuple(fits), measurement, path)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(c["label"] for c in self.record["candidates"])

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(ch["channel"] for ch in self.record["channels"])

    def _channel(self, channel):
        chs = self.record["channels"]
        if channel is None:
            if len(chs) != 1:
                raise ValueError(f"this comparison has channels {', '.join(self.channels)}: "
                                 "name one")
            return chs[0]
        for ch in chs:
            if ch["channel"] == channel:
                return ch
        raise ValueError(f"no channel {channel!r}; channels: {', '.join(self.channels)}")

    def ranking(self, channel=None, by: str | None = None) -> tuple[str, ...]:
        """Labels best first by ``cv``, ``loo`` or ``waic`` (default: cv where it ran)."""
        rk = self._channel(channel)["ranking"]
        by = by or ("cv" if "cv" in rk else "loo")
        if by not in rk:
            raise ValueError(f"no ranking by {by!r} (this comparison has {', '.join(rk)})")
        return tuple(rk[by])

    def winner(self, channel=None, by: str | None = None) -> str:
        return self.ranking(channel, by)[0]

    def fit(self, label) -> "object":
        """The :class:`FitResult` of a candidate."""
        return self.fits[self.labels.index(label)]

    def verdict(self, channel=None) -> str:
        return self._channel(channel)["verdict"]["text"]

    @property
    def warnings(self) -> tuple[str, ...]:
        return tuple(self.record["warnings"])

    # ---- tables -----------------------------------------------------------------------

    def table(self) -> list[dict]:
        """One row per channel and candidate (the columns of compare.csv), each channel's rows
        best first (by CV where it ran, else PSIS-LOO)."""
        cands = {c["label"]: c for c in self.record["candidates"]}
        out = []
        for ch in self.record["channels"]:
            mods = {mod["label"]: mod for mod in ch["models"]}
            for lab in self.ranking(ch["channel"]):
                mod = mods[lab]
                row = {"channel": ch["channel"], "label": lab, "model": cands[lab]["model"],
                       "n_free": mod["n_free"],
                       "in_sample_rms_rel": mod["in_sample"]["rms_relative_error"]}
                cv = mod.get("cv")
                if cv:
                    row.update(cv_rank=cv["rank"], cv_rms_rel=cv["rms_relative_error"],
                               cv_delta=cv["delta"], cv_delta_se=cv["delta_se"],
                               cv_delta_over_noise=cv["delta_over_noise"])
                for kind in ("loo", "waic"):
                    b = mod.get(kind)
                    if b:
                        row.update({f"{kind}_rank": b["rank"], f"elpd_{kind}": b["elpd"],
                                    f"elpd_{kind}_se": b["se"], f"p_{kind}": b["p"],
                                    f"{kind}_elpd_diff": b["elpd_diff"], f"{kind}_dse": b["dse"],
                                    f"{kind}_weight": b["weight"]})
                if mod.get("loo"):
                    pk = mod["loo"]["pareto_k"]
                    row.update(pareto_k_max=pk["max"], pareto_k_bad_rows=pk["bad"]
                               + pk["very_bad"])
                out.append(row)
        return out

    def incidence_table(self) -> list[dict]:
        """One row per channel, candidate and incidence (compare_incidences.csv)."""
        out = []
        for ch in self.record["channels"]:
            for mod in ch["models"]:
                for k, inc in enumerate(ch["incidences"]):
                    row = {"channel": ch["channel"], "label": mod["label"], **inc,
                           "in_sample_rms_rel": mod["in_sample"]["per_incidence"][k]}
                    if mod.get("cv"):
                        row["cv_rms_rel"] = mod["cv"]["per_incidence"][k]
                    if mod.get("loo"):
                        row["pareto_k_max"] = mod["loo"]["pareto_k_per_incidence"][k]
                    out.append(row)
        return out

    def to_json(self) -> str:
        return json.dumps(thaw(self.record), indent=2, allow_nan=False, ensure_ascii=False) + "\n"

    def to_csv(self) -> str:
        return _csv(SUMMARY_COLUMNS, self.table())

    def incidences_csv(self) -> str:
        return _csv(INCIDENCE_COLUMNS, self.incidence_table())

    def summary(self) -> str:
        """What ``fitlab compare`` prints: per channel the ranking table and the verdict, then
        the warnings."""
        lines = []
        for ch in self.record["channels"]:
            noise = ch["noise_scale"]["relative"]
            lines.append(f"channel {ch['channel']}: {ch['rows_fitted']} rows fitted, "
                         f"{len(ch['incidences'])} incidences; per-row noise scale "
                         f"{_fmt(noise)} ({ch['noise_scale']['source']})")
            head = f"  {'model':<34} {'free':>4} {'in-sample':>9}"
            has_cv = "cv" in ch["ranking"]
            has_ic = "loo" in ch["ranking"]
            if has_cv:
                head += f" {'CV rank':>7} {'held-out':>8} {'ΔCV ± SE':>17}"
            if has_ic:
                head += (f" {'LOO rank':>8} {'ELPD_loo ± SE':>18} {'ΔELPD ± SE':>16} "
                         f"{'k>good':>6}")
            lines.append(head)
            mods = {mod["label"]: mod for mod in ch["models"]}
            for lab in self.ranking(ch["channel"]):
                mod = mods[lab]
                line = (f"  {lab[:34]:<34} {mod['n_free']:>4} "
                        f"{_fmt(mod['in_sample']['rms_relative_error'], 4):>9}")
                if has_cv:
                    cv = mod["cv"]
                    d = ("best" if cv["rank"] == 1 else
                         f"{_fmt(cv['delta'], 3)} ± {_fmt(cv['delta_se'], 2)}")
                    line += (f" {cv['rank']:>7} {_fmt(cv['rms_relative_error'], 4):>8} "
                             f"{d:>17}")
                if has_ic:
                    lo = mod["loo"]
                    d = "best" if lo["rank"] == 1 else f"{lo['elpd_diff']:.1f} ± {lo['dse']:.1f}"
                    pk = lo["pareto_k"]
                    line += (f" {lo['rank']:>8} {lo['elpd']:>10.1f} ± {lo['se']:<5.1f} {d:>16} "
                             f"{pk['bad'] + pk['very_bad']:>6}")
                lines.append(line)
            for key in ("cv", "loo", "waic"):
                if key in ch["verdict"]:
                    lines.append("  " + ch["verdict"][key]["text"])
            if ch["verdict"].get("agree") is False:
                lines.append("  CV and PSIS-LOO pick different winners (see compare.md, "
                             "'When the measures disagree').")
        for w in self.record["warnings"]:
            lines.append(f"warning: {w}")
        return "\n".join(lines) + "\n"

    # ---- files ------------------------------------------------------------------------

    def save(self, out_dir, *, fits: bool = True) -> "CompareResult":
        """Write compare.json, compare.csv, compare_incidences.csv and (``fits``) each
        candidate's parameter file under fits/ into ``out_dir``, atomically; paths inside are
        relative to ``out_dir``. Returns the result with ``parameter_file`` entries set."""
        from fitlab.io.atomic import atomic_write_text
        from fitlab.io.files import path_for_record

        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise FitlabError(f"--out {out}: is a file, not a folder; give a folder")
        out.mkdir(parents=True, exist_ok=True)
        record = thaw(self.record)
        if fits and self.fits:
            (out / FITS_DIR).mkdir(exist_ok=True)
            for k, (cand, res) in enumerate(zip(record["candidates"], self.fits), start=1):
                rel = f"{FITS_DIR}/{k}_{_slug(cand['label'])}.json"
                res.save(out / rel)
                cand["parameter_file"] = rel
        if record["data"].get("path"):
            record["data"]["path"] = path_for_record(record["data"]["path"], out / TABLE_JSON)
        result = CompareResult.from_record(record, self.fits, self.measurement, str(out))
        atomic_write_text(out / TABLE_CSV, result.to_csv())
        atomic_write_text(out / INCIDENCE_CSV, result.incidences_csv())
        atomic_write_text(out / TABLE_JSON, result.to_json())
        return result

    def __repr__(self):
        return (f"CompareResult({', '.join(self.labels)}; winner "
                + ", ".join(f"{ch}: {self.winner(ch)}" for ch in self.channels) + ")")


def load_compare(path) -> CompareResult:
    """A comparison read back from its compare.json (data_formats/compare.md), without the
    candidates' fits (``fits`` is empty): its tables, summary and report page are the same."""
    from fitlab.errors import InputFileError
    from fitlab.io.files import read_bytes
    from fitlab.io.validate import load_json

    hint = "give a compare.json written by `fitlab compare --out DIR`"
    rec = load_json(path, read_bytes(path), what="fitlab comparison", hint=hint)
    if not isinstance(rec, dict) or rec.get("schema") != SCHEMA:
        raise InputFileError(path, f"is not a fitlab comparison (no \"schema\": \"{SCHEMA}\")",
                             hint=hint)
    if rec.get("schema_version") != SCHEMA_VERSION:
        raise InputFileError(path, f"has schema_version {rec.get('schema_version')!r}; this "
                             f"fitlab reads {SCHEMA_VERSION}", hint="rerun fitlab compare")
    for key, kind in (("data", dict), ("settings", dict), ("candidates", list),
                      ("channels", list), ("warnings", list), ("software", dict)):
        if not isinstance(rec.get(key), kind):
            what = "an object" if kind is dict else "a list"
            raise InputFileError(path, f"field {key!r} is missing or not {what}", hint=hint)
    return CompareResult.from_record(rec, (), None, str(Path(path).parent))


__all__ = ["Candidate", "CompareResult", "compare", "load_compare", "parse_candidate",
           "resolve_candidates",
           "cross_validate", "pointwise_log_likelihood", "information_criteria",
           "jackknife_difference"]
