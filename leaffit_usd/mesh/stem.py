"""Stem generation: smooth swept tubes along a skeleton of the stem Gaussians (paper, "Stem
Generation", extended).

1. **Skeleton.** The stem Gaussians (label 0) are joined in a k-nearest-neighbour graph;
   isolated specks (floaters) are dropped, pieces of the stem separated by a gap are bridged to
   the root's piece. Geodesic distance from the root over that graph is cut into level sets of
   width ``level_width``; every connected piece of a level set is one skeleton node at the
   centroid of its Gaussians (for a tube sampled around its circumference, the centroid lies on
   the axis), linked to the piece of the previous level it touches. Short terminal spurs are
   pruned. Stem Gaussians off every tube of that skeleton (a thin petiole or a branch base
   that the wide level sets of a thick stem swallowed) become extra chains
   (:func:`_missed_tubes`). A branch that shared its parent's level sets past the true fork is
   re-hung where its own direction meets the parent (:func:`continue_branches`). Once the
   tubes are swept, the Gaussians still far outside all of them go through the same chain
   building once more (groups too short for level sets, down to 4 Gaussians, as one node), and
   the tubes are swept again (:func:`_cover_missed`). A terminal tube that explains none of
   the Gaussians (the other tubes hold them) and whose surface stands out of the data (a second
   arc of another tube's surface made into a tube of its own) is dropped
   (:func:`_redundant_tubes`); so is such a tail of a branch tube past its last child
   (:func:`_trim_redundant_tails`). When the capture has too few stem
   Gaussians the segmentation's rootward tree is the skeleton instead (``skeleton="tree"``, the
   paper's).
2. **Streams.** At every junction the child with the longest subtree continues its parent, so
   the main stem is one tube from the root to its top and every branch / petiole one tube
   starting *on its parent's axis* (the junction is continuous: the branch grows out of the
   parent, no sphere lumps), as thick as itself from the start; the part of a branch hidden
   whole inside its parent is cut off (:func:`_seat_branches`).
3. **Smoothing.** Each stream's node centroids (weighted by their Gaussian counts) are
   smoothed by a cubic smoothing spline per coordinate against arc length
   (``scipy.interpolate.make_smoothing_spline``, cut-off ``axis_smoothing`` level widths),
   then resampled with rings every ``ring_spacing`` local radii.
4. **Radii.** Each node's observed radius is the median distance of its Gaussians to the smooth
   axis. Cross-section areas ``a = r^2`` are then solved in one sparse least-squares problem:
   data (each node's observed area, weighted by its Gaussian count) + smoothness along each
   stream + **Leonardo's rule as a regulariser** (``a_parent = sum a_children`` at every
   junction, weight ``leonardo_weight``); a node without data takes the Leonardo/tapering prior
   of the tree (module functions :func:`leonardo_radii`, below). Rows are relative (divided by
   the local area), so thin petioles weigh as much as the trunk.
5. **Tubes.** Rings of ``sides`` vertices, rotation-minimising frames (double reflection), an
   open base (``root_cap`` closes it), and a tapered, closed tip at the end of every stream (a petiole at
   its leaf base): the radius rounds off to a point over ``tip_length`` radii.
6. **Colour.** Every vertex takes the mean colour of its nearest stem Gaussians (vertex colours,
   sRGB in [0, 1]; the writer converts to linear ``displayColor``).

The same skeleton is swept at coarser levels of detail (fewer sides, sparser rings) for the
stage's ``LOD`` variant set (:data:`LOD_LEVELS`).

The tree-based Leonardo rule of the paper (:func:`leonardo_radii`): the area of an edge at node
``u`` is ``A = s(t(u)) * n(edge) * pi * r_p**2`` with ``n`` the tips it feeds and ``s``
interpolated from the root scale to 1 at the tips, so it holds exactly at every junction.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh.result import Stem, StemMesh

log = logging.getLogger("leaffit_usd")

DEFAULT_ROOT_RADIUS = 0.01  # working units (plant height 1): used when the capture can't tell
DEFAULT_PETIOLE_RADIUS = 0.003
SKELETONS = ("auto", "gaussians", "tree")
# (sides, ring spacing multiplier) of the coarser levels of detail, after LOD0's own
LOD_LEVELS = ((8, 2.0), (5, 4.0))
# the coverage pass (tubes already swept) takes groups of off-tube Gaussians from this size on:
# four points are the fewest that give a direction beyond their centroid (the first pass, which
# builds the tubes, still wants 8 and level sets)
_SMALL_MIN = 4
# a stream's node whose spread exceeds this multiple of the stream's median holds several tubes
# (the ratio of ``_inside_other_tubes``: 1.5 radii)
_MERGED_SPREAD = 1.5
# a node with fewer Gaussians of its own than this is not circle-fitted next to a junction
# (:func:`recentre_nodes`): 3 points are the fewest that fix a circle
_FEW_OWN = 3


@dataclass
class StemParams:
    """Stem parameters, working units (plant height = 1).

    root_radius, petiole_radius : radius at the root and at the petioles for the tree prior
        (Leonardo's rule); ``None`` = estimated from the capture. With the Gaussian skeleton they
        only fill in where the capture has no Gaussians to measure.
    skeleton : "gaussians" (level sets of the stem Gaussians), "tree" (the segmentation's
        rootward tree, the paper's) or "auto" (Gaussians; the tree when fewer than
        ``min_gaussians`` stem Gaussians are usable)
    level_width : level-set spacing of the Gaussian skeleton (working units)
    neighbours : k of the stem Gaussians' neighbour graph
    min_gaussians : fewest stem Gaussians for the Gaussian skeleton
    prune : terminal spurs shorter than ``prune`` x level_width are dropped
    base_level_ratio : level sets are at least this x the base's radius wide
    reach_level_ratio : ... and this x the median distance of a stem Gaussian to its
        ``neighbours``-th neighbour
    axis_smoothing : the axis spline smooths out wiggles shorter than about 2 pi x this x
        level_width
    leonardo_weight : weight of Leonardo's rule against the measured radii (relative rows)
    smooth_weight : weight of the radius smoothness along a stream
    sides : vertices per ring (LOD0)
    ring_spacing : ring spacing along the axis, multiple of the local radius (clamped to
        [0.25, 2] x level_width)
    tip_length : length of the rounded tip, multiple of the tip radius
    root_cap : close the base with a flat disk (off by default: a potted plant's stem goes into
        the soil, and a disk as wide as a thick base sticks out of the true surface)
    estimate_ball : radius of the neighbourhood used by the tree prior's estimates
    """

    root_radius: float | None = None
    petiole_radius: float | None = None
    skeleton: str = "auto"
    level_width: float = 0.01
    neighbours: int = 10
    min_gaussians: int = 60
    prune: float = 0.5
    axis_smoothing: float = 0.5
    base_level_ratio: float = 0.75
    reach_level_ratio: float = 1.0
    leonardo_weight: float = 1.0
    smooth_weight: float = 1.0
    sides: int = 12
    ring_spacing: float = 1.0
    tip_length: float = 1.5
    root_cap: bool = False
    estimate_ball: float = 0.05

    def validate(self) -> None:
        for name in ("root_radius", "petiole_radius"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive radius (working units) or None", v)
        if self.skeleton not in SKELETONS:
            raise ParameterError("skeleton", " or ".join(SKELETONS), self.skeleton)
        if int(self.sides) < 3:
            raise ParameterError("sides", "an integer >= 3", self.sides)
        if int(self.neighbours) < 2:
            raise ParameterError("neighbours", "an integer >= 2", self.neighbours)
        for name in ("level_width", "ring_spacing", "estimate_ball"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive number", v)
        for name in ("prune", "axis_smoothing", "base_level_ratio", "reach_level_ratio", "leonardo_weight",
                     "smooth_weight", "tip_length"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(name, "a number >= 0", v)


# ---- radius estimates from the capture -------------------------------------------------------
def _cross_section_radius(pts: np.ndarray) -> float | None:
    """Radius of the tube whose surface samples are ``pts`` (M, 3), or None.

    The axis is the points' principal direction; the points are projected onto the plane across
    it and a circle is fitted algebraically (Kasa: least squares on x^2 + y^2 + D x + E y + F = 0),
    which stays unbiased when only part of the circumference was captured (a tube seen from one
    side) — the PCA spread would shrink with the visible arc.
    """
    if len(pts) < 8:
        return None
    c = pts - pts.mean(0)
    w, V = np.linalg.eigh(c.T @ c / len(pts))  # ascending
    if w[2] <= 1.5 * w[1]:  # no clear axis: the ball holds a blob, not a tube
        return None
    q = c @ V[:, :2]  # coordinates across the axis
    A = np.column_stack([q, np.ones(len(q))])
    rhs = -(q ** 2).sum(1)
    (D, E, F), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    r2 = D * D / 4 + E * E / 4 - F
    if not np.isfinite(r2) or r2 <= 0:
        return None
    r = float(np.sqrt(r2))
    spread = float(np.sqrt(w[0] + w[1]))
    # an arc too flat to fit gives a huge circle: fall back to the spread then
    return r if r < 4 * spread + 1e-12 else spread


def estimate_radii(seg, points_working: np.ndarray, ball: float = 0.05) -> tuple[float | None, float | None]:
    """(root_radius, petiole_radius) from the stem Gaussians, or None where unknown.

    Root: a circle fitted across the axis of the stem Gaussians (label 0) within ``ball`` of the
    root. Petiole: median over leaves of the same figure for the stem Gaussians within
    ``0.4 ball`` of each leaf's petiole base (the petiole; the blade's own Gaussians would
    measure the blade).
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points_working, np.float64)
    labels = np.asarray(seg.labels)
    if len(pts) == 0:
        return None, None
    tree = cKDTree(pts)
    root_r = None
    if 0 <= int(seg.root_index) < len(pts):
        for b in (ball, 2 * ball, 0.5 * ball):  # a thick or short base needs another ball
            near = np.asarray(tree.query_ball_point(pts[int(seg.root_index)], b), np.int64)
            near = near[labels[near] == 0]
            root_r = _cross_section_radius(pts[near])
            if root_r is not None:
                break
    pet = []
    for base in np.asarray(seg.leaf_base, np.int64):
        if not 0 <= base < len(pts):
            continue
        near = np.asarray(tree.query_ball_point(pts[base], 0.4 * ball), np.int64)
        near = near[labels[near] == 0]
        r = _cross_section_radius(pts[near])
        if r is not None:
            pet.append(r)
    pet_r = float(np.median(pet)) if pet else None
    return root_r, pet_r


def _resolve_radii(params: StemParams, seg, points_working, fits) -> tuple[float, float]:
    root_r, pet_r = params.root_radius, params.petiole_radius
    if root_r is None or pet_r is None:
        est_root, est_pet = estimate_radii(seg, points_working, params.estimate_ball)
        if root_r is None:
            if est_root is None:
                log.warning("stem: too few stem Gaussians near the root to estimate its radius; "
                            "using %.4g (working units)", DEFAULT_ROOT_RADIUS)
                est_root = DEFAULT_ROOT_RADIUS
            # a noisy capture spreads Gaussians: keep the estimate within plausible bounds
            root_r = float(np.clip(est_root, 0.002, 0.05))
        if pet_r is None:
            if est_pet is None:
                log.warning("stem: cannot estimate the petiole radius from the capture; using %.4g",
                            min(DEFAULT_PETIOLE_RADIUS, root_r))
                est_pet = DEFAULT_PETIOLE_RADIUS
            pet_r = float(np.clip(est_pet, 0.001, 0.02))
            pet_r = min(pet_r, root_r)
    return float(root_r), float(pet_r)


