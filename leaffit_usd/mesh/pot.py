"""The pot and its soil as meshes (``convert --pot``): a surface of revolution fitted to the
Gaussians isolation classed as pot, and a disc at the soil's surface.

* **profile**: the pot's Gaussians in ``PROFILE_BINS`` height bins along its axis (from its lowest
  to its highest); each bin's radius is the ``OUTER_QUANTILE`` of its Gaussians' distances from
  the axis (the outer surface: the inner wall and the soil lie inside), bins without Gaussians
  interpolated, then smoothed over three bins; the lathe sweeps it through ``SEGMENTS`` angles,
  closed at the bottom by a fan;
* **soil**: a disc of ``SEGMENTS`` wedges at the soil Gaussians' median height, with the radius of
  the profile there (clipped to the soil's own extent);
* **colour**: per vertex, the mean colour of its ``COLOR_NEIGHBOURS`` nearest pot (soil)
  Gaussians, so a painted or two-coloured pot keeps its pattern. Vertex colours instead of a
  baked texture: a lathe of SEGMENTS x PROFILE_BINS vertices holds the capture's colour at the
  resolution its Gaussians have, with no texture file to carry.

Working frame (the plant's: root at the origin, +Z up), sRGB colours in [0, 1].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.geometry.plane import plane_basis

PROFILE_BINS = 24
SEGMENTS = 48
OUTER_QUANTILE = 0.75
COLOR_NEIGHBOURS = 8
MIN_GAUSSIANS = 50


@dataclass
class PotMesh:
    """pot_points (P, 3) float32, pot_faces (F, 3) int32 (outward), pot_colors (P, 3) float32;
    soil_points (S, 3), soil_faces (G, 3), soil_colors (S, 3): the same for the soil disc (empty
    when there is no soil); working frame."""

    pot_points: np.ndarray
    pot_faces: np.ndarray
    pot_colors: np.ndarray
    soil_points: np.ndarray
    soil_faces: np.ndarray
    soil_colors: np.ndarray


def _profile(h: np.ndarray, rho: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(PROFILE_BINS,) outer radius per height bin (see the module docstring)."""
    edges = np.linspace(lo, hi, PROFILE_BINS + 1)
    k = np.clip(np.searchsorted(edges, h, side="right") - 1, 0, PROFILE_BINS - 1)
    r = np.full(PROFILE_BINS, np.nan)
    for b in range(PROFILE_BINS):
        sel = rho[k == b]
        if len(sel) >= 3:
            r[b] = np.quantile(sel, OUTER_QUANTILE)
    ok = np.isfinite(r)
    if not ok.any():
        return np.full(PROFILE_BINS, float(np.quantile(rho, OUTER_QUANTILE)))
    x = np.arange(PROFILE_BINS)
    r = np.interp(x, x[ok], r[ok])
    pad = np.r_[r[0], r, r[-1]]
    return (pad[:-2] + pad[1:-1] + pad[2:]) / 3.0


def _colors(points: np.ndarray, src: np.ndarray, colors: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    k = int(min(COLOR_NEIGHBOURS, len(src)))
    _, nb = cKDTree(src).query(points, k=k)
    nb = np.asarray(nb).reshape(len(points), k)
    return np.asarray(colors, np.float64)[nb].mean(1).astype(np.float32)


def build_pot(pot_points: np.ndarray, pot_colors: np.ndarray, soil_points: np.ndarray,
              soil_colors: np.ndarray, axis: np.ndarray, centre: np.ndarray) -> PotMesh | None:
    """The pot and soil meshes (module docstring), or None when fewer than ``MIN_GAUSSIANS``
    pot Gaussians. pot_points (N, 3), pot_colors (N, 3), soil_points (M, 3), soil_colors (M, 3),
    axis (3,) unit (towards the plant), centre (3,) a point on the axis; working frame."""
    p = np.asarray(pot_points, np.float64)
    if len(p) < MIN_GAUSSIANS:
        return None
    u = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    c = np.asarray(centre, np.float64)
    basis = plane_basis(u)
    rel = p - c
    h = rel @ u
    rho = np.linalg.norm(rel @ basis, axis=1)
    lo, hi = float(np.quantile(h, 0.005)), float(np.quantile(h, 0.995))
    r = _profile(h, rho, lo, hi)
    zs = np.linspace(lo, hi, PROFILE_BINS)
    ang = np.linspace(0, 2 * np.pi, SEGMENTS, endpoint=False)
    ring = np.cos(ang)[:, None] * basis[:, 0] + np.sin(ang)[:, None] * basis[:, 1]   # (S, 3)
    pts = c + zs[:, None, None] * u + r[:, None, None] * ring[None]                 # (B, S, 3)
    pts = np.vstack([pts.reshape(-1, 3), c + lo * u])                              # + bottom centre
    faces = []
    for b in range(PROFILE_BINS - 1):
        for s in range(SEGMENTS):
            a0, a1 = b * SEGMENTS + s, b * SEGMENTS + (s + 1) % SEGMENTS
            b0, b1 = a0 + SEGMENTS, a1 + SEGMENTS
            faces += [(a0, a1, b1), (a0, b1, b0)]     # counter-clockwise seen from outside
    bottom = len(pts) - 1
    faces += [(bottom, (s + 1) % SEGMENTS, s) for s in range(SEGMENTS)]
    # the windings above are outward for a right-handed (e1, e2, axis); mirror them otherwise
    flip = float(np.cross(basis[:, 0], basis[:, 1]) @ u) < 0
    faces = np.asarray(faces, np.int32)[:, ::-1] if flip else np.asarray(faces, np.int32)
    pot = PotMesh(pot_points=pts.astype(np.float32), pot_faces=np.ascontiguousarray(faces),
                  pot_colors=_colors(pts, p, pot_colors), soil_points=np.zeros((0, 3), np.float32),
                  soil_faces=np.zeros((0, 3), np.int32), soil_colors=np.zeros((0, 3), np.float32))
    s_pts = np.asarray(soil_points, np.float64)
    if len(s_pts) >= MIN_GAUSSIANS:
        hs = float(np.median((s_pts - c) @ u))
        rs = float(np.interp(hs, zs, r))
        rs = min(rs, float(np.quantile(np.linalg.norm((s_pts - c) @ basis, axis=1), 0.99)))
        disc = np.vstack([c + hs * u, c + hs * u + rs * ring])
        pot.soil_points = disc.astype(np.float32)
        sf = np.asarray([(0, 1 + s, 1 + (s + 1) % SEGMENTS) for s in range(SEGMENTS)], np.int32)
        pot.soil_faces = np.ascontiguousarray(sf[:, ::-1] if flip else sf)
        pot.soil_colors = _colors(disc, s_pts, soil_colors)
    return pot


def chamfer(mesh_points: np.ndarray, mesh_faces: np.ndarray, gaussians: np.ndarray,
            samples: int = 20000, seed: int = 0) -> float:
    """Two-sided mean Chamfer distance between a mesh's surface (area-uniform samples) and the
    Gaussians' centres (N, 3); same units as the inputs."""
    from scipy.spatial import cKDTree

    v, f = np.asarray(mesh_points, np.float64), np.asarray(mesh_faces, np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(f), samples, p=area / area.sum())
    r1, r2 = rng.uniform(size=(2, samples))
    s = np.sqrt(r1)
    pts = (1 - s)[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri] + (s * r2)[:, None] * c[tri]
    g = np.asarray(gaussians, np.float64)
    d1, _ = cKDTree(g).query(pts)
    d2, _ = cKDTree(pts).query(g)
    return float(0.5 * (d1.mean() + d2.mean()))
