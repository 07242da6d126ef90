"""Texture space of the template: the chart from the template frame's xy to uv
(:class:`UVChart`: planar -- aspect-fitted or square texels -- or the envelope chart that makes
the leaf fill the texture), and rasterising an outline into texels.

The bake renders orthographically along +-Z of the template frame, carried into the chart's
coordinates, over the chart's bounds, so a texel *is* a render pixel (image layout of the
renderer: row 0 = ymax).
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


# ---- the chart: template-frame xy -> chart coordinates -> uv --------------------------------------
class UVChart:
    """The template's texture chart: template-frame xy -> chart coordinates (X, W) -> uv.

    ``bounds`` (xmin, xmax, ymin, ymax) are in chart coordinates and span the whole texture.
    Planar charts (``envelope=None``) have (X, W) = (x, y). Envelope charts keep X = x (the leaf's
    base -> apex axis) and straighten and widen each column of the leaf across the texture:

        W = (y - c(x)) * H0 / h(x)

    with c(x) a smooth centre line and h(x) >= the leaf's half-width about it (a smooth envelope,
    never below ``min_width`` x its largest value H0), so the leaf fills the chart's height in
    every column: the texture's texels are spent on the leaf, and a column is never sampled
    more coarsely than by the planar chart (H0 / h >= 1). The map is smooth; the vertices carry
    its exact uv, the texels between them its piecewise-linear interpolation.

    envelope : (xs (K,), c (K,), h (K,)) float64 samples of c and h, template frame; c and h are
        linear between the samples and constant beyond them.
    """

    def __init__(self, bounds, envelope=None):
        self.bounds = tuple(float(b) for b in bounds)
        self.envelope = None if envelope is None else tuple(np.asarray(a, np.float64) for a in envelope)

    @property
    def kind(self) -> str:
        return "planar" if self.envelope is None else "envelope"

    def _c_g(self, x: np.ndarray):
        """c(x), g(x) = H0 / h(x) and their x-derivatives, each (N,)."""
        xs, c, h = self.envelope
        g = float(h.max()) / h
        # the exact derivative of the piecewise-linear c and g: the slope of x's interval
        i = np.clip(np.searchsorted(xs, x, side="right") - 1, 0, len(xs) - 2)
        inside = (x >= xs[0]) & (x <= xs[-1])
        dx = xs[i + 1] - xs[i]
        dc = np.where(inside, (c[i + 1] - c[i]) / dx, 0.0)
        dg = np.where(inside, (g[i + 1] - g[i]) / dx, 0.0)
        return np.interp(x, xs, c), np.interp(x, xs, g), dc, dg

    def to_chart(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) chart coordinates of template-frame points ``xy`` (N, 2+)."""
        xy = np.asarray(xy, np.float64)[:, :2]
        if self.envelope is None:
            return xy.copy()
        c, g, _, _ = self._c_g(xy[:, 0])
        return np.stack([xy[:, 0], (xy[:, 1] - c) * g], 1)

    def uv(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) front UVs of template-frame points ``xy`` (N, 2+)."""
        return planar_uvs(self.to_chart(xy), self.bounds)

    def gaussians(self, means: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gaussians (means (M, 3), covariances (M, 3, 3), template frame) carried into chart
        coordinates (z unchanged) by the map and its Jacobian at each mean (first order)."""
        means = np.asarray(means, np.float64)
        cov = np.asarray(cov, np.float64)
        if self.envelope is None:
            return means, cov
        x, y = means[:, 0], means[:, 1]
        c, g, dc, dg = self._c_g(x)
        out = means.copy()
        out[:, 1] = (y - c) * g
        J = np.zeros((len(means), 3, 3))
        J[:, 0, 0] = 1.0
        J[:, 1, 0] = -dc * g + (y - c) * dg
        J[:, 1, 1] = g
        J[:, 2, 2] = 1.0
        return out, np.einsum("nij,njk,nlk->nil", J, cov, J)

    def polygon(self, poly_xy: np.ndarray, size: int) -> np.ndarray:
        """A closed template-frame polygon (k, 2) in chart coordinates, its edges subdivided to
        about a texel of a ``size``-texel texture first (the map bends straight edges)."""
        p = np.asarray(poly_xy, np.float64)[:, :2]
        if self.envelope is None or len(p) < 2:
            return self.to_chart(p)
        q = np.roll(p, -1, 0)
        step = (self.bounds[1] - self.bounds[0]) / max(int(size), 1)
        n = np.maximum(np.ceil(np.linalg.norm(q - p, axis=1) / max(step, 1e-12)), 1).astype(np.int64)
        t = np.concatenate([np.arange(k) / k for k in n])
        i = np.repeat(np.arange(len(p)), n)
        dense = p[i] + t[:, None] * (q[i] - p[i])
        return self.to_chart(dense)


