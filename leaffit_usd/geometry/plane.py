"""The orthonormal basis of a plane given its normal (any frame, unitless)."""
from __future__ import annotations

import numpy as np


def plane_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to unit vector ``u``.

    Written out (not np.cross): the up search calls it ~10^3 times. The one implementation
    (up search, isolation).
    """
    x, y, z = float(u[0]), float(u[1]), float(u[2])
    i = int(np.argmin(np.abs(u)))
    # e1 = u x a with a the axis least aligned with u
    e1 = (0.0, z, -y) if i == 0 else ((-z, 0.0, x) if i == 1 else (y, -x, 0.0))
    n1 = np.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    e1 = (e1[0] / n1, e1[1] / n1, e1[2] / n1)
    e2 = (y * e1[2] - z * e1[1], z * e1[0] - x * e1[2], x * e1[1] - y * e1[0])
    return np.array([[e1[0], e2[0]], [e1[1], e2[1]], [e1[2], e2[2]]])
