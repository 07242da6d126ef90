"""A leaf's two ends for the fit's landmarks: its base and apex from the segmentation
(:func:`base_apex`), and the apex walked out to the edge of the denoised blade
(:func:`apex_at_blade_edge`). Working frame."""
from __future__ import annotations

import numpy as np

from leaffit_usd.geometry.sampling import voxel_centroids

# the apex landmark's neighbourhood (x the base-apex distance) searched for the blade's edge
APEX_EDGE_RADIUS = 0.1
# steps of the walk out to the edge (each one a step along the outward direction)
APEX_EDGE_STEPS = 4


def apex_at_blade_edge(points: np.ndarray, base: np.ndarray, apex: np.ndarray,
                        radius: float = APEX_EDGE_RADIUS) -> np.ndarray:
    """(3,) the apex landmark walked out to the edge of the denoised blade. ``points`` (M, 3):
    the leaf's denoised centres; ``base``, ``apex`` (3,): the segmentation's; working frame.
    Each step (at most ``APEX_EDGE_STEPS``) takes the points within ``radius`` x |apex - base|
    of the apex, the direction u from the centroid of the area they cover to the apex (the
    blade's outward direction there), and moves as far along u as the farthest of them and
    across to the mean of those within a cell (reach / 8) of the farthest. ``apex`` unchanged
    when fewer than 3 points are that near.

    Why: the segmentation's apex is one Gaussian, its largest root distance among the geodesic
    domain's points. That is the leaf's outermost Gaussian on a plant under the domain's size
    (120k), but a subsample point inside the tip by about a sample spacing on a denser capture,
    and an off-surface fuzz Gaussian where one is outermost. The refinement pins the deformed
    template's apex to the target's (landmarks), so the offset of each leaf's apex Gaussian from
    its tip, and the template's, went straight into the leaves' tips: the Hausdorff distance of
    most leaves was at the tip (paper8 capsicum, auto labels, HD x10 at 100k / 1M before /
    after: seed 1 0.0391 / 0.0454 -> 0.0368 / 0.0388, ``benchmarks/scale.py`` at 8a1e8fc and
    4e99433; seeds 2, 3 scratch with the segmentation cached: 0.0527 / 0.0447 -> 0.0483 /
    0.0410, 0.0511 / 0.0430 -> 0.0474 / 0.0361). The denoised points have no fuzz. Outwards
    from the local centroid, not farthest from the base: a tip curled back towards the base has its end nearer the base
    than the bend before it. A step, not a jump to the farthest point: from an apex inside the
    blade the first direction is rough, and a jump lands on the rim beside the tip, where the
    next direction points off the blade."""
    P = np.asarray(points, np.float64)
    reach = radius * float(np.linalg.norm(apex - base))
    if len(P) < 3 or reach <= 0:
        return apex
    for _ in range(APEX_EDGE_STEPS):
        near = P[np.linalg.norm(P - apex, axis=1) <= reach]
        if len(near) < 3:
            return apex
        # the centroid of the area they cover, not of the points: a capture's density varies
        # (denser towards a narrowing tip), and a point centroid past the apex turned 'outwards' in
        out = apex - voxel_centroids(near, reach / 8.0, apex)[0].mean(0)
        n = float(np.linalg.norm(out))
        if n <= 1e-12 * reach:
            return apex
        # to the farthest points that way: as far out as the farthest, across to the mean of
        # those within a cell of it (the farthest point alone jumped sideways on a blunt tip,
        # where many are nearly as far, and turned the leaf's frame)
        u = out / n
        d = (near - apex) @ u
        far = near[d >= d.max() - reach / 8.0] - apex
        side = far.mean(0) - u * float((far @ u).mean())
        step = u * max(float(d.max()), 0.0) + side
        apex = apex + step
        if np.linalg.norm(step) <= 1e-3 * reach:
            break
    return apex


def base_apex(label, idx, means, seg):
    """(base (3,), apex (3,)) of leaf ``label`` (Gaussians ``idx`` of ``means``, working frame):
    the segmentation's own base and tip when it has them, else its root-distance extremes."""
    L = seg.n_leaves
    if len(seg.leaf_base) == L and len(seg.leaf_tip) == L and L > 0:
        return means[int(seg.leaf_base[label - 1])], means[int(seg.leaf_tip[label - 1])]
    if len(seg.dist_root) == len(means):
        d = np.asarray(seg.dist_root, np.float64)[idx]
    else:
        d = np.linalg.norm(means[idx], axis=1)
    return means[idx[int(np.argmin(d))]], means[idx[int(np.argmax(d))]]
