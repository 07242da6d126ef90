"""Heat-method geodesic distances on a point cloud (Crane, Weischedel, Wardetzky 2017).

Why not potpourri3d's ``PointCloudHeatSolver`` directly: it factors its Laplacian well, but it
exposes neither the factorisation nor a multi-right-hand-side solve, so each distance costs a
separate call (20-150 ms); the segmenter needs one distance per apex (tens of them) and the
solver on 100k points alone costs ~5 s to build. So this module keeps geometry-central's local
Delaunay triangulation of the cloud (``potpourri3d.PointCloudLocalTriangulation``, the first half
of geometry-central's point-cloud Laplacian) and runs the heat method on the resulting triangle
soup itself, with scipy's sparse LU factored once and reused for any number of right-hand sides:

* elements: the union of all local triangles (deduplicated), minus near-degenerate slivers; where
  a region is too thin to triangulate (a petiole a few samples wide, a 1-D chain), kNN edges are
  added as 1-D elements, so thin stems stay connected and get arc length right;
* optional orientation awareness: with per-point normals (a Gaussian's smallest-scale axis),
  triangles whose normal disagrees with a vertex normal and edges that leave a vertex's tangent
  plane are dropped, so a leaf lying just above another is not short-cut through;
* per element a constant gradient (matrix ``G``), measure ``a`` (area, or length x spacing); the
  Laplacian is ``L = G^T diag(a) G`` (for triangles exactly the cotan Laplacian) and the mass is
  lumped. Heat: ``(M + t L) u = delta`` with ``t = t_coef * h^2`` (h = mean element edge length);
  ``X = -grad u / |grad u|``; Poisson: ``L phi = G^T a X`` (the least-squares integral of X);
  shift so the sources are at 0.

Large clouds: ``domain=`` builds the operator on a subsample (int: a voxel subsample of about that
many points; or explicit indices) and transfers distances to every point by inverse-distance
interpolation over the 4 nearest domain points of the same connected component. Points in a
component that holds no source get ``inf``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.knn import interpolation_matrix, knn

log = logging.getLogger("leaffit_usd")

SLIVER = 0.02        # drop a triangle if area < SLIVER * (longest edge)^2 (min angle ~2 degrees)
LONG_EDGE = 1.5      # drop elements longer than 1.5 x the 8th-neighbour distance of their vertices (~2.5 spacings)
ORIENT_COS = 0.8     # orientation test: |n_tri . n_vertex| >= 0.8 (37 deg)
EDGE_SIN = 0.4     # |e . n_vertex| <= 0.4: an edge leaves a tangent plane by < 24 deg


def _principal_coordinates(points: np.ndarray) -> np.ndarray:
    """(N, 3) float64: ``points`` (N, 3) in their own principal frame (centroid origin, axes by
    decreasing variance, each axis signed so the third moment along it is >= 0). Rotating or
    translating the points leaves the result unchanged up to rounding."""
    c = points - points.mean(0)
    _, vec = np.linalg.eigh(c.T @ c)
    local = c @ vec[:, ::-1]
    return local * np.where((local ** 3).sum(0) < 0, -1.0, 1.0)


def voxel_subsample(points: np.ndarray, target: int) -> np.ndarray:
    """(M,) int64 sorted indices, one point per occupied voxel, M about ``target`` (<= N).

    points : (N, 3) float. The voxel size is adapted (surface-like scaling) in a few steps. The
    grid is aligned with the points' principal axes (:func:`_principal_coordinates`), so a rotated
    copy of the points gives the same subset: the segmentation does not move with a few degrees
    of error in the estimated up axis (it did by 2-5 mIoU with a grid aligned to the frame). The
    kept point of a voxel is the one nearest the voxel's centre, so the subsample does not
    depend on the order of the points either (up to exact duplicates): the same
    Gaussians in another file order give the same subset. (Keeping the first point of each voxel made the
    blades segmentation move by up to 7 mIoU with the file order of one capture.)
    """
    points = np.asarray(points, np.float64)
    n = len(points)
    if target >= n:
        return np.arange(n, dtype=np.int64)
    local = _principal_coordinates(points)
    lo = local.min(0)
    ext = np.ptp(local, 0).max() or 1.0
    size = ext / np.sqrt(target)
    for _ in range(8):
        keys = np.floor((local - lo) / size).astype(np.int64)
        dims = keys.max(0) + 1  # one int64 key per voxel: a 1-D sort is ~10x faster than rows
        flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
        srt = np.sort(flat)
        ratio = (1 + np.count_nonzero(srt[1:] != srt[:-1])) / target
        if 0.9 <= ratio <= 1.15:
            break
        size *= ratio ** 0.5
    # the point nearest its voxel's centre (a centroid would tie exactly in every 2-point voxel,
    # and rounding would then break the tie differently in a rotated copy); distinct points tie
    # only by accident, exact duplicates are the same position whichever is kept
    d2 = ((local - (lo + (keys + 0.5) * size)) ** 2).sum(1)
    order = np.lexsort((d2, flat))  # by voxel, then distance
    first = np.flatnonzero(np.r_[True, flat[order][1:] != flat[order][:-1]])
    return np.sort(order[first]).astype(np.int64)


class GeodesicSolver:
    """Heat-method geodesic distance on a point cloud; build once, then solve for many sources.

    points : (N, 3) float, any frame (distances are in its units).
    normals : optional (N, 3) float unit normals (NaN rows = unknown, e.g. a stem Gaussian whose
        smallest axis is ill-defined); enables the orientation-aware elements described above.
    domain : None (operator on all points), int (voxel subsample of about that many points) or
        (M,) int indices of the points to build the operator on.
    t_coef : heat time as a multiple of h^2 (geometry-central's default 1).
    bridge_gap : if given, pieces of at least ``bridge_min`` domain points that are cut off from
        the largest piece by a gap narrower than this (in the points' units) are joined to it by
        one 1-D element across the gap (a petiole that stops short of its blade); smaller or
        farther pieces stay apart (floaters).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray | None = None, *, domain=None,
                 t_coef: float = 1.0, bridge_gap: float | None = None, bridge_min: int = 20):
        pts = np.asarray(points, np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ParameterError("points", "a non-empty (N, 3) array", getattr(pts, "shape", pts))
        if not np.isfinite(pts).all():
            raise ParameterError("points", "finite coordinates", "NaN or inf values")
        if normals is not None:
            normals = np.asarray(normals, np.float64)
            if normals.shape != pts.shape:
                raise ParameterError("normals", f"shape {pts.shape}", normals.shape)
        if not t_coef > 0:
            raise ParameterError("t_coef", "a positive number", t_coef)
        self.points = pts
        n = len(pts)
        if domain is None:
            dom = np.arange(n, dtype=np.int64)
        elif np.isscalar(domain):
            if int(domain) < 4:
                raise ParameterError("domain", "at least 4 points", domain)
            dom = voxel_subsample(pts, int(domain))
        else:
            dom = np.unique(np.asarray(domain, np.int64))
            if len(dom) == 0 or dom[0] < 0 or dom[-1] >= n:
                raise ParameterError("domain", f"indices in [0, {n})", "out-of-range indices")
        # exact duplicates make the local triangulation degenerate: keep one of each
        _, first = np.unique(pts[dom], axis=0, return_index=True)
        if len(first) < len(dom):
            log.info("geodesics: %d duplicate points ignored in the operator", len(dom) - len(first))
            dom = dom[np.sort(first)]
        self.domain = dom
        self._x = pts[dom]
        self._nrm = None if normals is None else normals[dom]
        self._bridge_gap, self._bridge_min = bridge_gap, int(bridge_min)
        self.bridges = np.zeros((0, 2), np.int64)
        self._build(t_coef)
        self._tree = cKDTree(self._x)
        if len(dom) == n and np.array_equal(dom, np.arange(n)):
            self._W = None
        else:
            self._W = interpolation_matrix(self._x, pts, k=4, tree=self._tree)
            # nearest domain node of each point decides its component
        _, near = self._tree.query(pts, k=1, workers=-1)
        self._near = near.astype(np.int64)
        self.component = self.domain_component[self._near]

    # ---- construction --------------------------------------------------------------------
    def _build(self, t_coef: float) -> None:
        """Elements, the gradient operator, the components and the two factorisations."""
        x = self._x
        m = len(x)
        tris, edges = _mesh_elements(x, self._nrm)
        if self._bridge_gap is not None and self._bridge_gap > 0:
            self.bridges = _bridge(x, tris, edges, float(self._bridge_gap), self._bridge_min)
            if len(self.bridges):
                log.info("geodesics: %d gap(s) up to %.3g bridged", len(self.bridges),
                         float(np.linalg.norm(x[self.bridges[:, 0]] - x[self.bridges[:, 1]], axis=1).max()))
                edges = np.r_[edges, self.bridges]
        self.triangles, self.edges = tris, edges
        op = _operator(x, tris, edges)
        h = op.h
        self.h = h
        self.t = t_coef * h * h
        self._G, self._a3, self._mass = op.G, op.a3, op.mass
        adj = abs(op.L) + sp.eye(m)
        ncomp, comp = connected_components(adj, directed=False)
        self.n_components = int(ncomp)
        self.domain_component = comp.astype(np.int64)
        if not (h > 0 and np.isfinite(h)) or h < 1e-9 * max(float(np.ptp(x, 0).max()), 1e-300):
            raise ParameterError("points", "a cloud with distinct points", f"mean spacing {h:g}")
        self._heat, self._poisson = _factor(op, self.t)

    # ---- solves ------------------------------------------------------------------------
    def adjacency(self, lengths: bool = False) -> sp.csr_matrix:
        """(M, M) symmetric csr matrix of the element edges between domain points: 1 per edge, or
        the edge's Euclidean length with ``lengths=True`` (a graph for Dijkstra)."""
        e = [self.triangles[:, [0, 1]], self.triangles[:, [1, 2]], self.triangles[:, [0, 2]], self.edges]
        e = np.concatenate([q for q in e if len(q)] or [np.zeros((0, 2), np.int64)])
        m = len(self._x)
        a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(m, m)).tocsr()
        a = ((a + a.T) > 0).astype(np.int8).tocsr()
        a.sort_indices()
        if lengths:
            r = np.repeat(np.arange(m), np.diff(a.indptr))
            ln = np.linalg.norm(self._x[r] - self._x[a.indices], axis=1)
            a = sp.csr_matrix((np.maximum(ln, 1e-12), a.indices, a.indptr), shape=(m, m))
        return a

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def domain_points(self) -> np.ndarray:
        """(M, 3) float64 positions of the domain points (``points[domain]``; do not modify)."""
        return self._x

    def nearest_domain(self, point_indices) -> np.ndarray:
        """Domain position (index into ``domain``) of the domain point nearest each given point.

        point_indices : int or (K,) int indices into ``points``; returns an int64 of the same shape.
        A domain point is its own nearest (``nearest_domain(domain) == arange(M)``).
        """
        return self._near[point_indices]

    def domain_neighbors(self, position: np.ndarray, k: int) -> np.ndarray:
        """(k,) int64 domain positions of the k domain points nearest ``position`` ((3,) float,
        the points' frame), nearest first (Euclidean)."""
        return np.atleast_1d(self._tree.query(position, k=k)[1])

    def _to_domain(self, sources) -> np.ndarray:
        src = np.atleast_1d(np.asarray(sources, np.int64))
        if len(src) == 0:
            raise ParameterError("sources", "at least one point index", "an empty list")
        if src.min() < 0 or src.max() >= self.n_points:
            raise ParameterError("sources", f"indices in [0, {self.n_points})", src.tolist()[:5])
        return np.unique(self._near[src])

    def domain_distances(self, source_sets) -> np.ndarray:
        """(M, K) float64 distances on the domain points, one column per source set.

        source_sets : sequence of K sets of DOMAIN indices (each an int or a list of ints; a set
        gives the distance to its nearest member). inf in components holding no source.
        """
        m = len(self._x)
        k = len(source_sets)
        B = np.zeros((m, k))
        for j, s in enumerate(source_sets):
            s = np.atleast_1d(np.asarray(s, np.int64))
            B[s, j] = 1.0 / len(s)
        U = self._heat.solve(B)
        gu = (self._G @ U).reshape(-1, 3, k)
        nrm = np.linalg.norm(gu, axis=1, keepdims=True)
        X = -np.divide(gu, nrm, out=np.zeros_like(gu), where=nrm > 1e-300)
        rhs = self._G.T @ (self._a3[:, None] * X.reshape(-1, k))
        phi = self._poisson.solve(rhs)
        comp = self.domain_component
        for j, s in enumerate(source_sets):
            s = np.atleast_1d(np.asarray(s, np.int64))
            cs = np.unique(comp[s])
            for c in cs:
                sel = comp == c
                phi[sel, j] -= phi[s[comp[s] == c], j].mean()
            phi[~np.isin(comp, cs), j] = np.inf
        return np.maximum(phi, 0.0)

    def distances(self, sources_list) -> np.ndarray:
        """(N, K) float64: column j = distance of every point from ``sources_list[j]``.

        sources_list : sequence of K point indices or index lists (multi-source sets). All K
        right-hand sides are solved together with the stored factorisations.
        """
        sets = [self._to_domain(s) for s in sources_list]
        D = self.domain_distances(sets)
        return self.transfer(D, sources_list)

    def transfer(self, D: np.ndarray, sources_list=None) -> np.ndarray:
        """(M, K) domain values -> (N, K) values at every point (sources set to exactly 0)."""
        if self._W is None:
            out = D.copy()
        else:
            fin = np.isfinite(D)
            out = self._W @ np.where(fin, D, 0.0)
            # a point whose component holds no source stays unreachable
            reach = fin[self._near]
            out[~reach] = np.inf
        if sources_list is not None:
            for j, s in enumerate(sources_list):
                out[np.atleast_1d(np.asarray(s, np.int64)), j] = 0.0
        return out

    def distance(self, sources) -> np.ndarray:
        """(N,) float64 geodesic distance from ``sources`` (an index or a list: nearest source)."""
        return self.distances([sources])[:, 0]


# ---- operator construction (GeodesicSolver._build's steps) ---------------------------------
@dataclass
class _Operator:
    """The discrete operators on M domain points and E elements (triangles first, then edges).

    G : (3E, M) csr gradient (a constant gradient per element); a3 : (3E,) element measure,
    repeated per coordinate; mass : (M,) lumped mass; L : (M, M) csc Laplacian G^T diag(a3) G;
    h : mean element edge length (points' units).
    """

    G: sp.csr_matrix
    a3: np.ndarray
    mass: np.ndarray
    L: sp.csc_matrix
    h: float


def _mesh_elements(x: np.ndarray, nrm: np.ndarray | None):
    """Triangles (T, 3) int64 and 1-D edges (E, 2) int64 on the domain points ``x`` (M, 3);
    with normals ``nrm`` (M, 3) (NaN rows unknown), orientation-dropped elements that cut a piece
    off are given back (:func:`_reconnect`)."""
    m = len(x)
    kk = min(8, m - 1)
    if kk >= 1:
        d, nb = knn(x, kk + 1)
        spacing = np.maximum(d[:, -1], 1e-12)
    else:
        nb = np.zeros((m, 1), np.int64)
        spacing = np.ones(m)
    tris = _local_triangles(x)
    if len(tris):
        tris, dropped_tris = _filter_triangles(x, tris, spacing, nrm)
    else:
        dropped_tris = tris
    if kk >= 1:
        edges, dropped_edges = _thin_region_edges(x, tris, nb[:, 1:min(6, kk) + 1], spacing, nrm)
    else:
        edges = dropped_edges = np.zeros((0, 2), np.int64)
    if nrm is not None:
        tris, edges = _reconnect(m, tris, edges, dropped_tris, dropped_edges)
    return tris, edges


def unique_rows(a: np.ndarray, m: int) -> np.ndarray:
    """The distinct rows of ``a`` ((K, c) int, entries in [0, m), m**c < 2**63) in lexicographic
    order: ``np.unique(a, axis=0)``, on one int64 code per row (a 1-D unique is ~5x faster than
    the row-wise one, which sorts a structured view)."""
    a = np.asarray(a, np.int64)
    code = np.zeros(len(a), np.int64)
    for j in range(a.shape[1]):
        code = code * m + a[:, j]
    u = np.unique(code)
    out = np.empty((len(u), a.shape[1]), np.int64)
    for j in range(a.shape[1] - 1, -1, -1):
        u, out[:, j] = np.divmod(u, m)
    return out


def _local_triangles(x: np.ndarray) -> np.ndarray:
    """(T, 3) int64 sorted, deduplicated triangles of geometry-central's local Delaunay
    triangulation of ``x`` (M, 3); none for fewer than 4 points or a degenerate cloud."""
    tris = np.zeros((0, 3), np.int64)
    if len(x) >= 4:
        try:
            import potpourri3d as pp3d

            loc = pp3d.PointCloudLocalTriangulation(x).get_local_triangulation().reshape(-1, 3)
            loc = loc[(loc >= 0).all(1)]
            tris = unique_rows(np.sort(loc, 1).astype(np.int64), len(x))
            tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2])]
        except Exception as exc:  # noqa: BLE001 - degenerate clouds: edges only
            log.debug("local triangulation failed (%s); using kNN edges only", exc)
    return tris


