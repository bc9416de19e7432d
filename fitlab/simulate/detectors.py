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
- Points (``estimator = "point"``): the walk estimates the flux fraction per unit solid angle
  leaving along each exact direction d by next-event estimation (walk.py, "Point estimates");
  dividing by |cos θ| of d gives f itself, so a point row's "cosine-weighted solid angle" is
  |d_z|.
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


def point_rows(theta_o, phi_o, tally=None) -> tuple[Rows, np.ndarray]:
    """Point estimates at exact outgoing directions (degrees; θo > 90° is the transmission side):
    the rows, with |cos θo| as the divisor that turns a flux density per steradian into f, and
    the unit directions (R, 3)."""
    d = direction(np.asarray(theta_o, float), np.asarray(phi_o, float))
    idx = np.arange(d.shape[0]) if tally is None else np.asarray(tally, dtype=int)
    return Rows(np.asarray(theta_o, float), np.asarray(phi_o, float), idx, np.abs(d[:, 2])), d


#: Boundary classes for point estimates: what a boundary does to a path crossing it.
PASS, SMOOTH, ROUGH = "pass", "smooth", "rough"


def point_connections(classes) -> tuple[tuple[int, str | None], tuple[int, str | None]]:
    """Where next-event estimation connects a path to a requested direction, per side.

    ``classes``: per boundary 0..M, ``PASS`` (no index change), ``SMOOTH`` (a specular
    dielectric or conductor) or ``ROUGH`` (rough dielectric or conductor, Lambertian). Returns
    ``((k_up, why_not), (k_down, why_not))``: the reflection side connects at the first
    non-specular boundary k_up from the top (M + 1 if none: volume events only) and the
    transmission side at the last one from the bottom (-1 if none); ``why_not`` is None when
    the estimate is complete, else the reason it would miss light.

    Completeness: every exiting path has a last non-specular event; the estimate connects that
    event to the exit through the specular boundaries between it and the outside (deterministic
    refraction), so it must be the only way out. A specular boundary that can reflect a path back
    toward the exit side between k and the exit (an index change or a mirror strictly between
    the top and k_up, or between k_down and the bottom) would let light leave after a specular
    bounce that no connection follows."""
    M = len(classes) - 1
    rough = [j for j, c in enumerate(classes) if c == ROUGH]
    k_up = rough[0] if rough else M + 1
    k_down = rough[-1] if rough else -1
    between_up = [j for j in range(1, min(k_up, M + 1)) if classes[j] != PASS]
    between_down = [j for j in range(max(k_down + 1, 0), M) if classes[j] != PASS]
    why_up = why_down = None
    if between_up:
        why_up = (f"boundary {between_up[0]} is specular and lies between the top and the first "
                  "rough boundary: light reflected upward there would be missed")
    if between_down:
        why_down = (f"boundary {between_down[0]} is specular and lies between the last rough "
                    "boundary and the bottom: light reflected downward there would be missed")
    return (k_up, why_up), (k_down, why_down)


def cone_half_angle_cos(acceptance_sr: float) -> float:
    """cos γ of a cone of solid angle Ω = 2π(1 - cos γ)."""
    return 1.0 - acceptance_sr / (2.0 * np.pi)


def cone_half_angle_deg(acceptance_sr: float) -> float:
    """γ in degrees of a cone of solid angle Ω = 2π(1 - cos γ) (the CSV's aperture_deg)."""
    return float(np.degrees(np.arccos(cone_half_angle_cos(acceptance_sr))))


def _orthonormal_basis(n: np.ndarray):
    """Two unit vectors (s, t) with (s, t, n) right-handed orthonormal, for unit n (R, 3);
    branchless (Duff et al. 2017, "Building an Orthonormal Basis, Revisited")."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t = np.stack([b, sign + y * y * a, -y], axis=-1)
    return s, t


def cone_cos_solid_angle(d: np.ndarray, acceptance_sr: float, n_psi: int = 32,
                         n_phi: int = 128) -> np.ndarray:
    """∫ |cos θ| dω over the directions of each cone (d: (R, 3) unit axes) lying on the axis's
    side of the surface; midpoint rule in (cos ψ, φ) around the axis (dω = d(cos ψ) dφ)."""
    cg = cone_half_angle_cos(acceptance_sr)
    c = 1.0 - (np.arange(n_psi) + 0.5) / n_psi * (1.0 - cg)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    e1, e2 = _orthonormal_basis(np.asarray(d, dtype=np.float64))
    # ω_z for every (cone, ψ, φ)
    wz = (c[None, :, None] * d[:, None, None, 2]
          + s[None, :, None] * (np.cos(phi)[None, None, :] * e1[:, None, None, 2]
                                + np.sin(phi)[None, None, :] * e2[:, None, None, 2]))
    same_side = np.sign(wz) == np.sign(d[:, None, None, 2])
    dw = (1.0 - cg) / n_psi * (2.0 * np.pi / n_phi)
    return np.sum(np.where(same_side, np.abs(wz), 0.0), axis=(1, 2)) * dw


def inplane_rows(theta_o_signed, phi_i: float, acceptance_sr: float) -> tuple[Rows, np.ndarray]:
    """Goniometer arc positions in the plane of incidence: θo ≥ 0 at φo = φi + 180°, θo < 0 at
    φo = φi; |θo| > 90° is the transmission side. Returns the rows and the cone axes (R, 3);
    ``acceptance_sr`` 0: point rows (:func:`point_rows`), no cone."""
    t = np.asarray(theta_o_signed, dtype=float)
    theta = np.abs(t)
    phi = np.mod(np.where(t >= 0, phi_i + 180.0, phi_i), 360.0)
    if acceptance_sr == 0:
        return point_rows(theta, phi)
    d = direction(theta, phi)
    rows = Rows(theta, phi, np.arange(t.size), cone_cos_solid_angle(d, acceptance_sr))
    return rows, d


def measurement_rows(theta_o, phi_o, acceptance_sr: float) -> tuple[Rows, np.ndarray]:
    """Cones around the exact outgoing directions of one incidence of a measurement file."""
    d = direction(np.asarray(theta_o, float), np.asarray(phi_o, float))
    rows = Rows(np.asarray(theta_o, float), np.asarray(phi_o, float), np.arange(len(theta_o)),
                cone_cos_solid_angle(d, acceptance_sr))
    return rows, d
