"""Where the report's figures look: incidence groups, the plane of incidence, signed in-plane
scattering angles and hemisphere projections. Plain NumPy, degrees (as in files).

Signed in-plane angle x (degrees): the angle of wo from the normal of wo's own hemisphere,
positive on the forward side (φo = φi + 180°: the specular or refracted direction's side) and
negative on the backward side (φo = φi), so a scan reads left to right from back to forward
scattering, like a goniophotometer's in-plane sweep.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.io.directions import degrees_to_direction

#: A row is in the plane of incidence when its azimuth is within this many degrees of it.
IN_PLANE_TOL_DEG = 2.0
#: Data are "out of plane" (hemisphere maps are drawn) when more than this fraction of rows
#: lies outside the plane of incidence.
OUT_OF_PLANE_FRACTION = 0.2
#: Dense model curves: points per side.
DENSE_POINTS = 359

REFLECTION, TRANSMISSION = "reflection", "transmission"


class Incidence(NamedTuple):
    theta_i: float  # degrees
    phi_i: float  # degrees in [0, 360)
    rows: np.ndarray  # indices into the measurement


def incidences(m, rows) -> list[Incidence]:
    """Groups of rows sharing one incidence direction, sorted by (θi, φi)."""
    rows = np.asarray(rows)
    keys = np.stack([m.theta_i[rows], np.mod(m.phi_i[rows], 360.0)], axis=1)
    out = []
    for ti, pi in np.unique(keys, axis=0):
        sel = (keys[:, 0] == ti) & (keys[:, 1] == pi)
        out.append(Incidence(float(ti), float(pi), rows[sel]))
    return out


def side_of(m, rows) -> np.ndarray:
    """'reflection' where wo is on wi's side of the surface, else 'transmission'."""
    same = m.wi[rows, 2] * m.wo[rows, 2] > 0
    return np.where(same, REFLECTION, TRANSMISSION)


def _azimuth_offset(phi_i, phi_o):
    """φo − φi folded to [0°, 360°)."""
    return np.mod(np.asarray(phi_o) - np.asarray(phi_i), 360.0)


def theta_in_hemisphere(theta_o):
    """Angle of wo from the normal of its own hemisphere (0..90°)."""
    theta_o = np.asarray(theta_o, float)
    return np.where(theta_o <= 90.0, theta_o, 180.0 - theta_o)


def in_plane(m, rows, tol=IN_PLANE_TOL_DEG):
    """(mask, signed angle x) of ``rows``: in the plane of incidence within ``tol`` degrees."""
    rows = np.asarray(rows)
    d = _azimuth_offset(m.phi_i[rows], m.phi_o[rows])
    t = theta_in_hemisphere(m.theta_o[rows])
    back = np.minimum(d, 360.0 - d) <= tol
    fwd = np.abs(d - 180.0) <= tol
    pole = t <= tol  # near the pole the azimuth is moot
    mask = back | fwd | pole
    x = np.where(fwd | (pole & ~back), t, -t)
    return mask, x


def is_out_of_plane(m, rows) -> bool:
    mask, _ = in_plane(m, rows)
    return bool(mask.size and np.mean(~mask) > OUT_OF_PLANE_FRACTION)


def dense_scan(theta_i, phi_i, side, n=DENSE_POINTS):
    """(x, wi, wo) along the plane of incidence on one side: x from −89.5° to 89.5°."""
    x = np.linspace(-89.5, 89.5, n)
    wi = np.broadcast_to(degrees_to_direction(theta_i, phi_i), (n, 3))
    up = wi[0, 2] >= 0  # wi's hemisphere
    on_wi_side = side == REFLECTION
    theta = np.abs(x) if up == on_wi_side else 180.0 - np.abs(x)
    phi = np.where(x >= 0, phi_i + 180.0, phi_i)
    return x, np.array(wi), degrees_to_direction(theta, phi)


def disc_xy(theta_o, phi_o):
    """Azimuthal equidistant projection of wo's hemisphere: r = θ'/90° (θ' from that
    hemisphere's normal), angle φo."""
    r = theta_in_hemisphere(theta_o) / 90.0
    p = np.radians(phi_o)
    return r * np.cos(p), r * np.sin(p)


def pick_evenly(items, k):
    """At most ``k`` items, evenly spread, first and last included."""
    items = list(items)
    if len(items) <= k:
        return items
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, k)).astype(int))
    return [items[i] for i in idx]
