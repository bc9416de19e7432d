"""Joint fits over channels: parameters shared by every channel (``share=["alpha"]``, ``fitlab
fit --share alpha``), the others per channel: one geometry for an RGB or spectral file, its
colour per channel.

With shared parameters the channels are one least-squares problem. Its free vector holds each
shared parameter once and each other free parameter once per channel (the ``scale`` of
relative data is always per channel)::

    alpha, albedo[R], albedo[G], albedo[B], n[R], n[G], n[B], ...

and its rows are the channels' fitted rows, channel after channel. A row's model parameters are
the free vector gathered through the row's channel (:meth:`JointStatic.row_parameters`, called
by ``space.predict``), so the kernels of the independent fits (least squares, covariance from
the Jacobian, MCMC) run unchanged on the joint problem: the covariance spans every coordinate
(the shared α against each channel's albedo, and channels against each other through α), and
the MCMC samples the joint posterior. Each channel keeps its own loss constants (the relative
loss's 1% floor is per channel). For losses without absolute noise, one noise scale serves all
channels (least squares: σ̂ from the joint cost; MCMC: one nuisance σ_r).

The result has one entry per channel like an independent fit (so that every reader of a
parameter file works unchanged): that channel's values, standard errors and covariance block
of the joint problem (the shared parameters' identical in every channel and marked
``shared``), statistics over its rows, the joint run's solver record and starts (their values
as seen by the channel, their costs the joint cost), and its columns of the joint chain (rows
aligned across channels: sample i of every channel is one draw of the joint posterior), the
goodness-of-fit checks of an independent fit run on the channel's rows, and its columns of the
joint block bootstrap (whole incidences resampled in all channels at once). The
joint problem itself (its coordinates, full covariance, cost and dof) is the result's
``joint`` entry (data_formats/fit_json.md, "Joint fits").
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.fitting.channel import (alert_line, channel_problem, fitted_rows, least_squares_alerts,
                                    least_squares_warnings, statistics)
from fitlab.fitting import progress
from fitlab.fitting.least_squares import FitData, fit_least_squares
from fitlab.fitting.space import SCALE, FitSpace
from fitlab.fitting.status import Status
from fitlab.models import Model


def coordinate_name(name: str, channel: str) -> str:
    """The joint coordinate of a per-channel parameter: ``albedo[R]``."""
    return f"{name}[{channel}]"


class JointStatic(NamedTuple):
    """What the joint problem's compiled kernels depend on (hashable): the fields of
    ``space.StaticSpace`` and the layout over channels."""

    model: Model
    options: tuple  # sorted (name, value) pairs
    names: tuple[str, ...]  # joint coordinates
    log: tuple[bool, ...]
    fixed_names: tuple[str, ...]
    relative: bool
    channels: tuple[str, ...]
    counts: tuple[int, ...]  # fitted rows of each channel; the data hold them in this order
    #: (parameter, its coordinate in each channel): one index repeated for a shared parameter
    layout: tuple[tuple[str, tuple[int, ...]], ...]

    @property
    def model_name(self) -> str:
        return self.model.name

    #: The kernels' rows are the channels' rows in order (``counts``): never padded
    #: (least_squares.pad_rows).
    rows_fixed = True

    def coordinates(self, name: str) -> tuple:
        """The coordinate of parameter ``name`` in each channel (Nones if it is fixed)."""
        for n, idx in self.layout:
            if n == name:
                return idx
        return (None,) * len(self.channels)

    def row_parameters(self, theta, fixed: dict, wi):
        """(model parameters, scale) of every row: a shared parameter is one number, a
        per-channel one an array over the rows (shaped to broadcast against ``wi``'s leading
        axes: (rows,) or, with aperture nodes, (rows, 1))."""
        n = sum(self.counts)
        row_channel = np.repeat(np.arange(len(self.counts)), self.counts)
        shape = (n,) + (1,) * (wi.ndim - 2)
        params, scale = dict(fixed), 1.0
        for name, idx in self.layout:
            if len(set(idx)) == 1:
                v = theta[idx[0]]
            else:
                v = jnp.take(theta, np.asarray(idx)[row_channel]).reshape(shape)
            if name == SCALE:
                scale = v
            else:
                params[name] = v
        return params, scale


def joint_space(spaces: list[FitSpace], channels: tuple[str, ...], counts: tuple[int, ...],
                share: tuple[str, ...]) -> FitSpace:
    """The joint FitSpace of the channels' own spaces (same model, options, fixed values)."""
    first = spaces[0].static
    free, layout = [], []
    for name in first.names:
        per = [sp.free[sp.names.index(name)] for sp in spaces]
        if name in share:
            layout.append((name, (len(free),) * len(spaces)))
            free.append(per[0])
        else:
            layout.append((name, tuple(range(len(free), len(free) + len(spaces)))))
            free += [fp._replace(name=coordinate_name(name, ch)) for fp, ch in zip(per, channels)]
    static = JointStatic(first.model, first.options, tuple(p.name for p in free),
                         tuple(p.log for p in free), first.fixed_names, first.relative,
                         tuple(channels), tuple(counts), tuple(layout))
    return FitSpace(static, tuple(free), dict(spaces[0].fixed))


