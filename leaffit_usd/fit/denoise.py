"""Leaf denoising: MLS projection of Gaussian centres onto locally fitted planes (Amenta & Kil 2004).

For every point x: its k nearest neighbours (within ``sigma``) are weighted by a Gaussian kernel
exp(-|x_j - x|^2 / h^2), h = the distance to the k-th neighbour (adaptive, at most ``sigma``); the
weighted centroid c and the smallest principal axis n of the weighted covariance define the local
plane; x is moved to x - ((x - c).n) n. ``iterations`` repeats this from the projected points (the
plane is re-fitted around the moved point, as in the iterated MLS projection; neighbours are always
taken from the input so the support stays fixed).

k = ``neighbors`` for a leaf of at most ``reference_points`` Gaussians; a denser leaf of n uses
k = round(neighbors * n / reference_points) (:func:`neighbor_count`): the neighbourhood keeps its
share of the leaf's area (neighbors / reference_points) instead of shrinking as the capture gets
denser. Why: the capture's positional noise does not shrink with the density, and a fixed k over
a denser leaf averages it over a smaller patch. The same 9-leaf capsicum with the GT labels, its
leaves' 16,384-Gaussian subsets (``FitParams.leaf_gaussians``) at 1M against their 3.6-16k
Gaussians at 100k: the denoised centres' mean distance to the GT surface was 0.00053 vs 0.00039
plant heights with k = 24 (1.4x; 0.00029 with k = 48), the template mesh and the fit followed the
noise (Corr x10 0.0090 vs 0.0085, one leaf's HD 0.168 vs 0.060). With the share kept, a leaf's
neighbourhood is the same patch at any density above ``reference_points`` and holds more
Gaussians the denser the capture; sparser leaves (most of the sample plants' and of the external
100k plants': 2-8k Gaussians) keep k = ``neighbors`` exactly.

**Planes at anchors** (a leaf of more than ``plane_points`` Gaussians): with k growing with n the
cost of a plane at every point grows with n^2 (a 65,536-Gaussian leaf: k = 192, 172 s for the
1M capsicum's 9 leaves). The planes are fitted at ``plane_points`` anchors instead (a
position-order random sample; each plane still weighs k neighbours among all the leaf's
points, so it averages as much noise), and every other point is tested against and projected
onto its nearest anchor's plane. Anchors lie closer than the kernel radius h, where the plane
barely turns: on the curved noisy blade of ``tests/fit/test_fit_geometry.py`` (6,000 points,
1,500 anchors) the denoised centres' mean distance to the surface is 1.06x that of a plane at
every point (the test asserts < 1.1x), and ~7x less than the raw noise. A leaf of at most
``plane_points`` gives the same bytes as before (every point is an anchor). The cost is bounded
by the leaf cap: plane_points * neighbors * leaf_gaussians / reference_points neighbour terms
per pass.

Outliers, removed before projection:
* residual |(x - c).n| above ``sigma`` (the paper's sigma = 0.1, working units: points clearly off
  the leaf), or above ``mad_k`` robust standard deviations (1.4826 MAD) of the leaf's residuals
  (floaters close to the blade);
* isolated points: mean distance to the ``neighbors`` nearest above ``mad_k`` robust deviations of that
  statistic over the leaf (statistical outlier removal).
A leaf never loses more than ``max_removed`` of its points (the worst residuals go first).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.geometry.pca import pca
from leaffit_usd.geometry.sampling import sample_at_most

log = logging.getLogger("leaffit_usd")


@dataclass
class DenoiseParams:
    """sigma : outlier distance and largest kernel radius, working units (paper: 0.1)
    neighbors : k of the local plane fit (and of the isolation test) for a leaf of at most
        ``reference_points`` Gaussians
    reference_points : a leaf of n > reference_points Gaussians fits its planes to
        round(neighbors * n / reference_points) neighbours, the same share of its area
        (:func:`neighbor_count`; 0 = always ``neighbors``)
    iterations : projection steps
    mad_k : robust-deviation multiplier for residual and isolation outliers
    max_removed : at most this fraction of a leaf is removed as outliers
    plane_points : local planes are fitted at no more than this many of the leaf's points (the
        anchors, a position-order random sample); every other point is tested against and
        projected onto its nearest anchor's plane (0 = a plane at every point; see the module
        doc)"""

    sigma: float = 0.1
    neighbors: int = 24
    reference_points: int = 8192
    iterations: int = 2
    mad_k: float = 4.0
    max_removed: float = 0.2
    plane_points: int = 16384


class DenoiseResult(NamedTuple):
    """points : (M, 3) float64 projected centres (inputs' frame); keep : (N,) bool, inliers
    (``points`` are the projections of ``input[keep]``, in order); residual : (N,) float64 distance
    of each input point to its local plane; normals : (M, 3) float64 unit normal of the local
    plane each point was last projected onto (sign arbitrary); residual_limit : the largest
    residual the outlier test let through (working units; inf when nothing was tested)."""

    points: np.ndarray
    keep: np.ndarray
    residual: np.ndarray
    normals: np.ndarray
    residual_limit: float = float("inf")


def _robust_upper(x: np.ndarray, k: float) -> float:
    med = float(np.median(x))
    mad = float(np.median(np.abs(x - med)))
    return med + k * 1.4826 * mad


def _local_planes(query: np.ndarray, data: np.ndarray, idx: np.ndarray, dist: np.ndarray,
                  sigma: float):
    """Weighted local plane at each query point: centroid (N, 3) and unit normal (N, 3)."""
    nb = data[idx]                                                    # (N, k, 3)
    h = np.clip(dist[:, -1], 1e-12, sigma)[:, None]
    d2 = ((nb - query[:, None, :]) ** 2).sum(-1)
    w = np.exp(-d2 / h**2)
    w /= w.sum(1, keepdims=True)
    # stacked matmuls, not einsum (numpy's einsum loop: 1.7x slower here)
    c = np.matmul(w[:, None, :], nb)[:, 0]
    dc = nb - c[:, None, :]
    cov = np.matmul((dc * w[..., None]).transpose(0, 2, 1), dc)
    _, vec = np.linalg.eigh(cov)
    return c, vec[:, :, 0]


def neighbor_count(n: int, params: DenoiseParams) -> int:
    """k of the local plane fit for a leaf of ``n`` Gaussians: ``neighbors`` up to
    ``reference_points`` Gaussians, then in proportion to n (a fixed share of the leaf's area;
    see the module doc); never more than n."""
    k = int(params.neighbors)
    ref = int(params.reference_points)
    if ref > 0 and n > ref:
        k = int(round(k * n / ref))
    return int(min(k, n))


def denoise_leaf(points: np.ndarray, params: DenoiseParams = DenoiseParams()) -> DenoiseResult:
    """Denoise one leaf's Gaussian centres.

    points : (N, 3) float, working frame. Fewer than 4 points are returned unchanged (all kept).
    """
    p = np.asarray(points, np.float64)
    n = len(p)
    if n < 4:
        return DenoiseResult(p.copy(), np.ones(n, bool), np.zeros(n), _flat_normals(p))
    k_iso = int(min(params.neighbors, n))
    k = neighbor_count(n, params)  # >= k_iso
    tree = cKDTree(p)
    a = sample_at_most(p, params.plane_points)
    dist, idx = tree.query(p[a], k=k, workers=-1)
    c, nrm = _local_planes(p[a], p, idx, np.minimum(dist, params.sigma), params.sigma)
    if len(a) == n:          # a plane at every point (each point is its own anchor)
        own, iso_d = a, dist
    else:
        own = cKDTree(p[a]).query(p)[1]
        iso_d = tree.query(p, k=k_iso, workers=-1)[0]
    resid = np.abs(((p - c[own]) * nrm[own]).sum(1))
    # isolation: the mean distance to the ``neighbors`` nearest (relative to the leaf's own
    # median below, so it needs no share of the area; beyond sigma counts as sigma)
    iso = np.minimum(iso_d[:, 1:k_iso], params.sigma).mean(1)
    limit = min(params.sigma, max(_robust_upper(resid, params.mad_k), 1e-12))
    bad = resid > limit
    bad |= iso > max(_robust_upper(iso, params.mad_k), 1e-12)
    max_bad = int(params.max_removed * n)
    if bad.sum() > max_bad:
        # keep the limit: drop only the worst (by residual relative to the leaf's median)
        score = resid / max(np.median(resid), 1e-12) + iso / max(np.median(iso), 1e-12)
        worst = np.argsort(-np.where(bad, score, -np.inf))[:max_bad]
        bad = np.zeros(n, bool)
        bad[worst] = True
    keep = ~bad
    data = p[keep]
    q = data.copy()
    normals = _flat_normals(data)
    if len(data) >= 4:
        kk = int(min(k, len(data)))
        t2 = cKDTree(data)
        a2 = sample_at_most(data, params.plane_points)
        qa = data[a2]
        for _ in range(max(params.iterations, 1)):
            dist2, idx2 = t2.query(qa, k=kk, workers=-1)
            c2, n2 = _local_planes(qa, data, idx2, np.minimum(dist2, params.sigma), params.sigma)
            qa = qa - (((qa - c2) * n2).sum(1))[:, None] * n2
        if len(a2) == len(data):
            q, normals = qa, n2
        else:                # onto the nearest anchor's last plane (through its projection)
            own2 = cKDTree(data[a2]).query(data)[1]
            normals = n2[own2]
            q = data - (((data - qa[own2]) * normals).sum(1))[:, None] * normals
            q[a2] = qa
    if not np.isfinite(q).all():           # never propagate NaN: fall back to the raw points
        log.warning("denoise: non-finite projection, keeping raw points")
        q = data.copy()
    return DenoiseResult(q, keep, resid, normals, float(limit))


def _flat_normals(points: np.ndarray) -> np.ndarray:
    """(N, 3): the smallest principal axis of the whole set, for sets too small for local planes."""
    n = pca(points).axes[2] if len(points) >= 3 else np.array([0.0, 0.0, 1.0])
    return np.tile(n, (len(points), 1))
