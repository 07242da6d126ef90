"""Small synthetic plants with ground-truth leaf meshes, for the fit's tests and benchmark.

Not the sample generator (that is ``samples/``, with textures, petioles and realistic species);
this is the minimum the registration needs: curved, twisted, differently sized leaf sheets on a
vertical stem, Gaussians sampled by area on them with thickness noise and a few floaters,
a Segmentation with ``leaf_base``/``leaf_tip`` and the GT mesh of every leaf. Working frame (root at
the origin, +Z up, height ~1). Deterministic in ``seed``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.segment.result import Segmentation
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.splats.cloud import GaussianCloud


@dataclass
class SyntheticPlant:
    """cloud : GaussianCloud, working frame; seg : Segmentation with GT labels, base and tip;
    leaf_vertices : (V, 3) float64 GT leaf meshes, working frame; leaf_faces : (F, 3) int64;
    leaf_vertex_ids : (V,) int32, leaf label (1..L) of each vertex."""

    cloud: GaussianCloud
    seg: Segmentation
    leaf_vertices: np.ndarray
    leaf_faces: np.ndarray
    leaf_vertex_ids: np.ndarray


def leaf_sheet(length=0.2, width=0.08, bend=0.15, curl=0.6, twist=0.3, asym=0.0, tip=0.8,
               nu=40, nv=13):
    """GT leaf mesh in its local frame: base at the origin, apex at (length, 0, ~), +z upper side.

    Returns (vertices (nu*nv, 3) float64, faces (F, 3) int64), counter-clockwise from +z.
    bend : midrib rise as a fraction of the length (parabolic), curl : cross-section cupping,
    twist : radians of twist base->apex, asym : left/right width difference, tip : shape exponent.
    """
    u = np.linspace(0.0, 1.0, nu)
    v = np.linspace(-1.0, 1.0, nv)
    U, V = np.meshgrid(u, v, indexing="ij")
    half = 0.5 * width * np.sin(np.pi * np.clip(U, 0, 1) ** tip) ** 0.9
    half = half * (1.0 + asym * np.sign(V))
    x = length * U
    y = V * half
    z = bend * length * U**2 + curl * (y**2) / max(width, 1e-9)
    ang = twist * U
    y2 = y * np.cos(ang) - z * 0.0
    z2 = z + y * np.sin(ang)
    verts = np.stack([x, y2, z2], -1).reshape(-1, 3)
    faces = []
    for i in range(nu - 1):
        for j in range(nv - 1):
            a, b, c, d = i * nv + j, (i + 1) * nv + j, (i + 1) * nv + j + 1, i * nv + j + 1
            faces += [(a, b, c), (a, c, d)]
    return verts, np.asarray(faces, np.int64)


def sample_sheet(verts, faces, n, rng, noise=0.002, floaters=0.01):
    """Gaussians on a mesh: centres (n, 3) area-uniform + normal noise, in-plane std ~ spacing,
    thin normal std; returns (means, scales (n,3), rotation matrices (n,3,3))."""
    tri = verts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(faces), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], 1)
    pts = np.einsum("ni,nij->nj", bary, tri[f])
    e1 = tri[f, 1] - tri[f, 0]
    nrm = np.cross(e1, tri[f, 2] - tri[f, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(nrm, e1)
    pts = pts + nrm * rng.normal(0, noise, (n, 1))
    n_float = int(floaters * n)
    if n_float:
        pick = rng.choice(n, n_float, replace=False)
        pts[pick] += nrm[pick] * rng.uniform(0.02, 0.05, (n_float, 1)) * rng.choice([-1, 1], (n_float, 1))
    spacing = np.sqrt(area.sum() / n)
    scales = np.stack([np.full(n, 0.7 * spacing), np.full(n, 0.7 * spacing), np.full(n, 0.1 * spacing)], 1)
    rot = np.stack([e1, e2, nrm], -1)
    return pts, scales, rot


def _rot(axis, ang):
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.asarray(axis, float) * ang).as_matrix()


def make_plant(n_leaves=6, n_gaussians=20000, seed=0, stem_fraction=0.1, size_spread=0.25,
               noise=0.002, floaters=0.01) -> SyntheticPlant:
    """A vertical stem (height 1) with ``n_leaves`` leaves of varied size/curvature/twist."""
    rng = np.random.default_rng(seed)
    n_stem = int(stem_fraction * n_gaussians)
    n_leaf = (n_gaussians - n_stem) // max(n_leaves, 1)
    means, scales, rots, labels = [], [], [], []
    z = np.linspace(0, 1, n_stem)
    means.append(np.stack([rng.normal(0, 0.003, n_stem), rng.normal(0, 0.003, n_stem), z], 1))
    scales.append(np.full((n_stem, 3), 0.004))
    rots.append(np.tile(np.eye(3), (n_stem, 1, 1)))
    labels.append(np.zeros(n_stem, np.int32))
    gv, gf, gid, bases, tips = [], [], [], [], []
    voff = 0
    for l in range(n_leaves):
        L = 0.2 * np.exp(rng.uniform(-size_spread, size_spread))
        verts, faces = leaf_sheet(length=L, width=L * rng.uniform(0.35, 0.5),
                                  bend=rng.uniform(-0.05, 0.3), curl=rng.uniform(0.0, 0.8),
                                  twist=rng.uniform(-0.5, 0.5), asym=rng.uniform(-0.1, 0.1),
                                  tip=rng.uniform(0.7, 1.2))
        h = 0.2 + 0.75 * (l + 0.5) / n_leaves
        az = 2.39996 * l + rng.uniform(-0.2, 0.2)
        tilt = rng.uniform(-0.6, 0.3)            # pitch of the leaf (negative = raised)
        R = _rot([0, 0, 1], az) @ _rot([0, 1, 0], tilt)
        t = np.array([0.04 * np.cos(az), 0.04 * np.sin(az), h])
        vw = verts @ R.T + t
        pts, sc, rot = sample_sheet(verts, faces, n_leaf, rng, noise=noise, floaters=floaters)
        means.append(pts @ R.T + t)
        scales.append(sc)
        rots.append(np.einsum("ij,njk->nik", R, rot))
        labels.append(np.full(n_leaf, l + 1, np.int32))
        gv.append(vw)
        gf.append(faces + voff)
        gid.append(np.full(len(vw), l + 1, np.int32))
        voff += len(vw)
        bases.append(t)
        tips.append(np.array([L, 0, verts[np.argmax(verts[:, 0]), 2]]) @ R.T + t)
    means = np.concatenate(means)
    labels = np.concatenate(labels)
    rot_m = np.concatenate(rots)
    colors = np.where(labels[:, None] > 0, [0.2, 0.6, 0.2], [0.4, 0.3, 0.2])
    cloud = GaussianCloud.from_activated(means, np.concatenate(scales), matrix_to_quat(rot_m),
                                         np.full(len(means), 0.9), colors=colors)
    base_idx, tip_idx = [], []
    for l in range(n_leaves):
        idx = np.flatnonzero(labels == l + 1)
        base_idx.append(idx[np.argmin(np.linalg.norm(means[idx] - bases[l], axis=1))])
        tip_idx.append(idx[np.argmin(np.linalg.norm(means[idx] - tips[l], axis=1))])
    seg = Segmentation(labels=labels, root_index=0, leaf_tip=np.asarray(tip_idx, np.int64),
                       leaf_base=np.asarray(base_idx, np.int64))
    return SyntheticPlant(cloud, seg, np.concatenate(gv), np.concatenate(gf), np.concatenate(gid))
