"""Synthetic LeafFit plants for the runtime's tests and benchmarks (no capture needed).

``synthetic_asset`` builds a ``PlantAsset`` whose template is a gently curved, two-sided leaf
sheet (template local frame: +X petiole -> apex, +Z the upper side, working units, about 0.3 long)
and whose instances bend, twist and shear it, placed by random similarities.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from leaffit_usd.fit.mls import DEFAULT_REG, DEFAULT_SIGMA
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.usd.asset import PlantAsset

LEAF_LENGTH = 0.3   # template leaf length along +X, working units
LEAF_WIDTH = 0.14   # maximum width along Y


def leaf_sheet(n_points: int, rng: np.random.Generator, curvature: float = 1.0):
    """A leaf-shaped single sheet. Returns points (n, 3) float64, faces (G, 3) int32, uvs (n, 2).

    Points are stratified in the outline |y| <= W/2 sin(pi x / L)^0.7, with a cupped, arched
    surface z = curvature * (0.6 y^2 - 0.25 x (L - x)) (not coplanar, as a real leaf).
    """
    pts = []
    need = n_points
    while need > 0:
        x = rng.uniform(0, LEAF_LENGTH, 4 * need)
        y = rng.uniform(-LEAF_WIDTH / 2, LEAF_WIDTH / 2, 4 * need)
        inside = np.abs(y) <= LEAF_WIDTH / 2 * np.sin(np.pi * x / LEAF_LENGTH) ** 0.7
        pts.append(np.stack([x[inside], y[inside]], 1))
        need -= int(inside.sum())
    xy = np.concatenate(pts)[:n_points]
    z = curvature * (0.6 * xy[:, 1] ** 2 * 10 - 0.25 * xy[:, 0] * (LEAF_LENGTH - xy[:, 0]))
    tri = Delaunay(xy)
    faces = tri.simplices.astype(np.int32)
    # Delaunay also triangulates the concave notches of the outline: drop long sliver triangles.
    e = np.linalg.norm(xy[faces] - xy[np.roll(faces, 1, axis=1)], axis=2).max(1)
    faces = faces[e < 4 * np.median(e)]
    a, b, c = (xy[faces[:, i]] for i in range(3))
    ccw = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] > 0
    faces[~ccw] = faces[~ccw][:, ::-1]
    uvs = np.stack([xy[:, 0] / LEAF_LENGTH, 0.5 + xy[:, 1] / LEAF_WIDTH], 1)
    return np.column_stack([xy, z]), faces, uvs


def random_quaternions(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) uniformly random unit quaternions (w, x, y, z)."""
    from leaffit_usd.geometry.quaternion import normalize

    return normalize(rng.normal(size=(n, 4)))


def bend_targets(controls: np.ndarray, n: int, rng: np.random.Generator,
                 amount: float = 1.0) -> np.ndarray:
    """(n, K, 3) targets: each instance's controls bent along X, twisted, sheared and jittered."""
    p = np.asarray(controls, np.float64)
    out = np.empty((n, len(p), 3))
    for j in range(n):
        bend, twist, shear = amount * rng.uniform(-1, 1, 3) * np.array([2.0, 3.0, 0.3])
        ang = bend * p[:, 0]                        # bend about Y, growing towards the apex
        x = p[:, 0] * np.cos(ang) - p[:, 2] * np.sin(ang)
        z = p[:, 0] * np.sin(ang) + p[:, 2] * np.cos(ang)
        t = twist * p[:, 0]                         # twist about X
        y = p[:, 1] * np.cos(t) - z * np.sin(t)
        z = p[:, 1] * np.sin(t) + z * np.cos(t)
        y = y + shear * x
        out[j] = np.stack([x, y, z], 1) + amount * rng.normal(scale=0.004, size=p.shape)
    return out


def random_similarity(rng: np.random.Generator, scale=(0.5, 3.0), offset: float = 5.0) -> np.ndarray:
    """A random (4, 4) similarity: rotation, uniform scale, translation."""
    from leaffit_usd.runtime.evaluator import instance_matrices

    s = rng.uniform(*scale)
    return instance_matrices(rng.uniform(-offset, offset, (1, 3)), random_quaternions(1, rng),
                             np.full((1, 3), s))[0]


def synthetic_asset(n_leaves: int = 6, n_vertices: int = 512, K: int = 32, seed: int = 0,
                    sigma: float = DEFAULT_SIGMA, reg: float = DEFAULT_REG,
                    curvature: float = 1.0, dtype=np.float32) -> PlantAsset:
    """A plant of ``n_leaves`` deformed copies of a two-sided template of ``n_vertices`` vertices.

    Positions lie within a unit-height plant, orientations are random, scales uniform per leaf
    in [0.6, 1.4]; asset_to_input is a random similarity (offset, rotated, rescaled capture).
    """
    rng = np.random.default_rng(seed)
    half = n_vertices // 2
    sheet, sheet_faces, uv = leaf_sheet(half, rng, curvature)
    points = np.concatenate([sheet, sheet])
    faces = np.concatenate([sheet_faces, sheet_faces[:, ::-1] + half]).astype(np.int32)
    normals = np.zeros_like(points)
    normals[:half, 2], normals[half:, 2] = 1.0, -1.0
    controls = sheet[farthest_point_sampling(sheet, K)]
    s = rng.uniform(0.6, 1.4, n_leaves)
    stem = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 1.0]])
    return PlantAsset(
        template_points=points.astype(dtype),
        template_faces=faces,
        template_normals=normals.astype(dtype),
        template_uvs=np.concatenate([uv, uv]).astype(dtype),
        template_side=np.repeat(np.array([0, 1], np.uint8), half),
        template_controls=controls.astype(dtype),
        targets=bend_targets(controls, n_leaves, rng).astype(dtype),
        positions=np.column_stack([rng.uniform(-0.2, 0.2, (n_leaves, 2)),
                                   rng.uniform(0.1, 1.0, n_leaves)]).astype(dtype),
        orientations=random_quaternions(n_leaves, rng).astype(dtype),
        scales=np.repeat(s[:, None], 3, 1).astype(dtype),
        leaf_labels=np.arange(1, n_leaves + 1, dtype=np.int32),
        sigma=float(sigma), reg=float(reg),
        stem_points=stem.astype(dtype), stem_faces=np.array([[0, 1, 2]], np.int32),
        asset_to_input=random_similarity(rng),
        metadata={"synthetic": True, "seed": seed},
    )
