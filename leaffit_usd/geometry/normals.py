"""Triangle-mesh normals (the one implementation: template bake, evaluator, baked leaves, stage)."""
from __future__ import annotations

import numpy as np


def face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(..., F, 3) float64 face normals of length 2 x triangle area (right-hand rule, not unit).

    points : (..., V, 3), any frame; faces : (F, 3) int vertex indices shared by the batch.
    """
    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    a = p[..., f[:, 0], :]
    return np.cross(p[..., f[:, 1], :] - a, p[..., f[:, 2], :] - a)


def vertex_normals(points: np.ndarray, faces: np.ndarray, undefined=None) -> np.ndarray:
    """(..., V, 3) float64 area-weighted unit vertex normals, same frame as ``points``.

    points : (..., V, 3) one mesh or a batch of meshes sharing ``faces`` (F, 3) int.
    A vertex used by no face, or whose incident faces cancel or are degenerate, gets
    ``undefined`` ((3,) vector, e.g. +Z) or (0, 0, 0) when it is None.
    """
    import scipy.sparse as sp

    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    shape = p.shape
    n_v = shape[-2]
    batch = p.reshape(-1, n_v, 3)
    b = len(batch)
    if len(f):
        fn = face_normals(batch, f)                                          # (B, F, 3)
        inc = sp.csr_matrix((np.ones(f.size), (f.ravel(), np.repeat(np.arange(len(f)), 3))),
                            shape=(n_v, len(f)))
        n = (inc @ fn.transpose(1, 0, 2).reshape(len(f), b * 3)).reshape(n_v, b, 3).transpose(1, 0, 2)
    else:
        n = np.zeros_like(batch)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    ok = norm > 1e-20
    out = np.divide(n, norm, out=np.zeros_like(n), where=ok)
    if undefined is not None:
        out = np.where(ok, out, np.asarray(undefined, np.float64))
    return out.reshape(shape)
