"""Up-axis estimation of a plant capture in an arbitrary (SfM) frame, from geometry alone.

A plant's root end is narrow (one stem) and lies under the canopy's centre, while leaves spread
wide above; :func:`estimate_up_with_confidence` searches the sphere of directions for the one
that explains this best. Input frame throughout.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.outliers import inlier_mask
from leaffit_usd.geometry.plane import plane_basis

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


def _subsample(points: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    points = np.asarray(points)
    if len(points) <= k:
        return np.asarray(points, np.float64)
    idx = np.sort(np.random.default_rng(seed).choice(len(points), k, replace=False))
    return np.asarray(points[idx], np.float64)


def _voxel_subsample(p: np.ndarray, target: int) -> np.ndarray:
    """About ``target`` rows of ``p`` (M, 3 + C), one per occupied voxel (positions = first 3 columns).

    Spatially even, unlike a random subsample: a thin stem keeps about as many points as a
    leaf of the same area would, so the stem cue survives subsampling. Deterministic.
    """
    if len(p) <= target:
        return p
    xyz = p[:, :3]
    lo = xyz.min(0)
    ext = float(np.max(xyz.max(0) - lo)) or 1.0
    size = ext / 64.0
    keep = None
    for _ in range(8):  # surfaces: occupied voxels ~ 1 / size**2
        keys = np.floor((xyz - lo) / size).astype(np.int64)
        _, first = np.unique(keys, axis=0, return_index=True)
        keep = first
        ratio = len(first) / target
        if 0.8 <= ratio <= 1.25:
            break
        size *= np.sqrt(ratio)
    return p[np.sort(keep)]


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


def _root_score(p: np.ndarray, u: np.ndarray) -> tuple[float, np.ndarray]:  # noqa: C901
    """How well ``u`` explains 'narrow stem at the bottom, under a wide canopy'. Lower is better.

    p : (M, 3) or (M, 6) float64 (floaters removed; columns 3-5, when present, are the Gaussians'
    unit normals); u : (3,) unit. Returns (score, root estimate (3,)).
    With heights ``h = p @ u`` (robust extent ``ext`` from the 0.1/99.9 percentiles) and
    horizontal distances measured in the plane perpendicular to ``u``:

    * width term: for bottom bands of 5, 10, 15, 20 and 25 % of the extent, the 90th-percentile
      horizontal distance of the band's points from the band's own centre -- a stem is narrow
      in every horizontal direction, a leaf tip seen "from below" is a widening sheet;
    * offset term (weight 0.1): horizontal distance of the lowest band's centre from the
      canopy's centre (median of the points above 30 % of the extent);

    both divided by the canopy radius (90th-percentile horizontal distance of all points from
    that centre);

    * flatness term (weight 0.05, absolute): ``1 - sqrt(l_min / l_max)`` of the horizontal
      covariance of the 10 % band -- a stem's cut is round, a leaf tip seen edge-on is a line
      (without it, pointed leaf tips won a quarter of the synthetic plants); with normals, the
      same measure of the band's normals projected on the horizontal plane is added (a stem's
      surface normals point all round).

    The root estimate is the lowest band's centre at the bottom of the extent.
    """
    normals = p[:, 3:6] if p.shape[1] == 6 else None
    xyz = p[:, :3]
    h = xyz @ u
    lo, hi = _quantiles(h, (0.001, 0.999))
    ext = hi - lo
    if ext <= 0:
        return np.inf, xyz.mean(0)
    basis = plane_basis(u)
    x = xyz @ basis  # (M, 2) horizontal coordinates
    canopy = h > lo + 0.3 * ext
    xc = x[canopy] if canopy.sum() >= 10 else x
    c = _median2(xc)
    radius = _quantile(np.hypot(x[:, 0] - c[0], x[:, 1] - c[1]), 0.9)
    if radius <= 0:
        return np.inf, xyz.mean(0)
    # the bands are nested: select the widest once, then each band within it
    wide = h <= lo + _BANDS[-1] * ext
    order = np.argsort(h[wide], kind="stable")  # each band is a range of this order
    h_w, x_w = h[wide][order], x[wide][order]
    n_w = normals[wide][order] if normals is not None else None
    start = int(np.searchsorted(h_w, lo, "left"))
    widths, centre0, flat = [], None, 0.0
    for f in _BANDS:
        i0, i1 = start, int(np.searchsorted(h_w, lo + f * ext, "right"))
        if i1 - i0 < 3:  # too few: the lowest four points (and their ties)
            i0, i1 = 0, int(np.searchsorted(h_w, h_w[min(3, len(h_w) - 1)], "right"))
        xb = x_w[i0:i1]
        cb = _median2(xb)
        if centre0 is None:
            centre0 = cb
        widths.append(_quantile(np.hypot(xb[:, 0] - cb[0], xb[:, 1] - cb[1]), 0.9))
        if f == _BANDS[1] and len(xb) >= 5:
            flat = _roundness_defect(_cov2(xb))
            if n_w is not None:
                nh = n_w[i0:i1] @ basis  # (k, 2): a stem's surface normals go all round
                flat += _roundness_defect(nh.T @ nh / len(nh))
    offset = float(np.hypot(*(centre0 - c)))
    score = (np.mean(widths) + _OFFSET_WEIGHT * offset) / radius + _FLAT_WEIGHT * flat
    root = basis @ centre0 + u * lo
    return float(score), root


def _quantile(a: np.ndarray, q: float) -> float:
    """``np.quantile(a, q)`` (linear interpolation) of a 1-D array, with one partition call.

    The up search calls this ~10^4 times on small arrays, where np.quantile's overhead was
    most of the time.
    """
    return float(_quantiles(a, (q,))[0])


def _quantiles(a: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """``np.quantile(a, qs, axis=0)`` (linear interpolation) with one partition call.

    a : (M,) or (M, C); returns (len(qs),) or (len(qs), C).
    """
    n = len(a)
    pos = [q * (n - 1) for q in qs]
    ks = [int(p_) for p_ in pos]
    k1s = [min(k + 1, n - 1) for k in ks]
    part = np.partition(a, sorted(set(ks + k1s)), axis=0)
    t = np.array([p_ - k for p_, k in zip(pos, ks)])
    if a.ndim == 2:
        t = t[:, None]
    return part[ks] + (part[k1s] - part[ks]) * t


def _median2(x: np.ndarray) -> np.ndarray:
    """(2,) per-column medians of an (M, 2) array."""
    return _quantiles(x, (0.5,))[0]


def _cov2(x: np.ndarray) -> np.ndarray:
    """(2, 2) sample covariance of an (M, 2) array (``np.cov(x.T)`` without its overhead)."""
    d = x - x.mean(0)
    return d.T @ d / max(len(x) - 1, 1)


def _roundness_defect(cov: np.ndarray) -> float:
    """``1 - sqrt(l_min / l_max)`` of a symmetric 2x2 matrix (0 = round, 1 = a line)."""
    a, b, d = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    mid, rad = 0.5 * (a + d), np.hypot(0.5 * (a - d), b)
    l_min, l_max = max(mid - rad, 0.0), mid + rad
    return 1.0 - np.sqrt(l_min / max(l_max, 1e-300))


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors spread evenly over the sphere (deterministic)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _refine(p: np.ndarray, u: np.ndarray, score: float, cones=(12.0, 6.0, 3.0, 1.5)):
    for cone in np.radians(cones):
        improved = True
        while improved:
            improved = False
            basis = plane_basis(u)
            for ang in np.linspace(0, 2 * np.pi, 8, endpoint=False):
                d = np.cos(cone) * u + np.sin(cone) * (basis @ [np.cos(ang), np.sin(ang)])
                d /= np.linalg.norm(d)
                sc = _root_score(p, d)[0]
                if sc < score - 1e-9:
                    score, u, improved = sc, d, True
    return u, score


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
    p = p[np.lexsort(p[:, :3].T[::-1])]  # position order: the subsamples ignore the file order
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
                             (_voxel_subsample(p, _COARSE_POINTS), _VOXEL_STARTS)):
        sc = np.array([_root_score(coarse, d)[0] for d in dirs])
        scores = sc if scores is None else scores
        starts = []
        for i in np.argsort(sc):  # the best few distinct (> 30 degrees apart) minima
            if all(dirs[i] @ dirs[j] < np.cos(np.radians(30)) for j in starts):
                starts.append(i)
            if len(starts) == n_starts:
                break
        refined += [_refine(coarse, dirs[i], sc[i], cones=(12.0, 6.0))[0] for i in starts]
    # choose among the refined minima on the full sample: a thin stem holds few points of the
    # coarse one, so its sharp minimum can look worse there than a leaf tip's
    fine = [(_root_score(p, d)[0], k) for k, d in enumerate(refined)]
    _, k_best = min(fine)
    u, best = _refine(p, refined[k_best], fine[k_best][0], cones=(3.0, 1.5))
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
    return UpEstimate(up=u / np.linalg.norm(u), confidence=conf, root=root + center)


def estimate_up(points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) input-frame points -> (3,) float64 unit up vector. See :func:`estimate_up_with_confidence`."""
    return estimate_up_with_confidence(points, normals).up