def _filter_triangles(x, tris, spacing, nrm):
    """(kept, dropped) triangles: slivers and over-long triangles go (not into ``dropped``); with
    normals, triangles that leave a vertex's tangent plane are ``dropped`` (may be given back).

    x : (M, 3); tris : (T, 3) int64; spacing : (M,) 8th-neighbour distance; nrm : (M, 3) or None.
    """
    p0, p1, p2 = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    cr = np.cross(p1 - p0, p2 - p0)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    longest = np.sqrt(np.max([((p1 - p0) ** 2).sum(1), ((p2 - p1) ** 2).sum(1),
                              ((p0 - p2) ** 2).sum(1)], axis=0))
    keep = area > SLIVER * longest**2
    keep &= longest <= LONG_EDGE * spacing[tris].min(1)
    tris = tris[keep]
    area, cr = area[keep], cr[keep]
    keep = np.ones(len(tris), bool)
    if nrm is not None:
        fn = cr / np.maximum(2 * area, 1e-300)[:, None]
        for c in range(3):
            nv = nrm[tris[:, c]]
            known = np.isfinite(nv).all(1)
            dot = np.abs((fn * np.nan_to_num(nv)).sum(1))
            keep &= ~known | (dot >= ORIENT_COS)
            # no edge of the triangle may leave this vertex's tangent plane
            for o in range(3):
                if o != c:
                    ev = x[tris[:, o]] - x[tris[:, c]]
                    ev /= np.maximum(np.linalg.norm(ev, axis=1), 1e-300)[:, None]
                    keep &= ~known | (np.abs((ev * np.nan_to_num(nv)).sum(1)) <= EDGE_SIN)
    return tris[keep], tris[~keep]