def joint_data(datas: list[FitData]) -> FitData:
    """The channels' data, one after the other (aperture weights too, when given)."""
    host = [jax.tree.map(np.asarray, d) for d in datas]
    return jax.device_put(jax.tree.map(lambda *x: np.concatenate(x, axis=0), *host))


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def channel_view(space_c: FitSpace, ls, joint: FitSpace, c: int, rows: slice):
    """Channel ``c``'s view of the joint least-squares result: its coordinates' values,
    standard errors and covariance block, its rows' residuals and cost, the starts' values as
    the channel sees them (a ``LeastSquaresResult`` like an independent fit's)."""
    st = joint.static
    idx = [st.coordinates(name)[c] for name in space_c.names]

    def named(values: dict | None):
        return None if values is None else \
            {name: values[joint.names[i]] for name, i in zip(space_c.names, idx)}

    r = np.asarray(ls.residuals)[rows]
    at_bound = tuple(name for name, i in zip(space_c.names, idx) if joint.names[i] in ls.at_bound)
    starts = [{**s, "start": named(s["start"]), "end": named(s["end"])} for s in ls.starts]
    disagreement = None if ls.disagreement is None else {
        **ls.disagreement, "optima": [named(o) for o in ls.disagreement["optima"]]}
    view = ls._replace(native=np.asarray(ls.native)[idx], cost=0.5 * float(r @ r), residuals=r,
                       covariance=np.asarray(ls.covariance)[np.ix_(idx, idx)],
                       stderr=np.asarray(ls.stderr)[idx], dof=max(r.size - len(idx), 1),
                       at_bound=at_bound, starts=starts, disagreement=disagreement)
    if getattr(ls, "jacobian", None) is not None:
        view = view._replace(jacobian=np.asarray(ls.jacobian)[rows][:, idx])
    return view, idx


def mcmc_view(mc, idx: list[int], space_c: FitSpace, ndim: int, n_channels: int):
    """Channel columns of the joint chain (and the shared noise scale, if sampled); its run
    time split evenly over the channels (their sum is the run's)."""
    nuisance = len(mc.names) > ndim
    cols = list(idx) + ([ndim] if nuisance else [])
    return mc._replace(samples_native=mc.samples_native[:, idx], seconds=mc.seconds / n_channels,
                       chain_unit=mc.chain_unit[:, :, cols],
                       names=tuple(space_c.names) + (("log_noise",) if nuisance else ()),
                       tau=np.asarray(mc.tau)[cols])


