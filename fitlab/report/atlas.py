"""The validation atlas drawn and written up: per entry two maps over its grid (the largest
|albedo error| and the largest RMS error of f·cos over θi ≤ 80°, the 5% contour, the region
hatched, every point's value), the page ``reports/layered_atlas/README.md`` of a record
(fitlab/atlas/region.py) and the fit report's note (:func:`fit_note`)."""

from __future__ import annotations

import numpy as np

from fitlab.atlas.region import (ALBEDO_SE_LIMIT, NOISE_LIMIT, THRESHOLD, link, number_text,
                                 span_text, verdicts, within_region, worst)
from fitlab.report.style import new_figure, render, styled

#: The maps' colour scale: relative errors from this to COLOR_MAX on a log scale.
COLOR_MIN, COLOR_MAX = 0.002, 2.0


def figure_name(entry: dict) -> str:
    """The maps' file stem: the model's name with every run of other characters as '_'."""
    import re

    return re.sub(r"[^A-Za-z0-9]+", "_", entry["model"]).strip("_")


def _edges(axis: dict) -> np.ndarray:
    """Cell edges around the grid's values: midpoints (geometric on a log axis), the ends
    mirrored."""
    v = np.asarray(axis["values"], float)
    c = np.log10(v) if axis["scale"] == "log" else v
    mid = 0.5 * (c[1:] + c[:-1])
    e = np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])
    return 10.0 ** e if axis["scale"] == "log" else e


def _label(axis: dict) -> str:
    unit = axis.get("unit") or "1"
    unit = "dimensionless" if unit == "1" else unit
    return f"{axis['name']}: {axis.get('label') or axis['name']} ({unit}, {axis['scale']})"


@styled
def maps_figure(entry: dict):
    """Two panels over the grid: the largest |albedo error| and the largest relative RMS error
    of f·cos (noise taken out) over θi ≤ 80°, log colour scale, the 5% contour, the points
    within 5% of both hatched, noise-limited points marked '?', each point's value in %."""
    from matplotlib.colors import LogNorm
    from matplotlib.patches import Rectangle

    a, r = worst(entry)
    within, limited = verdicts(entry)
    ax0, ax1 = entry["axes"]
    xe, ye = _edges(ax0), _edges(ax1)
    x, y = np.asarray(ax0["values"], float), np.asarray(ax1["values"], float)
    fig = new_figure(10.0, 4.4)
    panels = fig.subplots(1, 2)
    norm = LogNorm(COLOR_MIN, COLOR_MAX)
    titles = (f"largest |albedo error| over θi ≤ {entry_max_theta(entry):g}°",
              f"largest relative RMS error of f·cos over θi ≤ {entry_max_theta(entry):g}° "
              "(simulation noise removed)")
    for ax, grid, title in zip(panels, (a, r), titles):
        shown = np.clip(np.where(np.isnan(grid), np.nan, grid), COLOR_MIN, COLOR_MAX)
        mesh = ax.pcolormesh(xe, ye, shown.T, norm=norm, cmap="magma_r", shading="flat")
        if np.nanmin(grid) < THRESHOLD < np.nanmax(grid) and min(grid.shape) > 1:
            ax.contour(x, y, np.nan_to_num(grid, nan=COLOR_MAX).T, levels=[THRESHOLD],
                       colors="tab:cyan", linewidths=1.6)
        for i in range(len(x)):
            for j in range(len(y)):
                if within[i, j]:
                    ax.add_patch(Rectangle((xe[i], ye[j]), xe[i + 1] - xe[i], ye[j + 1] - ye[j],
                                           fill=False, hatch="///", edgecolor="tab:cyan",
                                           linewidth=0.0))
                v = grid[i, j]
                text = "n/a" if np.isnan(v) else f"{100 * v:.2g}" + ("?" if limited[i, j] else "")
                ax.text(x[i], y[j], text, ha="center", va="center", fontsize=6.5,
                        color="white" if np.isfinite(v) and v > 0.2 else "black")
        if ax0["scale"] == "log":
            ax.set_xscale("log")
        if ax1["scale"] == "log":
            ax.set_yscale("log")
        ax.set_xlim(xe[0], xe[-1])
        ax.set_ylim(ye[0], ye[-1])
        ax.set_xticks(x, [number_text(v) for v in x])
        ax.set_yticks(y, [number_text(v) for v in y])
        ax.minorticks_off()
        ax.grid(False)
        ax.set_xlabel(_label(ax0))
        ax.set_ylabel(_label(ax1))
        ax.set_title(title)
        bar = fig.colorbar(mesh, ax=ax, shrink=0.9)
        bar.set_label("relative error (log scale; cells: value in %)")
    fig.suptitle(f"{entry['model']} vs the simulation of its stack. Hatched: within "
                 f"{THRESHOLD:.0%} in both maps; cyan line: {THRESHOLD:.0%}; ?: noise-limited")
    return fig