# ---- tree -> stem edges and radii ---------------------------------------------------------------
def stem_edges(seg) -> tuple[np.ndarray, np.ndarray]:
    """Edges of the tree that are not inside a leaf: (child, parent) indices into tree_nodes.

    An edge is inside a leaf when both its nodes carry the same leaf label; the edge from the
    last stem node to the first node of a leaf (the petiole attachment) is kept.
    """
    par = np.asarray(seg.tree_parent, np.int64)
    leaf = np.asarray(seg.tree_leaf, np.int64)
    child = np.flatnonzero(par >= 0)
    p = par[child]
    inside = (leaf[child] != 0) & (leaf[child] == leaf[p])
    return child[~inside], p[~inside]


def leonardo_radii(seg, points_working, root_radius: float, petiole_radius: float):
    """Per stem edge: (child, parent, r_at_parent_end, r_at_child_end, n_tips, t_parent, t_child).

    Radii in working units; see the module docstring for the rule.
    """
    pts = np.asarray(points_working, np.float64)[np.asarray(seg.tree_nodes, np.int64)]
    child, parent = stem_edges(seg)
    S = len(pts)
    if len(child) == 0:
        z = np.zeros(0)
        return child, parent, z, z, z.astype(np.int64), z, z
    # children lists inside the stem forest
    kids: dict[int, list[int]] = {}
    for c, p in zip(child.tolist(), parent.tolist()):
        kids.setdefault(p, []).append(c)
    in_stem = np.zeros(S, bool)
    in_stem[child] = True
    in_stem[parent] = True
    has_parent = np.zeros(S, bool)
    has_parent[child] = True
    roots = np.flatnonzero(in_stem & ~has_parent)
    # order: BFS from the forest roots
    order = []
    stack = list(roots.tolist())
    while stack:
        u = stack.pop()
        order.append(u)
        stack.extend(kids.get(u, []))
    order = np.asarray(order, np.int64)
    par_of = np.full(S, -1, np.int64)
    par_of[child] = parent
    # d: path length from the forest root (plus the root's own tree depth when not the plant root)
    d = np.zeros(S)
    for u in order:
        p = par_of[u]
        if p >= 0:
            d[u] = d[p] + np.linalg.norm(pts[u] - pts[p])
    # n_tips and h (longest path to a tip below), leaves-first
    n = np.zeros(S, np.int64)
    h = np.zeros(S)
    for u in order[::-1]:
        ks = kids.get(int(u), [])
        if not ks:
            n[u] = 1
            h[u] = 0.0
        else:
            n[u] = sum(int(n[k]) for k in ks)
            h[u] = max(h[k] + np.linalg.norm(pts[k] - pts[u]) for k in ks)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(d + h > 0, d / (d + h), 1.0)
    n_root = max(int(n[roots].max()), 1)
    s_root = root_radius ** 2 / (n_root * petiole_radius ** 2)
    s = s_root + (1.0 - s_root) * t
    a_p = petiole_radius ** 2  # (pi cancels)
    # edge (c -> p) feeds n[c] tips; its radius at either end uses that end's scale
    r_parent_end = np.sqrt(s[parent] * n[child] * a_p)
    r_child_end = np.sqrt(s[child] * n[child] * a_p)
    return child, parent, r_parent_end, r_child_end, n[child], t[parent], t[child]


# ---- skeleton ---------------------------------------------------------------------------------
@dataclass
class Skeleton:
    """A rooted tree of axis nodes, working frame.

    pos : (n, 3) float64 node positions; parent : (n,) int64, -1 at the root (node 0)
    count : (n,) int64, Gaussians measured at each node (0 = no data: tree skeleton)
    members : (M,) int64 point indices that make up the nodes; member_node : (M,) their node
    spread : (n,) float64, median distance of a node's Gaussians to its centroid (~ the local
        radius; 0 without data)
    """

    pos: np.ndarray
    parent: np.ndarray
    count: np.ndarray
    members: np.ndarray
    member_node: np.ndarray
    spread: np.ndarray | None = None
    graph: "_GraphContext | None" = None

    def __post_init__(self):
        if self.spread is None:
            self.spread = np.zeros(len(self.pos))

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in range(len(self.pos))]
        for c, p in enumerate(self.parent.tolist()):
            if p >= 0:
                kids[p].append(c)
        return kids


@dataclass
class _GraphContext:
    """What the Gaussian skeleton was cut from, kept for the coverage pass: idx (M,) the stem
    Gaussians' indices (sorted), G (M, M) their bridged neighbour graph, g (M,) geodesic distance
    from the base (inf: unreached), w_thin the level width of the thin tubes."""

    idx: np.ndarray
    G: object
    g: np.ndarray
    w_thin: float


def _neighbour_graph(P: np.ndarray, k: int):
    """Symmetric kNN graph (CSR, edge weight = length) and the length beyond which edges are cut."""
    from scipy.sparse import coo_matrix
    from scipy.spatial import cKDTree

    M = len(P)
    k = min(k, M - 1)
    d, j = cKDTree(P).query(P, k=k + 1)
    d, j = d[:, 1:], j[:, 1:]
    gap = 3.0 * float(np.median(d[:, -1]))
    rows = np.repeat(np.arange(M), k)
    w, cols = d.ravel(), j.ravel()
    ok = (w <= gap) & (w > 0)
    A = coo_matrix((w[ok], (rows[ok], cols[ok])), shape=(M, M)).tocsr()
    return A.maximum(A.T).tocoo(), gap


def _bridged_graph(P: np.ndarray, root_point: np.ndarray | None, params: StemParams):
    """The stem Gaussians' neighbour graph (CSR, edge weight = length) with every sizeable piece
    bridged to the root's piece (closest pair first; specks stay apart), the index of the
    Gaussian nearest the root (the lowest one without a root point) and the median distance to
    the k-th neighbour (the graph's reach: the capture's sampling)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    M = len(P)
    A, gap = _neighbour_graph(P, int(params.neighbours))
    ncomp, comp = connected_components(A, directed=False)
    r0 = int(np.argmin(np.linalg.norm(P - root_point, axis=1))) if root_point is not None \
        else int(np.argmin(P[:, 2]))
    sizes = np.bincount(comp, minlength=ncomp)
    min_piece = max(20, int(0.002 * M))
    rows, cols, vals = [A.row], [A.col], [A.data]
    joined = comp == comp[r0]
    others = [c for c in np.argsort(-sizes) if c != comp[r0] and sizes[c] >= min_piece]
    while others:
        tree = cKDTree(P[joined])
        jidx = np.flatnonzero(joined)
        best = None
        for c in others:
            ci = np.flatnonzero(comp == c)
            dd, jj = tree.query(P[ci])
            m = int(np.argmin(dd))
            if best is None or dd[m] < best[0]:
                best = (float(dd[m]), c, int(ci[m]), int(jidx[jj[m]]))
        dist, c, a, b = best
        rows.append(np.array([a, b]))
        cols.append(np.array([b, a]))
        vals.append(np.array([max(dist, 1e-9)] * 2))
        joined |= comp == c
        others.remove(c)
    G = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(M, M)).tocsr()
    return G, r0, gap / 3.0


def _base_sources(P: np.ndarray, G, r0: int, w: float) -> np.ndarray:
    """Indices of the root's piece of the lowest slab (``w`` thick): the base's whole ring, not
    one point on it (geodesic level sets from a point on a thick stem's surface would be arcs,
    not rings)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = len(P)
    Gc = G.tocoo()
    slab = P[:, 2] <= P[r0, 2] + w
    in_slab = slab[Gc.row] & slab[Gc.col]
    _, slab_lab = connected_components(coo_matrix((np.ones(int(in_slab.sum())),
                                                   (Gc.row[in_slab], Gc.col[in_slab])), shape=(M, M)),
                                       directed=False)
    return np.flatnonzero(slab & (slab_lab == slab_lab[r0]))


