"""``fitlab.fit_many``: one model fitted to many datasets at once (fitlab/fitting/batch.py does
the batched least squares), and what the results become: a parameter file per dataset (the
``fitlab-fit`` schema of a single fit, its least-squares part) and one table of every fit
(data_formats/fit_table_csv.md).

A dataset is one channel of one measurement. Datasets of one structure (model, options, free
parameters, loss, padded row count) share compiled calls, ``chunk`` datasets at a time; others
form groups of their own. The global stage is the single fit's default Halton scan of the unit
box (fitlab.fitting.searches; nlopt's MLSL cannot be batched), so a batched fit and
``fitlab.fit`` of the same data agree where the optimum is unique (tested); MCMC, the bootstrap and the goodness-of-fit
checks are the single fit's (``fitlab.fit``).
"""

from __future__ import annotations

import hashlib
import os
import sys
from types import SimpleNamespace
import time
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.batch import (CHUNK, SCAN, STARTS, BATCH_LM_ALGORITHM, BatchResult, Problem,
                                  paused_gc,
                                  chunks, fit_chunk, group)
from fitlab.fitting.least_squares import LeastSquaresResult, lm_record
from fitlab.fitting.status import Status, channel_statuses, trusted

#: Columns of the table before the per-parameter ones.
TABLE_COLUMNS = ("dataset", "source", "channel", "rows_fitted", "cost", "dof", "noise_scale",
                 "lm_stopped", "lm_iterations", "at_bound")


class Fitted(NamedTuple):
    """One dataset's least-squares fit."""

    dataset: int  # index of the measurement in the call
    channel: str
    names: tuple[str, ...]
    native: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    cost: float
    dof: int
    noise_scale: float
    lm_iterations: int
    lm_stopped: str
    at_bound: tuple[str, ...]
    residuals: np.ndarray
    scan_cost: float
    #: the posterior (NUTS, batched over the datasets) when fitted with mcmc=True
    mcmc: object = None
    #: Levenberg–Marquardt starts run (1, more where its end was suspect: batch.fit_chunk)
    lm_starts: int = 1


def _statuses_of(f: Fitted) -> tuple[Status, ...]:
    """A batched fit's statuses by the single fit's rule (fitlab.fitting.status), from the
    parts of a parameter file's channel entry it has."""
    return channel_statuses({
        "solver": {"stopped": f.lm_stopped},
        "parameters": {n: {"at_bound": n in f.at_bound} for n in f.names},
        "mcmc": None if f.mcmc is None else {"trustworthy": f.mcmc.trustworthy}})


