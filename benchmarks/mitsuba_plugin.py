"""fitlab's Mitsuba 3 plugin against Mitsuba's native ``roughconductor`` on the same Walter model
(GGX, α = 0.2, n = 0.2, k = 3.9), rendering the same scene (fitlab.export.mitsuba.preview_scene:
a sphere under an environment and a sun, ``path`` integrator, max depth 8) in the same run.

Three renders, each timed warm (a first render compiles and is timed apart), the least wall
time of ``--repeat`` runs:

* ``native``: Mitsuba's roughconductor, Dr.Jit's default symbolic loops and calls (the whole
  path tracer is one fused LLVM kernel);
* ``native, evaluated``: the same BSDF with Dr.Jit's evaluated loops and calls, the mode a
  Python BSDF needs (every bounce and every BSDF call launches kernels and materializes its
  arrays);
* ``plugin``: ``{"type": "fitlab", "model": "rough_conductor", ...}``, evaluated mode, each
  eval/sample/pdf a JAX call on the wavefront (arrays passed by DLPack, padded to powers of two).

Samples per second = pixels × spp / wall time. The ratios split the overhead into the part the
evaluated mode costs any Python BSDF and the part of fitlab's JAX calls. The renders must agree:
the plugin's image equals the native one within 4 standard errors of their difference per
channel (mean over the image).

    python benchmarks/mitsuba_plugin.py [--resolution 256] [--spp 32] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _walter_fit import machine, machine_line


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args(argv)

    import mitsuba as mi

    mi.set_variant(args.variant)
    from fitlab.export import mitsuba_plugin as fm
    from fitlab.export.material import material_from_model
    from fitlab.export.mitsuba import native_bsdf, plugin_bsdf, preview_scene

    fm.register()
    material = material_from_model("rough_conductor", {"Y": {"alpha": 0.2, "n": 0.2, "k": 3.9}})
    cases = {"native": (native_bsdf(material), False),
             "native, evaluated": (native_bsdf(material), True),
             "plugin": (plugin_bsdf(material), True)}
    samples = args.resolution ** 2 * args.spp
    print(machine_line(machine()))
    print(f"scene: sphere + environment + sun, path tracer (max depth 8), "
          f"{args.resolution}² pixels × {args.spp} spp = {samples} samples, {mi.variant()}")
    images, best = {}, {}
    for name, (bsdf, evaluated) in cases.items():
        scene = fm.load_scene(preview_scene(bsdf, resolution=args.resolution, spp=args.spp))

        def render(seed):
            import drjit as dr

            if evaluated:
                return fm.render(scene, seed=seed)
            img = mi.render(scene, seed=seed)
            dr.eval(img)
            return np.array(img)

        t0 = time.perf_counter()
        render(0)
        first = time.perf_counter() - t0
        times = []
        for r in range(args.repeat):
            t0 = time.perf_counter()
            images[name] = render(1 + r)
            times.append(time.perf_counter() - t0)
        best[name] = min(times)
        print(f"{name:>18}: first render {first:7.2f} s; warm {best[name]:7.3f} s "
              f"= {samples / best[name] / 1e6:8.3f} M samples/s")
    base = best["native"]
    for name in cases:
        print(f"{name:>18}: {best[name] / base:7.1f}× the native render's time")
    print(f"plugin / native, evaluated: {best['plugin'] / best['native, evaluated']:.1f}× "
          "(fitlab's JAX calls); native, evaluated / native: "
          f"{best['native, evaluated'] / base:.1f}× (Dr.Jit's evaluated mode)")
    a, b = images["plugin"], images["native"]
    n = a.shape[0] * a.shape[1]
    diff = (a - b).reshape(n, -1)
    z = diff.mean(axis=0) / (diff.std(axis=0, ddof=1) / np.sqrt(n))
    print("image means (R, G, B): plugin " + ", ".join(f"{v:.5f}" for v in a.reshape(n, -1)
                                                      .mean(0))
          + "; native " + ", ".join(f"{v:.5f}" for v in b.reshape(n, -1).mean(0))
          + "; z of the difference " + ", ".join(f"{v:.2f}" for v in z))
    if np.any(np.abs(z) > 4):
        print("DISAGREE: the plugin's image differs from the native one")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
