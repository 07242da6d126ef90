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
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from leaffit_usd.geometry.normals import face_normals

log = logging.getLogger("leaffit_usd")

SLIVER_MIN_ANGLE_DEG = 3.0   # boundary faces sharper than this are removed
MAX_FOLD_RATIO = 0.02        # projected overlap (double walls / folds) tolerated by the checks
MAX_UNUSED_FRACTION = 0.10   # samples left out of the sheet (a BPA gap at the rim, say)


@dataclass
class Sheet:
    """A single-sheet triangle mesh, template local frame.

    points : (S, 3) float64 ; faces : (G, 3) int64, counter-clockwise seen from +Z
    sample_index : (S,) int64, row of each vertex in the sampled point array
    info : figures of the reconstruction (holes before/after, removed faces, method ...)
    """

    points: np.ndarray
    faces: np.ndarray
    sample_index: np.ndarray
    info: dict = field(default_factory=dict)


# ---- topology helpers ---------------------------------------------------------------------------
def _edge_keys(faces: np.ndarray, n: int):
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    lo, hi = he.min(1), he.max(1)
    return he, lo * n + hi


def edge_face_counts(faces: np.ndarray, n: int):
    """(half_edges (3G, 2), count of faces on each half-edge's undirected edge (3G,))."""
    he, key = _edge_keys(faces, n)
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    return he, cnt[inv]


def boundary_loops(faces: np.ndarray, n: int) -> list[np.ndarray]:
    """Closed loops of boundary half-edges, each a (k,) vertex array following face winding.

    For a CCW sheet the outer loop runs counter-clockwise and holes clockwise (seen from +Z).
    Vertices with several outgoing boundary half-edges (bow-ties) are followed greedily.
    """
    if len(faces) == 0:
        return []
    he, cnt = edge_face_counts(faces, n)
    b = he[cnt == 1]
    nxt: dict[int, list[int]] = {}
    for a, c in b.tolist():
        nxt.setdefault(a, []).append(c)
    loops = []
    used = set()
    for a0, c0 in b.tolist():
        if (a0, c0) in used:
            continue
        loop = [a0]
        a, c = a0, c0
        while True:
            used.add((a, c))
            if c == a0:
                break
            loop.append(c)
            cand = [w for w in nxt.get(c, []) if (c, w) not in used]
            if not cand:
                break
            a, c = c, cand[0]
        loops.append(np.asarray(loop, np.int64))
    return loops


def face_components(faces: np.ndarray, n: int) -> tuple[int, np.ndarray]:
    """Connected components of faces sharing an edge: (count, label per face)."""
    G = len(faces)
    if G == 0:
        return 0, np.zeros(0, np.int64)
    _, key = _edge_keys(faces, n)
    fid = np.repeat(np.arange(G), 3)
    order = np.argsort(key, kind="stable")
    k, f = key[order], fid[order]
    same = k[1:] == k[:-1]
    a, b = f[:-1][same], f[1:][same]
    adj = coo_matrix((np.ones(len(a)), (a, b)), shape=(G, G))
    return connected_components(adj, directed=False)


def signed_area_xy(poly: np.ndarray) -> float:
    """Signed area of a closed polygon (k, 2+) in the xy plane (CCW positive)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def tri_min_angle(p: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(G,) smallest interior angle of each face, degrees."""
    a, b, c = p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]]
    la, lb, lc = (np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1),
                  np.linalg.norm(a - b, axis=1))
    eps = 1e-30

    def ang(opp, s1, s2):
        return np.degrees(np.arccos(np.clip((s1 ** 2 + s2 ** 2 - opp ** 2) / (2 * s1 * s2 + eps), -1, 1)))

    return np.minimum(np.minimum(ang(la, lb, lc), ang(lb, lc, la)), ang(lc, la, lb))


def nonmanifold_vertices(faces: np.ndarray, n: int) -> np.ndarray:
    """Vertices with more than one outgoing boundary half-edge (bow-ties), (k,) int64."""
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    he, cnt = edge_face_counts(faces, n)
    out = np.bincount(he[cnt == 1][:, 0], minlength=n)
    return np.flatnonzero(out > 1)