def entry_max_theta(entry: dict) -> float:
    from fitlab.atlas.grids import REGION_MAX_THETA_DEG

    return max(t for t in entry["theta_i"] if t <= REGION_MAX_THETA_DEG + 1e-9) \
        if any(t <= REGION_MAX_THETA_DEG + 1e-9 for t in entry["theta_i"]) else \
        REGION_MAX_THETA_DEG


def figures(entry: dict) -> dict:
    """{file name: bytes}: the entry's maps as PNG and SVG."""
    fig = maps_figure(entry)
    png, svg = render(fig)
    fig.clear()
    stem = figure_name(entry)
    return {f"{stem}.png": png, f"{stem}.svg": svg}


# --------------------------------------------------------------------------------------------
# The page
# --------------------------------------------------------------------------------------------


def _fixed_text(entry: dict) -> str:
    return ", ".join(f"{k} = {v:.4g}" for k, v in entry["fixed"].items()) or "none"


def _options_text(entry: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in entry["options"].items()) or "none"


def _samples_text(entry: dict) -> str:
    s = np.asarray(entry["samples"], int)
    return f"{s.min():,}" if s.min() == s.max() else f"{s.min():,} to {s.max():,}"


def per_incidence_text(entry: dict) -> str:
    """How many grid points are within the threshold at each incidence alone."""
    a = np.abs(np.asarray(entry["albedo_error"], float))
    r = np.asarray(entry["rms_error"], float)
    ok = (a <= THRESHOLD) & (r <= THRESHOLD)
    n = ok.shape[0] * ok.shape[1]
    return ", ".join(f"θi {t:g}°: {int(ok[..., k].sum())} of {n}"
                     for k, t in enumerate(entry["theta_i"]))


def entry_section(entry: dict) -> list[str]:
    within, limited = verdicts(entry)
    a0, a1 = entry["axes"]
    stem = figure_name(entry)
    prov = entry.get("provenance", {})
    n_in, n = int(within.sum()), within.size
    lines = [f"## {entry['model']}", "",
             f"**Within {THRESHOLD:.0%}: {entry['region']}** ({n_in} of {n} grid points"
             + (f"; {int(limited.sum())} noise-limited, marked '?'" if limited.any() else "")
             + "). Within it at each incidence alone: " + per_incidence_text(entry) + ".", "",
             f"![{entry['model']}: largest albedo error and RMS error of f·cos over the grid]"
             f"({stem}.png)", "",
             f"Maps: [{stem}.png]({stem}.png), [{stem}.svg]({stem}.svg). "
             f"Grid: {span_text(a0)} ({a0['scale']}, {len(a0['values'])} values) × "
             f"{span_text(a1)} ({a1['scale']}, {len(a1['values'])} values); other parameters: "
             f"{_fixed_text(entry)}; options: {_options_text(entry)}; incidences θi = "
             f"{', '.join(f'{t:g}' for t in entry['theta_i'])}°; sides: "
             f"{', '.join(entry['sides'])}. Paths per incidence: {_samples_text(entry)}"
             + (" (`--quick`)" if prov.get("quick") else "") + f"; made by `{prov.get('command')}`"
             + ".", ""]
    return lines


