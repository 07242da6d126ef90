"""The paper's apex method, its two marches over the geodesic domain (``segment.apex``): the
rootward tree (steepest descent of ``D_r`` from every apex with the deferred-merge rule, paths on
one cross-section ring merging) and the petiole march (the local diameter along a leaf's path to
where it drops under epsilon: the base). See :mod:`leaffit_usd.segment.apex` for the method and
where ours departs from the paper's."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.sparse import coo_matrix

from leaffit_usd.geometry.heat import GeodesicSolver
from leaffit_usd.segment.params import SegmentParams


@dataclass
class RootwardTree:
    """The rootward tree over the geodesic domain (paper step 3)."""

    nodes: list          # domain positions, in insertion order
    parent: list         # index into nodes, -1 for the root
    pos: dict            # domain position -> node index
    ring: np.ndarray | None = None  # (M,) cross-section ring id of every domain point


def build_tree(solver: GeodesicSolver, dr_dom, apex_g, root, p: SegmentParams):
    """Rootward tree by steepest descent of D_r with the deferred-merge rule.

    The descent runs over the geodesic operator's own surface graph (its triangle and 1-D element
    edges between domain points), so a path never leaps across the air gap between two leaves, as
    a Euclidean neighbourhood among the samples does. "The neighbourhood of p_k contains a visited
    node" is read on the surface too: p_k touches the tree when a visited point lies on the same
    cross-section ring, i.e. in the same connected piece of the D_r iso-band (width
    max(delta, 3 h)) through p_k (the girth of a stem, the width of a blade). Paths on opposite
    sides of a thick stem thus meet at the first ring they share, and paths on two leaves that
    are close in space but not on one surface never do. Deferred merge: the first touch is
    ignored; if the next point touches too, the path attaches to the nearest visited point of its
    ring (the junction).

    dr_dom : (M,) D_r at the domain points; apex_g : (A,) apex Gaussians, farthest first.
    Returns the tree (nodes = domain positions) and per apex its path apex -> root (node indices).
    """
    adj = solver.adjacency()
    ring = _cross_section_rings(solver, adj, dr_dom, p)
    root_d = int(solver.nearest_domain(root))
    tree = RootwardTree(nodes=[root_d], parent=[-1], pos={root_d: 0}, ring=ring)
    ring_nodes = {int(ring[root_d]): [0]}  # ring id -> tree nodes on it
    paths = []
    for a in apex_g.tolist():
        a_d = int(solver.nearest_domain(a))
        if a_d not in tree.pos:
            chain, attach_node = _descend(solver, adj, dr_dom, tree, ring_nodes, a_d)
            par_node = attach_node
            for v in reversed(chain):
                tree.pos[v] = len(tree.nodes)
                tree.nodes.append(v)
                tree.parent.append(par_node)
                par_node = tree.pos[v]
                ring_nodes.setdefault(int(ring[v]), []).append(par_node)
        paths.append(_path_to_root(tree, tree.pos[a_d]))
    return tree, paths


def _cross_section_rings(solver: GeodesicSolver, adj, dr_dom, p: SegmentParams) -> np.ndarray:
    """(M,) int ring id of each domain point: the connected pieces (over the surface graph
    ``adj``) of the D_r iso-bands of width max(delta, 3 h); unreached points share band -1."""
    m = len(dr_dom)
    w = max(p.delta, 3 * solver.h)
    band = np.where(np.isfinite(dr_dom), np.floor(np.nan_to_num(dr_dom, posinf=-w) / w), -1).astype(np.int64)
    coo = adj.tocoo()
    same = band[coo.row] == band[coo.col]
    sub = coo_matrix((np.ones(int(same.sum())), (coo.row[same], coo.col[same])), shape=(m, m))
    return connected_components(sub, directed=False)[1]


def _descend(solver: GeodesicSolver, adj, dr_dom, tree: RootwardTree, ring_nodes: dict, start: int):
    """Steepest descent of D_r over the surface graph from domain position ``start`` until the
    path meets the tree (deferred merge). Returns (chain: the new domain positions, start first;
    the tree node the chain's last point attaches to)."""
    x = solver.domain_points
    m = len(x)
    cur, chain, pending, attach_node = start, [start], False, 0
    for _ in range(m + 1):
        hit = _touched(x, tree, ring_nodes, cur)
        if hit >= 0 and pending:
            attach_node = hit
            break
        pending = hit >= 0
        nb = adj.indices[adj.indptr[cur]:adj.indptr[cur + 1]]
        lower = nb[dr_dom[nb] < dr_dom[cur]]
        if len(lower) == 0:  # a local minimum of the graph (noise): look a little wider
            wnb = solver.domain_neighbors(x[cur], int(min(32, m)))
            lower = wnb[dr_dom[wnb] < dr_dom[cur]]
        if len(lower) == 0:
            attach_node = hit if hit >= 0 else 0
            break
        nxt = int(lower[np.argmin(dr_dom[lower])])
        if nxt in tree.pos:
            attach_node = tree.pos[nxt]
            break
        chain.append(nxt)
        cur = nxt
    return chain, attach_node


def _touched(x, tree: RootwardTree, ring_nodes: dict, c: int) -> int:
    """The tree node on domain point c's ring nearest to it, or -1 when the ring has none."""
    cand = ring_nodes.get(int(tree.ring[c]))
    if not cand:
        return -1
    pos = x[[tree.nodes[t] for t in cand]]
    return int(cand[int(np.argmin(((pos - x[c]) ** 2).sum(1)))])


def _path_to_root(tree: RootwardTree, node: int) -> list:
    out = []
    while node >= 0:
        out.append(node)
        node = tree.parent[node]
    return out


def petiole_base(pts, d_a, path_g, junction_g, p: SegmentParams):
    """March from the tip along ``path_g`` (Gaussians, tip -> root); returns (base Gaussian,
    base distance D_a[base], whether some node had a local diameter >= epsilon).

    d_a : (N,) D_a of this leaf's primary tip at every Gaussian; junction_g : the Gaussian at the
    first junction of the tip's path in the paper's tree (the protection window is the first
    ``rho`` of D_a up to it).
    """
    dvals = d_a[path_g]
    protect = p.rho * d_a[junction_g]
    junction = int(np.searchsorted(np.maximum.accumulate(dvals), d_a[junction_g]))
    junction = min(max(junction, 1), len(path_g) - 1)
    fin = np.isfinite(d_a)
    limit = dvals.max() + p.delta
    cand = np.flatnonzero(fin & (d_a <= limit))
    order = cand[np.argsort(d_a[cand], kind="stable")]
    sd = d_a[order]
    has_blade = False

    def diameter(k):
        c = dvals[k]
        lo = np.searchsorted(sd, c - p.delta / 2, side="left")
        hi = np.searchsorted(sd, c + p.delta / 2, side="right")
        band = order[lo:hi]
        return float(np.sqrt(((pts[band] - pts[path_g[k]]) ** 2).sum(1).max())) if len(band) else 0.0

    widest = 0.0
    for k in range(1, len(path_g)):
        c = dvals[k]
        diam = diameter(k)
        widest = max(widest, diam)
        if diam >= p.epsilon:
            has_blade = True
        narrow = diam < p.epsilon and (p.petiole_relative <= 0 or diam < p.petiole_relative * widest)
        if c >= protect and narrow and (has_blade or not p.blade_first):
            if p.base_refine:
                k = _refine_base(k, diam, dvals, diameter, p)
            return int(path_g[k]), float(dvals[k]), has_blade
    # never narrower than epsilon before the root: base at the first junction
    return int(path_g[junction]), float(dvals[junction]), has_blade


def _refine_base(k0, d0, dvals, diameter, p: SegmentParams) -> int:
    """From the first node under epsilon, move on to where the blade has narrowed to the
    petiole's own diameter: the least diameter within 2 epsilon further on (the petiole plateau),
    and the first node within max(1.25 x, + delta) of it."""
    ks = [k0]
    ds = [d0]
    k = k0 + 1
    while k < len(dvals) and dvals[k] <= dvals[k0] + 2 * p.epsilon:
        ks.append(k)
        ds.append(diameter(k))
        k += 1
    plateau = min(ds)
    level = max(1.25 * plateau, plateau + p.delta)
    for kk, dd in zip(ks, ds):
        if dd <= level:
            return kk
    return k0
