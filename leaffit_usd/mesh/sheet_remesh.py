"""The template sheet re-triangulated inside a smooth outline (constrained Delaunay with
``triangle``): the outline smoothed, grown to the splats' silhouette, the interior re-sampled to the
vertex budget, heights extrapolated from the samples. Template local frame."""
from __future__ import annotations

import logging

import numpy as np


from leaffit_usd.mesh.sheet_topology import Sheet, boundary_loops, sheet_checks, signed_area_xy

log = logging.getLogger("leaffit_usd")


def _points_in_polygon(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(M,) bool: points q (M, 2) inside the closed polygon (k, 2) (even-odd rule)."""
    x, y = q[:, 0][:, None], q[:, 1][:, None]
    x0, y0 = poly[:, 0][None], poly[:, 1][None]
    x1, y1 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    cross = (y0 > y) != (y1 > y)
    xi = x0 + (y - y0) * (x1 - x0) / np.where(y1 != y0, y1 - y0, 1e-300)
    return (cross & (x < xi)).sum(1) % 2 == 1


def _segment_distance(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(M,) distance of points q (M, 2) to a closed polygon's edges."""
    a, b = poly, np.roll(poly, -1, 0)
    ab = b - a
    L2 = np.maximum((ab * ab).sum(1), 1e-300)
    best = np.full(len(q), np.inf)
    for s in range(0, len(q), 4096):
        qq = q[s:s + 4096, None, :]
        t = np.clip(((qq - a) * ab).sum(2) / L2, 0, 1)
        d = np.linalg.norm(qq - (a + t[..., None] * ab), axis=2).min(1)
        best[s:s + 4096] = d
    return best


def smooth_outline(loop_xy: np.ndarray, n_out: int, smoothing: float) -> np.ndarray:
    """(n_out, 2) closed outline resampled uniformly by arc length from a periodic cubic
    smoothing spline through ``loop_xy`` (k, 2) (scipy ``splprep``, ``per=1``).

    smoothing : the RMS distance the curve may keep from the input vertices (same units).
    """
    from scipy.interpolate import splev, splprep

    p = np.asarray(loop_xy, np.float64)
    keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-12]
    p = p[keep]
    if np.linalg.norm(p[0] - p[-1]) < 1e-12:
        p = p[:-1]
    closed = np.vstack([p, p[:1]])
    tck, _ = splprep([closed[:, 0], closed[:, 1]], s=len(p) * smoothing ** 2, per=1, k=3, quiet=2)
    u = np.linspace(0, 1, 20 * max(n_out, len(p)), endpoint=False)
    dense = np.stack(splev(u, tck), 1)
    seg = np.linalg.norm(np.diff(np.vstack([dense, dense[:1]]), axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    targets = np.linspace(0, s[-1], n_out, endpoint=False)
    closed_d = np.vstack([dense, dense[:1]])
    return np.stack([np.interp(targets, s, closed_d[:, k]) for k in range(2)], 1)


def _simple_polygon(poly: np.ndarray) -> bool:
    """True when no two non-adjacent edges of the closed polygon (k, 2) cross."""
    a, b = poly, np.roll(poly, -1, 0)
    k = len(poly)

    def orient(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    for i in range(k):
        j = np.arange(i + 2, k) if i > 0 else np.arange(2, k - 1)
        if not len(j):
            continue
        o1 = orient(a[i], b[i], a[j])
        o2 = orient(a[i], b[i], b[j])
        o3 = orient(a[j], b[j], a[i][None])
        o4 = orient(a[j], b[j], b[i][None])
        if ((o1 * o2 < 0) & (o3 * o4 < 0)).any():
            return False
    return True


def _extrapolate_z(P: np.ndarray, q: np.ndarray, k: int = 12) -> np.ndarray:
    """(M,) heights at xy points ``q`` (M, 2) off a height-field sheet (vertices P (S, 3)): the
    least-squares plane of the k vertices nearest in xy, evaluated at each point."""
    from scipy.spatial import cKDTree

    if len(q) == 0:
        return np.zeros(0)
    k = min(k, len(P))
    _, idx = cKDTree(P[:, :2]).query(q, k)
    idx = np.asarray(idx).reshape(len(q), k)
    nb = P[idx]                                            # (M, k, 3)
    c = nb.mean(1)
    A = np.concatenate([nb[:, :, :2] - c[:, None, :2], np.ones((len(q), k, 1))], 2)
    AtA = np.einsum("mki,mkj->mij", A, A) + 1e-12 * np.eye(3)[None]
    Atz = np.einsum("mki,mk->mi", A, nb[:, :, 2])
    coef = np.linalg.solve(AtA, Atz[..., None])[..., 0]     # slope x, slope y, height at c
    d = q - c[:, :2]
    return coef[:, 2] + (d * coef[:, :2]).sum(1)


def _grown_outline(outline: np.ndarray, grow, h: float, max_n: int) -> np.ndarray:
    """The smooth CCW outline (n, 2) replaced by ``grow(outline)`` (the grown region's boundary,
    a pixel staircase: :func:`leaffit_usd.mesh.outline_fit.silhouette_outline`) smoothed by a
    spline to within a pixel (RMS) and resampled every ``h`` (at most ``max_n`` vertices); the outline itself when the grown
    one is empty or not a simple CCW polygon."""
    region = np.asarray(grow(outline), np.float64).reshape(-1, 2)
    if len(region) < 8:
        return outline
    px = float(np.median(np.linalg.norm(region - np.roll(region, -1, 0), axis=1)))
    try:
        dense = smooth_outline(region, len(region), px)
        perim = float(np.linalg.norm(dense - np.roll(dense, -1, 0), axis=1).sum())
        grown = smooth_outline(dense, min(max(int(round(perim / h)), 8), max(max_n, 8)), 1e-6 * px)
    except (ValueError, TypeError):
        return outline
    if signed_area_xy(grown) <= 0 or not _simple_polygon(grown):
        return outline
    return grown


def remesh_sheet(points: np.ndarray, faces: np.ndarray, n_vertices: int,
                 outline_smoothing: float = 0.35, grow=None) -> Sheet | None:
    """A clean re-triangulation of a height-field sheet with about ``n_vertices`` vertices.

    The outer boundary of the sheet (points (S, 3), faces (G, 3), template frame, a height field
    over xy) becomes a smooth closed curve (:func:`smooth_outline`, allowed to stay
    ``outline_smoothing`` x the new vertex spacing from the old rim vertices), resampled at that
    spacing; interior vertices are a farthest-point subset of the sheet's vertices at least half
    a spacing inside it; the constrained Delaunay triangulation of both (``triangle``, the
    outline as segments, no extra vertices) is lifted onto the old sheet (linear
    interpolation of z over xy; outside the old sheet, the plane of its nearest vertices).
    Returns None when the sheet is not a height field or the result is not a clean disk (the
    caller keeps the old sheet).

    grow : optional ``grow(outline (n, 2)) -> (m, 2)``: the boundary of a region grown out
        from the smooth outline (out to the splats' silhouette,
        :func:`leaffit_usd.mesh.outline_fit.silhouette_outline`), which becomes the outline
        (smoothed to within a pixel, resampled every spacing); ignored when it is not a simple
        polygon.
    """
    import triangle as tr
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    from leaffit_usd.geometry.sampling import farthest_point_sampling

    P = np.asarray(points, np.float64)
    F = np.asarray(faces, np.int64)
    if len(F) < 2 or n_vertices < 8:
        return None
    checks = sheet_checks(P, F)
    if not checks["is_disk"]:
        return None
    loops = boundary_loops(F, len(P))
    outer = max(loops, key=lambda lp: abs(signed_area_xy(P[lp])))
    ring = P[outer, :2]
    if signed_area_xy(ring) < 0:
        ring = ring[::-1]
    area = abs(signed_area_xy(ring))
    perim = float(np.linalg.norm(ring - np.roll(ring, -1, 0), axis=1).sum())
    # triangular lattice: sqrt(3)/2 h^2 per vertex; boundary vertices every h
    h = float(np.sqrt(area / (0.866 * n_vertices)))
    for _ in range(3):  # the boundary takes a share of the budget: refine h once or twice
        n_b = max(int(round(perim / h)), 8)
        n_in = max(n_vertices - n_b, 0)
        h = float(np.sqrt(area / (0.866 * max(n_in + 0.5 * n_b, 1))))
    n_b = max(int(round(perim / h)), 8)
    try:
        outline = smooth_outline(ring, n_b, outline_smoothing * h)
    except (ValueError, TypeError):
        return None
    if signed_area_xy(outline) < 0:
        outline = outline[::-1]
    if not _simple_polygon(outline):
        return None
    if grow is not None:
        outline = _grown_outline(outline, grow, h, n_vertices)
        n_b = len(outline)
    inside = _points_in_polygon(P[:, :2], outline) & (_segment_distance(P[:, :2], outline) > 0.5 * h)
    cand = np.flatnonzero(inside)
    n_in = max(n_vertices - n_b, 0)
    if n_in == 0:        # the outline took the whole budget (a long, ragged rim)
        cand = cand[:0]
    elif len(cand) > n_in:
        cand = cand[farthest_point_sampling(P[cand], n_in)]
    V2 = np.vstack([outline, P[cand, :2]])
    seg = np.stack([np.arange(n_b), (np.arange(n_b) + 1) % n_b], 1)
    try:
        out = tr.triangulate({"vertices": V2, "segments": seg}, "pQ")
    except Exception:  # noqa: BLE001 - a degenerate outline must not stop the pipeline
        return None
    if "triangles" not in out or len(out["vertices"]) != len(V2):
        return None
    T = np.asarray(out["triangles"], np.int64)
    lin = LinearNDInterpolator(P[:, :2], P[:, 2])
    z = lin(V2)
    off = ~_points_in_polygon(V2, ring)
    z[off] = _extrapolate_z(P, V2[off])
    bad = ~np.isfinite(z)
    if bad.any():
        z[bad] = NearestNDInterpolator(P[:, :2], P[:, 2])(V2[bad])
    V = np.column_stack([V2, z])
    a, b, c = V2[T[:, 0]], V2[T[:, 1]], V2[T[:, 2]]
    cw = ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) < 0
    T[cw] = T[cw][:, ::-1]
    sheet = Sheet(V, T, np.full(len(V), -1, np.int64),
                  dict(method="outline", spacing=h, boundary_vertices=int(n_b), holes_before=0, holes_after=0))
    if not sheet_checks(V, T)["is_disk"]:
        return None
    return sheet
