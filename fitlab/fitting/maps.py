"""``fitlab.fit_maps`` / ``fitlab fit-maps STACK``: a spatially varying material fitted texel
by texel (data_formats/stack.md).

Every texel of a capture stack (fitlab/io/stack.py) is a dataset of the batched engine
(fitlab/fitting/batch.py): one per channel (or, with ``share``, one joint problem over the
channels, fitlab/fitting/joint.py), all on the stack's one set of directions. A texel's
problem is made as a single fit's (fitlab.fitting.channel: ``resolve_fit``,
``channel_problem``) from a measurement of its readings, with the same
:class:`~fitlab.fitting.request.FitRequest` and the same statuses
(fitlab.fitting.status.channel_statuses); a reading that is NaN is no row (in a joint problem,
a row of ROW_MASK 0, so that every texel has one structure). A texel with nothing to fit in a
channel (every reading NaN, no more readings than free parameters, only zeros) is not fitted
and gets :attr:`Status.NO_DATA`.

The result, :class:`MapsResult`, holds one array per parameter over the texels (and channels),
its standard error, the fit error (fitlab.metrics: the RMS relative error over the fitted
rows, the rule of ``fitlab fit``'s ``statistics.fit_error``) and the status code per texel
(``Status.code``); fitlab/export/maps.py writes them as OpenEXR maps with ``maps.json`` and
the renderer hand-off.
"""

from __future__ import annotations

import ast
import io
import shutil
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.status import Status, channel_statuses, trusted

#: fit_maps' defaults where they differ from a single fit's (FitRequest's): the batched fit's.
MAPS_DEFAULTS = {"starts": 4}
#: Texels per call of the prediction that scores the fits.
PREDICT_CHUNK = 4096


class MapsResult(NamedTuple):
    """Every texel's fit as arrays over (height, width[, channel]) (module text)."""

    model: str
    options: dict
    fixed: dict  # parameters held fixed (fix=, or eta from the table)
    channel_names: tuple[str, ...]
    #: {parameter: (H, W, C) values}, C = 1 for a parameter shared by the channels (and for a
    #: one-channel stack); NaN where the texel (channel) was not fitted
    values: dict
    stderr: dict
    shared: tuple[str, ...]
    rms: np.ndarray  # (H, W, C) the fit error per texel and channel; NaN: not fitted
    status: np.ndarray  # (H, W) int: Status.code of the texel's first status that is not ok
    settings: dict
    stack: object  # the fitlab.io.stack.Stack fitted
    notes: list
    seconds: float

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.status.shape)

    def counts(self) -> dict:
        """{status value: texels} of every status that occurs, converged first."""
        codes, n = np.unique(self.status, return_counts=True)
        members = list(Status)
        return {members[int(c)].value: int(k) for c, k in zip(codes, n)}

    @property
    def ok(self) -> bool:
        """Whether every texel's fit converged with nothing to report."""
        return not np.any(self.status)

    def raise_for_status(self) -> "MapsResult":
        """This result if it is :attr:`ok`, else a FitlabError counting each status."""
        members = list(Status)
        return trusted(self, "texels not to be trusted as they stand", [
            (f"{k} texel{'s' if k > 1 else ''}", Status(v)) for v, k in self.counts().items()
            if not members[[s.value for s in members].index(v)].ok])


def progress_line(request):
    """fitlab.fitting.progress.line when the request shows progress, else a no-op."""
    from fitlab.fitting import progress

    return progress.line if request.progress else (lambda msg: None)


def _template(stack):
    """A Measurement of the stack's directions, channel after channel (row c·n + j: image j,
    channel c), values 0: each texel's readings replace them."""
    from fitlab.io.measurement import Measurement, check_measurement

    n, C = stack.n_images, len(stack.channel_names)
    wi, wo = stack.directions()
    rep = lambda a: np.tile(np.asarray(a, float), C)  # noqa: E731
    scatter = "bsdf" if np.any(wo[:, 2] < 0) else "brdf"
    m = Measurement(
        path=stack.path, sha256=stack.sha256, theta_i=rep(stack.theta_i),
        phi_i=rep(stack.phi_i), theta_o=rep(stack.theta_o), phi_o=rep(stack.phi_o),
        wi=np.tile(wi, (C, 1)), wo=np.tile(wo, (C, 1)), value=np.zeros(n * C), sigma=None,
        channel=np.repeat(np.arange(C), n), channel_names=tuple(stack.channel_names),
        wavelength_nm=None, quantity="bsdf", file_quantity="bsdf",
        metadata={"scatter": scatter, **stack.metadata},
        lines=np.tile(np.asarray(stack.lines, dtype=int), C))
    return check_measurement(m)


