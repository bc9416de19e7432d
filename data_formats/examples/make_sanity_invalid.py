"""Regenerate the files invalid/sanity_*: valid files that a sanity gate refuses
(fitlab/io/gates.py; data_formats/measurement_csv.md, "Sanity gates", lists them and
tests/io/test_sanity_gates.py checks the refusal, the fix it names and the override).

    python data_formats/examples/make_sanity_invalid.py

Every value is a closed form (no random numbers): a Lambertian level with a GGX-like lobe, or a
flat level with a fixed ±1 % ripple.
"""

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "invalid"
HEAD = "# fitlab measurement CSV: a valid file that a sanity gate refuses (make_sanity_invalid.py)\n"


def lobe(theta_i, theta_o):
    """A diffuse level plus a specular lobe (f in 1/sr) in the plane of incidence."""
    half = np.radians((theta_o - theta_i) / 2)
    return 0.08 + 0.6 * np.exp(-np.tan(half) ** 2 / 0.05)


def ripple(k):
    return 1.0 + 0.01 * np.sin(1.7 * np.asarray(k, dtype=float))


def write(name, meta, header, rows):
    text = HEAD + "".join(f"# {k}: {v}\n" for k, v in meta.items()) + header + "\n"
    text += "".join(",".join(cells) + "\n" for cells in rows)
    (OUT / name).write_text(text, encoding="utf-8")
    print(f"wrote invalid/{name}")


def main():
    theta_o = np.arange(0, 81, 10.0)
    cols = "theta_i,phi_i,theta_o,phi_o,value"
    # radians: an in-plane BRDF scan written in radians (θi 30°, θo 0..80°).
    write("sanity_radians.csv", {"quantity": "bsdf", "scatter": "brdf"}, cols,
          [[f"{np.radians(30):.6f}", "0", f"{np.radians(t):.6f}", f"{np.pi:.6f}",
            f"{lobe(30, t):.5g}"] for t in theta_o])
    # radians, BTDF: the transmitted angles 100..170° in radians are all below 90 as degrees,
    # on the light's side: the radians message, not one about the sides of the surface.
    write("sanity_radians_btdf.csv", {"quantity": "bsdf", "scatter": "btdf"}, cols,
          [["0", "0", f"{np.radians(t):.6f}", "0", f"{lobe(0, 180 - t):.5g}"]
           for t in np.arange(100, 171, 10.0)])
    # quantity: a matte sample measured as f·|cos θo| (ρ/π·cos θo, ρ = 0.6), declared bsdf.
    write("sanity_quantity_cos.csv", {"quantity": "bsdf", "scatter": "brdf"}, cols,
          [[f"{ti:g}", "0", f"{t:g}", "180",
            f"{0.6 / np.pi * np.cos(np.radians(t)) * ripple(k):.5g}"]
           for ti in (0, 30) for k, t in enumerate(theta_o)])
    # quantity: a white matte sample's radiance factor (π·f ≈ 0.85), declared bsdf.
    write("sanity_radiance_factor.csv", {"quantity": "bsdf", "scatter": "brdf"}, cols,
          [[f"{ti:g}", "0", f"{t:g}", "180", f"{0.85 * ripple(k):.5g}"]
           for ti in (0, 30) for k, t in enumerate(theta_o)])
    # negative: relative data with a dark level subtracted twice (the diffuse part goes below 0
    # by 25 % of the peak).
    write("sanity_negative.csv", {"quantity": "relative", "scatter": "brdf"}, cols,
          [["30", "0", f"{t:g}", "180", f"{lobe(30, t) - 0.25:.5g}"] for t in theta_o])
    # tis: the brown vinyl excerpt of make_zemax_invalid.py with its first block's TIS 0.5
    # instead of 0.134506 (the grid's integral is 0.13).
    from make_zemax_invalid import excerpt

    lines = excerpt()
    assert lines[17] == "TIS 0.134506"
    lines[17] = "TIS 0.5"
    (OUT / "sanity_tis.bsdf").write_text("\n".join(lines) + "\n", encoding="ascii")
    print("wrote invalid/sanity_tis.bsdf")


if __name__ == "__main__":
    main()