def _level_pieces(P: np.ndarray, G, level: np.ndarray, ok: np.ndarray):
    """Connected pieces of the level sets: (piece label per reached Gaussian (R,), the reached
    Gaussians' indices (R,), node count n)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = len(P)
    Gc = G.tocoo()
    e_i, e_j = Gc.row, Gc.col
    same = (level[e_i] == level[e_j]) & ok[e_i] & ok[e_j]
    _, lab = connected_components(coo_matrix((np.ones(int(same.sum())), (e_i[same], e_j[same])),
                                             shape=(M, M)), directed=False)
    lab = np.where(ok, lab, -1)
    uniq, lab = np.unique(lab[ok], return_inverse=True)
    return lab, np.flatnonzero(ok), len(uniq)


def _piece_parents(G, node_of: np.ndarray, node_level: np.ndarray, pos: np.ndarray,
                   root: int) -> np.ndarray:
    """(n,) parent of each level-set piece: the piece of a lower level it touches most
    (preferring the previous level); a piece touching none hangs from the nearest lower one."""
    Gc = G.tocoo()
    n = len(pos)
    a, b = node_of[Gc.row], node_of[Gc.col]
    down = (a >= 0) & (b >= 0) & (node_level[b] < node_level[a])
    parent = np.full(n, -1, np.int64)
    if down.any():
        ca, cb = a[down], b[down]
        key = ca * n + cb
        uk, cnt = np.unique(key, return_counts=True)
        ch, pa = uk // n, uk % n
        prev = (node_level[pa] == node_level[ch] - 1).astype(np.int64)
        order = np.lexsort((-cnt, -prev, ch))
        first = np.r_[True, ch[order][1:] != ch[order][:-1]]
        parent[ch[order][first]] = pa[order][first]
    parent[root] = -1
    for u in np.flatnonzero((parent < 0) & (np.arange(n) != root)):  # touches no lower piece
        lower = np.flatnonzero(node_level < node_level[u])
        parent[u] = lower[np.argmin(np.linalg.norm(pos[lower] - pos[u], axis=1))] if len(lower) else root
    return parent


def gaussian_skeleton(points: np.ndarray, labels: np.ndarray, root_index: int,
                      params: StemParams) -> Skeleton | None:
    """Level-set skeleton of the stem Gaussians (label 0), or None when there are too few.

    points : (N, 3) working frame; labels : (N,) segmentation labels; root_index : the root
    Gaussian. See the module docstring (step 1).
    """
    from scipy.sparse.csgraph import dijkstra

    idx = np.flatnonzero(np.asarray(labels) == 0)
    if len(idx) < max(int(params.min_gaussians), 4):
        return None
    P = points[idx]
    M = len(P)
    root_point = points[int(root_index)] if 0 <= int(root_index) < len(points) else None
    G, r0, reach = _bridged_graph(P, root_point, params)
    w = float(params.level_width)
    sources = _base_sources(P, G, r0, w)
    ring = P[sources, :2]
    base_r = float(np.median(np.linalg.norm(ring - ring.mean(0), axis=1))) if len(sources) > 3 else 0.0
    # level sets no thinner than the base is wide (thin slabs of a thick stem break into arcs),
    # nor than the neighbour graph's reach (on a sparse capture a thinner slab's pieces are a
    # few Gaussians each: the nodes zigzag and spurious forks appear inside one tube)
    w = max(w, float(params.base_level_ratio) * base_r, float(params.reach_level_ratio) * reach)
    g = dijkstra(G, directed=False, indices=sources, min_only=True)
    ok = np.isfinite(g)
    if ok.sum() < max(int(params.min_gaussians), 4):
        return None
    level = np.where(ok, np.floor(np.where(ok, g, 0) / w), -1).astype(np.int64)
    lab, pts_ok, n = _level_pieces(P, G, level, ok)
    count = np.bincount(lab, minlength=n)
    pos = np.stack([np.bincount(lab, weights=P[pts_ok, k], minlength=n) for k in range(3)], 1) / count[:, None]
    node_level = np.zeros(n, np.int64)
    node_level[lab] = level[pts_ok]
    node_of = np.full(M, -1, np.int64)
    node_of[pts_ok] = lab
    root = int(node_of[r0])
    parent = _piece_parents(G, node_of, node_level, pos, root)
    dist = np.linalg.norm(P[pts_ok] - pos[lab], axis=1)
    order = np.lexsort((dist, lab))
    starts = np.searchsorted(lab[order], np.arange(n))
    spread = dist[order][np.minimum(starts + count // 2, len(order) - 1)]
    sk = Skeleton(pos=pos, parent=parent, count=count.astype(np.int64),
                  members=idx[pts_ok], member_node=lab.astype(np.int64), spread=spread)
    sk = _reroot(sk, root)
    sk = recentre_nodes(sk, points)
    sk = centre_junctions(prune_spurs(sk, float(params.prune) * w))
    # the missed tubes are thin: their level sets need not be as wide as the base, only as the
    # graph's reach
    w_thin = max(float(params.level_width), float(params.reach_level_ratio) * reach)
    sk = _missed_tubes(sk, points, idx, G, g, params, w_thin)
    sk = continue_branches(sk, w)
    sk.graph = _GraphContext(idx=idx, G=G, g=g, w_thin=w_thin)
    return sk


def _skeleton_residual(sk: Skeleton, q: np.ndarray) -> np.ndarray:
    """(M,) distance of points q (M, 3) outside the skeleton's tubes: distance to the nearest
    parent -> child segment minus the radius (``spread``, linear along the segment) there;
    negative inside."""
    from scipy.spatial import cKDTree

    c = np.flatnonzero(sk.parent >= 0)
    a, b = sk.pos[sk.parent[c]], sk.pos[c]
    ra, rb = sk.spread[sk.parent[c]], sk.spread[c]
    k = min(8, len(c))
    _, cand = cKDTree(0.5 * (a + b)).query(q, k=k)
    cand = cand.reshape(len(q), k)
    ab = b[cand] - a[cand]                                   # (M, k, 3)
    L2 = np.maximum((ab * ab).sum(2), 1e-30)
    u = np.clip(((q[:, None, :] - a[cand]) * ab).sum(2) / L2, 0.0, 1.0)
    d = np.linalg.norm(q[:, None, :] - (a[cand] + u[..., None] * ab), axis=2)
    r = ra[cand] + u * (rb[cand] - ra[cand])
    return (d - r).min(1)


def _missed_tubes(sk: Skeleton, points: np.ndarray, idx: np.ndarray, G, g: np.ndarray,
                  params: StemParams, w0: float | None = None, off: np.ndarray | None = None,
                  add_only: bool = False) -> Skeleton:
    """Thin tubes the level sets swallowed, added as branches.

    Level sets as wide as a thick stem (``base_level_ratio``) do not separate a thin petiole that
    leaves it at a shallow angle, nor the base of a branch that runs alongside its parent before
    it diverges: those Gaussians end up in the thick stem's level-set pieces, whose circle fit
    ignores them, and no tube covers them. Here the stem Gaussians lying off every skeleton tube
    (farther outside than a quarter of ``w0`` and than three times the robust spread of all the
    Gaussians' offsets), or deep inside one (within half its radius of the axis: the hidden base
    of a branch that starts inside its parent), are joined in the neighbour graph; every piece of
    at least 8 of them spanning at least ``w0`` is cut into level sets of the same geodesic
    distance ``g``, ``w0`` wide, and becomes a chain of nodes hanging from the nearest skeleton
    node, its Gaussians moved to the new nodes, which are then moved onto their tube's axis
    (:func:`recentre_nodes`). A piece that ends at the start of a branch is that branch's base
    instead: the branch's junction moves down to the piece's lower end.

    points : (N, 3) all Gaussians; idx : (M,) the stem Gaussians' indices into points (sorted);
    G : (M, M) their neighbour graph; g : (M,) geodesic distance from the base (inf: unreached);
    w0 : level width of the thin tubes (default ``level_width``; wider on a sparse capture).
    off : (len(sk.members),) bool, the members to treat as off the tubes (default: those off the
    skeleton's own tubes, :func:`_off_tubes`).
    add_only : the chains are only added (no branch is re-hung) and their Gaussians are copied
    to the new nodes, not moved (the coverage pass on swept tubes: the existing tubes keep their
    measurements and ends).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(sk.pos) < 2 or not len(sk.members):
        return sk
    w0 = float(params.level_width) if w0 is None else float(w0)
    M = len(idx)
    loc = np.searchsorted(idx, sk.members)                     # member slot -> row of G
    flag = np.zeros(M, bool)
    flag[loc[_off_tubes(sk, points[sk.members], w0) if off is None else off]] = True
    if flag.sum() < (_SMALL_MIN if add_only else 8):
        return sk
    Gc = G.tocoo()
    e = flag[Gc.row] & flag[Gc.col]
    _, comp = connected_components(coo_matrix((np.ones(int(e.sum())), (Gc.row[e], Gc.col[e])),
                                              shape=(M, M)), directed=False)
    row_of = np.full(M, -1, np.int64)
    row_of[loc] = np.arange(len(loc))                          # row of G -> member slot
    n0 = len(sk.pos)
    kids = sk.children()
    starts = np.asarray([c for u in range(n0) if len(kids[u]) > 1 for c in kids[u]], np.int64)
    grow = dict(pos=list(sk.pos), par=list(sk.parent), cnt=list(sk.count), spr=list(sk.spread),
                member_node=sk.member_node.copy())
    rows_off = np.flatnonzero(flag)
    extra_members, extra_nodes = [], []
    for c in np.unique(comp[rows_off]):
        rows = rows_off[comp[rows_off] == c]
        if not np.isfinite(g[rows]).all():
            continue
        ch = _piece_chain(rows, g, Gc, points[idx[rows]], w0) if len(rows) >= 8 else None
        if ch is None and add_only and len(rows) >= _SMALL_MIN:
            ch = _single_chain(points[idx[rows]])
        if ch is None:
            continue  # a patch, not a tube
        if add_only:
            extra_members.append(idx[rows])
            extra_nodes.append(_append_chain(grow, ch, None, sk.member_node))
        elif not _joins_branch(grow, ch, starts, n0, w0):
            _append_chain(grow, ch, row_of[rows], sk.member_node)
    if len(grow["pos"]) == n0 and (np.asarray(grow["par"]) == sk.parent).all():
        return sk
    pos = np.asarray(grow["pos"])
    out = Skeleton(pos=pos, parent=np.asarray(grow["par"], np.int64), count=np.asarray(grow["cnt"], np.int64),
                   members=np.concatenate([sk.members] + extra_members),
                   member_node=np.concatenate([grow["member_node"]] + extra_nodes), spread=np.asarray(grow["spr"]))
    new = np.zeros(len(pos), bool)
    new[n0:] = True
    return _reroot(recentre_nodes(out, points, only=new), 0)


def _off_tubes(sk: Skeleton, q: np.ndarray, w0: float) -> np.ndarray:
    """(M,) bool: the skeleton's member Gaussians q (M, 3) off every tube's surface, outside it
    (farther than a quarter of ``w0`` and than three robust standard deviations of all the
    offsets) or deep inside it (the hidden base of a branch that starts inside its parent, when
    the capture has Gaussians there)."""
    res = _skeleton_residual(sk, q)
    tau = max(3.0 * 1.4826 * float(np.median(np.abs(res))), 0.25 * w0)
    return (res > tau) | (res < -np.maximum(0.5 * sk.spread[sk.member_node], tau))


@dataclass
class _Chain:
    """Level-set pieces of a group of off-tube Gaussians: rows (R,) of the neighbour graph,
    piece (R,) of each, centroids cen (k, 3), counts n (k,), levels lvl (k,), the lower piece
    each hangs from (k,) (-1: the skeleton), the Gaussians q (R, 3)."""

    piece: np.ndarray
    cen: np.ndarray
    n: np.ndarray
    lvl: np.ndarray
    par: np.ndarray
    q: np.ndarray


def _piece_chain(rows: np.ndarray, g: np.ndarray, Gc, q: np.ndarray, w0: float) -> _Chain | None:
    """The group's level sets ``w0`` wide on the geodesic distance ``g``, their connected pieces
    and which lower piece each touches most; None when the centroids span less than ``w0``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = len(g)
    level = np.floor(g[rows] / w0).astype(np.int64)
    sub = np.zeros(M, bool)
    sub[rows] = True
    lvl = np.full(M, -1, np.int64)
    lvl[rows] = level
    same = sub[Gc.row] & sub[Gc.col] & (lvl[Gc.row] == lvl[Gc.col])
    _, plab = connected_components(coo_matrix((np.ones(int(same.sum())), (Gc.row[same], Gc.col[same])),
                                              shape=(M, M)), directed=False)
    uniq, piece = np.unique(plab[rows], return_inverse=True)
    k = len(uniq)
    n_p = np.bincount(piece, minlength=k)
    cen = np.stack([np.bincount(piece, weights=q[:, j], minlength=k) for j in range(3)], 1) / n_p[:, None]
    if k < 2 or float(np.linalg.norm(cen.max(0) - cen.min(0))) < w0:
        return None
    p_lvl = np.zeros(k, np.int64)
    p_lvl[piece] = level
    pc = np.full(M, -1, np.int64)
    pc[rows] = piece
    ee = sub[Gc.row] & sub[Gc.col]
    a_, b_ = pc[Gc.row[ee]], pc[Gc.col[ee]]
    down = p_lvl[b_] < p_lvl[a_]
    p_par = np.full(k, -1, np.int64)
    if down.any():
        key, cn = np.unique(a_[down] * k + b_[down], return_counts=True)
        o = np.lexsort((-cn, key // k))
        first = np.r_[True, (key // k)[o][1:] != (key // k)[o][:-1]]
        p_par[(key // k)[o][first]] = (key % k)[o][first]
    return _Chain(piece=piece, cen=cen, n=n_p, lvl=p_lvl, par=p_par, q=q)


def _single_chain(q: np.ndarray) -> _Chain:
    """A group of off-tube Gaussians too short for level sets (fewer than 8, or spanning less
    than a level width: a tube's last piece past a fork, the end of one of two touching
    petioles) as one node at its centroid: it hangs from the nearest node and, once swept,
    becomes a short tube from there that reaches its farthest Gaussian."""
    return _Chain(piece=np.zeros(len(q), np.int64), cen=q.mean(0)[None], n=np.array([len(q)]),
                  lvl=np.zeros(1, np.int64), par=np.full(1, -1, np.int64), q=q)


def _joins_branch(grow: dict, ch: _Chain, starts: np.ndarray, n0: int, w0: float) -> bool:
    """A chain that ends at the start of a branch (one of ``starts``, nodes < n0) is that
    branch's base, which ran alongside its parent inside the parent's level sets: the branch is
    re-hung from the skeleton node nearest the chain's lowest end (its first segment then
    follows the chain). True when done."""
    if not len(starts):
        return False
    pos, par, spr = np.asarray(grow["pos"][:n0]), grow["par"], grow["spr"]
    top, low = ch.cen[int(np.argmax(ch.lvl))], ch.cen[int(np.argmin(ch.lvl))]
    d_st = np.linalg.norm(pos[starts] - top, axis=1)
    v = int(starts[np.argmin(d_st)])
    if d_st.min() > 2.0 * w0 + spr[v]:
        return False
    a = int(np.argmin(np.linalg.norm(pos - low, axis=1)))
    u = a
    while u >= 0 and u != v:
        u = int(par[u])
    if u == v or a == par[v]:  # a in v's subtree: re-hanging would make a cycle
        return False
    par[v] = a
    return True


def _append_chain(grow: dict, ch: _Chain, slots: np.ndarray | None, member_node0: np.ndarray) -> np.ndarray:
    """Add the chain's pieces as nodes (in level order), the lowest hanging from the nearest
    node; their Gaussians (member ``slots``) move to them. ``slots`` None: nothing moves (the
    caller adds the Gaussians as new members). Returns (R,) the new node of each of the chain's
    Gaussians."""
    base = len(grow["pos"])
    old = np.asarray(grow["pos"])
    k = len(ch.cen)
    order = np.argsort(ch.lvl, kind="stable")
    new_id = np.empty(k, np.int64)
    new_id[order] = base + np.arange(k)
    for i in order:
        grow["par"].append(int(new_id[ch.par[i]]) if ch.par[i] >= 0 else
                           int(np.argmin(np.linalg.norm(old - ch.cen[i], axis=1))))
        grow["pos"].append(ch.cen[i])
        grow["cnt"].append(int(ch.n[i]))
        grow["spr"].append(float(np.median(np.linalg.norm(ch.q[ch.piece == i] - ch.cen[i], axis=1))))
    if slots is None:
        return new_id[ch.piece]
    grow["member_node"][slots] = new_id[ch.piece]
    cnt_old = np.bincount(member_node0[slots], minlength=base)
    for u in np.flatnonzero(cnt_old):
        grow["cnt"][u] = max(int(grow["cnt"][u]) - int(cnt_old[u]), 0)
    return new_id[ch.piece]


def _kasa_circle(q: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """Algebraic circle fit (Kasa) of 2-D points q (M, 2), refitted once without the points
    farther than 30 % of the radius from the circle: (centre (2,), radius, median
    |distance - radius| / radius over all points), or None when degenerate."""
    use = np.ones(len(q), bool)
    for _ in range(2):
        if use.sum() < 6:
            return None
        A = np.column_stack([q[use], np.ones(int(use.sum()))])
        (D, E, F), *_ = np.linalg.lstsq(A, -(q[use] ** 2).sum(1), rcond=None)
        r2 = D * D / 4 + E * E / 4 - F
        if not np.isfinite(r2) or r2 <= 0:
            return None
        c = np.array([-D / 2, -E / 2])
        r = float(np.sqrt(r2))
        dev = np.abs(np.linalg.norm(q - c, axis=1) - r)
        use = dev <= 0.3 * r
    return c, r, float(np.median(dev)) / r


def recentre_nodes(sk: Skeleton, points: np.ndarray, rounds: int = 2,
                   only: np.ndarray | None = None) -> Skeleton:
    """Nodes moved onto their tube's axis, ``spread`` set to the tube's radius there.

    A level-set piece of a tube reached from its side (a petiole leaving its stem, a sparse
    capture) is an arc, not a ring: its centroid lies near the surface, and a smoothed axis
    through such centroids measures radii too small. Each node takes the centre of a circle fitted
    (Kasa, algebraic, unbiased on a partial arc) to its own and its neighbours' Gaussians,
    projected across the local axis direction (parent -> child). Junctions and blobs, where the
    Gaussians are no circle (median misfit above 25 % of the radius, a radius beyond 3x the
    node's spread, a centre farther than 2x the spread), keep their centroid. So does a node
    with fewer than ``_FEW_OWN`` Gaussians of its own next to a junction: the junction's
    Gaussians are of several tubes, and with so few of its own nothing holds the circle to the
    node's tube (pothos_sh3: a 2-Gaussian node of a thin branch leaving the vine was fitted to
    the vine's junction and moved 0.012 off its branch, whose tube then ran 0.02 off the true
    one, HD 0.26). ``only`` (n,) bool:
    move just those nodes, fitted to their own and their neighbours among them (None: all).
    """
    n = len(sk.pos)
    if n < 2 or not len(sk.members):
        return sk
    kids = sk.children()
    order = np.argsort(sk.member_node, kind="stable")
    starts = np.searchsorted(sk.member_node[order], np.arange(n + 1))
    own = [sk.members[order[starts[u]:starts[u + 1]]] for u in range(n)]
    pos, spread = sk.pos.copy(), sk.spread.copy()
    for _ in range(rounds):
        new_pos, new_spread = pos.copy(), spread.copy()
        for u in (range(n) if only is None else np.flatnonzero(only)):
            p = int(sk.parent[u])
            nb = [u] + ([p] if p >= 0 else []) + kids[u]
            if only is not None:  # the other nodes' Gaussians are of other tubes
                nb = [k for k in nb if only[k]]
            a = pos[p] if p >= 0 else pos[u]
            b = np.mean([pos[k] for k in kids[u]], axis=0) if kids[u] else pos[u]
            t = b - a
            if np.linalg.norm(t) < 1e-12:
                continue
            t = t / np.linalg.norm(t)
            Q = points[np.concatenate([own[k] for k in nb])]
            if len(Q) < 8 or (len(own[u]) < _FEW_OWN and any(len(kids[k]) > 1 for k in nb[1:])):
                continue
            e1 = np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(t, e1)
            fit = _kasa_circle((Q - pos[u]) @ np.stack([e1, e2], 1))
            if fit is None:
                continue
            c, r, misfit = fit
            ref = max(float(sk.spread[nb].max()), 1e-9)
            if misfit > 0.25 or r > 3 * ref or np.linalg.norm(c) > 2 * ref:
                continue
            new_pos[u] = pos[u] + c[0] * e1 + c[1] * e2
            new_spread[u] = r
        pos, spread = new_pos, new_spread
    return Skeleton(pos=pos, parent=sk.parent, count=sk.count, members=sk.members,
                    member_node=sk.member_node, spread=spread)


def _chain_up(sk: Skeleton, kids: list[list[int]], c: int, length: float) -> list[int] | None:
    """Nodes from ``c`` along its single-child descendants within ``length`` of ``c`` (along
    the chain), or None when the chain ends (a tip or a fork) before it is that long."""
    out, u, run = [c], c, 0.0
    while len(kids[u]) == 1:
        v = kids[u][0]
        run += float(np.linalg.norm(sk.pos[v] - sk.pos[u]))
        if run > length:
            return out
        out.append(v)
        u = v
    return None


def continue_branches(sk: Skeleton, w: float, min_angle: float = 25.0) -> Skeleton:
    """Branches re-hung where their own direction meets their parent (direction continuity).

    A thin branch leaving a thicker tube shares the thicker one's level-set pieces for a while
    (slabs as wide as the thick tube, or as the graph's reach on a sparse capture): its chain
    starts at a junction above the true fork, the junction's centroid mixes both tubes, and the
    branch's first segment runs back down to it (a detour off both tubes). The branch's first
    ``4 w`` (level width ``w``), when it runs that far without forking, give a line (principal
    direction of its nodes); extended backwards it meets the parent's axis where the branch
    really leaves. The branch then hangs from the ancestor of its junction (within ``4 w`` down
    the parent) nearest that line, when that ancestor lies on the line (within its radius,
    ``spread``, and within half the junction's own distance to the line). Only branches leaving
    at more than ``min_angle`` degrees from the parent's direction: the parent's continuation is
    collinear with every node below the junction and stays where it is.

    sk : the skeleton (working frame); returns a new one (BFS order), or ``sk`` unchanged.
    """
    n = len(sk.pos)
    if n < 4:
        return sk
    kids = sk.children()
    par = sk.parent.copy()
    cos_max = np.cos(np.radians(min_angle))
    for j in range(n):
        if len(kids[j]) < 2 or sk.parent[j] < 0:
            continue
        down = [j]  # j and its ancestors within 4 w
        run, u = 0.0, j
        while sk.parent[u] >= 0 and run <= 4.0 * w:
            run += float(np.linalg.norm(sk.pos[u] - sk.pos[sk.parent[u]]))
            u = int(sk.parent[u])
            down.append(u)
        if len(down) < 2:
            continue
        t_par = sk.pos[j] - sk.pos[down[-1]]
        if np.linalg.norm(t_par) < 1e-12:
            continue
        t_par /= np.linalg.norm(t_par)
        for c in kids[j]:
            chain = _chain_up(sk, kids, c, 4.0 * w)
            if chain is None or len(chain) < 3:
                continue
            P = sk.pos[chain]
            cen = P.mean(0)
            d = np.linalg.svd(P - cen)[2][0]
            if d @ (P[-1] - P[0]) < 0:
                d = -d
            if abs(float(d @ t_par)) > cos_max:
                continue
            rel = sk.pos[down] - P[0]
            t = rel @ d
            dist = np.linalg.norm(rel - t[:, None] * d, axis=1)
            dist = np.where(t < 0, dist, np.inf)  # behind the branch's start only
            k = int(np.argmin(dist))
            a = down[k]
            if k == 0 or not np.isfinite(dist[k]) or dist[k] > sk.spread[a] or dist[k] > 0.5 * dist[0]:
                continue
            par[c] = a
    if (par == sk.parent).all():
        return sk
    return _reroot(Skeleton(pos=sk.pos, parent=par, count=sk.count, members=sk.members,
                            member_node=sk.member_node, spread=sk.spread), 0)


def centre_junctions(sk: Skeleton) -> Skeleton:
    """A junction's centroid is pulled towards its branches (its Gaussians are of several
    tubes): each junction moves halfway between its parent and its widest child (the parent
    tube's continuation)."""
    kids = sk.children()
    pos = sk.pos.copy()
    for u in range(len(pos)):
        p = int(sk.parent[u])
        if len(kids[u]) > 1 and p >= 0:
            k = max(kids[u], key=lambda c: sk.spread[c])
            pos[u] = 0.5 * (pos[p] + pos[k])
    return Skeleton(pos=pos, parent=sk.parent, count=sk.count, members=sk.members,
                    member_node=sk.member_node, spread=sk.spread)


def _reroot(sk: Skeleton, root: int) -> Skeleton:
    """Renumber the nodes reachable from ``root`` in BFS order (root = node 0); drop the rest."""
    kids = sk.children()
    order, head = [root], 0
    while head < len(order):
        order.extend(kids[order[head]])
        head += 1
    order = np.asarray(order, np.int64)
    new = np.full(len(sk.pos), -1, np.int64)
    new[order] = np.arange(len(order))
    par = np.where(sk.parent[order] >= 0, new[np.maximum(sk.parent[order], 0)], -1)
    par[0] = -1
    mem = new[sk.member_node] >= 0
    return Skeleton(pos=sk.pos[order], parent=par, count=sk.count[order],
                    members=sk.members[mem], member_node=new[sk.member_node[mem]],
                    spread=sk.spread[order])


def prune_spurs(sk: Skeleton, min_length: float, min_count: int = 8) -> Skeleton:
    """Drop terminal chains (tip up to, not including, the first junction) shorter than
    ``min_length`` or, on a measured skeleton, made of fewer than ``min_count`` Gaussians (a
    level-set piece of a few stray Gaussians is not a branch); their Gaussians go to the
    junction node. Repeated until nothing changes."""
    if len(sk.pos) < 3:
        return sk
    measured = bool(sk.count.any())
    while True:
        nxt = _prune_once(sk, min_length, min_count, measured)
        if len(nxt.pos) == len(sk.pos):
            return nxt
        sk = nxt


def _inside_other_tubes(sk: Skeleton, chain: list[int], junction: int, keep: np.ndarray,
                        ratio: float = 1.5) -> bool:
    """True when every node of ``chain`` lies within ``ratio`` x the radius (``spread``) of the
    nearest kept node outside the chain other than its ``junction`` (whose Gaussians, from
    several tubes, give no radius)."""
    other = keep.copy()
    other[chain] = False
    other[junction] = False
    if not other.any():
        return False
    cand = np.flatnonzero(other)
    d = np.linalg.norm(sk.pos[chain][:, None, :] - sk.pos[cand][None], axis=2)
    k = np.argmin(d, axis=1)
    return bool((d[np.arange(len(chain)), k] <= ratio * sk.spread[cand[k]]).all())


def _prune_once(sk: Skeleton, min_length: float, min_count: int, measured: bool) -> Skeleton:
    kids = sk.children()
    keep = np.ones(len(sk.pos), bool)
    target = np.arange(len(sk.pos))
    for tip in [u for u in range(len(sk.pos)) if not kids[u] and u != 0]:
        chain, u, length = [tip], tip, 0.0
        while sk.parent[u] >= 0 and len(kids[sk.parent[u]]) == 1:
            length += float(np.linalg.norm(sk.pos[u] - sk.pos[sk.parent[u]]))
            u = int(sk.parent[u])
            chain.append(u)
        j = int(sk.parent[u])
        if j < 0 or len(kids[j]) < 2:
            continue  # the chain reaches the root: the whole skeleton, keep it
        length += float(np.linalg.norm(sk.pos[u] - sk.pos[j]))
        few = measured and int(sk.count[chain].sum()) < min_count
        # a stub no longer than the junction is wide is a piece of the junction's own surface;
        # a chain running inside another tube is a second arc of that tube's surface
        if length < max(min_length, float(sk.spread[j])) or few or \
                (measured and _inside_other_tubes(sk, chain, j, keep)):
            keep[chain] = False
            target[chain] = j
    if keep.all():
        return sk
    new = np.full(len(sk.pos), -1, np.int64)
    new[keep] = np.arange(int(keep.sum()))
    par = sk.parent[keep]
    par = np.where(par >= 0, new[np.maximum(par, 0)], -1)
    cnt = np.bincount(new[target], weights=sk.count, minlength=int(keep.sum())).astype(np.int64)
    return Skeleton(pos=sk.pos[keep], parent=par, count=cnt, members=sk.members,
                    member_node=new[target[sk.member_node]], spread=sk.spread[keep])


def tree_skeleton(seg, points: np.ndarray) -> Skeleton | None:
    """The segmentation's rootward tree restricted to its stem edges (no measurements)."""
    child, parent = stem_edges(seg)
    if len(child) == 0:
        return None
    nodes = np.asarray(seg.tree_nodes, np.int64)
    used = np.unique(np.concatenate([child, parent]))
    new = np.full(len(nodes), -1, np.int64)
    new[used] = np.arange(len(used))
    par = np.full(len(used), -1, np.int64)
    par[new[child]] = new[parent]
    roots = np.flatnonzero(par < 0)
    pos = np.asarray(points, np.float64)[nodes[used]]
    main = int(roots[np.argmin(pos[roots, 2])])
    sk = Skeleton(pos=pos, parent=par, count=np.zeros(len(used), np.int64),
                  members=np.zeros(0, np.int64), member_node=np.zeros(0, np.int64))
    for r in roots:  # a forest: hang every other root under the nearest node of the main tree
        if r == main:
            continue
        reach = np.zeros(len(pos), bool)
        kids = sk.children()
        stack = [main]
        while stack:
            u = stack.pop()
            reach[u] = True
            stack.extend(kids[u])
        cand = np.flatnonzero(reach)
        par[r] = cand[np.argmin(np.linalg.norm(pos[cand] - pos[r], axis=1))]
    return _reroot(sk, main)


# ---- streams, smoothing, radii ----------------------------------------------------------------
def streams(sk: Skeleton) -> list[np.ndarray]:
    """Node lists of the tubes: the first is the root's; a branch starts at its junction node.

    At every junction the child with the longest subtree continues the parent's stream.
    """
    kids = sk.children()
    n = len(sk.pos)
    reach = np.zeros(n)
    for u in range(n - 1, -1, -1):  # BFS order: children after parents
        for c in kids[u]:
            reach[u] = max(reach[u], reach[c] + float(np.linalg.norm(sk.pos[c] - sk.pos[u])))
    out, todo = [], [(0, None)]
    while todo:
        u, start = todo.pop(0)
        chain = [start] if start is not None else []
        chain.append(u)
        while kids[u]:
            main = max(kids[u], key=lambda c: reach[c] + float(np.linalg.norm(sk.pos[c] - sk.pos[u])))
            for c in kids[u]:
                if c != main:
                    todo.append((c, u))
            u = main
            chain.append(u)
        out.append(np.asarray(chain, np.int64))
    return out


def _smooth_curve(pts: np.ndarray, weights: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Smoothed copy of a polyline (P, 3): a cubic smoothing spline per coordinate against chord
    length (``scipy.interpolate.make_smoothing_spline``), weights (P,) (large = keep); ``scale``
    is the length below which wiggles are smoothed out (None: chosen by generalised
    cross-validation, ~10x slower)."""
    from scipy.interpolate import make_smoothing_spline

    P = len(pts)
    if P < 5:
        return pts.copy()
    t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    if not (np.diff(t) > 1e-12).all():
        keep = np.r_[True, np.diff(t) > 1e-12]
        out = pts.copy()
        out[keep] = _smooth_curve(pts[keep], weights[keep], scale)
        return out
    # penalty lam * int f''^2 against sum w (y - f)^2 over points h apart: wiggles shorter than
    # about 2 pi * scale are smoothed out (None: generalised cross-validation, slow)
    h = float(t[-1]) / (P - 1)
    lam = None if scale is None else float(np.mean(weights)) / max(h, 1e-12) * float(scale) ** 4
    try:
        return np.stack([make_smoothing_spline(t, pts[:, k], w=weights, lam=lam)(t) for k in range(3)], 1)
    except (ValueError, np.linalg.LinAlgError):
        return pts.copy()


def _polyline_distance(q: np.ndarray, poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of points q (M, 3) to a polyline (P, 3) and the (fractional) vertex index of the
    closest point."""
    from scipy.spatial import cKDTree

    if len(poly) == 1:
        return np.linalg.norm(q - poly[0], axis=1), np.zeros(len(q))
    _, i = cKDTree(poly).query(q)
    best_d = np.full(len(q), np.inf)
    best_t = np.zeros(len(q))
    for s in (i - 1, i):
        s = np.clip(s, 0, len(poly) - 2)
        a, b = poly[s], poly[s + 1]
        ab = b - a
        L2 = np.maximum((ab * ab).sum(1), 1e-30)
        u = np.clip(((q - a) * ab).sum(1) / L2, 0, 1)
        d = np.linalg.norm(q - (a + u[:, None] * ab), axis=1)
        better = d < best_d
        best_d[better], best_t[better] = d[better], (s + u)[better]
    return best_d, best_t


def _leonardo_prior(sk: Skeleton, root_r: float, pet_r: float) -> np.ndarray:
    """(n,) prior cross-section area (r^2) per skeleton node from the tree rule (module doc)."""
    kids = sk.children()
    n = len(sk.pos)
    d = np.zeros(n)
    for u in range(1, n):
        d[u] = d[sk.parent[u]] + float(np.linalg.norm(sk.pos[u] - sk.pos[sk.parent[u]]))
    tips = np.zeros(n)
    h = np.zeros(n)
    for u in range(n - 1, -1, -1):
        if not kids[u]:
            tips[u] = 1
        else:
            tips[u] = sum(tips[c] for c in kids[u])
            h[u] = max(h[c] + float(np.linalg.norm(sk.pos[c] - sk.pos[u])) for c in kids[u])
    t = np.where(d + h > 0, d / np.maximum(d + h, 1e-30), 1.0)
    s_root = root_r ** 2 / (max(tips[0], 1) * pet_r ** 2)
    return (s_root + (1 - s_root) * t) * tips * pet_r ** 2


def solve_areas(sk: Skeleton, observed: np.ndarray, weight: np.ndarray, prior: np.ndarray,
                params: StemParams) -> np.ndarray:
    """(n,) cross-section areas r^2: measured areas, smoothness and Leonardo's rule in one sparse
    least-squares problem (module docstring, step 4). observed/weight : (n,) (weight 0 = none)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    n = len(sk.pos)
    kids = sk.children()
    scale = np.maximum(np.where(weight > 0, observed, prior), 1e-10)
    R, C, V, B = [], [], [], []
    row = 0

    def add(cols, vals, rhs, w, s):
        nonlocal row
        f = np.sqrt(w) / s
        R.extend([row] * len(cols))
        C.extend(cols)
        V.extend([v * f for v in vals])
        B.append(rhs * f)
        row += 1

    for u in range(n):
        if weight[u] > 0:
            add([u], [1.0], observed[u], weight[u], scale[u])
        add([u], [1.0], prior[u], 1e-3, scale[u])  # keeps every node determined
        ks = kids[u]
        if len(ks) == 1:
            add([u, ks[0]], [1.0, -1.0], 0.0, params.smooth_weight, max(scale[u], scale[ks[0]]))
        elif len(ks) > 1:
            add([u] + ks, [1.0] + [-1.0] * len(ks), 0.0, params.leonardo_weight * len(ks), scale[u])
    A = coo_matrix((V, (R, C)), shape=(row, n)).tocsr()
    b = np.asarray(B)
    a = spsolve((A.T @ A).tocsc(), A.T @ b)
    return np.maximum(np.asarray(a, np.float64), 0.0)


# ---- tubes --------------------------------------------------------------------------------------
def _rmf(axis: np.ndarray) -> np.ndarray:
    """(P, 3) reference vectors of rotation-minimising frames along a polyline (double reflection)."""
    P = len(axis)
    tang = np.gradient(axis, axis=0) if P > 1 else np.array([[0, 0, 1.0]])
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    t0 = tang[0]
    ref = np.array([1.0, 0, 0]) if abs(t0[0]) < 0.9 else np.array([0, 1.0, 0])
    r = ref - (ref @ t0) * t0
    r /= np.linalg.norm(r)
    out = np.zeros_like(axis)
    out[0] = r
    for i in range(P - 1):
        v1 = axis[i + 1] - axis[i]
        c1 = v1 @ v1
        if c1 < 1e-24:
            out[i + 1] = out[i]
            continue
        rl = out[i] - (2 / c1) * (v1 @ out[i]) * v1
        tl = tang[i] - (2 / c1) * (v1 @ tang[i]) * v1
        v2 = tang[i + 1] - tl
        c2 = v2 @ v2
        r2 = rl - (2 / c2) * (v2 @ rl) * v2 if c2 > 1e-24 else rl
        r2 -= (r2 @ tang[i + 1]) * tang[i + 1]
        out[i + 1] = r2 / max(np.linalg.norm(r2), 1e-12)
    return out, tang


def sweep(axis: np.ndarray, radii: np.ndarray, sides: int, cap_start: bool, tip: bool):
    """Tube mesh along ``axis`` (P, 3) with ring radii (P,): rings of ``sides`` vertices, a flat
    cap at the start when ``cap_start``, a closed point at the end when ``tip`` (the last ring
    is replaced by the apex). Returns (verts (V, 3), faces (F, 3) int64), faces outward."""
    P = len(axis)
    ref, tang = _rmf(axis)
    ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring_p = axis if not tip else axis[:-1]
    R = len(ring_p)
    u = ref[:R]
    w = np.cross(tang[:R], u)
    verts = (ring_p[:, None, :] + radii[:R, None, None] *
             (np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None] * w[:, None, :]))
    verts = verts.reshape(-1, 3)
    j = np.arange(sides)
    j2 = (j + 1) % sides
    faces = []
    for i in range(R - 1):
        a, b = i * sides + j, i * sides + j2
        faces.append(np.stack([a, b, b + sides], 1))
        faces.append(np.stack([a, b + sides, a + sides], 1))
    extra = []
    nv = len(verts)
    if tip and R >= 1:
        extra.append(axis[-1])
        last = (R - 1) * sides
        faces.append(np.stack([last + j, last + j2, np.full(sides, nv)], 1))
        nv += 1
    if cap_start and R >= 1:
        extra.append(axis[0])
        faces.append(np.stack([np.full(sides, nv), j2, j], 1))
        nv += 1
    if extra:
        verts = np.concatenate([verts, np.asarray(extra)])
    F = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    return verts, F.astype(np.int64)


def _resample(axis: np.ndarray, radii: np.ndarray, spacing: np.ndarray, tip_len: float,
              tip: bool):
    """Ring positions along a fine axis: every ``spacing`` (per fine sample), plus a rounded tip
    (radius r * sqrt(1 - x^2) over the last ``tip_len``). Returns (axis (R, 3), radii (R,))."""
    seg = np.linalg.norm(np.diff(axis, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    total = float(s[-1])
    if total <= 0:
        return axis[:1].repeat(2, 0), radii[:1].repeat(2)
    keep = [0.0]
    while True:
        i = int(np.searchsorted(s, keep[-1], side="right") - 1)
        nxt = keep[-1] + float(spacing[min(i, len(spacing) - 1)])
        if nxt >= total - 0.5 * float(spacing[-1]):
            break
        keep.append(nxt)
    keep.append(total)
    keep = np.asarray(keep)
    if tip:
        L = min(tip_len, 0.5 * total)
        body = keep[keep < total - L]
        x = np.array([0.0, 0.5, 0.8, 0.95, 1.0])
        keep = np.unique(np.r_[body, total - L + L * x])
    pts = np.stack([np.interp(keep, s, axis[:, k]) for k in range(3)], 1)
    r = np.interp(keep, s, radii)
    if tip:
        L = min(tip_len, 0.5 * total)
        x = np.clip((keep - (total - L)) / max(L, 1e-12), 0, 1)
        r = r * np.sqrt(np.clip(1 - x ** 2, 0, 1))
    return pts, r


@dataclass
class _Tube:
    axis: np.ndarray      # (P, 3) fine axis samples
    radii: np.ndarray     # (P,)
    cap_start: bool
    parent_tube: int      # index into the tube list, -1 for the root's
    attach: np.ndarray    # (3,) where the tube leaves its parent (its first axis point)
    stream: int = -1      # index of its stream (``streams(sk)``)
    own: np.ndarray | None = None  # (M, 3) its own nodes' Gaussians (not the junction's)


def _merged_nodes(spread: np.ndarray, is_branch: bool) -> np.ndarray:
    """(k,) bool: the nodes of a stream (spreads (k,), in stream order) whose level-set piece
    holds several tubes: a spread above ``_MERGED_SPREAD`` x the stream's median (a junction
    where branches leave along the parent, petiole bases running alongside it for a while).
    Their centroid lies between the tubes and pulls the axis off the parent (overlap: 0.02, two
    radii, over a run of junction nodes). A branch's first node (the junction, placed by
    its parent's stream) and streams shorter than 5 nodes (no median to speak of) keep theirs;
    at least two single-tube nodes must remain."""
    out = np.zeros(len(spread), bool)
    if len(spread) < 5 or not (spread > 0).any():
        return out
    out = spread > _MERGED_SPREAD * float(np.median(spread[spread > 0]))
    if is_branch:
        out[0] = False
    if (~out).sum() < 2:
        out[:] = False
    return out


def _tubes(sk: Skeleton, areas: np.ndarray, points: np.ndarray, params: StemParams,
           smoothed: dict | None = None) -> list[_Tube]:
    w = float(params.level_width)
    tubes: list[_Tube] = []
    node_pos = {} if smoothed is None else smoothed
    stream_of = {}
    for si, chain in enumerate(streams(sk)):
        pts = sk.pos[chain].copy()
        wt = np.sqrt(np.maximum(sk.count[chain], 1)).astype(np.float64)
        is_branch = si > 0
        merged = _merged_nodes(sk.spread[chain], is_branch)
        if merged.any():
            # their centroids lie between the tubes they hold: the stream's axis goes through
            # them as it does between its single-tube nodes on either side
            arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
            good = np.flatnonzero(~merged)
            inside = merged & (arc > arc[good[0]]) & (arc < arc[good[-1]])
            for k in range(3):
                pts[inside, k] = np.interp(arc[inside], arc[good], pts[good, k])
            wt[merged] *= 0.01
        if is_branch:
            pts[0] = node_pos.get(int(chain[0]), pts[0])
            wt[0] = 1e3 * wt.max()
        if len(pts) >= 2:
            sm = _smooth_curve(pts, wt, float(params.axis_smoothing) * w)
        else:
            sm = pts
        if is_branch:
            sm[0] = pts[0]
        for k, u in enumerate(chain.tolist()):
            if not (is_branch and k == 0):
                node_pos[u] = sm[k]
                stream_of[u] = si
        node_r = np.sqrt(areas[chain])
        if is_branch and len(node_r) > 1:
            # the junction node measures the parent: a branch is as thick as itself from the start
            node_r[0] = node_r[1]
        if not is_branch and len(sk.members) and len(sm) >= 2:
            # the root node's centroid lies inside the base: reach down to its lowest Gaussians
            mem = points[sk.members[sk.member_node == chain[0]]]
            d = sm[0] - sm[1]
            d /= max(np.linalg.norm(d), 1e-12)
            ext = float(np.clip(((mem - sm[0]) @ d).max(initial=0.0), 0.0, w))
            if ext > 1e-9:
                sm = np.concatenate([[sm[0] + ext * d], sm])
                node_r = np.r_[node_r[0], node_r]
        if len(sk.members) and len(sm) >= 2:
            # likewise the tip node's centroid lies short of the stream's end (a petiole's leaf
            # base): reach out to its farthest Gaussian along the end's direction
            mem = points[sk.members[sk.member_node == chain[-1]]]
            d = sm[-1] - sm[-2]
            d /= max(np.linalg.norm(d), 1e-12)
            ext = float(np.clip(((mem - sm[-1]) @ d).max(initial=0.0), 0.0, w))
            if ext > 1e-9:
                sm = np.concatenate([sm, [sm[-1] + ext * d]])
                node_r = np.r_[node_r, node_r[-1]]
        if len(sm) < 2:
            continue
        # fine axis: cubic interpolation of the smoothed nodes
        t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sm, axis=0), axis=1))]
        good = np.r_[True, np.diff(t) > 1e-12]
        sm, t, node_r = sm[good], t[good], node_r[good]
        if len(sm) < 2:
            continue
        step = 0.2 * w
        m = max(int(np.ceil(t[-1] / step)) + 1, 4)
        tf = np.linspace(0, t[-1], m)
        if len(sm) >= 4:
            from scipy.interpolate import make_interp_spline
            fine = make_interp_spline(t, sm, k=3)(tf)
        else:
            fine = np.stack([np.interp(tf, t, sm[:, k]) for k in range(3)], 1)
        rf = np.interp(tf, t, node_r)
        parent_tube = stream_of.get(int(chain[0]), -1) if is_branch else -1
        own = points[sk.members[np.isin(sk.member_node, chain[1:] if is_branch else chain)]] \
            if len(sk.members) else None
        tubes.append(_Tube(axis=fine, radii=rf, cap_start=not is_branch, parent_tube=parent_tube,
                           attach=fine[0], stream=si, own=own))
    tube_of = {tb.stream: i for i, tb in enumerate(tubes)}
    for tb in tubes:  # stream index -> tube index (a stream too short to sweep has no tube)
        tb.parent_tube = tube_of.get(tb.parent_tube, -1)
    return tubes


def _seat_branches(tubes: list[_Tube]) -> list[_Tube]:
    """Each branch starts where it emerges from its parent, not on the parent's axis: the part
    of its axis whose whole cross-section lies inside the parent tube (distance to the parent's
    axis + own radius <= parent radius) and has none of its Gaussians around it is cut off except
    its last sample, so the open start ring stays hidden inside the parent (no gap) and no wall
    the capture did not see runs down to the parent's axis."""
    from scipy.spatial import cKDTree

    for tb in tubes:
        if tb.parent_tube < 0 or len(tb.axis) < 3:
            continue
        par = tubes[tb.parent_tube]
        d, t = _polyline_distance(tb.axis, par.axis)
        rp = np.interp(t, np.arange(len(par.radii)), par.radii)
        seen = np.zeros(len(tb.axis), bool)
        if tb.own is not None and len(tb.own):
            # its Gaussians deep inside the parent (not the parent's wall around the junction)
            dq, tq = _polyline_distance(tb.own, par.axis)
            deep = tb.own[dq < 0.5 * np.interp(tq, np.arange(len(par.radii)), par.radii)]
            if len(deep):
                seen = cKDTree(deep).query(tb.axis)[0] <= 2.0 * tb.radii
        out = np.flatnonzero((d + tb.radii > rp) | seen)
        if not len(out):
            continue  # wholly inside the parent (a second arc of its surface): keep as built
        i0 = min(max(int(out[0]) - 1, 0), len(tb.axis) - 2)
        if i0 > 0:
            tb.axis, tb.radii = tb.axis[i0:], tb.radii[i0:]
            tb.attach = tb.axis[0]
    return tubes


def _observed_areas(sk: Skeleton, points: np.ndarray, params: StemParams):
    """Per node: (observed area (n,), weight (n,)) from its Gaussians' distances to the smoothed
    axis of its stream."""
    n = len(sk.pos)
    obs, wt = np.zeros(n), np.zeros(n)
    if not len(sk.members):
        return obs, wt
    smoothed: dict = {}
    tubes = _tubes(sk, np.full(n, 1e-6), points, params, smoothed)
    mem_pos = points[sk.members]
    chains = streams(sk)
    axis_of = {tb.stream: tb.axis for tb in tubes}
    for si, chain in enumerate(chains):
        own = chain[1:] if si > 0 else chain
        if si not in axis_of:
            continue
        axis = axis_of[si]
        sel = np.isin(sk.member_node, own)
        if not sel.any():
            continue
        d, _ = _polyline_distance(mem_pos[sel], axis)
        nodes = sk.member_node[sel]
        for u in np.unique(nodes):
            du = d[nodes == u]
            if len(du) >= 3:
                obs[u] = float(np.median(du)) ** 2
                wt[u] = len(du)
    ref = np.median(wt[wt > 0]) if (wt > 0).any() else 1.0
    return obs, np.minimum(wt / ref, 1.0)


def _vertex_colors(verts: np.ndarray, src_pts: np.ndarray, src_col: np.ndarray, k: int = 8):
    from scipy.spatial import cKDTree

    if len(src_pts) == 0:
        return None
    k = min(k, len(src_pts))
    d, j = cKDTree(src_pts).query(verts, k=k)
    if k == 1:
        return src_col[j]
    w = 1.0 / np.maximum(d, 1e-9)
    return (src_col[j] * w[..., None]).sum(1) / w.sum(1, keepdims=True)


def _mesh(tubes: list[_Tube], sides: int, spacing_mult: float, params: StemParams):
    """All tubes swept at one level of detail: (verts, faces, segments) with segments =
    (starts, ends, r_start, r_end, parent) of the rings' axis."""
    w = float(params.level_width)
    V, F, nv = [], [], 0
    starts, ends, r0, r1, par = [], [], [], [], []
    first_seg, seg_range = [], []
    for ti, tb in enumerate(tubes):
        spacing = np.clip(float(params.ring_spacing) * tb.radii, 0.25 * w, 2.0 * w) * spacing_mult
        ax, rr = _resample(tb.axis, tb.radii, spacing, float(params.tip_length) * float(tb.radii[-1]), True)
        v, f = sweep(ax, rr, sides, tb.cap_start and bool(params.root_cap), True)
        V.append(v)
        F.append(f + nv)
        nv += len(v)
        s0 = len(starts)
        for i in range(len(ax) - 1):
            starts.append(ax[i])
            ends.append(ax[i + 1])
            r0.append(rr[i])
            r1.append(rr[i + 1])
            par.append(len(starts) - 2 if i > 0 else -1)
        seg_range.append((s0, len(starts)))
        first_seg.append(s0)
    # a branch's first segment hangs from the parent tube's segment nearest its attachment
    for ti, tb in enumerate(tubes):
        if tb.parent_tube >= 0 and seg_range[ti][1] > seg_range[ti][0]:
            a, b = seg_range[tb.parent_tube]
            if b > a:
                mids = 0.5 * (np.asarray(starts[a:b]) + np.asarray(ends[a:b]))
                par[seg_range[ti][0]] = a + int(np.argmin(np.linalg.norm(mids - tb.attach, axis=1)))
    verts = np.concatenate(V) if V else np.zeros((0, 3))
    faces = np.concatenate(F) if F else np.zeros((0, 3), np.int64)
    seg = (np.asarray(starts).reshape(-1, 3), np.asarray(ends).reshape(-1, 3), np.asarray(r0),
           np.asarray(r1), np.asarray(par, np.int64))
    return verts, faces, seg


def _empty_stem() -> Stem:
    return Stem(starts=np.zeros((0, 3), np.float32), ends=np.zeros((0, 3), np.float32),
                radii_start=np.zeros(0, np.float32), radii_end=np.zeros(0, np.float32),
                parent=np.zeros(0, np.int64), points=np.zeros((0, 3), np.float32),
                faces=np.zeros((0, 3), np.int32))


def _check_inputs(seg, pts_all: np.ndarray) -> None:
    """Named errors for a points array that is not (N, 3) or a tree that does not index it."""
    if pts_all.ndim != 2 or pts_all.shape[1] != 3:
        raise ParameterError("points_working", "an (N, 3) array", pts_all.shape)
    nodes = np.asarray(seg.tree_nodes, np.int64)
    if len(nodes) and (nodes.min() < 0 or nodes.max() >= len(pts_all)):
        raise ParameterError("seg.tree_nodes", f"indices in [0, {len(pts_all)})",
                             f"range [{nodes.min()}, {nodes.max()}]")
    if len(np.asarray(seg.tree_parent)) != len(nodes) or len(np.asarray(seg.tree_leaf)) != len(nodes):
        raise ParameterError("seg.tree_parent/tree_leaf", f"{len(nodes)} entries (one per tree node)",
                             f"{len(np.asarray(seg.tree_parent))}/{len(np.asarray(seg.tree_leaf))}")


def _choose_skeleton(seg, pts_all: np.ndarray, labels: np.ndarray,
                     params: StemParams) -> tuple[Skeleton | None, str]:
    """(skeleton, kind): the Gaussian skeleton when asked for and possible, else the tree's."""
    sk = None
    kind = "tree"
    if params.skeleton in ("auto", "gaussians") and len(labels) == len(pts_all):
        sk = gaussian_skeleton(pts_all, labels, int(seg.root_index), params)
        kind = "gaussians"
        if sk is None or len(sk.pos) < 2:
            sk = None
            if params.skeleton == "gaussians":
                log.warning("stem: too few stem Gaussians for a skeleton; using the segmentation tree")
    if sk is None:
        sk, kind = tree_skeleton(seg, pts_all), "tree"
        if sk is not None and len(sk.pos) == 2:
            log.warning("stem: the segmentation tree has a single stem edge; the stem is one tapered tube")
    return sk, kind


def _prior_radii(sk: Skeleton, obs: np.ndarray, wt: np.ndarray, seg, pts_all: np.ndarray, fits,
                 params: StemParams) -> tuple[float, float]:
    """(root_radius, petiole_radius) of the Leonardo prior: the parameters, else the measured
    radii at the root's first nodes and at the tips, else estimates from the capture."""
    root_r, pet_r = params.root_radius, params.petiole_radius
    if root_r is None or pet_r is None:
        kids = sk.children()
        tipn = [u for u in range(len(sk.pos)) if not kids[u]]
        m_root = np.sqrt(obs[:3][wt[:3] > 0]) if (wt[:3] > 0).any() else None
        m_tip = np.sqrt(obs[tipn][wt[tipn] > 0]) if (wt[tipn] > 0).any() else None
        if root_r is None and m_root is not None and len(m_root):
            root_r = float(np.median(m_root))
        if pet_r is None and m_tip is not None and len(m_tip):
            pet_r = float(np.median(m_tip))
        if root_r is None or pet_r is None:
            r_root, r_pet = _resolve_radii(StemParams(root_radius=root_r, petiole_radius=pet_r,
                                                      estimate_ball=params.estimate_ball),
                                           seg, pts_all, fits)
            root_r, pet_r = r_root, r_pet
    return root_r, min(pet_r, root_r)


def _skeleton_tubes(sk: Skeleton, kind: str, seg, pts_all: np.ndarray, fits,
                    params: StemParams) -> tuple[list[_Tube], float, float]:
    """(tubes, root radius, petiole radius) of a skeleton: measured radii regularised by
    Leonardo's rule (the prior alone on the tree skeleton), smoothed axes, seated branches."""
    obs, wt = _observed_areas(sk, pts_all, params) if kind == "gaussians" else \
        (np.zeros(len(sk.pos)), np.zeros(len(sk.pos)))
    root_r, pet_r = _prior_radii(sk, obs, wt, seg, pts_all, fits, params)
    prior = _leonardo_prior(sk, float(root_r), float(pet_r))
    # nothing measured (tree skeleton): the prior is the whole answer
    areas = solve_areas(sk, obs, wt, prior, params) if (wt > 0).any() else prior
    areas = np.maximum(areas, (0.25 * pet_r) ** 2)
    return _seat_branches(_tubes(sk, areas, pts_all, params)), float(root_r), float(pet_r)


def _tube_residual(tubes: list[_Tube], q: np.ndarray) -> np.ndarray:
    """(M,) distance of points q (M, 3) outside the swept tubes: distance to the nearest tube's
    axis minus its radius there (negative inside)."""
    res = np.full(len(q), np.inf)
    for tb in tubes:
        d, t = _polyline_distance(q, tb.axis)
        res = np.minimum(res, d - np.interp(t, np.arange(len(tb.radii)), tb.radii))
    return res


def _drop_subtrees(sk: Skeleton, drop: np.ndarray) -> Skeleton:
    """The skeleton without the nodes ``drop`` (n,) bool and everything hanging from them
    (their Gaussians leave the members); the root is never dropped."""
    if not drop.any():
        return sk
    gone = drop.copy()
    gone[0] = False
    for u in range(1, len(sk.pos)):  # BFS order: a parent before its children
        gone[u] |= gone[sk.parent[u]]
    keep = ~gone
    new = np.full(len(sk.pos), -1, np.int64)
    new[keep] = np.arange(int(keep.sum()))
    par = sk.parent[keep]
    mem = keep[sk.member_node]
    return Skeleton(pos=sk.pos[keep], parent=np.where(par >= 0, new[np.maximum(par, 0)], -1),
                    count=sk.count[keep], members=sk.members[mem], member_node=new[sk.member_node[mem]],
                    spread=sk.spread[keep])


def _hysteresis(ctx: _GraphContext, members: np.ndarray, weak: np.ndarray, strong: np.ndarray) -> np.ndarray:
    """(len(members),) bool: the ``weak`` members connected (neighbour graph, through weak
    members) to a ``strong`` one — a miss is found by its far core and taken whole, out to where
    its Gaussians meet a tube."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = len(ctx.idx)
    loc = np.searchsorted(ctx.idx, members)
    w = np.zeros(M, bool)
    w[loc[weak]] = True
    Gc = ctx.G.tocoo()
    e = w[Gc.row] & w[Gc.col]
    _, comp = connected_components(coo_matrix((np.ones(int(e.sum())), (Gc.row[e], Gc.col[e])), shape=(M, M)),
                                   directed=False)
    hit = np.zeros(M, bool)
    hit[np.unique(comp[loc[strong & weak]])] = True
    return weak & hit[comp[loc]]


def _cover_tau(tubes: list[_Tube], q: np.ndarray, w_thin: float) -> float:
    """How far outside the swept tubes a stem Gaussian q (M, 3) may lie and still be on them:
    three robust standard deviations of all the Gaussians' offsets, at least a quarter of the
    thin tubes' level width."""
    res = _tube_residual(tubes, q)
    return max(3.0 * 1.4826 * float(np.median(np.abs(res))), 0.25 * float(w_thin))


def _cover_missed(sk: Skeleton, tubes: list[_Tube], points: np.ndarray, params: StemParams) -> Skeleton:
    """The skeleton with chains added for the stem Gaussians the swept tubes still miss.

    :func:`_missed_tubes` judges the Gaussians against the skeleton's straight node-to-node
    segments with the nodes' spreads as radii; the tubes are swept along smoothed axes with
    radii solved under Leonardo's rule, and pruning, smoothing and seating move them: a petiole's
    last Gaussians beyond its tip, a thin branch's end past a fork, one of two touching parallel
    petioles can end up outside every tube by several of its radii (the true surface there has no
    mesh near it). Those Gaussians go through the same chain building as the first pass: the
    groups of Gaussians outside the tubes by more than the first pass's threshold (three robust
    standard deviations of all the offsets, a quarter of the thin tubes' level width) that
    reach twice as far out somewhere (a miss, not the tubes' own noise). The same skeleton
    (``is``) when none are found.
    """
    from scipy.spatial import cKDTree

    ctx = sk.graph
    if ctx is None or not len(sk.members):
        return sk
    res = _tube_residual(tubes, points[sk.members])
    tau = max(3.0 * 1.4826 * float(np.median(np.abs(res))), 0.25 * float(ctx.w_thin))
    off = _hysteresis(ctx, sk.members, res > tau, res > 2.0 * tau)
    if off.sum() < _SMALL_MIN:
        return sk
    out = _missed_tubes(sk, points, ctx.idx, ctx.G, ctx.g, params, ctx.w_thin, off=off, add_only=True)
    if out is sk:
        return sk
    # the old nodes keep their positions; a new node whose circle fit put it inside an existing
    # tube found that tube's own wall (a second arc of it), not a missed tube: it goes, with
    # what hangs from it
    old = cKDTree(sk.pos).query(out.pos)[0] <= 1e-12
    inside = ~old & (_tube_residual(tubes, out.pos) < 0)
    return _drop_subtrees(out, inside)


def _surface_gaps(tubes: list[_Tube], tree, sides: int) -> list[np.ndarray]:
    """Per tube, (V,) the distance of each vertex of its swept surface (``sides`` per ring, one
    ring per fine axis sample) to the nearest stem Gaussian (``tree``: a cKDTree of them)."""
    out = []
    for tb in tubes:
        v, _ = sweep(tb.axis, tb.radii, sides, False, False)
        out.append(tree.query(v)[0])
    return out


def _gap_reference(gaps: list, i: int) -> float:
    """The capture's own gaps between stem Gaussians, seen from tube surfaces: the 99th
    percentile of ``gaps`` (per tube, each surface sample's distance to the nearest stem Gaussian,
    :func:`_surface_gaps`) over every tube but ``i``. A surface standing out of the data by more
    than a multiple of this is off it (:func:`_redundant_tubes`, :func:`_trim_redundant_tails`)."""
    return float(np.percentile(np.concatenate([g for j, g in enumerate(gaps) if j != i]
                                              or [np.zeros(1)]), 99))


def _redundant_tubes(tubes: list[_Tube], q: np.ndarray, tau: float, sides: int,
                     share: float = 0.9, stand_out: float = 1.5) -> list[int]:
    """Indices of the terminal branch tubes that explain no Gaussian and stand out of the data.

    - **Explain nothing:** at least ``share`` of the tube's own Gaussians lie within ``tau``
      outside (or inside) the other tubes still kept.
    - **Stand out:** somewhere its surface is farther from every stem Gaussian (``q`` (M, 3))
      than ``stand_out`` x the 99th percentile of that distance over the other tubes' surfaces
      (the capture's own gaps between Gaussians).

    Such a tube was built from a second arc of another tube's surface, swept around an axis that
    lies on that surface: the level sets of a thick petiole leaving a thin branch split the
    petiole's ring in two past the fork, and the far arc became a chain of its own (pothos: the
    end of the branch past the fork got a 0.013 tube, as thick as the petiole, half of it in the
    air 0.02 from any true surface). A tube made of a few Gaussians the other tubes also cover,
    but whose surface lies on the data, stays: it may still be the only mesh over part of a true
    tube. Tubes are judged one at a time against the tubes still kept (most explained, then
    fewest Gaussians, first), so of two tubes that explain each other one stays."""
    from scipy.spatial import cKDTree

    has_kid = {tb.parent_tube for tb in tubes}
    cand = [i for i, tb in enumerate(tubes)
            if tb.parent_tube >= 0 and i not in has_kid and tb.own is not None and len(tb.own)]
    if not cand or not len(q):
        return []
    gaps = _surface_gaps(tubes, cKDTree(q), sides)
    cand = [i for i in cand if float(gaps[i].max()) > stand_out * _gap_reference(gaps, i)]
    if not cand:
        return []
    lo = np.stack([tb.axis.min(0) - tb.radii.max() for tb in tubes])
    hi = np.stack([tb.axis.max(0) + tb.radii.max() for tb in tubes])
    res = {}  # candidate -> (own, tubes) residuals, inf where the tube is out of reach
    for i in cand:
        own = tubes[i].own
        r = np.full((len(own), len(tubes)), np.inf)
        near = ((lo <= own.max(0) + tau) & (hi >= own.min(0) - tau)).all(1)
        near[i] = False
        for j in np.flatnonzero(near):
            r[:, j] = _tube_residual([tubes[j]], own)
        res[i] = r
    kept = np.ones(len(tubes), bool)
    while True:
        left = [i for i in cand if kept[i]]
        if not left:
            break
        frac = {}
        for i in left:
            k = kept.copy()
            k[i] = False
            frac[i] = float(np.mean(res[i][:, k].min(1, initial=np.inf) <= tau))
        best = min(left, key=lambda i: (-frac[i], len(tubes[i].own), i))
        if frac[best] < share:
            break
        kept[best] = False
    return [int(i) for i in np.flatnonzero(~kept)]


def _drop_redundant(tubes: list[_Tube], q: np.ndarray, tau: float, sides: int) -> list[_Tube]:
    """The tubes without those of :func:`_redundant_tubes` (nothing hangs from them), parents
    renumbered; every other tube stays as it was swept."""
    gone = set(_redundant_tubes(tubes, q, tau, sides))
    if not gone:
        return tubes
    new = {}
    for i in range(len(tubes)):
        if i not in gone:
            new[i] = len(new)
    out = [tubes[i] for i in sorted(new)]
    for tb in out:
        tb.parent_tube = new.get(tb.parent_tube, -1)
    return out


def _trim_redundant_tails(tubes: list[_Tube], q: np.ndarray, tau: float, sides: int,
                          share: float = 0.9, stand_out: float = 1.5) -> list[_Tube]:
    """The tubes with each branch tube's redundant tail cut off: the part past where its last
    child leaves it, judged as :func:`_redundant_tubes` judges a terminal tube (at least
    ``share`` of the tail's own Gaussians lie within ``tau`` of the other tubes, and its surface
    somewhere stands farther from every stem Gaussian ``q`` (M, 3) than ``stand_out`` x the
    99th percentile of that gap over the other tubes' surfaces). A chain that runs along a
    thin branch's end and then onto a second arc of the thick petiole beside it is one stream
    (the arc is its longer subtree), so the arc is no terminal tube of its own and the terminal
    rule never sees it (pothos_sh3's upper fork: the arc's tube, 0.0105-0.0143 thick around an
    axis on the petiole's surface, stood 0.02 from every true tube). The tail keeps its first
    fine sample past the last child's start (the child still grows out of it) and a rounded tip."""
    from scipy.spatial import cKDTree

    parents = {tb.parent_tube for tb in tubes if tb.parent_tube >= 0}
    cand = [i for i in sorted(parents) if tubes[i].parent_tube >= 0 and tubes[i].own is not None
            and len(tubes[i].own)]
    if not cand or not len(q):
        return tubes
    gaps = _surface_gaps(tubes, cKDTree(q), sides)
    for i in cand:
        tb = tubes[i]
        last = max(float(_polyline_distance(c.attach[None], tb.axis)[1][0])
                   for c in tubes if c.parent_tube == i)
        k = int(np.ceil(last)) + 1  # first sample of the tail
        if k >= len(tb.axis) - 2:
            continue
        if float(gaps[i].reshape(len(tb.axis), sides)[k:].max()) <= stand_out * _gap_reference(gaps, i):
            continue
        t_own = _polyline_distance(tb.own, tb.axis)[1]
        tail = tb.own[t_own > k]
        if len(tail) < _SMALL_MIN:
            continue
        head = _Tube(axis=tb.axis[:k + 1], radii=tb.radii[:k + 1], cap_start=False, parent_tube=-1,
                     attach=tb.attach)
        others = [tubes[j] for j in range(len(tubes)) if j != i] + [head]
        if float(np.mean(_tube_residual(others, tail) <= tau)) < share:
            continue
        tb.axis, tb.radii, tb.own = tb.axis[:k + 1], tb.radii[:k + 1], tb.own[t_own <= k]
    return tubes


def stem_labels(seg) -> np.ndarray:
    """(N,) the segmentation's labels with the unassigned Gaussians it never reached from the
    root set to -1: label 0 means "stem or unassigned", and only the reached ones are stem.
    Why: a piece the segmentation left apart from the plant (``dist_root`` infinite) is not
    stem, but the level-set skeleton bridges gaps and swept a tube through it: the pot-rim
    remnants that isolation kept on two capture-like samples (185 of green_pepper's Gaussians,
    all unreached) became a ring of tubes 0.14 plant heights from the stem
    (``benchmarks/isolation.py --convert``). Labels unchanged when ``dist_root`` is absent."""
    labels = np.asarray(seg.labels)
    d = np.asarray(seg.dist_root)
    if len(d) != len(labels):
        return labels
    return np.where((labels == 0) & ~np.isfinite(d), -1, labels)


def build_stem(seg, points_working, fits=None, params: StemParams | None = None,
               colors=None) -> Stem:
    """The stem as smooth swept tubes (module docstring).

    seg : Segmentation (labels, root_index; tree_nodes, tree_parent, tree_leaf, leaf_base for the
        tree skeleton and the radius prior)
    points_working : (N, 3) float, the Gaussians the segmentation ran on, working frame
    fits : LeafFits or None (unused by the geometry; accepted so callers pass the whole state)
    colors : (N, 3) float sRGB in [0, 1] of those Gaussians, or None (no vertex colours)
    Returns a ``Stem`` (working frame) with LOD0 in points/faces/colors and the coarser levels
    in ``lods``. No stem Gaussians and no stem edges give an empty stem and a warning.
    """
    params = params or StemParams()
    params.validate()
    pts_all = np.asarray(points_working, np.float64)
    _check_inputs(seg, pts_all)
    labels = stem_labels(seg)
    sk, kind = _choose_skeleton(seg, pts_all, labels, params)
    if sk is None or len(sk.pos) < 2:
        log.warning("stem: the segmentation tree has no stem edges and no stem Gaussians; writing no stem")
        return _empty_stem()
    tubes, root_r, pet_r = _skeleton_tubes(sk, kind, seg, pts_all, fits, params)
    if kind == "gaussians" and tubes:
        w_thin = float(sk.graph.w_thin) if sk.graph is not None else float(params.level_width)
        covered = _cover_missed(sk, tubes, pts_all, params)
        if covered is not sk:
            sk = covered
            tubes, root_r, pet_r = _skeleton_tubes(sk, kind, seg, pts_all, fits, params)
        q = pts_all[sk.members]
        tau = _cover_tau(tubes, q, w_thin)
        tubes = _drop_redundant(tubes, q, tau, int(params.sides))
        tubes = _trim_redundant_tails(tubes, q, tau, int(params.sides))
    if not tubes:
        log.warning("stem: no tube could be swept; writing no stem")
        return _empty_stem()
    # colour sources: the skeleton's Gaussians, or every stem-labelled one
    src = sk.members if len(sk.members) else np.flatnonzero(labels == 0) if len(labels) == len(pts_all) \
        else np.zeros(0, np.int64)
    col = None if colors is None else np.asarray(colors, np.float64)

    def level(sides, mult):
        v, f, segs = _mesh(tubes, sides, mult, params)
        c = _vertex_colors(v, pts_all[src], col[src]) if col is not None and len(src) else None
        return v, f, segs, c

    v, f, (st, en, r0, r1, par), c = level(int(params.sides), 1.0)
    lods = []
    for sides, mult in LOD_LEVELS:
        lv, lf, _, lc = level(min(int(sides), int(params.sides)), mult)
        lods.append(StemMesh(points=lv.astype(np.float32), faces=lf.astype(np.int32),
                             colors=None if lc is None else lc.astype(np.float32)))
    log.info("stem: %s skeleton, %d nodes, %d tubes, %d vertices (LOD0)", kind, len(sk.pos),
             len(tubes), len(v))
    return Stem(starts=st.astype(np.float32), ends=en.astype(np.float32),
                radii_start=r0.astype(np.float32), radii_end=r1.astype(np.float32),
                parent=par, points=v.astype(np.float32), faces=f.astype(np.int32),
                colors=None if c is None else c.astype(np.float32), lods=lods,
                info=dict(skeleton=kind, nodes=int(len(sk.pos)), tubes=len(tubes),
                          root_radius=float(root_r), petiole_radius=float(pet_r)))
