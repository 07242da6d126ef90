"""Leaf instances as blades: the default automatic segmentation (``SegmentParams.method = "blades"``).

Why a departure from the paper's apex -> tree -> petiole march (still there as
``method="apex"``, and exactly the paper's with ``--paper-rules``): on plants we did not design
(issue "Segmentation that holds on plants we did not design") the march fails in ways no threshold
fixes. It stops on no petiole and one leaf swallows the stem; it groups the leaflets of a compound
leaf like the lobes of one blade; it leaves small or cordate leaves on the stem; and its fixed
radii break on uneven density. What a 3DGS capture gives beyond points answers these directly: a
leaf is an open, thin *sheet*, and the stem, petioles, petiolules and rachises are *tubes*. A
flat Gaussian's smallest axis is the surface normal, and the normals of a sheet patch all agree
(up to sign), while the normals around a tube turn through a half circle or more within a radius
of its diameter.

Steps (working frame: root at the origin, +Z up, plant height 1; radii in those units):

1. **Surface graph** on a uniform (voxel) subsample of about ``domain_points`` Gaussians (a grid
   in the points' own principal frame, per voxel the Gaussian nearest its centre: the same
   capture in another file order or frame gives the same graph, see ``voxel_subsample``): each
   point joined to its ``graph_k`` nearest neighbours, an edge kept when it is at most 2.5 local
   spacings long (density-adaptive: the spacing is each point's own 6th-neighbour distance) and,
   between sheet points, when it stays in both tangent planes (``|e . n| <= tangent_sin``) and
   the two normals agree (``|n_i . n_j| >= normal_cos``). So two sheets a few millimetres apart
   (a tip hanging over a lower leaf, overlapping leaflets) are not joined, however close.
2. **Tubes** (``stalk``): the normal tensor ``T = mean n n^T`` over the neighbours within
   ``stalk_radius`` has its second eigenvalue above ``stalk_ratio`` x its first (a sheet: ~0; a
   tube: ~1), smoothed by two rounds of majority vote over the graph. Only the tube network
   holding the root's nearest tube point (lowest heat-method ``D_r``) is stem: tube-like spots on
   a curled blade that do not connect to the stem stay blade. Where the tube test drops out
   for a stretch (a scanner sees one side of a stem; noisy normals), a tube piece thick across
   within ``stem_gap`` stalk radii of the stem along the graph continues it.
3. **Blades** are the connected components of the sheet points. A blade touches the stem where
   its petiole (or petiolule, or a sessile base) enters: the *attachments*, sheet points with a
   stem neighbour, clustered within ``attach_link`` spacings. A blade with several attachments
   is several leaves (touching or overlapping leaves, each on its own stalk): it is split by
   graph-geodesic distance from each attachment. An attachment with blade all round it is a stem
   touching the blade's face, not a stalk's entry (:func:`face_contacts`), and cuts nothing.
   A "blade" entered by the stem at ``stem_contacts`` or more separate places (face contacts
   aside) runs along it: a stretch of stem the tube test missed (a scan's flat strip), not leaves.
4. **Leaflets joined at one point** (the three leaflets of a trifoliate leaf meeting at the end of
   the rachis, touching young leaves of a bud) share one attachment. The merge tree of the
   superlevel sets of the distance from the attachment separates them: tips are born, branches
   merge at saddles. Two branches of at least ``min_leaf_fraction`` of the domain that merge
   where less than ``palm_fraction`` of their size lies below the saddle meet at their bases:
   they are two leaves; so are two that merge above a strip narrower than either
   (``stalk_narrow``: a stalk the tube test missed, as a scan that sees a stem from one side
   makes it a flat band). Lobes of one blade meet above a palm as wide as they are and stay one
   leaf.
5. **Tubes that look like sheets**: a thick main stem is flat at ``stalk_radius``; a would-be
   leaf whose normals wrap around (``T``'s eigenvalue ratio over the whole piece above
   ``tube_ratio``) is a stem piece, not a leaf, when its *positions* say tube too; so is a blade
   that touches the stem with more than ``STEM_PATCH`` of its points (a leaf touches it only
   where its stalk enters: a patch of stem surface is bordered by stem all round) and is a tube
   by its positions. The normals alone cannot tell a tube from a leaf curled along its length,
   cupped or folded (its normals turn through a half circle too), and on real scans that sent
   whole leaves to the stem (maize, tomato; ``benchmarks/real_scans.py``). The positions can:
   the neighbourhood's covariance (:func:`shape_eigenvalues`, opacity-weightable) is thick
   across a tube (``lambda_3 / lambda_2`` 0.4-0.8 at 2-4 ``stalk_radius``) and thin on a sheet,
   curled or not, two-layered or noisy (0.02-0.12), and a tube is longer along the axis its
   normals wrap around than across it and closed round that axis (:func:`tube_shaped`), a
   curled, rolled or twisted leaf is not. A piece found as a leaf must be thicker than a half
   ring (``blade_thick``): a leaf folded at its midrib into a U is as thick as a stem seen from
   one side (0.2-0.3 on the maize scans). These do not use the Gaussians' rotations, the least
   reliable part of a real capture. Sheet bits too small to be leaves (a blade cut by the sheet
   test where it folds) join the nearest leaf through non-stem points.
6. Leaves are ordered bottom to top by the ``D_r`` of their base; every Gaussian takes the label
   of its nearest domain point; floaters stay unassigned. The rootward tree (for the stem mesh)
   is the graph's shortest-path tree from the root to every leaf tip.

**Confidence** per leaf, in [0, 1] (:func:`leaf_confidence`): the product of three factors, each
1 for a clean leaf: the leaf is not a piece cut from a larger blade (0.6 if it was split by
attachments or by the merge tree), its own normals agree (1 - the normal tensor's eigenvalue
ratio, i.e. it is one sheet), and its size against the plant's median leaf (``min(1, 2 s / median)``:
fragments are doubtful). The edit command opens on the least confident leaf.

Heat-method geodesics give ``D_r`` (one factorisation, :mod:`leaffit_usd.geometry.heat`); the
distances inside one blade, from its attachments, are Dijkstra distances on the surface graph
(each blade is small, and the graph already excludes the short-cuts between sheets that the
heat method's triangulation would take).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from leaffit_usd.geometry.heat import GeodesicSolver, voxel_subsample
from leaffit_usd.geometry.plane import plane_basis
from leaffit_usd.geometry.sampling import position_order

log = logging.getLogger("leaffit_usd")

SPLIT_CONFIDENCE = 0.6   # confidence factor of a leaf cut from a larger blade
# wider tube tests (radius factor, ratio): a thick stem turns its normals through >= ~120 degrees
# within twice, and >= ~150 degrees within four times the radius; a leaf blade does not
TUBE_WIDE = ((2, 0.5), (4, 0.7))
PALM_BALANCE = 0.2       # leaflets cut apart at their bases are of comparable size (>= 1/5)
#: a stalk contact with blade in at least this share of the angular sectors around it, in every
#: annulus of ``FACE_ANNULI``, touches the blade's face: a stem passing under or over it, not a
#: stalk entering at the blade's margin (``face_contacts``). 15 of 16: blade all round but for
#: one sector's sampling gap.
FACE_SECTORS, FACE_SHARE = 16, 15 / 16
FACE_ANNULI = ((2.0, 4.0), (4.0, 8.0))   # inner, outer radius in median graph spacings
STEM_PATCH = 0.25        # a "blade" touching the stem with more than this fraction of its points
                         # is a patch of stem surface (leaves touch it with 0.1-6 %, patches 40-60 %)
ISLAND_GAP = 0.5         # pieces farther than this (plant reach units) from the plant are not it
#   (a hole in uneven sampling can leave a leaf 0.1-0.3 away from the rest; clutter is the
#   isolation stage's job)
HEAT_SUBSAMPLE = 3       # the root distance's heat operator runs on every 3rd graph point (voxel)


@dataclass
class SurfaceGraph:
    """The subsampled surface and its sheet-aware neighbourhood graph.

    domain : (M,) int64 Gaussian indices of the graph's points (ordered by x, then y, then z)
    points : (M, 3) float64, working frame
    normals : (M, 3) float64 unit normals (a flat Gaussian's smallest axis, else local PCA)
    spacing : (M,) float64, distance to the 6th nearest domain point (working units)
    graph : (M, M) csr, symmetric, edge lengths (working units)
    neighbors, dists : (M, K) int64 / float64, Euclidean nearest domain points (self first;
        K = max(12, graph_k + 1))
    """

    domain: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    spacing: np.ndarray
    graph: csr_matrix
    neighbors: np.ndarray
    dists: np.ndarray

    @property
    def size(self) -> int:
        return len(self.domain)

    def scale(self, factor: float) -> None:
        """Multiply every length (points, spacing, distances, edge lengths) by ``factor``, in place."""
        self.points = self.points * factor
        self.spacing = self.spacing * factor
        self.dists = self.dists * factor
        self.graph = self.graph * factor

    def subgraph(self, mask: np.ndarray) -> csr_matrix:
        """The graph restricted to edges with both ends in ``mask`` ((M,) bool)."""
        return _restrict(self.graph, mask)


def _pca_normals(points: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """(M, 3) unit normals by local PCA over each point's neighbours ``nbrs`` ((M, k) indices)."""
    x = points[nbrs] - points[nbrs].mean(1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", x, x))
    return vec[:, :, 0]


def build_surface_graph(points: np.ndarray, normals: np.ndarray | None, include: np.ndarray,
                        params) -> SurfaceGraph:
    """Step 1. points : (N, 3) working frame; normals : (N, 3) or None (NaN rows = unknown);
    include : (N,) bool, the Gaussians that may be graph points (floaters excluded)."""
    pool = np.flatnonzero(include)
    dom = pool[voxel_subsample(points[pool], params.domain_points)]
    # in position order, not file order: graph ties (equal distances, merge order) then fall the
    # same way whatever the order of the Gaussians in the file
    dom = dom[position_order(points[dom])]
    x = points[dom].astype(np.float64)
    m = len(x)
    kq = int(min(max(12, params.graph_k + 1), m))  # the graph's edges, spacing, PCA normals
    d, nb = cKDTree(x).query(x, k=kq, workers=-1)
    d, nb = d.reshape(m, kq), nb.reshape(m, kq)
    given = np.asarray(normals, np.float64)[dom] if normals is not None else np.full((m, 3), np.nan)
    nrm = given.copy()
    unknown = ~np.isfinite(given).all(1)
    if unknown.any():  # not a flat Gaussian (or no normals given): local PCA
        nrm[unknown] = _pca_normals(x, nb[unknown, :min(12, kq)])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    spacing = d[:, min(6, kq - 1)]
    k = int(min(params.graph_k, kq - 1))
    rows = np.repeat(np.arange(m), k)
    cols = nb[:, 1:k + 1].ravel()
    length = d[:, 1:k + 1].ravel()
    ok = (length <= 2.5 * np.maximum(spacing[rows], spacing[cols])) & (length > 0)
    g = coo_matrix((length[ok], (rows[ok], cols[ok])), shape=(m, m)).tocsr()
    g = g.maximum(g.T).tocsr()
    return SurfaceGraph(domain=dom, points=x, normals=nrm, spacing=spacing, graph=g, neighbors=nb,
                        dists=d)


def sheet_edges(g: SurfaceGraph, tube: np.ndarray, params) -> csr_matrix:
    """Step 1, the sheet test: the graph without edges that leave a tangent plane or join two
    disagreeing normals, unless an end is a tube point (a tube's normals turn by design)."""
    c = g.graph.tocoo()
    e = g.points[c.col] - g.points[c.row]
    e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-12)
    ni, nj = g.normals[c.row], g.normals[c.col]
    flat = ((np.abs((e * ni).sum(1)) <= params.tangent_sin) & (np.abs((e * nj).sum(1)) <= params.tangent_sin)
            & (np.abs((ni * nj).sum(1)) >= params.normal_cos))
    keep = flat | tube[c.row] | tube[c.col]
    return coo_matrix((c.data[keep], (c.row[keep], c.col[keep])), shape=c.shape).tocsr()


def normal_tensor_ratio(normals: np.ndarray) -> float:
    """Second over first eigenvalue of ``mean n n^T`` of (k, 3) unit normals: ~0 for one sheet,
    ~1 for normals around a tube."""
    ev = np.linalg.eigvalsh(normals.T @ normals / max(len(normals), 1))
    return float(ev[1] / max(ev[2], 1e-12))


def _tensor_ratio_within(points, normals, queries, radius, k=64) -> np.ndarray:
    """(Q,) second / first eigenvalue of ``mean n n^T`` over the (up to ``k`` nearest) ``points``
    within ``radius`` of each of ``queries`` ((Q, 3))."""
    q = len(queries)
    kk = int(min(k, len(points)))
    d, nb = cKDTree(points).query(queries, k=kk, distance_upper_bound=radius, workers=-1)
    nb = nb.reshape(q, kk)
    # neighbours beyond the radius come back as index len(points): a zero normal row
    padded = np.concatenate([np.asarray(normals, np.float64), np.zeros((1, 3))])
    nn = padded[nb]  # (Q, k, 3)
    count = np.maximum((nb < len(points)).sum(1), 1)
    t = (nn.transpose(0, 2, 1) @ nn) / count[:, None, None]  # batched 3x3: matmul, not einsum (5x)
    ev = np.linalg.eigvalsh(t)
    return ev[:, 1] / np.maximum(ev[:, 2], 1e-12)


def shape_eigenvalues(points: np.ndarray, weights: np.ndarray | None, queries: np.ndarray,
                      radius: float, k: int = 48) -> np.ndarray:
    """(Q, 3) float64 eigenvalues, largest first, of the weighted covariance of the positions of
    the (up to ``k`` nearest) ``points`` ((P, 3)) within ``radius`` of each of ``queries``
    ((Q, 3)); ``weights`` ((P,) >= 0, e.g. opacities; None = 1). Zero where fewer than 3
    points lie within the radius. The neighbourhood's own shape, whatever its Gaussians' axes
    say: a sheet gives lambda_3 << lambda_2, a tube of diameter below the radius lambda_3 ~
    lambda_2 << lambda_1."""
    q = len(queries)
    kk = int(min(k, len(points)))
    _, nb = cKDTree(points).query(queries, k=kk, distance_upper_bound=radius, workers=-1)
    nb = nb.reshape(q, kk)
    w = np.ones(len(points)) if weights is None else np.asarray(weights, np.float64)
    wp = np.concatenate([w, [0.0]])[nb]  # beyond the radius: index len(points), weight 0
    xp = np.concatenate([np.asarray(points, np.float64), np.zeros((1, 3))])[nb]
    tot = np.maximum(wp.sum(1), 1e-12)
    mu = (xp * wp[..., None]).sum(1) / tot[:, None]
    dx = (xp - mu[:, None]) * np.sqrt(wp)[..., None]
    ev = np.linalg.eigvalsh(dx.transpose(0, 2, 1) @ dx / tot[:, None, None])[:, ::-1]
    ev[(nb < len(points)).sum(1) < 3] = 0.0
    return np.maximum(ev, 0.0)


def thickness(g: SurfaceGraph, weights: np.ndarray | None, factor: float, params) -> np.ndarray:
    """(M,) lambda_3 / lambda_2 of the neighbourhood within ``factor`` x ``stalk_radius`` of each
    graph point (:func:`shape_eigenvalues`; on a coarser voxel subsample beyond the base radius,
    so that the neighbours reach that far): ~0 on a sheet, curled or not, at scales below its
    curl radius; 0.2-1 across a tube (a half-circle arc, one side of a stem seen by a scanner,
    gives ~0.2; a full circle 1)."""
    pts, w = g.points, weights
    if factor > 1:
        sub = voxel_subsample(g.points, max(64, int(g.size / (factor * factor))))
        pts, w = g.points[sub], None if weights is None else weights[sub]
    ev = shape_eigenvalues(pts, w, g.points, factor * params.stalk_radius)
    return ev[:, 2] / np.maximum(ev[:, 1], 1e-300)


def tube_mask(g: SurfaceGraph, params) -> np.ndarray:
    """Step 2 (before the root test): (M,) bool, True where the surface is a tube: the normal
    tensor's eigenvalue ratio exceeds ``stalk_ratio`` within ``stalk_radius``, or the stricter
    ``TUBE_WIDE`` ratios within larger radii (a stem thicker than ``stalk_radius`` is locally
    flat at that radius; the wide tests run on a coarser subsample so that 64 neighbours reach
    that far). Unsmoothed; see :func:`smooth_mask`."""
    tube = _tensor_ratio_within(g.points, g.normals, g.points, params.stalk_radius) > params.stalk_ratio
    for factor, ratio in TUBE_WIDE:
        coarse = voxel_subsample(g.points, max(64, g.size // (factor * factor)))
        todo = np.flatnonzero(~tube)  # a point already found a tube needs no wider test
        tube[todo] = _tensor_ratio_within(g.points[coarse], g.normals[coarse], g.points[todo],
                                          factor * params.stalk_radius) > ratio
    return tube


def smooth_mask(graph: csr_matrix, mask: np.ndarray, rounds: int = 2) -> np.ndarray:
    """(M,) bool: ``mask`` after ``rounds`` of majority vote over each point and its neighbours
    in ``graph``."""
    tube = mask
    a = (graph > 0).astype(np.float64)
    deg = np.asarray(a.sum(1)).ravel()
    for _ in range(rounds):
        tube = (a @ tube.astype(np.float64) + tube) / (deg + 1) > 0.5
    return tube


def rooted_stem(g: SurfaceGraph, tube: np.ndarray, d_root: np.ndarray, link: float,
                min_size: int, thick: np.ndarray | None = None, gap: float = 0.0,
                params=None) -> np.ndarray:
    """Step 2: (M,) bool, the stem: of the pieces of tube points (tube points at most ``link``
    apart are one piece, so a stem whose tube test drops out for a moment stays one piece) with
    at least ``min_size`` points, the one reaching lowest in ``D_r``. Other tube-like spots (a
    curled blade's) are not stem. With ``thick`` ((M,) :func:`piece_thickness`), ``gap`` > 0
    (working units) and ``params``, pieces of at least ``min_size`` points that are thick across
    (``params.piece_thick``) and lie within ``gap`` of the stem along the surface graph join it,
    transitively: the stem beyond a stretch where the tube test dropped out."""
    idx = np.flatnonzero(tube & np.isfinite(d_root))
    out = np.zeros(len(tube), bool)
    if not len(idx):
        return out
    pairs = cKDTree(g.points[idx]).query_pairs(link, output_type="ndarray")
    n, comp = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                              shape=(len(idx), len(idx))), directed=False)
    size = np.bincount(comp, minlength=n)
    low = np.full(n, np.inf)
    np.minimum.at(low, comp, d_root[idx])
    low[size < min(min_size, size.max())] = np.inf
    first = int(np.argmin(low))
    out[idx[comp == first]] = True
    if thick is None or gap <= 0 or params is None:
        return out
    # chain: a tube piece (thick across, of leaf size) within ``gap`` of the stem along the surface
    # graph continues it (the tube test drops out where a scan samples a stem from one side)
    cand = [c for c in range(n)
            if c != first and size[c] >= min_size and _is_thick(thick[idx[comp == c]], params)]
    while cand:
        d = dijkstra(g.graph, indices=np.flatnonzero(out), min_only=True, limit=gap)
        near = [c for c in cand if np.isfinite(d[idx[comp == c]]).any()]
        if not near:
            break
        for c in near:
            out[idx[comp == c]] = True
        cand = [c for c in cand if c not in near]
    return out


def _attachment_groups(g: SurfaceGraph, members, attached, link) -> list:
    """Attachment points of one blade (``members[attached[members]]``), clustered by single
    linkage at ``link`` (working units); each cluster with >= 2 points is one stalk's entry."""
    a = members[attached[members]]
    if len(a) < 2:
        return []
    pairs = cKDTree(g.points[a]).query_pairs(link, output_type="ndarray")
    n, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                             shape=(len(a), len(a))), directed=False)
    counts = np.bincount(lab, minlength=n)
    return [a[lab == i] for i in range(n) if counts[i] >= 2]


