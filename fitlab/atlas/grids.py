"""The validation atlas's grids: for each layered model family, the two parameters it is mapped
over, their values, the parameters held fixed, the options and the incidences. Data, one
:class:`Spec` per entry of :data:`GRIDS` (a :class:`fitlab.registry.Registry` keyed by the
model's registry name): the code that computes, draws and looks up the atlas reads these fields
and never a model's name.

A parameter not on an axis is held at the registry's typical value (``Parameter.default``)
unless ``fixed`` names it; options are the model's defaults unless ``options`` names them.

Why these grids (7 × 7 values, log axes for widths α, concentrations κ and thicknesses Tρ): each
pair is the two parameters that move the model's approximation most (which bounces or orders it
leaves out, how glossy the layer it refracts through is), over the range a fit meets.

- ``coated(rough_conductor)`` α × coat η: the single bounce under a smooth coat misses the
  light the coat reflects back down (more of it as η grows) onto a glossy or rough base.
- ``coated(lambertian)`` albedo × coat η: the default ``interreflection=single`` misses the
  inter-reflections between coat and base, which grow with the albedo.
- ``weidlich_wilkie(rough_conductor)`` α1 × α2: the collimated single-point assumption
  (refraction through the macro normal, no blur by the rough top interface) against the base's
  own roughness.
- ``weidlich_wilkie(lambertian)`` α1 × albedo2: the same assumption, and the eq. 4 TIR term's
  account of the base's inter-reflections, which grow with its albedo (τ1 = 0: absorption only
  scales the subsurface light and is left at its typical 0).
- ``thin_layer(rough_conductor)`` κ1 × κ2 and ``thin_layer(rough_dielectric)`` κ1 × η: the
  joint spherical warping's range (Guo et al. 2015) and fitlab's energy compensation, whose
  table spans κ 10 … 10⁴ (fitlab/models/thin_layer_compensation.py).
- ``spongecake(surface)`` and ``spongecake(surface,multiple=learned)`` α × Tρ: single scattering
  (the default) against every order, and the learned multiple-scattering lobe over the range its
  network was trained on (α 0.05 … 1, Tρ 0.1 … 10:
  fitlab/models/data/spongecake_ms_1layer.json).
"""

from __future__ import annotations

from typing import NamedTuple

from fitlab.registry import Registry

#: The incidences of every grid (degrees from the normal); the region's verdict reads those
#: up to :data:`REGION_MAX_THETA_DEG`.
THETA_I_DEG = (0.0, 30.0, 60.0, 80.0)
REGION_MAX_THETA_DEG = 80.0
#: The simulator's hemisphere bins of each observed side (uniform in θ and φ: 10° × 10°).
THETA_BINS, PHI_BINS = 9, 36


class Axis(NamedTuple):
    """One axis of a grid: a model parameter, its values (ascending), how it is drawn and
    interpolated (``log`` or ``linear``) and what the maps call it."""

    name: str
    values: tuple
    scale: str = "linear"
    label: str = ""


class Spec(NamedTuple):
    """One atlas entry's grid: ``model`` (a registry name), the two axes, the parameters held
    at stated values (``fixed``; the others at the registry's typical values), the options set
    (``options``; the others at the model's defaults), the incidences, and ``seconds_per_point``:
    the measured cost of one grid point at the default sample counts (2-core CPU), for the
    estimate printed before a run."""

    model: str
    axes: tuple
    fixed: dict = {}
    options: dict = {}
    theta_i: tuple = THETA_I_DEG
    seconds_per_point: float = 2.0


ALPHA = (0.01, 0.02, 0.05, 0.1, 0.2, 0.4, 0.8)
COAT_ETA = (1.1, 1.25, 1.4, 1.55, 1.7, 2.0, 2.5)
ALBEDO = (0.05, 0.2, 0.35, 0.5, 0.65, 0.8, 0.95)
KAPPA = (10.0, 31.6, 100.0, 316.0, 1000.0, 3160.0, 10000.0)
LAYER_ETA = (1.1, 1.2, 1.33, 1.5, 1.7, 2.0, 2.5)
FLAKE_ALPHA = (0.05, 0.08, 0.13, 0.2, 0.35, 0.6, 1.0)
T_RHO = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)


