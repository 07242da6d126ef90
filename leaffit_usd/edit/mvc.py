"""Mean value coordinates (Floater 2003) for a closed 2D polygon (the cage).

For a point x and cage vertices b_i (counter-clockwise or not), with d_i = b_i - x,
r_i = |d_i|, A_i = det(d_i, d_{i+1}), D_i = d_i . d_{i+1}:

    tan(alpha_i / 2) = (r_i r_{i+1} - D_i) / A_i          (Hormann & Floater 2006, signed)
    w_i = (tan(alpha_{i-1} / 2) + tan(alpha_i / 2)) / r_i,   lambda_i = w_i / sum_j w_j

The signed form is valid for any simple polygon and for points outside it (where lambda can be
negative but still reproduces linear functions). Points on a cage vertex get that vertex's
indicator; points on an edge get linear interpolation between its two end vertices.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError


def mean_value_coordinates(cage: np.ndarray, points: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """MVC of ``points`` with respect to the polygon ``cage``.

    cage : (M, 2) float, polygon vertices in order (closed implicitly, M >= 3)
    points : (P, 2) float, same 2D frame
    Returns (P, M) float64; rows sum to 1 and ``coords @ cage == points`` (linear precision).
    """
    cage = np.asarray(cage, np.float64)
    points = np.asarray(points, np.float64)
    if cage.ndim != 2 or cage.shape[1] != 2 or len(cage) < 3:
        raise ParameterError("cage", "(M, 2) polygon with M >= 3", getattr(cage, "shape", cage))
    if points.ndim != 2 or points.shape[1] != 2:
        raise ParameterError("points", "(P, 2) array", points.shape)
    scale = max(np.ptp(cage, axis=0).max(), eps)
    tol = eps * scale
    d = cage[None, :, :] - points[:, None, :]                 # (P, M, 2)
    dn = np.roll(d, -1, axis=1)                               # d_{i+1}
    r = np.linalg.norm(d, axis=2)                             # (P, M)
    rn = np.roll(r, -1, axis=1)
    A = d[..., 0] * dn[..., 1] - d[..., 1] * dn[..., 0]
    D = (d * dn).sum(2)
    out = np.zeros((len(points), len(cage)))

    on_vertex = r < tol
    on_edge = (np.abs(A) <= tol * np.maximum(r + rn, tol)) & (D < 0) & ~on_vertex & ~np.roll(on_vertex, -1, 1)
    special = on_vertex.any(1) | on_edge.any(1)

    # general position
    g = ~special
    if g.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(np.abs(A[g]) > 0, (r[g] * rn[g] - D[g]) / A[g], 0.0)
            w = (np.roll(t, 1, axis=1) + t) / r[g]
        out[g] = w / w.sum(1, keepdims=True)
    # on a vertex: indicator
    pv = np.flatnonzero(on_vertex.any(1))
    out[pv, on_vertex[pv].argmax(1)] = 1.0
    # on an edge (i, i+1): linear interpolation
    pe = np.flatnonzero(on_edge.any(1) & ~on_vertex.any(1))
    if len(pe):
        i = on_edge[pe].argmax(1)
        j = (i + 1) % len(cage)
        s = r[pe, i] / (r[pe, i] + rn[pe, i])
        out[pe, i] = 1.0 - s
        out[pe, j] = s
    return out


def transfer(src_cage: np.ndarray, dst_cage: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map ``points`` (P, 2) inside ``src_cage`` (M, 2) into ``dst_cage`` (M, 2): sum_i lambda_i b_i^dst."""
    if np.shape(src_cage) != np.shape(dst_cage):
        raise ParameterError("dst_cage", f"same shape as src_cage {np.shape(src_cage)}", np.shape(dst_cage))
    return mean_value_coordinates(src_cage, points) @ np.asarray(dst_cage, np.float64)
