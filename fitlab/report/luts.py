"""Lookup tables exported for a fit (``fitlab lut ... --from-fit FIT.json``, OpenEXR, read with
``fitlab.export.exr.read_exr``): which tables belong to the fit, a preview of each and its
measured accuracy figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import LogNorm, Normalize

from fitlab.errors import InputFileError
from fitlab.report.style import CMAP_VALUES, new_figure, styled

#: At most this many channels are previewed per table (every one is in the accuracy table).
MAX_CHANNELS = 4


def _same_file(a, b) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def source_fit_path(lut_path, source_fit: str) -> Path:
    """The parameter file a table's ``fitlab.source_fit`` names: relative to the table's folder
    (as fitlab writes it), else (tables of older versions) as given."""
    src = Path(source_fit)
    if src.is_absolute():
        return src
    beside = Path(lut_path).parent / src
    return beside if beside.exists() or not src.exists() else src


def lut_belongs(info: dict, fit_path, fit_sha256: str, lut_path) -> bool:
    """Whether an EXR header (``describe_exr``) of the table ``lut_path`` names this fit: its
    ``source_fit_sha256`` equals the fit file's, or (without a hash) its ``source_fit`` is the
    same file."""
    sha = info.get("source_fit_sha256")
    if sha:
        return sha == fit_sha256
    src = info.get("source_fit")
    return bool(src) and _same_file(source_fit_path(lut_path, src), fit_path)


def discover_luts(fit_path) -> list:
    """``*.exr`` files beside the fit file whose header names it (sorted by name)."""
    from fitlab.export.exr import describe_exr, is_exr
    from fitlab.io.files import sha256_of

    fit_path = Path(fit_path)
    sha = sha256_of(fit_path)
    found = []
    for p in sorted(fit_path.resolve().parent.glob("*.exr")):
        if not is_exr(p):
            continue
        try:
            info = describe_exr(p)
        except InputFileError:
            continue  # not a fitlab table: not ours to judge here
        if lut_belongs(info, fit_path, sha, p):
            found.append(p)
    return found


def check_lut(path, fit_path):
    """Read and validate an EXR given with ``--lut``; (table, note) where note says when the
    table was not baked from this fit. A table baked from another fit is an error."""
    from fitlab.export.exr import describe_exr, read_exr
    from fitlab.io.files import sha256_of

    table = read_exr(path)
    info = describe_exr(path)
    sha = info.get("source_fit_sha256")
    if table.source_fit:
        src = source_fit_path(path, table.source_fit)
        if (sha and sha != sha256_of(fit_path)) or (not sha and not _same_file(src, fit_path)):
            raise InputFileError(path, f"was baked from the fit {src}, not from "
                                 f"{fit_path}", column="fitlab.source_fit",
                                 hint="give the tables baked with `fitlab lut ... --from-fit "
                                 f"{fit_path}`")
        return table, None
    return table, "baked from a model and parameters, not from this fit's parameter file"


def _ticks(ax, axis, which):
    t = np.linspace(0.0, 1.0, 5)
    labels = [f"{x:.3g}" for x in axis.to_x(t)]
    (ax.set_xticks if which == "x" else ax.set_yticks)(t, labels)
    label = f"{axis.name} ({axis.mapping} axis)"
    (ax.set_xlabel if which == "x" else ax.set_ylabel)(label)


def _norm(v):
    pos = v[v > 0]
    if pos.size == v.size and pos.size and pos.max() / pos.min() > 100.0:
        return LogNorm(pos.min(), pos.max()), "log"
    lo, hi = float(v.min()), float(v.max())
    return Normalize(lo, hi if hi > lo else lo + 1.0), "linear"


@styled
def lut_figure(values, channels, axes, *, title: str):
    """Preview of a table: a line per channel (1 axis); a colour image per channel in texture
    coordinates with the axis values as tick labels (2 axes); the first, middle and last slice
    of the third axis per channel (3 axes). ``values`` (H, W, C) as stored. Returns a Figure."""
    values = np.asarray(values, float)
    chans = list(range(min(len(channels), MAX_CHANNELS)))
    if len(axes) == 1:
        fig = new_figure(6.0, 3.4)
        ax = fig.add_subplot()
        x = axes[0].nodes()
        for c in chans:
            ax.plot(x, values[0, :, c], lw=1.3, label=channels[c])
        ax.set_xlabel(f"{axes[0].name} ({axes[0].mapping} axis, {axes[0].size} samples)")
        ax.set_ylabel("table value")
        ax.legend(frameon=False)
        ax.set_title(title)
        return fig
    n1 = axes[1].size
    slices = [(None, values)] if len(axes) == 2 else [
        (j, values[j * n1:(j + 1) * n1]) for j in sorted({0, axes[2].size // 2, axes[2].size - 1})]
    nrow, ncol = len(slices), len(chans)
    fig = new_figure(3.3 * ncol + 0.6, 3.0 * nrow + 0.5)
    grid = fig.subplots(nrow, ncol, squeeze=False)
    for r, (j, v) in enumerate(slices):
        for c in chans:
            ax = grid[r, c]
            img = v[:, :, c]
            norm, kind = _norm(img)
            im = ax.imshow(img, origin="lower", extent=(0, 1, 0, 1), aspect="auto", norm=norm,
                           cmap=CMAP_VALUES, interpolation="nearest")
            _ticks(ax, axes[0], "x")
            _ticks(ax, axes[1], "y")
            ax.grid(False)
            sub = "" if j is None else f", {axes[2].name} = {axes[2].nodes()[j]:.3g}"
            ax.set_title(f"{channels[c]}{sub}", fontsize=8.5)
            fig.colorbar(im, ax=ax, shrink=0.85, label=f"value ({kind} colour scale)")
    fig.suptitle(title, fontsize=9.5)
    return fig


def accuracy_rows(accuracy: dict) -> list:
    """[metric, max rel, RMS rel, what it is measured against] from a table's accuracy record."""
    rows = []
    for key in sorted(k for k, v in accuracy.items() if isinstance(v, dict)):
        rec = accuracy[key]
        if "candidates" in rec:  # axes chosen by measurement: one row per candidate table
            for c in rec["candidates"]:
                chosen = " (chosen)" if c.get("size") == rec.get("chosen") else ""
                rows.append([f"{key}: {rec.get('check', '')} of the {c.get('size')} "
                             f"candidate{chosen}", c.get("max_rel"), c.get("rms_rel"),
                             rec.get("reason", "")])
            continue
        what = rec.get("reference") or rec.get("dtype") or rec.get("method") or ""
        if "points" in rec:
            what = f"{what} ({rec['points']} points)".strip()
        if "max_rel" not in rec and "max_abs_error_estimate" in rec:
            rows.append([f"{key} (absolute error estimate, not relative)",
                         rec["max_abs_error_estimate"], None, what])
        else:
            rows.append([key, rec.get("max_rel"), rec.get("rms_rel"), what])
        for ch, sub in sorted((rec.get("per_channel") or {}).items()):
            if len(rec["per_channel"]) > 1:
                rows.append([f"{key}: {ch}", sub.get("max_rel"), sub.get("rms_rel"), ""])
    return rows
