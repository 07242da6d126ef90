"""Stem generation: the rootward tree's non-leaf edges become tapered cylinders (paper, "Stem Generation").

Radii follow Leonardo's rule: at every junction the cross-section area of the parent branch
equals the sum of its children's. Pure Leonardo with a petiole radius ``r_p`` fixes the root
radius to ``r_p * sqrt(n_leaves)``; the paper lets the user give both a root and a petiole radius
and interpolates. We do it so the rule still holds *exactly* at every junction: the area of an
edge at node ``u`` is

    A(edge, u) = s(t(u)) * n(edge) * pi * r_p**2

with ``n(edge)`` the number of tips (petioles) the edge feeds, ``t(u)`` in [0, 1] the node's
relative position between the root (0) and the tips below it (1):
``t = d(u) / (d(u) + h(u))`` (``d`` path length from the root, ``h`` longest path length to a tip
below), and ``s`` a scale interpolated linearly from ``s_root = r_root**2 / (n_root r_p**2)`` at
the root to 1 at the tips. All edges meeting at a junction share ``s(t(u))``, so parent area =
sum of children's areas there; along an unbranched run the radius tapers smoothly.

Mesh: each maximal unbranched chain is one tube (rings at its nodes, oriented by the averaged
tangent: no gaps at bends); junctions, the root and the tips get a sphere of the largest radius
meeting there, so joints are closed.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh.result import Stem

log = logging.getLogger("leaffit_usd")

DEFAULT_ROOT_RADIUS = 0.01  # working units (plant height 1): used when the capture can't tell
DEFAULT_PETIOLE_RADIUS = 0.003


@dataclass
class StemParams:
    """Stem parameters, working units (plant height = 1).

    root_radius, petiole_radius : cylinder radius at the root and at the petioles; ``None`` =
        estimated from the capture (spread of the stem Gaussians around the root / the leaf bases)
    sides : number of sides of each tube (>= 3)
    sphere_rings : latitude rings of the joint spheres (>= 2); longitude = ``sides``
    estimate_ball : radius of the neighbourhood used by the estimates, working units
    simplify : unbranched runs of tree edges are merged into fewer cylinders while the axis stays
        within ``simplify`` x the local radius of the tree's polyline (Douglas-Peucker); 0 keeps
        every tree edge. Junctions, tips and the root are always kept, so Leonardo's rule holds.
    """

    root_radius: float | None = None
    petiole_radius: float | None = None
    sides: int = 8
    sphere_rings: int = 4
    estimate_ball: float = 0.05
    simplify: float = 0.5

    def validate(self) -> None:
        for name in ("root_radius", "petiole_radius"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive radius (working units) or None", v)
        if int(self.sides) < 3:
            raise ParameterError("sides", "an integer >= 3", self.sides)
        if int(self.sphere_rings) < 2:
            raise ParameterError("sphere_rings", "an integer >= 2", self.sphere_rings)
        if not (np.isfinite(self.simplify) and self.simplify >= 0):
            raise ParameterError("simplify", "a number >= 0 (multiple of the local radius)", self.simplify)
        if not (np.isfinite(self.estimate_ball) and self.estimate_ball > 0):
            raise ParameterError("estimate_ball", "a positive distance", self.estimate_ball)


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


# ---- mesh -------------------------------------------------------------------------------------
def _frame(axis: np.ndarray, ref: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``axis`` (parallel transport of ``ref`` when given)."""
    a = axis / max(np.linalg.norm(axis), 1e-12)
    if ref is None or abs(np.dot(ref, a)) > 0.99:
        ref = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    u = ref - np.dot(ref, a) * a
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def _sphere(center, radius, sides, rings):
    th = np.linspace(0, np.pi, rings + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                     np.cos(th)[:, None].repeat(sides, 1)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]]) * radius + center
    f = []
    R = len(th)
    for j in range(sides):
        j2 = (j + 1) % sides
        f.append([0, 1 + j, 1 + j2])
        for i in range(R - 1):
            a, b = 1 + i * sides + j, 1 + i * sides + j2
            c, d = a + sides, b + sides
            f += [[a, c, d], [a, d, b]]
        last = 1 + R * sides
        f.append([1 + (R - 1) * sides + j, last, 1 + (R - 1) * sides + j2])
    return v, np.asarray(f, np.int64)


