"""The simulator's boundaries and phase functions: Mitsuba 3's own plugins where Mitsuba has them,
behind the adapter of protocol.py, and fitlab's own (own_bsdfs.py) where it has not.

Two name → behaviour tables, :data:`BOUNDARIES` (by boundary kind) and :data:`PHASES` (by phase
kind), build one object per boundary or region of a stack. Their parameters are Dr.Jit arrays
made opaque (kernel inputs, not constants), so a stack *structure* compiles once whatever its
values.

Mitsuba's conventions, converted here and nowhere else (:func:`f_from_mitsuba`): the walk
traces flux from the light, so every Mitsuba BSDF runs in ``TransportMode.Importance`` with
``si.wi`` toward the light; its sample weight is then the fraction of flux carried (no 1/η² of
radiance transport), and its ``eval`` is f(wi, wo)|cos θo| with f in fitlab's (radiance)
convention — checked against fitlab's JAX models in tests/simulate/test_simulate_engine.py.

Used from Mitsuba (variant llvm_ad_rgb / cuda_ad_rgb): ``roughdielectric`` and
``roughconductor`` (GGX, isotropic and anisotropic, visible-normal sampling),
``conductor``, ``diffuse``, the ``hg`` and ``isotropic`` phase functions, Mitsuba's SGGX
functions (``sggx_sample``, ``sggx_pdf``, ``sggx_projected_area``: see :class:`SGGXPhase` for why
not its ``sggx`` plugin), and ``mi.fresnel`` / ``mi.refract`` / ``mi.reflect`` for the smooth
dielectric (Mitsuba's ``dielectric`` plugin keeps η as a constant compiled into the kernel). fitlab's own: the
Beckmann (exact and rational masking), Phong and vMF interfaces (see
:data:`MITSUBA_DISTRIBUTIONS` for why not Mitsuba's Beckmann), the SGGX flakes' Schlick Fresnel
(SpongeCake eq. 5).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab.registry import Registry
from fitlab.simulate.protocol import FORCE_CHOOSE, FORCE_REFLECT, FORCE_REFRACT

#: Microfacet distributions Mitsuba's rough plugins implement as fitlab defines them (fitlab name
#: → Mitsuba name). Mitsuba's ``beckmann`` masks with Walter's rational eq. 27 (0.3 % from the
#: exact erf G1 of fitlab's ``beckmann``), and its visible-normal sampling follows the exact one,
#: so neither Beckmann family is Mitsuba's: both are written in own_bsdfs.py.
MITSUBA_DISTRIBUTIONS = {"ggx": "ggx"}


class BoundarySpec(NamedTuple):
    """The structure of one boundary (static: part of the compiled kernel's key).

    kind: ``pass``, ``dielectric``, ``lambertian`` or ``conductor``; distribution: ``smooth``
    or a microfacet family of fitlab.microfacet.REGISTRY; anisotropic: widths α_x ≠ α_y."""

    kind: str
    distribution: str = "smooth"
    anisotropic: bool = False

    @property
    def specular(self) -> bool:
        return self.kind in ("dielectric", "conductor") and self.distribution == "smooth"

    @property
    def nonspecular(self) -> bool:
        return self.kind != "pass" and not self.specular


class BoundaryValues(NamedTuple):
    """The parameter values of one boundary (kernel inputs)."""

    alpha: float = 0.0
    alpha_y: float = 0.0
    eta: float = 1.0  # n_below / n_above
    albedo: tuple = (0.0, 0.0, 0.0)  # per channel
    n: tuple = (1.0, 1.0, 1.0)  # conductor, relative to the medium above
    k: tuple = (0.0, 0.0, 0.0)


def f_from_mitsuba(value, wo):
    """fitlab's f (1/sr, no cosine) from a Mitsuba ``eval`` in importance transport, which is
    f(wi, wo)|cos θo|."""
    import drjit as dr

    cos_o = dr.abs(wo.z)
    return dr.select(cos_o > 0, value / dr.maximum(cos_o, 1e-30), 0.0)


def _opaque(obj):
    """Make every parameter of a Mitsuba object a kernel input (not a compiled constant)."""
    import drjit as dr
    import mitsuba as mi

    params = mi.traverse(obj)
    for key in params.keys():
        value = params[key]
        if dr.is_array_v(value):
            dr.make_opaque(value)
    return obj


def _rgb(values):
    v = [float(x) for x in values]
    return {"type": "rgb", "value": v * 3 if len(v) == 1 else v}


def _local_si(wi):
    import drjit as dr
    import mitsuba as mi

    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = wi
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    return si


class MitsubaBoundary:
    """A Mitsuba BSDF behind the protocol (importance transport, local frame +z up).

    ``eta`` (a rough dielectric's n_below/n_above, a kernel input): the walk may force a branch
    here. One unforced Mitsuba ``sample`` serves every lane: its lobe choice (reflect when
    ``sample1`` ≤ F) is forced by passing ``sample1`` = 0 (reflect) or 1 (refract; under total
    internal reflection F = 1 and the forced refraction's weight 1 − F is 0), and the weight
    times F or 1 − F at the sampled microfacet (Walter eq. 22 from ``mi.fresnel``) is the
    forced branch's, as Mitsuba's own ``type_mask`` contexts weight it; its density stays the
    unforced one. A branch forced for every lane (``force`` one int) is sampled in that
    branch's context itself."""

    def __init__(self, bsdf, nonspecular: bool, eta=None):
        import mitsuba as mi

        self.bsdf = _opaque(bsdf)
        self.nonspecular = nonspecular
        self.eta = eta
        self.ctx = mi.BSDFContext(mi.TransportMode.Importance)
        # one branch for every lane: Mitsuba's own one-lobe contexts
        self.ctx_lobe = {code: mi.BSDFContext(mi.TransportMode.Importance, flags)
                         for code, flags in ((FORCE_REFLECT, mi.BSDFFlags.Reflection),
                                             (FORCE_REFRACT, mi.BSDFFlags.Transmission))}

    def sample(self, wi, sample1, sample2, force, active, need_pdf=False):
        import drjit as dr
        import mitsuba as mi

        si = _local_si(wi)
        if self.eta is not None and isinstance(force, int) and force != FORCE_CHOOSE:
            return self._sample_lobe(si, sample1, sample2, force, active, need_pdf)
        if self.eta is not None:
            sample1 = dr.select(force == FORCE_REFLECT, 0.0,
                                dr.select(force == FORCE_REFRACT, 1.0, sample1))
        bs, weight = self.bsdf.sample(self.ctx, si, sample1, sample2, active)
        wo, pdf = dr.normalize(bs.wo), bs.pdf
        weight = mi.Spectrum(weight)
        if self.eta is not None:
            reflected = wo.z * wi.z > 0
            eta_local = dr.select(wi.z > 0, self.eta, 1.0 / self.eta)
            h = dr.normalize(dr.select(reflected, wi + wo, wi + wo * eta_local))
            h = dr.mulsign(h, h.z)
            F = mi.fresnel(dr.dot(wi, h), self.eta)[0]
            factor = dr.select(force == FORCE_CHOOSE, 1.0,
                               dr.select(force == FORCE_REFLECT,
                                         dr.select(reflected, F, 0.0),
                                         dr.select(reflected, 0.0, 1.0 - F)))
            weight = weight * factor
        ok = active & (pdf > 0) & dr.all(dr.isfinite(weight))
        weight = dr.select(ok, weight, 0.0)
        pdf = dr.select(ok & self.nonspecular, pdf, 0.0)
        return wo, weight, pdf

    def _sample_lobe(self, si, sample1, sample2, force: int, active, need_pdf):
        """:meth:`sample` with one branch forced for every lane: Mitsuba's sampling in that
        lobe's context (its weight holds F or 1 − F), the density the unforced one."""
        import drjit as dr
        import mitsuba as mi

        bs, weight = self.bsdf.sample(self.ctx_lobe[force], si, sample1, sample2, active)
        wo = dr.normalize(bs.wo)
        weight = mi.Spectrum(weight)
        ok = active & (bs.pdf > 0) & dr.all(dr.isfinite(weight))
        pdf = self.bsdf.pdf(self.ctx, si, wo, ok) if need_pdf else mi.Float(0.0)
        return wo, dr.select(ok, weight, 0.0), dr.select(ok & self.nonspecular, pdf, 0.0)

    def eval(self, wi, wo, active):
        return f_from_mitsuba(self.bsdf.eval(self.ctx, _local_si(wi), wo, active), wo)

    def pdf(self, wi, wo, active):
        return self.bsdf.pdf(self.ctx, _local_si(wi), wo, active)

    def eval_pdf(self, wi, wo, active):
        value, pdf = self.bsdf.eval_pdf(self.ctx, _local_si(wi), wo, active)
        return f_from_mitsuba(value, wo), pdf


class SmoothDielectric:
    """A flat dielectric interface, η = n_below/n_above a kernel input: reflect with probability
    F (Walter eq. 22, total internal reflection included), else refract by Snell's law, with
    Mitsuba's ``fresnel``, ``reflect`` and ``refract``. Specular: eval and pdf are 0."""

    nonspecular = False

    def __init__(self, eta: float):
        import drjit as dr
        import mitsuba as mi

        self.eta = dr.opaque(mi.Float, eta)

    def sample(self, wi, sample1, sample2, force, active, need_pdf=False):
        import drjit as dr
        import mitsuba as mi

        r, cos_t, eta_it, eta_ti = mi.fresnel(wi.z, self.eta)
        reflect = sample1 < r
        reflect = dr.select(force == FORCE_CHOOSE, reflect, force == FORCE_REFLECT)
        factor = dr.select(force == FORCE_CHOOSE, 1.0, dr.select(reflect, r, 1.0 - r))
        wo = dr.select(reflect, mi.reflect(wi), mi.refract(wi, cos_t, eta_ti))
        weight = dr.select(active, mi.Spectrum(factor), 0.0)
        return wo, weight, mi.Float(0.0)

    def eval(self, wi, wo, active):
        import mitsuba as mi

        return mi.Spectrum(0.0)

    def pdf(self, wi, wo, active):
        import mitsuba as mi

        return mi.Float(0.0)

    def eval_pdf(self, wi, wo, active):
        return self.eval(wi, wo, active), self.pdf(wi, wo, active)


def _dielectric(spec: BoundarySpec, v: BoundaryValues, forceable: bool):
    import mitsuba as mi

    if spec.distribution == "smooth":
        return SmoothDielectric(v.eta)
    if spec.distribution in MITSUBA_DISTRIBUTIONS:
        d = {"type": "roughdielectric", "distribution": MITSUBA_DISTRIBUTIONS[spec.distribution],
             "int_ior": float(v.eta), "ext_ior": 1.0, "sample_visible": True}
        d.update({"alpha_u": v.alpha, "alpha_v": v.alpha_y} if spec.anisotropic
                 else {"alpha": v.alpha})
        bsdf = mi.load_dict(d)
        return MitsubaBoundary(bsdf, True, mi.traverse(_opaque(bsdf))["eta"] if forceable
                               else None)
    from fitlab.simulate.own_bsdfs import OwnRoughDielectric

    return OwnRoughDielectric(spec.distribution, _f(v.alpha),
                              _f(v.alpha_y) if spec.anisotropic else None, _f(v.eta))


def _conductor(spec: BoundarySpec, v: BoundaryValues, forceable: bool):
    import mitsuba as mi

    nk = {"eta": _rgb(v.n), "k": _rgb(v.k)}
    if spec.distribution == "smooth":
        return MitsubaBoundary(mi.load_dict({"type": "conductor", **nk}), False)
    if spec.distribution in MITSUBA_DISTRIBUTIONS:
        d = {"type": "roughconductor", "distribution": MITSUBA_DISTRIBUTIONS[spec.distribution],
             "sample_visible": True, **nk}
        d.update({"alpha_u": v.alpha, "alpha_v": v.alpha_y} if spec.anisotropic
                 else {"alpha": v.alpha})
        return MitsubaBoundary(mi.load_dict(d), True)
    from fitlab.simulate.own_bsdfs import OwnRoughConductor

    return OwnRoughConductor(spec.distribution, _f(v.alpha),
                             _f(v.alpha_y) if spec.anisotropic else None,
                             _spectrum(v.n), _spectrum(v.k))


def _lambertian(spec: BoundarySpec, v: BoundaryValues, forceable: bool):
    import mitsuba as mi

    return MitsubaBoundary(mi.load_dict({"type": "diffuse", "reflectance": _rgb(v.albedo)}),
                           True)


def _f(x):
    import drjit as dr
    import mitsuba as mi

    return dr.opaque(mi.Float, float(x))


def _spectrum(values):
    import drjit as dr
    import mitsuba as mi

    v = [float(x) for x in values]
    v = v * 3 if len(v) == 1 else v
    return dr.opaque(mi.Spectrum, v)


#: boundary kind → builder(spec, values, forceable) of a protocol.py boundary (None: no event).
BOUNDARIES: Registry[Callable | None] = Registry("boundary kind", {
    "pass": None,
    "dielectric": _dielectric,
    "lambertian": _lambertian,
    "conductor": _conductor,
})


def make_boundary(spec: BoundarySpec, values: BoundaryValues, forceable: bool = False):
    """The boundary object of ``spec`` with ``values`` (None for ``pass``)."""
    builder = BOUNDARIES[spec.kind]
    return None if builder is None else builder(spec, values, forceable)


# --------------------------------------------------------------------------------------------
# Phase functions
# --------------------------------------------------------------------------------------------


def _medium_interaction(wi):
    import drjit as dr
    import mitsuba as mi

    mei = dr.zeros(mi.MediumInteraction3f)
    mei.wi = wi
    mei.sh_frame = mi.Frame3f(wi)
    mei.p = mi.Point3f(0.5, 0.5, 0.5)  # the centre of a constant SGGX grid
    return mei


class MitsubaPhase:
    """A Mitsuba phase function behind the protocol (``wi`` back along the path)."""

    def __init__(self, phase):
        import mitsuba as mi

        self.phase = _opaque(phase)
        self.ctx = mi.PhaseFunctionContext(None)

    def sample(self, wi, sample1, sample2, active):
        wo, weight, pdf = self.phase.sample(self.ctx, _medium_interaction(wi), sample1, sample2,
                                            active)
        return wo, weight, pdf

    def eval(self, wi, wo, active):
        value, _ = self.phase.eval_pdf(self.ctx, _medium_interaction(wi), wo, active)
        return value.x

    def projected_area(self, w, active):
        """σ(w), the SGGX projected flake area (SpongeCake eq. 3/7); 1 for other phases."""
        import mitsuba as mi

        return mi.Float(1.0)


class SGGXPhase:
    """The specular microflake phase function of the SGGX distribution (SpongeCake eq. 4 with
    F = 1; Heitz et al. 2015) from Mitsuba's ``sggx_sample``, ``sggx_pdf`` and
    ``sggx_projected_area``, S a kernel input.

    Mitsuba's ``sggx`` plugin is not used: its ``sample`` does not follow its own ``eval_pdf``
    for a general incident direction (``sggx_sample`` projects S into the frame with the
    transposed basis: measured, the mean sampled direction differed from the quadrature of the
    density by 0.8 for a fiber along x; tests/simulate/test_simulate_engine.py), and its S lives in a
    volume texture looked up at every call. Here S is expressed in the frame of wi by fitlab
    (S' = Bᵀ S B, B = [s t wi]) and ``sggx_sample`` is called in the identity frame, where the
    two conventions agree."""

    def __init__(self, S: np.ndarray):
        import drjit as dr
        import mitsuba as mi

        six = [S[0, 0], S[1, 1], S[2, 2], S[0, 1], S[0, 2], S[1, 2]]
        self.S = [dr.opaque(mi.Float, float(x)) for x in six]

    def _params(self, six=None):
        import mitsuba as mi

        return mi.SGGXPhaseFunctionParams(six or self.S)

    def _quad(self, a, b):
        """aᵀ S b."""
        xx, yy, zz, xy, xz, yz = self.S
        return (a.x * (xx * b.x + xy * b.y + xz * b.z) + a.y * (xy * b.x + yy * b.y + yz * b.z)
                + a.z * (xz * b.x + yz * b.y + zz * b.z))

    def sample(self, wi, sample1, sample2, active):
        import drjit as dr
        import mitsuba as mi

        frame = mi.Frame3f(wi)
        s, t, n = frame.s, frame.t, frame.n
        local = [self._quad(s, s), self._quad(t, t), self._quad(n, n), self._quad(s, t),
                 self._quad(s, n), self._quad(t, n)]
        identity = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        m = frame.to_world(mi.Vector3f(mi.sggx_sample(identity, sample2, self._params(local))))
        wo = dr.normalize(mi.reflect(wi, m))
        return wo, mi.Spectrum(1.0), self.eval(wi, wo, active)

    def eval(self, wi, wo, active):
        import drjit as dr
        import mitsuba as mi

        h = wi + wo
        ok = dr.squared_norm(h) > 1e-12
        h = dr.normalize(dr.select(ok, h, mi.Vector3f(0.0, 0.0, 1.0)))
        p = 0.25 * mi.sggx_pdf(h, self._params()) / dr.maximum(
            mi.sggx_projected_area(wi, self._params()), 1e-30)
        return dr.select(ok & active, p, 0.0)

    def projected_area(self, w, active):
        """σ(w) = sqrt(wᵀSw) (SpongeCake eq. 7)."""
        import drjit as dr

        return dr.sqrt(dr.maximum(self._quad(w, w), 0.0))


def sggx_matrix(kind: str, roughness: float, axis) -> np.ndarray:
    """S of surface-like (α²I + (1 − α²) a aᵀ) or fiber-like (I + (α² − 1) a aᵀ) flakes
    (SpongeCake §3.3), in NumPy."""
    a = np.asarray(axis, dtype=float)
    a2 = roughness * roughness
    aat = np.outer(a, a)
    return a2 * np.eye(3) + (1.0 - a2) * aat if kind == "surface" else np.eye(3) + (a2 - 1.0) * aat


def _hg(values):
    import mitsuba as mi

    return MitsubaPhase(mi.load_dict({"type": "hg", "g": float(values["g"])}))


def _isotropic(values):
    import mitsuba as mi

    return MitsubaPhase(mi.load_dict({"type": "isotropic"}))


def _sggx(values):
    return SGGXPhase(values["S"])


#: phase kind → builder(values) of a protocol.py phase function.
PHASES: Registry[Callable] = Registry("phase kind",
                                     {"isotropic": _isotropic, "hg": _hg, "sggx": _sggx})
