"""Automatic leaf instance segmentation: :func:`segment_plant` runs the default "blades" method
(:mod:`leaffit_usd.segment.blades`) or the paper's apex method (:mod:`leaffit_usd.segment.apex`)
on the working-frame points, on a subset of at most ``max_gaussians``; :func:`working_normals` gives
the Gaussians' normals in the working frame. The parameters: :mod:`leaffit_usd.segment.params`."""
from __future__ import annotations

import logging
import time
from dataclasses import asdict

import numpy as np

from leaffit_usd.errors import ParameterError, UserError
from leaffit_usd.geometry.outliers import inlier_mask
from leaffit_usd.geometry.sampling import position_order_sample
from leaffit_usd.segment.result import Segmentation

log = logging.getLogger("leaffit_usd")

from leaffit_usd.segment.apex import segment_apex
from leaffit_usd.segment.attach import attach_outliers, nearest_within_reach
from leaffit_usd.segment.params import METHODS, SegmentParams  # noqa: F401 (this module's API)


def segment_plant(points_working: np.ndarray, root_index: int, params: SegmentParams | None = None,
                  normals: np.ndarray | None = None, timings: dict | None = None) -> Segmentation:
    """Automatic leaf instance segmentation of one plant.

    points_working : (N, 3) float, working frame (root at origin, +Z up, height 1)
    root_index : index of the root Gaussian
    params : :class:`SegmentParams` (paper defaults)
    normals : optional (N, 3) float, working frame, each Gaussian's smallest-scale axis (NaN rows
        where it is ill-defined); used by the orientation-aware geodesics
    timings : optional dict filled with seconds per step
    Returns a :class:`Segmentation` with every field filled (indices into ``points_working``).
    Gaussians outside the connected component of the root are left unassigned (0), with a warning.
    """
    p = (params or SegmentParams()).validate()
    pts = _checked_points(points_working)
    n = len(pts)
    if not (isinstance(root_index, (int, np.integer)) and 0 <= root_index < n):
        raise ParameterError("root_index", f"an index in [0, {n})", root_index)
    root = int(root_index)
    tm = timings if timings is not None else {}
    t0 = time.perf_counter()
    if p.method == "blades" and 0 < p.max_gaussians < n:
        return _segment_subset(pts, root, normals, p, tm, t0)
    inlier = inlier_mask(pts, p.outlier_factor)
    inlier[root] = True
    if (~inlier).any():
        log.info("%d isolated Gaussians (floaters) left out of the segmentation", int((~inlier).sum()))
    if p.method == "blades":
        return _segment_blades(pts, root, inlier, normals, p, tm, t0)
    return segment_apex(pts, root, inlier, normals, p, tm, t0)


def _segment_subset(pts, root, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The blades method on ``p.max_gaussians`` of the Gaussians (see ``SegmentParams``), the
    result extended to all ``N``: each other Gaussian takes the label and D_r (+ the distance) of
    its nearest subset Gaussian, when that one was placed (finite D_r) and is within the
    floater-attach distance (2 x ``outlier_factor`` x the subset's median 8th-neighbour distance,
    as for the subset's own floaters); the rest are floaters (0, infinite D_r)."""
    keep = np.union1d(position_order_sample(pts, p.max_gaussians - 1, p.seed), [root])
    sub = segment_plant(pts[keep], int(np.searchsorted(keep, root)), p,
                        normals=None if normals is None else np.asarray(normals)[keep], timings=tm)
    t1 = time.perf_counter()
    placed = keep[np.isfinite(sub.dist_root)]
    d, j = nearest_within_reach(pts[placed], pts, p)
    near = np.isfinite(d)
    full_labels = np.zeros(len(pts), np.int32)
    dist = np.full(len(pts), np.inf, np.float32)
    sub_of = np.searchsorted(keep, placed[j[near]])
    full_labels[near] = sub.labels[sub_of]
    dist[near] = sub.dist_root[sub_of] + d[near]
    full_labels[keep] = sub.labels  # the subset keeps its own labels (its floaters too)
    dist[keep] = sub.dist_root
    tm["propagate"] = time.perf_counter() - t1
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation on %d of %d Gaussians, labels propagated to the rest (%.2f s)",
             len(keep), len(pts), tm["propagate"])
    return Segmentation(
        labels=full_labels, root_index=int(root), apex_indices=keep[sub.apex_indices],
        apex_labels=sub.apex_labels, leaf_tip=keep[sub.leaf_tip], leaf_base=keep[sub.leaf_base],
        tree_nodes=keep[sub.tree_nodes], tree_parent=sub.tree_parent, tree_leaf=sub.tree_leaf,
        dist_root=dist, params=asdict(p), confidence=sub.confidence)


def _checked_points(points_working) -> np.ndarray:
    """(N, 3) float64 of the caller's points, or ParameterError / UserError saying what is wrong."""
    pts = np.asarray(points_working, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ParameterError("points", "an (N, 3) array", getattr(pts, "shape", None))
    n = len(pts)
    if n < 8:
        raise UserError(f"the cloud has {n} Gaussians: too few to segment (need at least 8)")
    if not np.isfinite(pts).all():
        raise ParameterError("points", "finite coordinates", "NaN or inf values")
    if float(np.ptp(pts, 0).max()) < 1e-6:
        raise UserError("the cloud has no extent (all Gaussians at one point, working units): "
                        "nothing to segment")
    return pts


def _segment_blades(pts, root, inlier, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The default method (:mod:`leaffit_usd.segment.blades`), packed as a Segmentation."""
    from leaffit_usd.segment.blades import segment_blades

    res = segment_blades(pts, root, inlier, normals, p, tm)
    labels = res.labels.copy()
    d_root = res.d_root.copy()
    lost = int((~np.isfinite(d_root) & inlier).sum())
    if lost:
        log.info("the cloud is in pieces: %d of %d Gaussians are not connected to the root (no "
                 "root distance; their leaves are still found)", lost, len(pts))
    if (~inlier).any() and inlier.sum() > 1:
        attach_outliers(pts, labels, d_root, inlier, np.ones(len(pts), bool), p)
    n_leaves = len(res.leaf_tip)
    tree_leaf = labels[res.tree_nodes].astype(np.int32)
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation: %d leaves (%.2f s)", n_leaves, tm["total"])
    return Segmentation(
        labels=labels.astype(np.int32), root_index=int(root), apex_indices=res.leaf_tip.astype(np.int64),
        apex_labels=np.arange(1, n_leaves + 1, dtype=np.int32), leaf_tip=res.leaf_tip.astype(np.int64),
        leaf_base=res.leaf_base.astype(np.int64), tree_nodes=res.tree_nodes.astype(np.int64),
        tree_parent=res.tree_parent.astype(np.int64), tree_leaf=tree_leaf,
        dist_root=d_root.astype(np.float32), params=asdict(p), confidence=res.confidence)


def working_normals(cloud, rotation: np.ndarray | None = None, flat_ratio: float = 0.5) -> np.ndarray:
    """(N, 3) float64 unit normals of a GaussianCloud's Gaussians (``cloud.shortest_axes()``) in
    the working frame, NaN where the Gaussian is not flat (smallest scale > ``flat_ratio`` x the
    middle one: a round Gaussian's smallest axis says nothing about a surface).
    rotation : (3, 3) input axes -> working axes (``Frame.rotation``); None keeps the input frame.
    """
    n = cloud.shortest_axes().astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    s = np.sort(cloud.scales.astype(np.float64), axis=1)
    if rotation is not None:
        n = n @ np.asarray(rotation, np.float64).T
    n[s[:, 0] > flat_ratio * s[:, 1]] = np.nan
    return n