def _uses_value(expr) -> bool:
    """Whether a --fit-subset expression reads the values (then it is evaluated per texel)."""
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError:
        return False  # subset_mask says why
    return any(isinstance(n, ast.Name) and n.id in ("value", "sigma") for n in ast.walk(tree))


def _texel_problems(t, m, rows_fit, request, setup):
    """The Problems of texel ``t`` (Measurement ``m`` of its readings, ``rows_fit`` its rows to
    fit): one per channel, or one joint problem with ``request.share``; [] when a channel has
    nothing to fit (no reading, only zeros, no more readings than free parameters)."""
    from fitlab.fitting.batch import Problem
    from fitlab.fitting.channel import channel_problem
    from fitlab.fitting.joint import joint_space
    from fitlab.fitting.least_squares import ROW_MASK

    model, options, fixed, _, loss, start = setup
    found = []
    for c in range(len(m.channel_names)):
        name = m.channel_names[c]
        in_chan = m.channel == c
        rows = in_chan & rows_fit
        if not np.any(m.value[rows] != 0):  # no reading, or only zeros
            return []
        if request.share:
            # every row of the channel, a missing reading masked (ROW_MASK 0, its value the
            # channel's mean: finite for every loss): one structure for every texel
            filled = np.where(rows, m.value, np.mean(m.value[rows]))
            try:
                space, data, x0 = channel_problem(m._replace(value=filled), model, options,
                                                  fixed, loss, start, in_chan, name, in_chan)
            except ValueError:
                return []
            if rows.sum() <= space.ndim:
                return []
            data = data._replace(consts={**data.consts,
                                         ROW_MASK: rows[in_chan].astype(np.float64)})
        else:
            try:
                space, data, x0 = channel_problem(m, model, options, fixed, loss, start, rows,
                                                  name, in_chan)
            except ValueError:  # fewer rows than free parameters
                return []
        found.append((name, space, data, np.asarray(x0, float), int(rows.sum())))
    if not request.share:
        return [Problem(space, data, x0, loss, n, (t, c))
                for c, (_, space, data, x0, n) in enumerate(found)]
    from fitlab._jax import jax

    names = tuple(f[0] for f in found)
    counts = tuple(int(np.shape(f[2].value)[0]) for f in found)
    joint = joint_space([f[1] for f in found], names, counts, request.share)
    data = jax.tree.map(lambda *x: np.concatenate(x, axis=0), *[f[2] for f in found])
    x0 = np.empty(joint.ndim)
    for c, f in enumerate(found):
        for name, x in zip(f[1].names, f[3]):
            x0[joint.static.coordinates(name)[c]] = x
    return [Problem(joint, data, x0, loss, sum(f[4] for f in found), (t, None))]