def _thin_region_edges(x, tris, nb, spacing, nrm):
    """(kept, dropped) 1-D elements where triangles do not cover: kNN edges (not triangle sides)
    at points in fewer than 3 triangles, no longer than LONG_EDGE x spacing; with normals, edges
    that leave an end's tangent plane are ``dropped`` (may be given back).

    x : (M, 3); tris : (T, 3) int64; nb : (M, k) int64 nearest neighbours (self excluded);
    spacing : (M,); nrm : (M, 3) or None.
    """
    m = len(x)
    cover = np.bincount(tris.ravel(), minlength=m) if len(tris) else np.zeros(m, np.int64)
    e = np.stack([np.repeat(np.arange(m), nb.shape[1]), nb.ravel()], 1)
    e = unique_rows(np.sort(e, 1), m)
    e = e[e[:, 0] != e[:, 1]]
    if len(tris):
        te = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [0, 2]]])
        te = unique_rows(np.sort(te, 1), m)
        code = lambda a: a[:, 0] * m + a[:, 1]  # noqa: E731
        e = e[~np.isin(code(e), code(te))]
    poor = cover < 3
    e = e[poor[e[:, 0]] | poor[e[:, 1]]]
    vec = x[e[:, 1]] - x[e[:, 0]]
    ln = np.linalg.norm(vec, axis=1)
    ok = (ln > 0) & (ln <= LONG_EDGE * spacing[e].min(1))
    if nrm is not None:
        u = vec / np.maximum(ln, 1e-300)[:, None]
        for c in range(2):
            nv = nrm[e[:, c]]
            known = np.isfinite(nv).all(1)
            ok &= ~known | (np.abs((u * np.nan_to_num(nv)).sum(1)) <= EDGE_SIN)
    good = (ln > 0) & (ln <= LONG_EDGE * spacing[e].min(1))
    return e[ok], e[good & ~ok]


