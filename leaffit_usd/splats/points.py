"""Gaussians for a plain point cloud (a laser, MVS or phone scan): each point becomes one Gaussian
shaped by its neighbourhood, so every later stage sees the same kind of input as from a 3DGS
capture.

How (input frame and units throughout):

* **orientation and shape**: the covariance of the point's ``k`` nearest neighbours (itself
  included; scipy's cKDTree). Its eigenvectors are the Gaussian's axes (the smallest one is the
  local PCA normal of the surface), the square roots of its eigenvalues its relative scales;
* **size**: a Gaussian should cover the point's share of the surface, not the whole
  neighbourhood: the two larger scales are rescaled so that their geometric mean is half the
  point's mean distance to its ``SPACING_K`` nearest neighbours (neighbouring Gaussians then
  overlap at about one standard deviation, as a trained 3DGS's do). The smallest is kept in
  proportion but never below ``MIN_THICKNESS`` x the largest (a perfectly flat patch would give
  a zero scale);
* **opacity** ``OPACITY`` (a scan point is a surface sample, not a semi-transparent blob), colour
  from the file, or mid grey.

Deterministic: the same points in the same order give the same bytes.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.geometry.knn import knn
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.splats.cloud import GaussianCloud

NEIGHBORS = 16         # neighbours of the covariance
SPACING_K = 6          # neighbours of the local spacing
MIN_THICKNESS = 0.05   # smallest scale, at least this x the largest
OPACITY = 0.9
GREY = 0.5
MIN_POINTS = 200       # fewer points than this cannot describe a plant's leaves


def gaussians_from_points(points: np.ndarray, colors: np.ndarray | None = None, source="points",
                          k: int = NEIGHBORS) -> GaussianCloud:
    """A GaussianCloud with one Gaussian per point (same order).

    points : (N, 3) float, input frame; colors : (N, 3) float RGB in [0, 1] or None (grey);
    source : the file's name, for errors. Raises InputFileError when there are fewer than
    ``MIN_POINTS`` distinct finite points (too few to build neighbourhoods from).
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputFileError(source, f"expected (N, 3) point positions, got shape {p.shape}")
    finite = np.isfinite(p).all(1)
    n_ok = int(finite.sum())
    distinct = len(np.unique(p[finite], axis=0)) if n_ok else 0
    if distinct < MIN_POINTS:
        raise InputFileError(source, f"has {distinct} distinct points; a plant needs at least "
                                     f"{MIN_POINTS} to build Gaussians from their neighbourhoods")
    pf = np.where(finite[:, None], p, 0.0)
    centre = np.median(pf[finite], axis=0)
    q = pf - centre  # better-conditioned covariances far from the origin (scanner frames)
    kk = int(min(k, distinct))
    d, nb = knn(q[finite], kk)
    idx = np.flatnonzero(finite)
    nbp = q[idx][nb]  # (M, k, 3)
    x = nbp - nbp.mean(1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", x, x) / max(kk - 1, 1)
    w, v = np.linalg.eigh(cov)  # ascending eigenvalues; columns = axes
    v = np.where((np.linalg.det(v) < 0)[:, None, None], v * np.array([-1.0, 1.0, 1.0]), v)
    sig = np.sqrt(np.maximum(w, 0.0))
    spacing = d[:, 1:min(SPACING_K, kk - 1) + 1].mean(1) if kk > 1 else np.ones(len(idx))
    spacing = np.where(spacing > 0, spacing, np.median(spacing[spacing > 0]) if (spacing > 0).any() else 1.0)
    gm = np.sqrt(np.maximum(sig[:, 1] * sig[:, 2], 1e-300))
    factor = np.where(gm > 0, 0.5 * spacing / np.maximum(gm, 1e-300), 0.0)
    scales = sig * factor[:, None]
    scales[:, 1:] = np.where(gm[:, None] > 0, scales[:, 1:], 0.5 * spacing[:, None])
    scales[:, 0] = np.maximum(scales[:, 0], MIN_THICKNESS * scales[:, 2])
    n = len(p)
    all_scales = np.full((n, 3), np.nan)
    all_scales[idx] = scales
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    quats[idx] = matrix_to_quat(v)
    if colors is None:
        rgb = np.full((n, 3), GREY)
    else:
        rgb = np.clip(np.asarray(colors, np.float64), 0.0, 1.0)
    cloud = GaussianCloud.from_activated(p, all_scales, quats, np.full(n, OPACITY), colors=rgb)
    if not finite.all():  # rows with NaN positions stay NaN: load's drop_invalid reports them
        cloud.log_scales[~finite] = np.nan
    return cloud
