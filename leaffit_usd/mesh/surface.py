"""Template leaf surface: FPS + ball pivoting + repair, with a planar (2D Delaunay) fallback.

All points are in the **template local frame** (origin at the petiole base, +X base -> apex,
+Z the leaf normal), so a leaf is close to a height field z(x, y). Two reconstructions:

* ``"bpa"`` (the paper's): open3d's ball pivoting on the FPS samples with radii from their
  spacing, then repair: degenerate/duplicate faces, folded faces (normal against the point
  normals), non-manifold edges (keep the two best-shaped faces), boundary slivers, islands (keep
  the largest component), non-manifold vertices (keep the largest fan), and hole filling: every
  boundary loop but the outer one is triangulated without new vertices (ear clipping in the
  leaf plane, best-shaped ear first — Liepa's first stage with a greedy instead of a DP
  minimum; no refinement, so the vertex budget holds).
* ``"planar"``: 2D Delaunay of the samples' (x, y), restricted to an alpha shape (circumradius
  <= ``alpha`` x spacing), largest component, interior holes put back (the removed Delaunay
  triangles not connected to the convex hull), bow-ties removed, lifted by the points' z. A
  height field by construction: it cannot make double walls. Used when BPA's result fails the
  sheet checks (``method="auto"``) — on a strongly curled leaf the planar fallback would fold,
  which the checks report (``fold_ratio``).

Both return a :class:`Sheet`; :func:`sheet_checks` says whether it is one connected manifold open
sheet with disk topology (one boundary loop, Euler characteristic 1) and no folds.
"""
from __future__ import annotations

import logging

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from leaffit_usd.geometry.normals import face_normals
from leaffit_usd.mesh.sheet_remesh import remesh_sheet, smooth_outline  # noqa: F401 (API)
from leaffit_usd.mesh.sheet_topology import (Sheet, boundary_loops, compact_sheet,  # noqa: F401 (API)
                                            drop_degenerate, fill_holes, fill_notches, fix_bowties,
                                            fix_nonmanifold_edges, fold_ratio, largest_component,
                                            orient_ccw, remove_boundary_slivers, sample_spacing,
                                            sheet_checks, signed_area_xy, tri_min_angle)

log = logging.getLogger("leaffit_usd")


# ---- topology helpers ---------------------------------------------------------------------------


def bpa_sheet(points: np.ndarray, radii=(2.0, 3.0, 4.0)) -> Sheet:
    """Ball pivoting (open3d) + repair. points : (S, 3) float, template local frame.

    radii : ball radii as multiples of the samples' median nearest-neighbour spacing.
    """
    import open3d as o3d

    pts = np.asarray(points, np.float64)
    spacing = sample_spacing(pts)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(min(16, len(pts) - 1)))
    nrm = np.asarray(pcd.normals)
    nrm[nrm[:, 2] < 0] *= -1.0  # +Z is the leaf normal in the template frame
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector([float(r) * spacing for r in radii]))
    faces = np.asarray(mesh.triangles, np.int64).reshape(-1, 3)
    # open3d keeps the input vertex order for BPA (mesh.vertices == pcd.points)
    mv = np.asarray(mesh.vertices)
    if len(mv) != len(pts) or not np.allclose(mv, pts):
        _, remap = cKDTree(pts).query(mv)
        faces = remap[faces]
    info = dict(method="bpa", spacing=spacing, bpa_faces=int(len(faces)))
    faces = drop_degenerate(pts, faces)
    # folds: a face whose normal opposes its vertices' normals
    if len(faces):
        fn = face_normals(pts, faces)
        vn = nrm[faces].sum(1)
        keep = (fn * vn).sum(1) > 0
        info["folded_faces_removed"] = int((~keep).sum())
        faces = faces[keep]
    faces = fix_nonmanifold_edges(pts, faces)
    faces, info["slivers_removed"] = remove_boundary_slivers(pts, faces)
    faces, info["islands_removed"] = largest_component(pts, faces)
    faces = fix_bowties(pts, faces)
    faces = orient_ccw(pts, faces)
    faces, info["holes_before"], info["holes_after"] = fill_holes(pts, faces)
    faces, info["notches_filled"] = fill_notches(pts, faces, 4.0 * spacing)
    faces = fix_nonmanifold_edges(pts, faces)
    faces = fix_bowties(pts, faces)
    faces = orient_ccw(pts, faces)
    idx = np.arange(len(pts), dtype=np.int64)
    if len(faces) == 0:
        return Sheet(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), info)
    p, f, si = compact_sheet(pts, faces, idx)
    info["unused_samples"] = int(len(pts) - len(p))
    return Sheet(p, f, si, info)