def face_contacts(g: SurfaceGraph, members: np.ndarray, groups: list) -> np.ndarray:
    """(G,) bool: which stalk contacts ``groups`` (lists of graph indices) of the blade
    ``members`` (graph indices) touch the blade's face rather than enter it.

    A petiole (petiolule, sessile base) enters its blade at the blade's margin or in a sinus:
    around the entry, the stalk's side is open. A stem passing under or over a blade and
    brushing it is surrounded by blade. A contact whose :func:`contact_sector_shares` reach
    ``FACE_SHARE`` in every annulus touches the face. Measured with
    ``benchmarks/contact_cues.py`` (our suite and seed 1 of heliosdev8, hard4 and paper8): of 57
    contacts on blades with several, the 46 true entries fill at most 14 of the 16 sectors; 2 of
    the 11 second contacts of a leaf fill all 16 (a stem under white_flag_bush's leaf 7, Helios
    sugar beet's leaf 1). The other 9 are at a margin, as an entry is, and still cut their leaf."""
    return np.array([min(contact_sector_shares(g, members, grp)) >= FACE_SHARE for grp in groups],
                    bool)


def contact_sector_shares(g: SurfaceGraph, members: np.ndarray, grp: np.ndarray) -> tuple:
    """Per annulus of ``FACE_ANNULI`` (radii in median graph spacings) around the contact
    ``grp``'s centre, in its tangent plane (its points' mean normal): the share of
    ``FACE_SECTORS`` angular sectors that hold a point of the blade ``members`` lying within half
    the annulus' outer radius of that plane. 1.0: blade all round."""
    spacing = float(np.median(g.spacing))
    centre, n = contact_plane(g, grp)
    if n is None:
        return (0.0,) * len(FACE_ANNULI)
    rel = g.points[members] - centre
    xy = rel @ plane_basis(n)
    r = np.linalg.norm(xy, axis=1)
    sector = np.floor((np.arctan2(xy[:, 1], xy[:, 0]) + np.pi) / (2 * np.pi) * FACE_SECTORS)
    h = np.abs(rel @ n)
    out = []
    for lo, hi in FACE_ANNULI:
        sel = (r >= lo * spacing) & (r < hi * spacing) & (h < 0.5 * hi * spacing)
        out.append(len(np.unique(sector[sel])) / FACE_SECTORS)
    return tuple(out)


