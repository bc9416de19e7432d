"""Axes, mappings and tables: the grid and texel convention every table kind shares, the
lookup a shader performs (in float64), and :class:`Spec`, what a table kind evaluates.

Grid and texel convention (every axis): an axis with N samples stores the value at the axis
coordinate x_i = map(t_i) with t_i = i / (N - 1), i = 0 .. N-1 (see :data:`TEXEL_CONVENTION`).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab.version import __version__
from fitlab.numerics import ALPHA_MIN

#: Schema of the table description (written to EXR headers).
SCHEMA = "fitlab-lut"
SCHEMA_VERSION = 1

#: Allowed number of samples along one axis.
SIZE_MIN, SIZE_MAX = 2, 4096
#: μ below this is evaluated at MU_MIN (the albedo integrands have a finite limit at μ → 0).
MU_MIN = 1e-7


# --------------------------------------------------------------------------------------------
# Axes and mappings
# --------------------------------------------------------------------------------------------


class Mapping(NamedTuple):
    name: str
    #: x(t, lo, hi) for t in [0, 1]
    to_x: Callable
    #: t(x, lo, hi), the inverse (the shader computes this)
    to_t: Callable
    formula: str
    breaks_down: str


def _t_linear(x, lo, hi):
    return (x - lo) / (hi - lo)


def _t_u8(x, lo, hi):
    return np.sqrt(np.sqrt(np.sqrt(np.maximum((hi - x) / (hi - lo), 0.0))))


def _t_sqrt(x, lo, hi):
    return np.sqrt(np.maximum((x - lo) / (hi - lo), 0.0))


def _t_log(x, lo, hi):
    return np.log(np.maximum(x, lo) / lo) / np.log(hi / lo)


MAPPINGS = {
    "linear": Mapping(
        "linear", lambda t, lo, hi: lo + (hi - lo) * t, _t_linear, "x = lo + (hi - lo) t",
        "features narrower than (hi - lo)/(N - 1) are smeared: a D lobe of width α along "
        "cos θh (width ≈ α²/2) is unresolved for α below about sqrt(2/(N - 1))"),
    "u8": Mapping(
        "u8", lambda t, lo, hi: hi - (hi - lo) * t**8, _t_u8, "x = hi - (hi - lo) t^8 (Elek 2010)",
        "dense near hi, sparse near lo (the last texel spans 1 - (1 - 1/(N-1))^8 ≈ 8/(N-1) of the "
        "range); in float32 the shader's hi - x (1 - cos θh) has no digits below 6e-8, so lobes "
        "narrower than α ≈ 3e-4 are quantized by the input itself, not the table"),
    "sqrt": Mapping(
        "sqrt", lambda t, lo, hi: lo + (hi - lo) * t**2, _t_sqrt, "x = lo + (hi - lo) t^2",
        "dense near lo; the first interval spans (hi - lo)/(N - 1)^2, so relative steps are "
        "large just above lo when lo is tiny"),
    "log": Mapping(
        "log", lambda t, lo, hi: lo * (hi / lo) ** t, _t_log, "x = lo (hi/lo)^t",
        "equal ratios between samples; needs 0 < lo < hi; coarse near hi when the range spans "
        "many decades"),
}


class Axis(NamedTuple):
    """One table axis: ``size`` samples of coordinate ``name`` over [lo, hi] at
    x_i = mapping(i / (size - 1))."""

    name: str
    lo: float
    hi: float
    size: int
    mapping: str
    description: str

    def nodes(self) -> np.ndarray:
        t = np.arange(self.size) / (self.size - 1)
        x = MAPPINGS[self.mapping].to_x(t, self.lo, self.hi)
        x[0], x[-1] = MAPPINGS[self.mapping].to_x(np.array([0.0, 1.0]), self.lo, self.hi)
        return x

    def to_t(self, x) -> np.ndarray:
        return np.clip(MAPPINGS[self.mapping].to_t(np.asarray(x, float), self.lo, self.hi), 0.0, 1.0)

    def to_x(self, t) -> np.ndarray:
        return MAPPINGS[self.mapping].to_x(np.asarray(t, float), self.lo, self.hi)


class Table(NamedTuple):
    """A baked table. ``values`` is float64 of shape (H, W, C) as it will be stored (already
    rounded to ``dtype``): axes[0] runs along the width, axes[1] along the height, and a third
    axis (if any) stacks axes[1]-high slices along the height (H = axes[1].size × axes[2].size)."""

    kind: str
    values: np.ndarray
    channels: tuple
    axes: tuple
    dtype: str
    quantity: str
    model: dict | None
    params: dict
    accuracy: dict
    source_fit: str | None = None
    notes: tuple = ()

    def describe(self) -> dict:
        """Everything but the values, as JSON-ready data (what the EXR header holds)."""
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": self.kind,
            "channels": list(self.channels), "dtype": self.dtype, "quantity": self.quantity,
            "axes": [a._asdict() for a in self.axes], "model": self.model, "params": self.params,
            "accuracy": self.accuracy, "source_fit": self.source_fit, "notes": list(self.notes),
            "texel_convention": TEXEL_CONVENTION, "fitlab_version": __version__,
        }


TEXEL_CONVENTION = (
    "sample i of an N-sample axis is at t = i/(N-1) (first and last texel centres at the ends of "
    "the range); a shader maps x to t = map^-1(x) clamped to [0, 1], then to the texture "
    "coordinate s = (t (N-1) + 0.5)/N and filters bilinearly; a third axis stacks slices of "
    "axes[1].size rows along the height and is interpolated linearly between two slices")


# --------------------------------------------------------------------------------------------
# Lookup (the same arithmetic as the generated shader, in float64)
# --------------------------------------------------------------------------------------------


def _texel_pos(axis: Axis, x):
    """Continuous sample index p in [0, N-1] of coordinate x (what s·N - 0.5 is in a shader)."""
    return axis.to_t(x) * (axis.size - 1)


def _lerp_index(p, n):
    i0 = np.clip(np.floor(p).astype(int), 0, n - 2) if n > 1 else np.zeros_like(p, dtype=int)
    return i0, (p - i0)[..., None]


def lookup(table: Table, coords) -> np.ndarray:
    """Bilinear (trilinear with a slice axis) interpolation of the stored values at axis
    coordinates ``coords`` (P, n_axes) → (P, C), exactly as the generated shader reads them."""
    coords = np.atleast_2d(np.asarray(coords, float))
    v = table.values
    ax = table.axes
    if len(ax) == 1:
        i, f = _lerp_index(_texel_pos(ax[0], coords[:, 0]), ax[0].size)
        return v[0, i] * (1 - f) + v[0, i + 1] * f
    i, fx = _lerp_index(_texel_pos(ax[0], coords[:, 0]), ax[0].size)
    j, fy = _lerp_index(_texel_pos(ax[1], coords[:, 1]), ax[1].size)

    def bilinear(row0):
        r0, r1 = row0 + j, row0 + j + 1
        a = v[r0, i] * (1 - fx) + v[r0, i + 1] * fx
        b = v[r1, i] * (1 - fx) + v[r1, i + 1] * fx
        return a * (1 - fy) + b * fy

    if len(ax) == 2:
        return bilinear(0)
    k, fz = _lerp_index(_texel_pos(ax[2], coords[:, 2]), ax[2].size)
    n1 = ax[1].size
    return bilinear(k * n1) * (1 - fz) + bilinear((k + 1) * n1) * fz


def grid_coords(axes) -> np.ndarray:
    """Axis coordinates of every stored sample, (H·W, n_axes), in storage (row-major) order."""
    nodes = [a.nodes() for a in axes]
    if len(axes) == 1:
        return nodes[0][:, None]
    if len(axes) == 2:
        Y, X = np.meshgrid(nodes[1], nodes[0], indexing="ij")
        return np.stack([X.ravel(), Y.ravel()], axis=-1)
    Z, Y, X = np.meshgrid(nodes[2], nodes[1], nodes[0], indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=-1)


def shape_of(axes, n_channels):
    """(H, W, C) of a table with these axes (a third axis stacks slices along the height)."""
    if len(axes) == 1:
        return (1, axes[0].size, n_channels)
    h = axes[1].size * (axes[2].size if len(axes) == 3 else 1)
    return (h, axes[0].size, n_channels)



# --------------------------------------------------------------------------------------------
# What a table kind evaluates
# --------------------------------------------------------------------------------------------


class Spec(NamedTuple):
    """What a table kind evaluates: ``evaluate(coords (P, n_axes)) -> (values (P, C), error
    estimate (P, C) or None)``; bake() runs it at the grid nodes."""

    kind: str
    channels: tuple
    axes: tuple
    evaluate: Callable
    quantity: str
    model: dict | None
    params: dict
    method: str
    notes: tuple = ()
    n_check: int = 2048
    orders: dict | None = None
    #: further accuracy checks of the baked table: ((name, check(table, spec, n_points) -> dict),
    #: ...), stored as accuracy[name] (e.g. the model table's parameterization error)
    checks: tuple = ()


def make_axis(name, lo, hi, size, mapping, description):
    """An :class:`Axis` after checking its mapping, size and range (ValueError naming the axis)."""
    if mapping not in MAPPINGS:
        raise ValueError(f"axis {name}: unknown mapping {mapping!r}; choose one of "
                         f"{', '.join(MAPPINGS)}")
    if int(size) != size or not SIZE_MIN <= size <= SIZE_MAX:
        raise ValueError(f"axis {name}: size must be an integer in [{SIZE_MIN}, {SIZE_MAX}], "
                         f"got {size!r}")
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"axis {name}: the range [{lo}, {hi}] must be finite with lo < hi")
    if mapping == "log" and lo <= 0:
        raise ValueError(f"axis {name}: the log mapping needs lo > 0, got {lo}")
    return Axis(name, lo, hi, int(size), mapping, description)


def alpha_axis(size, mapping, rng):
    lo, hi = rng
    if lo < ALPHA_MIN or hi > 1.0:
        raise ValueError(f"axis alpha: the range must lie within [{ALPHA_MIN:g}, 1], got "
                         f"[{lo:g}, {hi:g}]")
    return make_axis("alpha", lo, hi, size, mapping, "microfacet width α (Walter α_b / α_g)")


def mu_axis(size, mapping):
    return make_axis("mu", 0.0, 1.0, size, mapping,
                 f"μ = cos θi of the incident direction (values at μ < {MU_MIN:g} are the limit)")

