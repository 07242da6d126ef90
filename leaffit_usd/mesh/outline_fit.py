"""The template outline out to the leaf's edge: the splats' silhouette.

The sheet is triangulated through samples of the Gaussians' *centres*, and the outermost centres
lie inside the leaf's edge (by up to a sample spacing where the capture's margin is sparse; the
smoothing spline through them cuts the convex parts a little further). Each leaf of the asset
then came out ~10 % smaller in area than the true leaf (rubber_tree: 0.85-0.95 of the true
area, median 0.90) and its silhouette a pixel or two inside the input's, all round.

:func:`silhouette_outline` grows the smooth outline, as a region, out to where the template's
splats, rendered along the sheet view's -Z, stop covering the leaf (alpha = the cut-out's
threshold): the leaf's edge as the capture shows it. Only outwards (a gap in a sparse margin is
the cut-out's business, not the outline's), at most ``max_out`` from the outline; the region's
boundary, smoothed to within a pixel, becomes the outline (the alpha cut-out carves the
serration's notches). It moved the outline's vertices along their normals before, which stopped
at the first place the outline would cross itself (a notch's two sides meeting).
"""
from __future__ import annotations

import numpy as np


def splat_alpha_image(means: np.ndarray, cov: np.ndarray, opac: np.ndarray, pad: float,
                      long_side: int = 768):
    """Alpha (H, W) of splats (means (M, 3), cov (M, 3, 3), opac (M,), sheet-view frame)
    rendered along -Z over their xy bounding box grown by ``pad``, and the bounds
    (xmin, xmax, ymin, ymax); the longer side has ``long_side`` pixels (square pixels).

    Rendered with Mip-Splatting's 2D filter (``antialias``): the image's pixel is fixed by the
    leaf's size, so the denser the capture the smaller its splats are in pixels, and 3DGS's
    plain dilation (each splat at least ~0.55 px at its full opacity) widened the silhouette
    with the density: a fringe of sub-pixel splats past a tip or along a petiole stub reached
    alpha 0.5. The capsicum of ``benchmarks/scale.py`` (seed 1, Corr / HD / OE x10 of height,
    main at a8b4436 / e8f97f3; at 1M and 5M the HD also moves by +-0.004 with the fit's random
    subsets, README) at 100k / 1M / 5M Gaussians: 0.00861 / 0.0404 / 0.0108, 0.00833 / 0.0390 / 0.0103,
    0.00838 / 0.0452 / 0.0120 with the plain dilation; 0.00857 / 0.0413 / 0.0106,
    0.00824 / 0.0417 / 0.0091, 0.00817 / 0.0412 / 0.0084 with the filter."""
    from leaffit_usd.splats.render import render_orthographic_np

    lo = means[:, :2].min(0) - pad
    hi = means[:, :2].max(0) + pad
    px = float(max(hi - lo)) / long_side
    W = max(int(np.ceil((hi[0] - lo[0]) / px)), 8)
    H = max(int(np.ceil((hi[1] - lo[1]) / px)), 8)
    bounds = (float(lo[0]), float(lo[0] + W * px), float(lo[1]), float(lo[1] + H * px))
    grey = np.full((len(means), 3), 0.5)
    r = render_orthographic_np(means, cov, grey, opac, W, H, bounds, antialias=True)
    return np.asarray(r.alpha, np.float64), bounds


def polygon_mask(poly: np.ndarray, bounds, shape) -> np.ndarray:
    """(H, W) bool: pixel centres inside the closed polygon ``poly`` (k, 2) (even-odd rule), for
    an image of ``shape`` (H, W) over ``bounds`` (xmin, xmax, ymin, ymax), row 0 = ymax."""
    xmin, xmax, ymin, ymax = bounds
    H, W = shape
    px = (xmax - xmin) / W
    y = ymax - (np.arange(H) + 0.5) * px                       # (H,) row centres
    x0, y0 = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    cross = (y0[None] > y[:, None]) != (y1[None] > y[:, None])  # (H, k)
    xi = x0[None] + (y[:, None] - y0[None]) * (x1 - x0)[None] / np.where(y1 != y0, y1 - y0, 1e-300)[None]
    xc = xmin + (np.arange(W) + 0.5) * px
    out = np.zeros((H, W), bool)
    for r in np.flatnonzero(cross.any(1)):
        xs = np.sort(xi[r, cross[r]])
        n = np.searchsorted(xs, xc)                             # crossings left of each centre
        out[r] = n % 2 == 1
    return out


