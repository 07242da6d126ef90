"""A quick-look picture of a segmentation: two orthographic views (front X-Z, side Y-Z, working
frame) side by side; Gaussians coloured by leaf (stem grey), the rootward tree in black, apexes as
red rings, petiole bases as blue squares, the root as a black square. Plain numpy raster, written
with OpenImageIO.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.segment.result import Segmentation

STEM = np.array([0.62, 0.62, 0.62])
BACKGROUND = np.array([1.0, 1.0, 1.0])


def leaf_colors(n: int) -> np.ndarray:
    """(n + 1, 3) float RGB in [0, 1]: row 0 = stem grey, rows 1..n distinct hues (golden ratio)."""
    out = np.zeros((n + 1, 3))
    out[0] = STEM
    for i in range(1, n + 1):
        h = (i * 0.61803398875) % 1.0
        out[i] = _hsv(h, 0.75, 0.85)
    return out


def _hsv(h, s, v):
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def render_preview(points_working: np.ndarray, seg: Segmentation, size: int = 700) -> np.ndarray:
    """(size, 2 * size, 3) float32 RGB image of ``seg`` over ``points_working`` ((N, 3), working
    frame, the points the segmentation ran on)."""
    pts = np.asarray(points_working, np.float64)
    cols = leaf_colors(seg.n_leaves)[np.clip(seg.labels, 0, None)]
    panels = []
    for axes in ((0, 2), (1, 2)):
        img = np.empty((size, size, 3))
        img[:] = BACKGROUND
        uv = pts[:, axes]
        lo, hi = uv.min(0), uv.max(0)
        span = float((hi - lo).max()) * 1.06 or 1.0
        c = (lo + hi) / 2

        def to_px(q):
            q = (np.asarray(q, np.float64)[..., list(axes)] - c) / span + 0.5
            col = np.clip((q[..., 0] * (size - 1)).round().astype(int), 0, size - 1)
            row = np.clip(((1 - q[..., 1]) * (size - 1)).round().astype(int), 0, size - 1)
            return row, col

        order = np.argsort(pts[:, 1 - axes[0] if axes[0] < 2 else 0])  # draw far points first
        r, cc = to_px(pts[order])
        img[r, cc] = cols[order]
        # tree edges
        if len(seg.tree_nodes):
            child = np.flatnonzero(seg.tree_parent >= 0)
            a = pts[seg.tree_nodes[child]]
            b = pts[seg.tree_nodes[seg.tree_parent[child]]]
            t = np.linspace(0, 1, 6)[:, None, None]
            seg_pts = (a[None] * (1 - t) + b[None] * t).reshape(-1, 3)
            r, cc = to_px(seg_pts)
            img[r, cc] = 0.05
        _marks(img, *to_px(pts[seg.apex_indices]), color=(0.9, 0.05, 0.05), ring=True)
        _marks(img, *to_px(pts[seg.leaf_base]), color=(0.05, 0.2, 0.95), ring=False)
        _marks(img, *to_px(pts[[seg.root_index]]), color=(0, 0, 0), ring=False)
        panels.append(img)
    return np.concatenate(panels, axis=1).astype(np.float32)


def _marks(img, rows, cols, color, ring, r=5):
    h, w = img.shape[:2]
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    dd = np.sqrt(yy**2 + xx**2)
    keep = (np.abs(dd - r + 0.5) < 1.0) if ring else (np.maximum(abs(yy), abs(xx)) <= r // 2 + 1)
    oy, ox = yy[keep], xx[keep]
    for y, x in zip(np.atleast_1d(rows), np.atleast_1d(cols)):
        py, px = np.clip(y + oy, 0, h - 1), np.clip(x + ox, 0, w - 1)
        img[py, px] = color


def write_preview(path, points_working: np.ndarray, seg: Segmentation, size: int = 700) -> None:
    """Render :func:`render_preview` and write it (PNG, JPEG or EXR by suffix) atomically."""
    from leaffit_usd.image_io import write_image

    write_image(path, render_preview(points_working, seg, size))