def contact_plane(g: SurfaceGraph, grp: np.ndarray):
    """The tangent plane of the contact ``grp`` (graph indices): its points' centroid (3,) and
    their mean normal, signs aligned to the first point's (unit (3,); None when they cancel)."""
    nv = g.normals[grp] * np.sign(g.normals[grp] @ g.normals[grp[0]])[:, None]
    n = nv.mean(0)
    norm = float(np.linalg.norm(n))
    return g.points[grp].mean(0), (n / norm if norm > 1e-12 else None)


def split_at_narrow_saddles(nodes, dist, graph, normals, params, min_size, surface=None,
                            thick=None):
    """Step 4: leaves of one blade piece by the merge tree of the superlevel sets of ``dist``.

    nodes : (k,) graph indices of the piece; dist : (k,) distance from its attachment;
    graph : the sheet graph; normals : (M, 3) of the graph's points. Two branches of at least
    ``min_size`` points that merge are cut apart (each frozen as a leaf) when

    * less than ``params.palm_fraction`` of their size lies below the saddle (they meet at their
      bases: leaflets at the end of a rachis) and the smaller is at least ``PALM_BALANCE`` of
      the larger (a sliver of overlap is no leaflet), or
    * exactly one of them is a tube (normal tensor ratio above ``params.tube_ratio`` and, when
      ``surface`` (the SurfaceGraph) is given, :func:`_piece_is_tube` with ``thick`` ((M,)
      :func:`piece_thickness`): a curled sheet's normals wrap around too): a leaf meeting a stem
      too thick to pass the local tube test; the tube branch goes on.

    After a cut at the bases the merged set goes on as a *junction* (the few points where the
    leaflets meet); what it gathers is not a leaf of its own unless a larger, unflagged branch
    absorbs it.

    Returns (list of (k_i,) node arrays, one per leaf; (r,) leftover nodes: junctions and branches
    below ``min_size``, assigned to the nearest leaf later).
    """
    k = len(nodes)
    # the piece's own graph as Python lists: the sweep below visits every point once, and
    # numpy calls on a handful of neighbours each cost more than the work they do
    sub = graph[nodes][:, nodes].tocsr()
    indptr, indices = sub.indptr.tolist(), sub.indices.tolist()
    order = np.argsort(-dist, kind="stable")
    rank_below = np.searchsorted(np.sort(dist), dist).tolist()  # points below each point's level
    nrm = normals[nodes]
    parent = list(range(k))
    free: dict = {}
    junction: dict = {}
    seen = [False] * k
    leaves, rest = [], []
    dist_l = dist.tolist()
    top: dict = {}   # the highest level (distance) of each branch: where its tip was born
    low = float(dist.min()) if k else 0.0

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def is_tube(x):  # of the branch's free points (asked only when two leaf-size branches meet)
        if surface is None:
            return normal_tensor_ratio(nrm[free[x]]) > params.tube_ratio
        return _piece_is_tube(surface, nodes[free[x]], thick, params)

    def freeze(x):
        leaves.append(np.asarray(free[x]))
        free[x] = []

    for v in order.tolist():
        seen[v] = True
        free[v], junction[v], top[v] = [v], False, dist_l[v]
        for r in sorted({find(u) for u in indices[indptr[v]:indptr[v + 1]] if seen[u]} - {v}):
            a = find(v)
            if a == r:
                continue
            if len(free[a]) >= min_size and len(free[r]) >= min_size:
                ta, tr = is_tube(a), is_tube(r)
                if ta != tr:  # a sheet meets a tube: the sheet is a leaf
                    freeze(r if ta else a)
                elif (min(len(free[a]), len(free[r])) >= PALM_BALANCE * max(len(free[a]), len(free[r]))
                      and (rank_below[v] < params.palm_fraction * (len(free[a]) + len(free[r]))
                           or _narrow_below(rank_below[v], dist_l[v] - low,
                                            [(len(free[x]), top[x] - dist_l[v]) for x in (a, r)],
                                            params))):  # met at their bases: two leaves
                    for x in (a, r):  # a junction met again is leftover, not a leaf
                        if junction[x]:
                            rest.extend(free[x])
                            free[x] = []
                        else:
                            freeze(x)
                    junction[a] = junction[r] = True
            if len(free[a]) < len(free[r]) or (len(free[a]) == len(free[r]) and junction[a]):
                a, r = r, a
            # a junction stays one unless a branch of leaf size absorbs it
            junction[a] = (junction[a] or junction[r]) and not (
                len(free[a]) >= min_size and not junction[a])
            parent[r] = a
            free[a].extend(free[r])
            top[a] = max(top[a], top[r])
            del free[r], junction[r], top[r]
    for x, f in free.items():
        (leaves.append(np.asarray(f)) if len(f) >= min_size and not junction[x] else rest.extend(f))
    return [nodes[x] for x in leaves], nodes[np.asarray(rest, np.int64)]