def mask_outline(mask: np.ndarray, bounds) -> np.ndarray:
    """(k, 2) the outer boundary of the largest region of ``mask`` (H, W) (pixel corners, CCW,
    xy over ``bounds`` as :func:`polygon_mask`), or (0, 2) for an empty mask. The region's
    pixels are triangulated and the boundary followed with :func:`surface.boundary_loops`."""
    from scipy.ndimage import label

    from leaffit_usd.mesh.surface import boundary_loops, signed_area_xy

    lab, n = label(mask)
    if n == 0:
        return np.zeros((0, 2))
    big = lab == (1 + int(np.argmax(np.bincount(lab.ravel())[1:])))
    H, W = mask.shape
    r, c = np.nonzero(big)
    v = lambda rr, cc: rr * (W + 1) + cc  # noqa: E731 - corner (row, col) of the (H+1, W+1) grid
    bl, br, tr, tl = v(r + 1, c), v(r + 1, c + 1), v(r, c + 1), v(r, c)
    F = np.concatenate([np.stack([bl, br, tr], 1), np.stack([bl, tr, tl], 1)])   # CCW in xy
    loops = boundary_loops(F, (H + 1) * (W + 1))
    xmin, xmax, ymin, ymax = bounds
    px = (xmax - xmin) / W
    rings = [np.stack([xmin + (lp % (W + 1)) * px, ymax - (lp // (W + 1)) * px], 1) for lp in loops]
    return max(rings, key=lambda q: signed_area_xy(q))


def silhouette_outline(alpha: np.ndarray, bounds, thr: float, max_out: float):
    """``outline(ring (k, 2)) -> (m, 2)`` for :func:`leaffit_usd.mesh.surface.remesh_sheet`: the
    leaf's region grown out from the closed polygon ``ring`` (CCW, the sheet's smooth outline)
    into the splat silhouette (alpha >= ``thr`` in the image ``alpha`` (H, W) over ``bounds``,
    row 0 = ymax; closed over a quarter of ``max_out``, holes filled) up to ``max_out`` from
    it, and that region's outer boundary (a pixel staircase, CCW; the caller smooths it).

    A region, not vertices moved along their normals: the normals of a notch's two sides
    converge, and a grown outline crossed itself there. Moving the vertices stopped the whole
    outline's growth at the first crossing (lucky_bamboo's strap template grew two of its six
    steps and its leaves came out 0.87 of the true area); the region fills the notch where the
    splats cover it and stays out of it where they do not."""
    from scipy.ndimage import binary_closing, binary_fill_holes, distance_transform_edt

    xmin, xmax, ymin, ymax = bounds
    H, W = alpha.shape
    px = (xmax - xmin) / W
    # the silhouette without its pin-holes and nicks (a sparse margin's gaps are the cut-out's)
    r = max(int(round(0.25 * max_out / px)), 1)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    fg = alpha >= thr
    solid = binary_closing(np.pad(fg, r + 1), structure=xx * xx + yy * yy <= r * r)
    solid = binary_fill_holes(solid[r + 1:-r - 1, r + 1:-r - 1] | fg)

    def outline(ring: np.ndarray) -> np.ndarray:
        inside = polygon_mask(np.asarray(ring, np.float64), bounds, (H, W))
        near = distance_transform_edt(~inside) * px <= max_out
        return mask_outline(binary_fill_holes(inside | (solid & near)), bounds)

    return outline
