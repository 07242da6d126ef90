"""Front and back texture bake of the template leaf: its Gaussians rendered orthographically
from +Z and -Z of the template frame, each side's own layer over the other (module docstring of
:mod:`leaffit_usd.mesh.template`, step 5), with the one-layer / coverage fallbacks."""
from __future__ import annotations

import logging
import time

import numpy as np

from leaffit_usd.mesh.sheet_distance import signed_sheet_offset
from leaffit_usd.mesh.template_gaussians import template_gaussians_local, template_view_colors
from leaffit_usd.mesh.texture_alpha import inpainted, side_texture
from leaffit_usd.mesh.uv_chart import UVChart, rasterize_polygon

log = logging.getLogger("leaffit_usd")


def bake_subset(xy: np.ndarray, layer: np.ndarray, cap: int) -> tuple[np.ndarray, float]:
    """Which of the template's ``n`` Gaussians the bake renders: all when ``cap`` is 0 or
    ``n <= cap``, else ``cap`` of them spread evenly over the leaf and over its two layers.

    xy : (n, 2) float, template frame (their centres in the texture plane); layer : (n,) bool
    (True = front layer). Returns ``(indices (m,) int64 sorted, widen)``: each kept Gaussian
    stands for ``widen = n / m`` of its neighbours, so its covariance is multiplied by ``widen``
    (its footprint area by ``widen``: opacity x area per unit area, hence the layer's accumulated
    alpha, stays what the whole set gives).

    The choice is systematic sampling along a Z-order (Morton) curve of a 1024^2 grid over the
    leaf, per layer: every (n / m)-th Gaussian in curve order. A random subset clumps and leaves
    gaps, and a gap in the own layer lets the other side's colour through (a colour shift where
    the two sides differ); the even spread keeps each layer's cover uniform. Deterministic.

    Why: a dense capture's template leaf holds ~90k Gaussians at 1M and ~450k at 5M; the bake's
    cost grows with them while a 1024^2 texture cannot show more. Measured on the paper8
    capsicum at 1M (89,634 -> 65,536, ``MeshParams.bake_gaussians``): vs the full bake, mean
    dE76 1.9 (p95 6.1), PSNR 37.5 dB, alpha cut-out IoU 0.9997, mean colour shift < 0.1/255;
    bake CPU 20 -> 12 s. (32,768: dE 3.6, PSNR 33 dB.)
    """
    n = len(xy)
    if cap <= 0 or n <= cap:
        return np.arange(n, dtype=np.int64), 1.0
    xy = np.asarray(xy, np.float64)
    lo, hi = xy.min(0), xy.max(0)
    cell = np.clip(((xy - lo) / np.maximum(hi - lo, 1e-300) * 1023.0).astype(np.int64), 0, 1023)
    code = np.zeros(n, np.int64)
    for bit in range(10):                                   # interleave x and y bits
        code |= ((cell[:, 0] >> bit) & 1) << (2 * bit)
        code |= ((cell[:, 1] >> bit) & 1) << (2 * bit + 1)
    code |= np.asarray(layer, np.int64) << 20
    order = np.argsort(code, kind="stable")
    pick = order[((np.arange(cap) + 0.5) * (n / cap)).astype(np.int64)]
    return np.sort(pick), n / float(cap)


