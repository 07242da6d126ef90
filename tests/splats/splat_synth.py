"""A small synthetic 3DGS plant for the foundation tests (until/besides samples/).

Stem along +Z from the origin, leaves (elliptic sheets on petioles) around it, a few floaters,
then an arbitrary similarity (rotation, scale, offset). Ground truth: up vector, root point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.splats.cloud import GaussianCloud


@dataclass
class SynthPlant:
    cloud: GaussianCloud   # input frame
    up: np.ndarray         # (3,) unit, input frame
    root: np.ndarray       # (3,) input frame
    height: float          # input units
    scale: float           # input units per plant unit


def make_plant(seed: int = 0, n_leaves: int = 7, per_leaf: int = 600, n_floaters: int = 10,
               rotate: bool = True, sh_degree: int = 0, lean: float = 0.0) -> SynthPlant:
    rng = np.random.default_rng(seed)
    pts, nrm, col = [], [], []
    stem_h = rng.uniform(0.5, 0.8)
    # stem: a slightly curved line with radius 0.012
    t = rng.uniform(0, 1, 400)
    z = t * stem_h
    bend = lean * z ** 2
    ang = rng.uniform(0, 2 * np.pi, len(t))
    r = 0.012
    stem = np.stack([bend + r * np.cos(ang), r * np.sin(ang), z], 1)
    pts.append(stem); nrm.append(np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1))
    col.append(np.tile([0.35, 0.5, 0.2], (len(t), 1)))
    golden = np.pi * (3 - np.sqrt(5))
    for i in range(n_leaves):
        zb = stem_h * (0.35 + 0.65 * i / max(n_leaves - 1, 1))
        az = i * golden + rng.normal(0, 0.2)
        d = np.array([np.cos(az), np.sin(az), 0.0])
        base = np.array([lean * zb ** 2, 0, zb])
        # petiole
        pl = rng.uniform(0.05, 0.12)
        tilt = np.radians(rng.uniform(15, 50))
        pdir = np.cos(tilt) * d + np.sin(tilt) * np.array([0, 0, 1.0])
        s = rng.uniform(0, 1, 40)[:, None]
        pts.append(base + s * pl * pdir); nrm.append(np.tile([0, 0, 1.0], (40, 1)))
        col.append(np.tile([0.3, 0.45, 0.2], (40, 1)))
        # leaf sheet: ellipse length L, width W along pdir2 (leaf tilt), curved down a bit
        L = rng.uniform(0.25, 0.4)
        W = L * rng.uniform(0.3, 0.5)
        ltilt = np.radians(rng.uniform(-10, 30))
        ldir = np.cos(ltilt) * d + np.sin(ltilt) * np.array([0, 0, 1.0])
        side = np.cross([0, 0, 1.0], d)
        lnorm = np.cross(ldir, side)
        u = rng.uniform(0, 1, per_leaf)
        v = rng.uniform(-1, 1, per_leaf) * np.sin(np.pi * u) * 0.5 * W
        droop = -0.3 * L * u ** 2
        p = base + pl * pdir + np.outer(u * L, ldir) + np.outer(v, side) + np.outer(droop, lnorm)
        pts.append(p); nrm.append(np.tile(lnorm, (per_leaf, 1)))
        c = np.array([0.2, 0.6, 0.15]) + 0.1 * np.cos(20 * v / max(W, 1e-6))[:, None]
        col.append(c)
    # floaters around the plant
    fl = rng.uniform([-0.6, -0.6, -0.1], [0.6, 0.6, 1.2], (n_floaters, 3))
    pts.append(fl); nrm.append(np.tile([0, 0, 1.0], (n_floaters, 1))); col.append(rng.uniform(0, 1, (n_floaters, 3)))
    P = np.concatenate(pts); N = np.concatenate(nrm); C = np.clip(np.concatenate(col), 0, 1)
    n = len(P)
    # flat Gaussians: normal = third axis
    a1 = np.cross(N, rng.normal(size=(n, 3)))
    a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
    a2 = np.cross(N, a1)
    R = np.stack([a1, a2, N], axis=2)
    q = matrix_to_quat(R)
    scales = np.stack([np.full(n, 0.01), np.full(n, 0.006), np.full(n, 0.001)], 1)
    height = float(P[:-n_floaters, 2].max()) if n_floaters else float(P[:, 2].max())
    sh = None
    if sh_degree:
        from leaffit_usd.splats.cloud import SH_C0
        sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
        sh[:, 0] = (C - 0.5) / SH_C0
        sh[:, 1:] = rng.normal(0, 0.05, sh[:, 1:].shape)
    cloud = GaussianCloud.from_activated(P, scales, q, rng.uniform(0.5, 0.99, n), colors=C, sh=sh)
    up, root, scale = np.array([0, 0, 1.0]), np.zeros(3), 1.0
    if rotate:
        from leaffit_usd.splats.transform import transform_cloud

        rot = Rotation.random(random_state=seed + 1000).as_matrix()
        scale = float(rng.uniform(0.2, 5.0))
        m = np.eye(4)
        m[:3, :3] = scale * rot
        m[:3, 3] = rng.uniform(-3, 3, 3)
        cloud = transform_cloud(cloud, m)
        up = rot @ up
        root = m[:3, 3].copy()
    return SynthPlant(cloud=cloud, up=up, root=root, height=height * scale, scale=scale)
