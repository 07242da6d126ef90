"""Floaters: points far from every other point of a capture (the one isolation test)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def inlier_mask(points: np.ndarray, factor: float, k: int = 8) -> np.ndarray:
    """(N,) bool: False for isolated points, whose k-th neighbour is farther than ``factor`` x
    the median k-th-neighbour distance.

    points : (N, 3) float, any frame (the test is scale-free). Everything is an inlier when
    ``factor <= 0``, when there are at most ``k + 1`` points, or when the median distance is 0.
    """
    pts = np.asarray(points, np.float64)
    n = len(pts)
    if factor <= 0 or n <= k + 1:
        return np.ones(n, bool)
    d, _ = cKDTree(pts).query(pts, k=k + 1, workers=-1)
    dk = d[:, -1]
    med = np.median(dk)
    if med <= 0:
        return np.ones(n, bool)
    return dk <= factor * med
