"""Floaters: points far from every other point of a capture (``inlier_mask``), and statistical
outliers (``statistical_inliers``, used by plant isolation)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


SUBSAMPLE_ABOVE = 200_000  # above this many points the test runs on a voxel subsample


def inlier_mask(points: np.ndarray, factor: float, k: int = 8) -> np.ndarray:
    """(N,) bool: False for isolated points, whose k-th neighbour is farther than ``factor`` x
    the median k-th-neighbour distance.

    points : (N, 3) float, any frame (the test is scale-free). Everything is an inlier when
    ``factor <= 0``, when there are at most ``k + 1`` points, or when the median distance is 0.
    Above ``SUBSAMPLE_ABOVE`` points the test runs on a voxel subsample of that size (one point
    per occupied voxel keeps every isolated one) and a point is a floater when its nearest inlier
    of the subsample is farther than ``factor`` x the subsample's median k-th-neighbour
    distance: the same test at the subsample's spacing, ~3x cheaper at 1M points.
    """
    pts = np.asarray(points, np.float64)
    n = len(pts)
    if factor <= 0 or n <= k + 1:
        return np.ones(n, bool)
    if n > SUBSAMPLE_ABOVE:
        from leaffit_usd.geometry.heat import voxel_subsample

        sub = voxel_subsample(pts, SUBSAMPLE_ABOVE)
        ok = sub[inlier_mask(pts[sub], factor, k)]
        tree = cKDTree(pts[ok])
        med = float(np.median(tree.query(pts[ok[:: max(1, len(ok) // 20000)]], k=k + 1)[0][:, -1]))
        d, _ = tree.query(pts, k=1, workers=-1)
        return d <= factor * med
    d, _ = cKDTree(pts).query(pts, k=k + 1, workers=-1)
    dk = d[:, -1]
    med = np.median(dk)
    if med <= 0:
        return np.ones(n, bool)
    return dk <= factor * med


def statistical_inliers(points: np.ndarray, k: int, std_ratio: float,
                        distances: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: False for statistical outliers, whose mean distance to their ``k`` nearest
    points (itself included, as open3d counts) exceeds the mean of that over all points by
    ``std_ratio`` standard deviations (sample std). The rule of open3d's
    ``remove_statistical_outlier`` (tests check the same mask), on scipy's exact kd-tree: no
    open3d import, the same answer at any thread count.

    points : (N, 3) float, any frame. distances : optional (N, >= k) float, each point's sorted
    neighbour distances with itself first (from a k-NN query the caller already ran; the
    neighbours may come from a larger cloud). Everything is an inlier when there are at most
    ``k`` points.
    """
    pts = np.asarray(points, np.float64)
    n = len(pts)
    if n <= k:
        return np.ones(n, bool)
    if distances is None:
        from leaffit_usd.geometry import knn

        distances, _ = cKDTree(pts).query(pts, k=k, workers=knn.WORKERS)
        distances = distances.reshape(n, -1)
    m = np.asarray(distances, np.float64)[:, :k].sum(1) / k
    mu = m.sum() / n
    sd = np.sqrt(((m - mu) ** 2).sum() / max(n - 1, 1))
    return m <= mu + std_ratio * sd