def sheet_checks(points: np.ndarray, faces: np.ndarray) -> dict:
    """Topology figures of a sheet: components, non-manifold edges/vertices, boundary loops,
    Euler characteristic, fold ratio (projected overlap / projected area) and ``is_disk``."""
    n = len(points)
    if len(faces) == 0:
        return dict(components=0, nonmanifold_edges=0, nonmanifold_vertices=0, boundary_loops=0,
                    euler=0, fold_ratio=0.0, is_disk=False)
    he, cnt = edge_face_counts(faces, n)
    _, key = _edge_keys(faces, n)
    n_edges = len(np.unique(key))
    used = np.unique(faces)
    euler = len(used) - n_edges + len(faces)
    ncomp, _ = face_components(faces, n)
    loops = boundary_loops(faces, n)
    nm_e = int(len(np.unique(key[cnt > 2])))
    nm_v = int(len(nonmanifold_vertices(faces, n)))
    # directed half-edge used twice = inconsistent winding
    hk = he[:, 0] * n + he[:, 1]
    bad_winding = int(len(hk) - len(np.unique(hk)))
    fold = fold_ratio(points, faces, loops)
    is_disk = (ncomp == 1 and nm_e == 0 and nm_v == 0 and len(loops) == 1 and euler == 1
               and bad_winding == 0 and fold <= MAX_FOLD_RATIO)
    return dict(components=int(ncomp), nonmanifold_edges=nm_e, nonmanifold_vertices=nm_v,
                boundary_loops=len(loops), euler=int(euler), inconsistent_winding=bad_winding,
                fold_ratio=float(fold), is_disk=bool(is_disk))


def fold_ratio(points, faces, loops=None) -> float:
    """Projected overlap of a sheet in the xy plane, relative to its silhouette area.

    ``(sum_f |A_xy(f)| - |A_xy(outer loop)|) / |A_xy(outer loop)|``: 0 for a height field
    without holes; positive where the sheet folds over itself or doubles up (double walls).
    """
    if len(faces) == 0:
        return 0.0
    if loops is None:
        loops = boundary_loops(faces, len(points))
    if not loops:
        return 1.0  # closed surface: all of it overlaps
    areas = [abs(signed_area_xy(points[lp])) for lp in loops]
    outer = max(areas)
    holes = sum(areas) - outer
    tri = 0.5 * np.abs(face_normals(points, faces)[:, 2]).sum()
    return float(max(tri - (outer - holes), 0.0) / max(outer, 1e-30))


