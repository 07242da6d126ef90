"""Quaternions (w, x, y, z), the one convention of the package: rotation matrices, products,
and the (x, y, z, w) order of USD's ``Gf.Quat*`` arrays and scipy.

Every function broadcasts over leading axes where it says so and returns float64 unless noted.
"""
from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) -> (N, 3, 3) rotation matrices (same dtype)."""
    q = np.asarray(q)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    m = np.empty((len(q), 3, 3), dtype=q.dtype)
    m[:, 0, 0] = 1 - 2 * (y * y + z * z)
    m[:, 0, 1] = 2 * (x * y - w * z)
    m[:, 0, 2] = 2 * (x * z + w * y)
    m[:, 1, 0] = 2 * (x * y + w * z)
    m[:, 1, 1] = 1 - 2 * (x * x + z * z)
    m[:, 1, 2] = 2 * (y * z - w * x)
    m[:, 2, 0] = 2 * (x * z - w * y)
    m[:, 2, 1] = 2 * (y * z + w * x)
    m[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (w, x, y, z), w >= 0."""
    from scipy.spatial.transform import Rotation

    q = from_xyzw(Rotation.from_matrix(np.asarray(m, np.float64)).as_quat())
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of (..., 4) quaternions (w, x, y, z); broadcasts, float64."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def normalize(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions scaled to unit length (float64); a zero quaternion stays zero."""
    q = np.asarray(q, np.float64)
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-30)


def to_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """(..., 4) (w, x, y, z) -> (..., 4) (x, y, z, w) (USD ``Vt.Quat*Array`` numpy, scipy), contiguous."""
    q = np.asarray(q_wxyz)
    return np.ascontiguousarray(np.concatenate([q[..., 1:], q[..., :1]], axis=-1))


def from_xyzw(q_xyzw: np.ndarray) -> np.ndarray:
    """(..., 4) (x, y, z, w) -> (..., 4) (w, x, y, z), same dtype, contiguous."""
    q = np.asarray(q_xyzw)
    return np.ascontiguousarray(np.concatenate([q[..., 3:], q[..., :3]], axis=-1))