def _specs() -> tuple:
    base_alpha = Axis("alpha", ALPHA, "log", "microfacet width α of the base")
    coat_eta = Axis("coat_eta", COAT_ETA, "linear", "coat index η1/η0")
    alpha1 = Axis("alpha1", ALPHA, "log", "top interface width α1")
    kappa1 = Axis("kappa1", KAPPA, "log", "top vMF concentration κ1")
    flakes = (Axis("alpha1", FLAKE_ALPHA, "log", "flake roughness α"),
              Axis("tau1", T_RHO, "log", "thickness Tρ"))
    return (
        Spec("coated(rough_conductor)", (base_alpha, coat_eta), fixed={"coat_tau": 0.0},
             seconds_per_point=0.2),
        Spec("coated(lambertian)", (Axis("albedo", ALBEDO, "linear", "base albedo ρ"), coat_eta),
             fixed={"coat_tau": 0.0}, seconds_per_point=0.35),
        Spec("weidlich_wilkie(rough_conductor)",
             (alpha1, Axis("alpha2", ALPHA, "log", "base width α2")), fixed={"tau1": 0.0},
             seconds_per_point=0.2),
        Spec("weidlich_wilkie(lambertian)",
             (alpha1, Axis("albedo2", ALBEDO, "linear", "base albedo ρ2")), fixed={"tau1": 0.0},
             seconds_per_point=0.35),
        Spec("thin_layer(rough_conductor)",
             (kappa1, Axis("kappa2", KAPPA, "log", "bottom vMF concentration κ2")),
             fixed={"tau": 0.0}, seconds_per_point=1.5),
        Spec("thin_layer(rough_dielectric)",
             (kappa1, Axis("eta", LAYER_ETA, "linear", "layer index η")), fixed={"tau": 0.0},
             seconds_per_point=1.3),
        Spec("spongecake(surface)", flakes, seconds_per_point=0.2),
        Spec("spongecake(surface,multiple=learned)", flakes, seconds_per_point=0.25),
    )


#: The atlas's entries by model name, in the order the page shows them.
GRIDS: Registry = Registry("atlas model", {s.model: s for s in _specs()},
                           listing="`fitlab atlas --help`")


def quick(spec: Spec) -> Spec:
    """``spec`` for ``--quick``: every third value of each axis (both ends kept: 7 → 3)."""
    def thin(values):
        keep = list(values[::3])
        return tuple(keep if keep[-1] == values[-1] else keep + [values[-1]])

    return spec._replace(axes=tuple(a._replace(values=thin(a.values)) for a in spec.axes))


def with_values(spec: Spec, values: dict | None = None, theta_i=None) -> Spec:
    """``spec`` with the values of some axes replaced (``values``: {axis name: values}) and
    other incidences; ValueError saying what to do for an axis the grid does not have, fewer
    than two values, values not ascending or incidences outside [0°, 89°]."""
    axes = list(spec.axes)
    for name, vals in (values or {}).items():
        names = [a.name for a in axes]
        if name not in names:
            raise ValueError(f"{spec.model}'s atlas grid has no axis {name!r}; its axes are "
                             f"{' and '.join(names)}")
        vals = tuple(float(v) for v in vals)
        if len(vals) < 2 or any(b <= a for a, b in zip(vals, vals[1:])):
            raise ValueError(f"--values {name}=...: give at least two ascending values")
        k = names.index(name)
        if axes[k].scale == "log" and vals[0] <= 0:
            raise ValueError(f"--values {name}=...: a log axis needs values above 0")
        axes[k] = axes[k]._replace(values=vals)
    out = spec._replace(axes=tuple(axes))
    if theta_i is not None:
        t = tuple(float(x) for x in theta_i)
        if not t or any(not 0.0 <= x <= 89.0 for x in t) or len(set(t)) != len(t):
            raise ValueError("--theta-i: give distinct incidences in [0, 89] degrees")
        out = out._replace(theta_i=tuple(sorted(t)))
    return out


__all__ = ["ALPHA", "Axis", "GRIDS", "PHI_BINS", "REGION_MAX_THETA_DEG", "Spec", "THETA_BINS",
           "THETA_I_DEG", "quick", "with_values"]
