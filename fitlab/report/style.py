"""matplotlib set-up for every report figure: the Agg backend, Figures made without pyplot (no
display, no global figure registry), one house style, and deterministic PNG/SVG bytes."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")  # never a display, whatever MPLBACKEND says

from matplotlib.figure import Figure  # noqa: E402

#: Resolution of the PNGs (embedded in index.html and written beside it).
PNG_DPI = 90

#: Sequential, perceptually uniform map for values; diverging map (centred on 0) for residuals.
CMAP_VALUES = "viridis"
CMAP_RESIDUAL = "RdBu_r"

RC = {
    "font.size": 9.0,
    "axes.titlesize": 9.5,
    "axes.labelsize": 9.0,
    "legend.fontsize": 8.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "svg.hashsalt": "fitlab-report",  # stable element ids in SVG output
    "svg.fonttype": "path",
    "path.simplify": True,
    "image.cmap": CMAP_VALUES,
}


def new_figure(width_in: float, height_in: float, **kwargs) -> Figure:
    """A Figure attached to no display (pyplot is never imported)."""
    with matplotlib.rc_context(RC):
        return Figure(figsize=(width_in, height_in), layout="constrained", **kwargs)


def style():
    """Context manager applying the report's rcParams while a figure is drawn."""
    return matplotlib.rc_context(RC)


def render(fig: Figure) -> tuple[bytes, bytes]:
    """(PNG bytes, SVG bytes) of ``fig``, identical for identical figures: no dates, no software
    version in the metadata, a fixed SVG hash salt."""
    with matplotlib.rc_context(RC):
        png = io.BytesIO()
        fig.savefig(png, format="png", dpi=PNG_DPI, metadata={"Software": None})
        # The PNG's draw placed every axes; keep those positions rather than lay out again.
        fig.set_layout_engine("none")
        svg = io.BytesIO()
        fig.savefig(svg, format="svg", dpi=PNG_DPI, metadata={"Date": None, "Creator": None})
    return png.getvalue(), svg.getvalue()


def styled(fn):
    """Decorator: build the figure under the report's rcParams (they apply when artists are made)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with matplotlib.rc_context(RC):
            return fn(*args, **kwargs)

    return wrapper
