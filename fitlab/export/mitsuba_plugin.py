"""fitlab's BSDF plugin for Mitsuba 3: any registry model (or a fit's parameter file) in a
Mitsuba scene, evaluated, sampled and weighted by fitlab's own JAX code.

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import fitlab.export.mitsuba_plugin
    fitlab.export.mitsuba_plugin.register()
    scene = mi.load_dict({..., "bsdf": {"type": "fitlab", "fit": "fits/brown_vinyl.json"}})
    image = fitlab.export.mitsuba_plugin.render(scene)

Properties of the plugin (``type: fitlab``): ``fit`` (a parameter file; ``channel`` picks one of
its channels, else one channel renders grey and R, G, B render in colour), or ``model`` with the
model's parameters by name (``R__alpha``, ``G__alpha``, ``B__alpha`` for per-channel values) and
its options as ``option__NAME`` (Mitsuba reserves '.' in property names; a '.' in a
fitlab name is written ``__``: fitlab.export.mitsuba.plugin_property). Mitsuba's ``eval`` is f·|cos θ| of its ``wo`` argument; in
radiance mode ``si.wi`` points toward the camera and ``wo`` toward the light, so the plugin
returns fitlab's f(wi = light side, wo = camera side)·|cos θ_light| (importance mode: the other
way round), the physical mapping of data_formats/MITSUBA_MAPPING.md. ``sample`` draws with
fitlab's sampler from ``si.wi`` (for an RGB material with different parameters per channel,
with the G channel's), and its weight is that value over fitlab's pdf.

Each component of a direction reaches JAX through DLPack without a copy (``Float.jax()``); JAX
then stacks and pads them (one copy, inside XLA); the results come back as Dr.Jit arrays built
from the JAX arrays (``mi.Float(jax_array)``: one more copy of the values a call returns).
Python BSDFs need Dr.Jit's *evaluated* calls and loops (a JAX function cannot be traced into a
Dr.Jit kernel): :func:`render` (and :func:`evaluated_mode`) switch them on for the render.
Vectorized variants (``llvm_ad_rgb``, ``cuda_ad_rgb``) call the plugin once per wavefront;
scalar variants once per ray (slow, but correct). Lane counts are padded to powers of two so
that JAX compiles a handful of kernels, not one per call.
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np

#: The name scenes use for the plugin (``{"type": "fitlab", ...}``).
PLUGIN = "fitlab"
#: Smallest padded lane count (JAX compiles one kernel per padded size).
_MIN_LANES = 256


def _mitsuba():
    from fitlab.simulate.engine import select_libllvm

    select_libllvm()  # Dr.Jit picks its libLLVM at import: one it can use (LLVM >= 17)
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - the extra is installed in tests
        raise ImportError("fitlab.export.mitsuba_plugin needs Mitsuba 3: pip install 'fitlab[mitsuba]'") from exc
    if not mi.variant():
        raise RuntimeError("choose a Mitsuba variant first, e.g. mi.set_variant('llvm_ad_rgb')")
    return mi, dr


# ------------------------------------------------------------------------------------------
# The material a plugin instance renders, and its compiled kernels
# ------------------------------------------------------------------------------------------


def material_of_properties(values: dict):
    """The :class:`fitlab.export.material.Material` named by plugin properties (a plain dict:
    ``fit`` [+ ``channel``], or ``model`` + parameters + ``option__NAME``)."""
    from fitlab.fitting.result import load_fit
    from fitlab.export.material import (RGB, ExportError, material_from_fit,
                                        material_from_model)

    if "fit" in values:
        extra = sorted(set(values) - {"fit", "channel"})
        if extra:
            raise ExportError(f"fitlab plugin: with 'fit' give only 'channel', not "
                              f"{', '.join(extra)}")
        return material_from_fit(load_fit(values["fit"]), values.get("channel"))
    if "model" not in values:
        raise ExportError("fitlab plugin: give 'fit' (a parameter file) or 'model' (a registry "
                          "model) with its parameters")
    from fitlab.export.mitsuba import SEP

    prefix = f"option{SEP}"
    options = {k[len(prefix):].replace(SEP, "."): str(v) for k, v in values.items()
               if k.startswith(prefix)}
    params = {k: float(v) for k, v in values.items()
              if k != "model" and not k.startswith(prefix)}
    channel_of = {f"{c}{SEP}": c for c in RGB}
    per_channel = {k for k in params if k[:len(RGB[0]) + len(SEP)] in channel_of}
    plain = {k.replace(SEP, "."): v for k, v in params.items() if k not in per_channel}
    if per_channel:
        channels = {c: dict(plain) for c in RGB}
        for k in per_channel:
            head = k[:len(RGB[0]) + len(SEP)]
            channels[channel_of[head]][k[len(head):].replace(SEP, ".")] = params[k]
    else:
        channels = {"Y": plain}
    return material_from_model(values["model"], channels, options)


def _pad(n: int) -> int:
    return max(_MIN_LANES, 1 << max(0, int(n - 1).bit_length()))


class Kernels:
    """The compiled JAX functions of one material, in float32 (Mitsuba's precision):
    ``values(light, view)`` → (N, 3) f(light, view)·|cos θ_light|, ``pdf(wi, wo)`` → (N,)
    density of sampling ``wo`` from ``wi``, ``sample(wi, u)`` → (wo, pdf)."""

    def __init__(self, material):
        from fitlab._jax import jax, jnp

        from fitlab.api import check_params, resolve_options
        from fitlab.models import get_model

        if material.wavelengths_nm is not None:
            from fitlab.export.material import ExportError

            raise ExportError(f"{material.source}: fitlab's Mitsuba plugin renders grey or R, "
                              f"G, B, not the spectrum {', '.join(material.channels)}; give "
                              "'channel' (one wavelength)")
        model = get_model(material.model)
        options = resolve_options(model, material.options)
        for params in material.channels.values():
            check_params(model, params)
        names = list(material.channels)
        stacked = {p: np.asarray([[material.channels[c][p]] for c in names], np.float32)
                   for p in model.parameter_names}  # (C, 1): broadcasts against (N,)
        pick = names.index("G") if "G" in names else 0
        lead = {p: v[pick] for p, v in stacked.items()}
        self.material, self.model = material, model
        self.transmission = model.capabilities.transmission
        self.colour = len(names) == 3

        def f_cos(light, view):
            f = model.eval(stacked, light[None], view[None], **options)  # (C, N)
            f = f * jnp.abs(light[:, 2])[None]
            return (f if self.colour else jnp.broadcast_to(f, (3,) + f.shape[1:])).T

        def pdf(wi, wo):
            return model.pdf(lead, wi, wo, **options)

        def sample(wi, u):
            wo, _, p = model.sample(lead, wi, u, **options)
            return wo, p

        self.values = jax.jit(f_cos)
        self.pdf = jax.jit(pdf)
        self.sample = jax.jit(sample)


@functools.lru_cache(maxsize=64)
def _kernels_of(key: tuple) -> Kernels:
    return Kernels(material_of_properties(dict(key)))


# ------------------------------------------------------------------------------------------
# Dr.Jit <-> JAX
# ------------------------------------------------------------------------------------------


def _to_jax(vec, n_pad: int, fill: tuple):
    """(n_pad, len(vec)) float32 JAX array of the Dr.Jit vector ``vec`` (its components moved
    by DLPack), padded with the constant row ``fill``."""
    from fitlab._jax import jnp

    cols = [jnp.asarray(c.jax() if hasattr(c, "jax") else np.asarray(c), dtype=jnp.float32)
            .reshape(-1) for c in vec]
    a = jnp.stack(cols, axis=-1)
    n = a.shape[0]
    if n_pad > n:
        a = jnp.concatenate([a, jnp.broadcast_to(jnp.asarray(fill, jnp.float32),
                                                 (n_pad - n, a.shape[1]))])
    return a


def _width(*arrays) -> int:
    import drjit as dr

    return max(dr.width(a) for a in arrays)


def register(name: str = PLUGIN) -> None:
    """Register the plugin with Mitsuba 3 (for the variant set now) under ``name``."""
    mi, dr = _mitsuba()

    class FitlabBSDF(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            values = {}
            for key in props.keys():
                if key in ("id", "type"):
                    continue
                values[key] = props[key]
            if "fit" in values:  # relative to the scene file, like Mitsuba's own file names
                values["fit"] = str(mi.file_resolver().resolve(values["fit"]))
            self._key = tuple(sorted((k, v if isinstance(v, str) else float(v))
                                     for k, v in values.items()))
            k = _kernels_of(self._key)
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if k.transmission:
                flags = flags | mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.BackSide
            self.m_components = [flags]
            self.m_flags = flags

        @property
        def kernels(self) -> Kernels:
            return _kernels_of(self._key)

        def _ends(self, ctx, si, wo):
            """(light side, view side) directions: radiance mode traces from the camera."""
            if ctx.mode == mi.TransportMode.Radiance:
                return wo, si.wi
            return si.wi, wo

        def _eval(self, ctx, si, wo, active):
            n = _width(si.wi.x, wo.x, active)
            n_pad = _pad(n)
            light, view = self._ends(ctx, si, wo)
            v = self.kernels.values(_to_jax(light, n_pad, (0, 0, 1)),
                                    _to_jax(view, n_pad, (0, 0, 1)))[:n]
            value = mi.Color3f(mi.Float(v[:, 0]), mi.Float(v[:, 1]), mi.Float(v[:, 2]))
            return dr.select(active, value, 0.0)

        def _pdf(self, ctx, si, wo, active):
            n = _width(si.wi.x, wo.x, active)
            n_pad = _pad(n)
            p = self.kernels.pdf(_to_jax(si.wi, n_pad, (0, 0, 1)),
                                 _to_jax(wo, n_pad, (0, 0, 1)))[:n]
            return dr.select(active, mi.Float(p), 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._eval(ctx, si, wo, active)

        def pdf(self, ctx, si, wo, active=True):
            return self._pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._eval(ctx, si, wo, active), self._pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            n = _width(si.wi.x, sample1, sample2.x, active)
            n_pad = _pad(n)
            u = _to_jax([sample2.x, sample2.y, sample1], n_pad, (0.5, 0.5, 0.5))
            wo_j, p_j = self.kernels.sample(_to_jax(si.wi, n_pad, (0, 0, 1)), u)
            wo = mi.Vector3f(mi.Float(wo_j[:n, 0]), mi.Float(wo_j[:n, 1]),
                             mi.Float(wo_j[:n, 2]))
            pdf = mi.Float(p_j[:n])
            ok = active & (pdf > 0)
            value = self._eval(ctx, si, wo, ok)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = dr.select(ok, pdf, 0.0)
            bs.eta = 1.0
            crossing = si.wi.z * wo.z < 0
            bs.sampled_type = mi.UInt32(dr.select(
                crossing, mi.UInt32(+mi.BSDFFlags.GlossyTransmission),
                mi.UInt32(+mi.BSDFFlags.GlossyReflection)))
            bs.sampled_component = mi.UInt32(0)
            weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
            return bs, weight

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            m = self.kernels.material
            return f"FitlabBSDF[model={m.model}, channels={','.join(m.channels)}]"

    mi.register_bsdf(name, lambda props: FitlabBSDF(props))


@contextlib.contextmanager
def evaluated_mode():
    """Dr.Jit's evaluated calls and loops while the block runs (a Python BSDF that calls JAX
    needs them; they are restored afterwards)."""
    _, dr = _mitsuba()
    flags = (dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicLoops,
             dr.JitFlag.SymbolicConditionals)
    saved = [dr.flag(f) for f in flags]
    try:
        for f in flags:
            dr.set_flag(f, False)
        yield
    finally:
        for f, v in zip(flags, saved):
            dr.set_flag(f, v)


def render(scene, *, spp: int | None = None, seed: int = 0):
    """``mi.render`` in evaluated mode (what a scene with the fitlab plugin needs); returns the
    image as a NumPy array (H, W, C)."""
    mi, _ = _mitsuba()
    with evaluated_mode():
        image = mi.render(scene, spp=spp or 0, seed=seed)
    return np.array(image)




def load_scene(scene: dict):
    """``mi.load_dict`` of a scene dictionary made by fitlab.export.mitsuba (whose transforms
    are plain ``{"look_at": {...}}`` data, as in its XML) with the transforms made Mitsuba's."""
    mi, _ = _mitsuba()

    def convert(value):
        if isinstance(value, dict) and set(value) == {"look_at"}:
            return mi.ScalarTransform4f().look_at(**value["look_at"])
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        return value

    return mi.load_dict(convert(scene))