class ManyResult(NamedTuple):
    """Every dataset's fit (``fits``, in dataset then channel order) and the run's facts."""

    model: str
    options: dict
    loss: dict  # {dataset index: loss}
    fits: list
    measurements: list
    fixed: list  # per measurement, the fixed values (η from its file ...)
    notes: list  # per measurement
    groups: int
    seconds: float
    settings: dict

    def parameters(self, dataset: int, channel: str | None = None) -> dict:
        """{parameter: best-fit value} of one dataset (and channel)."""
        for f in self.fits:
            if f.dataset == dataset and (channel is None or f.channel == channel):
                return dict(zip(f.names, map(float, f.native)))
        raise KeyError((dataset, channel))

    def statuses(self, dataset: int, channel: str | None = None) -> tuple[Status, ...]:
        """What limits trust in one dataset's fit (and channel): fitlab.fitting.status, by the
        same rule as a single fit's (its solver's stop, parameters at a bound, the chain)."""
        for f in self.fits:
            if f.dataset == dataset and (channel is None or f.channel == channel):
                return _statuses_of(f)
        raise KeyError((dataset, channel))

    def _untrusted(self) -> list[tuple[str, Status]]:
        """(which fit, status) of every status that is not ``ok``."""
        return [(f"dataset {f.dataset} channel {f.channel}", s) for f in self.fits
                for s in _statuses_of(f) if not s.ok]

    @property
    def ok(self) -> bool:
        """Whether every dataset's fit can be used as it stands."""
        return not self._untrusted()

    def raise_for_status(self) -> "ManyResult":
        """This result if it is :attr:`ok`, else a FitlabError naming each fit's statuses."""
        return trusted(self, "fits not to be trusted as they stand", self._untrusted())

    def table(self, out=None) -> str:
        """Every fit as CSV text (data_formats/fit_table_csv.md): one row per dataset and
        channel, the value and standard error of each free parameter. ``out``: the table's
        path, to name the data files relative to it (else by their file names): never an
        absolute path of this machine."""
        from pathlib import Path

        from fitlab.io.files import path_for_record

        def source(path):
            if out is not None and Path(path).exists():
                return path_for_record(path, out)
            return Path(path).name
        names = list(dict.fromkeys(n for f in self.fits for n in f.names))
        head = list(TABLE_COLUMNS) + [c for n in names for c in (n, f"{n}_stderr")]
        mcmc = any(f.mcmc is not None for f in self.fits)
        if mcmc:
            head += [c for n in names for c in (f"{n}_p16", f"{n}_p50", f"{n}_p84")]
            head += ["posterior_ess", "posterior_trusted"]
        lines = [f"# fitlab fit table: model {self.model}; one row per dataset and channel",
                 ",".join(head)]
        for f in self.fits:
            m = self.measurements[f.dataset]
            label = m.metadata.get("dataset")
            cells = [str(f.dataset), _csv(source(m.path) + (f"#{label}" if label else "")),
                     _csv(f.channel),
                     str(len(f.residuals)), repr(float(f.cost)),
                     str(int(f.dof)), repr(float(f.noise_scale)), f.lm_stopped,
                     str(int(f.lm_iterations)), _csv(" ".join(f.at_bound))]
            vals = dict(zip(f.names, f.native))
            errs = dict(zip(f.names, f.stderr))
            for n in names:
                cells += ([repr(float(vals[n])), repr(float(errs[n]))] if n in vals else ["", ""])
            if mcmc:
                q = {} if f.mcmc is None else {
                    n: np.percentile(f.mcmc.samples_native[:, k], [16, 50, 84])
                    for k, n in enumerate(f.names)}
                for n in names:
                    cells += [repr(float(x)) for x in q[n]] if n in q else ["", "", ""]
                cells += ["" if f.mcmc is None else repr(float(f.mcmc.ess)),
                          "" if f.mcmc is None else str(bool(f.mcmc.trustworthy)).lower()]
            lines.append(",".join(cells))
        return "\n".join(lines) + "\n"

    def records(self):
        """(measurement index, parameter-file record) per measurement: the ``fitlab-fit``
        schema of a single fit, with the least-squares part of each channel."""
        from fitlab.export.paramfile import build_record
        from fitlab.fitting.channel import least_squares_warnings, statistics
        from fitlab.models import get_model

        model = get_model(self.model)
        by_m: dict = {}
        for f in self.fits:
            by_m.setdefault(f.dataset, []).append(f)
        for i, fits in sorted(by_m.items()):
            m = self.measurements[i]
            rows_fit = self.settings["rows"][i]
            channels = []
            for f in fits:
                space = self.settings["spaces"][(i, f.channel)]
                ls = _least_squares_result(f, self.settings)
                c = m.channel_names.index(f.channel)
                in_chan = m.channel == c
                pred = space.predict(f.native, m.wi[in_chan], m.wo[in_chan])
                stats = statistics(m.select(in_chan), rows_fit[in_chan], pred, ls,
                                   None if m.sigma is None else m.sigma[in_chan], self.loss[i])
                channels.append({"channel": f.channel, "space": space, "ls": ls, "mcmc": f.mcmc,
                                 "statistics": stats, "goodness": None, "bootstrap": None,
                                 "warnings": least_squares_warnings(ls)
                                 + ([] if f.mcmc is None else list(f.mcmc.warnings)),
                                 "seconds_least_squares": 0.0})
            result = {"model": model, "options": self.options, "fixed": self.fixed[i],
                      "loss": self.loss[i], "notes": self.notes[i]
                      + ["fitted by fitlab.fit_many (batched least squares: Halton scan, "
                         "Levenberg-Marquardt" + ("; posterior by NUTS, batched over the "
                                                  "datasets" if fits[0].mcmc is not None
                                                  else "; no MCMC")
                         + "; no bootstrap or goodness checks)"],
                      "seed": self.settings["seed"], "subset_rows": rows_fit,
                      "channels": channels}
            yield i, build_record(result, m, subset_expr=self.settings.get("subset_expr"),
                                  illuminant=self.settings.get("illuminant"))


def output_name(m) -> str:
    """The parameter file's stem of a dataset: the data file's stem, with ``.LABEL`` for a
    dataset of a file with a ``dataset`` column."""
    from pathlib import Path

    label = m.metadata.get("dataset")
    return Path(m.path).stem + (f".{label}" if label else "")


def _csv(text) -> str:
    text = str(text)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text


