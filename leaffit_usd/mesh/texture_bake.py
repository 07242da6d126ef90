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


def bake_textures(cloud_working, fits, sheet_points: np.ndarray, sheet_faces: np.ndarray,
                  outline_xy: np.ndarray, chart: UVChart, size: int, thr: float = 0.5,
                  min_coverage: float = 0.6, supersample: int = 1):
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
    Returns (front, back, info) with coverage figures and the fallback used, if any.
    """
    from leaffit_usd.splats.render import render_orthographic_np

    means, cov, _, opac = template_gaussians_local(cloud_working, fits)
    view_colors = template_view_colors(cloud_working, fits)  # view-dependent (SH) per side
    bounds = chart.bounds
    mask = rasterize_polygon(chart.polygon(outline_xy, size), size, size, bounds)
    info = {}
    if len(means) == 0:
        log.warning("mesh: the template has no Gaussians to bake; textures are flat grey")
        flat = np.concatenate([np.full((size, size, 3), 0.3), mask[..., None]], -1)
        return flat, flat[:, ::-1].copy(), dict(coverage_front=0.0, coverage_back=0.0,
                                                 texture_fallback="flat")
    t0 = time.perf_counter()
    off = signed_sheet_offset(means, sheet_points, sheet_faces)
    means_c, cov_c = chart.gaussians(means, cov)   # into the chart's coordinates
    info["front_gaussians"] = int((off >= 0).sum())
    info["back_gaussians"] = int((off < 0).sum())

    ss = max(int(supersample), 1)

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
    fallback = None
    if cf < min_coverage and cb < min_coverage:
        fallback = "inpainted"
        log.warning("mesh: the template's splats cover only %.0f%% (front) / %.0f%% (back) of the "
                    "leaf; textures are inpainted over the mesh silhouette", 100 * cf, 100 * cb)
        front, back_reg = inpainted(front, mask, thr), inpainted(back_reg, mask, thr)
    elif cb < min_coverage:
        fallback = "back_from_front"
        log.warning("mesh: the leaf's back is covered only %.0f%%; the back texture reuses the "
                    "front", 100 * cb)
        back_reg = front.copy()
    elif cf < min_coverage:
        fallback = "front_from_back"
        log.warning("mesh: the leaf's front is covered only %.0f%%; the front texture reuses the "
                    "back", 100 * cf)
        front = back_reg.copy()
    info["texture_fallback"] = fallback
    info["alpha_coverage_front"] = float((front[..., 3] > thr).mean())
    info["alpha_coverage_back"] = float((back_reg[..., 3] > thr).mean())
    return front, back_reg[:, ::-1].copy(), info
