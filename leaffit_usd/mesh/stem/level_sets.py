"""The skeleton from the stem Gaussians themselves (:func:`gaussian_skeleton`): a k-NN graph,
geodesic level sets from the base ring, one node per level-set piece; and the missed-tube
pass (:func:`missed_tubes`): stem Gaussians off every tube become extra chains.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.mesh.stem.params import StemParams
from leaffit_usd.mesh.stem.skeleton import (centre_junctions, continue_branches, prune_spurs,
                                            recentre_nodes, reroot, Skeleton, skeleton_residual)


# the coverage pass (tubes already swept) takes groups of off-tube Gaussians from this size on:
# four points are the fewest that give a direction beyond their centroid (the first pass, which
# builds the tubes, still wants 8 and level sets)
SMALL_MIN = 4


@dataclass
class GraphContext:
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
    sk = reroot(sk, root)
    sk = recentre_nodes(sk, points)
    sk = centre_junctions(prune_spurs(sk, float(params.prune) * w))
    # the missed tubes are thin: their level sets need not be as wide as the base, only as the
    # graph's reach
    w_thin = max(float(params.level_width), float(params.reach_level_ratio) * reach)
    sk = missed_tubes(sk, points, idx, G, g, params, w_thin)
    sk = continue_branches(sk, w)
    sk.graph = GraphContext(idx=idx, G=G, g=g, w_thin=w_thin)
    return sk


def missed_tubes(sk: Skeleton, points: np.ndarray, idx: np.ndarray, G, g: np.ndarray,
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
    if flag.sum() < (SMALL_MIN if add_only else 8):
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
        if ch is None and add_only and len(rows) >= SMALL_MIN:
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
    return reroot(recentre_nodes(out, points, only=new), 0)


def _off_tubes(sk: Skeleton, q: np.ndarray, w0: float) -> np.ndarray:
    """(M,) bool: the skeleton's member Gaussians q (M, 3) off every tube's surface, outside it
    (farther than a quarter of ``w0`` and than three robust standard deviations of all the
    offsets) or deep inside it (the hidden base of a branch that starts inside its parent, when
    the capture has Gaussians there)."""
    res = skeleton_residual(sk, q)
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