def _narrow_below(below: int, depth: float, branches: list, params) -> bool:
    """Whether what lies below a saddle of the merge tree (``below`` points over ``depth`` of
    distance down to the attachment) is a stalk, narrower than each of the ``branches`` meeting
    there ((points, height above the saddle) each): its points per unit of distance, a width
    (times the sampling density), under ``params.stalk_narrow`` x the narrower branch's. Two
    leaves met at the top of a stalk that the tube test missed (a scan sees it as a flat strip)
    have a narrow strip below their saddle, however long; the lobes of one blade meet above
    a palm as wide as they are."""
    if depth <= 0 or any(h <= 0 for _, h in branches):
        return False
    return below / depth < params.stalk_narrow * min(n / h for n, h in branches)


@dataclass
class BladeLeaves:
    """Leaves on the surface graph: per domain point its leaf (0 = stem / none), per leaf
    whether it was split from a larger blade, and the stem mask."""

    labels: np.ndarray      # (M,) int64, 0..L
    was_split: np.ndarray   # (L,) bool
    stem: np.ndarray        # (M,) bool


def find_leaves(g: SurfaceGraph, sheet: csr_matrix, stem: np.ndarray, d_root: np.ndarray,
                params, thick: np.ndarray | None = None) -> BladeLeaves:
    """Steps 3-5 on the surface graph. thick : (M,) :func:`piece_thickness` of each point (None:
    computed here, unweighted)."""
    m = g.size
    if thick is None:
        thick = piece_thickness(g, None, params)
    blade = ~stem
    gb = _restrict(sheet, blade)
    n_comp, comp = connected_components(gb, directed=False)
    comp[~blade] = -1
    sizes = np.bincount(comp[blade], minlength=n_comp)
    c = sheet.tocoo()
    attached = np.zeros(m, bool)
    attached[c.col[stem[c.row] & blade[c.col]]] = True
    min_size = max(20, int(params.min_leaf_fraction * m))
    link = params.attach_link * float(np.median(g.spacing))
    leaves, split, rest = [], [], []
    stem = stem.copy()
    for cid in np.flatnonzero(sizes >= min_size):
        members = np.flatnonzero(comp == cid)
        if attached[members].mean() > STEM_PATCH and (  # stem surface the tube test missed
                _is_thick(thick[members], params)
                or tube_shaped(g.points[members], g.normals[members], params)):
            stem[members] = True
            continue
        groups = _attachment_groups(g, members, attached, link)
        if len(groups) > 1:  # a stem touching the blade's face is not a leaf's entry
            face = face_contacts(g, members, groups)
            if not face.all():
                groups = [grp for grp, f in zip(groups, face) if not f]
        if len(groups) >= params.stem_contacts:  # runs along the stem: stem the tube test missed
            stem[members] = True
            continue
        if not groups:  # no stalk touches it: grow from its lowest point
            fin = np.where(np.isfinite(d_root[members]), d_root[members], np.inf)
            groups = [members[[int(np.argmin(fin))]]]
        dist = np.stack([dijkstra(gb, indices=grp, min_only=True)[members] for grp in groups])
        owner = np.argmin(dist, 0)
        for i in range(len(groups)):
            piece, pd = members[owner == i], dist[i][owner == i]
            if len(piece) < min_size:
                rest.append(piece)
                continue
            lv, left = split_at_narrow_saddles(piece, np.where(np.isfinite(pd), pd, 0.0), gb,
                                               g.normals, params, min_size)
            leaves += lv
            split += [len(groups) > 1 or len(lv) > 1] * len(lv)
            rest.append(left)
    keep = []
    for lv, sp in zip(leaves, split):
        if _piece_is_tube(g, lv, thick, params):  # step 5: a tube, not a leaf
            stem[lv] = True
        else:
            keep.append((lv, sp))
    labels = np.zeros(m, np.int64)
    for i, (lv, _) in enumerate(keep):
        labels[lv] = i + 1
    rest_nodes = np.concatenate(rest) if rest else np.zeros(0, np.int64)
    if len(rest_nodes) and keep:
        todo = np.zeros(m, bool)
        todo[rest_nodes] = True
        _nearest_leaf(gb, labels, todo)
    _claim_loose_sheet(g, labels, stem)
    return BladeLeaves(labels=labels, was_split=np.asarray([s for _, s in keep], bool), stem=stem)


