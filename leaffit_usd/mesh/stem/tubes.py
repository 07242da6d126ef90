"""From streams to swept tubes (:class:`Tube`, working frame): smoothed axes, rings along
rotation-minimising frames, rounded tips, branches seated on their parents, the mesh at
each level of detail and its vertex colours.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.mesh.stem.params import StemParams
from leaffit_usd.mesh.stem.skeleton import Skeleton, streams


# (sides, ring spacing multiplier) of the coarser levels of detail, after LOD0's own
LOD_LEVELS = ((6, 2.0), (4, 4.0))


# a stream's node whose spread exceeds this multiple of the stream's median holds several tubes
# (the ratio of ``_inside_other_tubes``: 1.5 radii)
_MERGED_SPREAD = 1.5


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


def polyline_distance(q: np.ndarray, poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
class Tube:
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


def stream_tubes(sk: Skeleton, areas: np.ndarray, points: np.ndarray, params: StemParams,
           smoothed: dict | None = None) -> list[Tube]:
    w = float(params.level_width)
    tubes: list[Tube] = []
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
        tubes.append(Tube(axis=fine, radii=rf, cap_start=not is_branch, parent_tube=parent_tube,
                           attach=fine[0], stream=si, own=own))
    tube_of = {tb.stream: i for i, tb in enumerate(tubes)}
    for tb in tubes:  # stream index -> tube index (a stream too short to sweep has no tube)
        tb.parent_tube = tube_of.get(tb.parent_tube, -1)
    return tubes


def seat_branches(tubes: list[Tube]) -> list[Tube]:
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
        d, t = polyline_distance(tb.axis, par.axis)
        rp = np.interp(t, np.arange(len(par.radii)), par.radii)
        seen = np.zeros(len(tb.axis), bool)
        if tb.own is not None and len(tb.own):
            # its Gaussians deep inside the parent (not the parent's wall around the junction)
            dq, tq = polyline_distance(tb.own, par.axis)
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


def vertex_colors(verts: np.ndarray, src_pts: np.ndarray, src_col: np.ndarray, k: int = 8):
    from scipy.spatial import cKDTree

    if len(src_pts) == 0:
        return None
    k = min(k, len(src_pts))
    d, j = cKDTree(src_pts).query(verts, k=k)
    if k == 1:
        return src_col[j]
    w = 1.0 / np.maximum(d, 1e-9)
    return (src_col[j] * w[..., None]).sum(1) / w.sum(1, keepdims=True)


def tubes_mesh(tubes: list[Tube], sides: int, spacing_mult: float, params: StemParams):
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


def tube_residual(tubes: list[Tube], q: np.ndarray) -> np.ndarray:
    """(M,) distance of points q (M, 3) outside the swept tubes: distance to the nearest tube's
    axis minus its radius there (negative inside)."""
    res = np.full(len(q), np.inf)
    for tb in tubes:
        d, t = polyline_distance(q, tb.axis)
        res = np.minimum(res, d - np.interp(t, np.arange(len(tb.radii)), tb.radii))
    return res