def joint_record(joint: FitSpace, ls, mc, share, n_fit: int) -> dict:
    """The parameter file's ``joint`` entry (data_formats/fit_json.md, "Joint fits")."""
    rec = {
        "shared": list(share),
        "channels": list(joint.static.channels),
        "parameters": list(joint.names),
        "value": [float(v) for v in ls.native],
        "stderr": [_num(v) for v in ls.stderr],
        "covariance": {"parameters": list(joint.names),
                       "matrix": [[_num(v) for v in row] for row in ls.covariance],
                       "source": "least squares of the joint problem: noise² (JᵀJ)⁻¹ at the "
                                 "optimum, native units"},
        "n_fit": int(n_fit), "cost": float(ls.cost), "dof": int(ls.dof),
        "residual_noise_scale": float(ls.noise_scale),
    }
    if mc is not None:
        rec["mcmc"] = {"coordinates": list(mc.names),
                       "autocorrelation_time": [_num(t) for t in mc.tau],
                       "correlation": np.corrcoef(mc.samples_native.T).tolist()}
    return rec


def fit_joint(m, request, setup, rows_fit, chan_ids):
    """The channels ``chan_ids`` of Measurement ``m`` fitted as one problem with the parameters
    ``request.share`` shared (``request``: the checked FitRequest; ``setup``: its FitSetup for
    ``m``, fitlab.fitting.channel.resolve_fit). Returns the channel entries of ``driver.fit_measurement``'s result and
    the ``joint`` entry. Each channel's data, space and statistics are made as for an independent
    fit (fitlab.fitting.channel).

    Data with an aperture are fitted with the aperture quadrature (fitlab.fitting.aperture) of
    order ``aperture_order`` (None: its start order, not refined: the automatic doubling of
    independent fits is not run on a joint problem); each channel's ``aperture`` record states
    the quadrature's measured error at the joint optimum, with a warning when it is too large.

    Goodness of fit is checked on each channel as for an independent fit; the block bootstrap
    (``request.bootstrap`` refits; None: fitlab.fitting.resampling's default) resamples whole incidences
    in all channels at once and refits the joint problem (:func:`joint_bootstrap`)."""
    model, options, fixed, _, loss, start = setup
    share, seed, n_starts, quiet = request.share, request.seed, request.starts, not request.progress
    order = auto = None
    if m.has_aperture:
        from fitlab.fitting import aperture as _aperture

        order, auto = _aperture.start_order(request.aperture_order)
    log = (lambda msg: None) if quiet else progress.line
    t0 = time.perf_counter()

    names, spaces, datas, starts, masks = [], [], [], [], []
    for c in chan_ids:
        name, in_chan, rows = fitted_rows(m, c, rows_fit)
        if rows is None:
            continue
        space, data, start_native = channel_problem(m, model, options, fixed, loss, start, rows,
                                                    name, in_chan, order)
        names.append(name)
        spaces.append(space)
        datas.append(data)
        starts.append(np.asarray(start_native, dtype=float))
        masks.append((c, in_chan, rows))
    counts = tuple(int(d.value.shape[0]) for d in datas)
    if order is not None and len({d.weights.shape[1] for d in datas}) > 1:
        raise ValueError("--share: the channels' rows have different aperture rules (a different "
                         "number of quadrature nodes per row); fit the channels separately")
    joint = joint_space(spaces, tuple(names), counts, share)
    data = joint_data(datas)
    start_native = np.empty(joint.ndim)
    for c, sp in enumerate(spaces):
        for name, x in zip(sp.names, starts[c]):
            start_native[joint.static.coordinates(name)[c]] = x
    log(f"fitting {model.name} to channels {', '.join(names)} jointly: {sum(counts)} rows, "
        f"shared {', '.join(share)}; {joint.ndim} free coordinates; loss {loss}; global "
        f"{request.global_search} + {n_starts} starts")
    ls = fit_least_squares(joint, data, loss, start_native=start_native, n_starts=n_starts,
                           seed=seed, progress=not quiet, lm_maxiter=request.lm_maxiter,
                           search=request.global_search, solver=request.local_solver)
    t_ls = time.perf_counter() - t0
    if ls.solver["stopped"] == Status.NON_FINITE:
        from fitlab.fitting.channel import non_finite_fit

        raise non_finite_fit(f"{m.path}: channels {', '.join(names)} (joint fit)", len(ls.starts))
    log("  least squares: " + ", ".join(f"{k} = {v:.6g} ± {s:.2g}" for k, v, s in
                                        zip(joint.names, ls.native, ls.stderr))
        + f"  ({t_ls:.2f} s)")
    for alert in least_squares_alerts(ls, joint.names):  # now, before MCMC and bootstrap
        alert_line(quiet, f"warning: joint fit of channels {', '.join(names)}: {alert}")
    chain = None
    if request.mcmc:
        from fitlab.fitting.samplers import sample_posterior

        log(f"  MCMC: {request.mcmc_steps} steps over the joint posterior")
        chain = sample_posterior(request.sampler, joint, data, loss, ls, seed=seed,
                                 nsteps=request.mcmc_steps, walkers=request.walkers,
                                 progress=not quiet)
    boot = joint_bootstrap(m, joint, data, loss, ls, [mk[2] for mk in masks], request, log=log)
    results, offset = [], 0
    for k, (name, space_c) in enumerate(zip(names, spaces)):
        c, in_chan, rows_c = masks[k]
        rows = slice(offset, offset + counts[k])
        offset += counts[k]
        ls_c, idx = channel_view(space_c, ls, joint, k, rows)
        mc_c = None if chain is None else mcmc_view(chain, idx, space_c, joint.ndim, len(names))
        warnings = least_squares_warnings(ls_c)
        aperture = None
        if order is not None:
            _, _, aperture, more = _aperture.settle_order(space_c, ls_c, datas[k], m, rows_c,
                                                          loss, order, auto=False, refit=None)
            if auto:
                aperture["order_choice"] = "joint: not refined"
            warnings += more
        warnings += list(chain.warnings) if chain else []
        if order is None:
            full = space_c.predict(ls_c.native, m.wi[in_chan], m.wo[in_chan])
        else:
            full = _aperture.predict_rows(space_c, ls_c.native, m, in_chan, order)
        stats = statistics(m.select(in_chan), rows_fit[in_chan], full, ls_c,
                           None if m.sigma is None else m.sigma[in_chan], loss)
        good, boot_c, more = channel_misfit(m, rows_c, space_c, datas[k], loss, ls_c, mc_c,
                                            boot, joint, idx, seed=seed)
        warnings += more
        results.append({"channel": name, "space": space_c, "ls": ls_c, "mcmc": mc_c,
                        "statistics": stats, "seconds_least_squares": t_ls / len(names),
                        "goodness": good, "bootstrap": boot_c,
                        "seconds_bootstrap": (boot or {}).get("seconds", 0.0) / len(names),
                        "prediction": full, "rows": np.flatnonzero(in_chan),
                        "warnings": warnings, "shared": share,
                        **({"aperture": aperture} if aperture is not None else {})})
    return results, joint_record(joint, ls, chain, share, sum(counts))