def planar_chart(xy: np.ndarray, size: int, margin: float, layout: str = "fit") -> UVChart:
    """The planar chart of points ``xy`` (S, 2): aspect-fitted (``fit``) or square texels."""
    b = chart_bounds(xy, margin, size) if layout == "fit" else uv_bounds(xy, size, margin)
    return UVChart(b)


def envelope_chart(outline_xy: np.ndarray, size: int, margin: float, min_width: float = 0.3,
                   samples: int = 256) -> UVChart:
    """The envelope chart (:class:`UVChart`) of a leaf whose outer outline is ``outline_xy``
    (k, 2), template frame: per column x, the outline's lowest and highest y, each widened by a
    running extreme and smoothed into an envelope; their midpoint is the centre line c(x), their
    half-distance, floored at ``min_width`` x its largest value, is h(x). Falls back to the
    planar fitted chart for a degenerate outline."""
    from scipy.ndimage import gaussian_filter1d, maximum_filter1d, minimum_filter1d

    p = np.asarray(outline_xy, np.float64)[:, :2]
    if len(p) < 3 or np.ptp(p[:, 0]) <= 0 or np.ptp(p[:, 1]) <= 0:
        return planar_chart(p, size, margin, "fit")
    x0, x1 = float(p[:, 0].min()), float(p[:, 0].max())
    xs = np.linspace(x0, x1, samples)
    a, b = p, np.roll(p, -1, 0)
    lo_x, hi_x = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
    hit = (xs[:, None] >= lo_x[None]) & (xs[:, None] <= hi_x[None])            # (K, E)
    dx = np.where(b[:, 0] != a[:, 0], b[:, 0] - a[:, 0], 1.0)
    t = np.clip((xs[:, None] - a[None, :, 0]) / dx[None], 0.0, 1.0)
    y = a[None, :, 1] + t * (b[:, 1] - a[:, 1])[None]
    yu = np.where(hit, y, -np.inf).max(1)
    yl = np.where(hit, y, np.inf).min(1)
    ok = np.isfinite(yu) & np.isfinite(yl)
    if ok.sum() < 2:
        return planar_chart(p, size, margin, "fit")
    yu = np.interp(xs, xs[ok], yu[ok])
    yl = np.interp(xs, xs[ok], yl[ok])
    sigma = samples / 48.0
    # upper and lower envelopes, each a running extreme over 2 sigma smoothed (and never inside
    # the outline); c and h are their midpoint and half-distance: every column is filled from
    # its own lower to its own upper edge. (A centre line smoothed on its own lagged behind a
    # meandering strap leaf and widened h to its far side: lucky_bamboo's leaf filled 67 % of
    # the chart, 79 % with the two envelopes.)
    w = int(2 * sigma) | 1
    u = np.maximum(gaussian_filter1d(maximum_filter1d(yu, size=w, mode="nearest"), sigma,
                                     mode="nearest"), yu)
    lo = np.minimum(gaussian_filter1d(minimum_filter1d(yl, size=w, mode="nearest"), sigma,
                                      mode="nearest"), yl)
    c = 0.5 * (u + lo)
    h_raw = 0.5 * (u - lo)
    h = np.maximum(h_raw, float(min_width) * float(h_raw.max()))
    h = np.maximum(h, 1e-12)
    chart = UVChart((0.0, 1.0, 0.0, 1.0), (xs, c, h))
    chart.bounds = chart_bounds(chart.polygon(p, size), margin, size)
    return chart
