"""Tube radii (working units): estimated from the capture when not given, the tree's Leonardo
prior per node, each node's observed area, and the sparse least-squares solve of data,
smoothness and Leonardo's rule (:func:`solve_areas`).
"""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.mesh.stem.params import StemParams
from leaffit_usd.mesh.stem.skeleton import Skeleton, streams
from leaffit_usd.mesh.stem.tubes import polyline_distance, stream_tubes

log = logging.getLogger("leaffit_usd")


DEFAULT_ROOT_RADIUS = 0.01  # working units (plant height 1): used when the capture can't tell


DEFAULT_PETIOLE_RADIUS = 0.003


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


def leonardo_prior(sk: Skeleton, root_r: float, pet_r: float) -> np.ndarray:
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


def observed_areas(sk: Skeleton, points: np.ndarray, params: StemParams):
    """Per node: (observed area (n,), weight (n,)) from its Gaussians' distances to the smoothed
    axis of its stream."""
    n = len(sk.pos)
    obs, wt = np.zeros(n), np.zeros(n)
    if not len(sk.members):
        return obs, wt
    smoothed: dict = {}
    tubes = stream_tubes(sk, np.full(n, 1e-6), points, params, smoothed)
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
        d, _ = polyline_distance(mem_pos[sel], axis)
        nodes = sk.member_node[sel]
        for u in np.unique(nodes):
            du = d[nodes == u]
            if len(du) >= 3:
                obs[u] = float(np.median(du)) ** 2
                wt[u] = len(du)
    ref = np.median(wt[wt > 0]) if (wt > 0).any() else 1.0
    return obs, np.minimum(wt / ref, 1.0)


def prior_radii(sk: Skeleton, obs: np.ndarray, wt: np.ndarray, seg, pts_all: np.ndarray, fits,
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