# ------------------------------------------------------------------------------------------
# The virtual goniometer and the white furnace (tests, report, benchmarks)
# ------------------------------------------------------------------------------------------


def _frame_up(w):
    w = np.asarray(w, float)
    return [0.0, 0.0, 1.0] if abs(w[2]) < 0.9 else [0.0, 1.0, 0.0]


def goniometer_scene(bsdf: dict, wi, wo, *, spp: int = 4, pixels: int = 2) -> dict:
    """A plane (normal +z, tangent +x: fitlab's local frame) with ``bsdf``, a directional
    emitter of irradiance 1 arriving from ``wi`` and an orthographic sensor looking at the
    plane's centre from ``wo`` (a window of 2 mm, so any view angle sees only the plane); the
    ``direct`` integrator. Each pixel is then the radiance f(wi, wo)·cos θi (Mitsuba's
    emitter sampling of a directional light has no variance)."""
    mi, _ = _mitsuba()
    T = mi.ScalarTransform4f
    wo = [float(x) for x in wo]
    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
        "sensor": {"type": "orthographic",
                   "to_world": T().look_at(origin=[2 * x for x in wo], target=[0, 0, 0],
                                           up=_frame_up(wo)) @ T().scale([1e-3, 1e-3, 1.0]),
                   "sampler": {"type": "independent", "sample_count": int(spp)},
                   "film": {"type": "hdrfilm", "width": int(pixels), "height": int(pixels),
                            "pixel_format": "rgb", "rfilter": {"type": "box"}}},
        "plane": {"type": "rectangle", "to_world": T().scale([10.0, 10.0, 1.0]), "bsdf": bsdf},
        "light": {"type": "directional", "direction": [-float(x) for x in wi],
                  "irradiance": 1.0},
    }


