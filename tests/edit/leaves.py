"""Synthetic leaf sheets and PlantAssets for the editing tests (template local frame: base at the
origin, +X to the apex, +Z normal)."""
import numpy as np
from scipy.spatial import Delaunay

from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.usd.asset import PlantAsset


def outline(kind: str, n: int = 120) -> np.ndarray:
    """(n, 2) counter-clockwise outline from base (0, 0) to apex (length 1) and back."""
    t = np.linspace(0, 1, n // 2 + 1)
    if kind == "ellipse":
        half = 0.25 * np.sin(np.pi * t)
    elif kind == "lanceolate":
        half = 0.08 * np.sin(np.pi * t) ** 0.8 * (1 - 0.3 * t)
    elif kind == "heart":
        half = 0.35 * np.sin(np.pi * t) ** 0.6 * (1 - t) ** 0.3 + 0.05 * np.sin(np.pi * t)
    elif kind == "lobed":
        half = 0.3 * np.sin(np.pi * t) * (0.75 + 0.25 * np.cos(6 * np.pi * t))
    else:
        raise ValueError(kind)
    right = np.c_[t, -half]
    left = np.c_[t[::-1], half[::-1]]
    return np.vstack([right[:-1], left[:-1]])


def _inside(poly, pts):
    x, y = pts[:, 0], pts[:, 1]
    inside = np.zeros(len(pts), bool)
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, 0)):
        cross = ((y0 > y) != (y1 > y)) & (x < (x1 - x0) * (y - y0) / (y1 - y0 + 1e-300) + x0)
        inside ^= cross
    return inside


def sheet(kind: str, seed: int = 0, n_inner: int = 600, bend: float = 0.1):
    """A curved leaf sheet: (S, 3) points, (G, 3) faces (CCW from +Z)."""
    poly = outline(kind)
    rng = np.random.default_rng(seed)
    lo, hi = poly.min(0), poly.max(0)
    cand = rng.uniform(lo, hi, (n_inner * 4, 2))
    inner = cand[_inside(poly, cand)][:n_inner]
    pts2 = np.vstack([poly, inner])
    tri = Delaunay(pts2).simplices
    cen = pts2[tri].mean(1)
    tri = tri[_inside(poly, cen)]
    z = bend * (pts2[:, 0] ** 2) - 0.5 * bend * pts2[:, 1] ** 2
    return np.c_[pts2, z], tri


def asset_from_sheet(points, faces, n_leaves=5, K=32, sigma=0.3, seed=0) -> PlantAsset:
    """A PlantAsset with the sheet as template (front + back copies) and smoothly varied instances."""
    rng = np.random.default_rng(seed)
    v = len(points)
    tp = np.vstack([points, points]).astype(np.float32)
    tf = np.vstack([faces, faces[:, ::-1] + v]).astype(np.int32)
    normals = np.vstack([np.tile([0, 0, 1.0], (v, 1)), np.tile([0, 0, -1.0], (v, 1))]).astype(np.float32)
    uv = (points[:, :2] - points[:, :2].min(0)) / np.ptp(points[:, :2], 0).max()
    p = points[farthest_point_sampling(points, K)]
    targets = []
    for _ in range(n_leaves):
        s = rng.uniform(0.8, 1.2, 2)
        bend = rng.uniform(-0.15, 0.15)
        q = p.copy()
        q[:, 0] *= s[0]
        q[:, 1] *= s[1]
        q[:, 2] += bend * q[:, 0] ** 2 + 0.05 * rng.normal(size=1) * q[:, 1]
        targets.append(q)
    return PlantAsset(
        template_points=tp, template_faces=tf, template_normals=normals,
        template_uvs=np.vstack([uv, uv]).astype(np.float32),
        template_side=np.r_[np.zeros(v), np.ones(v)].astype(np.uint8),
        template_controls=p.astype(np.float32), targets=np.asarray(targets, np.float32),
        positions=rng.normal(size=(n_leaves, 3)).astype(np.float32),
        orientations=np.tile([1, 0, 0, 0], (n_leaves, 1)).astype(np.float32),
        scales=np.ones((n_leaves, 3), np.float32), leaf_labels=np.arange(1, n_leaves + 1, dtype=np.int32),
        sigma=sigma, reg=0.01, stem_points=np.zeros((0, 3), np.float32),
        stem_faces=np.zeros((0, 3), np.int32), asset_to_input=np.eye(4),
        front_texture="front.png", back_texture="back.png", metadata={})
