"""Synthetic pipeline results (TemplateMesh, LeafFits, Stem, Frame) for the usd tests.

The template is a curved leaf-shaped sheet in the template local frame (+X petiole -> apex,
+Z up side), duplicated into front/back copies as ``mesh.template`` does; fits place L copies by
random similarities with bent targets.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from leaffit_usd.fit.result import LeafFits
from leaffit_usd.mesh.result import Stem, TemplateLOD, TemplateMesh
from leaffit_usd.geometry.quaternion import quat_to_matrix
from leaffit_usd.splats.frame import Frame


def template_mesh(n=120, seed=0, tex=64) -> TemplateMesh:
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 1, (4 * n, 2))
    x = 0.3 * u[:, 0]
    y = 0.14 * (u[:, 1] - 0.5)
    keep = np.abs(y) <= 0.07 * np.sin(np.pi * x / 0.3) ** 0.7
    xy = np.stack([x[keep], y[keep]], 1)[:n]
    xy = np.concatenate([xy, [[0.0, 0.0], [0.3, 0.0]]])
    z = 0.3 * xy[:, 1] ** 2 - 0.2 * xy[:, 0] * (0.3 - xy[:, 0])
    sheet = np.column_stack([xy, z]).astype(np.float32)
    faces = Delaunay(xy).simplices.astype(np.int32)
    a, b, c = (xy[faces[:, i]] for i in range(3))
    ccw = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] > 0
    faces[~ccw] = faces[~ccw][:, ::-1]
    S = len(sheet)
    points = np.concatenate([sheet, sheet])
    normals = np.concatenate([np.tile([0, 0, 1.0], (S, 1)), np.tile([0, 0, -1.0], (S, 1))]).astype(np.float32)
    uv = np.stack([xy[:, 0] / 0.3, 0.5 + xy[:, 1] / 0.14], 1).astype(np.float32)
    uvs = np.concatenate([uv, uv])
    side = np.concatenate([np.zeros(S, np.uint8), np.ones(S, np.uint8)])
    all_faces = np.concatenate([faces, faces[:, ::-1] + S]).astype(np.int32)
    img = np.zeros((tex, tex, 4), np.uint8)
    img[..., 1] = np.linspace(60, 200, tex, dtype=np.uint8)[:, None]
    img[..., 3] = 255
    back = img.copy()
    back[..., 0] = 90
    return TemplateMesh(points=points, faces=all_faces, normals=normals, uvs=uvs, side=side,
                        front_texture=img, back_texture=back, sheet_points=sheet, sheet_faces=faces)


def leaf_fits(template: TemplateMesh, L=5, K=16, seed=1) -> LeafFits:
    rng = np.random.default_rng(seed)
    S = len(template.sheet_points)
    idx = np.sort(rng.choice(S, K, replace=False))
    p = template.sheet_points[idx].astype(np.float32)
    targets = np.empty((L, K, 3), np.float32)
    m = np.zeros((L, 4, 4))
    q = rng.normal(size=(L, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quat_to_matrix(q)
    for j in range(L):
        bend = rng.uniform(-1, 1)
        t = p.astype(np.float64).copy()
        t[:, 2] += bend * t[:, 0] ** 2
        t[:, 1] *= rng.uniform(0.8, 1.2)
        targets[j] = t + rng.normal(scale=0.003, size=t.shape)
        s = rng.uniform(0.6, 1.4)
        m[j, :3, :3] = s * R[j]
        m[j, :3, 3] = rng.uniform(-0.3, 0.3, 3) + [0, 0, 0.5]
        m[j, 3, 3] = 1
    return LeafFits(template_label=1, template_points=p, template_gaussians=np.arange(K),
                    template_controls=p, leaf_labels=np.arange(1, L + 1, dtype=np.int32),
                    targets=targets, leaf_to_working=m, errors=np.full(L, 0.01, np.float32),
                    fallback=np.zeros(L, bool), sigma=0.1, reg=0.01, params={"K": K, "steps": 0})


def stem() -> Stem:
    import trimesh

    cyl = trimesh.creation.cylinder(radius=0.01, segment=[[0, 0, 0], [0, 0, 0.8]], sections=8)
    return Stem(starts=np.zeros((1, 3), np.float32), ends=np.array([[0, 0, 0.8]], np.float32),
                radii_start=np.array([0.01], np.float32), radii_end=np.array([0.01], np.float32),
                parent=np.array([-1]), points=np.asarray(cyl.vertices, np.float32),
                faces=np.asarray(cyl.faces, np.int32))


def frame() -> Frame:
    """Input frame: up +Y, root at (1, 2, 3), plant 2.5 units tall."""
    pts = np.array([[1.0, 2.0, 3.0], [1.0, 4.5, 3.0]])
    return Frame.from_root_up(pts, pts[0], np.array([0.0, 1.0, 0.0]))


def coarser_template(t: TemplateMesh, n: int) -> TemplateLOD:
    """A coarser two-sided template: the first n sheet vertices, re-triangulated."""
    sheet = t.sheet_points[:n]
    f = Delaunay(sheet[:, :2]).simplices.astype(np.int64)
    a, b, c = (sheet[f[:, i], :2] for i in range(3))
    cw = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] < 0
    f[cw] = f[cw][:, ::-1]
    S = len(t.sheet_points)
    return TemplateLOD(points=np.concatenate([sheet, sheet]),
                       faces=np.concatenate([f, f[:, ::-1] + n]).astype(np.int32),
                       normals=np.concatenate([t.normals[:n], t.normals[S:S + n]]),
                       uvs=np.concatenate([t.uvs[:n], t.uvs[S:S + n]]),
                       side=np.concatenate([np.zeros(n, np.uint8), np.ones(n, np.uint8)]))
