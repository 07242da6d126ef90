"""Gaussians the segmentation left out (floaters, a subset's complement) take the label of
the nearest labelled Gaussian within reach; shared by both methods (``segment.auto``,
``segment.apex``)."""
from __future__ import annotations


import numpy as np
from scipy.spatial import cKDTree



from leaffit_usd.segment.params import SegmentParams


def attach_outliers(pts, labels, d_root, inlier, reach, p: SegmentParams, k: int = 8) -> None:
    """Isolated Gaussians close to the plant (a leaf's off-surface fuzz) take the label and D_r of
    their nearest segmented Gaussian if it is within 2 x the outlier radius (outlier_factor x the
    median 8th-neighbour distance); farther ones (true floaters) stay unassigned. In place."""
    ok = np.flatnonzero(inlier & reach)
    if len(ok) < k + 1:
        return
    out = np.flatnonzero(~inlier)
    d, j = nearest_within_reach(pts[ok], pts[out], p, k)
    near = np.isfinite(d)
    labels[out[near]] = labels[ok[j[near]]]
    d_root[out[near]] = d_root[ok[j[near]]] + d[near]


def nearest_within_reach(src: np.ndarray, query: np.ndarray, p: SegmentParams, k: int = 8):
    """Each query point's nearest ``src`` point (both (n, 3), working frame) if it lies within
    the floater-attach distance, 2 x ``outlier_factor`` x the median distance of src's points to
    their k-th neighbour (measured on at most ~20k of them). Returns (d, j): (Q,) distances, inf
    where none is within reach, and (Q,) indices into src (len(src) there)."""
    tree = cKDTree(src)
    med = float(np.median(tree.query(src[:: max(1, len(src) // 20000)], k=k + 1, workers=-1)[0][:, -1]))
    return tree.query(query, k=1, distance_upper_bound=2 * p.outlier_factor * med, workers=-1)
