"""Direction-pair files (``theta_i, phi_i, theta_o, phi_o`` in degrees), the input of
``fitlab eval``. Spec: data_formats/directions_csv.md."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fitlab.errors import InputFileError
from fitlab.io.csvtable import read_table

COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")


class DirectionPairs(NamedTuple):
    path: str
    theta_i: np.ndarray  # degrees, as in the file
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    metadata: dict

    def cartesian(self):
        """(wi, wo), unit vectors of shape (N, 3) in float64."""
        return (degrees_to_direction(self.theta_i, self.phi_i),
                degrees_to_direction(self.theta_o, self.phi_o))


def degrees_to_direction(theta_deg, phi_deg) -> np.ndarray:
    """Unit direction from θ (from +z) and φ (from +x) in degrees. Plain NumPy: this is I/O."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def direction_to_degrees(w) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`degrees_to_direction`: θ in [0°, 180°] and φ in [0°, 360°) of unit
    vectors (..., 3); φ is 0 on the z axis."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.degrees(np.arccos(np.clip(w[..., 2], -1.0, 1.0)))
    phi = np.mod(np.degrees(np.arctan2(w[..., 1], w[..., 0])), 360.0)
    on_axis = np.hypot(w[..., 0], w[..., 1]) < 1e-12
    return theta, np.where(on_axis | (phi >= 360.0), 0.0, phi)


def check_angles(table, theta_cols=("theta_i", "theta_o"), phi_cols=("phi_i", "phi_o")):
    """θ in [0°, 180°], φ in [-360°, 360°]; errors name the first offending line."""
    for name in theta_cols:
        bad = np.flatnonzero((table.columns[name] < 0) | (table.columns[name] > 180))
        if bad.size:
            j = bad[0]
            raise InputFileError(
                table.path, f"{table.columns[name][j]:g}° is outside [0°, 180°]",
                line=int(table.lines[j]), column=name,
                hint="θ is measured from the +z normal in degrees; θ > 90° is the transmission side",
            )
    for name in phi_cols:
        bad = np.flatnonzero(np.abs(table.columns[name]) > 360)
        if bad.size:
            j = bad[0]
            raise InputFileError(
                table.path, f"{table.columns[name][j]:g}° is outside [-360°, 360°]",
                line=int(table.lines[j]), column=name, hint="φ is an azimuth in degrees from +x",
            )


def read_directions(path) -> DirectionPairs:
    table = read_table(path, COLUMNS, what="direction file")
    check_angles(table)
    c = table.columns
    return DirectionPairs(table.path, c["theta_i"], c["phi_i"], c["theta_o"], c["phi_o"],
                          table.metadata)
