"""The paper's apex method of leaf instance segmentation with heat geodesics (paper Sec. "Leaf
Instance Segmentation"; ``SegmentParams.method = "apex"``, exactly the paper's with
``SegmentParams.paper()``).

Steps, in the working frame (root at the origin, +Z up, plant height 1; tau, delta, epsilon are in
these units):

1. ``D_r``: heat-method geodesic distance from the root Gaussian (one factorisation, see
   :mod:`leaffit_usd.geometry.heat`).
2. Farthest point sampling to ``N_s`` samples; ``N_k`` Euclidean nearest samples each; apex
   candidates = strict local maxima of ``D_r`` over those neighbours.
3. The rootward tree: from each apex (farthest first) steepest descent of ``D_r``, with the
   deferred-merge rule (a path touching a visited node merges only if its next
   node also touches one); junctions are the nodes where paths meet.
4. ``D_a`` from every apex (all solved together); apexes a, a' are on one leaf when
   ``D_a[a'] < D_a[lca] + D_a'[lca] - tau``; leaves are the connected components.
5. Petiole: from the primary tip (largest ``D_r``) along its path, the local diameter
   ``d = max |p_k - g|`` over the Gaussians with ``|D_a[g] - D_a[p_k]| <= delta/2``; the first node
   past the protection window (fraction ``rho`` of the path from the tip to its first junction)
   with ``d < epsilon`` is the base; the Gaussians with ``D_a`` below the base's are the leaf.

Choices the paper leaves open, and deviations (each with its reason; all switchable):

* Geodesic domain: the operator is built on the N_s FPS samples plus a seeded random subset of the
  Gaussians (``geodesic_points``; random keeps the relative density of thin stems, which FPS and
  voxel grids thin out) and distances are interpolated to every Gaussian; ~0.6 s on 20k points
  instead of ~5 s on 100k, with D_r within ~1% of the plant height of the full solve.
* Floaters (``outlier_factor``) are left out of the geodesics; afterwards those within twice the
  outlier radius of the plant (off-surface fuzz of a leaf) take their nearest Gaussian's label,
  the others stay unassigned. Pieces cut off by a gap narrower than
  ``bridge_gap`` are joined across it; pieces still apart from the root stay unassigned.
* Apex test (``apex_surface_neighbors``): of the N_k Euclidean neighbours only those reachable
  along the surface within the same radius vote; a 512-sample ball around a small leaf's tip
  otherwise reaches into the neighbouring leaf, whose higher D_r vetoes the apex.
* Tree: steepest descent over the geodesic operator's surface graph (a Euclidean neighbourhood
  among the samples leaps across the air between leaves); "the neighbourhood contains a visited
  node" is read as "a visited node lies on the same cross-section ring" (connected piece of the
  D_r iso-band), so paths on opposite sides of a thick stem merge, and paths on two leaves close
  in space never do. Deferred-merge rule as in the paper.
* Petiole (``blade_first``): the base can be found only after the march crossed the blade
  (diameter >= epsilon once), besides the protection window; long tapering tips otherwise stop
  the march early. An instance whose diameter never reaches epsilon has no blade (e.g. the top of
  a bare stem) and is dropped (``require_blade``). From the first node under epsilon the base
  moves on to where the diameter reaches the petiole's own (``base_refine``): a blade's base is
  narrower than epsilon over ~10% of its length.
* Grouping (``lca_on_blade``): besides the tau test, both paths must reach the LCA over a blade
  (a cross-section ring at least epsilon wide just above it); apexes whose paths come down
  petioles to meet on a stem are different leaves, even when touching blades short-cut the
  geodesic between them.
* Lobes (``tau_relative``): the paper's tau = 0.5 is an absolute margin, but its units cannot be
  recovered (delta = 0.01 is "approx. 1 cm", so 1 unit ~ 1 m and tau ~ 50 cm, more than a whole
  potted plant; in our units, plant height 1, no two lobe tips of one leaf are ever 0.5 apart
  along the blade). The test's meaning is "the direct geodesic is clearly shorter than the path
  through the LCA", which scales with the paths involved, so we also group two apexes when
  ``D_a[a'] < (1 - tau_relative) (D_a[lca] + D_a'[lca])`` and both paths, once past their narrow
  tips, stay on the blade all the way to the LCA (no cross-section ring down to it passes the
  petiole rule below: no petiole in between). Why 0.1: two lobe tips a lobe length apart fanning at
  60-90 deg with a sinus at half the lobe length give a ratio of 0.6-0.8 (a deep sinus -> 1);
  apexes of different leaves whose path runs through the stem give 1 minus the heat method's
  error (measured 0.97-0.99). Leaves whose blades touch can short-cut far more (ratios 0.88 on a
  bushy plant), which is why the relative test alone is not enough and needs the no-petiole
  condition (a petiole, or a stem, lies between two leaves' blades; never between two lobes).
  Known cost: where one leaf lies on another (the paper's horizontal-overlap failure) a tip's path
  crosses onto the other blade and the two look like lobes of one blade (ratios 0.73-0.80 on the
  generated overlap plants): hard_horizontal loses a leaf to this rule.
  ``tau_relative = 0`` restores the paper's absolute test alone.
* Petiole (``petiole_relative``): epsilon = 0.05 alone is the width of a blade on long-thin
  (grass-like) or narrow-lobed leaves, whose own width then hovers around it and the march stops
  on the blade. A petiole is a stalk, much narrower than the blade it carries, while a blade's
  width changes little between consecutive delta bands; so the base also needs the diameter under
  ``petiole_relative`` (0.5) x the widest diameter the march has seen on this leaf. Elliptic
  blades narrow smoothly from > 0.1 to the petiole, where both tests hold at once.
* A Gaussian claimed by several leaves goes to the one where it lies deepest (smallest
  ``D_a / base distance``).
* Optionally (``orientation_aware``, off by default) with ``normals`` (each flat Gaussian's
  smallest-scale axis), the geodesic operator drops elements that leave a Gaussian's tangent
  plane, so a leaf lying just above another is not short-cut (never cutting a piece off: see
  :mod:`leaffit_usd.geometry.heat`). It works on clean stacked sheets (tests/geometry) but the
  generated plants' Gaussian axes are noisy enough that it costs more than it gains there.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from leaffit_usd.geometry.heat import GeodesicSolver
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.segment.result import Segmentation

log = logging.getLogger("leaffit_usd")

from leaffit_usd.segment.apex_tree import RootwardTree, build_tree, petiole_base
from leaffit_usd.segment.attach import attach_outliers
from leaffit_usd.segment.params import SegmentParams


@dataclass
class _Geodesics:
    """The apex method's geodesic domain and D_r (steps 1-2 of the module docstring).

    solver : the heat-method operator on the FPS samples plus the random domain subset
    inlier : (N,) bool, not a floater (the root always is)
    d_root : (N,) float64 D_r, working units; inf at floaters and pieces apart from the root
    reach : (N,) bool, finite ``d_root``
    samples : (S,) int64 Gaussians, the FPS samples connected to the root (the root included)
    """

    solver: GeodesicSolver
    inlier: np.ndarray
    d_root: np.ndarray
    reach: np.ndarray
    samples: np.ndarray


@dataclass
class _ApexTree:
    """Apexes and the rootward tree (step 3).

    apex_g : (A,) int64 apex Gaussians, largest D_r first
    apex_d : (A,) int64 their domain positions
    tree : the rootward tree over domain positions
    paths : A arrays of tree node indices, apex -> root
    dr_dom : (M,) float64 D_r at the domain points
    """

    apex_g: np.ndarray
    apex_d: np.ndarray
    tree: RootwardTree
    paths: list
    dr_dom: np.ndarray


@dataclass
class _Leaves:
    """Per apex group (step 5), before the labels.

    groups : (G,) int group ids (sorted); dist : (N, G) float64 D_a from each group's primary tip
    (inf at floaters); keep : columns of the groups that are leaves (a blade was found);
    tip, base : Gaussian indices, base_dist : D_a at the base, one per kept group
    """

    groups: np.ndarray
    dist: np.ndarray
    keep: list
    tip: list
    base: list
    base_dist: list


@dataclass
class _RingWidths:
    """Surface cross-section width at a domain point: its ring's extent, cached per ring.

    x : (M, 3) domain points, working frame; ring : (M,) ring id of each (``RootwardTree.ring``).
    """

    x: np.ndarray
    ring: np.ndarray
    cache: dict = field(default_factory=dict)

    def __call__(self, node_d: int) -> float:
        r = int(self.ring[node_d])
        if r not in self.cache:
            mem = self.x[self.ring == r]
            self.cache[r] = float(np.sqrt(((mem - self.x[node_d]) ** 2).sum(1).max())) if len(mem) else 0.0
        return self.cache[r]


def segment_apex(pts, root, inlier, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The paper's method (steps 1-5 of the module docstring), with our deviations as ``p`` says."""
    n = len(pts)
    samples, domain = _sample_domain(pts, root, inlier, p)
    tm["sampling"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    nrm = normals if (normals is not None and p.orientation_aware) else None
    solver = GeodesicSolver(pts, nrm, domain=domain, t_coef=p.t_coef,
                            bridge_gap=p.bridge_gap if p.bridge_gap > 0 else None)
    tm["geodesic_build"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    geo = _root_distance(solver, root, inlier, samples)
    tm["distance_root"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    apex_g = _find_apexes(pts, geo, root, p)
    tm["apexes"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    at = _apex_tree(geo, apex_g, root, p)
    tm["tree"] = time.perf_counter() - t1
    seg_params = asdict(p)
    if len(apex_g) == 0:
        log.warning("no leaf apex found (no sample is a strict local maximum of the distance "
                    "from the root over its %d neighbours): every Gaussian is stem",
                    int(min(p.n_neighbors, len(geo.samples) - 1)))
        return _result(n, root, solver.domain, at.tree, np.zeros(0, np.int64), np.zeros(0, np.int32),
                       [], [], np.zeros(n, np.int32), geo.d_root, seg_params)
    t1 = time.perf_counter()
    Dd = solver.domain_distances([[int(a)] for a in at.apex_d])  # (M, A) D_a on the domain
    group = _group_apexes(geo, at, Dd, p)
    tm["grouping"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    leaves = _leaf_bases(pts, geo, at, group, Dd, p)
    labels, group_label, leaf_tip, leaf_base = _label_leaves(geo.d_root, leaves)
    labels[~geo.reach | ~inlier] = 0
    if (~inlier).any() and inlier.sum() > 1:
        attach_outliers(pts, labels, geo.d_root, inlier, geo.reach, p)
    apex_labels = group_label[np.searchsorted(leaves.groups, group)].astype(np.int32)
    tm["petiole_labels"] = time.perf_counter() - t1
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation: %d apexes, %d leaves (%.2f s)", len(apex_g), int(labels.max(initial=0)),
             tm["total"])
    return _result(n, root, solver.domain, at.tree, apex_g, apex_labels, leaf_tip, leaf_base, labels,
                   geo.d_root, seg_params)


def _sample_domain(pts, root, inlier, p: SegmentParams):
    """(samples, domain): (S,) int64 FPS samples of the inliers (the root included) and (M,) int64
    the geodesic domain, the samples plus ``geodesic_points`` random inliers (seeded by ``p.seed``)."""
    rng = np.random.default_rng(p.seed)
    pool = np.flatnonzero(inlier)
    if len(pool) > p.fps_candidates > 0:  # FPS cost is O(N N_s): run it on a random subset
        pool = np.union1d(rng.choice(pool, p.fps_candidates, replace=False), [root])
    start = int(np.searchsorted(pool, root))
    samples = pool[farthest_point_sampling(pts[pool], p.n_samples, start=start)]
    if root not in set(samples.tolist()):
        samples = np.union1d(samples, [root])
    inl = np.flatnonzero(inlier)
    extra = rng.choice(inl, size=min(len(inl), p.geodesic_points), replace=False)
    return samples, np.union1d(samples, extra)


def _root_distance(solver: GeodesicSolver, root, inlier, samples) -> _Geodesics:
    """D_r from the root; floaters and pieces apart from the root are unreached (warned about)."""
    d_root = solver.distance(root)
    d_root[~inlier] = np.inf  # floaters are left out: not reached
    reach = np.isfinite(d_root)
    n = len(d_root)
    lost = int((~reach & inlier).sum())  # connected pieces apart from the root's
    if lost:
        (log.warning if lost > 0.005 * n else log.info)(
            "the cloud is disconnected: %d of %d Gaussians are not connected to the root and stay "
            "unassigned", lost, n)
    return _Geodesics(solver=solver, inlier=inlier, d_root=d_root, reach=reach,
                      samples=samples[reach[samples]])


def _find_apexes(pts, geo: _Geodesics, root, p: SegmentParams) -> np.ndarray:
    """(A,) int64 apex Gaussians, largest D_r first: samples whose D_r is a strict maximum over
    their N_k nearest samples (with ``apex_surface_neighbors``, those also near on the surface)."""
    samples = geo.samples
    sp_pts = pts[samples]
    dr_s = geo.d_root[samples]
    tree_kd = cKDTree(sp_pts)
    nk = int(min(p.n_neighbors, len(samples) - 1))
    apex_local = np.zeros(0, np.int64)
    if nk >= 1:
        kq = int(min(16, nk))
        _, nb16 = tree_kd.query(sp_pts, k=kq + 1, workers=-1)
        # a strict maximum over N_k neighbours is one over its nearest 16 first: test the few
        # survivors against all N_k (same result, ~20x less kNN work)
        cand = np.flatnonzero((dr_s[nb16[:, 1:]] < dr_s[:, None]).all(1) & (samples != root))
        if len(cand):
            d_c, nb_c = tree_kd.query(sp_pts[cand], k=nk + 1, workers=-1)
            d_c, nb_c = d_c.reshape(len(cand), -1), nb_c.reshape(len(cand), -1)
            others = np.where(nb_c == cand[:, None], -1, nb_c)  # drop self
            if p.apex_surface_neighbors:
                others = _surface_filter(geo.solver, samples, cand, others, d_c)
            vals = np.where(others >= 0, dr_s[np.maximum(others, 0)], -np.inf)
            apex_local = cand[(vals < dr_s[cand, None]).all(1)]
    order = apex_local[np.argsort(-dr_s[apex_local], kind="stable")]
    return samples[order]


def _apex_tree(geo: _Geodesics, apex_g, root, p: SegmentParams) -> _ApexTree:
    """The rootward tree through every apex (:func:`build_tree`)."""
    solver = geo.solver
    dr_dom = geo.d_root[solver.domain]
    tree, paths = build_tree(solver, dr_dom, apex_g, root, p)
    return _ApexTree(apex_g=apex_g, apex_d=solver.nearest_domain(apex_g), tree=tree,
                     paths=[np.asarray(pth) for pth in paths], dr_dom=dr_dom)


def _group_apexes(geo: _Geodesics, at: _ApexTree, Dd, p: SegmentParams) -> np.ndarray:
    """(A,) int group id per apex: apexes on one leaf (the tau test and ours, see SegmentParams)
    are joined, the groups are the connected components.

    Dd : (M, A) float64 D_a of every apex on the domain points.
    """
    widths = _RingWidths(geo.solver.domain_points, at.tree.ring)
    anc = at.paths  # tree node indices, apex -> root
    A = len(at.apex_g)
    adj_r, adj_c = [], []
    for i in range(A):
        set_i = {v: k for k, v in enumerate(anc[i].tolist())}
        for j in range(i + 1, A):
            lca = next((v for v in anc[j].tolist() if v in set_i), None)
            if lca is None:
                continue
            pos_j = {v: k for k, v in enumerate(anc[j].tolist())}
            if _one_leaf(geo, at, Dd, widths, (i, set_i[lca]), (j, pos_j[lca]), lca, p):
                adj_r.append(i), adj_c.append(j)
    g = coo_matrix((np.ones(len(adj_r)), (adj_r, adj_c)), shape=(A, A))
    return connected_components(g, directed=False)[1]


def _one_leaf(geo: _Geodesics, at: _ApexTree, Dd, widths: _RingWidths, ik, jk, lca,
              p: SegmentParams) -> bool:
    """Are apexes i and j on one leaf? ik, jk : (apex, position of the LCA on its path); lca : the
    LCA's tree node. Lobes of one blade (``tau_relative``), or the paper's tau test (with
    ``lca_on_blade``, both paths coming to the LCA over a blade)."""
    (i, ki), (j, kj) = ik, jk
    lca_d = int(geo.solver.nearest_domain(geo.solver.domain[at.tree.nodes[lca]]))
    direct = 0.5 * (Dd[at.apex_d[j], i] + Dd[at.apex_d[i], j])
    via = Dd[lca_d, i] + Dd[lca_d, j]
    log.debug("apex pair %d,%d: direct %.3f via lca %.3f (lca D_r %.3f)", i, j, direct, via,
              at.dr_dom[at.tree.nodes[lca]])
    if p.tau_relative > 0 and direct < (1 - p.tau_relative) * via and (
            _all_blade(at, widths, i, ki, p) and _all_blade(at, widths, j, kj, p)):
        return True  # lobes of one blade (see tau_relative)
    return bool(direct < via - p.tau and (not p.lca_on_blade or (
        _on_blade(at, widths, i, ki, lca, p) and _on_blade(at, widths, j, kj, lca, p))))


def _on_blade(at: _ApexTree, widths: _RingWidths, i, k_lca, lca, p: SegmentParams) -> bool:
    """Does apex i's path cross a ring at least epsilon wide within epsilon (in D_r) before
    reaching the LCA? (Lobes of one blade meet where the blade fans out; two leaves meet on
    the stem, each coming down a petiole.)"""
    tree = at.tree
    d0 = at.dr_dom[tree.nodes[lca]]
    for v in at.paths[i][:k_lca][::-1].tolist():
        node_d = tree.nodes[v]
        if at.dr_dom[node_d] > d0 + p.epsilon:
            return False
        if widths(node_d) >= p.epsilon:
            return True
    return False


def _all_blade(at: _ApexTree, widths: _RingWidths, i, k_lca, p: SegmentParams) -> bool:
    """Does apex i's path, once past its narrow tip (a ring at least epsilon wide), stay on
    the blade down to the LCA, never passing a petiole (a ring narrower than epsilon and, with
    ``petiole_relative``, than that fraction of the widest ring seen: the petiole rule)?"""
    w = np.asarray([widths(at.tree.nodes[v]) for v in at.paths[i][:k_lca + 1].tolist()])
    wide = np.flatnonzero(w >= p.epsilon)
    if not len(wide):
        return False
    w = w[wide[0]:]
    petiole = w < p.epsilon
    if p.petiole_relative > 0:
        petiole &= w < p.petiole_relative * np.maximum.accumulate(w)
    return not petiole.any()


def _leaf_bases(pts, geo: _Geodesics, at: _ApexTree, group, Dd, p: SegmentParams) -> _Leaves:
    """Per group, D_a from its primary tip (largest D_r) at every Gaussian and the petiole base
    along the tip's path (:func:`petiole_base`); groups without a blade are dropped when
    ``require_blade``."""
    solver, tree = geo.solver, at.tree
    children = np.zeros(len(tree.nodes), np.int64)
    par = np.asarray(tree.parent)
    np.add.at(children, par[par >= 0], 1)
    groups = np.unique(group)
    tips_j = [int(max(np.flatnonzero(group == gid), key=lambda j: geo.d_root[at.apex_g[j]]))
              for gid in groups]
    D_all = solver.transfer(Dd[:, tips_j], [[int(at.apex_g[j])] for j in tips_j])  # (N, G)
    D_all[~geo.inlier] = np.inf  # a floater's interpolated distance means nothing
    leaves = _Leaves(groups=groups, dist=D_all, keep=[], tip=[], base=[], base_dist=[])
    for col, j in enumerate(tips_j):
        cpath = at.paths[j]
        junction = next((k for k in range(1, len(cpath)) if children[cpath[k]] >= 2), len(cpath) - 1)
        junction_g = int(solver.domain[tree.nodes[cpath[junction]]])
        path_g = solver.domain[np.asarray([tree.nodes[v] for v in at.paths[j].tolist()])]
        base_g, b, has_blade = petiole_base(pts, D_all[:, col], path_g, junction_g, p)
        if p.require_blade and not has_blade:
            log.info("apex %d: no blade wider than epsilon=%.3g along its path; not a leaf",
                     int(at.apex_g[j]), p.epsilon)
            continue
        leaves.keep.append(col), leaves.tip.append(int(at.apex_g[j]))
        leaves.base.append(base_g), leaves.base_dist.append(b)
    return leaves


def _label_leaves(d_root, leaves: _Leaves):
    """(labels (N,) int32, group_label (G,) int32, leaf_tip, leaf_base): each Gaussian goes to the
    leaf where it lies deepest (smallest D_a / base distance) if that is below 1; leaves are
    numbered 1..L bottom to top (D_r of the base)."""
    n = len(d_root)
    labels = np.zeros(n, np.int32)
    group_label = np.zeros(len(leaves.groups), np.int32)
    leaf_tip, leaf_base = leaves.tip, leaves.base
    if leaves.keep:
        ratio = leaves.dist[:, leaves.keep] / np.maximum(np.asarray(leaves.base_dist), 1e-12)[None]
        best = np.argmin(ratio, axis=1)
        inside = ratio[np.arange(n), best] < 1.0
        # order leaves bottom to top (D_r of the base), deterministic labels 1..L
        rank = np.argsort(np.argsort(d_root[np.asarray(leaf_base)], kind="stable"), kind="stable")
        labels[inside] = (rank[best[inside]] + 1).astype(np.int32)
        for k, col in enumerate(leaves.keep):
            group_label[col] = rank[k] + 1
        perm = np.argsort(rank)
        leaf_tip = np.asarray(leaf_tip, np.int64)[perm]
        leaf_base = np.asarray(leaf_base, np.int64)[perm]
    return labels, group_label, leaf_tip, leaf_base


def _surface_filter(solver, samples, cand, nbrs, dists):
    """Keep, of each candidate's N_k Euclidean neighbours, those also reachable along the surface
    graph within the same radius (the distance to its N_k-th neighbour); the rest become -1.

    A Euclidean ball of N_k = 512 of 8192 samples is about one leaf's area: around the tip of a
    small leaf it reaches across the air gap into a neighbouring leaf, whose higher D_r then
    vetoes the apex. Removing only the neighbours that are not on the same surface patch keeps the
    paper's test (and its robustness to noise) where leaves are apart, and fixes crowded plants.
    """
    from scipy.sparse.csgraph import dijkstra

    graph = solver.adjacency(lengths=True)
    near = solver.nearest_domain
    radius = np.where(np.isfinite(dists), dists, 0).max(1)
    out = nbrs.copy()
    step = 64
    for lo in range(0, len(cand), step):
        c = cand[lo:lo + step]
        geo = dijkstra(graph, indices=near(samples[c]), limit=float(radius[lo:lo + step].max()) * 1.5)
        nb = nbrs[lo:lo + step]
        g = np.take_along_axis(geo, near(samples[np.maximum(nb, 0)]), axis=1)
        # along the surface a neighbour is never closer than in space; allow the graph's detour
        # (paths on a point-cloud graph are ~1.2-1.4x the true geodesic)
        far = ~(g <= 1.5 * radius[lo:lo + step, None])
        out[lo:lo + step] = np.where(far, -1, nb)
    return out


def _result(n, root, samples, tree, apex_g, apex_labels, leaf_tip, leaf_base, labels, d_root, prm):
    nodes = samples[np.asarray(tree.nodes, np.int64)]
    parent = np.asarray(tree.parent, np.int64)
    return Segmentation(
        labels=labels.astype(np.int32),
        root_index=int(root),
        apex_indices=np.asarray(apex_g, np.int64),
        apex_labels=np.asarray(apex_labels, np.int32),
        leaf_tip=np.asarray(leaf_tip, np.int64),
        leaf_base=np.asarray(leaf_base, np.int64),
        tree_nodes=nodes,
        tree_parent=parent,
        tree_leaf=labels[nodes].astype(np.int32),
        dist_root=d_root.astype(np.float32),
        params=prm,
    )
