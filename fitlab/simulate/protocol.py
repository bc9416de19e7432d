"""What the Dr.Jit walk (walk.py) asks of a boundary and of a phase function.

The walk is Dr.Jit code in a Mitsuba 3 variant (``llvm_ad_rgb`` on the CPU, ``cuda_ad_rgb`` on a
GPU; engine.py); a boundary or phase function is any object with the methods below, written
with that variant's types (``mi.Vector3f``, ``mi.Float``, ``mi.Point2f``, ``mi.Spectrum``,
``mi.UInt32``, ``mi.Bool``). Most are Mitsuba's own plugins behind a thin adapter
(components.py); fitlab writes only what Mitsuba lacks (own_bsdfs.py).

Every method is traced inside a symbolic ``dr.while_loop``: no Python branching on array
values, no ``dr.eval`` and no printing; select with ``dr.select``; lanes with ``active`` false
must give finite values (they are discarded).

Frame: the boundary's local frame, normal +z = toward the region above it. Directions are
unit vectors. ``wi`` points toward where the light came from (``wi.z > 0``: the light arrives
from above), ``wo`` is the direction the light leaves in (``wo.z > 0``: upward).

Boundary (interface or substrate)::

    nonspecular: bool                      # a rough or diffuse event (Python constant)
    sample(wi, sample1, sample2, force, active) -> (wo, weight, pdf)
        weight: the fraction of flux carried, f(wi, wo)|cos θo| / pdf in flux (importance)
                transport: Walter eq. 41 for a rough dielectric, no 1/η² factor; times F or
                1 - F when ``force`` forces a branch; 0 for an invalid sample
        pdf:    density per solid angle of the *unforced* sampling (0 for a specular event)
        force:  UInt32 per lane, FORCE_CHOOSE (by the Fresnel probability), FORCE_REFLECT or
                FORCE_REFRACT (ignored by opaque boundaries), or one int for every lane
    eval(wi, wo, active) -> Spectrum
        fitlab's f(wi, wo) in 1/sr, radiance convention, without the cosine (Walter eqs 20-21:
        f_t(i, o)/η_o² = f_t(o, i)/η_i²), as fitlab's JAX models return it
    pdf(wi, wo, active) -> Float
        the density with which ``sample`` (unforced) returns wo
    eval_pdf(wi, wo, active) -> (Spectrum, Float)
        both of one pair at once (Mitsuba's ``eval_pdf`` shares their work)

Phase function (a medium's)::

    sample(wi, sample1, sample2, active) -> (wo, weight, pdf)      # weight 1 for exact sampling
    eval(wi, wo, active) -> Float                                   # p(wi, wo) in 1/sr

``wi`` of a phase function points back along the path (−travel direction), as Mitsuba's
``MediumInteraction3f.wi``; forward scattering is ``wo = −wi``.
"""

#: Where the walk runs (the names of ``fitlab simulate --device``; engine.py picks the backend).
DEVICES = ("auto", "cpu", "gpu")
#: Paths per launch of the kernel for exit tallies (per-path exit slots: ~32 bytes a path).
LAUNCH_PATHS = 1 << 20
#: Branch forcing codes (effects.EffectPlan: force_top / force_bottom / split_first).
FORCE_CHOOSE, FORCE_REFLECT, FORCE_REFRACT = 0, 1, 2
