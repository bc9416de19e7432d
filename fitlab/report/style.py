"""matplotlib set-up for every report figure: the Agg backend, Figures made without pyplot (no
display, no global figure registry), one house style, and deterministic PNG/SVG bytes."""

from __future__ import annotations

import io
import textwrap

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


def title_room(fig: Figure) -> list:
    """[(title Text, the width in pixels it may take)] of a laid-out figure: an axes' titles
    (centre, left, right) the width of their axes, the figure's suptitle the figure's width
    less a margin."""
    out = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        width = ax.get_window_extent().width
        out += [(t, width) for t in (ax.title, ax._left_title, ax._right_title)
                if t.get_text()]
    sup = getattr(fig, "_suptitle", None)
    if sup is not None and sup.get_text():
        out.append((sup, fig.bbox.width * 0.98))
    return out


def fit_titles(fig: Figure, dpi: float = PNG_DPI, laid_out: bool = False) -> bool:
    """Wrap every title that is wider than its room (:func:`title_room`, less 2%) onto more
    lines, so no title is cut at the figure's edges or runs past its axes; the layout engine
    then makes room for the extra lines. Measured at the PNG's resolution: hinted text is not
    proportional to the dpi. ``laid_out``: the figure was just drawn (its axes have their final
    widths), so it is not laid out again here. Returns whether a title was wrapped."""
    previous = fig.dpi
    fig.set_dpi(dpi)
    wrapped = False
    try:
        if not laid_out:
            fig.draw_without_rendering()  # lays the figure out: the axes' final widths
        renderer = fig._get_renderer()
        for text, room in title_room(fig):
            room *= 0.98
            words = " ".join(text.get_text().split())
            width = text.get_window_extent(renderer).width
            if width <= room:
                continue
            wrapped = True
            n = max(10, int(len(words) * room / width))
            while True:
                text.set_text(textwrap.fill(words, n, break_on_hyphens=False))
                if n <= 10 or text.get_window_extent(renderer).width <= room:
                    break
                n -= max(1, n // 12)
    finally:
        fig.set_dpi(previous)
    return wrapped


def _png(fig: Figure) -> bytes:
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=PNG_DPI, metadata={"Software": None})
    return png.getvalue()


def render(fig: Figure) -> tuple[bytes, bytes]:
    """(PNG bytes, SVG bytes) of ``fig``, identical for identical figures: no dates, no software
    version in the metadata, a fixed SVG hash salt. Titles wider than their axes (or the
    figure) are wrapped (:func:`fit_titles`), measured on the PNG's own layout: the PNG is
    drawn again only when one was."""
    with matplotlib.rc_context(RC):
        png = _png(fig)
        if fit_titles(fig, laid_out=True):
            png = _png(fig)  # laid out again, with room for the wrapped lines
        # The PNG's draw placed every axes; keep those positions rather than lay out again.
        fig.set_layout_engine("none")
        svg = io.BytesIO()
        fig.savefig(svg, format="svg", dpi=PNG_DPI, metadata={"Date": None, "Creator": None})
    return png, svg.getvalue()


def styled(fn):
    """Decorator: build the figure under the report's rcParams (they apply when artists are made)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with matplotlib.rc_context(RC):
            return fn(*args, **kwargs)

    return wrapper


class Figures:
    """A report's figures, rendered as they are added (:func:`render`: PNG and SVG), each
    returned as its HTML (fitlab.report.html.figure_html); ``say`` reports each one."""

    def __init__(self, say):
        self.entries: list = []
        self.say = say

    def add(self, name, fig, caption, alt, half=False) -> str:
        from fitlab.report.html import FigureEntry, figure_html

        png, svg = render(fig)
        fig.clear()
        entry = FigureEntry(name, caption, alt, png, svg)
        self.entries.append(entry)
        self.say(f"report: figure {len(self.entries)}: {name}.png")
        return figure_html(entry, half)
