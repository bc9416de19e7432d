"""The directional albedo E(ω) = ∫ f(ω, ωo) |cos θo| dωo of a model, tabulated once per
parameter set over a fixed grid of incident directions and interpolated between them.

E is the mean weight of the model's own importance sampler; here it is the mean over a fixed
quasi-random point set (:func:`points`: the first :data:`N_POINTS` points of the 3-D Sobol
sequence, Cranley–Patterson shifted by a fixed vector), so the table is a deterministic,
differentiable function of the parameters. The grid (:func:`grid`) has polar nodes
:data:`THETA_NODES_DEG`, dense toward grazing where E changes fastest, on one or both sides of
the surface, and :data:`PHI_NODES` azimuths for a model that is not isotropic; :func:`lookup`
interpolates linearly in θ and (periodically) in φ, :func:`lookup_min` reads the least value of
the cell's four nodes (for a safety factor that may dip between them).

A table costs N_POINTS samples per node and parameter set: :func:`per_parameter_set` makes one
table per element of the parameters' broadcast shape when that shape has at most
:data:`MAX_ELEMENTS` elements (scalars: one table, whatever the number of rows; a stack axis of
a training batch); parameters given per row make one table when the rows share one set, and
otherwise one per *distinct* set, at most :data:`MAX_DISTINCT` of them (the rows of a joint
fit's channels, a test's parameter sets): rows whose set is not among them get NaN, a failure
no caller can mistake for a value.

Used by SpongeCake's multiple-scattering lobe (fitlab/models/spongecake_multiple.py) to keep
its energy within the stack's budget.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from fitlab._jax import jnp

#: quasi-random points per node: the albedo of a SpongeCake stack to about 0.006 at grazing
N_POINTS = 128
#: polar angles of the nodes on each side (degrees from the normal)
THETA_NODES_DEG = (0.0, 30.0, 50.0, 65.0, 75.0, 81.0, 85.0, 87.5, 89.0, 89.7, 89.95)
#: azimuths of the nodes (evenly spaced over 360°) for a model that is not isotropic
PHI_NODES = 16
#: per-element tables up to this many parameter sets; beyond it, distinct sets only
MAX_ELEMENTS = 64
MAX_DISTINCT = 8
#: the Cranley–Patterson shift of the Sobol points (fixed: the table is deterministic)
_SHIFT = (0.5, 0.3819660112501051, 0.2360679774997897)


@functools.lru_cache(maxsize=None)
def points(n: int = N_POINTS) -> np.ndarray:
    """(n, 3) points in [0, 1)³: the unscrambled Sobol sequence shifted by :data:`_SHIFT`."""
    from scipy.stats import qmc

    base = qmc.Sobol(3, scramble=False).random(n)
    return np.mod(base + np.asarray(_SHIFT), 1.0)


class Grid(NamedTuple):
    theta: np.ndarray   # (T,) radians
    phi: np.ndarray     # (F,) radians, F = 1 for an isotropic model
    sides: int          # 1: above the surface only; 2: above, then below

    @property
    def size(self) -> int:
        return self.sides * len(self.theta) * len(self.phi)


@functools.lru_cache(maxsize=None)
def grid(isotropic: bool, both_sides: bool) -> Grid:
    phi = np.zeros(1) if isotropic else 2.0 * np.pi * np.arange(PHI_NODES) / PHI_NODES
    return Grid(np.radians(np.asarray(THETA_NODES_DEG)), phi, 2 if both_sides else 1)


def directions(g: Grid) -> np.ndarray:
    """(g.size, 3) unit incident directions, ordered (side, θ, φ)."""
    s = np.array([1.0, -1.0][:g.sides])
    S, T, F = np.meshgrid(s, g.theta, g.phi, indexing="ij")
    w = np.stack([np.sin(T) * np.cos(F), np.sin(T) * np.sin(F), S * np.cos(T)], axis=-1)
    return w.reshape(-1, 3)


def tabulate(sample_weight, params: dict, g: Grid, dtype):
    """E at every node for parameters ``params`` (arrays of broadcast shape P): (P..., g.size).
    ``sample_weight(params, wi, u)`` returns the sampler's weights for directions wi and points
    u of shape (P..., G, N, 3) (params are given shape (P..., 1, 1))."""
    w = jnp.asarray(directions(g), dtype)[:, None, :]
    u = jnp.asarray(points(), dtype)[None, :, :]
    shape = jnp.broadcast_shapes(*(jnp.shape(v) for v in params.values()))
    full = shape + (g.size, N_POINTS, 3)
    p = {k: jnp.asarray(v)[..., None, None] for k, v in params.items()}
    weight = sample_weight(p, jnp.broadcast_to(w, full), jnp.broadcast_to(u, full))
    return jnp.mean(jnp.broadcast_to(weight, full[:-1]), axis=-1)


def _cell(g: Grid, w):
    """The node indices (side, θ below, θ above, φ before, φ after) of the grid cell holding
    each direction w (..., 3), and its fractional position (t in θ, s in φ)."""
    T, F = len(g.theta), len(g.phi)
    mu = w[..., 2]
    theta = jnp.arccos(jnp.clip(jnp.abs(mu), 0.0, 1.0))
    nodes = jnp.asarray(g.theta, w.dtype)
    i = jnp.clip(jnp.searchsorted(nodes, theta, side="right") - 1, 0, T - 2)
    t = jnp.clip((theta - nodes[i]) / (nodes[i + 1] - nodes[i]), 0.0, 1.0)
    side = jnp.where(mu < 0, 1, 0) if g.sides == 2 else jnp.zeros(mu.shape, jnp.int32)
    if F == 1:
        j0 = j1 = jnp.zeros_like(i)
        s = jnp.zeros_like(t)
    else:
        phi = jnp.mod(jnp.arctan2(w[..., 1], w[..., 0]), 2.0 * jnp.pi) * (F / (2.0 * jnp.pi))
        j0 = jnp.clip(jnp.floor(phi).astype(jnp.int32), 0, F - 1)
        j1 = jnp.mod(j0 + 1, F)
        s = phi - j0.astype(phi.dtype)
    return (side, i, i + 1, j0, j1), (t, s)


class Tables(NamedTuple):
    """Tables of a batch of parameter sets: ``values`` (P..., G), one per element of the
    parameters' broadcast shape P, with ``rows`` None; or (K, G), one per distinct set, with
    ``rows`` (P...) the set of each element."""
    values: object
    rows: object = None


def _corners(tables, g: Grid, w):
    """The tables' values at the four nodes of w's cell: ((θ0 φ0, θ0 φ1), (θ1 φ0, θ1 φ1))."""
    if not isinstance(tables, Tables):
        tables = Tables(tables)
    (side, i0, i1, j0, j1), frac = _cell(g, w)
    T, F = len(g.theta), len(g.phi)
    if tables.rows is None:
        table = jnp.broadcast_to(tables.values, jnp.broadcast_shapes(
            tables.values.shape[:-1], w.shape[:-1]) + tables.values.shape[-1:])

        def at(ii, jj):
            idx = (side * T + ii) * F + jj
            return jnp.take_along_axis(table, idx[..., None], axis=-1)[..., 0]
    else:  # a gather per row from the small (K, G) table, none materialized per row
        rows = jnp.broadcast_to(tables.rows, jnp.broadcast_shapes(tables.rows.shape,
                                                                   w.shape[:-1]))

        def at(ii, jj):
            return tables.values[rows, (side * T + ii) * F + jj]

    return ((at(i0, j0), at(i0, j1)), (at(i1, j0), at(i1, j1))), frac


def _neighbourhood(table, g: Grid, w):
    """``table``'s values at the nodes around each direction w: the cell's four and, for an
    azimuthal grid, those of the cells one azimuth step either side."""
    ((a, b), (c, d)), _ = _corners(table, g, w)
    values = [a, b, c, d]
    if len(g.phi) > 1:
        step = 2.0 * np.pi / len(g.phi)
        for turn in (-step, step):
            c_, s_ = float(np.cos(turn)), float(np.sin(turn))
            r = jnp.stack([c_ * w[..., 0] - s_ * w[..., 1], s_ * w[..., 0] + c_ * w[..., 1],
                           w[..., 2]], axis=-1)
            ((a, b), (c, d)), _ = _corners(table, g, r)
            values += [a, b, c, d]
    return values


def lookup_max(table, g: Grid, w):
    """The greatest of ``table``'s values around each direction w (:func:`_neighbourhood`): a
    quantity read as an upper envelope, for a bound that must hold between the nodes too."""
    values = _neighbourhood(table, g, w)
    out = values[0]
    for v in values[1:]:
        out = jnp.maximum(out, v)
    return out


def per_parameter_set(make_table, params: dict) -> Tables:
    """``make_table(params)`` (P..., G) for the parameters' broadcast shape P: once per element
    when P has at most :data:`MAX_ELEMENTS` elements; otherwise (parameters given per row) once
    when every row holds the same set, else once per distinct set, at most
    :data:`MAX_DISTINCT` of them (rows beyond them get NaN)."""
    from fitlab._jax import jax

    names = sorted(params)
    shape = jnp.broadcast_shapes(*(jnp.shape(params[k]) for k in names))
    n = int(np.prod(shape, dtype=np.int64))
    if n <= MAX_ELEMENTS:
        return Tables(make_table(params))
    x = jnp.stack([jnp.broadcast_to(jnp.asarray(params[k]), shape).reshape(-1) for k in names],
                  axis=-1)

    def nan_row(table):
        """A row of NaN after the tables: where a row whose set is not among them points."""
        return jnp.concatenate([table, jnp.full((1,) + table.shape[-1:], jnp.nan, table.dtype)])

    def one(x):
        table = make_table({k: x[0, c] for c, k in enumerate(names)})
        return (nan_row(jnp.broadcast_to(table, (MAX_DISTINCT,) + table.shape[-1:])),
                jnp.zeros(n, jnp.int32))

    def distinct(x):
        sets, inverse = jnp.unique(x, axis=0, size=MAX_DISTINCT, fill_value=x[0],
                                   return_inverse=True)
        inverse = inverse.reshape(-1).astype(jnp.int32)
        table = make_table({k: sets[:, c] for c, k in enumerate(names)})
        found = jnp.all(sets[inverse] == x, axis=-1)
        return nan_row(table), jnp.where(found, inverse, MAX_DISTINCT)

    values, rows = jax.lax.cond(jnp.all(x == x[0]), one, distinct, x)
    return Tables(values, rows.reshape(shape))
