"""The validation atlas's numbers: a layered model against the Monte Carlo simulation of its own
stack (``Model.scene_of``, every bounce and scattering order traced:
:func:`fitlab.simulate.model_stack.stack_scene`) at each point of a grid of its parameters
(:mod:`fitlab.atlas.grids`), for each incidence θi.

At a grid point and θi the simulator tallies hemisphere bins
(:data:`~fitlab.atlas.grids.THETA_BINS` × :data:`~fitlab.atlas.grids.PHI_BINS` per side the
model has: its reflection, and its transmission where it declares one) and the flux leaving
each side; the model is integrated over the same bins (:func:`bin_estimator`). The measures
are scored on :class:`Cells`, unions of bins of about equal cosine-weighted solid angle (a 10°
ring at the pole holds a sixth of one at 45°: its bins alone would be 2.4 times noisier). Two
measures, each with the simulation's own noise in it:

- **albedo error** (A_model − A_sim) / A_sim, signed, over the sides the model has, with its
  standard error A_model σ_sim / A_sim² (the model's quadrature error is far below it);
- **RMS error of f·cos**, relative: the RMS over the hemisphere (solid-angle measure, the
  model's sides together) of the model's f·|cos θo| minus the simulation's, divided by the RMS
  of the simulation's f·|cos θo|: sqrt(Σ_c Ω_c (v_c^m − v_c^s)² / Σ_c Ω_c (v_c^s)²), v_c the
  mean of f·|cos θo| over cell c. A relative L2 error: a lobe's shape and energy where its
  light goes, not a tail cell's ratio (a relative error per cell above a floor, the fits'
  measure, is dominated at grazing incidence by dim cells just above the floor, where a
  glossy lobe's tail is 10⁻² of its peak). The simulation's noise in the same measure, ν =
  sqrt(Σ_c Ω_c σ_c² / Σ_c Ω_c (v_c^s)²), is given beside it, and the RMS error is given as
  measured and with the noise taken out, sqrt(max(rms² − ν², 0)) (the expected square of the
  measured RMS is the model's own square plus ν²).

The model over a bin: ∫_b f |cos θo| dωo by multiple importance sampling (Veach's balance
heuristic) of two strategies: the model's own sampler at :data:`MODEL_POINTS` quasi-random
points (the shifted Sobol points of :func:`fitlab.models.directional_albedo.points`; exact
where its lobe is narrow) and :data:`BIN_NODES`² midpoints of every bin in the cosine-weighted
measure (:func:`bin_nodes`; exact where the model is smooth over a bin, and wherever its
sampler does not reach). Its albedo is the sum over the bins. Checked on the coated model's
single bounce, for which the model is exact: albedo within its standard error, RMS error
(noise removed) 1 to 2% at 4,000,000 paths, the model's quadrature included.

Paths per incidence: a pilot run of :data:`PILOT_PATHS` sets them so that ν reaches
:data:`fitlab.fitting.model_check.AIM_SE` and the albedo's relative standard error
:data:`AIM_ALBEDO_SE` (:func:`fitlab.fitting.model_check.samples_for`,
from 1,000 to :data:`MAX_SAMPLES`), or ``samples`` when given. Every grid point uses the same
seed (common random numbers: the maps' noise is smooth across the grid).
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import numpy as np

from fitlab.atlas.grids import PHI_BINS, THETA_BINS, Spec

#: Quasi-random points per strategy, per incidence, of the model's bin integrals.
MODEL_POINTS = 1 << 14
QUICK_MODEL_POINTS = 1 << 12
#: The bins' own nodes (second strategy): BIN_NODES × BIN_NODES per bin.
BIN_NODES = 6
#: Paths per incidence of the pilot run that sets the sample count (it also compiles the walk).
PILOT_PATHS = 20_000
#: The relative standard error of the simulated albedo the sample count aims at (a tenth of the
#: region's 5% threshold; the RMS error's noise aims at model_check's AIM_SE).
AIM_ALBEDO_SE = 0.005
#: At most this many paths per incidence (``--quick``: QUICK_MAX_SAMPLES).
MAX_SAMPLES = 2_000_000
QUICK_MAX_SAMPLES = 100_000


# --------------------------------------------------------------------------------------------
# The grid's models, parameters and scenes
# --------------------------------------------------------------------------------------------


def options_of(model, spec: Spec) -> dict:
    """The model's default options with the grid's own (every option named)."""
    return {**model.default_options(), **spec.options}


def params_at(model, spec: Spec, i: int, j: int) -> dict:
    """The parameters of grid point (i, j): the registry's typical values, the grid's fixed
    ones, then the two axes' values."""
    p = {q.name: float(q.default) for q in model.parameters}
    p.update({k: float(v) for k, v in spec.fixed.items()})
    (a, b) = spec.axes
    p[a.name], p[b.name] = float(a.values[i]), float(b.values[j])
    return p