def _tube(path: np.ndarray, radii: np.ndarray, sides: int):
    """Tube through ``path`` (P, 3) with per-ring ``radii`` (P,); open ends. Outward faces."""
    P = len(path)
    tang = np.zeros_like(path)
    seg = np.diff(path, axis=0)
    seg /= np.maximum(np.linalg.norm(seg, axis=1, keepdims=True), 1e-12)
    tang[0], tang[-1] = seg[0], seg[-1]
    if P > 2:
        mid = seg[:-1] + seg[1:]
        bad = np.linalg.norm(mid, axis=1) < 1e-9
        mid[bad] = seg[1:][bad]
        tang[1:-1] = mid
    ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    verts = []
    ref = None
    for i in range(P):
        u, w = _frame(tang[i], ref)
        ref = u
        # keep the tube's thickness at bends: scale the ring by 1/cos(half bend angle) (capped)
        scale = 1.0
        if 0 < i < P - 1:
            c = float(np.dot(seg[i - 1], tang[i] / max(np.linalg.norm(tang[i]), 1e-12)))
            scale = 1.0 / max(c, 0.5)
        verts.append(path[i] + radii[i] * scale * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w))
    v = np.concatenate(verts)
    f = []
    for i in range(P - 1):
        for j in range(sides):
            j2 = (j + 1) % sides
            a, b = i * sides + j, i * sides + j2
            f += [[a, b, b + sides], [a, b + sides, a + sides]]
    return v, np.asarray(f, np.int64)


