"""Texture space of the template: the UV chart's bounds in the template frame (aspect-fitted or
square texels), planar UVs into it, and rasterising an outline into texels.

The bake renders orthographically along +-Z of the template frame over these very bounds, so a
texel *is* a render pixel (image layout of the renderer: row 0 = ymax).
"""
from __future__ import annotations

import numpy as np


def uv_bounds(xy: np.ndarray, size: int, margin: float) -> tuple[float, float, float, float]:
    """Square-texel bounds (xmin, xmax, ymin, ymax) of a ``size`` x ``size`` texture around ``xy``."""
    from leaffit_usd.splats.render import fit_bounds

    return fit_bounds(xy, size, size, margin)


def chart_bounds(xy: np.ndarray, margin: float, size: int = 0) -> tuple[float, float, float, float]:
    """Aspect-fitted bounds (xmin, xmax, ymin, ymax): the bounding box of ``xy`` (S, 2) grown by
    ``margin`` of its own extent on each axis; mapped onto the whole square texture, so the
    leaf fills it whatever its aspect ratio (texels are then rectangles on the leaf). With
    ``size`` (texels), the margin is at least 5 texels (the cut-out's soft rim stays off the
    border: an empty border for clamped lookups)."""
    if size:
        margin = max(margin, 5.0 / size)
    m = np.asarray(xy, np.float64)[:, :2]
    if len(m) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    lo, hi = m.min(0), m.max(0)
    ext = np.maximum(hi - lo, 1e-9)
    lo, hi = lo - margin * ext, hi + margin * ext
    return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


def planar_uvs(xy: np.ndarray, bounds) -> np.ndarray:
    """(S, 2) front UVs of template-frame ``xy`` (S, 2) for the texture covering ``bounds``."""
    xmin, xmax, ymin, ymax = bounds
    return np.stack([(xy[:, 0] - xmin) / (xmax - xmin), (xy[:, 1] - ymin) / (ymax - ymin)], 1)


def rasterize_polygon(poly_xy: np.ndarray, width: int, height: int, bounds) -> np.ndarray:
    """(H, W) bool: pixel centres inside the closed polygon (k, 2) (even-odd rule), image layout
    of the renderer (row 0 = ymax)."""
    xmin, xmax, ymin, ymax = bounds
    sx, sy = (xmax - xmin) / width, (ymax - ymin) / height
    yc = ymax - (np.arange(height) + 0.5) * sy                        # (H,)
    p0, p1 = poly_xy, np.roll(poly_xy, -1, 0)
    y0, y1 = p0[:, 1][None], p1[:, 1][None]
    cross = ((y0 <= yc[:, None]) & (yc[:, None] < y1)) | ((y1 <= yc[:, None]) & (yc[:, None] < y0))
    t = (yc[:, None] - y0) / np.where(y1 != y0, y1 - y0, 1.0)
    xc = p0[:, 0][None] + t * (p1[:, 0] - p0[:, 0])[None]
    col = np.ceil((xc - xmin) / sx - 0.5).astype(np.int64)            # first pixel right of x
    col = np.clip(col, 0, width)
    r, e = np.nonzero(cross)
    toggle = np.zeros((height, width + 1), np.int64)
    np.add.at(toggle, (r, col[r, e]), 1)
    return (np.cumsum(toggle, axis=1)[:, :width] % 2).astype(bool)