def _regular_problems(texels, readings, template, rows_fit, request, setup):
    """(t, the Problems of texel t) of ``texels``, whose readings are all finite and fitted on
    the same rows ``rows_fit`` (no per-texel subset, no relative scale): the first one's
    Problems made by :func:`_texel_problems` (the single fit's ``channel_problem``), every
    other's the same with its own values and the loss's constants of them
    (fitlab.fitting.losses ``loss_weights``, as channel_problem computes them), sharing the
    first's space and direction arrays (fitlab.fitting.batch stacks them at once)."""
    from fitlab.fitting.batch import Problem
    from fitlab.fitting.least_squares import ROW_MASK, FitData
    from fitlab.fitting.losses import loss_weights

    loss = setup[4]
    C = len(template.channel_names)
    chans = [template.channel == c for c in range(C)]
    rows = [ch & rows_fit for ch in chans]
    # a channel with only zeros on its fitted rows: nothing to fit (as _texel_problems says)
    empty = np.zeros(len(texels), dtype=bool)
    for r in rows:
        empty |= ~np.any(readings[np.ix_(texels, np.flatnonzero(r))] != 0, axis=1)
    first = next((t for t, e in zip(texels, empty) if not e), None)
    proto = [] if first is None else _texel_problems(
        first, template._replace(value=readings[first]), rows_fit, request, setup)
    if not proto:
        return [(t, []) for t in texels]
    share = bool(request.share)
    # every texel's values and loss constants per channel at once (rows on the last axis)
    idx = np.asarray(texels)
    per_channel = []
    for ch, r in zip(chans, rows):
        if share:  # every row of the channel, a row not fitted the channel's mean
            v = np.where(r[ch], readings[np.ix_(idx, np.flatnonzero(ch))],
                         np.mean(readings[np.ix_(idx, np.flatnonzero(r))], axis=1)[:, None])
        else:
            v = readings[np.ix_(idx, np.flatnonzero(r))]
        co = template.wo[ch if share else r, 2]
        w = {k: np.broadcast_to(np.asarray(x, float), v.shape)
             for k, x in loss_weights(loss, v, None, co).items()}
        per_channel.append((v, w))
    if share:  # one joint problem per texel: the channels' rows one after another
        value = np.concatenate([v for v, _ in per_channel], axis=1)
        consts = {k: np.concatenate([w[k] for _, w in per_channel], axis=1)
                  for k in per_channel[0][1]}
        per_problem = [(value, consts, proto[0], None)]
    else:
        per_problem = [(v, w, p, c) for c, ((v, w), p) in enumerate(zip(per_channel, proto))]
    out = []
    for j, (t, e) in enumerate(zip(texels, empty)):
        if e:
            out.append((t, []))
        elif t == first:
            out.append((t, proto))
        else:  # the prototype's problem with this texel's values (built directly: 10^5 texels)
            got = []
            for v, w, p, c in per_problem:
                d = p.data
                own = {k: x[j] for k, x in w.items()}
                if ROW_MASK in d.consts:
                    own[ROW_MASK] = d.consts[ROW_MASK]
                got.append(Problem(p.space, FitData(d.wi, d.wo, v[j], own, d.weights),
                                   p.start_native, p.loss, p.n_rows, (t, c)))
            out.append((t, got))
    return out


def check_maps_request(request, *, scan: int, chunk: int):
    """``request`` if a map fit can do it: what a batched fit offers (fitlab.fitting.many.
    check_batch), ``share`` besides (one joint problem per texel), no MCMC."""
    from fitlab.fitting.many import check_batch

    check_batch(request.replace(share=()) if request.share else request, scan=scan,
                chunk=chunk)
    if request.mcmc:
        raise FitlabError(f"fit-maps fits least squares per texel; not {request.name_of('mcmc')}"
                          " (fit one texel's readings with fitlab fit for a posterior)")
    return request


