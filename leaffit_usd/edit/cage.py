"""2D leaf cages for cross-species retargeting (paper Sec. "Geometry retargeting across species").

A cage is the leaf outline seen in its PCA view (template local frame: +X from the petiole base
to the apex, +Z the normal), cut at the apex and at the base into a left and a right boundary,
each resampled uniformly by arc length. Two leaves' cages have the same vertex count and
vertex i of one corresponds to vertex i of the other, so mean value coordinates carry points
from one leaf into the other.

The outline is the boundary loop of the single-sheet template mesh projected onto the PCA
plane. For a sheet that does not fold over itself this is the silhouette the paper traces on
a rendered image, without pixel quantisation.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import UserError


def boundary_loop(faces: np.ndarray) -> np.ndarray:
    """Vertex indices of the longest boundary loop of a triangle mesh, in order.

    faces : (F, 3) int. Raises UserError when the mesh has no boundary (closed or empty).
    """
    faces = np.asarray(faces, np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bnd = e[cnt[inv.ravel()] == 1]           # directed boundary edges (keep face orientation)
    if len(bnd) == 0:
        raise UserError("the leaf mesh has no boundary: cannot trace its outline")
    nxt = {}
    for a, b in bnd:
        nxt.setdefault(int(a), int(b))
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(loop)
    return np.asarray(max(loops, key=len), np.int64)


def _resample(polyline: np.ndarray, n: int) -> np.ndarray:
    """n points uniformly spaced by arc length along a (M, 2) polyline, end points included."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, polyline[:, k]) for k in range(2)], axis=1)


def leaf_cage(points: np.ndarray, faces: np.ndarray, n_side: int = 32,
              base: np.ndarray | None = None) -> np.ndarray:
    """The 2D cage of a leaf sheet.

    points : (V, 3) float, template local frame (+X base -> apex); faces : (F, 3) int
    base : (2,) petiole base in the plane (default: the origin, as the local frame defines it)
    Returns (2 * n_side - 2, 2) float64, counter-clockwise: apex, left side (+Y), base, right side.
    The apex is the outline point farthest from the base. Raises UserError for an outline too
    short to have an apex.
    """
    loop = boundary_loop(faces)
    xy = np.asarray(points, np.float64)[loop, :2]
    if len(xy) < 6:
        raise UserError(f"the leaf outline has only {len(xy)} points: no apex can be detected")
    base = np.zeros(2) if base is None else np.asarray(base, np.float64)
    d = np.linalg.norm(xy - base, axis=1)
    ia = int(np.argmax(d))
    ib = int(np.argmin(d))
    area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    if d[ia] <= 1e-9 or abs(area) < 1e-3 * d[ia] ** 2:
        raise UserError("no detectable apex: the leaf outline is degenerate (no area or no extent)")
    # orient the loop counter-clockwise (positive signed area)
    if area < 0:
        xy, ia, ib = xy[::-1], len(xy) - 1 - ia, len(xy) - 1 - ib
    m = len(xy)
    walk = lambda i, j: xy[[(i + k) % m for k in range(((j - i) % m) + 1)]]  # noqa: E731
    left = walk(ia, ib)      # CCW from the apex (+X) passes through +Y: the left side
    right = walk(ib, ia)     # from the base back to the apex along -Y
    left = _resample(np.vstack([left[:-1], base]) if np.linalg.norm(left[-1] - base) > 0 else left, n_side)
    right = _resample(np.vstack([base, right[1:]]), n_side)
    return np.vstack([left[:-1], right[:-1]])