def _operator(x: np.ndarray, tris: np.ndarray, edges: np.ndarray) -> _Operator:
    """Gradient operator, element measures, lumped mass and Laplacian of the element soup.

    Triangles: the constant gradient of the linear hat functions, measure = area. Edges: the
    derivative along the edge, measure = length x h (h = mean element edge length).
    """
    m = len(x)
    rows, cols, vals = [], [], []
    if len(tris):
        p = [x[tris[:, c]] for c in range(3)]
        cr = np.cross(p[1] - p[0], p[2] - p[0])
        dbl = np.linalg.norm(cr, axis=1)
        nh = cr / dbl[:, None]
        opp = [p[2] - p[1], p[0] - p[2], p[1] - p[0]]
        base = np.arange(len(tris)) * 3
        for c in range(3):
            g = np.cross(nh, opp[c]) / dbl[:, None]
            for k in range(3):
                rows.append(base + k), cols.append(tris[:, c]), vals.append(g[:, k])
        tri_a = dbl / 2
    else:
        tri_a = np.zeros(0)
    h_edges = []
    if len(tris):
        h_edges.append(np.linalg.norm(opp[0], axis=1))
    if len(edges):
        vec = x[edges[:, 1]] - x[edges[:, 0]]
        ln = np.linalg.norm(vec, axis=1)
        h_edges.append(ln)
    h = float(np.mean(np.concatenate(h_edges))) if h_edges else 1.0
    if len(edges):
        u = vec / ln[:, None] ** 2
        base = 3 * len(tris) + np.arange(len(edges)) * 3
        for k in range(3):
            rows += [base + k, base + k]
            cols += [edges[:, 1], edges[:, 0]]
            vals += [u[:, k], -u[:, k]]
        edge_a = ln * h
    else:
        edge_a = np.zeros(0)
    n_el = len(tris) + len(edges)
    G = sp.csr_matrix((np.concatenate(vals) if vals else np.zeros(0),
                       (np.concatenate(rows) if rows else np.zeros(0, int),
                        np.concatenate(cols) if cols else np.zeros(0, int))),
                      shape=(3 * n_el, m))
    a = np.concatenate([tri_a, edge_a])
    a3 = np.repeat(a, 3)
    mass = np.zeros(m)
    if len(tris):
        np.add.at(mass, tris.ravel(), np.repeat(tri_a / 3, 3))
    if len(edges):
        np.add.at(mass, edges.ravel(), np.repeat(edge_a / 2, 2))
    mass = np.maximum(mass, 1e-3 * h * h)  # isolated points keep the systems definite
    L = (G.T @ sp.diags(a3) @ G).tocsc()
    return _Operator(G=G, a3=a3, mass=mass, L=L, h=h)