def fit_maps(stack, model, *, out_dir=None, gltf: bool = False, workers: int | None = None,
             scheduler: str | None = None, tile_rows: int | None = None,
             scan: int | None = None, chunk: int | None = None, throw: bool = False,
             **settings) -> MapsResult:
    """Fit ``model`` to every texel of a capture stack (a folder, data_formats/stack.md, or a
    :class:`fitlab.io.stack.Stack`) with the batched engine (module text); returns a
    :class:`MapsResult` (:func:`fitlab.export.maps.write_maps` writes it, as ``fitlab fit-maps
    --out-dir`` does).

    ``model`` is a registry name, a Model or a whole :class:`~fitlab.fitting.request.FitRequest`;
    ``settings`` are the request's fields as in :func:`fitlab.fit`: ``fix``, ``free``,
    ``options``, ``loss``, ``subset`` (an expression over the stack's rows: ``theta_i``,
    ``phi_i``, ``theta_o``, ``phi_o``, ``channel``, ``row`` (the image's index),
    ``specular_deg`` and ``value``, the last evaluated per texel), ``share`` (parameters shared
    by the channels: one joint problem per texel), ``starts``, ``seed``, ``lm_maxiter``,
    ``progress`` (a bar over the texels); what only a single fit of one file offers (MCMC,
    the bootstrap, ``start``, ``channels``, the aperture, Walter's diagnostics, another global
    search) is refused. ``scan``, ``chunk``: the batched engine's (Halton points; datasets per
    compiled call). ``throw``: raise a FitlabError counting the texels whose status is not
    ``ok`` instead of returning them (after writing ``out_dir``).

    ``out_dir``: also write the maps there (fitlab.export.maps.write_maps: all or nothing),
    as ``fitlab fit-maps --out-dir``; ``gltf``: also the glTF 2.0 material with PNG textures
    (:func:`convert_to_gltf`: a second fit per texel). ``workers`` / ``scheduler``: fit in tiles of
    ``tile_rows`` image rows on Dask.distributed workers, resumable
    (:func:`fit_maps_tiled`; needs ``out_dir``)."""
    from fitlab.fitting import progress
    from fitlab.fitting.batch import CHUNK, SCAN, chunks, fit_chunk, group, paused_gc
    from fitlab.fitting.channel import resolve_fit
    from fitlab.fitting.request import FitRequest, as_request
    from fitlab.fitting.subset import rows_of
    from fitlab.io.stack import Stack, read_stack

    t0 = time.perf_counter()
    scan = SCAN if scan is None else scan
    chunk = CHUNK if chunk is None else chunk
    request = as_request(model, settings if isinstance(model, FitRequest)
                         else {**MAPS_DEFAULTS, **settings})
    share = check_maps_request(request, scan=scan, chunk=chunk).share
    if workers is not None or scheduler is not None:
        if out_dir is None or isinstance(stack, Stack):
            raise FitlabError("workers/scheduler fit a stack folder in tiles and write out_dir: "
                              "give both")
        result, _ = fit_maps_tiled(stack, request, out_dir, scan=scan, chunk=chunk, gltf=gltf,
                                   workers=1 if workers is None else workers,
                                   scheduler=scheduler, tile_rows=tile_rows,
                                   progress=request.progress)
        return result.raise_for_status() if throw else result
    if gltf and out_dir is None:
        raise FitlabError("gltf: the glTF material is written into out_dir: give it")
    if out_dir is not None:
        from fitlab.export.maps import check_out_dir

        check_out_dir(out_dir)
    say = progress_line(request)
    if not isinstance(stack, Stack):
        say(f"reading the stack {stack}")
        stack = read_stack(stack)
    template = _template(stack)
    try:
        setup = resolve_fit(template, request)
    except ValueError as exc:
        raise FitlabError(f"{stack.path}: {exc}") from None
    if share and len(stack.channel_names) < 2:
        raise FitlabError(f"{request.name_of('share')}: the stack has one channel "
                          f"({stack.channel_names[0]}); sharing is across R, G, B")
    H, W = stack.shape
    n, C = stack.n_images, len(stack.channel_names)
    # (texels, C·n): each texel's readings in the template's row order
    readings = np.transpose(stack.values, (0, 1, 3, 2)).reshape(H * W, C * n).astype(float)
    finite = np.isfinite(readings)
    per_texel = isinstance(request.subset, str) and _uses_value(request.subset)
    base = None if per_texel else rows_of(request.subset, template)[1]
    say(f"{H} x {W} texels, {n} images, {C} channel{'s' if C > 1 else ''}: setting up the fits")
    with paused_gc():  # a record per texel: fitlab.fitting.batch.paused_gc
        problems, no_data = [None] * (H * W), np.zeros(H * W, dtype=bool)
        rows_used = np.zeros((H * W, C * n), dtype=bool)
        regular = (np.zeros(H * W, dtype=bool) if per_texel or template.is_relative
                   else np.all(finite, axis=1))
        if np.any(regular):  # every reading finite: one structure, the values substituted
            rows_used[regular] = base
            for t, got in _regular_problems(np.flatnonzero(regular), readings, template, base,
                                            request, setup):
                no_data[t] = not got
                problems[t] = got
        for t in np.flatnonzero(~regular):
            m = template._replace(value=np.where(finite[t], readings[t], 0.0))
            if per_texel:
                try:
                    mask = rows_of(request.subset, m._replace(
                        value=np.where(finite[t], readings[t], np.nan)))[1]
                except FitlabError:  # selects none of this texel's readings
                    mask = np.zeros(C * n, dtype=bool)
            else:
                mask = base
            rows_used[t] = mask & finite[t]
            got = _texel_problems(t, m, rows_used[t], request, setup)
            no_data[t] = not got
            problems[t] = got
        problems = [p for got in problems for p in got]
        groups = group(problems, joint=bool(share))
        work = [(g, r) for g in groups for r in chunks(len(g), chunk)]
        bar = progress.bar(request.progress, len(problems), "texel fits", "fit")
        fits = {}
        try:
            for g, r in work:
                idx = [g[j] for j in r]
                res = fit_chunk([problems[j] for j in idx], starts=request.starts, scan=scan,
                                seed=request.seed, lm_maxiter=request.lm_maxiter,
                                batch=min(chunk, len(g)))
                for k, j in enumerate(idx):
                    fits[problems[j].key] = (problems[j], res.names, res.native[k], res.stderr[k],
                                             res.stopped[k], res.at_bound[k])
                if bar is not None:
                    bar.update(len(idx))
        finally:
            if bar is not None:
                bar.close()
    result = _assemble(stack, request, setup, fits, no_data, readings, rows_used, scan=scan,
                       chunk=chunk, seconds=time.perf_counter() - t0)
    if out_dir is not None:
        _write(result, out_dir, gltf, say, request.progress)
    return result.raise_for_status() if throw else result