def piece_thickness(g: SurfaceGraph, weights: np.ndarray | None, params) -> np.ndarray:
    """(M,) the larger of :func:`thickness` at 2 and 4 x ``stalk_radius``: with
    :func:`tube_shaped`, what decides whether a piece whose normals wrap around is a tube or a
    curled sheet."""
    return np.maximum(thickness(g, weights, 2.0, params), thickness(g, weights, 4.0, params))


def tube_shaped(points: np.ndarray, normals: np.ndarray, params) -> bool:
    """Whether a piece whose normals wrap around ((k, 3) points and unit normals) is long along
    the axis they wrap around (the normal tensor's least eigenvector) against its extent across
    it, and closed round that axis (:func:`radial_share` above ``tube_radial``: at least about a
    half ring): a tube is (a stem piece is longer than it is thick, and round), a curled sheet
    is not (a leaf curled along its length is only its width long on that axis, and its arch is
    wide), nor is a leaf rolled or twisted along its length (a maize whorl's youngest leaf: long
    on the axis its normals turn about, but an open arc or a strap across it). Extents are
    5-95 % ranges, so stray points do not count."""
    if len(points) < 3:
        return False
    axis = np.linalg.eigh(normals.T @ normals)[1][:, 0]
    along = points @ axis
    across = points - along[:, None] * axis
    c = across - across.mean(0)
    main = np.linalg.eigh(c.T @ c)[1][:, -1]
    length = np.subtract(*np.percentile(along, [95, 5]))
    width = np.subtract(*np.percentile(c @ main, [95, 5]))
    if length <= params.tube_elongation * max(width, 1e-12):
        return False
    return radial_share(points, normals, axis) > params.tube_radial