def goniometer(bsdf: dict, wi, wo, *, spp: int = 4, seed: int = 0) -> np.ndarray:
    """(N, 3) mean pixel values of :func:`goniometer_scene` for each pair (wi[k], wo[k]):
    f(wi, wo)·cos θi per colour channel as Mitsuba renders the plane."""
    mi, _ = _mitsuba()
    out = []
    for a, b in zip(np.atleast_2d(wi), np.atleast_2d(wo)):
        scene = mi.load_dict(goniometer_scene(bsdf, a, b, spp=spp))
        out.append(render(scene, seed=seed).reshape(-1, 3).mean(axis=0))
    return np.asarray(out)


def furnace_scene(bsdf: dict, wo, *, spp: int = 256, pixels: int = 4) -> dict:
    """The plane of :func:`goniometer_scene` under a constant environment of radiance 1 (a
    white furnace), seen from ``wo``, one bounce (``path``, max_depth 2): each pixel estimates
    ∫ f(wl, wo) cos θl dωl, the albedo for light arriving from every direction and leaving
    toward ``wo`` (for a reciprocal BRDF the directional albedo at incidence wo)."""
    scene = goniometer_scene(bsdf, [0.0, 0.0, 1.0], wo, spp=spp, pixels=pixels)
    del scene["light"]
    scene["integrator"] = {"type": "path", "max_depth": 2}
    scene["environment"] = {"type": "constant", "radiance": 1.0}
    return scene