def sides_of(model) -> tuple:
    """The sides a model scatters to, as the simulator's detector names them."""
    c = model.capabilities
    return tuple(s for s, on in (("reflection", c.reflection),
                                 ("transmission", c.transmission)) if on)


def scene_at(model, params: dict, options: dict, spec: Spec):
    """The validated simulator Scene of ``model``'s stack at ``params`` (every effect traced)
    with the grid's incidences and the atlas's hemisphere bins; ValueError saying why where
    the model at these values is no layered stack the simulator traces."""
    from fitlab.fitting.model_check import applicable
    from fitlab.simulate import scene_from_dict

    scene, status, why = applicable(model, params, options)
    if scene is None:
        raise ValueError(f"{model.name} at {params}: {why} ({status})")
    return scene_from_dict({
        **scene, "name": f"atlas: {model.name}",
        "illumination": {"theta_i": [float(t) for t in spec.theta_i]},
        "detector": {"type": "hemisphere", "sides": list(sides_of(model)),
                     "theta_bins": THETA_BINS, "phi_bins": PHI_BINS},
        "effects": {**scene.get("effects", {}), "color": "mono"}})


@functools.lru_cache(maxsize=None)
def bins(sides: tuple):
    """(Rows, Ω): the simulator's hemisphere bins of ``sides`` (its own
    :func:`fitlab.simulate.detectors.hemisphere_rows`, in its row order) and each bin's solid
    angle Ω = Δφ |cos θ0 − cos θ1| in sr."""
    from fitlab.simulate.detectors import hemisphere_rows

    rows = hemisphere_rows(THETA_BINS, PHI_BINS, sides)
    e = np.radians(rows.edges)
    omega = (e[:, 3] - e[:, 2]) * np.abs(np.cos(e[:, 0]) - np.cos(e[:, 1]))
    return rows, omega


# --------------------------------------------------------------------------------------------
# The model over the simulator's bins
# --------------------------------------------------------------------------------------------


def bin_index(w, jnp):
    """The tally index of direction(s) w (..., 3) among the simulator's hemisphere bins of both
    sides: (side · THETA_BINS + θ bin) · PHI_BINS + φ bin, θ from the normal of its side
    (fitlab.simulate.walk's order)."""
    z = w[..., 2]
    side = jnp.where(z < 0, 1, 0)
    theta = jnp.degrees(jnp.arccos(jnp.clip(jnp.abs(z), 0.0, 1.0)))
    tb = jnp.clip(jnp.floor(theta / 90.0 * THETA_BINS).astype(jnp.int32), 0, THETA_BINS - 1)
    phi = jnp.mod(jnp.arctan2(w[..., 1], w[..., 0]), 2.0 * jnp.pi)
    pb = jnp.clip(jnp.floor(phi / (2.0 * jnp.pi) * PHI_BINS).astype(jnp.int32), 0,
                  PHI_BINS - 1)
    return (side * THETA_BINS + tb) * PHI_BINS + pb