def radial_share(points: np.ndarray, normals: np.ndarray, axis: np.ndarray,
                 slices: int = 8) -> float:
    """How closed a piece's cross-sections are round ``axis`` ((3,) unit): the median over its
    points ((k, 3) positions, unit normals) of ``|n . r|``, ``r`` the unit direction across the
    axis from the centroid of the point's slice (one of ``slices`` equal-count slices along the
    axis, so a bent piece keeps its centre) to the point. A ring's centroid is its centre: 1.0;
    an arc's lies inside the arc, off its centre of curvature: 0.81 for a half ring, 0.72 for
    150 degrees, 0.47 for a quarter; a twisted strap passes through its centroid: ~0."""
    along = points @ axis
    across = points - along[:, None] * axis
    edges = np.quantile(along, np.linspace(0.0, 1.0, slices + 1)[1:-1])
    part = np.searchsorted(edges, along)
    sums = np.zeros((slices, 3))
    np.add.at(sums, part, across)
    centre = sums / np.maximum(np.bincount(part, minlength=slices), 1)[:, None]
    r = across - centre[part]
    r /= np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)
    return float(np.median(np.abs((normals * r).sum(1))))


def _piece_is_tube(g: SurfaceGraph, nodes: np.ndarray, thick: np.ndarray | None, params) -> bool:
    """Step 5 for one piece (graph indices) found as a leaf: its normals wrap around (normal
    tensor ratio above ``tube_ratio``) and its positions say tube, not curled sheet: thicker
    across than a half ring (:func:`piece_thickness`, median above ``blade_thick``) or
    :func:`tube_shaped`."""
    if normal_tensor_ratio(g.normals[nodes]) <= params.tube_ratio:
        return False
    return (thick is None or _is_thick(thick[nodes], params, params.blade_thick)
            or tube_shaped(g.points[nodes], g.normals[nodes], params))


