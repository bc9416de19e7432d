"""The conventions every fitlab file and command states, written once: parameter files and
lookup-table headers carry :data:`CONVENTIONS`, ``fitlab models`` prints :func:`conventions_text`.
The full text is data_formats/CONVENTIONS.md."""

from __future__ import annotations

DOCUMENT = "data_formats/CONVENTIONS.md"

CONVENTIONS = {
    "frame": "local shading frame, normal = +z; theta from +z, phi from +x",
    "directions": "unit vectors pointing away from the surface; wi toward the light, wo toward the detector",
    "value": "BSDF f in 1/sr without the cosine factor; relative data: scale * f",
    "angles": "degrees in files, radians in code",
    "roughness": "alpha = microfacet width (Walter alpha_b / alpha_g); Phong via alpha_p = 2/alpha^2 - 2",
    "shadowing": "separable Smith G = G1(i) G1(o) (Walter eq. 23)",
    "refraction": "eta = n_inside / n_outside (inside = -z side); BTDF for radiance transport (Walter eq. 21)",
    "document": DOCUMENT,
}


def conventions_text() -> str:
    """:data:`CONVENTIONS` as one paragraph for a terminal."""
    items = "; ".join(f"{key}: {text}" for key, text in CONVENTIONS.items() if key != "document")
    return f"{items}. Full text: {DOCUMENT}"


__all__ = ["CONVENTIONS", "DOCUMENT", "conventions_text"]
