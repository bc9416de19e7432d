"""Model comparison: ``fitlab.compare`` (and ``fitlab compare``) fits every candidate model to one
measurement with :func:`fitlab.fit` and ranks them, per channel, by how well they predict data
they were not fitted to (data_formats/compare.md).

Leave-one-incidence-out cross-validation (CV). For each incidence direction (θi, φi) among the
fitted rows, the model is refitted without that incidence's rows (the same loss, each kept
row's loss constant that of a fit to the kept rows) by Levenberg–Marquardt from the full fit's
optimum, every fold a lane of the full fit's compiled, batched stage
(``crossval.batched_folds``), and the refitted model predicts them. Score: the RMS relative error (model − data)/data of the held-out rows, per
incidence and pooled over every held-out row (rows below 1% of their incidence's maximum are not
counted, as in the fit statistics). A fold keeps the data's shape: the rows it leaves out get a
zero residual through a row mask (``least_squares.ROW_MASK``), so the full fit's compilation
serves every fold of a model. A fold used to repeat the global search as well (1-11 s a fold on
brown vinyl on the shared 2-core machine, most of a comparison's time:
benchmarks/bench_first_hour.py).

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

import sys

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.compare.candidates import Candidate, parse_candidate, resolve_candidates
from fitlab.fitting.compare.common import SCHEMA, SCHEMA_VERSION
from fitlab.fitting.compare.criteria import _arviz, information_criteria, pointwise_log_likelihood
from fitlab.fitting.compare.crossval import (aperture_order, cross_validate, incidences_of,
                                             jackknife_difference)
from fitlab.fitting.compare.record import DECISIVE_SE, SMALL_ELPD, _record
from fitlab.fitting.compare.result import (INCIDENCE_COLUMNS, SUMMARY_COLUMNS, CompareResult,
                                           load_compare)
from fitlab.fitting.result import thaw


# --------------------------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------------------------


class _Progress:
    """A tqdm bar on stderr whose time left is estimated from measured step times: each kind of
    step (a full fit, a cross-validation fold, PSIS-LOO and WAIC) counts at the mean of the
    steps of that kind measured so far (tqdm's own estimate would average a fold that takes a
    tenth of a second with a full fit that takes tens); before a kind has been measured the
    estimate says so instead of guessing."""

    def __init__(self, total: dict):
        import time

        from tqdm import tqdm

        self.clock = time.perf_counter
        self.left = dict(total)
        self.spent = {k: [0.0, 0] for k in total}
        self.t = self.clock()
        self.what = ""
        self.bar = tqdm(total=sum(total.values()), desc="compare", unit="step",
                        file=sys.stderr, dynamic_ncols=True, mininterval=0.5,
                        bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} steps [{elapsed}] "
                        "{postfix}")

    def doing(self, what: str):
        self.what = what
        self.bar.set_postfix_str(f"{what}; {self.eta()}", refresh=False)
        self.bar.refresh()

    def eta(self) -> str:
        todo = {k: n for k, n in self.left.items() if n}
        if not todo:
            return "finishing"
        if any(self.spent[k][1] == 0 for k in todo):
            return "time left: measuring the first " + ", ".join(
                k for k in todo if self.spent[k][1] == 0)
        s = sum(n * self.spent[k][0] / self.spent[k][1] for k, n in todo.items())
        return f"about {s:.0f} s left (measured step times)"

    def step(self, kind: str):
        now = self.clock()
        self.spent[kind][0] += now - self.t
        self.spent[kind][1] += 1
        self.left[kind] -= 1
        self.t = now
        self.bar.update(1)
        self.doing(self.what)

    def write(self, text: str):
        self.bar.write(text, file=sys.stderr)

    def close(self):
        self.bar.close()


def compare(measurement, models, *, fix: dict | None = None, free=(), options: dict | None = None,
            loss: str | None = None, subset=None, channels=None, cv: bool = True,
            mcmc: bool = True, mcmc_steps: int = 3000, walkers: int | None = None,
            starts: int = 8, seed: int = 0, global_search: str = "scan",
            local_solver: str = "fitlab", progress: bool = False, throw: bool = False, angles: str | None = None, accept=(),
            quantity: str | None = None) -> "CompareResult":
    """Fit each of ``models`` to ``measurement`` (a Measurement or a path) and rank them by
    leave-one-incidence-out cross-validation (``cv``) and by PSIS-LOO and WAIC from the MCMC
    posterior (``mcmc``, needs ArviZ); returns an immutable :class:`CompareResult`.

    models: model names, :class:`Candidate` objects, dicts of Candidate's fields, or strings
    written as on the command line (``"NAME --fix P=V --option O=V --free P --label TEXT"``).
    fix, options, free: apply to every candidate that has the parameter or option (a
    candidate's own settings win). loss, subset, channels, mcmc_steps, walkers, starts, seed,
    global_search, local_solver: as in :func:`fitlab.fit` (one loss for all: the ELPDs of different losses are not the same
    likelihood). progress: a bar with the time left on stderr. What limits trust in the ranking is
    ``result.statuses(label, channel)`` and ``result.ok``; throw: raise a FitlabError naming it
    instead of returning a comparison that is not ``ok``. angles, accept, quantity: how a path
    is read (:func:`fitlab.read`; not with a Measurement)."""
    from fitlab.fitting.api import fit, measurement_of
    from fitlab.fitting.subset import channel_ids, rows_of

    m = measurement_of(measurement, angles=angles, accept=accept, quantity=quantity)
    if not cv and not mcmc:
        raise FitlabError("nothing to rank by: keep cross-validation (cv=True, drop --no-cv) "
                          "or the posterior's PSIS-LOO and WAIC (mcmc=True, drop --no-mcmc)")
    if mcmc:
        _arviz()
    expr, rows_fit = rows_of(subset, m)
    chan_ids = channel_ids(channels, m, "--channel")
    chan_ids = list(range(len(m.channel_names))) if chan_ids is None else chan_ids
    chan_ids = [c for c in chan_ids if np.any(rows_fit & (m.channel == c))]
    if not chan_ids:
        raise FitlabError(f"{m.path}: no row is left to fit (check --fit-subset and --channel)")
    # One request per candidate, all sharing these settings (checked once, by FitRequest). The
    # fits' block bootstrap does not enter the ranking (the cross-validation is its
    # misfit-aware measure), nor does a layered model's check against its own stack
    # (fitlab.fitting.model_check; `fitlab fit` of the chosen model gives it): left out.
    loss = loss or ("chi2" if m.sigma is not None else "relative")
    settings = {"loss": loss, "subset": rows_fit, "mcmc": mcmc, "mcmc_steps": mcmc_steps,
                "walkers": walkers, "starts": starts, "seed": seed, "bootstrap": 0,
                "check_model": "off",
                "global_search": global_search, "local_solver": local_solver,
                "channels": tuple(m.channel_names[c] for c in chan_ids)}
    cands = resolve_candidates(models, fix, options, free, settings)
    fix = {k: float(v) for k, v in (fix or {}).items()}  # each checked by a candidate's request
    incs = {c: incidences_of(m, rows_fit & (m.channel == c)) for c in chan_ids}
    if cv:
        few = [m.channel_names[c] for c in chan_ids if len(incs[c]) < 2]
        if few:
            raise FitlabError(f"{m.path}: channel {few[0]} has one incidence direction among the "
                              "fitted rows: leave-one-incidence-out cross-validation needs two "
                              "or more; rank by PSIS-LOO and WAIC alone with --no-cv")
    total = {"full fit": len(cands),
             "CV fold": len(cands) * sum(len(incs[c]) for c in chan_ids) if cv else 0,
             "PSIS-LOO": len(cands) * len(chan_ids) if mcmc else 0}
    bar = _Progress(total) if progress else None
    say = (lambda s: (bar.write(s) if bar is not None else None))
    fits, per = [], {c: [] for c in chan_ids}
    run_warnings = []
    try:
        for cand in cands:
            if bar is not None:
                bar.doing(f"{cand.label}: fit" + (" + MCMC" if mcmc else ""))
            try:
                res = fit(m, cand.request)
            except FitlabError as exc:
                raise FitlabError(f"--model {cand.label!r}: {exc}") from None
            res = res.with_record({**thaw(res.record),
                                   "data": {**thaw(res.record["data"]), "fit_subset": expr}})
            fits.append(res)
            if bar is not None:
                bar.step("full fit")
            for c in chan_ids:
                name = m.channel_names[c]
                rows = rows_fit & (m.channel == c)
                # in-sample: the fit's own stored error (statistics.fit_error, the one
                # definition: fitlab.metrics.fit_error over the fitted rows)
                entry = {"in_sample": res._fit(name)["statistics"]["fit_error"],
                         "folds": None, "ic": None, "fit": res._fit(name)}
                if cv:
                    def on_fold(fold, _label=cand.label):
                        if bar is not None:
                            bar.step("CV fold")
                            bar.doing(f"{_label}: CV, θi = {fold['theta_i']:g}° done")
                    entry["folds"] = cross_validate(m, cand, loss, rows, c, seed=seed,
                                                    starts=starts, on_fold=on_fold,
                                                    order=aperture_order(res, name),
                                                    fit=res._fit(name))
                if mcmc:
                    if bar is not None:
                        bar.doing(f"{cand.label}: PSIS-LOO, WAIC")
                    ll = pointwise_log_likelihood(m, cand, res, loss, rows, c)
                    loo, waic = information_criteria(ll["loglik"], ll["reff"])
                    entry["ic"] = {"loo": loo, "waic": waic, **{k: v for k, v in ll.items()
                                                               if k != "loglik"}}
                    del ll
                    if bar is not None:
                        bar.step("PSIS-LOO")
                per[c].append(entry)
            say(f"compare: {cand.label} done")
    finally:
        if bar is not None:
            bar.close()
    record = _record(m, cands, fits, per, chan_ids, incs, rows_fit, expr, loss, cv, mcmc,
                     mcmc_steps, walkers, starts, seed, fix, options, free, run_warnings)
    out = CompareResult.from_record(record, fits, m)
    return out.raise_for_status() if throw else out


__all__ = ["Candidate", "CompareResult", "compare", "load_compare", "parse_candidate",
           "resolve_candidates",
           "cross_validate", "pointwise_log_likelihood", "information_criteria",
           "jackknife_difference",
           "SUMMARY_COLUMNS", "INCIDENCE_COLUMNS", "SCHEMA", "SCHEMA_VERSION", "DECISIVE_SE",
           "SMALL_ELPD"]
