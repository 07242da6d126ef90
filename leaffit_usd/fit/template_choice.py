"""The automatic template leaf (``FitParams.template == "auto"``, step 3 of
:mod:`leaffit_usd.fit.register`): among the leaves that are not degenerate and whose size lies
within the middle half (25th-75th percentile) of the leaf sizes, the one with the highest
``symmetry * fill * min(1, density / median density)``: *symmetry* = min/max of the blade area
left and right of the midrib, *fill* = occupied fraction of the convex hull of the points in the
leaf plane, *density* = Gaussians per unit area. Ties go to the size closest to the median, then
the lowest label. Leaves are the registration's prepared leaves (local frame, working units)."""
from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import ConvexHull

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.params import FitParams

log = logging.getLogger("leaffit_usd")


def shape_scores(lf):
    """(symmetry, fill, density) of a leaf in its plane (see the module doc); ``lf`` has
    ``local`` (M, 3) its denoised centres in its local frame, and ``all_gaussians`` / ``sampled``."""
    xy = lf.local[:, :2]
    try:
        hull = ConvexHull(xy)
        area = float(hull.volume)
    except Exception:  # noqa: BLE001 - qhull raises on flat/degenerate input
        return 0.0, 0.0, 0.0
    if area <= 0:
        return 0.0, 0.0, 0.0
    g = 24
    lo, hi = xy.min(0), xy.max(0)
    cell = np.maximum((hi - lo) / g, 1e-12)
    ij = np.minimum(((xy - lo) / cell).astype(int), g - 1)
    occ = np.zeros((g, g), bool)
    occ[ij[:, 0], ij[:, 1]] = True
    cx = lo[0] + (np.arange(g) + 0.5) * cell[0]
    cy = lo[1] + (np.arange(g) + 0.5) * cell[1]
    X, Y = np.meshgrid(cx, cy, indexing="ij")
    eq = hull.equations
    inside = (np.stack([X.ravel(), Y.ravel()], 1) @ eq[:, :2].T + eq[:, 2] <= 1e-12).all(1)
    inside = inside.reshape(g, g)
    fill = float((occ & inside).sum() / max(inside.sum(), 1))
    cell_area = float(cell[0] * cell[1])
    left = float((occ & (Y > 0)).sum()) * cell_area
    right = float((occ & (Y < 0)).sum()) * cell_area
    sym = min(left, right) / max(left, right, 1e-300)
    # density of the whole leaf, not of its subset: with every leaf capped at leaf_gaussians
    # (a dense capture), the subset's count / area only says how small the leaf is
    n = len(xy)
    if lf.all_gaussians is not None and lf.sampled is not None and len(lf.sampled):
        n *= len(lf.all_gaussians) / len(lf.sampled)
    return sym, fill, n / area


def choose_template(leaves: list, params: FitParams) -> int:
    L = len(leaves)
    if params.template != "auto":
        lab = int(params.template)
        if not 1 <= lab <= L:
            raise ParameterError("template", f"a leaf label in 1..{L} or 'auto'", params.template)
        if leaves[lab - 1].degenerate:
            raise ParameterError("template", "a leaf that is not degenerate "
                                 f"(leaf {lab}: {leaves[lab - 1].degenerate})", params.template)
        return lab
    ok = [lf for lf in leaves if not lf.degenerate]
    if not ok:
        best = max(leaves, key=lambda lf: (len(lf.local), -lf.label))
        log.warning("fit: every leaf is degenerate; leaf %d (most Gaussians) is the template",
                    best.label)
        return best.label
    sizes = np.array([lf.size for lf in ok])
    q1, q3 = np.percentile(sizes, [25, 75])
    med = float(np.median(sizes))
    cand = [lf for lf in ok if q1 - 1e-12 <= lf.size <= q3 + 1e-12] or ok
    scores = {lf.label: shape_scores(lf) for lf in cand}
    dens_med = float(np.median([s[2] for s in scores.values()])) or 1.0
    def key(lf):
        sym, fill, dens = scores[lf.label]
        return (-(sym * fill * min(1.0, dens / dens_med)), abs(lf.size - med), lf.label)
    best = min(cand, key=key)
    log.info("fit: template leaf %d (auto: symmetry %.2f, fill %.2f, size %.3f, median %.3f)",
             best.label, scores[best.label][0], scores[best.label][1], best.size, med)
    return best.label