def _factor(op: _Operator, t: float):
    """(heat, poisson) sparse LU factorisations: ``M + t L+`` and ``L + 1e-6 M``.

    Heat step with the positive part of the cotan weights (L+): an M-matrix, so u >= 0 and the
    triangular solves keep tiny far-field values relatively accurate (the full cotan Laplacian of
    a point-cloud triangle soup has obtuse slivers; with it, u loses all precision where it falls
    below 1e-14 of its peak and the gradient there is noise). Raises ParameterError on a singular
    system (a degenerate cloud).
    """
    L, Mm = op.L, sp.diags(op.mass)
    opts = dict(permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
    off = (L - sp.diags(L.diagonal())).tocsr()
    off.data = np.minimum(off.data, 0.0)
    off.eliminate_zeros()
    Lpos = off - sp.diags(np.asarray(off.sum(1)).ravel())
    try:
        heat = spla.splu((Mm + t * Lpos).tocsc(), **opts)
        # tiny mass term: removes the constant null space of each component
        poisson = spla.splu((L + 1e-6 * Mm).tocsc(), **opts)
    except RuntimeError as exc:  # singular: a degenerate cloud (all points nearly coincide)
        raise ParameterError("points", "a cloud with a non-degenerate extent",
                             f"a singular Laplacian ({exc})") from None
    return heat, poisson


def _components(m, tris, edges):
    pairs = [tris[:, [0, 1]], tris[:, [1, 2]], edges]
    e = np.concatenate([q for q in pairs if len(q)] or [np.zeros((0, 2), np.int64)])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(m, m))
    return connected_components(g, directed=False)[1]