def _least_squares_result(f: Fitted, settings: dict) -> LeastSquaresResult:
    named = {n: float(v) for n, v in zip(f.names, f.native)}
    return LeastSquaresResult(
        f.native, float(f.cost), f.residuals, f.covariance, f.stderr, float(f.noise_scale),
        int(f.dof), f.at_bound, int(f.lm_iterations),
        [{"start": None, "end": named, "cost": float(f.cost),
          "lm_iterations": int(f.lm_iterations), "lm_stopped": f.lm_stopped}],
        None,
        {"algorithm": "batched Halton scan (fitlab.fitting.batch)",
         "evaluations": int(settings["scan"]), "non_finite": 0, "status": "done",
         "best_cost": float(f.scan_cost) if np.isfinite(f.scan_cost) else None,
         "lm_starts": int(f.lm_starts), "local_minima_worse": None},
        lm_record(f.lm_stopped, int(f.lm_iterations), int(settings["lm_maxiter"]),
                  algorithm=BATCH_LM_ALGORITHM))


def _problems(measurements, request):
    """Every dataset's Problem, with what records need (spaces, rows, fixed, notes, loss).
    Datasets of one instrument (the same directions, channels, fitted rows and fit set-up as
    an earlier one: :func:`_geometry`) take that one's problems with their own values
    (fitlab.fitting.channel ``channel_problems_like``: the same numbers, built at once)."""
    from fitlab.fitting.channel import resolve_fit
    from fitlab.fitting.subset import rows_of
    from fitlab.io.gates import notes as read_notes

    per, spaces, rows, fixed_all, notes_all, losses = {}, {}, [], [], [], {}
    setups, memo, protos, likes, seen = {}, {}, {}, {}, {}  # resolve_fit: eta and sigma
    for i, m in enumerate(measurements):
        key = (m.eta(), m.sigma is None)
        if key not in setups:
            try:
                setups[key] = resolve_fit(m, request)
            except ValueError as exc:
                raise FitlabError(f"{m.path}: {exc}") from None
        _, mask = rows_of(request.subset, m)
        rows.append(mask)
        fixed_all.append(dict(setups[key].fixed))
        notes_all.append(list(setups[key].notes) + read_notes(m))  # how the file was read
        losses[i] = setups[key].loss
        if m.has_aperture:
            raise FitlabError(f"{m.path}: data with an aperture are fitted one at a time "
                              "(fitlab fit), whose quadrature order adapts per file")
        # the same arrays as an earlier dataset's (datasets of one file, or made from one
        # template): that one's geometry, else the arrays' contents digested
        same = (key, m.quantity, m.channel_names, id(m.wi), id(m.wo), id(m.channel),
                None if request.subset is None else mask.tobytes())
        g = seen.get(same)
        if g is None:
            g = seen[same] = _geometry(m, mask, key)
        if g in protos:
            likes[g].append(i)
            continue
        protos[g], likes[g] = i, []
        per[i] = _own_problems(i, m, mask, setups[key], memo)
    for g, members in likes.items():
        if members:
            m0 = measurements[protos[g]]
            per.update(_like_problems(per[protos[g]], m0, rows[protos[g]],
                                      [measurements[i] for i in members], members,
                                      setups[(m0.eta(), m0.sigma is None)], memo))
    problems = [p for i in range(len(measurements)) for p in per[i]]
    for p in problems:
        spaces[p.key] = p.space
    opts = next(iter(setups.values())).options
    return problems, spaces, rows, fixed_all, notes_all, losses, opts


def _geometry(m, mask, setup_key):
    """What datasets must share to take one's problems with their own values: the fit's
    set-up, the quantity, the channels, and the directions and fitted rows (their shapes, and
    a BLAKE2 digest of their bytes: equal digests of different arrays are not to be met)."""
    arrays = (m.wi, m.wo, m.channel, mask)
    h = hashlib.blake2b(b"".join(np.ascontiguousarray(x).tobytes() for x in arrays),
                        digest_size=32)
    return (setup_key, m.quantity, m.channel_names, *(x.shape for x in arrays),
            *(x.dtype for x in arrays), h.digest())


def _own_problems(i, m, mask, setup, memo) -> list:
    """Dataset ``i``'s problems, one per channel with rows to fit (the single fit's
    ``channel_problem``)."""
    from fitlab.fitting.channel import channel_problem, fitted_rows

    mdl, opts, fixed, _, lss, start = setup
    out = []
    for c in range(len(m.channel_names)):
        name, in_chan, r = fitted_rows(m, c, mask)
        if r is None:
            continue
        try:
            space, data, start_native = channel_problem(m, mdl, opts, fixed, lss, start, r,
                                                        name, in_chan, memo=memo)
        except ValueError as exc:
            raise FitlabError(f"{m.path}: {exc}") from None
        out.append(Problem(space, data, np.asarray(start_native, float), lss, int(r.sum()),
                           (i, name)))
    return out


