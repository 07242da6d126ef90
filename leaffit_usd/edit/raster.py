"""A small vectorised triangle rasteriser (orthographic, looking down -Z), for silhouettes,
depth maps and UV look-ups of meshes: the retarget cages and the texture-propagation checks.

Pixel (row, col) covers x in [xmin + col*px, xmin + (col+1)*px], y from the top (row 0 = ymax).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Raster:
    """Result of :func:`rasterize`.

    mask : (H, W) bool, covered pixels
    depth : (H, W) float64, z of the front-most surface (nearest to +Z viewer), NaN where empty
    face : (H, W) int64, index of the visible triangle (-1 where empty)
    bary : (H, W, 3) float64, barycentric coordinates in that triangle
    bounds : (xmin, xmax, ymin, ymax) of the image, same units as the points
    """

    mask: np.ndarray
    depth: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    bounds: tuple

    def interpolate(self, values: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Interpolate per-vertex ``values`` (V, C) at every covered pixel -> (H, W, C), NaN elsewhere."""
        values = np.asarray(values, np.float64)
        out = np.full(self.mask.shape + values.shape[1:], np.nan)
        f = faces[self.face[self.mask]]
        out[self.mask] = np.einsum("pk,pk...->p...", self.bary[self.mask], values[f])
        return out


def rasterize(points: np.ndarray, faces: np.ndarray, width: int, height: int, bounds) -> Raster:
    """Rasterise triangles seen from +Z.

    points : (V, 3) float, the view frame (x right, y up, z towards the viewer)
    faces : (F, 3) int; both windings are drawn (no culling)
    bounds : (xmin, xmax, ymin, ymax) of the image
    """
    pts = np.asarray(points, np.float64)
    faces = np.asarray(faces, np.int64)
    xmin, xmax, ymin, ymax = map(float, bounds)
    sx, sy = width / (xmax - xmin), height / (ymax - ymin)
    # pixel-space coordinates: col = (x - xmin) * sx, row = (ymax - y) * sy
    c = (pts[:, 0] - xmin) * sx
    r = (ymax - pts[:, 1]) * sy
    tri_c, tri_r, tri_z = c[faces], r[faces], pts[faces, 2]
    c0 = np.clip(np.floor(tri_c.min(1) - 0.5).astype(np.int64) + 1, 0, width)
    c1 = np.clip(np.floor(tri_c.max(1) - 0.5).astype(np.int64) + 1, 0, width)
    r0 = np.clip(np.floor(tri_r.min(1) - 0.5).astype(np.int64) + 1, 0, height)
    r1 = np.clip(np.floor(tri_r.max(1) - 0.5).astype(np.int64) + 1, 0, height)
    nw, nh = np.maximum(c1 - c0, 0), np.maximum(r1 - r0, 0)
    count = nw * nh
    tri = np.repeat(np.arange(len(faces)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    cc = c0[tri] + local % np.maximum(nw[tri], 1)
    rr = r0[tri] + local // np.maximum(nw[tri], 1)
    px, py = cc + 0.5, rr + 0.5
    a_c, a_r = tri_c[tri], tri_r[tri]
    v0c, v0r = a_c[:, 1] - a_c[:, 0], a_r[:, 1] - a_r[:, 0]
    v1c, v1r = a_c[:, 2] - a_c[:, 0], a_r[:, 2] - a_r[:, 0]
    v2c, v2r = px - a_c[:, 0], py - a_r[:, 0]
    den = v0c * v1r - v1c * v0r
    ok = np.abs(den) > 1e-15
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (v2c * v1r - v1c * v2r) / den
        b2 = (v0c * v2r - v2c * v0r) / den
    b0 = 1.0 - b1 - b2
    eps = -1e-9
    inside = ok & (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
    tri, rr, cc = tri[inside], rr[inside], cc[inside]
    bary = np.stack([b0[inside], b1[inside], b2[inside]], 1)
    z = (bary * tri_z[tri]).sum(1)
    pix = rr * width + cc
    order = np.lexsort((-z, pix))                      # per pixel, largest z (nearest) first
    pix, first = np.unique(pix[order], return_index=True)
    sel = order[first]
    mask = np.zeros(height * width, bool)
    depth = np.full(height * width, np.nan)
    face = np.full(height * width, -1, np.int64)
    bb = np.zeros((height * width, 3))
    mask[pix] = True
    depth[pix] = z[sel]
    face[pix] = tri[sel]
    bb[pix] = bary[sel]
    shape = (height, width)
    return Raster(mask.reshape(shape), depth.reshape(shape), face.reshape(shape),
                  bb.reshape(shape + (3,)), (xmin, xmax, ymin, ymax))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks of the same shape."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0
