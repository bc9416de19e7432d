"""Figure of the LUT accuracy study (benchmarks/lut_accuracy.py): for each table kind, the
maximum and RMS relative error of the table read as a shader reads it, against direct
evaluation, versus the file size, per axis mapping and channel type."""

from __future__ import annotations

from pathlib import Path

from fitlab.report.style import new_figure, render, styled

_MARKERS = {"half": "o", "float": "s"}


@styled
def lut_accuracy_figure(rows, path_png) -> Path:
    """``rows``: dicts with kind, label (what varies besides size), dtype, size_bytes, max_rel,
    rms_rel. Writes a PNG (and an SVG beside it); returns the PNG path."""
    kinds = list(dict.fromkeys(r["kind"] for r in rows))
    ncol = min(3, len(kinds))
    nrow = (len(kinds) + ncol - 1) // ncol
    fig = new_figure(3.6 * ncol, 2.9 * nrow)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for ax, kind in zip(axes.ravel(), kinds):
        sub = [r for r in rows if r["kind"] == kind]
        labels = list(dict.fromkeys(r["label"] for r in sub))
        colors = {lab: f"C{i}" for i, lab in enumerate(labels)}
        for lab in labels:
            for dtype, marker in _MARKERS.items():
                pts = sorted((r["size_bytes"], r["max_rel"], r["rms_rel"]) for r in sub
                             if r["label"] == lab and r["dtype"] == dtype)
                if not pts:
                    continue
                x = [p[0] for p in pts]
                ax.plot(x, [max(p[1], 1e-8) for p in pts], marker=marker, color=colors[lab],
                        ls="-", lw=1, ms=4, label=f"{lab}, {dtype}, max")
                ax.plot(x, [max(p[2], 1e-8) for p in pts], marker=marker, color=colors[lab],
                        ls=":", lw=1, ms=3, mfc="none", label=f"{lab}, {dtype}, RMS")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(kind)
        ax.set_xlabel("EXR file size (bytes)")
        ax.set_ylabel("relative error vs direct evaluation (1)")
        ax.legend(fontsize=5.5, ncol=1, loc="best")
    for ax in axes.ravel()[len(kinds):]:
        ax.set_visible(False)
    fig.suptitle("LUT accuracy: lookup as in the shader vs direct evaluation "
                 "(solid: max, dotted: RMS; o half, s float)", fontsize=9)
    png, svg = render(fig)
    path_png = Path(path_png)
    path_png.write_bytes(png)
    path_png.with_suffix(".svg").write_bytes(svg)
    return path_png


__all__ = ["lut_accuracy_figure"]
