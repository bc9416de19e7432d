"""Detectors: where the simulated flux is tallied, and the cosine-weighted solid angle that turns
a bin's flux fraction into a BSDF value.

A bin (or cone) b collecting the flux fraction P_b of a collimated beam estimates the
cosine-weighted mean of the BSDF over it: f_b = P_b / ∫_b |cos θo| dω (f in 1/sr, radiance
BTDF, data_formats/scene_toml.md "Output").

- Hemisphere bins: uniform in θ over [0°, 90°] on each side and in φ over [0°, 360°);
  ∫ |cos θ| dω = Δφ (sin²θ1 - sin²θ0)/2 exactly.
- Cones (in-plane arcs, measurement directions): all directions within the half angle γ of d,
  Ω = 2π(1 - cos γ); ∫ |cos θ| dω over the part of the cone on d's side of the surface by
  quadrature (exact π sin²γ |d_z| when the cone does not cross the horizon).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Rows(NamedTuple):
    """Output rows of one incidence: outgoing angles in degrees, the tally index of each row and
    the cosine-weighted solid angle of its bin or cone; for hemisphere bins, each row's bin
    edges θo_lo, θo_hi, φo_lo, φo_hi in degrees (the aperture written to the CSV)."""

    theta_o: np.ndarray
    phi_o: np.ndarray
    tally: np.ndarray
    cos_solid_angle: np.ndarray
    edges: np.ndarray | None = None


def direction(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def hemisphere_rows(theta_bins: int, phi_bins: int, sides) -> Rows:
    """Bin centres of the observed sides, in the tally order of walk._bin_index."""
    edges = np.linspace(0.0, 90.0, theta_bins + 1)
    pedges = np.linspace(0.0, 360.0, phi_bins + 1)
    s2 = np.sin(np.radians(edges)) ** 2
    dphi = np.radians(360.0 / phi_bins)
    th, ph, tally, cw, ed = [], [], [], [], []
    for side_index, side in enumerate(("reflection", "transmission")):
        for tb in range(theta_bins):
            for pb in range(phi_bins):
                if side not in sides:
                    continue
                centre = 0.5 * (edges[tb] + edges[tb + 1])
                th.append(centre if side == "reflection" else 180.0 - centre)
                ph.append(0.5 * (pedges[pb] + pedges[pb + 1]))
                tally.append((side_index * theta_bins + tb) * phi_bins + pb)
                cw.append(0.5 * dphi * (s2[tb + 1] - s2[tb]))
                lo, hi = (edges[tb], edges[tb + 1]) if side == "reflection" else \
                    (180.0 - edges[tb + 1], 180.0 - edges[tb])
                ed.append((lo, hi, pedges[pb], pedges[pb + 1]))
    return Rows(np.array(th), np.array(ph), np.array(tally, dtype=int), np.array(cw),
                np.array(ed, dtype=float).reshape(-1, 4))


def cone_half_angle_cos(acceptance_sr: float) -> float:
    """cos γ of a cone of solid angle Ω = 2π(1 - cos γ)."""
    return 1.0 - acceptance_sr / (2.0 * np.pi)


def cone_half_angle_deg(acceptance_sr: float) -> float:
    """γ in degrees of a cone of solid angle Ω = 2π(1 - cos γ) (the CSV's aperture_deg)."""
    return float(np.degrees(np.arccos(cone_half_angle_cos(acceptance_sr))))


def cone_cos_solid_angle(d: np.ndarray, acceptance_sr: float, n_psi: int = 32,
                         n_phi: int = 128) -> np.ndarray:
    """∫ |cos θ| dω over the directions of each cone (d: (R, 3) unit axes) lying on the axis's
    side of the surface; midpoint rule in (cos ψ, φ) around the axis (dω = d(cos ψ) dφ)."""
    from fitlab.phase import orthonormal_basis
    import jax.numpy as jnp

    cg = cone_half_angle_cos(acceptance_sr)
    c = 1.0 - (np.arange(n_psi) + 0.5) / n_psi * (1.0 - cg)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    e1, e2 = (np.asarray(v) for v in orthonormal_basis(jnp.asarray(d, dtype=jnp.float64)))
    # ω_z for every (cone, ψ, φ)
    wz = (c[None, :, None] * d[:, None, None, 2]
          + s[None, :, None] * (np.cos(phi)[None, None, :] * e1[:, None, None, 2]
                                + np.sin(phi)[None, None, :] * e2[:, None, None, 2]))
    same_side = np.sign(wz) == np.sign(d[:, None, None, 2])
    dw = (1.0 - cg) / n_psi * (2.0 * np.pi / n_phi)
    return np.sum(np.where(same_side, np.abs(wz), 0.0), axis=(1, 2)) * dw


def inplane_rows(theta_o_signed, phi_i: float, acceptance_sr: float) -> tuple[Rows, np.ndarray]:
    """Goniometer arc positions in the plane of incidence: θo ≥ 0 at φo = φi + 180°, θo < 0 at
    φo = φi; |θo| > 90° is the transmission side. Returns the rows and the cone axes (R, 3)."""
    t = np.asarray(theta_o_signed, dtype=float)
    theta = np.abs(t)
    phi = np.mod(np.where(t >= 0, phi_i + 180.0, phi_i), 360.0)
    d = direction(theta, phi)
    rows = Rows(theta, phi, np.arange(t.size), cone_cos_solid_angle(d, acceptance_sr))
    return rows, d


def measurement_rows(theta_o, phi_o, acceptance_sr: float) -> tuple[Rows, np.ndarray]:
    """Cones around the exact outgoing directions of one incidence of a measurement file."""
    d = direction(np.asarray(theta_o, float), np.asarray(phi_o, float))
    rows = Rows(np.asarray(theta_o, float), np.asarray(phi_o, float), np.arange(len(theta_o)),
                cone_cos_solid_angle(d, acceptance_sr))
    return rows, d