def bin_nodes(sides: tuple, k: int = BIN_NODES):
    """The second strategy's directions: k × k midpoints of every bin of ``sides``, uniform in
    the cosine-weighted measure within the bin (midpoints in sin²θ and φ, since |cos θ| dω =
    d(sin²θ)/2 dφ). Returns (directions (B·k², 3), their bins' tally indices, and per tally
    index of both sides k² / ∫_b |cos θ| dω, 0 for a side not in ``sides``): the nodes' density
    per unit cosine-weighted measure, bin by bin."""
    rows, _ = bins(sides)
    e = np.radians(rows.edges)
    s2 = np.sin(np.where(e[:, :2] > np.pi / 2, np.pi - e[:, :2], e[:, :2])) ** 2
    lo, hi = np.minimum(s2[:, 0], s2[:, 1]), np.maximum(s2[:, 0], s2[:, 1])
    m = (np.arange(k) + 0.5) / k
    u = lo[:, None, None] + (hi - lo)[:, None, None] * m[None, :, None]
    phi = e[:, 2, None, None] + (e[:, 3] - e[:, 2])[:, None, None] * m[None, None, :]
    u, phi = np.broadcast_arrays(u, phi)
    sign = np.where(np.asarray(rows.theta_o) > 90.0, -1.0, 1.0)[:, None, None]
    r = np.sqrt(u)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), sign * np.sqrt(1.0 - u)], axis=-1)
    density = np.zeros(2 * THETA_BINS * PHI_BINS)
    density[rows.tally] = k * k / rows.cos_solid_angle
    return d.reshape(-1, 3), np.repeat(rows.tally, k * k), density


@functools.lru_cache(maxsize=None)
def bin_estimator(model, options: tuple, sides: tuple, n: int = MODEL_POINTS):
    """A compiled function ``(params, wi) -> (T, 2 · THETA_BINS · PHI_BINS)``: ∫_b f |cos θo|
    dωo of ``model`` (``options``: sorted (name, value) pairs) over every bin b of both sides,
    for incidences wi (T, 3), by the balance heuristic (Veach) of two strategies: the model's
    sampler at n quasi-random points, and the bins' own nodes (:func:`bin_nodes`: a midpoint
    rule in the cosine-weighted measure of each bin). One compilation per model, options, sides
    and n; params are scalars (a dict of float64)."""
    from fitlab._jax import jax, jnp
    from fitlab.models.directional_albedo import points

    opts = dict(options)
    u = jnp.asarray(points(n))
    nodes, node_bin, dens = (jnp.asarray(x) for x in bin_nodes(sides))
    n_bins = 2 * THETA_BINS * PHI_BINS

    def one(params, wi):
        # strategy 1: the model's sampler (weight = f|cos θo|/pdf); the nodes' density there
        W = jnp.broadcast_to(wi, u.shape)
        wo_s, weight, pdf_s = model.sample(params, W, u, **opts)
        b_s = bin_index(wo_s, jnp)
        den_s = n * pdf_s + dens[b_s] * jnp.abs(wo_s[..., 2])
        ok_s = (pdf_s > 0) & (den_s > 0)
        c_s = jnp.where(ok_s, weight * pdf_s / jnp.where(ok_s, den_s, 1.0), 0.0)
        # strategy 2: the bins' nodes
        Wn = jnp.broadcast_to(wi, nodes.shape)
        f_n = model.eval(params, Wn, nodes, **opts)
        cos_n = jnp.abs(nodes[..., 2])
        den_n = n * model.pdf(params, Wn, nodes, **opts) + dens[node_bin] * cos_n
        c_n = jnp.where(den_n > 0, f_n * cos_n / jnp.where(den_n > 0, den_n, 1.0), 0.0)
        out = jnp.zeros(n_bins, c_s.dtype)
        return out.at[b_s].add(c_s).at[node_bin].add(c_n)

    return jax.jit(jax.vmap(one, in_axes=(None, 0)))


