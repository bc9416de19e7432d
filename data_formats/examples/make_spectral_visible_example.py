"""Regenerate measurement_spectral_visible.csv: a synthetic spectral BRDF whose nine bands span
the visible range (380-780 nm every 50 nm), so that a fit of it has a colour
(data_formats/fit_json.md, "Colour of a spectral fit").

Truth: lambertian+rough_conductor (GGX) with one geometry for every band, alpha = 0.25, n = 1.5,
k = 0 (a dielectric-like specular lobe), and the diffuse albedo of the Macbeth ColorChecker's
"orange" patch (N. Ohta's measurement, colour-science's
``SDS_COLOURCHECKERS["ColorChecker N Ohta"]["orange"]``, BSD-3-Clause) sampled at the bands.
In-plane rows at θi = 20° and 50°, θo every 10° on both sides, f in 1/sr with sigma = 2% of f
plus 0.002 1/sr, Gaussian noise of that sigma, seed 37.

    python data_formats/examples/make_spectral_visible_example.py
"""

from pathlib import Path

import numpy as np

import fitlab
from fitlab.io.directions import degrees_to_direction

MODEL = "lambertian+rough_conductor"
GEOMETRY = {"alpha": 0.25, "n": 1.5, "k": 0.0}
PATCH = "orange"
BANDS_NM = tuple(range(380, 781, 50))
REL_NOISE, FLOOR, SEED = 0.02, 0.002, 37


def albedo_at_bands() -> list[float]:
    import colour

    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"][PATCH]
    return [float(sd[w]) for w in BANDS_NM]


def main():
    rng = np.random.default_rng(SEED)
    rows = [(ti, 0.0, to, po) for ti in (20.0, 50.0) for po in (0.0, 180.0)
            for to in range(0 if po == 0.0 else 10, 81, 10)]
    a = np.asarray(rows)
    wi, wo = degrees_to_direction(a[:, 0], a[:, 1]), degrees_to_direction(a[:, 2], a[:, 3])
    lines = []
    for w, albedo in zip(BANDS_NM, albedo_at_bands()):
        f = np.asarray(fitlab.eval_bsdf(MODEL, {**GEOMETRY, "albedo": albedo}, wi, wo))
        sigma = REL_NOISE * f + FLOOR
        value = np.maximum(f + sigma * rng.standard_normal(f.shape), 0.0)
        lines += [f"{ti:g},{pi:g},{to:g},{po:g},{w},{v:.6g},{s:.4g}"
                  for (ti, pi, to, po), v, s in zip(rows, value, sigma)]
    out = Path(__file__).with_name("measurement_spectral_visible.csv")
    head = [
        "# Synthetic spectral BRDF, nine bands over the visible range (380-780 nm), made by",
        f"# make_spectral_visible_example.py: {MODEL}, alpha={GEOMETRY['alpha']}, "
        f"n={GEOMETRY['n']}, k={GEOMETRY['k']} in every band,",
        f"# albedo = ColorChecker N Ohta '{PATCH}' reflectance at the bands (colour-science, "
        "BSD-3-Clause);",
        f"# sigma = {REL_NOISE:.0%} of f + {FLOOR} 1/sr, Gaussian noise, seed {SEED}.",
        "# quantity: bsdf",
        "# scatter: brdf",
        f"# sample: synthetic ColorChecker {PATCH} with a glossy coat-like lobe",
        "theta_i,phi_i,theta_o,phi_o,wavelength_nm,value,sigma",
    ]
    out.write_text("\n".join(head + lines) + "\n", encoding="utf-8")
    print(f"wrote {out} ({len(lines)} rows)")


if __name__ == "__main__":
    main()