def _is_thick(values: np.ndarray, params, level: float | None = None) -> bool:
    """A piece is thick across (a tube, not a curled or folded sheet) when the median of its
    :func:`piece_thickness` ``values`` exceeds ``level`` (None: ``params.piece_thick``)."""
    level = params.piece_thick if level is None else level
    return bool(len(values)) and float(np.median(values)) > level


def _claim_loose_sheet(g: SurfaceGraph, labels: np.ndarray, stem: np.ndarray) -> None:
    """Non-stem graph points still without a leaf join the leaf nearest along the graph through
    non-stem points. In place. These are sheet pieces too small to be leaves: mostly single
    points whose normal disagrees with all their neighbours' (a round or badly fitted Gaussian),
    which the sheet test cuts off one by one. On the samples generator they were most of the
    leaf points lost to the stem (1.1-1.3 % of all Gaussians, all along the blades); bits that
    touch only the stem stay stem."""
    loose = (labels == 0) & ~stem
    if loose.any() and (labels > 0).any():
        _nearest_leaf(g.subgraph(~stem), labels, loose)


def _nearest_leaf(graph: csr_matrix, labels: np.ndarray, todo: np.ndarray) -> None:
    """Points ``todo`` ((M,) bool) take the label of the nearest labelled point along ``graph``
    (one multi-source Dijkstra); unreachable ones keep theirs. In place."""
    dl, _, src = dijkstra(graph, indices=np.flatnonzero(labels > 0), min_only=True,
                          return_predecessors=True)
    take = todo & np.isfinite(dl)
    labels[take] = labels[src[take]]


def _restrict(graph: csr_matrix, mask: np.ndarray) -> csr_matrix:
    """``graph`` without the edges that have an end outside ``mask`` ((M,) bool)."""
    c = graph.tocoo()
    keep = mask[c.row] & mask[c.col]
    return coo_matrix((c.data[keep], (c.row[keep], c.col[keep])), shape=c.shape).tocsr()


def leaf_confidence(g: SurfaceGraph, found: BladeLeaves) -> np.ndarray:
    """(L,) float in [0, 1] per leaf (see the module docstring): split factor x sheet coherence x
    size against the median leaf."""
    n_leaves = len(found.was_split)
    if n_leaves == 0:
        return np.zeros(0)
    sizes = np.bincount(found.labels, minlength=n_leaves + 1)[1:].astype(np.float64)
    med = float(np.median(sizes))
    conf = np.empty(n_leaves)
    for i in range(n_leaves):
        nodes = np.flatnonzero(found.labels == i + 1)
        coherence = 1.0 - normal_tensor_ratio(g.normals[nodes])
        size = min(1.0, 2.0 * sizes[i] / max(med, 1.0))
        conf[i] = (SPLIT_CONFIDENCE if found.was_split[i] else 1.0) * coherence * size
    return np.clip(conf, 0.0, 1.0)


@dataclass
class BladeResult:
    """What :func:`segment_blades` hands back to ``segment_plant`` (indices are Gaussians)."""

    labels: np.ndarray         # (N,) int32, 0..L, ordered bottom to top
    leaf_tip: np.ndarray       # (L,) int64
    leaf_base: np.ndarray      # (L,) int64
    confidence: np.ndarray     # (L,) float64
    tree_nodes: np.ndarray     # (S,) int64
    tree_parent: np.ndarray    # (S,) int64
    d_root: np.ndarray         # (N,) float64, heat-method distance from the root (inf: unreached)


def plant_reach(g: SurfaceGraph, source: int) -> float:
    """The plant's reach from its root: the 99th percentile of the distances of the root's
    connected piece from the root point ``source`` (graph units; the plant height for an upright
    plant, whatever up axis the frame chose; clutter apart from the plant does not count)."""
    _, comp = connected_components(g.graph, directed=False)
    d = np.linalg.norm(g.points[comp == comp[source]] - g.points[source], axis=1)
    return float(np.percentile(d, 99)) if len(d) > 1 else 1.0