def _like_problems(proto: list, m0, mask0, ms: list, index: list, setup, memo) -> dict:
    """{dataset index: its problems} of the datasets ``ms`` (indices ``index``), on the
    geometry of ``m0`` (fitted rows ``mask0``) whose problems are ``proto``: each channel's at once
    (fitlab.fitting.channel ``channel_problems_like``)."""
    from fitlab.fitting.channel import _start_values, channel_problems_like, fitted_rows

    mdl, opts, _, _, lss, start = setup
    value = np.stack([m.value for m in ms])
    sigma = None if m0.sigma is None else np.stack([m.sigma for m in ms])
    out = {i: [] for i in index}
    for p in proto:
        c = m0.channel_names.index(p.key[1])
        in_chan = m0.channel == c
        r = in_chan & mask0
        v = value[:, r]
        empty = ~np.any(v != 0, axis=1)
        if empty.any():  # the single fit's message, naming the file
            j = int(np.flatnonzero(empty)[0])
            fitted_rows(ms[j], c, mask0)
        f = (_start_values(mdl, opts, start, m0, in_chan, memo)[r[in_chan]]
             if m0.is_relative else None)
        got = channel_problems_like(p.space, p.data, p.start_native, lss, v,
                                    None if sigma is None else sigma[:, r], f)
        for i, space, data, x0 in zip(index, *got):
            out[i].append(Problem(space, data, x0, lss, p.n_rows, (i, p.key[1])))
    return out


def _posteriors(problems, res: BatchResult, *, seed, nsteps, chains, batch):
    """NUTS posteriors of a chunk's datasets, batched (padded like the least squares)."""
    try:
        from fitlab.fitting.nuts import run_nuts_many
    except ImportError:  # pragma: no cover - blackjax is in the test extra
        raise FitlabError("mcmc with fit_many uses NUTS: pip install 'fitlab[samplers]'") \
            from None
    from fitlab.fitting.least_squares import pad_to, padded_size

    size = padded_size(max(p.n_rows for p in problems))
    items = []
    for k, p in enumerate(problems):
        # what NUTS reads of a least-squares result: the start, the noise scale, and the
        # standard errors and degrees of freedom of its initial mass matrix
        ls = SimpleNamespace(native=res.native[k], noise_scale=res.noise_scale[k],
                             stderr=res.stderr[k], dof=res.dof[k],
                             covariance=res.covariance[k])
        items.append((p.space, pad_to(p.data, size), p.loss, ls))
    n_real = len(items)
    items += [items[-1]] * (batch - n_real)  # one compilation for every chunk
    return run_nuts_many(items, seed=seed, nsteps=nsteps, nchains=chains)[:n_real]


#: fit_many's defaults where they differ from a single fit's (FitRequest's).
MANY_DEFAULTS = {"starts": STARTS, "mcmc_steps": 1000, "walkers": 4, "sampler": "nuts"}