def joint_bootstrap(m, joint: FitSpace, data: FitData, loss, ls, rows_list, request, *,
                    log) -> dict | None:
    """The block bootstrap of the joint problem (fitlab.fitting.resampling): whole incidence
    directions resampled **in every channel at once** (an incidence is one block across the
    channels, as the instrument measured it), each replicate refitted jointly (the refits,
    seed and step limit of ``request``). None when not run (``bootstrap=0``, or None with
    fewer than 3 incidences); {"skipped": ...} when asked
    for with too few incidences."""
    from fitlab.fitting import goodness as gof
    from fitlab.fitting.resampling import (DEFAULT_BOOTSTRAP, MIN_BLOCKS, block_bootstrap,
                                           skip_reason, skipped_record)

    rows = np.concatenate([np.flatnonzero(r) for r in rows_list])
    keys, block = gof.incidence_blocks(m.theta_i[rows], m.phi_i[rows])
    bootstrap = request.bootstrap
    n = bootstrap if bootstrap is not None else (DEFAULT_BOOTSTRAP if len(keys) >= MIN_BLOCKS
                                                 else 0)
    if not n:
        return None
    if len(keys) < MIN_BLOCKS:
        return {"requested": int(n), "blocks": len(keys),
                "skipped": f"{len(keys)} fitted incidence direction(s): the bootstrap resamples "
                           f"whole incidences and needs at least {MIN_BLOCKS}"}
    skip = skip_reason(ls)
    if skip is not None:
        log(f"  bootstrap skipped: {skip[1]}")
        rec = skipped_record(skip, int(n), len(keys))
        return {k: rec[k] for k in ("requested", "blocks", "skipped", "skipped_status")}
    adaptive = bootstrap is None
    log("  bootstrap: refitting " + (f"up to {n}" if adaptive else f"{n}")
        + f" resamples of {len(keys)} incidences (all channels jointly)")
    res = block_bootstrap(joint, data, loss, ls, block, replicates=int(n), seed=request.seed,
                          batch=len(ls.starts), progress=request.progress,
                          lm_maxiter=request.lm_maxiter, solver=request.local_solver,
                          adaptive=adaptive)
    log(f"  bootstrap: {res['stop_reason']}")
    return res


