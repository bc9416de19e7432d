"""Registry models and fits tabulated as Zemax / Radiant IS-BSDF files (``.bsdf``): the grid
(standard or another file's angles), the values and the TIS of every block by importance
sampling. The file text itself is :func:`fitlab.io.zemax.format_zemax`; spec and angle
conventions: data_formats/zemax_bsdf.md."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fitlab.api import eval_bsdf, sample_bsdf
from fitlab.models import get_model
from fitlab.api import check_params, resolve_options
from fitlab.errors import FitlabError
from fitlab.export.paramfile import read_fit
from fitlab.io.atomic import atomic_write_text
from fitlab.io.directions import degrees_to_direction
from fitlab.io.files import path_for_record
from fitlab.io.fitfile import tabulation_channels
from fitlab.io.zemax import (DIGITS, HORIZON_EPS, SCATTER, SPEC, Grid, format_zemax,
                             incidence_angle, parse_zemax, scatter_directions, scatter_frame,
                             side_cosine)
from fitlab.version import __version__
#: incidence angles of the light in the standard grid (the AngleOfIncidence column for BRDF;
#: for BTDF the column holds their refraction angles)
STANDARD_INCIDENCE = tuple(float(x) for x in range(0, 81, 5))
STANDARD_AZIMUTH_HALF = tuple(float(x) for x in range(0, 181, 10))
#: for a model that is not isotropic (Asymmetrical files): the whole circle of azimuths, and
#: sample rotations (φi of the light in the tangent frame) every 45°
STANDARD_AZIMUTH_FULL = tuple(float(x) for x in range(0, 351, 10))
STANDARD_ROTATION_FULL = tuple(float(x) for x in range(0, 316, 45))
#: fine near the pole, out to 180° so that every AOI's whole hemisphere is covered
STANDARD_RADIAL = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0,
                   40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0, 110.0, 120.0, 130.0, 140.0, 150.0,
                   160.0, 170.0, 180.0)
#: importance samples per block for the written TIS (a square number: 256 × 256 strata)
TIS_SAMPLES = 1 << 16


def parse_angles(text, what: str) -> tuple:
    """'0,5,10' or 'START:STOP:STEP' (STOP included) → sorted angles in degrees."""
    if isinstance(text, (list, tuple, np.ndarray)):
        out = [float(x) for x in text]
    else:
        out = []
        for part in str(text).split(","):
            part = part.strip()
            try:
                if ":" in part:
                    a, b, step = (float(x) for x in part.split(":"))
                    if step <= 0 or b < a:
                        raise ValueError
                    n = int(np.floor((b - a) / step + 1e-9))
                    out += [a + k * step for k in range(n + 1)]
                else:
                    out.append(float(part))
            except ValueError:
                raise FitlabError(f"--{what} {text!r}: give angles in degrees as '0,5,10' or "
                                  "'START:STOP:STEP' (e.g. 0:80:5)") from None
    if not out or not np.all(np.isfinite(out)):
        raise FitlabError(f"--{what} {text!r}: give at least one finite angle")
    if len(set(out)) != len(out):
        raise FitlabError(f"--{what} {text!r}: an angle is listed twice")
    return tuple(sorted(out))


def resolve_grid(grid="standard", *, aoi=None, azimuth=None, radial=None, scatter="BRDF",
                 eta: float = 1.0) -> Grid:
    """The grid to write: ``grid`` is 'standard', a Grid, or a Zemax file whose angles to reuse;
    ``aoi``/``azimuth``/``radial`` (lists or '0:80:5' strings) replace its lists."""
    if grid in (None, "standard"):
        inc = np.radians(STANDARD_INCIDENCE)
        col = STANDARD_INCIDENCE if scatter == "BRDF" else \
            tuple(float(x) for x in np.degrees(np.arcsin(np.sin(inc) / eta)))
        base = Grid((0.0,), col, STANDARD_AZIMUTH_HALF, STANDARD_RADIAL)
    elif isinstance(grid, Grid):
        base = grid
    else:
        zf = parse_zemax(grid)
        base = Grid(tuple(zf.rotation), tuple(zf.aoi), tuple(zf.azimuth), tuple(zf.radial))
    g = base._replace(**{k: parse_angles(v, k) for k, v in
                         (("aoi", aoi), ("azimuth", azimuth), ("radial", radial)) if v is not None})
    for key, lo, hi, closed in (("aoi", 0, 90, False), ("azimuth", 0, 360, True),
                                ("radial", 0, 180, True)):
        bad = [v for v in getattr(g, key) if v < lo or v > hi or (v == hi and not closed)]
        if bad:
            raise FitlabError(f"--{key}: {bad[0]:g}° is outside "
                              f"[{lo}°, {hi}°{']' if closed else ')'}")
    if scatter == "BTDF":
        try:
            incidence_angle(g.aoi, scatter, eta)
        except ValueError as exc:
            raise FitlabError(f"--aoi: {exc}; for BTDF the AngleOfIncidence column is the angle "
                              "of the refracted ray") from None
    return g


def _asymmetrical_grid(model_name, g: Grid, grid, azimuth) -> Grid:
    """The grid of an anisotropic model: it is not symmetric about the plane of incidence, so
    the file is Asymmetrical (azimuths over the whole circle) and holds several sample
    rotations; the standard grid gets both, a given grid must already have them."""
    if grid in (None, "standard"):
        g = g._replace(rotation=STANDARD_ROTATION_FULL)
        if azimuth is None:
            g = g._replace(azimuth=STANDARD_AZIMUTH_FULL)
    if max(g.azimuth) <= 180.0:
        raise FitlabError(f"model {model_name!r} is anisotropic, so its BSDF is not symmetric "
                          "about the plane of incidence: give azimuths over the whole circle "
                          "(e.g. --azimuth 0:350:10) for an Asymmetrical file")
    return g


def _split_channels(params) -> dict:
    if params and all(isinstance(v, dict) for v in params.values()):
        return dict(params)
    return {"Y": dict(params)}


def _stratified_uniforms(rng, blocks: int) -> np.ndarray:
    """(blocks, TIS_SAMPLES, 3) uniforms, jittered-stratified on a square grid in the first two
    coordinates (less variance than independent samples, never more)."""
    n = int(round(np.sqrt(TIS_SAMPLES)))
    cells = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    u = rng.random((blocks, n * n, 3))
    u[..., :2] = (cells + u[..., :2]) / n
    return u


def grid_directions(grid: Grid, scatter: str, eta: float = 1.0):
    """The directions of a grid's places: wi (rotation, aoi, 3) with φi = SampleRotation, wo
    (rotation, aoi, azimuth, radial, 3), and where wo is on the scattering side (not masked);
    ``eta`` places the light of BTDF data (the AngleOfIncidence is the refracted ray's)."""
    rot, aoi = np.asarray(grid.rotation), np.asarray(grid.aoi)
    frame = scatter_frame(aoi[None, :], rot[:, None], scatter)
    wo = scatter_directions(frame[:, :, None, None], np.asarray(grid.radial)[None, :],
                            np.asarray(grid.azimuth)[:, None])
    theta_i = incidence_angle(aoi, scatter, eta)
    wi = degrees_to_direction(*np.broadcast_arrays(theta_i[None, :], rot[:, None]))
    return wi, wo, side_cosine(wo, scatter) > HORIZON_EPS


def tabulate(model_name: str, channel_params: dict, options: dict | None, grid: Grid,
             scatter: str = "BRDF", seed: int = 0):
    """Model values on the grid, (channel, rotation, aoi, azimuth, radial), 0 where wo is on
    the wrong side; and the TIS (channel, rotation, aoi) by importance sampling, with its
    standard error."""
    model = get_model(model_name)
    if scatter == "BTDF" and not model.capabilities.transmission:
        raise FitlabError(f"model {model.name!r} scatters only in reflection, so its BTDF is "
                          "zero; write a BRDF (--scatter BRDF) or choose a transmitting model")
    rng = np.random.default_rng(seed)
    values, tis, err = [], [], []
    for params in channel_params.values():
        wi, wo, good = grid_directions(grid, scatter, float(params.get("eta", 1.0)))
        shape = wo.shape[:-1]
        wi_all = np.broadcast_to(wi[:, :, None, None], shape + (3,)).reshape(-1, 3)
        f = np.asarray(eval_bsdf(model.name, params, wi_all, wo.reshape(-1, 3), options))
        values.append(np.where(good, f.reshape(shape), 0.0))
        u = _stratified_uniforms(rng, wi.shape[0] * wi.shape[1])
        wi_s = np.broadcast_to(wi.reshape(-1, 1, 3), u.shape)
        wo_s, weight, _ = sample_bsdf(model.name, params, wi_s, u, options)
        w = np.where(side_cosine(np.asarray(wo_s), scatter) > 0, np.asarray(weight), 0.0)
        tis.append(w.mean(axis=-1).reshape(wi.shape[:2]))
        err.append((w.std(axis=-1) / np.sqrt(TIS_SAMPLES)).reshape(wi.shape[:2]))
    return np.stack(values), np.stack(tis), np.stack(err)


def write_zemax(path, model: str, params: dict, options: dict | None = None, *,
                grid="standard", aoi=None, azimuth=None, radial=None, scatter: str = "BRDF",
                comments=(), digits: int = DIGITS) -> dict:
    """Tabulate a registry model as a Zemax BSDF file, atomically.

    ``params``: the model's parameters, or {channel: parameters} for channels X, Y, Z.
    ``comments``: (key, text) pairs written as '# key: text' header lines.
    Returns a summary (grid sizes, symmetry, TIS range)."""
    scatter = scatter.upper()
    if scatter not in SCATTER.values():
        raise FitlabError(f"--scatter {scatter}: choose BRDF or BTDF")
    m = get_model(model)
    options = resolve_options(m, options)
    channel_params = _split_channels(params)
    for p in channel_params.values():
        try:
            check_params(m, p)
        except ValueError as exc:
            raise FitlabError(str(exc)) from None
    etas = {float(p.get("eta", 1.0)) for p in channel_params.values()}
    if len(etas) > 1:
        raise FitlabError("the channels have different eta, so their BTDF poles differ; "
                          "write one channel at a time")
    eta = etas.pop()
    g = resolve_grid(grid, aoi=aoi, azimuth=azimuth, radial=radial, scatter=scatter, eta=eta)
    if not m.capabilities.isotropic:
        g = _asymmetrical_grid(m.name, g, grid, azimuth)
    values, tis, err = tabulate(m.name, channel_params, options, g, scatter)
    header = [f"Data generated by fitlab {__version__}: a model tabulated ({SPEC})"]
    metadata = {
        "model": m.name,
        "options": ", ".join(f"{k}={v}" for k, v in options.items()) or "none",
        **{f"parameters{'' if len(channel_params) == 1 else '_' + c}":
           ", ".join(f"{k}={v:.10g}" for k, v in p.items()) for c, p in channel_params.items()},
        **dict(comments),
        "values": "BSDF f in 1/sr without the cosine factor; 0 where the direction is below the "
                  "horizon (or in the surface plane)",
        "angles": f"ScatterRadial/ScatterAzimuth about the "
                  f"{'specular' if scatter == 'BRDF' else 'refracted'} ray; azimuth 0 toward the "
                  "normal axis, counter-clockwise seen from the detector",
        "tis": f"integral of f cos(theta_o) over the "
               f"{'reflected' if scatter == 'BRDF' else 'transmitted'} hemisphere, {TIS_SAMPLES} "
               f"stratified importance samples per block (largest standard error "
               f"{float(np.max(err)):.2g}, estimated as for independent samples: an upper bound)",
        "source_keyword": "'Measured', the only value the format defines; the values come from "
                          "a model",
    }
    if any("eta" in p for p in channel_params.values()):
        metadata.update(eta_outside=1, eta_inside=f"{eta:.10g}")
    text = format_zemax(g, tuple(channel_params), values, tis, scatter, header, metadata, digits)
    atomic_write_text(path, text)
    return {"path": str(path), "model": m.name, "scatter": scatter,
            "symmetry": "PlaneSymmetrical" if max(g.azimuth) <= 180.0 else "Asymmetrical",
            "channels": list(channel_params), "grid": {k: len(v) for k, v in g._asdict().items()},
            "tis_range": [float(tis.min()), float(tis.max())], "tis_stderr": float(err.max())}


def write_zemax_from_fit(path, fit_path, *, channel: str | None = None, **kwargs) -> dict:
    """Tabulate a fit (parameter file, data_formats/fit_json.md) as a Zemax file. A relative
    fit's ``scale`` is not applied: the file holds the absolute model f."""
    rec = read_fit(fit_path)
    fits, notes = tabulation_channels(rec, source=fit_path, channel=channel,
                                      layout=("X", "Y", "Z"), single="Y", file_kind="Zemax")
    # Both paths relative to the output's folder: no absolute path of this machine.
    data = Path(rec["data"]["path"])
    if not data.is_absolute():  # recorded relative to the fit's folder
        data = Path(fit_path).parent / data
    source = [("fit", f"{path_for_record(fit_path, path)} (data {path_for_record(data, path)}, "
                      f"channel(s) {', '.join(f['channel'] for f in rec['fits'])})")]
    source += [("note", n) for n in notes]
    comments = tuple(kwargs.pop("comments", ())) + tuple(source)
    summary = write_zemax(path, rec["model"]["name"], fits, rec["model"].get("options") or {},
                          comments=comments, **kwargs)
    summary["notes"] = notes
    return summary


def complete_zemax(path, job, *, grid=None, aoi=None, azimuth=None, radial=None,
                   scatter=None) -> dict:
    """A completion (fitlab.export.filling.Job) as a Zemax file (not written: fitlab.export.
    completion writes it with its record): on the data's own grid when the data are a Zemax
    file, else ``grid`` (default standard; --aoi/--azimuth/--radial replace lists), every
    place above the horizon the data's reading or the fit's value. The TIS lines are the data
    file's where its blocks are the output's, else the fit's (importance-sampled)."""
    from fitlab.export.filling import Filled, check_absolute, fill
    from fitlab.io.files import path_for_record

    m = job.m
    check_absolute(m, "Zemax")
    channels = tuple(m.channel_names)
    if channels not in (("Y",), ("X", "Y", "Z")) and len(channels) != 1:
        raise FitlabError(f"{Path(m.path).name} has channels {', '.join(channels)}; a Zemax "
                          "file holds one channel (Monochrome) or X, Y, Z: complete it as a "
                          "measurement CSV (OUT.csv) or OpenMATERIAL (OUT.xompt)")
    scatter = (scatter or ("BTDF" if m.metadata.get("scatter") == "btdf" else "BRDF")).upper()
    if scatter not in SCATTER.values():
        raise FitlabError(f"--scatter {scatter}: choose BRDF or BTDF")
    own = job.format == "zemax" and grid is None
    eta = m.eta() or 1.0
    g = resolve_grid(m.path if own else (grid or "standard"), aoi=aoi, azimuth=azimuth,
                     radial=radial, scatter=scatter, eta=eta)
    wi, wo, good = grid_directions(g, scatter, eta)
    shape = wo.shape[:-1]
    wi_all = np.broadcast_to(wi[:, :, None, None], shape + (3,))[good]
    values = np.zeros((len(channels),) + shape)
    parts = []
    for c in range(len(channels)):
        f = fill(job, np.full(len(wi_all), c), wi_all, wo[good])
        values[c][good] = f.value
        parts.append(f)
    filled = Filled(*(np.concatenate(a) for a in zip(*parts)))
    zf = parse_zemax(m.path) if job.format == "zemax" else None
    if zf is not None and (tuple(zf.rotation), tuple(zf.aoi)) == (g.rotation, g.aoi) \
            and zf.channels == channels:
        tis, tis_said, tis_digits = (zf.tis, f"as stored in {Path(m.path).name} (the "
                                     "instrument's)", 10)
    else:
        params = {c: {k: v for k, v in job.fit.parameters[c].items() if k != "scale"}
                  for c in channels}
        _, tis, err = tabulate(job.fit.model, params, job.fit.options, g, scatter)
        tis_said = (f"the fit's model, {TIS_SAMPLES} stratified importance samples per block "
                    f"(largest standard error {float(np.max(err)):.2g})")
        tis_digits = 4
    record = Path(str(path) + ".completion.json").name
    n = int(filled.completed.sum())
    comments = (zf.comments if zf is not None else ()) + (
        f"Completed by fitlab {__version__}: the measurement with {n} values filled in by a "
        "fit (data_formats/completion_json.md)",)
    metadata = {**(zf.metadata if zf is not None else {}),
                "completed_values": f"{n} of {filled.value.size} values above the horizon are "
                                    f"the fit's, not readings; {record} lists them and why",
                "completed_by": f"fit {path_for_record(job.fit_path, path)} (model "
                                f"{job.fit.model}) of data {path_for_record(m.path, path)}",
                "tis": tis_said}
    written = channels if channels in (("Y",), ("X", "Y", "Z")) else ("Y",)
    notes = [] if written == channels else \
        [f"channel {channels[0]} written as the file's one channel (Monochrome)"]
    text = format_zemax(g, written, values, tis, scatter, comments, metadata,
                        tis_digits=tis_digits)
    return {"content": text, "filled": filled,
            "marks": f"none in the file (a Zemax table has no per-value flag): {record}",
            "grid": {k: len(v) for k, v in g._asdict().items()},
            "grid_source": "the data's own" if own else
            ("standard" if grid in (None, "standard") else Path(str(grid)).name),
            "scatter": scatter, "notes": notes}


__all__ = ["Grid", "STANDARD_INCIDENCE", "STANDARD_AZIMUTH_HALF", "STANDARD_RADIAL",
           "TIS_SAMPLES", "parse_angles", "resolve_grid", "grid_directions", "tabulate",
           "write_zemax", "write_zemax_from_fit", "complete_zemax"]