def check_batch(request, *, scan: int = SCAN, chunk: int = CHUNK):
    """``request`` if a batched fit can do it (fit_many and the Dask runner; the CLI asks before
    reading the data): what only a single fit offers is refused, the posteriors are NUTS's, and
    ``scan`` and ``chunk`` are positive integers."""
    for name, v in (("scan", scan), ("chunk", chunk)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise FitlabError(f"{request.name_of(name)} must be an integer of at least 1, got "
                              f"{v!r}")
    single = [request.name_of(f) for f in request.single_only()]
    if single:
        raise FitlabError(f"several datasets are fitted at once (batched least squares); not "
                          f"with {', '.join(single)}: fit the files one at a time for those")
    if request.mcmc and request.sampler != "nuts":
        raise FitlabError(f"a batched fit samples its posteriors with NUTS "
                          f"({request.name_of('sampler')} nuts), not {request.sampler}: emcee "
                          "runs one file at a time")
    return request


def fit_many(measurements, model, *, scan: int = SCAN, chunk: int = CHUNK,
             throw: bool = False, angles: str | None = None, accept=(),
             quantity: str | None = None, **settings) -> ManyResult:
    """Fit ``model`` to every channel of every measurement (Measurements or paths; a file with
    a ``dataset`` column is one measurement per dataset, ``ManyResult.measurements``) with
    batched least squares (fitlab/fitting/batch.py); returns a :class:`ManyResult` (its
    ``records()`` are parameter files, its ``table()`` one CSV of every fit).

    ``model`` is a registry name, a Model or a whole :class:`fitlab.fitting.request.FitRequest`;
    ``settings`` are the request's fields as in :func:`fitlab.fit` (``fix``, ``free``,
    ``options``, ``loss``, ``subset``, ``starts``, ``seed``, ``lm_maxiter``, ``mcmc``,
    ``mcmc_steps``, ``walkers``, ``progress``), with the defaults of :data:`MANY_DEFAULTS`:
    ``starts`` are Levenberg–Marquardt starts besides the scan's best point and the model's
    defaults; ``mcmc`` also samples the posterior of every dataset by NUTS (blackjax;
    ``walkers`` chains × ``mcmc_steps`` adaptation and draws), vmapped over the datasets of a
    chunk as well (emcee, the single fit's reference sampler, is not batched: use fitlab.fit
    per file). What only a single fit offers (``share``, ``bootstrap``, ``aperture_order``,
    ``start``, ``channels``, ``walter_diagnostics``) is refused. ``scan``: Halton points of the
    global stage; ``chunk``: datasets per compiled call (memory grows with it). ``throw``: raise
    a FitlabError naming the fits that are not ``ok`` (``ManyResult.statuses``) instead of
    returning them. ``angles``, ``accept``, ``quantity``: how the paths among ``measurements`` are
    read (:func:`fitlab.read`)."""
    from fitlab.fitting.api import read
    from fitlab.fitting.request import FitRequest, as_request

    t0 = time.perf_counter()
    request = check_batch(as_request(model, settings if isinstance(model, FitRequest)
                                     else {**MANY_DEFAULTS, **settings}), scan=scan, chunk=chunk)
    if isinstance(measurements, (str, bytes, os.PathLike)) or hasattr(measurements, "value"):
        measurements = [measurements]
    ms = [d for m in measurements
          for d in (read(m, angles=angles, accept=accept, quantity=quantity)
                    if not hasattr(m, "value") else m).datasets()]
    if not ms:
        raise FitlabError("fit_many needs at least one measurement")
    starts, seed, lm_maxiter = request.starts, request.seed, request.lm_maxiter
    mdl, subset = request.model, request.subset
    with paused_gc():  # thousands of small records: batch.paused_gc
        problems, spaces, rows, fixed, notes, losses, opts = _problems(ms, request)
        if not problems:
            raise FitlabError("no dataset has rows to fit (check the subset)")
        groups = group(problems)
        work = [(g, r) for g in groups for r in chunks(len(g), chunk)]
        bar = None
        if request.progress:
            from tqdm import tqdm

            bar = tqdm(total=len(problems), desc="fits", unit="fit", file=sys.stderr,
                       mininterval=0.5, dynamic_ncols=True)
        fits = [None] * len(problems)
        try:
            for g, r in work:
                idx = [g[j] for j in r]
                res: BatchResult = fit_chunk([problems[j] for j in idx], starts=starts, scan=scan,
                                             seed=seed, lm_maxiter=lm_maxiter,
                                             batch=min(chunk, len(g)))
                posts = [None] * len(idx)
                if request.mcmc:
                    posts = _posteriors([problems[j] for j in idx], res, seed=seed,
                                        nsteps=request.mcmc_steps, chains=request.walkers or 4,
                                        batch=min(chunk, len(g)))
                # per dataset its row of each result (Python numbers converted at once)
                for j, (i, channel), *row in zip(
                        idx, res.keys, res.native, res.stderr, res.covariance,
                        res.cost.tolist(), res.dof.tolist(), res.noise_scale.tolist(),
                        res.iterations.tolist(), res.stopped, res.at_bound, res.residuals,
                        res.scan_cost.tolist(), posts, res.lm_starts.tolist()):
                    fits[j] = Fitted(i, channel, res.names, *row)
                if bar is not None:
                    bar.update(len(idx))
        finally:
            if bar is not None:
                bar.close()
    settings = {"starts": starts, "scan": scan, "seed": seed, "lm_maxiter": lm_maxiter,
                "chunk": chunk, "mcmc": request.mcmc, "spaces": spaces, "rows": rows,
                "subset_expr": subset if isinstance(subset, str) else None,
                "illuminant": request.illuminant}
    out = ManyResult(mdl.name, opts, losses, fits, ms, fixed, notes, len(groups),
                     time.perf_counter() - t0, settings)
    return out.raise_for_status() if throw else out


__all__ = ["fit_many", "check_batch", "MANY_DEFAULTS", "ManyResult", "Fitted", "TABLE_COLUMNS", "output_name"]