def _compact(points, faces, sample_index):
    used = np.unique(faces)
    remap = np.full(len(points), -1, np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[faces], sample_index[used]


# ---- hole filling -------------------------------------------------------------------------------
def _ear_clip(p2: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangulate a simple polygon (k, 2) (either orientation); returns CCW-consistent index
    triples in the polygon's own orientation. Best-shaped ear first; never fails (forces an
    ear when the polygon is not simple in projection)."""
    k = len(p2)
    sgn = 1.0 if signed_area_xy(p2) >= 0 else -1.0
    verts = list(range(k))
    tris = []
    while len(verts) > 3:
        m = len(verts)
        P = p2[verts]
        prv, nxt = np.roll(P, 1, 0), np.roll(P, -1, 0)
        e1, e2 = P - prv, nxt - P
        cross = sgn * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        best, best_q = None, -np.inf
        for i in np.flatnonzero(cross > 0):
            a, b, c = prv[i], P[i], nxt[i]
            # any other polygon vertex inside (a, b, c)?
            mask = np.ones(m, bool)
            mask[[(i - 1) % m, i, (i + 1) % m]] = False
            Q = P[mask]
            if len(Q):
                def side(u, v):
                    return sgn * ((v[0] - u[0]) * (Q[:, 1] - u[1]) - (v[1] - u[1]) * (Q[:, 0] - u[0]))
                inside = (side(a, b) > 0) & (side(b, c) > 0) & (side(c, a) > 0)
                if inside.any():
                    continue
            la, lb, lc = np.linalg.norm(b - c), np.linalg.norm(c - a), np.linalg.norm(a - b)
            q = cross[i] / max(la * la + lb * lb + lc * lc, 1e-30)  # ~ shape quality
            if q > best_q:
                best, best_q = i, q
        if best is None:  # not simple in projection: clip the most convex corner anyway
            best = int(np.argmax(cross))
        tris.append((verts[(best - 1) % m], verts[best], verts[(best + 1) % m]))
        del verts[best]
    tris.append(tuple(verts))
    return tris


def fill_holes(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Fill every boundary loop but the outer one (largest projected area); no new vertices.

    Returns (faces, holes_before, holes_after).
    """
    loops = boundary_loops(faces, len(points))
    if len(loops) <= 1:
        return faces, 0, 0
    areas = [abs(signed_area_xy(points[lp])) for lp in loops]
    outer = int(np.argmax(areas))
    new = []
    for li, lp in enumerate(loops):
        if li == outer or len(lp) < 3:
            continue
        # the hole's boundary half-edges run clockwise: fill the reversed (CCW) polygon
        poly = lp[::-1]
        for a, b, c in _ear_clip(points[poly, :2]):
            new.append((poly[a], poly[b], poly[c]))
    if new:
        faces = np.concatenate([faces, np.asarray(new, np.int64)])
    after = len(boundary_loops(faces, len(points))) - 1
    return faces, len(loops) - 1, max(after, 0)


# ---- repair steps ---------------------------------------------------------------------------------
def _drop_degenerate(points, faces):
    f = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    _, first = np.unique(np.sort(f, 1), axis=0, return_index=True)
    f = f[np.sort(first)]
    area = 0.5 * np.linalg.norm(face_normals(points, f), axis=1)
    return f[area > 1e-14 * max(np.ptp(points, 0).max(), 1e-12) ** 2]


def _fix_nonmanifold_edges(points, faces):
    """While an edge has > 2 faces, remove the worst-shaped face on it."""
    n = len(points)
    for _ in range(50):
        he, key = _edge_keys(faces, n)
        uk, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        bad = cnt[inv] > 2
        if not bad.any():
            break
        fid = np.repeat(np.arange(len(faces)), 3)[bad]
        ek = inv[bad]
        q = tri_min_angle(points, faces)[fid]
        # per bad edge, the face with the smallest min-angle
        order = np.lexsort((q, ek))
        first = np.r_[True, ek[order][1:] != ek[order][:-1]]
        drop = np.unique(fid[order][first])
        faces = np.delete(faces, drop, axis=0)
    return faces


def _remove_boundary_slivers(points, faces, min_angle=SLIVER_MIN_ANGLE_DEG):
    n = len(points)
    removed = 0
    for _ in range(5):
        he, cnt = edge_face_counts(faces, n)
        on_boundary = (cnt.reshape(-1, 3) == 1).any(1)
        sliver = on_boundary & (tri_min_angle(points, faces) < min_angle)
        if not sliver.any():
            break
        removed += int(sliver.sum())
        faces = faces[~sliver]
    return faces, removed


def _largest_component(points, faces):
    ncomp, lab = face_components(faces, len(points))
    if ncomp <= 1:
        return faces, 0
    area = 0.5 * np.linalg.norm(face_normals(points, faces), axis=1)
    keep = int(np.argmax(np.bincount(lab, weights=area)))
    return faces[lab == keep], ncomp - 1


def _fix_bowties(points, faces):
    """At every vertex with several face fans, keep the fan with the largest area."""
    n = len(points)
    for _ in range(20):
        bad = nonmanifold_vertices(faces, n)
        if len(bad) == 0:
            break
        drop = []
        for v in bad.tolist():
            fi = np.flatnonzero((faces == v).any(1))
            sub = faces[fi]
            # fans: faces around v connected through edges that contain v
            adj_pairs = []
            for i in range(len(fi)):
                for j in range(i + 1, len(fi)):
                    shared = set(sub[i].tolist()) & set(sub[j].tolist())
                    if v in shared and len(shared) == 2:
                        adj_pairs.append((i, j))
            m = len(fi)
            if adj_pairs:
                a, b = np.asarray(adj_pairs).T
                _, lab = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m)),
                                              directed=False)
            else:
                lab = np.arange(m)
            area = 0.5 * np.linalg.norm(face_normals(points, sub), axis=1)
            keep = int(np.argmax(np.bincount(lab, weights=area)))
            drop.extend(fi[lab != keep].tolist())
        if not drop:
            break
        faces = np.delete(faces, np.unique(np.asarray(drop, np.int64)), axis=0)
        faces, _ = _largest_component(points, faces)
    return faces


def _orient_ccw(points, faces):
    """Consistent winding (trimesh), then flipped so the projected area is positive (+Z side)."""
    import trimesh

    if len(faces) == 0:
        return faces
    tm = trimesh.Trimesh(points, faces, process=False, validate=False)
    trimesh.repair.fix_winding(tm)
    f = np.asarray(tm.faces, np.int64)
    if face_normals(points, f)[:, 2].sum() < 0:
        f = f[:, ::-1]
    return np.ascontiguousarray(f)


