"""numpy -> USD value conversions shared by the stage writer and the scripting API."""
from __future__ import annotations

import numpy as np


def vec3f_array(a: np.ndarray):
    """(..., 3) float -> ``Vt.Vec3fArray`` (flattened to (N, 3) float32)."""
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, np.float32).reshape(-1, 3))


def quat_arrays(q_wxyz: np.ndarray):
    """(L, 4) quaternions (w, x, y, z) -> (``Vt.QuathArray``, ``Vt.QuatfArray``), normalised."""
    from pxr import Vt

    from leaffit_usd.geometry.quaternion import normalize, to_xyzw

    xyzw = to_xyzw(normalize(q_wxyz))
    return (Vt.QuathArray.FromNumpy(xyzw.astype(np.float16)),
            Vt.QuatfArray.FromNumpy(xyzw.astype(np.float32)))


def matrix4d(m: np.ndarray):
    """(4, 4) column-vector matrix -> ``Gf.Matrix4d`` (USD's row-vector convention: transposed)."""
    from pxr import Gf

    return Gf.Matrix4d(np.asarray(m, np.float64).T.tolist())


def extent(points: np.ndarray):
    """``Vt.Vec3fArray`` [min, max] of (..., 3) points (the origin twice when there are none)."""
    from pxr import Vt

    p = np.asarray(points, np.float32).reshape(-1, 3)
    if not len(p):
        p = np.zeros((1, 3), np.float32)
    return Vt.Vec3fArray.FromNumpy(np.stack([p.min(0), p.max(0)]))
