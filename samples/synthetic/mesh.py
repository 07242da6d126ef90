"""Small synthetic inputs for the mesh stage's tests and benchmark (no samples needed).

* :func:`synthetic_leaf` — a curved, pointed-elliptic leaf of flat Gaussians with a green top
  layer and a pale bottom layer (a two-sided capture), placed in the working frame by a
  similarity, with the ``LeafFits`` the fit stage would hand over for it;
* :func:`synthetic_tree` — a ``Segmentation`` whose rootward tree is a main stem with branches,
  each ending in a few leaf nodes.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.fit.result import LeafFits
from leaffit_usd.segment.result import Segmentation
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.splats.cloud import GaussianCloud

TOP_RGB = (0.15, 0.55, 0.12)
BOTTOM_RGB = (0.65, 0.80, 0.45)
MARK_TOP = (0.85, 0.10, 0.10)
MARK_BOTTOM = (0.10, 0.15, 0.85)


def leaf_surface(u: np.ndarray, v: np.ndarray, length=1.0, width=0.4, cup=0.25, arch=0.15):
    """Leaf mid-surface, template local frame. u in [0, 1] along the blade, v in [-1, 1] across.

    Half-width ``width/2 * sin(pi u)^0.7`` (pointed base and apex), cupped across (z ~ v^2) and
    arched along (z ~ u(1-u)). Returns (P, 3) points and (P, 3) unit normals (+Z side).
    """
    hw = 0.5 * width * np.sin(np.pi * u) ** 0.7
    x = length * u
    y = hw * v
    z = cup * length * (y / (0.5 * width)) ** 2 * 0.25 + arch * length * u * (1 - u)
    # normal from the partial derivatives (numerical)
    e = 1e-5
    def pos(uu, vv):
        hw_ = 0.5 * width * np.sin(np.pi * uu) ** 0.7
        yy = hw_ * vv
        return np.stack([length * uu, yy, cup * length * (yy / (0.5 * width)) ** 2 * 0.25
                         + arch * length * uu * (1 - uu)], -1)
    du = (pos(np.clip(u + e, 0, 1), v) - pos(np.clip(u - e, 0, 1), v))
    dv = (pos(u, v + e) - pos(u, v - e))
    n = np.cross(du, dv)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    n[n[:, 2] < 0] *= -1
    return np.stack([x, y, z], -1), n


def _similarity(rng, scale):
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(size=3) * 0.8).as_matrix()
    m = np.eye(4)
    m[:3, :3] = R * scale
    m[:3, 3] = rng.normal(size=3) * 0.2
    return m


def synthetic_leaf(n: int = 6000, seed: int = 0, two_sided: bool = True, thickness: float = 0.004,
                   noise: float = 0.002, scale: float = 0.2, length=1.0, width=0.4, cup=0.25,
                   arch=0.15, holes: bool = False, marker: bool = False) -> tuple[GaussianCloud, LeafFits]:
    """A leaf of ``n`` flat Gaussians in the working frame and its ``LeafFits`` (one leaf).

    The template local frame is the leaf's own (petiole base at the origin, +X to the apex, +Z up
    the leaf); ``leaf_to_working`` is a random similarity of scale ``scale``. ``two_sided``: half
    the Gaussians lie ``thickness/2`` above the mid-surface (green, the front) and half below
    (pale, the back); otherwise one green layer. ``holes``: leave a round gap in the blade (a
    missing patch of the capture). ``marker``: the quarter u < 0.4, v > 0.3 (base half, +Y side)
    is red on the top layer and blue on the bottom layer (catches mirrored or flipped textures).
    template_points = mid-surface positions + ``noise`` (as the
    fit's denoising would leave them).
    """
    rng = np.random.default_rng(seed)
    m = int(n * 1.4)
    u = rng.uniform(0, 1, m)
    v = rng.uniform(-1, 1, m)
    if holes:
        ok = (u - 0.55) ** 2 + (v * 0.2) ** 2 > 0.07 ** 2
        u, v = u[ok], v[ok]
    u, v = u[:n], v[:n]
    p, nrm = leaf_surface(u, v, length, width, cup, arch)
    top = (np.arange(len(p)) % 2 == 0) if two_sided else np.ones(len(p), bool)
    side = np.where(top, 0.5, -0.5) * thickness
    centres = p + side[:, None] * nrm
    # flat Gaussians: in-plane sigma ~ the sample spacing, normal sigma tiny
    area = length * width * 0.7
    s = 0.8 * np.sqrt(area / max(len(p), 1)) * (1 + 0.2 * rng.random(len(p)))
    scales = np.stack([s, s * (0.7 + 0.3 * rng.random(len(p))), np.full(len(p), 1e-4 * length)], 1)
    t1 = np.cross(nrm, [0.0, 1.0, 0.0])
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-12)
    t2 = np.cross(nrm, t1)
    Rl = np.stack([t1, t2, nrm], -1)  # columns: local axes
    rgb = np.where(top[:, None], np.asarray(TOP_RGB), np.asarray(BOTTOM_RGB))
    # a vein along the midrib on both sides, darker/lighter, so orientation is visible
    vein = np.abs(v * np.sin(np.pi * u) ** 0.7) < 0.04
    rgb = np.where(vein[:, None], rgb * np.where(top, 0.6, 1.15)[:, None], rgb)
    rgb = np.clip(rgb + rng.normal(0, 0.02, rgb.shape), 0, 1)
    if marker:
        quarter = (u < 0.4) & (v > 0.3)
        rgb[quarter & top] = MARK_TOP
        rgb[quarter & ~top] = MARK_BOTTOM
    M = _similarity(rng, scale)
    sc = scale
    R = M[:3, :3] / sc
    means_w = centres @ M[:3, :3].T + M[:3, 3]
    rot_w = np.einsum("ij,njk->nik", R, Rl)
    cloud = GaussianCloud.from_activated(means_w, scales * sc, matrix_to_quat(rot_w),
                                         np.full(len(p), 0.9), colors=rgb)
    tpl = p + rng.normal(0, noise, p.shape)
    fits = LeafFits(
        template_label=1,
        template_points=tpl.astype(np.float32),
        template_gaussians=np.arange(len(p), dtype=np.int64),
        template_controls=tpl[np.linspace(0, len(tpl) - 1, 32).astype(int)].astype(np.float32),
        leaf_labels=np.array([1], np.int32),
        targets=tpl[np.linspace(0, len(tpl) - 1, 32).astype(int)][None].astype(np.float32),
        leaf_to_working=M[None],
        errors=np.zeros(1, np.float32),
        fallback=np.zeros(1, bool),
    )
    return cloud, fits


def synthetic_tree(n_branches: int = 3, leaves_per_branch: int = 2, seed: int = 0,
                   stem_radius: float = 0.01) -> tuple[Segmentation, np.ndarray]:
    """A Segmentation whose tree is a vertical main stem with ``n_branches`` side branches, each
    forking into ``leaves_per_branch`` petioles ending in 3 leaf nodes; plus the (N, 3) working
    points (tree nodes first, then stem-surface Gaussians of radius ``stem_radius`` around the
    main stem's lower part, so radius estimates have something to measure).
    """
    rng = np.random.default_rng(seed)
    pts, parent, leaf = [np.zeros(3)], [-1], [0]

    def add(p, par, lab):
        pts.append(np.asarray(p, float))
        parent.append(par)
        leaf.append(lab)
        return len(pts) - 1

    prev = 0
    label = 0
    leaf_base = []
    for b in range(n_branches):
        for k in range(4):
            prev = add([0, 0, (b * 4 + k + 1) * 0.05], prev, 0)
        ang = 2 * np.pi * b / n_branches
        d = np.array([np.cos(ang), np.sin(ang), 0.5])
        q = prev
        for k in range(3):
            q = add(pts[prev] + d * 0.04 * (k + 1), q, 0)
        fork = q
        for j in range(leaves_per_branch):
            a2 = ang + (j - (leaves_per_branch - 1) / 2) * 0.8
            d2 = np.array([np.cos(a2), np.sin(a2), 0.3])
            r = add(pts[fork] + d2 * 0.03, fork, 0)
            label += 1
            s = r
            first = None
            for k in range(3):
                s = add(pts[r] + d2 * 0.03 * (k + 1), s, label)
                first = s if first is None else first
            leaf_base.append(first)
    tp = np.asarray(pts)
    S = len(tp)
    # stem surface Gaussians around the lower main stem
    m = 400
    z = rng.uniform(0, 0.1, m)
    th = rng.uniform(0, 2 * np.pi, m)
    ring = np.stack([stem_radius * np.cos(th), stem_radius * np.sin(th), z], 1)
    allp = np.concatenate([tp, ring])
    labels = np.zeros(len(allp), np.int32)
    labels[:S] = np.asarray(leaf, np.int32)
    seg = Segmentation(labels=labels, root_index=0, leaf_base=np.asarray(leaf_base, np.int64),
                       tree_nodes=np.arange(S, dtype=np.int64),
                       tree_parent=np.asarray(parent, np.int64),
                       tree_leaf=np.asarray(leaf, np.int32))
    return seg, allp


STEM_RGB = (0.30, 0.45, 0.12)
BRANCH_RGB = (0.70, 0.15, 0.10)


def synthetic_stem_plant(n: int = 6000, seed: int = 0):
    """A Y-shaped stem captured as surface Gaussians: a gently curved main stem (radius 0.012
    tapering to 0.006, 0.8 tall) and a side branch leaving it at z = 0.35 (radius 0.005, red),
    plus 10 floaters far off and a small blade (label 1) at the branch's end.

    Returns (seg, points (N, 3), colors (N, 3), tubes) where tubes is a list of
    (axis (K, 3), radius (K,)) with the exact centrelines; working frame, root at the origin.
    """
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, 200)
    main = np.stack([0.03 * np.sin(2.5 * t), 0.02 * t ** 2, 0.8 * t], 1)
    r_main = 0.012 - 0.006 * t
    j = int(np.searchsorted(main[:, 2], 0.35))
    d = np.array([0.8, 0.0, 0.6])
    d /= np.linalg.norm(d)
    tb = np.linspace(0, 1, 120)
    branch = main[j] + 0.3 * tb[:, None] * d + np.stack([0 * tb, 0.03 * np.sin(np.pi * tb), 0.05 * tb ** 2], 1)
    r_branch = np.full(len(tb), 0.005)
    tubes = [(main, r_main), (branch, r_branch)]
    pts, cols = [], []
    lengths = [float(np.linalg.norm(np.diff(a, axis=0), axis=1).sum() * r.mean()) for a, r in tubes]
    for (a, r), L, rgb in zip(tubes, lengths, (STEM_RGB, BRANCH_RGB)):
        m = int(n * L / sum(lengths))
        i = rng.integers(0, len(a) - 1, m)
        u = rng.random(m)
        c = a[i] + u[:, None] * (a[i + 1] - a[i])
        tan = a[i + 1] - a[i]
        tan /= np.linalg.norm(tan, axis=1, keepdims=True)
        e1 = np.cross(tan, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(tan, e1)
        ang = rng.uniform(0, 2 * np.pi, m)
        rr = r[i] + u * (r[np.minimum(i + 1, len(r) - 1)] - r[i])
        pts.append(c + (rr + rng.normal(0, 0.0004, m))[:, None] * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2))
        cols.append(np.clip(np.asarray(rgb) + rng.normal(0, 0.02, (m, 3)), 0, 1))
    # a small blade beyond the branch's end (label 1) and floaters far off (label 0)
    tip = branch[-1]
    blade = tip + d * 0.01 + rng.uniform(-1, 1, (300, 3)) * [0.05, 0.03, 0.002] + [0.05, 0, 0]
    floaters = rng.uniform(-1, 1, (10, 3)) * 0.1 + [0.4, 0.4, 0.9]
    P = np.concatenate(pts + [blade, floaters])
    C = np.concatenate(cols + [np.tile([0.2, 0.6, 0.2], (300, 1)), np.tile([0.9, 0.9, 0.9], (10, 1))])
    n_stem = sum(len(p) for p in pts)
    labels = np.zeros(len(P), np.int32)
    labels[n_stem:n_stem + 300] = 1
    root = int(np.argmin(np.linalg.norm(P[:n_stem] - main[0], axis=1)))
    seg = Segmentation(labels=labels, root_index=root)
    return seg, P, C, tubes