def fill_notches(points, faces, max_gap: float, max_angle_deg: float = 60.0, iterations: int = 4):
    """Close sharp notches of the outer boundary (an ear added across a reflex rim vertex).

    A rim vertex ``v`` between ``a`` and ``b`` whose rim edges enclose less than
    ``max_angle_deg`` outside the sheet, with ``|a - b| <= max_gap`` and no vertex inside
    (a, v, b), gets the face (v, a, b). No new vertices; the sheet stays a disk. Returns
    (faces, count added).
    """
    n = len(points)
    added = 0
    for _ in range(iterations):
        loops = boundary_loops(faces, n)
        if not loops:
            break
        lp = max(loops, key=lambda l: abs(signed_area_xy(points[l])))
        if len(lp) < 5:
            break
        he, _ = edge_face_counts(faces, n)
        existing = set(map(tuple, np.sort(he, 1).tolist()))
        P = points[:, :2]
        a, v, b = np.roll(lp, 1), lp, np.roll(lp, -1)
        e1, e2 = P[a] - P[v], P[b] - P[v]
        turn = (P[v] - P[a])[:, 0] * (P[b] - P[v])[:, 1] - (P[v] - P[a])[:, 1] * (P[b] - P[v])[:, 0]
        cosang = (e1 * e2).sum(1) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-30)
        ang = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
        gap = np.linalg.norm(points[a] - points[b], axis=1)
        cand = np.flatnonzero((turn < 0) & (ang < max_angle_deg) & (gap <= max_gap))
        new, used = [], set()
        tree = cKDTree(P)
        for i in cand[np.argsort(ang[cand])]:
            ai, vi, bi = int(a[i]), int(v[i]), int(b[i])
            if used & {ai, vi, bi} or (min(ai, bi), max(ai, bi)) in existing:
                continue
            tri = P[[vi, ai, bi]]
            c = tri.mean(0)
            near = tree.query_ball_point(c, float(np.linalg.norm(tri - c, axis=1).max()) + 1e-12)
            inside = False
            for q in near:
                if q in (ai, vi, bi):
                    continue
                x = P[q]
                s1 = (tri[1, 0] - tri[0, 0]) * (x[1] - tri[0, 1]) - (tri[1, 1] - tri[0, 1]) * (x[0] - tri[0, 0])
                s2 = (tri[2, 0] - tri[1, 0]) * (x[1] - tri[1, 1]) - (tri[2, 1] - tri[1, 1]) * (x[0] - tri[1, 0])
                s3 = (tri[0, 0] - tri[2, 0]) * (x[1] - tri[2, 1]) - (tri[0, 1] - tri[2, 1]) * (x[0] - tri[2, 0])
                if (s1 > 0 and s2 > 0 and s3 > 0) or (s1 < 0 and s2 < 0 and s3 < 0):
                    inside = True
                    break
            if inside:
                continue
            new.append((vi, ai, bi))
            used |= {ai, vi, bi}
        if not new:
            break
        faces = np.concatenate([faces, np.asarray(new, np.int64)])
        added += len(new)
    return faces, added


# ---- reconstructions ----------------------------------------------------------------------------
def sample_spacing(points: np.ndarray) -> float:
    """Median distance from each point to its nearest neighbour."""
    if len(points) < 2:
        return 1.0
    d, _ = cKDTree(points).query(points, k=2)
    s = float(np.median(d[:, 1]))
    return s if s > 0 else float(np.ptp(points, 0).max() / max(np.sqrt(len(points)), 1.0) or 1.0)


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
    faces = _drop_degenerate(pts, faces)
    # folds: a face whose normal opposes its vertices' normals
    if len(faces):
        fn = face_normals(pts, faces)
        vn = nrm[faces].sum(1)
        keep = (fn * vn).sum(1) > 0
        info["folded_faces_removed"] = int((~keep).sum())
        faces = faces[keep]
    faces = _fix_nonmanifold_edges(pts, faces)
    faces, info["slivers_removed"] = _remove_boundary_slivers(pts, faces)
    faces, info["islands_removed"] = _largest_component(pts, faces)
    faces = _fix_bowties(pts, faces)
    faces = _orient_ccw(pts, faces)
    faces, info["holes_before"], info["holes_after"] = fill_holes(pts, faces)
    faces, info["notches_filled"] = fill_notches(pts, faces, 4.0 * spacing)
    faces = _fix_nonmanifold_edges(pts, faces)
    faces = _fix_bowties(pts, faces)
    faces = _orient_ccw(pts, faces)
    idx = np.arange(len(pts), dtype=np.int64)
    if len(faces) == 0:
        return Sheet(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), info)
    p, f, si = _compact(pts, faces, idx)
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
    faces, info["slivers_removed"] = _remove_boundary_slivers(pts, faces)
    faces, info["islands_removed"] = _largest_component(pts, faces)
    faces = _fix_bowties(pts, faces)
    faces, _, info["holes_after"] = fill_holes(pts, faces)  # slivers/bow-ties can open some
    faces, info["notches_filled"] = fill_notches(pts, faces, 2.0 * alpha * spacing)
    if len(faces) == 0:
        return Sheet(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), info)
    p, f, si = _compact(pts, faces, idx)
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
