"""The template's *sheet view*: the direction the template sheet is built, charted and baked
along.

The fit's template frame has +Z along the smallest principal axis of the leaf's points. For a
flat or gently curved leaf that is the leaf's normal, and the sheet is a height field over the
frame's xy. For an arched strap leaf (lucky bamboo, grasses, a drooping blade) whose arch is
deeper than its half-width, the smallest principal axis is the leaf's *width*: seen along it
the leaf is edge-on (its picture is the arch's side view), ball pivoting and the planar
fallback leave a third of the leaf off the sheet, and the texture holds a wavy band.

:func:`sheet_view_rotation` looks along the leaf's mean surface normal instead, when that is
more than ``max_angle_deg`` from the frame's +Z: normals estimated from the points and oriented
consistently over the leaf (open3d), averaged. A leaf that turns by less than 180 degrees is a
height field seen along its mean normal. The rotation keeps +X (base -> apex) as close as it
can (projected onto the new view plane), so the UV chart's columns still run across the leaf.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.fit.params import FACE_ON_MAX_DEG


def mean_oriented_normal(points: np.ndarray, k: int = 16) -> tuple[np.ndarray, float]:
    """The mean of consistently oriented normals of ``points`` (N, 3) and the fraction of the
    normals within 90 degrees of it (1.0 = a height field seen along it).

    Normals: open3d's k-NN plane fits, oriented by propagation over the k-NN graph
    (``orient_normals_consistent_tangent_plane``), the overall sign towards +Z.
    Returns ((3,) unit vector, fraction); +Z and 1.0 for fewer than ``k + 1`` points.
    """
    import open3d as o3d

    P = np.asarray(points, np.float64)
    P = P[np.isfinite(P).all(1)]
    if len(P) < k + 1:
        return np.array([0.0, 0.0, 1.0]), 1.0
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k))
    pc.orient_normals_consistent_tangent_plane(k)
    n = np.asarray(pc.normals, np.float64)
    m = n.mean(0)
    if m[2] < 0:
        n, m = -n, -m
    norm = float(np.linalg.norm(m))
    if norm < 1e-9:
        return np.array([0.0, 0.0, 1.0]), 0.0
    m = m / norm
    return m, float(np.mean(n @ m > 0.0))


def sheet_view_rotation(points: np.ndarray, max_angle_deg: float = FACE_ON_MAX_DEG) -> np.ndarray:
    """(3, 3) rotation from the template frame to the sheet-view frame (rows: the view frame's
    axes in template coordinates; view = template @ R.T).

    The identity when the leaf's mean oriented normal (:func:`mean_oriented_normal`) is within
    ``max_angle_deg`` of +Z (the usual leaf: the fit's frame is kept as it is); otherwise z =
    that normal, x = the template's +X projected onto the plane normal to it, y = z cross x.
    """
    m, _ = mean_oriented_normal(points)
    if float(m[2]) >= np.cos(np.radians(max_angle_deg)):
        return np.eye(3)
    x = np.array([1.0, 0.0, 0.0]) - m[0] * m
    if np.linalg.norm(x) < 1e-6:   # the normal along +X: any x in the plane
        x = np.array([0.0, 1.0, 0.0]) - m[1] * m
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(m, x), m])