#: Geometries of :func:`conversion_error`: incidences 0-80° in the plane φi = 0, views over the
#: hemisphere (θo 0-80°, six azimuths), fixed so that the figures are comparable between runs.
CHECK_THETA_I = (0.0, 20.0, 40.0, 60.0, 80.0)
CHECK_THETA_O = (5.0, 30.0, 55.0, 80.0)
CHECK_PHI_O = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)


def check_geometries() -> tuple[np.ndarray, np.ndarray]:
    """(wi, wo) of :func:`conversion_error` (120 reflection pairs)."""
    t_i, t_o, p_o = np.meshgrid(np.radians(CHECK_THETA_I), np.radians(CHECK_THETA_O),
                                np.radians(CHECK_PHI_O), indexing="ij")
    wi = np.stack([np.sin(t_i), np.zeros_like(t_i), np.cos(t_i)], -1).reshape(-1, 3)
    wo = np.stack([np.sin(t_o) * np.cos(p_o), np.sin(t_o) * np.sin(p_o), np.cos(t_o)],
                  -1).reshape(-1, 3)
    return wi, wo


def conversion_error(material, bsdf: dict) -> dict:
    """How far Mitsuba's render of ``bsdf`` is from fitlab's f·cos θi of ``material`` on the
    goniometer at :func:`check_geometries`: relative RMS and largest relative difference (over
    the pairs where fitlab's value is above 1e-6 of its largest), per channel combined."""
    from fitlab.api import eval_bsdf

    wi, wo = check_geometries()
    rendered = goniometer(bsdf, wi, wo)
    cols = [np.asarray(eval_bsdf(material.model, p, wi, wo, material.options))
            * wi[:, 2] for p in material.channels.values()]
    expected = np.stack(cols * 3 if len(cols) == 1 else cols, axis=-1)
    keep = expected > 1e-6 * expected.max()
    rel = np.abs(rendered - expected)[keep] / expected[keep]
    return {"pairs": int(wi.shape[0]), "relative_rms": float(np.sqrt(np.mean(rel ** 2))),
            "relative_max": float(rel.max()),
            "geometry": "theta_i " + ",".join(f"{t:g}" for t in CHECK_THETA_I) + "; theta_o "
            + ",".join(f"{t:g}" for t in CHECK_THETA_O) + "; phi_o "
            + ",".join(f"{t:g}" for t in CHECK_PHI_O) + " (degrees)",
            "renderer": f"Mitsuba {_mitsuba()[0].__version__} {_mitsuba()[0].variant()}"}


def ensure_variant() -> str:
    """The Mitsuba variant in use, choosing one if none is set: ``llvm_ad_rgb`` (vectorized,
    needs libLLVM), else ``scalar_rgb``; the plugin registered for it."""
    import mitsuba as mi

    if not mi.variant():
        try:
            mi.set_variant("llvm_ad_rgb")
        except Exception:  # noqa: BLE001 - no libLLVM: Mitsuba raises a plain exception
            mi.set_variant("scalar_rgb")
    register()
    return mi.variant()


__all__ = ["PLUGIN", "Kernels", "evaluated_mode", "material_of_properties", "register", "render",
           "load_scene", "goniometer_scene", "goniometer", "furnace_scene", "check_geometries",
           "conversion_error", "ensure_variant"]