def _write(result, out_dir, gltf: bool, say, progress: bool) -> None:
    """write_maps, after the glTF conversion when asked for."""
    from fitlab.export.maps import write_maps

    conversion = None
    if gltf:
        say("converting every texel to glTF's BRDF (a fit per texel)")
        conv, why = convert_to_gltf(result, progress=progress)
        conversion = conv if conv is not None else why
    say(f"writing {out_dir}")
    write_maps(result, out_dir, gltf=conversion)


def _assemble(stack, request, setup, fits, no_data, readings, rows_used, *, scan, chunk,
              seconds) -> MapsResult:
    """The texels' fits as maps: values, standard errors, fit error, status codes."""
    from fitlab.fitting.joint import coordinate_name

    model, options, fixed, notes, loss, _ = setup
    H, W = stack.shape
    C = len(stack.channel_names)
    T = H * W
    free = [p.name for p in model.parameters if p.name not in fixed]
    share = request.share
    width = {p: (1 if (p in share or C == 1) else C) for p in free}
    values = {p: np.full((T, width[p]), np.nan) for p in free}
    stderr = {p: np.full((T, width[p]), np.nan) for p in free}
    status = np.where(no_data, Status.NO_DATA.code, 0).astype(np.int32)
    fitted = np.zeros((T, C), dtype=bool)
    statuses = {}
    for (t, c), (problem, names, native, err, stopped, at_bound) in fits.items():
        chans = range(C) if c is None else [c]
        for ch in chans:
            for p in free:
                key = coordinate_name(p, stack.channel_names[ch]) if (
                    c is None and p not in share) else p
                k = names.index(key)
                col = 0 if width[p] == 1 else ch
                values[p][t, col] = native[k]
                stderr[p][t, col] = err[k]
            fitted[t, ch] = True
        how = (stopped, tuple(at_bound), names)  # a few distinct ones over the texels
        if how not in statuses:
            found = channel_statuses({"solver": {"stopped": stopped},
                                      "parameters": {nm: {"at_bound": nm in at_bound}
                                                     for nm in names}})
            statuses[how] = [s for s in found if not s.ok]
        bad = statuses[how]
        if bad and status[t] == 0:
            status[t] = bad[0].code
    rms = _fit_errors(stack, model, options, fixed, values, width, fitted, rows_used, readings)
    shape2 = (H, W)
    out_vals = {p: values[p].reshape(H, W, width[p]) for p in free}
    out_err = {p: stderr[p].reshape(H, W, width[p]) for p in free}
    settings = {"fix": dict(request.fix), "free": list(request.free),
                "options": dict(request.options), "loss": loss,
                "subset": request.subset if isinstance(request.subset, str) else None,
                "share": list(share), "starts": request.starts, "scan": int(scan),
                "seed": request.seed, "lm_maxiter": request.lm_maxiter, "chunk": int(chunk)}
    return MapsResult(model.name, dict(options), dict(fixed), tuple(stack.channel_names),
                      out_vals, out_err, tuple(share), rms.reshape(H, W, C),
                      status.reshape(shape2), settings, stack, list(notes), seconds)