def incidence_directions(theta_i) -> np.ndarray:
    t = np.radians(np.asarray(theta_i, float))
    return np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)


def model_bins(model, options: dict, sides: tuple, params: dict, theta_i,
               n: int = MODEL_POINTS) -> np.ndarray:
    """(T, rows): the model's cosine-weighted mean f over each of the simulator's bins of
    ``sides`` (its row order), per incidence: ∫_b f|cos θo| dωo / ∫_b |cos θo| dωo."""
    from fitlab._jax import jnp

    rows, _ = bins(sides)
    fn = bin_estimator(model, tuple(sorted(options.items())), sides, n)
    p = {k: jnp.float64(v) for k, v in params.items()}
    flux = np.asarray(fn(p, jnp.asarray(incidence_directions(theta_i))))
    return flux[:, rows.tally] / rows.cos_solid_angle[None, :]


# --------------------------------------------------------------------------------------------
# The measures
# --------------------------------------------------------------------------------------------


class Cells(NamedTuple):
    """The cells the measures are scored on: unions of the simulator's bins of about equal
    cosine-weighted solid angle (a 10° ring near the pole or the horizon holds a sixth of the
    light a Lambertian sends into one at 45°: its φ bins are merged :func:`merge_factor` at a
    time). ``of_row``: each bin's cell (the simulator's row order); ``cw``: ∫ |cos θo| dω and
    ``omega``: the solid angle of each cell."""

    of_row: np.ndarray
    cw: np.ndarray
    omega: np.ndarray

    @property
    def size(self) -> int:
        return len(self.cw)


def merge_factor(ring_cw: float, largest_cw: float) -> int:
    """How many φ bins of a θ ring one cell takes: the divisor of PHI_BINS closest to (below)
    the largest ring's ∫|cos| dω over this ring's."""
    want = max(1, int(round(largest_cw / ring_cw)))
    return max(d for d in range(1, want + 1) if PHI_BINS % d == 0)