def segment_blades(pts: np.ndarray, root: int, inlier: np.ndarray, normals, params,
                   timings: dict) -> BladeResult:
    """Steps 1-6. pts : (N, 3) working frame; inlier : (N,) bool (floaters False).

    The radii (``stalk_radius``, ``bridge_gap``, ``ISLAND_GAP``) are in units of :func:`plant_reach`, which is
    the working unit (plant height) when the up axis is right and does not change when the
    estimated up axis is wrong (the height along a wrong axis can be a fraction of the plant).
    """
    t = time.perf_counter()
    g = build_surface_graph(pts, normals, inlier, params)
    source = _source_node(g, pts[root])
    reach = max(plant_reach(g, source), 1e-12)
    g.scale(1.0 / reach)
    pts = np.asarray(pts, np.float64) / reach
    timings["graph"] = time.perf_counter() - t

    t = time.perf_counter()
    heat = voxel_subsample(g.points, max(64, g.size // HEAT_SUBSAMPLE))
    heat = np.union1d(heat, [source])
    _, to_heat = cKDTree(g.points[heat]).query(g.points, k=1, workers=-1)
    solver = GeodesicSolver(g.points[heat], None,
                            bridge_gap=params.bridge_gap if params.bridge_gap > 0 else None)
    d_heat = solver.distance(int(np.searchsorted(heat, source)))
    d_root = d_heat[to_heat] + np.linalg.norm(g.points - g.points[heat][to_heat], axis=1)
    timings["distance_root"] = time.perf_counter() - t

    t = time.perf_counter()
    raw = tube_mask(g, params)
    sheet = sheet_edges(g, raw, params)
    tube = smooth_mask(sheet, raw)
    thick = piece_thickness(g, None, params)
    stem = rooted_stem(g, tube, d_root, params.attach_link * float(np.median(g.spacing)),
                       max(20, int(params.min_leaf_fraction * g.size)), thick=thick,
                       gap=params.stem_gap * params.stalk_radius, params=params)
    far = far_pieces(g, source, ISLAND_GAP)
    if far.any():
        log.warning("the cloud is disconnected: %d of %d graph points lie more than %.2g plant "
                    "heights from the plant and stay unassigned", int(far.sum()), g.size, ISLAND_GAP)
        sheet = _restrict(sheet, ~far)
        stem = stem & ~far
    found = find_leaves(g, sheet, stem | far, d_root, params, thick=thick)
    found.stem &= ~far
    conf = leaf_confidence(g, found)
    timings["leaves"] = time.perf_counter() - t

    t = time.perf_counter()
    out = _to_gaussians(pts, g, found, conf, reach, d_root, source, inlier)
    timings["labels"] = time.perf_counter() - t
    return out


def _source_node(g: SurfaceGraph, root_point: np.ndarray) -> int:
    """The graph point the root distances start from: the nearest to the root Gaussian within the
    graph's largest connected piece (a root click can land on a stray Gaussian or in a hole)."""
    _, comp = connected_components(g.graph, directed=False)
    main = np.flatnonzero(comp == np.argmax(np.bincount(comp)))
    return int(main[np.argmin(np.linalg.norm(g.points[main] - root_point, axis=1))])


def far_pieces(g: SurfaceGraph, source: int, gap: float) -> np.ndarray:
    """(M,) bool: graph points of pieces farther than ``gap`` from the root's piece (something
    else in the capture, not a piece of the plant cut off by a hole in the sampling)."""
    _, comp = connected_components(g.graph, directed=False)
    main = comp == comp[source]
    far = np.zeros(g.size, bool)
    if main.all():
        return far
    d, _ = cKDTree(g.points[main]).query(g.points[~main], k=1, workers=-1)
    others = np.flatnonzero(~main)
    for c in np.unique(comp[others]):
        sel = comp[others] == c
        if d[sel].min() > gap:
            far[others[sel]] = True
    return far


def _to_gaussians(pts, g: SurfaceGraph, found: BladeLeaves, conf, reach, d_root, root_d, inlier):
    """Step 6: order leaves by base D_r, labels for every Gaussian (nearest domain point), tips,
    bases and the shortest-path tree from the root to every tip."""
    n_leaves = len(found.was_split)
    lab = found.labels
    big = np.where(np.isfinite(d_root), d_root, -np.inf)
    low = np.where(np.isfinite(d_root), d_root, np.inf)
    tips_d, bases_d = np.zeros(n_leaves, np.int64), np.zeros(n_leaves, np.int64)
    for i in range(n_leaves):
        nodes = np.flatnonzero(lab == i + 1)
        tips_d[i] = nodes[np.argmax(big[nodes])]
        bases_d[i] = nodes[np.argmin(low[nodes])]
    order = np.argsort(low[bases_d], kind="stable")
    rank = np.empty(n_leaves, np.int64)
    rank[order] = np.arange(n_leaves)
    relabel = np.concatenate([[0], rank + 1])
    lab_sorted = relabel[lab]
    dn, near = cKDTree(g.points).query(pts, k=1, workers=-1)
    d_all = (d_root[near] + dn) * reach
    d_all[~inlier] = np.inf
    labels = lab_sorted[near].astype(np.int32)
    labels[~inlier] = 0  # a piece cut off from the root (a hole) keeps its leaves
    _, pred = dijkstra(g.graph, indices=root_d, return_predecessors=True)
    nodes, parent = _shortest_path_tree(pred, root_d, tips_d[order])
    return BladeResult(labels=labels, leaf_tip=g.domain[tips_d[order]], leaf_base=g.domain[bases_d[order]],
                       confidence=conf[order], tree_nodes=g.domain[nodes], tree_parent=parent,
                       d_root=d_all)


def _shortest_path_tree(pred: np.ndarray, root: int, tips: np.ndarray):
    """Nodes (domain indices) and parents (indices into the node list, -1 at the root) of the
    union of the shortest paths root -> each tip (tips that cannot be reached are skipped)."""
    pos = {root: 0}
    nodes, parent = [root], [-1]
    for tip in tips.tolist():
        chain = []
        v = tip
        while v >= 0 and v not in pos:
            chain.append(v)
            v = int(pred[v])
        if v < 0:
            continue
        for u in reversed(chain):
            pos[u] = len(nodes)
            nodes.append(u)
            parent.append(pos[v])
            v = u
    return np.asarray(nodes, np.int64), np.asarray(parent, np.int64)
