"""Lookup tables for shaders: pure functions that bake 1D/2D/3D tables of BSDF quantities and
return them with everything a shader author needs to read them back (axes, mappings, texel
convention, model, parameters, measured accuracy). No file I/O here: ``fitlab.export.exr`` writes
a :class:`Table`, ``fitlab.export.shader`` writes the GLSL/HLSL that reads it.

Table kinds (:data:`KINDS`):

``D``                 π α² D(cos θh; α) over (cos θh, α) for one microfacet distribution (Walter
                      eqs 25, 30, 33); D = value / (π α²). The scale keeps the peak near 1 (half
                      floats overflow at D > 65504, i.e. GGX α < 2.2e-3) and makes the α direction
                      smooth. Elek 2010 section 3.1: 512 × 512, non-linear u⁸ axis for the
                      near-specular part; α on a log axis by default (Elek's linear α axis is an
                      option: measured 17× larger RMS error at 512², benchmarks/lut_accuracy.py).
``fresnel``           F(cos θ) for one material (Elek 2010 section 3.1, 128 samples): a conductor
                      (n, k) per channel (presets copper / chromium / cuprite, Elek appendix A) or
                      a dielectric η (channels for incidence from outside and from inside).
``albedo_conductor``  directional albedo E(μ, α) = ∫ f cos θo dωo of the microfacet BRDF with
                      F = 1 (the energy-compensation table of Kulla & Conty 2017) and, in a
                      second channel, the average albedo E_avg(α) = 2 ∫ E(μ) μ dμ.
``albedo_dielectric`` the same for a rough dielectric interface over (μ, α, η): reflection and
                      transmission, for incidence from outside (relative index η) and from inside
                      (1/η), and their averages; η slices are stacked along the height.
``dfg``               the split-sum DFG table (Karis 2013): scale and bias with
                      ∫ f cos θo dωo = F0 · scale + bias under Schlick's Fresnel.
``model``             a registry model's (or a fit's) own BRDF f(wi, wo) over (cos θh, cos θd)
                      in Rusinkiewicz's half/difference parameterization at φd = 90°, or, with a
                      third size, over (cos θh, cos θd, φd) (φd folded into [0°, 90°] for a
                      reciprocal model). :func:`bake_auto` lets the measured parameterization
                      error choose (``fitlab lut model``'s default, ``--phi-d auto``).

Grid and texel convention (every axis): an axis with N samples stores the value at the axis
coordinate x_i = map(t_i) with t_i = i / (N - 1), i = 0 .. N-1: the first and last texel centres
sit exactly at the ends of the range. A shader turns a coordinate x into t = map⁻¹(x) (clamped to
[0, 1]) and into the texture coordinate s = (t (N - 1) + 0.5) / N, so that hardware bilinear
filtering interpolates between the stored samples. Mappings (:data:`MAPPINGS`): ``linear``,
``u8`` (Elek's x = hi - (hi - lo) t⁸: dense near hi), ``sqrt`` (x = lo + (hi - lo) t²: dense
near lo) and ``log`` (x = lo (hi/lo)^t).

Integrals (albedo, DFG) use deterministic quadrature (``fitlab.quadrature``), never Monte
Carlo (:mod:`fitlab.lut.albedo`). Every table stores the values of the higher of two quadrature
orders and, as its error estimate, the difference to the lower one. Accuracy against direct
evaluation (bilinear lookup of the stored, rounded values at random points vs the model or a
fresh quadrature there) is measured for every table and stored in it (:func:`measure_accuracy`).

Modules: :mod:`~fitlab.lut.axes` (mappings, axes, :class:`Table`, :func:`lookup`, the grid and
:class:`Spec`), :mod:`~fitlab.lut.albedo` (albedo quadrature), :mod:`~fitlab.lut.baking`
(:func:`bake`, :func:`measure_accuracy`, :func:`round_to`) and :mod:`~fitlab.lut.kinds` (the
evaluators, the :data:`KINDS` registry whose entries carry their table maker, what they need
from a model or fit and their optional axes, :func:`make_spec`, :func:`bake_auto`). To add a
kind: write its ``spec_*`` evaluator and its ``make`` / ``prepare`` in kinds.py and register a
:class:`Kind`.
"""

from fitlab.lut.albedo import ALBEDO_DISTRIBUTIONS, QUAD_ORDERS, albedo_integrals
from fitlab.lut.axes import (
    MAPPINGS, MU_MIN, SCHEMA, SCHEMA_VERSION, SIZE_MAX, SIZE_MIN, TEXEL_CONVENTION, Axis, Mapping,
    Spec, Table, grid_coords, lookup,
)
from fitlab.lut.baking import HALF_MAX, REL_FLOOR, TEXELS_MAX, bake, measure_accuracy, round_to
from fitlab.lut.kinds import (
    KINDS, PHI_D, PHI_D_SIZE, PHI_D_TARGET, Kind, bake_auto, conductor_preset, get_kind,
    halfdiff_coordinates, halfdiff_directions, make_spec, model_coordinates, phi_d_of,
    spec_albedo_conductor, spec_albedo_dielectric, spec_D, spec_dfg, spec_fresnel, spec_model,
    spec_of_table,
)
from fitlab.numerics import ALPHA_MIN

__all__ = [
    "Axis", "Table", "Spec", "Kind", "KINDS", "MAPPINGS", "bake", "lookup", "make_spec",
    "spec_of_table", "measure_accuracy", "albedo_integrals", "conductor_preset",
    "halfdiff_directions", "halfdiff_coordinates", "phi_d_of", "model_coordinates", "bake_auto",
    "PHI_D", "PHI_D_TARGET", "PHI_D_SIZE", "grid_coords", "round_to",
    # imported by fitlab.export, the tests and the benchmarks
    "get_kind", "Mapping", "SCHEMA", "SCHEMA_VERSION", "SIZE_MIN", "SIZE_MAX", "TEXEL_CONVENTION",
    "TEXELS_MAX", "HALF_MAX", "REL_FLOOR", "MU_MIN", "ALPHA_MIN", "QUAD_ORDERS",
    "ALBEDO_DISTRIBUTIONS", "spec_D", "spec_fresnel", "spec_albedo_conductor", "spec_dfg",
    "spec_albedo_dielectric", "spec_model",
]