def _bridge(x, tris, edges, gap, min_size):
    """(B, 2) int64 edges joining pieces (>= min_size points) to the largest piece across gaps
    <= ``gap``, closest gap first (Kruskal on pieces)."""
    m = len(x)
    comp = _components(m, tris, edges)
    sizes = np.bincount(comp)
    main = sizes.argmax()
    in_main = comp == main
    big = sizes >= min_size
    out = []
    while True:
        cand = np.flatnonzero(~in_main & big[comp])
        if len(cand) == 0:
            break
        mi = np.flatnonzero(in_main)
        d, j = cKDTree(x[mi]).query(x[cand], k=1, distance_upper_bound=gap)
        if not np.isfinite(d).any():
            break
        k = int(np.argmin(d))
        a, b = int(cand[k]), int(mi[j[k]])
        out.append((a, b))
        in_main |= comp == comp[a]
    return np.asarray(out, np.int64).reshape(-1, 2)


def _reconnect(m, tris, edges, dropped_tris, dropped_edges):
    """Give back orientation-dropped elements where dropping them cut a piece off.

    The orientation test must only remove short-cuts, never the one junction that holds a leaf to
    its petiole (a stem meeting a leaf at a right angle fails the tangent-plane test). So every
    piece that is disconnected from the largest piece of its component in the unfiltered element
    graph gets back all dropped elements touching it.
    """
    if not len(dropped_tris) and not len(dropped_edges):
        return tris, edges
    full = _components(m, np.r_[tris, dropped_tris], np.r_[edges, dropped_edges])
    for _ in range(4):
        part = _components(m, tris, edges)
        # the largest filtered piece of each unfiltered component is its main piece
        key = full * (m + 1) + part
        uk, cnt = np.unique(key, return_counts=True)
        main = {}
        for k_, c_ in zip(uk.tolist(), cnt.tolist()):
            f_ = k_ // (m + 1)
            if c_ > main.get(f_, (0, -1))[0]:
                main[f_] = (c_, k_ % (m + 1))
        main_part = np.array([main[f][1] for f in full.tolist()])
        orphan = part != main_part
        if not orphan.any():
            break
        t_back = orphan[dropped_tris].any(1) if len(dropped_tris) else np.zeros(0, bool)
        e_back = orphan[dropped_edges].any(1) if len(dropped_edges) else np.zeros(0, bool)
        if not t_back.any() and not e_back.any():
            break
        tris = np.r_[tris, dropped_tris[t_back]]
        edges = np.r_[edges, dropped_edges[e_back]]
        dropped_tris, dropped_edges = dropped_tris[~t_back], dropped_edges[~e_back]
    return tris, edges


def compute_distance(points: np.ndarray, sources, **kwargs) -> np.ndarray:
    """One-off: (N,) float64 heat geodesic distance from ``sources``; see :class:`GeodesicSolver`."""
    return GeodesicSolver(points, **kwargs).distance(sources)