def page(rec: dict, estimate_min: float | None = None) -> str:
    """``reports/layered_atlas/README.md`` of the atlas record ``rec``: how it was made, the
    measures and the region rule, then per model its region, maps and grid."""
    m = rec.get("method", {})
    lines = [
        "# Layered-model validation atlas", "",
        "Each layered model family of fitlab against the Monte Carlo simulation of its own "
        "stack (`fitlab simulate` on `Model.scene_of`: every bounce and scattering order "
        "traced), over a grid of two of its parameters, the others held at stated values. "
        f"Where a model is within {THRESHOLD:.0%} of the simulation is named below per model; "
        "`fitlab models NAME` shows it, and the report of a fit whose parameters lie outside "
        "it says so. The numbers: `fitlab/models/data/layered_atlas.json` "
        "([data_formats/layered_atlas.md](../../data_formats/layered_atlas.md)).", "",
        "Regenerate everything with `fitlab atlas --write-package-data` from the source "
        "tree's root (one model: `--model NAME`; a smoke run: `--quick`)"
        + (f"; the full atlas takes about {estimate_min:.0f} minutes on a 2-core CPU"
           if estimate_min else "") + ".", "",
    ]
    quick = [e["model"] for e in rec["entries"] if e.get("provenance", {}).get("quick")]
    if quick:
        lines += [f"**Smoke run**: {', '.join(quick)} come from `--quick` (every third grid "
                  "value, at most "
                  f"{m.get('quick_max_samples', 0):,} paths per incidence, "
                  f"{m.get('quick_model_points', 0):,} model points): noisier and coarser "
                  "than the atlas proper, which `fitlab atlas --write-package-data` makes.", ""]
    lines += [
        "## How it is made", "",
        f"- **Simulation**: for each grid point one scene with the incidences θi of the grid, "
        f"hemisphere bins of {m.get('theta_bins')} θ × {m.get('phi_bins')} φ per side the "
        "model scatters to, scored on cells that join a ring's φ bins where the ring is small "
        "(about equal cosine-weighted solid angle each). Paths per incidence: a pilot run of "
        f"{m.get('pilot_paths', 0):,} sets them so that the simulation's noise ν (below) "
        f"reaches {m.get('aim_se')} and the albedo's relative standard error "
        f"{m.get('aim_albedo_se')}, at most {m.get('max_samples', 0):,}; every point uses the "
        "same seed.",
        "- **Model**: integrated over the same bins by multiple importance sampling (balance "
        "heuristic) of its own sampler at "
        f"{m.get('model_points', 0):,} quasi-random points and a {m.get('bin_nodes')} × "
        f"{m.get('bin_nodes')} midpoint rule in the cosine-weighted measure of each bin; its "
        "albedo is the sum over the bins.",
        "- **Albedo error**: (model − simulation) / simulation of the light leaving on the "
        "model's sides (the delta components the model declares apart are left out of both), "
        "signed in the JSON, its standard error beside it.",
        "- **RMS error of f·cos**: the RMS over the hemisphere (solid-angle measure) of the "
        "model's f·|cos θo| minus the simulation's, relative to the RMS of the simulation's "
        "(a relative L2 error: where the light goes and how much, not the ratio in a dim tail "
        "cell), with the simulation's own noise ν in the same measure taken out: "
        "sqrt(max(rms² − ν², 0)).",
        f"- **Within {THRESHOLD:.0%}**: the largest |albedo error| and the largest RMS error "
        f"over θi ≤ {rec.get('region_max_theta_i'):g}° are both at most {THRESHOLD:g}. "
        f"**Noise-limited** ('?'): ν above {NOISE_LIMIT:g} or the albedo error's standard "
        f"error above {ALBEDO_SE_LIMIT:g} at some counted θi; the verdict there is the "
        "noise-corrected one, and more paths may move it. The region's words hold at the "
        "grid's values: between them the boundary is known to one grid step.",
        "- **A fit's verdict** (`fitlab.atlas.region.within_region`): the two largest errors "
        "read bilinearly from the grid (log coordinates on a log axis) at the fitted values; "
        "no verdict where the model's options differ from the atlas's, a value lies outside "
        "the grid, or a parameter off the axes is more than 10% of max(|value|, 1) away from "
        "the atlas's.", "",
        "## Models", ""]
    for e in rec["entries"]:
        lines.append(f"- [{e['model']}](#{e['anchor']}): {e['region']}")
    lines.append("")
    for e in rec["entries"]:
        lines += entry_section(e)
    return "\n".join(lines).rstrip() + "\n"


# --------------------------------------------------------------------------------------------
# The fit report's note
# --------------------------------------------------------------------------------------------


def fit_note(model, params: dict, options: dict) -> str | None:
    """The fit report's sentence on the atlas: where the fitted model's parameters lie
    outside its 5% region, the errors the atlas reads there and its page; inside or without
    a verdict, one short line; None for a model the atlas does not map."""
    from fitlab.atlas.region import entry_of, package_atlas

    atlas = package_atlas()
    if atlas is None or entry_of(model.name, atlas) is None:
        return None
    verdict, text = within_region(model, params, options, atlas)
    if verdict is False:
        return (f"Validation atlas: the fitted parameters lie {text}. The model's own "
                "approximation of its stack may limit this fit there (the model check above, "
                "where run, measures it at the fit's directions).")
    return f"Validation atlas: {text}."


__all__ = ["figure_name", "figures", "fit_note", "link", "maps_figure", "page"]
