"""The stem skeleton (:class:`Skeleton`: a rooted tree of axis nodes, working frame) and the
operations on it: streams, spur pruning, re-hanging a branch where its own direction meets
its parent, junction placement, nodes moved onto their tube's axis; and the segmentation's
rootward tree as a skeleton (the paper's, :func:`tree_skeleton`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np



# a node with fewer Gaussians of its own than this is not circle-fitted next to a junction
# (:func:`recentre_nodes`): 3 points are the fewest that fix a circle
_FEW_OWN = 3


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
    graph: "GraphContext | None" = None

    def __post_init__(self):
        if self.spread is None:
            self.spread = np.zeros(len(self.pos))

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in range(len(self.pos))]
        for c, p in enumerate(self.parent.tolist()):
            if p >= 0:
                kids[p].append(c)
        return kids


def skeleton_residual(sk: Skeleton, q: np.ndarray) -> np.ndarray:
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
    return reroot(Skeleton(pos=sk.pos, parent=par, count=sk.count, members=sk.members,
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


def reroot(sk: Skeleton, root: int) -> Skeleton:
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
    return reroot(sk, main)


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


def drop_subtrees(sk: Skeleton, drop: np.ndarray) -> Skeleton:
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