def _fit_errors(stack, model, options, fixed, values, width, fitted, rows_used, readings):
    """(texels, C) the fit error of each fitted texel and channel (fitlab.metrics: the RMS
    relative error over its fitted rows, rows below 1% of their incidence's peak left out);
    the predictions are one jitted call per PREDICT_CHUNK texels, all on the stack's
    directions."""
    from fitlab.fitting.space import model_kernel
    from fitlab.metrics import fit_error_rms_many

    T, C = fitted.shape
    n = stack.n_images
    wi, wo = stack.directions()
    kernel = model_kernel(model, tuple(sorted(options.items())))
    out = np.full((T, C), np.nan)
    block = min(PREDICT_CHUNK, T)
    for c in range(C):
        sel = slice(c * n, (c + 1) * n)
        for a in range(0, T, block):
            idx = np.arange(a, min(a + block, T))
            pad = np.concatenate([idx, np.full(block - idx.size, idx[0])])
            params = {k: np.float64(v) for k, v in fixed.items()}
            for p, arr in values.items():
                col = arr[pad, 0 if width[p] == 1 else c]
                params[p] = np.nan_to_num(col, nan=_default(model, p))[:, None]
            pred = np.asarray(kernel(params, wi[None], wo[None]))[:idx.size]
            rms = fit_error_rms_many(pred, readings[idx, sel], rows_used[idx, sel],
                                     stack.theta_i, stack.phi_i)
            out[idx, c] = np.where(fitted[idx, c], rms, np.nan)
    return out


def _default(model, name):
    return next(p.default for p in model.parameters if p.name == name)


# ------------------------------------------------------------------------------------------
# The glTF hand-off: glTF's BRDF fitted to every texel's material (fitlab/export/gltf_maps.py
# writes it)
# ------------------------------------------------------------------------------------------

#: Every this-many-th reflection pair of fitlab export's glTF conversion pairs.
GLTF_PAIR_STRIDE = 3
#: Texel fits of the conversion per compiled call (each has a few thousand rows).
GLTF_CHUNK = 64