def channel_misfit(m, rows_c, space_c, data_c, loss, ls_c, mc_c, boot, joint, idx, *, seed):
    """Goodness of fit of one channel of a joint fit (the checks of an independent fit, on the
    channel's rows, residuals and chain columns) and its view of the joint bootstrap: (goodness,
    bootstrap record or None, warnings with the failure sentence, if any, first)."""
    from fitlab.fitting import goodness as gof
    from fitlab.fitting.losses import has_absolute_noise
    from fitlab.fitting.resampling import bootstrap_caveats, predictive_check, run_record

    keys, block = gof.incidence_blocks(m.theta_i[rows_c], m.phi_i[rows_c])
    predictive = None if mc_c is None else predictive_check(space_c, data_c, loss, mc_c, block,
                                                            seed=seed)
    good = gof.assess(ls_c.residuals, block=block, keys=keys, theta_o=m.theta_o[rows_c],
                      phi_o=m.phi_o[rows_c], wo=m.wo[rows_c], n_params=space_c.ndim,
                      absolute_noise=has_absolute_noise(loss), predictive=predictive)
    warnings, rec = [], None
    if boot is not None and "skipped" in boot:
        rec = {"method": "block bootstrap over incidence directions", **boot, "replicates": 0}
        warnings.append("no bootstrap: " + boot["skipped"])
    elif boot is not None:
        rec = {"method": "block bootstrap over incidence directions, all channels at once (whole "
                         "incidences resampled with replacement in every channel, each replicate "
                         "refitted jointly from the least-squares optimum)",
               **run_record(boot), "seed": int(seed)}
        if "at_bound" in boot:
            rec["at_bound"] = {n: boot["at_bound"][joint.names[i]]
                               for n, i in zip(space_c.names, idx)
                               if joint.names[i] in boot["at_bound"]}
        if boot["replicates"] >= 2:
            rec["parameters"] = dict(zip(space_c.names,
                                         gof.bootstrap_summary(boot["samples"][:, idx])))
        note, more = bootstrap_caveats(boot["blocks"], boot["replicates"], boot["requested"],
                                       boot["non_finite"], rec.get("at_bound"))
        if note:  # a caveat kept with the record, as for one channel
            rec["note"] = note
        warnings += more
    sentence = gof.failure_sentence(good, has_mcmc=mc_c is not None,
                                    bootstrap=bool(rec and rec.get("parameters")))
    return good, rec, ([sentence] if sentence else []) + warnings


__all__ = ["JointStatic", "coordinate_name", "joint_space", "joint_data",
           "fit_joint", "joint_bootstrap"]