def _bake_set(means, cov, opac, view_colors: dict, off, cap: int, chart, pixel: tuple):
    """The template Gaussians the bake renders (:func:`bake_subset`), carried into the chart.

    means (M, 3), cov (M, 3, 3), opac (M,), view_colors {from_below: (M, 3)}, off (M,) signed
    sheet offsets: template frame; cap : ``max_gaussians``; chart : the :class:`UVChart`;
    pixel : (sx, sy) size of a render pixel in chart units. Returns (means, cov) in the chart's
    coordinates, then opac, view_colors, off of the kept Gaussians, and ``info`` (bake_gaussians,
    bake_widen).
    """
    from leaffit_usd.splats.render import DILATION

    keep, widen = bake_subset(means[:, :2], off >= 0, cap)
    info = {"bake_gaussians": int(len(keep)), "bake_widen": float(widen)}
    if widen <= 1.0:
        return (*chart.gaussians(means, cov), opac, view_colors, off, info)
    means_c, cov_c = chart.gaussians(means[keep], cov[keep] * widen)
    # the renderer adds DILATION px^2 to every footprint: widen that part too, so each kept
    # Gaussian's screen footprint is ``widen`` times the one it had (sub-pixel splats are mostly
    # dilation; without this a thin layer lets the other side's colour through)
    cov_c[:, 0, 0] += (widen - 1.0) * DILATION * pixel[0] ** 2
    cov_c[:, 1, 1] += (widen - 1.0) * DILATION * pixel[1] ** 2
    return (means_c, cov_c, opac[keep], {k: v[keep] for k, v in view_colors.items()}, off[keep],
            info)


def _coverage_fallback(front, back_reg, cf: float, cb: float, mask, thr: float, min_coverage: float):
    """(front, back, fallback name or None): a side whose splats cover less than
    ``min_coverage`` of the sheet's silhouette takes the other side's texture; both: colours
    inpainted over the silhouette. Each with a warning."""
    if cf < min_coverage and cb < min_coverage:
        log.warning("mesh: the template's splats cover only %.0f%% (front) / %.0f%% (back) of the "
                    "leaf; textures are inpainted over the mesh silhouette", 100 * cf, 100 * cb)
        return inpainted(front, mask, thr), inpainted(back_reg, mask, thr), "inpainted"
    if cb < min_coverage:
        log.warning("mesh: the leaf's back is covered only %.0f%%; the back texture reuses the "
                    "front", 100 * cb)
        return front, front.copy(), "back_from_front"
    if cf < min_coverage:
        log.warning("mesh: the leaf's front is covered only %.0f%%; the front texture reuses the "
                    "back", 100 * cf)
        return back_reg.copy(), back_reg, "front_from_back"
    return front, back_reg, None


