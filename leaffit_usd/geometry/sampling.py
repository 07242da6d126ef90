"""Farthest point sampling (FPS), returning indices into the input; a seeded random sample
that ignores the order of the points (:func:`position_order_sample`); voxel centroids
(:func:`voxel_centroids`).

open3d's C++ FPS does the work (about 0.6 s for 8,192 of 100k points on 2 cores, ~10x a numpy
loop); it returns points rather than indices, so they are mapped back with an exact kd-tree
lookup. Deterministic: the first sample is ``start`` (default: index 0).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError


def farthest_point_sampling(points: np.ndarray, k: int, start: int = 0) -> np.ndarray:
    """Indices of ``k`` farthest-point samples of ``points``.

    points : (N, 3) float, any frame. Returns (min(k, N_unique),) int64 indices in increasing
    order (the set FPS picks from ``start``: each next sample the point farthest, Euclidean, from
    all chosen so far). Duplicate points are returned once.
    """
    points = np.asarray(points, np.float64)
    n = len(points)
    if k <= 0:
        raise ParameterError("k", "a positive number of samples", k)
    if n == 0:
        return np.zeros(0, np.int64)
    if not 0 <= start < n:
        raise ParameterError("start", f"an index in [0, {n})", start)
    if k >= n:
        order = np.unique(points, axis=0, return_index=True)[1]
        return np.sort(order).astype(np.int64)
    if k <= 64 or n <= 2000:
        return np.sort(_fps_numpy(points, k, start))
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    chosen = np.asarray(pc.farthest_point_down_sample(int(k), int(start)).points)
    _, idx = cKDTree(points).query(chosen, k=1)
    idx = idx.astype(np.int64)
    return np.unique(idx)


def _fps_numpy(points: np.ndarray, k: int, start: int) -> np.ndarray:
    """Reference FPS in numpy, O(N k), in selection order; small inputs and tests of the fast path."""
    idx = np.empty(k, np.int64)
    idx[0] = start
    d = ((points - points[start]) ** 2).sum(1)
    for i in range(1, k):
        idx[i] = int(np.argmax(d))
        if d[idx[i]] <= 0:
            return idx[:i]
        d = np.minimum(d, ((points - points[idx[i]]) ** 2).sum(1))
    return idx


def position_order(points: np.ndarray) -> np.ndarray:
    """(N,) int64 indices that put ``points`` (N, 3), finite, in position order: by x, then y,
    then z, equal positions by index (``np.lexsort``'s order).

    One argsort of x, then only the runs of equal x (float32 captures have a few hundred in
    100k points) are sorted by y, z and index: 5-10x faster than the three-key lexsort.
    """
    p = np.asarray(points)
    order = np.argsort(p[:, 0])
    xs = p[order, 0]
    same = xs[1:] == xs[:-1]
    if same.any():
        tied = np.flatnonzero(np.r_[same, False] | np.r_[False, same])  # positions in runs
        run = np.cumsum(np.r_[True, ~same])[tied]  # the run each belongs to
        idx = order[tied]
        order[tied] = idx[np.lexsort((idx, p[idx, 2], p[idx, 1], run))]
    return order.astype(np.int64)


def grid_order(points: np.ndarray, cells: int = 64) -> np.ndarray:
    """(N,) int64 indices that visit ``points`` (N, 3), finite, cell by cell of a grid with
    ``cells`` cells along the longest side of their bounding box (z-major, then y, then x; within
    a cell in the given order: ``np.lexsort`` is stable).

    For memory locality, not for results: a kd-tree query of 100k neighbours in this order runs
    faster than in a capture's own order (each query finds the nodes and points it needs
    still in cache from its predecessor). The segmentation's results do not depend on the order
    of the Gaussians (ties are broken by position, :func:`position_order`).
    """
    p = np.asarray(points, np.float64)
    if not len(p):
        return np.zeros(0, np.int64)
    lo = p.min(0)
    size = float((p.max(0) - lo).max()) / cells
    c = np.floor((p - lo) / (size if size > 0 else 1.0)).astype(np.int64)
    return np.lexsort((c[:, 0], c[:, 1], c[:, 2])).astype(np.int64)


def canonical_order(points: np.ndarray, cells: int = 64) -> np.ndarray:
    """(N,) int64 indices that put ``points`` (N, 3), finite, in an order of their positions
    alone: grid cells (:func:`grid_order`) visited in turn, within a cell by position
    (:func:`position_order`). The same points in any given order come out the same (up to exact
    duplicates, which keep their given order), and neighbours stay close in memory.
    """
    by_position = position_order(points)
    return by_position[grid_order(np.asarray(points)[by_position], cells)]


def position_order_sample(points: np.ndarray, k: int, seed) -> np.ndarray:
    """(min(N, k),) int64 sorted indices into ``points`` (N, 3): a seeded random sample of k
    points drawn from the points in position order (:func:`position_order`), not in their given
    order, so the same points in another file order give the same sample. All when N <= k.
    ``seed``: an int or a sequence of ints (``np.random.default_rng``'s seed)."""
    n = len(points)
    if n <= k:
        return np.arange(n, dtype=np.int64)
    by_position = position_order(points)
    return np.sort(by_position[np.random.default_rng(seed).choice(n, k, replace=False)]).astype(np.int64)


def sample_at_most(points: np.ndarray, n: int, seed=0) -> np.ndarray:
    """(min(N, n),) int64 sorted indices into ``points`` (N, 3): all of them when N <= n or
    n <= 0 (no limit), else :func:`position_order_sample` of n (free of the file order; ``seed``
    as there)."""
    if n <= 0:
        return np.arange(len(points), dtype=np.int64)
    return position_order_sample(points, int(n), seed)


def voxel_centroids(points: np.ndarray, size: float, origin=None):
    """The centroid of each occupied voxel of a grid of cubes of edge ``size`` with a corner at
    ``origin`` (default: the points' minimum), same frame and units as ``points`` (N, 3).

    Returns ((V, 3) centroids in voxel-key order (lexicographic in the voxel's x, y, z index),
    (N,) int64 voxel of each point, (V,) int64 points per voxel)."""
    p = np.asarray(points, np.float64)
    keys = np.floor((p - (p.min(0) if origin is None else origin)) / size).astype(np.int64)
    keys -= keys.min(0)
    dims = keys.max(0) + 1  # one int64 key per voxel: a 1-D sort is ~10x faster than rows
    _, inv, cnt = np.unique((keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2],
                            return_inverse=True, return_counts=True)
    inv = inv.ravel()
    cen = np.stack([np.bincount(inv, p[:, i], len(cnt)) for i in range(3)], axis=1) / cnt[:, None]
    return cen, inv, cnt
