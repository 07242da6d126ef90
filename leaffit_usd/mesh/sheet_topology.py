"""The template sheet's topology, its checks and its repairs (template local frame): edges and
boundary loops, components, the sheet checks (one manifold disk, no folds), hole filling by ear
clipping, degenerate, non-manifold, sliver, bow-tie and notch repairs, the sample spacing. Used
by the reconstructions in :mod:`leaffit_usd.mesh.surface`."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from leaffit_usd.geometry.normals import face_normals

log = logging.getLogger("leaffit_usd")


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


SLIVER_MIN_ANGLE_DEG = 3.0   # boundary faces sharper than this are removed


MAX_FOLD_RATIO = 0.02        # projected overlap (double walls / folds) tolerated by the checks


MAX_UNUSED_FRACTION = 0.10   # samples left out of the sheet (a BPA gap at the rim, say)


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


def compact_sheet(points, faces, sample_index):
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


def drop_degenerate(points, faces):
    f = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    _, first = np.unique(np.sort(f, 1), axis=0, return_index=True)
    f = f[np.sort(first)]
    area = 0.5 * np.linalg.norm(face_normals(points, f), axis=1)
    return f[area > 1e-14 * max(np.ptp(points, 0).max(), 1e-12) ** 2]


def fix_nonmanifold_edges(points, faces):
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


def remove_boundary_slivers(points, faces, min_angle=SLIVER_MIN_ANGLE_DEG):
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


def largest_component(points, faces):
    ncomp, lab = face_components(faces, len(points))
    if ncomp <= 1:
        return faces, 0
    area = 0.5 * np.linalg.norm(face_normals(points, faces), axis=1)
    keep = int(np.argmax(np.bincount(lab, weights=area)))
    return faces[lab == keep], ncomp - 1


def fix_bowties(points, faces):
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
        faces, _ = largest_component(points, faces)
    return faces


def orient_ccw(points, faces):
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