def convert_to_gltf(result, *, chunk: int | None = None, progress: bool = False):
    """(the conversion's MapsResult, None), or (None, why not): glTF's BRDF (``gltf_pbr``)
    fitted to every fitted texel of ``result``, as a map fit of a synthetic stack: each texel's
    material at every GLTF_PAIR_STRIDE-th reflection pair of ``fitlab export``'s conversion
    pairs, the export's settings (log loss, ``base_color`` per channel, the rest shared,
    ``specular_color`` 1) and ``ior`` fixed at 1.5 (KHR_materials_ior has no texture);
    fitlab/export/gltf_maps.py writes it."""
    from fitlab.api import eval_bsdf
    from fitlab.export.gltf_material import candidates, conversion_pairs
    from fitlab.io.directions import direction_to_degrees
    from fitlab.io.stack import Stack
    from fitlab.models import get_model

    caps = get_model(result.model).capabilities
    if not caps.reflection:
        return None, f"{result.model} reflects nothing; glTF's material reflects"
    if candidates(caps)[0] != "gltf_pbr":
        return None, (f"{result.model} is {'transmitting' if caps.transmission else 'anisotropic'}"
                      "; the maps' glTF conversion fits glTF's core BRDF only (export a texel "
                      "with fitlab export --to gltf)")
    if result.channel_names not in (("R", "G", "B"), ("Y",)):
        return None, f"glTF takes linear RGB or grey, not channels {result.channel_names}"
    wi, wo = conversion_pairs(isotropic=caps.isotropic)
    keep = wo[:, 2] > 0
    wi, wo = wi[keep][::GLTF_PAIR_STRIDE], wo[keep][::GLTF_PAIR_STRIDE]
    H, W = result.shape
    C = len(result.channel_names)
    f = np.full((H, W, len(wi), C), np.nan, dtype=np.float32)
    for k in range(C):
        params = {p: float(v) for p, v in result.fixed.items()}
        ok = np.ones((H, W), dtype=bool)
        for p, arr in result.values.items():
            a = arr[:, :, 0 if arr.shape[2] == 1 else k]
            ok &= np.isfinite(a)
            params[p] = np.where(np.isfinite(a), a, next(
                q.default for q in get_model(result.model).parameters if q.name == p))[..., None]
        vals = np.asarray(eval_bsdf(result.model, params, wi[None, None], wo[None, None],
                                    dict(result.options)))
        vals = np.where(vals > 0, vals, np.nan)  # the log loss: a zero is no reading
        f[:, :, :, k] = np.where(ok[..., None], vals, np.nan)
    t_i, p_i = direction_to_degrees(wi)
    t_o, p_o = direction_to_degrees(wo)
    stack = Stack(f"<glTF conversion of {result.model}>", (), t_i, p_i, t_o, p_o,
                  np.arange(1, len(wi) + 1), tuple(result.channel_names), f, {}, "")
    share = ("metallic", "roughness_factor", "specular") if C > 1 else ()
    conv = fit_maps(stack, "gltf_pbr", fix={"specular_color": 1.0, "ior": 1.5}, share=share,
                    loss="log", starts=4, chunk=GLTF_CHUNK if chunk is None else chunk,
                    progress=progress)
    return conv._replace(settings={**conv.settings, "pair_stride": GLTF_PAIR_STRIDE}), None


# ------------------------------------------------------------------------------------------
# Past one process: tiles on Dask.distributed (fitlab/chunked.py runs them)
#
# ``fit_maps(..., workers=N)`` / ``fitlab fit-maps ... --workers N`` (or ``--scheduler``) fits
# the stack in tiles of image rows, as ``fitlab fit FILE ... --workers`` does with files
# (fitlab/fitting/distributed.py). A tile's identity is a hash of the stack (its table's and
# images' SHA-256), its rows and the settings, so a rerun skips the tiles already done and a
# changed image or setting fits them again. A task reads the stack, fits its rows with
# fit_maps and writes its arrays (``DIR.tiles/ID.npz``) atomically, then its record
# (``DIR.tiles/chunks/ID.json``), the commit marker; the work folder ``DIR.tiles`` sits beside
# DIR while tiles are pending. The driver waits for every tile, then writes DIR all or nothing
# (fitlab/export/maps.py) and removes the work folder.
# ------------------------------------------------------------------------------------------

#: Texels per tile when no tile size is given (rows of the image, at least one).
TEXELS_PER_TILE = 16384


def work_folder(out_dir) -> Path:
    """Where the tiles of ``out_dir``'s fit wait until the maps are written."""
    out = Path(out_dir)
    return out.parent / f"{out.name}.tiles"


def tile_settings(request, scan: int, chunk: int) -> dict:
    """The request's settings as plain values (JSON, hashing, the workers' fit_maps)."""
    if request.subset is not None and not isinstance(request.subset, str):
        raise FitlabError("the Dask runner takes the subset as an expression, not a row mask")
    return {"model": request.model.name, "fix": dict(request.fix), "free": list(request.free),
            "options": dict(request.options), "loss": request.loss, "subset": request.subset,
            "share": list(request.share), "starts": request.starts, "seed": request.seed,
            "lm_maxiter": request.lm_maxiter, "scan": int(scan), "chunk": int(chunk)}


def tile_id(settings: dict, stack_sha256: str, y0: int, y1: int) -> str:
    """A tile's identity: the stack's contents, the tile's rows and the settings."""
    from fitlab.chunked import digest

    return digest(settings, stack_sha256, int(y0), int(y1))


