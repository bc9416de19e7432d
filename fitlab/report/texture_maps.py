"""The report of a map fit (``fitlab report DIR --out R`` where DIR is a ``fitlab fit-maps``
folder, data_formats/stack.md): each parameter's map with a colour bar in its unit, its standard
error, the fit error and status maps, histograms, and a few texels' readings against the fitted
model. One self-contained ``index.html`` with the figures beside it (PNG and SVG), written
as every fitlab report is: in memory first, then atomically, ``index.html`` last; the same
folder gives the same bytes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.ticker import MaxNLocator

from fitlab.errors import FitlabError, InputFileError
from fitlab.export.maps import read_maps_record
from fitlab.io.atomic import atomic_open
from fitlab.report.html import (document, note_html, paragraph, table_html)
from fitlab.report.style import CMAP_RESIDUAL, CMAP_VALUES, Figures, new_figure, styled

#: Texels whose readings are plotted against the model: the best, the median and the worst fit
#: error among the converged texels, and the first texel of each other status.
SCAN_TEXELS = 3
#: Colours of the status map: converged, then the other codes that occur.
STATUS_COLOURS = ("#2b8a3e", "#e67700", "#c92a2a", "#5f3dc4", "#868e96", "#1971c2")


def is_maps_folder(path) -> bool:
    """Whether ``path`` is a ``fitlab fit-maps`` folder (it holds maps.json)."""
    return Path(path).is_dir() and (Path(path) / "maps.json").is_file()


def _image(folder: Path, name: str, channels) -> np.ndarray:
    from fitlab.io.exr_image import image_header, read_image

    names, _ = image_header(folder / name)
    missing = [c for c in channels if c not in names]
    if missing:
        raise InputFileError(folder / name, f"lacks the channel(s) {', '.join(missing)} that "
                             "maps.json lists", column="channels")
    return read_image(folder / name, tuple(channels)).astype(float)


def _unit(unit: str) -> str:
    return "dimensionless" if unit in ("1", "") else unit


@styled
def _map_figure(arrays, titles, label, *, cmap=CMAP_VALUES, log=False):
    """A row of texel maps (one per channel), each with its colour bar labelled ``label``."""
    from matplotlib.colors import LogNorm

    fig = new_figure(3.0 * len(arrays) + 0.4, 2.9)
    axes = fig.subplots(1, len(arrays), squeeze=False)[0]
    for ax, a, title in zip(axes, arrays, titles):
        finite = a[np.isfinite(a)]
        norm = None
        if log and finite.size and np.all(finite > 0) and finite.max() > finite.min():
            norm = LogNorm(finite.min(), finite.max())
        im = ax.imshow(np.ma.masked_invalid(a), cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_title(title)
        _texel_axes(ax)
        fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    return fig


def _texel_axes(ax):
    ax.set_xlabel("x (texel)")
    ax.set_ylabel("y (texel)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(False)


@styled
def _status_figure(status, codes):
    present = sorted(int(c) for c in np.unique(status))
    colours = [STATUS_COLOURS[min(k, len(STATUS_COLOURS) - 1)] for k in range(len(present))]
    index = np.searchsorted(present, status.astype(int))
    fig = new_figure(4.2, 3.0)
    ax = fig.subplots()
    im = ax.imshow(index, cmap=ListedColormap(colours),
                   norm=BoundaryNorm(np.arange(len(present) + 1) - 0.5, len(present)),
                   interpolation="nearest")
    bar = fig.colorbar(im, ax=ax, ticks=range(len(present)), shrink=0.85)
    bar.ax.set_yticklabels([f"{c} {codes.get(str(c), '?')}" for c in present])
    ax.set_title("status per texel")
    _texel_axes(ax)
    return fig


@styled
def _histograms(series):
    """One histogram per (title, values, unit)."""
    fig = new_figure(3.0 * len(series), 2.5)
    axes = fig.subplots(1, len(series), squeeze=False)[0]
    for ax, (title, values, unit) in zip(axes, series):
        v = values[np.isfinite(values)]
        ax.hist(v, bins=min(40, max(5, int(np.sqrt(v.size)) + 1)) if v.size else 5,
                color="#4a7ab5")
        ax.set_title(title)
        ax.set_xlabel(_unit(unit))
        ax.set_ylabel("texels")
    return fig


@styled
def _scan_figure(rows, readings, preds, title):
    """A texel's readings (markers) and the fitted model (line) per image, images ordered by
    (θi, θo, φo); one curve per channel."""
    order = np.lexsort((rows[:, 3], rows[:, 2], rows[:, 0]))
    fig = new_figure(6.4, 3.3)
    ax = fig.subplots()
    x = np.arange(len(order))
    for name, data, pred, colour in zip(readings, readings.values(), preds.values(),
                                        ("#c92a2a", "#2b8a3e", "#1971c2", "#333333")):
        ax.plot(x, data[order], "o", ms=3.5, color=colour, label=f"{name} readings")
        ax.plot(x, pred[order], "-", lw=1.0, color=colour, label=f"{name} model")
    ax.set_yscale("log")
    ticks = [k for k in range(len(order)) if k == 0 or rows[order[k], 0] != rows[order[k - 1], 0]]
    ax.set_xticks(ticks, [f"θi {rows[order[k], 0]:g}°" for k in ticks])
    ax.set_xlabel("images, by θi then θo, φo")
    ax.set_ylabel("f (1/sr)")
    ax.set_title(title)
    ax.legend(fontsize=6.5, ncols=len(readings), loc="upper center",
              bbox_to_anchor=(0.5, -0.28), frameon=False)
    return fig


def _texels(status, rms):
    """(y, x, why) of the texels whose readings are plotted."""
    out = []
    ok = (status == 0) & np.isfinite(rms)
    if ok.any():
        flat = np.where(ok, rms, np.nan)
        order = np.argsort(np.where(np.isfinite(flat), flat, np.inf), axis=None, kind="stable")
        order = order[:int(ok.sum())]
        for why, k in (("smallest fit error", order[0]), ("median fit error",
                                                           order[len(order) // 2]),
                       ("largest fit error", order[-1]))[:SCAN_TEXELS]:
            y, x = np.unravel_index(k, rms.shape)
            if (y, x, why) not in out:
                out.append((int(y), int(x), why))
    for code in sorted(int(c) for c in np.unique(status) if c != 0):
        y, x = np.argwhere(status == code)[0]
        out.append((int(y), int(x), f"first texel of status code {code}"))
    return out


def _scans(figs, folder, rec, values, channels, status, rms):
    """The texel scans: the stack read again (maps.json names it), the model at its images."""
    from fitlab.api import eval_bsdf
    from fitlab.io.stack import read_stack

    stack_dir = (folder / rec["stack"]["folder"]).resolve()
    try:
        stack = read_stack(stack_dir)
    except InputFileError as exc:
        return note_html(f"No texel scans: the stack could not be read ({exc}).")
    if stack.sha256 != rec["stack"]["sha256"]:
        return note_html(f"No texel scans: the stack at {rec['stack']['folder']} is not the one "
                         "fitted (its SHA-256 differs).")
    wi, wo = stack.directions()
    rows = np.stack([stack.theta_i, stack.phi_i, stack.theta_o, stack.phi_o], axis=1)
    body = []
    worst = np.nanmax(np.where(np.isfinite(rms), rms, -np.inf), axis=2) if rms.size else rms
    for y, x, why in _texels(status, worst):
        readings, preds = {}, {}
        for k, c in enumerate(channels):
            params = dict(rec["fixed"])
            for p, arr in values.items():
                params[p] = float(arr[y, x, 0 if arr.shape[2] == 1 else k])
            readings[c] = stack.values[y, x, :, k].astype(float)
            preds[c] = (np.full(len(rows), np.nan) if not all(np.isfinite(list(params.values())))
                        else np.asarray(eval_bsdf(rec["model"], params, wi, wo, rec["options"])))
        err = ", ".join(f"{c} {rms[y, x, k]:.3g}" for k, c in enumerate(channels)
                        if np.isfinite(rms[y, x, k]))
        title = f"texel (x={x}, y={y}): {why}" + (f"; fit error {err}" if err else "")
        body.append(figs.add(f"texel_{x}_{y}", _scan_figure(rows, readings, preds, title),
                             f"Texel (x={x}, y={y}), {why}: its readings in every image of the "
                             "stack (markers; NaN readings absent) against the fitted model "
                             "(lines), per channel.", f"readings and model at texel {x}, {y}"))
    return "".join(body)


@styled
def _render_figure(r):
    """Per rendered stack row: the input image, three.js's render of the glTF (both f in 1/sr,
    the mean over the channels, one colour scale) and their relative difference."""
    n = len(r.rows)
    fig = new_figure(10.2, 2.9 * n)
    axes = fig.subplots(n, 3, squeeze=False)
    diff = r.relative_difference()
    for k in range(n):
        t_i, p_i, t_o, p_o = r.angles[k]
        where = f"row {r.rows[k]}: θi {t_i:g}°, φi {p_i:g}°, θo {t_o:g}°, φo {p_o:g}°"
        inp = r.input[:, :, k].mean(axis=-1)  # NaN where a channel has no reading
        ren = r.render[:, :, k].mean(axis=-1)
        both = np.concatenate([inp[np.isfinite(inp)], ren[np.isfinite(ren)]])
        lo, hi = (both.min(), both.max()) if both.size else (0.0, 1.0)
        d = diff[:, :, k].mean(axis=-1)
        lim = max(float(np.nanmax(np.abs(d))) if np.isfinite(d).any() else 0.0, 1e-3)
        for ax, a, title, cmap, (vmin, vmax), label in (
                (axes[k, 0], inp, f"input, {where}", CMAP_VALUES, (lo, hi), "f (1/sr)"),
                (axes[k, 1], ren, f"three.js render / cos θi, row {r.rows[k]}", CMAP_VALUES,
                 (lo, hi), "f (1/sr)"),
                (axes[k, 2], d, f"(render - input) / input, row {r.rows[k]}", CMAP_RESIDUAL,
                 (-lim, lim), "relative difference")):
            im = ax.imshow(np.ma.masked_invalid(a), cmap=cmap, vmin=vmin, vmax=vmax,
                           interpolation="nearest")
            ax.set_title(title, fontsize=7.5)
            _texel_axes(ax)
            fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    return fig


def _threejs_section(figs, folder, rec):
    """The glTF hand-off rendered by three.js beside the input images
    (fitlab/export/gltf_maps_render.py), or why it is not."""
    from fitlab.export import threejs
    from fitlab.export.gltf_maps_render import gltf_handoff, render_maps_gltf

    gltf, why = gltf_handoff(folder, rec)
    if gltf is None:
        return note_html(f"No three.js render: {why}.")
    lacks = threejs.missing()
    if lacks:
        return note_html(f"The three.js render of material.gltf was skipped: {lacks} (install "
                         f"{threejs.INSTALL}).")
    try:
        r = render_maps_gltf(folder, record=rec)
    except FitlabError as exc:  # RenderError, a stack that is not the one fitted ...
        return note_html(f"The three.js render of material.gltf was skipped: {exc}")
    med = r.median_relative_difference()
    body = figs.add("threejs_render", _render_figure(r), (
        f"material.gltf (the glTF hand-off) rendered by three.js r{r.three} in headless "
        f"Chromium under the capture's own geometry, for {len(r.rows)} rows of the stack (near "
        "normal, middle, grazing): a directional light of irradiance 1 from wi, an orthographic "
        f"camera from wo, {r.size} × {r.size} float pixels, no tone mapping; the render "
        "resampled to the texel grid (each texel's centre projected by the camera) and divided "
        "by cos θi, so both it and the input are f in 1/sr (shown: the mean over the channels, "
        "one colour scale per row). Right: the relative difference (mean over the channels), "
        "blank where the input has no reading. It holds the map fit's error, the glTF "
        "conversion's (gltf/conversion_rms.exr) and three.js's departures from glTF's "
        "specification (tests/browser/README.md). Median |relative difference| per row: "
        + ", ".join(f"row {i} {m:.3g}" for i, m in zip(r.rows, med)) + "."),
        "input images, three.js renders of the glTF and their relative difference")
    d = np.abs(r.relative_difference())
    rows = []
    for k, i in enumerate(r.rows):
        per = [np.median(v[np.isfinite(v)]) if np.isfinite(v).any() else np.nan
               for v in (d[:, :, k, c] for c in range(d.shape[3]))]
        rows.append([str(i), ", ".join(f"{a:g}°" for a in r.angles[k]), f"{med[k]:.3g}"]
                    + [f"{v:.3g}" for v in per])
    body += table_html(["row", "θi, φi, θo, φo", "median |rel. diff.|"]
                       + [f"median, {c}" for c in r.channels], rows,
                       numeric=tuple(range(2, 3 + len(r.channels))))
    return body


def build_maps_report(folder, out_dir, *, progress: bool = True) -> dict:
    """Write ``out_dir/index.html`` and its figures for the map fit in ``folder``; returns a
    summary (``files``, ``figures``, ``index``) as ``build_report`` does."""
    folder = Path(folder)
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    rec = read_maps_record(folder)
    channels = rec["stack"]["channels"]
    figs = Figures(say)
    values, sections = {}, []
    for p, spec in rec["parameters"].items():
        values[p] = _image(folder, spec["file"], spec["channels"])
        std = _image(folder, spec["stderr_file"], spec["channels"])
        unit = _unit(spec["unit"])
        shared = " (shared by the channels)" if spec["shared"] else ""
        body = figs.add(f"map_{p}", _map_figure(
            [values[p][..., k] for k in range(len(spec["channels"]))],
            [f"{p}, channel {c}" for c in spec["channels"]], f"{p} ({unit})"),
            f"{p}{shared}: {spec['description']}, per texel, in {unit} (range "
            f"[{spec['lower']:g}, {spec['upper']:g}]); blank where the texel was not fitted.",
            f"map of {p}")
        body += figs.add(f"map_{p}_std", _map_figure(
            [std[..., k] for k in range(len(spec["channels"]))],
            [f"standard error of {p}, {c}" for c in spec["channels"]],
            f"standard error ({unit})", log=True),
            f"Standard error of {p} per texel (least squares), {unit}, logarithmic colours.",
            f"map of the standard error of {p}")
        sections.append((f"param-{p}", f"{p}{shared}", body))
    rms = _image(folder, rec["rms"]["file"], rec["rms"]["channels"])
    status = _image(folder, rec["status"]["file"], ["Y"])[..., 0].astype(int)
    codes = rec["status"]["codes"]
    body = figs.add("map_rms", _map_figure(
        [rms[..., k] for k in range(rms.shape[2])],
        [f"fit error, {c}" for c in rec["rms"]["channels"]], "RMS relative error", log=True),
        "The fit error per texel and channel: " + rec["rms"]["definition"] + ".",
        "map of the fit error")
    body += figs.add("map_status", _status_figure(status, codes),
                     "The status per texel (maps.json's codes): "
                     + "; ".join(f"{codes[str(c)]}: {n} texels" for c, n in
                                 ((int(c), int((status == c).sum())) for c in np.unique(status)))
                     + ".", "map of the status codes")
    body += table_html(["status", "code", "texels"],
                       [[s, next(k for k, v in codes.items() if v == s), str(n)]
                        for s, n in rec["status"]["counts"].items()], numeric=(1, 2))
    sections.append(("errors", "Fit error and status", body))
    series = [(f"{p} {c}", values[p][..., k].ravel(), rec["parameters"][p]["unit"])
              for p in values for k, c in enumerate(rec["parameters"][p]["channels"])]
    series += [(f"fit error {c}", rms[..., k].ravel(), "RMS relative error")
               for k, c in enumerate(rec["rms"]["channels"])]
    hist = "".join(figs.add(f"histograms_{j}", _histograms(series[j:j + 4]),
                            "Histograms over the fitted texels.", "histograms")
                   for j in range(0, len(series), 4))
    sections.append(("histograms", "Histograms", hist))
    sections.append(("texels", "Texels against their readings",
                     _scans(figs, folder, rec, values, channels, status, rms)))
    sections.append(("threejs", "The glTF hand-off in three.js",
                     _threejs_section(figs, folder, rec)))
    mitsuba = rec["handoff"]["mitsuba"]
    prov = table_html([], [
        ["model", rec["model"]], ["options", json.dumps(rec["options"])],
        ["fixed", json.dumps(rec["fixed"])], ["settings", json.dumps(rec["settings"])],
        ["stack", f"{rec['stack']['folder']} ({rec['stack']['width']} x "
                  f"{rec['stack']['height']} texels, {rec['stack']['images']} images, "
                  f"channels {' '.join(channels)}; SHA-256 {rec['stack']['sha256']})"],
        ["Mitsuba 3", mitsuba.get("scene") or mitsuba.get("reason", "")],
        ["glTF 2.0", rec["handoff"]["gltf"].get("reason", "")],
        ["fitlab", rec["version"]]])
    sections.append(("provenance", "Fit, stack and provenance", prov))
    counts = rec["status"]["counts"]
    n = sum(counts.values())
    finite = rms[np.isfinite(rms)]
    lead = paragraph(
        f"{rec['model']} fitted to {n} texels of {rec['stack']['images']} images: "
        + ", ".join(f"{v} {k}" for k, v in counts.items())
        + (f"; median fit error {np.median(finite):.3g}" if finite.size else "") + ".")
    title = f"Map fit report: {rec['model']} on {Path(rec['stack']['folder']).name}"
    names = [f"{f.name}.{ext}" for f in figs.entries for ext in ("png", "svg")]
    page = document(title, sections, files=sorted(names), lead=lead)
    files = {f"{f.name}.{ext}": getattr(f, ext) for f in figs.entries for ext in ("png", "svg")}
    files["index.html"] = page.encode("utf-8")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FitlabError(f"--out {out}: is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    for name in sorted(files, key=lambda n: (n == "index.html", n)):
        with atomic_open(out / name, "wb") as fh:
            fh.write(files[name])
    say(f"report: wrote {out / 'index.html'} and {len(figs.entries)} figures (PNG + SVG)")
    return {"files": sorted(files), "figures": [f.name for f in figs.entries],
            "index": str(out / "index.html")}


__all__ = ["is_maps_folder", "build_maps_report"]
