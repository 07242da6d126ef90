"""Rigid, similarity and affine transforms of a whole GaussianCloud (means, rotations, scales).

Matrices are 4x4 with column vectors (``x' = m @ [x, 1]``), float64.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.quaternion import matrix_to_quat, quat_multiply, quat_to_matrix
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.sh import rotate_sh


def similarity_parts(m: np.ndarray, name: str = "m") -> tuple[float, np.ndarray, np.ndarray]:
    """Split a 4x4 similarity ``x' = s R x + t`` into (s, R (3, 3), t (3,)), float64.

    Raises ParameterError when ``m`` is not a similarity (shear, non-uniform scale, reflection,
    projective last row).
    """
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ParameterError(name, "a finite 4x4 matrix", getattr(m, "shape", m))
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise ParameterError(name, "an affine matrix with last row (0, 0, 0, 1)", m[3].tolist())
    a = m[:3, :3]
    det = float(np.linalg.det(a))
    if det <= 0:
        raise ParameterError(name, "a similarity with positive determinant (no reflection)", det)
    s = det ** (1.0 / 3.0)
    r = a / s
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6):
        raise ParameterError(name, "a similarity (rotation * uniform scale + translation)",
                             "a matrix with shear or non-uniform scale")
    return s, r, m[:3, 3].copy()


def transform_cloud(cloud: GaussianCloud, m: np.ndarray, allow_affine: bool = False) -> GaussianCloud:
    """Apply the 4x4 transform ``m`` (column vectors: ``x' = m @ [x, 1]``) to every Gaussian.

    For a similarity ``x' = s R x + t``: means are mapped, quaternions are left-multiplied by
    the rotation's quaternion (their length is kept, so unnormalised input stays unnormalised),
    ``log_scales += log(s)``; opacities and extras are unchanged. With ``allow_affine`` any
    invertible affine map is accepted: covariances ``A S A^T`` are eigen-decomposed into new
    unit quaternions and scales (Gaussian axes are then re-sorted; exact in the covariance).

    SH coefficients are rotated with the Gaussians (:func:`leaffit_usd.splats.sh.rotate_sh`, by
    ``R``; for a general affine map by the rotation of its polar decomposition), so the colour
    seen along a direction of the new frame is the colour seen along the matching direction
    before; the DC term is unchanged.

    Returns a new cloud (float32 arrays); ``file_index``/``file_count`` are kept.
    """
    m = np.asarray(m, np.float64)
    try:
        s, r, t = similarity_parts(m)
    except ParameterError:
        if not allow_affine:
            raise
        return _transform_affine(cloud, m)
    qr = matrix_to_quat(r[None])[0]
    means = (cloud.means.astype(np.float64) @ (s * r).T + t).astype(np.float32)
    quats = quat_multiply(qr, cloud.quats.astype(np.float64)).astype(np.float32)
    log_scales = (cloud.log_scales.astype(np.float64) + np.log(s)).astype(np.float32)
    return GaussianCloud(means=means, log_scales=log_scales, quats=quats,
                         opacity_logits=cloud.opacity_logits.copy(), sh=rotate_sh(cloud.sh, r),
                         extra={k: v.copy() for k, v in cloud.extra.items()},
                         file_index=cloud.file_index.copy(), file_count=cloud.file_count)


def _transform_affine(cloud: GaussianCloud, m: np.ndarray) -> GaussianCloud:
    """``transform_cloud`` for any invertible affine ``m``: covariances re-decomposed."""
    if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise ParameterError("transform", "an affine 4x4 matrix", m.tolist())
    a = m[:3, :3]
    if abs(np.linalg.det(a)) < 1e-300:
        raise ParameterError("transform", "an invertible matrix", "a singular matrix")
    means = (cloud.means.astype(np.float64) @ a.T + m[:3, 3]).astype(np.float32)
    rq = quat_to_matrix(cloud.rotations.astype(np.float64))
    s2 = np.exp(2.0 * cloud.log_scales.astype(np.float64))
    cov = np.einsum("nij,nj,nkj->nik", rq, s2, rq)
    cov = np.einsum("ij,njk,lk->nil", a, cov, a)
    w, v = np.linalg.eigh(cov)
    v[np.linalg.det(v) < 0, :, 0] *= -1.0  # proper rotations
    u, _, vt = np.linalg.svd(a)
    polar = u @ vt  # the rotation nearest ``a`` (a reflection if det(a) < 0: then no SH rotation)
    sh = rotate_sh(cloud.sh, polar) if np.linalg.det(polar) > 0 else cloud.sh.copy()
    return GaussianCloud(
        means=means, log_scales=(0.5 * np.log(np.maximum(w, 1e-300))).astype(np.float32),
        quats=matrix_to_quat(v).astype(np.float32), opacity_logits=cloud.opacity_logits.copy(),
        sh=sh, extra={k: v_.copy() for k, v_ in cloud.extra.items()},
        file_index=cloud.file_index.copy(), file_count=cloud.file_count)