def _rdp(path: np.ndarray, tol: np.ndarray) -> list[int]:
    """Douglas-Peucker on a polyline (P, 3) with a per-vertex tolerance (P,); kept indices."""
    keep = [0, len(path) - 1]
    stack = [(0, len(path) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        a, b = path[i], path[j]
        ab = b - a
        L2 = float(ab @ ab)
        mid = path[i + 1:j]
        t = np.clip(((mid - a) @ ab) / L2, 0, 1) if L2 > 0 else np.zeros(len(mid))
        d = np.linalg.norm(mid - (a + t[:, None] * ab), axis=1)
        k = int(np.argmax(d - tol[i + 1:j]))
        if d[k] > tol[i + 1 + k]:
            keep.append(i + 1 + k)
            stack += [(i, i + 1 + k), (i + 1 + k, j)]
    return sorted(set(keep))


def simplify_chains(points, child, parent, r_parent_end, r_child_end, factor: float):
    """Merge unbranched runs of stem edges (see ``StemParams.simplify``); same array layout.

    points : (S, 3) tree node positions; child, parent : (E,) edge end nodes; radii per edge end.
    """
    if factor <= 0 or len(child) == 0:
        return child, parent, r_parent_end, r_child_end
    S = len(points)
    deg = np.zeros(S, np.int64)
    np.add.at(deg, child, 1)
    np.add.at(deg, parent, 1)
    edge_of_child = np.full(S, -1, np.int64)
    edge_of_child[child] = np.arange(len(child))
    kids: dict[int, list[int]] = {}
    for e, p in enumerate(parent.tolist()):
        kids.setdefault(p, []).append(e)
    out_c, out_p, out_rp, out_rc = [], [], [], []
    for e0 in range(len(child)):
        if deg[parent[e0]] == 2 and edge_of_child[parent[e0]] >= 0:
            continue  # not the start of a chain
        chain = [e0]
        while deg[child[chain[-1]]] == 2 and len(kids.get(int(child[chain[-1]]), [])) == 1:
            chain.append(kids[int(child[chain[-1]])][0])
        nodes = np.concatenate([[parent[chain[0]]], child[chain]])
        radii = np.concatenate([[r_parent_end[chain[0]]], r_child_end[chain]])
        keep = _rdp(points[nodes], factor * radii)
        for i, j in zip(keep[:-1], keep[1:]):
            out_p.append(nodes[i])
            out_c.append(nodes[j])
            out_rp.append(radii[i] if i > 0 else r_parent_end[chain[0]])
            out_rc.append(radii[j])
    return (np.asarray(out_c, np.int64), np.asarray(out_p, np.int64),
            np.asarray(out_rp, np.float64), np.asarray(out_rc, np.float64))


def build_stem(seg, points_working, fits=None, params: StemParams | None = None) -> Stem:
    """Stem cylinders from ``seg``'s rootward tree.

    seg : Segmentation (tree_nodes, tree_parent, tree_leaf, root_index, labels, leaf_base)
    points_working : (N, 3) float, the Gaussians the segmentation ran on, working frame
    fits : LeafFits or None (unused by the geometry; accepted so callers pass the whole state)
    Returns a ``Stem`` (working frame). A tree without stem edges gives an empty stem and a
    warning; a single edge gives one tapered cylinder and a warning.
    """
    params = params or StemParams()
    params.validate()
    pts_all = np.asarray(points_working, np.float64)
    if pts_all.ndim != 2 or pts_all.shape[1] != 3:
        raise ParameterError("points_working", "an (N, 3) array", pts_all.shape)
    nodes = np.asarray(seg.tree_nodes, np.int64)
    if len(nodes) and (nodes.min() < 0 or nodes.max() >= len(pts_all)):
        raise ParameterError("seg.tree_nodes", f"indices in [0, {len(pts_all)})",
                             f"range [{nodes.min()}, {nodes.max()}]")
    if len(np.asarray(seg.tree_parent)) != len(nodes) or len(np.asarray(seg.tree_leaf)) != len(nodes):
        raise ParameterError("seg.tree_parent/tree_leaf", f"{len(nodes)} entries (one per tree node)",
                             f"{len(np.asarray(seg.tree_parent))}/{len(np.asarray(seg.tree_leaf))}")
    root_r, pet_r = _resolve_radii(params, seg, pts_all, fits)
    child, parent, r_p_end, r_c_end, n_tips, _, _ = leonardo_radii(seg, pts_all, root_r, pet_r)
    n_tree_edges = len(child)
    child, parent, r_p_end, r_c_end = simplify_chains(pts_all[nodes], child, parent, r_p_end,
                                                      r_c_end, float(params.simplify))
    if len(child) < n_tree_edges:
        log.info("stem: %d tree edges -> %d cylinders (simplify=%g)", n_tree_edges, len(child),
                 params.simplify)
    empty = Stem(starts=np.zeros((0, 3), np.float32), ends=np.zeros((0, 3), np.float32),
                 radii_start=np.zeros(0, np.float32), radii_end=np.zeros(0, np.float32),
                 parent=np.zeros(0, np.int64), points=np.zeros((0, 3), np.float32),
                 faces=np.zeros((0, 3), np.int32))
    if len(child) == 0:
        log.warning("stem: the segmentation tree has no stem edges; writing no stem")
        return empty
    if n_tree_edges == 1:
        log.warning("stem: the segmentation tree has a single stem edge; the stem is one tapered cylinder")
    tp = pts_all[nodes]
    starts, ends = tp[parent], tp[child]
    # parent cylinder of each edge: the edge whose child node is this edge's parent node
    edge_of_child = np.full(len(nodes), -1, np.int64)
    edge_of_child[child] = np.arange(len(child))
    e_parent = edge_of_child[parent]

    # ---- mesh: chains of unbranched edges -> tubes; spheres at junctions, roots and tips ----
    kids: dict[int, list[int]] = {}
    for e, p in enumerate(parent.tolist()):
        kids.setdefault(p, []).append(e)
    deg = np.zeros(len(nodes), np.int64)  # stem-graph degree
    np.add.at(deg, child, 1)
    np.add.at(deg, parent, 1)
    sides, rings = int(params.sides), int(params.sphere_rings)
    V, F, nv = [], [], 0
    done = np.zeros(len(child), bool)
    for e0 in range(len(child)):
        # start a chain at an edge whose parent node is a key node (not a degree-2 pass-through)
        if done[e0] or (deg[parent[e0]] == 2 and e_parent[e0] >= 0):
            continue
        chain = [e0]
        while True:
            c = child[chain[-1]]
            nxt = kids.get(int(c), [])
            if deg[c] == 2 and len(nxt) == 1:
                chain.append(nxt[0])
            else:
                break
        done[chain] = True
        path = np.concatenate([[starts[chain[0]]], ends[chain]])
        radii = np.concatenate([[r_p_end[chain[0]]], r_c_end[chain]])
        v, f = _tube(path, radii, sides)
        V.append(v)
        F.append(f + nv)
        nv += len(v)
    # any edge not reached (cycles can't occur in a tree; safety for odd inputs)
    for e in np.flatnonzero(~done):
        v, f = _tube(np.stack([starts[e], ends[e]]), np.array([r_p_end[e], r_c_end[e]]), sides)
        V.append(v)
        F.append(f + nv)
        nv += len(v)
    # joint spheres: every stem-graph node that is not a degree-2 pass-through
    node_r = np.zeros(len(nodes))
    np.maximum.at(node_r, parent, r_p_end)
    np.maximum.at(node_r, child, r_c_end)
    for u in np.flatnonzero((deg > 0) & (deg != 2)):
        v, f = _sphere(tp[u], node_r[u], sides, rings)
        V.append(v)
        F.append(f + nv)
        nv += len(v)
    # degree-2 nodes joining two chains that are not one chain (e.g. a forest root of degree 2)
    for u in np.flatnonzero(deg == 2):
        if edge_of_child[u] < 0:  # a root with two children: close it with a sphere
            v, f = _sphere(tp[u], node_r[u], sides, rings)
            V.append(v)
            F.append(f + nv)
            nv += len(v)
    return Stem(starts=starts.astype(np.float32), ends=ends.astype(np.float32),
                radii_start=r_p_end.astype(np.float32), radii_end=r_c_end.astype(np.float32),
                parent=e_parent.astype(np.int64),
                points=np.concatenate(V).astype(np.float32),
                faces=np.concatenate(F).astype(np.int32))
