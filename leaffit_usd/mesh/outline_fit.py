"""The template outline out to the leaf's edge: the splats' silhouette.

The sheet is triangulated through samples of the Gaussians' *centres*, and the outermost centres
lie inside the leaf's edge (by up to a sample spacing where the capture's margin is sparse; the
smoothing spline through them cuts the convex parts a little further). Each leaf of the asset
then came out ~10 % smaller in area than the true leaf (rubber_tree: 0.85-0.95 of the true
area, median 0.90) and its silhouette a pixel or two inside the input's, all round.

:func:`silhouette_grow` moves the smooth outline's vertices outwards to where the template's
splats, rendered along the sheet view's -Z, stop covering the leaf (alpha = the cut-out's
threshold): the leaf's edge as the capture shows it. Only outwards (a gap in a sparse margin is
the cut-out's business, not the outline's), at most ``max_out``, smoothed along the outline
after a running maximum over three vertices (the curve reaches the serration's tips; the alpha
cut-out carves the notches).
"""
from __future__ import annotations

import numpy as np


def splat_alpha_image(means: np.ndarray, cov: np.ndarray, opac: np.ndarray, pad: float,
                      long_side: int = 768):
    """Alpha (H, W) of splats (means (M, 3), cov (M, 3, 3), opac (M,), sheet-view frame)
    rendered along -Z over their xy bounding box grown by ``pad``, and the bounds
    (xmin, xmax, ymin, ymax); the longer side has ``long_side`` pixels (square pixels)."""
    from leaffit_usd.splats.render import render_orthographic_np

    lo = means[:, :2].min(0) - pad
    hi = means[:, :2].max(0) + pad
    px = float(max(hi - lo)) / long_side
    W = max(int(np.ceil((hi[0] - lo[0]) / px)), 8)
    H = max(int(np.ceil((hi[1] - lo[1]) / px)), 8)
    bounds = (float(lo[0]), float(lo[0] + W * px), float(lo[1]), float(lo[1] + H * px))
    grey = np.full((len(means), 3), 0.5)
    r = render_orthographic_np(means, cov, grey, opac, W, H, bounds)
    return np.asarray(r.alpha, np.float64), bounds


def silhouette_grow(alpha: np.ndarray, bounds, thr: float, max_out: float):
    """``grow(outline (n, 2), normals (n, 2)) -> offsets (n,)`` for
    :func:`leaffit_usd.mesh.surface.remesh_sheet`: per vertex, how far along its outward normal
    the splat silhouette (alpha >= ``thr`` in the image ``alpha`` (H, W) over ``bounds``, row 0
    = ymax; closed over a quarter of ``max_out``, holes filled) goes on (0 where the vertex
    itself is outside it), at most ``max_out``; a running maximum over 3 vertices, then a
    Gaussian smoothing (sigma 1 vertex) along the outline."""
    from scipy.ndimage import (binary_closing, binary_fill_holes, gaussian_filter1d,
                               map_coordinates, maximum_filter1d)

    xmin, xmax, ymin, ymax = bounds
    H, W = alpha.shape
    px = (xmax - xmin) / W
    steps = np.arange(0.0, max_out + 0.5 * px, 0.5 * px)
    # the silhouette without its pin-holes and nicks (a sparse margin's gaps are the cut-out's)
    r = max(int(round(0.25 * max_out / px)), 1)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    solid = binary_closing(np.pad(alpha >= thr, r + 1), structure=xx * xx + yy * yy <= r * r)
    solid = binary_fill_holes(solid[r + 1:-r - 1, r + 1:-r - 1] | (alpha >= thr)).astype(np.float64)

    def grow(outline: np.ndarray, normals: np.ndarray) -> np.ndarray:
        q = outline[:, None, :] + steps[None, :, None] * normals[:, None, :]     # (n, T, 2)
        col = (q[..., 0] - xmin) / px - 0.5
        row = (ymax - q[..., 1]) / px - 0.5
        a = map_coordinates(solid, [row.ravel(), col.ravel()], order=1, mode="constant",
                            cval=0.0).reshape(q.shape[:2])
        inside = a >= 0.5
        first_out = np.where(inside.all(1), len(steps), np.argmin(inside, axis=1))
        off = np.where(first_out > 0, steps[np.maximum(first_out - 1, 0)], 0.0)
        off = maximum_filter1d(off, 3, mode="wrap")
        return np.clip(gaussian_filter1d(off, 1.0, mode="wrap"), 0.0, max_out)

    return grow