@functools.lru_cache(maxsize=None)
def cells(sides: tuple) -> Cells:
    """The atlas's :class:`Cells` over the hemisphere bins of ``sides``."""
    rows, omega = bins(sides)
    ring = (rows.tally // PHI_BINS)  # side · THETA_BINS + θ bin
    pb = rows.tally % PHI_BINS
    ring_cw = {r: rows.cos_solid_angle[ring == r].sum() for r in np.unique(ring)}
    largest = max(ring_cw.values())
    of_row, next_cell, first = np.zeros(len(ring), int), 0, {}
    for r in sorted(ring_cw):  # rings in tally order
        m = merge_factor(ring_cw[r], largest)
        first[r] = next_cell
        next_cell += PHI_BINS // m
        sel = ring == r
        of_row[sel] = first[r] + pb[sel] // m
    cw = np.bincount(of_row, rows.cos_solid_angle, next_cell)
    return Cells(of_row, cw, np.bincount(of_row, omega, next_cell))


def cell_means(value: np.ndarray, sigma: np.ndarray | None, sides: tuple):
    """Bin means (..., rows) → cell means (..., cells): Σ value·cw / Σ cw; with ``sigma``
    also the cells' standard errors, sqrt(Σ (σ·cw)²) / Σ cw (the bins' errors taken as
    independent)."""
    rows, _ = bins(sides)
    c = cells(sides)

    def total(x):
        x = np.asarray(x, float) * rows.cos_solid_angle
        out = np.zeros(x.shape[:-1] + (c.size,))
        np.add.at(out, (..., c.of_row), x)
        return out

    mean = total(value) / c.cw
    if sigma is None:
        return mean
    err = np.zeros(np.shape(sigma)[:-1] + (c.size,))
    np.add.at(err, (..., c.of_row), (np.asarray(sigma, float) * rows.cos_solid_angle) ** 2)
    return mean, np.sqrt(err) / c.cw


def hemisphere_rms(model_value, sim_value, sim_sigma, c: Cells) -> tuple[float, float]:
    """(measured RMS error, noise ν) of f·|cos θo| over the hemisphere at one incidence, both
    relative to the RMS of the simulation's f·|cos θo| (module docstring). Cell means of f
    (cosine-weighted) m, s, σ: v = s·cw/Ω, so Ω (Δv)² = (Δs)² cw² / Ω."""
    w = c.cw ** 2 / c.omega
    norm = float(np.sum(w * sim_value ** 2))
    if not norm > 0:
        return float("nan"), float("inf")
    rms = float(np.sqrt(np.sum(w * (model_value - sim_value) ** 2) / norm))
    return rms, float(np.sqrt(np.sum(w * sim_sigma ** 2) / norm))


def incidence_measures(model_value, sim_value, sim_sigma, c: Cells, model_albedo, sim_albedo,
                       sim_albedo_se) -> dict:
    """The measures at one incidence (cell means; the albedos over the model's sides)."""
    rms, noise = hemisphere_rms(model_value, sim_value, sim_sigma, c)
    ok = sim_albedo > 0
    return {
        "albedo_sim": float(sim_albedo),
        "albedo_error": float(model_albedo / sim_albedo - 1.0) if ok else float("nan"),
        "albedo_error_se": float(model_albedo * sim_albedo_se / sim_albedo ** 2) if ok
        else float("nan"),
        "rms_error_measured": rms,
        "rms_noise": noise,
        "rms_error": float(np.sqrt(max(rms ** 2 - noise ** 2, 0.0))) if np.isfinite(rms)
        else float("nan"),
        "cells": int(np.sum(sim_value > 0)),
    }


def _sim_cells(result, sides: tuple):
    T = len(result.incidences)
    return cell_means(result.value[:, 0].reshape(T, -1), result.sigma[:, 0].reshape(T, -1),
                      sides)


def measures(result, model_value: np.ndarray, sides: tuple) -> list[dict]:
    """Per incidence of a SimulationResult (hemisphere bins of ``sides``), the measures of the
    model's bin means ``model_value`` (T, rows)."""
    rows, _ = bins(sides)
    c = cells(sides)
    value, sigma = _sim_cells(result, sides)
    model = cell_means(model_value, None, sides)
    k = [i for i, s in enumerate(("reflection", "transmission")) if s in sides]
    a_sim = result.energy[:, k, 0].sum(axis=1)
    a_se = np.sqrt((result.energy_sigma[:, k, 0] ** 2).sum(axis=1))
    a_model = (model_value * rows.cos_solid_angle[None, :]).sum(axis=1)
    return [incidence_measures(model[t], value[t], sigma[t], c, a_model[t], a_sim[t], a_se[t])
            for t in range(len(model))]


def pilot_noise(result, sides: tuple) -> float:
    """The largest noise ν of the RMS error of f·cos (:func:`hemisphere_rms`) over the
    incidences of a simulation."""
    c = cells(sides)
    value, sigma = _sim_cells(result, sides)
    return max(hemisphere_rms(v, v, s, c)[1] for v, s in zip(value, sigma))


def pilot_albedo_se(result, sides: tuple) -> float:
    """The largest relative standard error of the simulated albedo over the incidences."""
    k = [i for i, s in enumerate(("reflection", "transmission")) if s in sides]
    a = result.energy[:, k, 0].sum(axis=1)
    se = np.sqrt((result.energy_sigma[:, k, 0] ** 2).sum(axis=1))
    return float(np.max(np.where(a > 0, se / np.where(a > 0, a, 1.0), np.inf)))


def simulate_point(scene, sides: tuple, *, samples: int | None, seed: int, quick: bool):
    """(SimulationResult, paths per incidence): ``samples`` paths, or as many as bring the
    pilot's noise ν (:func:`hemisphere_rms`) to model_check's aim and its albedo's relative
    standard error to AIM_ALBEDO_SE, at most MAX_SAMPLES
    (``quick``: QUICK_MAX_SAMPLES)."""
    from fitlab.fitting.model_check import AIM_SE, samples_for
    from fitlab.simulate import simulate

    if samples is not None:
        return simulate(scene, samples, seed), int(samples)
    pilot = simulate(scene, PILOT_PATHS, seed)
    most = QUICK_MAX_SAMPLES if quick else MAX_SAMPLES
    n = max(samples_for(pilot_noise(pilot, sides), pilot=PILOT_PATHS, target=AIM_SE, most=most),
            samples_for(pilot_albedo_se(pilot, sides), pilot=PILOT_PATHS,
                        target=AIM_ALBEDO_SE, most=most))
    if n <= PILOT_PATHS:
        return pilot, PILOT_PATHS
    return simulate(scene, n, seed), n


# --------------------------------------------------------------------------------------------
# One entry
# --------------------------------------------------------------------------------------------

#: The per-incidence measures an entry keeps, as (n0, n1, T) arrays.
KEPT = ("albedo_error", "albedo_error_se", "rms_error", "rms_noise", "albedo_sim")


def compute_entry(spec: Spec, *, samples: int | None = None, seed: int = 0,
                  quick: bool = False, model_points: int | None = None,
                  on_point=lambda k, total, seconds: None) -> dict:
    """The numbers of one atlas entry: every grid point of ``spec`` simulated and scored.
    Returns {"model", "options", "axes", "fixed", "theta_i", "sides", "samples" (n0, n1),
    KEPT... (n0, n1, T) lists, "model_points"}; ``on_point(k, total, seconds)`` after each
    point (progress). ValueError where the model is not layered at a grid point."""
    from fitlab.models import get_model

    model = get_model(spec.model)
    options = options_of(model, spec)
    sides = sides_of(model)
    n_model = model_points or (QUICK_MODEL_POINTS if quick else MODEL_POINTS)
    (a, b) = spec.axes
    shape = (len(a.values), len(b.values))
    out = {k: np.full(shape + (len(spec.theta_i),), np.nan) for k in KEPT}
    paths = np.zeros(shape, dtype=int)
    total = shape[0] * shape[1]
    for k, (i, j) in enumerate(np.ndindex(shape)):
        t0 = time.perf_counter()
        params = params_at(model, spec, i, j)
        scene = scene_at(model, params, options, spec)
        result, paths[i, j] = simulate_point(scene, sides, samples=samples, seed=seed,
                                             quick=quick)
        mv = model_bins(model, options, sides, params, spec.theta_i, n_model)
        for t, m in enumerate(measures(result, mv, sides)):
            for key in KEPT:
                out[key][i, j, t] = m[key]
        on_point(k + 1, total, time.perf_counter() - t0)
    fixed = {q.name: float(q.default) for q in model.parameters
             if q.name not in (a.name, b.name)}
    fixed.update({n: float(v) for n, v in spec.fixed.items()})
    return {"model": model.name, "options": options,
            "axes": [{"name": ax.name, "label": ax.label or ax.name,
                      "unit": _unit(model, ax.name), "scale": ax.scale,
                      "values": [float(v) for v in ax.values]} for ax in spec.axes],
            "fixed": fixed, "theta_i": [float(t) for t in spec.theta_i], "sides": list(sides),
            "model_points": n_model, "samples": paths.tolist(),
            **{k: v.tolist() for k, v in out.items()}}


def _unit(model, name: str) -> str:
    return next((q.unit for q in model.parameters if q.name == name), "1")


__all__ = ["KEPT", "MODEL_POINTS", "PILOT_PATHS", "bin_estimator", "bins",
           "compute_entry", "incidence_measures", "measures", "model_bins", "options_of",
           "hemisphere_rms", "params_at", "scene_at", "sides_of", "simulate_point"]
