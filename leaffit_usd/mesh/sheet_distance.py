"""Distances from points to a triangle sheet (open3d raycasting scene): unsigned, and signed
along the closest face's normal (which side of a leaf blade a Gaussian lies on)."""
from __future__ import annotations

import numpy as np


def point_sheet_distance(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) float64 distance of each point to the triangle mesh (open3d raycasting scene)."""
    import open3d as o3d

    if len(points) == 0:
        return np.zeros(0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    q = o3d.core.Tensor(np.ascontiguousarray(points, np.float32))
    return scene.compute_distance(q).numpy().astype(np.float64)


def signed_sheet_offset(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) signed distance of each point to the sheet along the closest face's normal (+ = front)."""
    import open3d as o3d

    if len(points) == 0 or len(faces) == 0:
        return np.zeros(len(points))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    r = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, np.float32)))
    cp, n = r["points"].numpy().astype(np.float64), r["primitive_normals"].numpy().astype(np.float64)
    return ((points - cp) * n).sum(1)
