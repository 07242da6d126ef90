"""PCA frames of leaves: principal plane = local xy, normal = local +z, base -> apex = local +x.

The leaf local frame (see ``fit.result.LeafFits``): origin at the leaf's petiole base, +X from the
base towards the apex (the base->apex vector projected onto the principal plane, so the sign never
depends on an eigenvector's sign), +Z the plane normal (smallest principal axis) oriented to the
upper side, +Y = Z x X (right-handed).

"Upper side" rule, in order: the normal points along +up (working +Z) when it is at least 0.1 away
from horizontal; else away from the plant's vertical axis (the radial direction of the leaf's
centroid); else towards +Y of the working frame (a deterministic tie-break).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


class PCAResult(NamedTuple):
    """centroid : (3,) float64; axes : (3, 3) float64, rows = principal axes, largest variance
    first; variances : (3,) float64 descending (units^2)."""

    centroid: np.ndarray
    axes: np.ndarray
    variances: np.ndarray


def pca(points: np.ndarray, weights: np.ndarray | None = None) -> PCAResult:
    """Principal axes of ``points`` (N, 3) float, any frame (optionally weighted, (N,) >= 0)."""
    p = np.asarray(points, np.float64)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, np.float64)
    w = w / max(w.sum(), 1e-300)
    c = w @ p
    d = p - c
    cov = (d * w[:, None]).T @ d
    val, vec = np.linalg.eigh(cov)
    order = np.argsort(val)[::-1]
    return PCAResult(c, vec[:, order].T.copy(), np.maximum(val[order], 0.0))


def leaf_frame(points: np.ndarray, base: np.ndarray, apex: np.ndarray,
               up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Rigid leaf frame (4, 4) float64: leaf local -> working frame (no scale).

    points : (N, 3) float, working frame, the leaf's (denoised) Gaussian centres
    base, apex : (3,) float, working frame, petiole base and primary apex of the leaf
    up : (3,) the plant's up direction in the working frame (+Z)

    Columns of the rotation block are the local X, Y, Z axes in the working frame; the
    translation is ``base``. Robust to degenerate input: a collinear leaf gets a normal chosen
    perpendicular to its axis and to ``up`` where possible; coincident base and apex fall back to
    the largest principal axis, oriented from ``base`` towards the centroid.
    """
    p = np.asarray(points, np.float64)
    base = np.asarray(base, np.float64)
    apex = np.asarray(apex, np.float64)
    up = np.asarray(up, np.float64)
    up = up / np.linalg.norm(up)
    if len(p) >= 3:
        res = pca(p)
        n = res.axes[2]
        e1 = res.axes[0]
        centroid = res.centroid
        planar = res.variances[1] > 1e-6 * max(res.variances[0], 1e-300)
    else:
        centroid = p.mean(0) if len(p) else base
        n, e1, planar = up.copy(), np.array([1.0, 0.0, 0.0]), False
    axis = apex - base
    if not planar:
        # collinear (or too few points): the plane is not defined; take the plane containing the
        # leaf axis and as close to horizontal as possible
        a = axis if np.linalg.norm(axis) > 1e-12 else e1
        a = a / max(np.linalg.norm(a), 1e-300)
        side = np.cross(up, a)
        if np.linalg.norm(side) < 1e-6:
            side = np.cross([0.0, 1.0, 0.0], a) if abs(a[1]) < 0.9 else np.cross([1.0, 0.0, 0.0], a)
        n = np.cross(a, side)
    n = n / np.linalg.norm(n)
    # orient the normal to the upper side
    s = float(n @ up)
    if abs(s) < 0.1:
        radial = centroid - (centroid @ up) * up
        s = float(n @ radial) if np.linalg.norm(radial) > 1e-9 else 0.0
        if abs(s) < 1e-9:
            s = float(n[1]) if abs(n[1]) > 1e-9 else float(n[0])
    if s < 0:
        n = -n
    x = axis - (axis @ n) * n
    if np.linalg.norm(x) < 1e-9 * max(1.0, np.linalg.norm(axis)):
        x = e1 - (e1 @ n) * n
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
        if (centroid - base) @ x < 0:
            x = -x
    x = x / np.linalg.norm(x)
    y = np.cross(n, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, n, base
    return m


def to_local(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map working-frame points (N, 3) into the frame of the similarity ``m`` (local -> working)."""
    a = m[:3, :3]
    return np.linalg.solve(a, (np.asarray(points, np.float64) - m[:3, 3]).T).T