def _fit_tile(stack_dir: str, settings: dict, y0: int, y1: int, work: str, cid: str) -> str:
    """The task: fit rows ``y0:y1`` of the stack, write their arrays, then the marker."""
    from fitlab.io.atomic import atomic_open
    from fitlab.io.stack import read_stack

    from fitlab.chunked import marker_path, write_marker

    if marker_path(work, cid).exists():
        return cid
    stack = read_stack(stack_dir)
    part = stack._replace(values=stack.values[y0:y1])
    kw = {k: v for k, v in settings.items() if k not in ("model", "scan", "chunk")}
    res = fit_maps(part, settings["model"], scan=settings["scan"], chunk=settings["chunk"], **kw)
    arrays = {"rms": res.rms, "status": res.status}
    for p in res.values:
        arrays[f"value.{p}"] = res.values[p]
        arrays[f"stderr.{p}"] = res.stderr[p]
    (Path(work) / "chunks").mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with atomic_open(Path(work) / f"{cid}.npz", "wb") as fh:
        fh.write(buf.getvalue())
    write_marker(work, cid, {"rows": [y0, y1], "file": f"{cid}.npz", "notes": res.notes})
    return cid


def fit_maps_tiled(stack, request, out_dir, *, scan: int, chunk: int, gltf: bool = False,
                   workers: int = 2,
                   scheduler: str | None = None, tile_rows: int | None = None,
                   progress: bool = True, retries: int = 3):
    """Fit ``stack`` (a folder) in tiles on a Dask cluster (module text) and write ``out_dir``;
    returns (the MapsResult of the whole stack, the run's summary: ``tiles``, ``done_before``,
    ``fitted``)."""
    import time

    from fitlab.chunked import run_chunks
    from fitlab.export.maps import check_out_dir
    from fitlab.fitting.channel import resolve_fit
    from fitlab.io.stack import read_stack

    t0 = time.perf_counter()
    check_maps_request(request, scan=scan, chunk=chunk)
    out = check_out_dir(out_dir)
    whole = read_stack(stack)  # every input checked before any worker starts
    H, W = whole.shape
    if tile_rows is None:
        tile_rows = max(1, TEXELS_PER_TILE // W)
    if isinstance(tile_rows, bool) or not isinstance(tile_rows, int) or tile_rows < 1:
        raise FitlabError(f"--tile-rows must be an integer of at least 1, got {tile_rows!r}")
    settings = tile_settings(request, scan, chunk)
    work = work_folder(out)
    root = str(Path(stack).resolve())
    tiles = [(tile_id(settings, whole.sha256, y0, min(y0 + tile_rows, H)),
              (root, settings, y0, min(y0 + tile_rows, H))) for y0 in range(0, H, tile_rows)]
    run = run_chunks(_fit_tile, tiles, work, workers=workers, scheduler=scheduler,
                     progress=progress, retries=retries, desc="tiles")
    parts = []
    for rec in run["records"]:
        with np.load(work / rec["file"]) as z:
            parts.append({k: z[k] for k in z.files})
    cat = lambda key: np.concatenate([p[key] for p in parts], axis=0)  # noqa: E731
    names = [k[len("value."):] for k in parts[0] if k.startswith("value.")]
    setup = resolve_fit(_template(whole), request)
    result = MapsResult(request.model.name, dict(setup.options), dict(setup.fixed),
                        tuple(whole.channel_names), {p: cat(f"value.{p}") for p in names},
                        {p: cat(f"stderr.{p}") for p in names}, tuple(request.share),
                        cat("rms"), cat("status"),
                        {k: v for k, v in settings.items() if k != "model"} | {
                            "loss": setup.loss, "tiles": len(tiles), "tile_rows": tile_rows},
                        whole, list(run["records"][0]["notes"]), time.perf_counter() - t0)
    _write(result, out, gltf, progress_line(request), request.progress)
    shutil.rmtree(work, ignore_errors=True)
    return result, {"tiles": run["chunks"], "done_before": run["done_before"],
                    "fitted": run["done_now"]}


__all__ = ["fit_maps", "check_maps_request", "MapsResult", "MAPS_DEFAULTS", "TEXELS_PER_TILE",
           "work_folder", "tile_settings", "tile_id", "fit_maps_tiled", "convert_to_gltf",
           "GLTF_PAIR_STRIDE", "GLTF_CHUNK"]
