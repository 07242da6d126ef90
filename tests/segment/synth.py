"""Small synthetic plants with known leaf labels, for the segmentation and geodesic tests.

Working frame: root at the origin, +Z up, height about 1. A vertical stem (cylinder), and per leaf
a petiole (thin cylinder, labelled stem = 0) ending in a flat elliptic (or two-lobed) blade
(label 1..L). Points are sampled uniformly by area; ``normals`` are the surface normals (the
smallest-scale axis a 3DGS Gaussian on that surface would have).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SynthPlant:
    points: np.ndarray   # (N, 3) float64, working frame
    normals: np.ndarray  # (N, 3) float64 unit
    labels: np.ndarray   # (N,) int32: 0 stem/petiole, 1..L leaves, -1 floaters
    root_index: int


def _cylinder(a, b, radius, n, rng):
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = b - a
    length = np.linalg.norm(axis)
    w = axis / length
    u = np.cross(w, [1.0, 0, 0]) if abs(w[0]) < 0.9 else np.cross(w, [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    t = rng.random(n)
    phi = rng.random(n) * 2 * np.pi
    radial = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return a + t[:, None] * axis + radius * radial, radial


def _blade(base, direction, length, width, n, rng, lobed=False, droop=0.15):
    """Elliptic blade from ``base`` along horizontal-ish ``direction`` (unit), gently drooping."""
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    side = np.cross([0, 0, 1.0], d)
    side /= np.linalg.norm(side)
    pts = []
    while sum(len(p) for p in pts) < n:
        x = rng.random(4 * n)
        y = (rng.random(4 * n) - 0.5) * 2
        if lobed:  # two lobes: widest at x=0.7, a notch at the centre tip
            half = np.sin(np.pi * np.clip(x, 0, 1)) ** 0.8 * (0.6 + 0.4 * x)
            keep = np.abs(y) <= half
            keep &= ~((x > 0.55) & (np.abs(y) < 0.35 * (x - 0.55) / 0.45))
        else:
            keep = np.abs(y) <= np.sqrt(np.clip(1 - (2 * x - 1) ** 2, 0, None))
        pts.append(np.stack([x[keep], y[keep]], 1))
    xy = np.concatenate(pts)[:n]
    s = xy[:, 0] * length
    lat = xy[:, 1] * width / 2
    z = -droop * s**2 / length + 0.1 * s  # rises then droops
    p = base + s[:, None] * d + lat[:, None] * side + z[:, None] * np.array([0, 0, 1.0])
    dz = -2 * droop * s / length + 0.1
    tangent = d[None] + dz[:, None] * np.array([0, 0, 1.0])
    nrm = np.cross(tangent, side[None])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return p, nrm


def make_plant(n_leaves=6, n_points=20000, seed=0, lobed=False, leaf_length=0.22,
               leaf_width=0.12, petiole=0.06, floaters=0, stem_radius=0.008) -> SynthPlant:
    """A plant of height about 1 with ``n_leaves`` leaves spiralling up the stem."""
    rng = np.random.default_rng(seed)
    stem_h = 0.85
    leaf_area = leaf_length * leaf_width * np.pi / 4
    stem_area = 2 * np.pi * stem_radius * stem_h
    pet_area = 2 * np.pi * 0.004 * petiole
    total = n_leaves * (leaf_area + pet_area) + stem_area
    density = n_points / total
    P, N, L = [], [], []
    p, nr = _cylinder([0, 0, 0], [0, 0, stem_h], stem_radius, int(stem_area * density), rng)
    P.append(p), N.append(np.full_like(nr, np.nan)), L.append(np.zeros(len(p), np.int32))
    for j in range(n_leaves):
        h = 0.25 + 0.6 * (j + 0.5) / n_leaves
        ang = j * 2.4 + rng.normal(0, 0.1)
        d = np.array([np.cos(ang), np.sin(ang), 0.0])
        a = np.array([0, 0, h]) + stem_radius * d
        b = a + petiole * (d + np.array([0, 0, 0.5])) / np.linalg.norm(d + [0, 0, 0.5])
        p, nr = _cylinder(a, b, 0.004, max(int(pet_area * density), 20), rng)
        P.append(p), N.append(np.full_like(nr, np.nan)), L.append(np.zeros(len(p), np.int32))
        p, nr = _blade(b, d, leaf_length, leaf_width, int(leaf_area * density), rng, lobed=lobed)
        P.append(p), N.append(nr), L.append(np.full(len(p), j + 1, np.int32))
    if floaters:
        p = rng.uniform([-0.5, -0.5, 0], [0.5, 0.5, 1], (floaters, 3))
        P.append(p), N.append(np.tile([0, 0, 1.0], (floaters, 1))), L.append(np.full(floaters, -1, np.int32))
    points = np.concatenate(P) + rng.normal(0, 0.0008, (sum(len(p) for p in P), 3))
    normals = np.concatenate(N)
    labels = np.concatenate(L)
    perm = rng.permutation(len(points))
    points, normals, labels = points[perm], normals[perm], labels[perm]
    root = int(np.argmin(np.linalg.norm(points, axis=1)))
    return SynthPlant(points, normals, labels, root)
