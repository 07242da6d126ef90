"""Up-axis estimation of a plant capture in an arbitrary (SfM) frame, from geometry alone.

A plant's root end is narrow (one stem) and lies under the canopy's centre, while leaves spread
wide above; :func:`estimate_up_with_confidence` searches the sphere of directions for the one
that explains this best. Input frame throughout.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.heat import voxel_subsample
from leaffit_usd.geometry.outliers import inlier_mask
from leaffit_usd.geometry.plane import plane_basis
from leaffit_usd.geometry.sampling import position_order

_UP_SAMPLE = 20_000       # points used by the up estimator (deterministic subsample)
LOW_UP_CONFIDENCE = 0.35  # below this, estimate_up was wrong in some benchmark runs (benchmarks/up_axis.py)


class UpEstimate(NamedTuple):
    """Result of :func:`estimate_up_with_confidence`.

    up : (3,) float64 unit vector, input frame
    confidence : float in [0, 1]; how much better the chosen axis explains "narrow root under
        a wide canopy" than the runner-up (0 = a coin toss, > 0.3 = clear)
    root : (3,) float64, input frame; the estimated root position (bottom of the stem)
    """

    up: np.ndarray
    confidence: float
    root: np.ndarray


def _subsample(p: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """``k`` rows of ``p`` (M, 3 + C) drawn at random (seeded), kept in their order."""
    if len(p) <= k:
        return np.asarray(p, np.float64)
    idx = np.sort(np.random.default_rng(seed).choice(len(p), k, replace=False))
    return np.asarray(p[idx], np.float64)


def _remove_isolated(p: np.ndarray, k: int = 8, factor: float = 4.0) -> np.ndarray:
    """Drop the floaters of ``p`` (M, 3 + C; positions = first 3 columns) unless they are half of it."""
    if len(p) <= 4 * k:
        return p
    keep = inlier_mask(p[:, :3], factor, k)
    return p[keep] if keep.sum() > len(p) // 2 else p


_BANDS = (0.05, 0.10, 0.15, 0.20, 0.25)
_OFFSET_WEIGHT = 0.1
_FLAT_WEIGHT = 0.05
_CANOPY_CHECK_DEG = 40.0
_COARSE_DIRS = 300      # directions of the coarse search over the sphere
_COARSE_POINTS = 2000   # points of the coarse search
_STARTS = 5             # distinct coarse minima refined (random coarse sample)
_VOXEL_STARTS = 3       # distinct coarse minima refined (spatially even coarse sample)
_CHUNK = 1_000_000       # directions x points scored at once (memory: ~50 bytes each)
# leaf-normal check of a low-confidence estimate (see estimate_up_with_confidence)
_NORMAL_CHECK_DEG = 30.0  # the estimate disagrees with the leaves' normal axis beyond this
_NORMAL_AXIS_RATIO = 2.0  # the normals share one axis: its eigenvalue >= this x the next one
_END_BANDS = (0.02, 0.05, 0.10)  # the ends' widths: bands of these fractions of the extent
_END_RATIO = 0.5          # one end is the stem's: at most this x as wide as the other
# (of the 126 benchmark plants' low-confidence answers more than 30 degrees off the normal
# axis, the 19 it turns (each 35-138 degrees off) had ratio >= 2.2 and ends <= 0.30; the 3
# it leaves alone (grasses, right already, whose normal axis is 70-110 degrees off) <= 1.4, >= 0.72)
_GROUP = 32              # directions scored together (similar counts in their lowest 25 %)


def _root_score(p: np.ndarray, u: np.ndarray) -> tuple[float, np.ndarray]:
    """(score, root (3,)) of one direction ``u`` (3,): see :func:`_root_scores`."""
    scores, roots = _root_scores(p, np.asarray(u, np.float64)[None])
    return float(scores[0]), roots[0]


def _root_scores(p: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How well each direction explains 'narrow stem at the bottom, under a wide canopy'.

    p : (M, 3) or (M, 6) float64 (floaters removed; columns 3-5, when present, are the Gaussians'
    unit normals); dirs : (D, 3) unit vectors. Returns (scores (D,), lower is better; roots
    (D, 3), same frame as p). For a direction ``u``, with heights ``h = p @ u`` (robust extent
    ``ext`` from the 0.1/99.9 percentiles) and horizontal distances measured in the plane
    perpendicular to ``u``:

    * width term: for bottom bands of 5, 10, 15, 20 and 25 % of the extent, the 90th-percentile
      horizontal distance of the band's points from the band's own centre (per-axis median) --
      a stem is narrow in every horizontal direction, a leaf tip seen "from below" is a
      widening sheet;
    * offset term (weight 0.1): horizontal distance of the lowest band's centre from the
      canopy's centre (median of the points above 30 % of the extent);

    both divided by the canopy radius (90th-percentile horizontal distance of all points from
    that centre);

    * flatness term (weight 0.05, absolute): ``1 - sqrt(l_min / l_max)`` of the horizontal
      covariance of the 10 % band -- a stem's cut is round, a leaf tip seen edge-on is a line
      (without it, pointed leaf tips won a quarter of the synthetic plants); with normals, the
      same measure of the band's normals projected on the horizontal plane is added (a stem's
      surface normals point all round).

    The root estimate is the lowest band's centre at the bottom of the extent. A band with
    fewer than 3 points is replaced by the lowest four points (and their ties).

    All directions at once (arrays (D, ..., M), medians and quantiles by one sort or partition
    per statistic): the up search scores ~10^3 directions, and one direction at a time spent
    most of its time in numpy's per-call overhead.
    """
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    pt = np.ascontiguousarray(p.T)  # (3 or 6, M): rows for the matrix products
    h = dirs.astype(p.dtype) @ pt[:3]  # (D, M) heights
    lo, hi = _quantiles(h, (0.001, 0.999))
    ext = hi - lo
    # the bands' statistics need, per direction, only its points in the lowest 25 % (a few
    # hundred of 2k to 20k): directions with similar counts are scored together
    n_wide = (h <= (lo + _BANDS[-1] * ext)[:, None]).sum(1)
    order = np.argsort(n_wide, kind="stable")
    step = max(1, min(_GROUP, _CHUNK // len(p)))
    scores, roots = np.empty(len(dirs)), np.empty((len(dirs), 3))
    for i in range(0, len(dirs), step):
        g = order[i:i + step]
        scores[g], roots[g] = _root_scores_group(pt, dirs[g], h[g], lo[g], ext[g], int(n_wide[g].max()))
    return scores, roots


def _root_scores_group(pt, dirs, h, lo, ext, n_wide):
    """:func:`_root_scores` of directions ``dirs`` (D, 3) for the points ``pt`` (3 or 6, M; the
    transpose of ``p``) with heights ``h`` (D, M), their robust bottoms ``lo`` and extents
    ``ext`` (D,), and at most ``n_wide`` points in the lowest 25 %."""
    n_d, m = h.shape
    basis = np.stack([plane_basis(u) for u in dirs])  # (D, 3, 2)
    basis_t = basis.transpose(0, 2, 1).astype(pt.dtype)  # (D, 2, 3)
    x = basis_t @ pt[:3]  # (D, 2, M) horizontal coordinates
    canopy = h > (lo + 0.3 * ext)[:, None]
    canopy[canopy.sum(1) < 10] = True
    c = _masked_quantiles(x, canopy[:, None], (0.5,))[0]  # (D, 2) canopy centre
    radius = _quantiles(_norm2(x - c[:, :, None]), (0.9,))[0]
    # gather, per direction, its L lowest points (L >= every band's count)
    n_wide = min(m, max(4, n_wide))
    idx = np.argpartition(h, n_wide - 1, axis=1)[:, :n_wide] if n_wide < m else np.broadcast_to(np.arange(m), (n_d, m))
    hw = np.take_along_axis(h, idx, 1)  # (D, L)
    xw = np.take_along_axis(x, idx[:, None], 2)  # (D, 2, L)
    fourth = np.partition(hw, 3, axis=1)[:, 3]  # the lowest four points' top
    widths, centre0, flat = [], None, np.zeros(n_d)
    for f in _BANDS:
        band = (hw >= lo[:, None]) & (hw <= (lo + f * ext)[:, None])
        few = band.sum(1) < 3
        band[few] = hw[few] <= fourth[few, None]
        cb = _masked_quantiles(xw, band[:, None], (0.5,))[0]  # (D, 2)
        widths.append(_masked_quantiles(_norm2(xw - cb[:, :, None]), band, (0.9,))[0])
        if centre0 is None:
            centre0 = cb
        if f == _BANDS[1]:
            k = band.sum(1)
            ok = k >= 5
            xb = np.where(band[:, None], xw - (xw * band[:, None]).sum(2, keepdims=True) / k[:, None, None], 0.0)
            flat = np.where(ok, _roundness_defect(xb @ xb.transpose(0, 2, 1) / np.maximum(k - 1, 1)[:, None, None]), 0.0)
            if len(pt) == 6:  # a stem's surface normals go all round
                nw = basis_t @ np.take_along_axis(pt[None, 3:6], idx[:, None], 2)  # (D, 2, L)
                nw = nw * band[:, None]
                flat = flat + np.where(ok, _roundness_defect(nw @ nw.transpose(0, 2, 1) / np.maximum(k, 1)[:, None, None]), 0.0)
    offset = _norm2(centre0 - c)
    with np.errstate(divide="ignore", invalid="ignore"):
        score = (np.mean(widths, axis=0) + _OFFSET_WEIGHT * offset) / radius + _FLAT_WEIGHT * flat
    root = (basis @ centre0[:, :, None])[:, :, 0] + dirs * lo[:, None]
    bad = (ext <= 0) | (radius <= 0)
    score[bad] = np.inf
    root[bad] = pt[:3].mean(1)
    return score, root


def _norm2(v: np.ndarray) -> np.ndarray:
    """Lengths of 2-vectors stored along axis 1: (D, 2, ...) -> (D, ...)."""
    return np.sqrt(v[:, 0] ** 2 + v[:, 1] ** 2)


def _quantiles(a: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """``np.quantile(a, qs, axis=-1)`` (linear interpolation) with one partition (or sort) call.

    a : (..., M); returns (len(qs), ...).
    """
    n = a.shape[-1]
    pos = [q * (n - 1) for q in qs]
    ks = [int(p_) for p_ in pos]
    if len(qs) == 1:
        # one order statistic by a one-kth partition (3-4x faster than with two kth), the next
        # one as the least above it: the same two values
        part = np.partition(a, ks[0], axis=-1)
        v0 = part[..., ks[0]]
        v1 = part[..., ks[0] + 1:].min(-1) if ks[0] + 1 < n else v0
        return (v0 + (v1 - v0) * (pos[0] - ks[0]))[None]
    k1s = [min(k + 1, n - 1) for k in ks]
    kth = sorted(set(ks + k1s))
    # numpy's partition at several kth is slower than a sort (introselect per kth)
    part = np.partition(a, kth, axis=-1) if len(kth) <= 2 else np.sort(a, axis=-1)
    return np.stack([part[..., k] + (part[..., k1] - part[..., k]) * (p_ - k)
                     for p_, k, k1 in zip(pos, ks, k1s)])


def _masked_quantiles(a: np.ndarray, mask: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """Per row, ``np.quantile`` (linear interpolation) of the entries of ``a`` where ``mask``.

    a : (..., M) finite; mask : bool, broadcastable to ``a``, at least one True per row.
    Returns (len(qs), ...). One sort (masked entries as +inf, which sort last).
    """
    mask = np.broadcast_to(mask, a.shape)
    k = mask.sum(-1)
    srt = np.sort(np.where(mask, a, np.inf), axis=-1)
    out = []
    for q in qs:
        pos = q * (k - 1)
        k0 = pos.astype(np.int64)
        k1 = np.minimum(k0 + 1, k - 1)
        v0 = np.take_along_axis(srt, k0[..., None], -1)[..., 0]
        v1 = np.take_along_axis(srt, k1[..., None], -1)[..., 0]
        out.append(v0 + (v1 - v0) * (pos - k0))
    return np.stack(out)


def _roundness_defect(cov: np.ndarray) -> np.ndarray:
    """``1 - sqrt(l_min / l_max)`` of symmetric 2x2 matrices (..., 2, 2) (0 = round, 1 = a line)."""
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    mid, rad = 0.5 * (a + d), np.hypot(0.5 * (a - d), b)
    l_min, l_max = np.maximum(mid - rad, 0.0), mid + rad
    return 1.0 - np.sqrt(l_min / np.maximum(l_max, 1e-300))


def _normal_axis(n: np.ndarray) -> tuple[np.ndarray, float]:
    """The axis the unit normals ``n`` (M, 3) share and how clearly: ``(axis (3,) unit vector,
    sign arbitrary; ratio = largest / second eigenvalue of the normals' scatter sum n n^T)``.

    Leaves face the light, so a broadleaf plant's Gaussian normals (shortest axes, unsigned)
    gather around the up axis (ratio 2.2-14 on the benchmark's broadleaf and thin-leaved plants,
    the axis 1-18 degrees from up); a grass's blades stand on edge and spread theirs around it
    (ratio 1.1-2.0 on its sorghum, wheat, bean and cowpea, the axis up to 84 degrees off).
    """
    w, v = np.linalg.eigh(n.T @ n)
    return v[:, 2], float(w[2] / max(w[1], 1e-300))


def _end_width(p: np.ndarray, u: np.ndarray) -> float:
    """How wide the plant's bottom end is along ``u`` (3,): the mean over the bands of
    ``_END_BANDS`` (fractions of the robust extent, from its 0.1 percentile up) of the band's
    90th-percentile horizontal distance from its own centre (per-axis median), divided by the
    canopy radius (as in :func:`_root_scores`). A stem's end is narrow, a canopy's is wide.
    p : (M, 3 + C) float64, positions first; a band of < 3 points counts as width 0."""
    h = p[:, :3] @ u
    lo, hi = np.quantile(h, (0.001, 0.999))
    ext = hi - lo
    if ext <= 0:
        return 0.0
    x = p[:, :3] @ plane_basis(u)
    canopy = h > lo + 0.3 * ext
    c = np.median(x[canopy] if canopy.sum() >= 10 else x, axis=0)
    radius = np.quantile(np.linalg.norm(x - c, axis=1), 0.9)
    widths = []
    for f in _END_BANDS:
        xb = x[(h >= lo) & (h <= lo + f * ext)]
        widths.append(np.quantile(np.linalg.norm(xb - np.median(xb, axis=0), axis=1), 0.9)
                      if len(xb) >= 3 else 0.0)
    return float(np.mean(widths) / radius) if radius > 0 else 0.0


def _leaf_normal_check(p: np.ndarray, u: np.ndarray) -> np.ndarray | None:
    """A better up than a low-confidence ``u`` (3,) from the leaves' normals, or None.

    p : (M, 6) float64 centred points with unit normals. When the normals share a clear axis
    (:func:`_normal_axis`, ratio >= ``_NORMAL_AXIS_RATIO``) that is more than
    ``_NORMAL_CHECK_DEG`` from ``u``, and one end along that axis is clearly the narrower
    (:func:`_end_width`, at most ``_END_RATIO`` of the other's: the stem's), returns the axis
    pointing away from the narrow end. Otherwise None (keep ``u``).
    """
    a, ratio = _normal_axis(p[:, 3:6])
    if ratio < _NORMAL_AXIS_RATIO or abs(float(u @ a)) >= np.cos(np.radians(_NORMAL_CHECK_DEG)):
        return None
    wa, wb = _end_width(p, a), _end_width(p, -a)
    if max(wa, wb) <= 0 or min(wa, wb) > _END_RATIO * max(wa, wb):
        return None
    return a if wa < wb else -a


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors spread evenly over the sphere (deterministic)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _refine(p: np.ndarray, us: np.ndarray, scores: np.ndarray, cones: tuple[float, ...]):
    """Pattern search on the sphere from each start: ``(us (S, 3), scores (S,))`` improved.

    p : the points :func:`_root_scores` takes; us : (S, 3) unit start directions with their
    scores (S,). For each cone (degrees), every start moves to the best of 8 directions at that
    angle around it while one improves its score; all starts' rings are scored in one call.
    """
    us, scores = np.array(us, np.float64).reshape(-1, 3), np.array(scores, np.float64).reshape(-1)
    ring = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring = np.stack([np.cos(ring), np.sin(ring)])  # (2, 8)
    for cone in np.radians(cones):
        active = np.arange(len(us))
        while len(active):
            cand = np.concatenate([np.cos(cone) * us[i] + np.sin(cone) * (plane_basis(us[i]) @ ring).T
                                   for i in active])  # (8 A, 3)
            cand /= np.linalg.norm(cand, axis=1, keepdims=True)
            sc = _root_scores(p, cand)[0].reshape(len(active), 8)
            best = sc.argmin(1)
            better = sc[np.arange(len(active)), best] < scores[active] - 1e-9
            moved = active[better]
            us[moved] = cand.reshape(len(active), 8, 3)[better, best[better]]
            scores[moved] = sc[better, best[better]]
            active = moved
    return us, scores


def estimate_up_with_confidence(points: np.ndarray, normals: np.ndarray | None = None) -> UpEstimate:
    """Estimate the up axis of a plant capture in an arbitrary (SfM) frame.

    points : (N, 3) float, input frame (Gaussian centres). Deterministic, and independent of the order of the points.
    normals : optional (N, 3) unit vectors, input frame: each Gaussian's shortest axis (see
        :meth:`GaussianCloud.shortest_axes`); adds the cue "a stem's surface normals point all round".

    Cues (no learning): a plant's root end is narrow (one stem) and lies under the canopy's
    centre, while leaves spread wide above. :func:`_root_score` measures this for a direction
    (lower is better). Principal axes are not reliable candidates (an asymmetric plant's axis is
    often 20-30 degrees off every principal axis and the score is sharp), so the score is
    evaluated on 300 directions spread over the sphere on two 2k-point subsamples (a random one
    and a spatially even one, which keeps a thin stem's points); the best distinct minima
    (> 30 degrees apart; five and three) are refined by a pattern search on the sphere (cones of
    12 and 6 degrees), re-scored on a 20k-point random subsample, and the best is refined there
    (cones of 3 and 1.5 degrees).
    ``confidence = 1 - best / best_elsewhere`` with ``best_elsewhere`` the best refined minimum
    more than 45 degrees away (0 = ambiguous; below ``LOW_UP_CONFIDENCE`` check the result).
    A final gravity check replaces the stem direction by the root-to-canopy direction when the
    two differ by more than 40 degrees.

    With normals, a low-confidence answer (below ``LOW_UP_CONFIDENCE``) is checked against the
    leaves: when their normals share a clear axis more than 30 degrees from it and one end
    along that axis is clearly a stem's (:func:`_leaf_normal_check`), that axis, pointing away
    from the narrow end, is the answer (the confidence stays low). On the benchmark plants this
    fixed every low-confidence answer more than 30 degrees off a clear normal axis (19 of 126,
    each 35-138 degrees off; 1-7 degrees after) and changed no other.
    """
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ParameterError("points", "an (N, 3) array", getattr(p, "shape", None))
    if len(p) < 10:
        raise ParameterError("--up auto", "at least 10 Gaussians to estimate the up axis "
                             "(give it with --up)", f"{len(p)} Gaussians")
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != p.shape:
            raise ParameterError("normals", f"shape {p.shape} like points", normals.shape)
        p = np.concatenate([p, normals], axis=1)
    p = p[np.isfinite(p).all(1)]
    p = p[position_order(p[:, :3])]  # position order: the subsamples ignore the file order
    p = _remove_isolated(_subsample(p, _UP_SAMPLE))
    center = np.zeros(p.shape[1])
    center[:3] = p[:, :3].mean(0)
    p = p - center
    center = center[:3]
    dirs = fibonacci_sphere(_COARSE_DIRS)
    refined, scores = [], None
    # two coarse samples: a random one (density-weighted, like the fine sample) and a spatially
    # even one (keeps a thin stem's points); the best distinct minima of each are refined
    for coarse, n_starts in ((_subsample(p, _COARSE_POINTS, seed=1), _STARTS),
                             (p[voxel_subsample(p[:, :3], _COARSE_POINTS)], _VOXEL_STARTS)):
        sc = _root_scores(coarse, dirs)[0]
        scores = sc if scores is None else scores
        starts = []
        for i in np.argsort(sc):  # the best few distinct (> 30 degrees apart) minima
            if all(dirs[i] @ dirs[j] < np.cos(np.radians(30)) for j in starts):
                starts.append(i)
            if len(starts) == n_starts:
                break
        refined += list(_refine(coarse, dirs[starts], sc[starts], cones=(12.0, 6.0))[0])
    # choose among the refined minima on the full sample: a thin stem holds few points of the
    # coarse one, so its sharp minimum can look worse there than a leaf tip's
    fine = [(sc, k) for k, sc in enumerate(_root_scores(p, np.array(refined))[0])]
    _, k_best = min(fine)
    u, best = (a[0] for a in _refine(p, refined[k_best], fine[k_best][0], cones=(3.0, 1.5)))
    cos45 = np.cos(np.radians(45))
    far = [sc for sc, k in fine if refined[k] @ u < cos45]
    if not far:
        far = [sc for d, sc in zip(dirs, scores) if d @ u < cos45]
    second = min(far) if far else np.inf
    conf = float(np.clip(1 - best / second, 0, 1)) if np.isfinite(second) and second > 0 else 0.0
    _, root = _root_score(p, u)
    # Gravity check: the stem's base direction can be far from vertical (a creeping or sharply
    # bent stem) while the canopy still sits above the root. When the canopy's centroid is more
    # than 40 degrees off the stem direction, trust the centroid (and say the answer is shaky).
    to_canopy = p[:, :3].mean(0) - root
    if np.linalg.norm(to_canopy) > 0:
        to_canopy /= np.linalg.norm(to_canopy)
        if u @ to_canopy < np.cos(np.radians(_CANOPY_CHECK_DEG)):
            u, conf = to_canopy, 0.5 * conf
    if p.shape[1] == 6 and conf < LOW_UP_CONFIDENCE:
        checked = _leaf_normal_check(p, u)
        if checked is not None:
            u = checked
            _, root = _root_score(p, u)
    return UpEstimate(up=u / np.linalg.norm(u), confidence=conf, root=root + center)


def estimate_up(points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) input-frame points -> (3,) float64 unit up vector. See :func:`estimate_up_with_confidence`."""
    return estimate_up_with_confidence(points, normals).up