def _circumradius_2d(p2: np.ndarray, tri: np.ndarray) -> np.ndarray:
    a, b, c = p2[tri[:, 0]], p2[tri[:, 1]], p2[tri[:, 2]]
    la, lb, lc = (np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1),
                  np.linalg.norm(a - b, axis=1))
    area2 = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    return la * lb * lc / np.maximum(2 * area2, 1e-300)


def planar_sheet(points: np.ndarray, alpha: float = 2.5) -> Sheet:
    """2D Delaunay in the leaf plane restricted to an alpha shape, lifted by z.

    points : (S, 3) float, template local frame. alpha : maximum circumradius as a multiple of
    the samples' median nearest-neighbour spacing.
    """
    pts = np.asarray(points, np.float64)
    spacing = sample_spacing(pts)
    info = dict(method="planar", spacing=spacing)
    idx = np.arange(len(pts), dtype=np.int64)
    p2 = pts[:, :2]
    try:
        dl = Delaunay(p2)
    except Exception as exc:  # collinear or too few points: no planar triangulation exists
        log.warning("mesh: planar triangulation impossible (%s)", exc)
        return Sheet(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), info)
    tri = dl.simplices.astype(np.int64)
    # scipy keeps coplanar/duplicate points out of the triangulation; they are simply unused
    keep = _circumradius_2d(p2, tri) <= alpha * spacing
    # removed triangles not connected (through removed triangles) to the convex hull are
    # interior holes: put them back
    nb = dl.neighbors  # -1 = hull side
    removed = np.flatnonzero(~keep)
    if len(removed):
        rid = np.full(len(tri), -1, np.int64)
        rid[removed] = np.arange(len(removed))
        a, b = [], []
        for k in range(3):
            other = nb[removed, k]
            ok = (other >= 0) & (~keep[np.maximum(other, 0)])
            a.append(rid[removed[ok]])
            b.append(rid[other[ok]])
        a, b = np.concatenate(a), np.concatenate(b)
        R = len(removed)
        _, lab = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(R, R)), directed=False)
        touches_hull = np.zeros(lab.max() + 1 if R else 0, bool)
        on_hull = (nb[removed] < 0).any(1)
        touches_hull[lab[on_hull]] = True
        interior = removed[~touches_hull[lab]]
        info["holes_before"] = int(len(np.unique(lab[~touches_hull[lab]])))
        keep[interior] = True
    else:
        info["holes_before"] = 0
    faces = tri[keep]
    # Delaunay simplices may be either orientation: make them CCW in xy
    a, b, c = p2[faces[:, 0]], p2[faces[:, 1]], p2[faces[:, 2]]
    cw = ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) < 0
    faces[cw] = faces[cw][:, ::-1]
    faces, info["slivers_removed"] = remove_boundary_slivers(pts, faces)
    faces, info["islands_removed"] = largest_component(pts, faces)
    faces = fix_bowties(pts, faces)
    faces, _, info["holes_after"] = fill_holes(pts, faces)  # slivers/bow-ties can open some
    faces, info["notches_filled"] = fill_notches(pts, faces, 2.0 * alpha * spacing)
    if len(faces) == 0:
        return Sheet(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), info)
    p, f, si = compact_sheet(pts, faces, idx)
    info["unused_samples"] = int(len(pts) - len(p))
    return Sheet(p, f, si, info)


def fallback_quad(points: np.ndarray) -> Sheet:
    """Two triangles spanning the points' xy bounding box at their mean z (last resort)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0 or not np.isfinite(pts).all():
        lo, hi, z = np.array([0.0, -0.25]), np.array([1.0, 0.25]), 0.0
    else:
        lo, hi, z = pts[:, :2].min(0), pts[:, :2].max(0), float(pts[:, 2].mean())
        ext = max(float((hi - lo).max()), 1e-3)
        hi = np.maximum(hi, lo + 0.05 * ext)
    p = np.array([[lo[0], lo[1], z], [hi[0], lo[1], z], [hi[0], hi[1], z], [lo[0], hi[1], z]])
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return Sheet(p, f, np.full(4, -1, np.int64), dict(method="quad", holes_before=0, holes_after=0))


# ---- clean outline + constrained triangulation ------------------------------------------------------