def bake_textures(cloud_working, fits, sheet_points: np.ndarray, sheet_faces: np.ndarray,
                  outline_xy: np.ndarray, chart: UVChart, size: int, thr: float = 0.5,
                  min_coverage: float = 0.6, supersample: int = 1, max_gaussians: int = 0,
                  rotation=None, cut_out: bool = True):
    """Front and back RGBA float textures (H, W, 4) in [0, 1], straight alpha, row 0 = top.

    Colours are view-dependent: each texture evaluates the Gaussians' SH (working frame) for its
    own view direction, down onto the front and up onto the back (:func:`template_view_colors`).

    sheet_points, sheet_faces : the sheet (template frame, CCW from +Z). A capture of a leaf holds
        a layer of Gaussians on each side of the blade; each side is its own layer (Gaussians on
        that side of the sheet: signed offset along the closest face's normal) composited over
        the other layer, so the global depth sort of the rasteriser cannot mix the two layers
        where the blade is tilted in the view, and gaps in one layer show the other.
    outline_xy : (k, 2) the sheet's outer boundary, template frame (coverage and fallbacks)
    chart : the front texture's chart (:class:`UVChart`: template frame -> texture); the
        Gaussians are carried into its coordinates and rendered over its bounds; the back texture
        is its mirror image (column c of the back = column W-1-c of the front)
    max_gaussians : at most this many Gaussians rendered, widened for the rest (:func:`bake_subset`)
    rotation : (3, 3) template -> sheet view (:mod:`.view_frame`), the frame of the sheet and chart
    cut_out : alpha from the splat coverage (the leaf's own edge, serration kept); False: alpha =
        the sheet's silhouette (``outline_xy``), for a leaf the view does not see face-on, whose
        steep parts leave gaps between splats seen edge-on that are no edge of the leaf
    Returns (front, back, info) with coverage figures and the fallback used, if any.
    """
    from leaffit_usd.splats.render import render_orthographic_np
    means, cov, _, opac = template_gaussians_local(cloud_working, fits, rotation)
    view_colors = template_view_colors(cloud_working, fits, rotation)  # view-dependent (SH) per side
    bounds = chart.bounds
    mask = rasterize_polygon(chart.polygon(outline_xy, size), size, size, bounds)
    info = {"template_gaussians": int(len(means))}
    if len(means) == 0:
        log.warning("mesh: the template has no Gaussians to bake; textures are flat grey")
        flat = np.concatenate([np.full((size, size, 3), 0.3), mask[..., None]], -1)
        return flat, flat[:, ::-1].copy(), dict(coverage_front=0.0, coverage_back=0.0,
                                                 texture_fallback="flat")
    t0 = time.perf_counter()
    off = signed_sheet_offset(means, sheet_points, sheet_faces)
    info["front_gaussians"] = int((off >= 0).sum())
    info["back_gaussians"] = int((off < 0).sum())

    ss = max(int(supersample), 1)
    pixel = ((bounds[1] - bounds[0]) / (size * ss), (bounds[3] - bounds[2]) / (size * ss))
    means_c, cov_c, opac, view_colors, off, sub = _bake_set(    # into the chart's coordinates
        means, cov, opac, view_colors, off, int(max_gaussians), chart, pixel)
    info.update(sub)

    def render(sel, from_below):
        """Premultiplied colour (H, W, 3) and alpha (H, W), rendered ss x ss per texel and
        box-filtered (the average of premultiplied samples: dividing by the averaged alpha
        later gives the coverage-weighted colour, true to the input at the rim)."""
        sel = np.flatnonzero(sel)
        if len(sel) == 0:
            z = np.zeros((size, size))
            return z[..., None].repeat(3, -1), z
        n = size * ss
        r = render_orthographic_np(means_c[sel], cov_c[sel], view_colors[from_below][sel], opac[sel],
                                   n, n, bounds, from_below=from_below)
        c = np.asarray(r.color, np.float64).reshape(size, ss, size, ss, 3).mean((1, 3))
        a = np.asarray(r.alpha, np.float64).reshape(size, ss, size, ss).mean((1, 3))
        return c, a

    def side(own_sel, from_below):
        """The side's own layer composited over the other layer (premultiplied 'over')."""
        c1, a1 = render(own_sel, from_below)
        c2, a2 = render(~own_sel, from_below)
        own_cover = float((a1 > thr)[mask].mean()) if mask.any() else 0.0
        return (c1 + (1 - a1)[..., None] * c2, a1 + (1 - a1) * a2), own_cover

    front_sel = off >= 0
    (fc, fa), own_f = side(front_sel, False)
    (bc, ba), own_b = side(~front_sel, True)   # registered with the front (not mirrored yet)
    front, cf = side_texture(fc, fa, thr, mask)
    back_reg, cb = side_texture(bc, ba, thr, mask)
    info["own_layer_coverage_front"], info["own_layer_coverage_back"] = own_f, own_b
    one_layer = [nm for nm, c in (("front", own_f), ("back", own_b)) if c < min_coverage]
    if one_layer:
        log.warning("mesh: the leaf's %s side has few Gaussians of its own (seen from one side "
                    "only?); that texture shows the other layer", " and ".join(one_layer))
    info["one_layer_sides"] = one_layer
    info["bake_seconds"] = time.perf_counter() - t0
    info["coverage_front"], info["coverage_back"] = cf, cb
    front, back_reg, fallback = _coverage_fallback(front, back_reg, cf, cb, mask, thr, min_coverage)
    info["texture_fallback"] = fallback
    info["alpha_cut_out"] = bool(cut_out and fallback != "inpainted")
    if not cut_out and fallback != "inpainted":
        front[..., 3] = back_reg[..., 3] = mask
    info["alpha_coverage_front"] = float((front[..., 3] > thr).mean())
    info["alpha_coverage_back"] = float((back_reg[..., 3] > thr).mean())
    return front, back_reg[:, ::-1].copy(), info
