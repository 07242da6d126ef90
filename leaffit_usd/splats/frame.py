"""Frames: input (the capture's own), working (the paper's normalised units), asset (USD).

Working frame convention: the root is at the origin, the plant's up direction is +Z, and the
plant height (extent of the Gaussians along up, from the root) is 1. Every algorithm parameter
(N_s, tau, delta, epsilon, sigma ...) is defined in these units.

``Frame.input_to_working`` is a 4x4 similarity ``x_w = s * R @ (x_in - root)``; its inverse maps
any result back to the input frame exactly (up to float rounding).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.splats.cloud import GaussianCloud, quat_to_matrix

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}


def parse_up(text: str) -> np.ndarray:
    """'+y', '-z', 'y' or 'X,Y,Z' -> (3,) float64 unit vector. Raises ParameterError."""
    t = text.strip().lower()
    sign = -1.0 if t.startswith("-") else 1.0
    key = t.lstrip("+-")
    if key in AXES:
        return sign * np.asarray(AXES[key], dtype=np.float64)
    try:
        v = np.asarray([float(c) for c in t.split(",")], dtype=np.float64)
    except ValueError:
        raise ParameterError("--up", "an axis (+x, -y, z ...) or a vector X,Y,Z", text) from None
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
        raise ParameterError("--up", "a non-zero vector X,Y,Z", text)
    return v / np.linalg.norm(v)


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """(3, 3) float64 rotation R with R @ up = +Z (minimal rotation; deterministic)."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    c = float(up @ z)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])  # 180 degrees about X
    v = np.cross(up, z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1.0 / (1.0 + c))


@dataclass
class Frame:
    """The similarity between the input frame and the working frame.

    root : (3,) float64, input frame
    up : (3,) float64 unit vector, input frame
    height : float, plant height in input units (> 0)
    rotation : (3, 3) float64, input axes -> working axes (rotation @ up = +Z)
    """

    root: np.ndarray
    up: np.ndarray
    height: float
    rotation: np.ndarray

    @staticmethod
    def from_root_up(points: np.ndarray, root: np.ndarray, up: np.ndarray) -> "Frame":
        """Frame with origin at ``root``, +Z along ``up`` and height = extent of ``points`` above root.

        points : (N, 3) input frame. Height is the largest distance along ``up`` from the root
        (robust to a root chosen slightly above the lowest point).
        """
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
        root = np.asarray(root, np.float64)
        h = (np.asarray(points, np.float64) - root) @ up
        height = float(h.max() - min(h.min(), 0.0))
        if not np.isfinite(height) or height <= 0:
            raise ParameterError("points", "a cloud with a positive extent along up", height)
        return Frame(root=root, up=up, height=height, rotation=rotation_to_z(up))

    @property
    def scale(self) -> float:
        """Working units per input unit."""
        return 1.0 / self.height

    @property
    def input_to_working(self) -> np.ndarray:
        """(4, 4) float64 similarity, input frame -> working frame."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = -self.scale * self.rotation @ self.root
        return m

    @property
    def working_to_input(self) -> np.ndarray:
        """(4, 4) float64 similarity, working frame -> input frame."""
        m = np.eye(4)
        m[:3, :3] = self.height * self.rotation.T
        m[:3, 3] = self.root
        return m

    def to_working(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) input frame -> (N, 3) working frame (float64)."""
        return (np.asarray(points, np.float64) - self.root) @ self.rotation.T * self.scale

    def to_input(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) working frame -> (N, 3) input frame (float64)."""
        return np.asarray(points, np.float64) @ self.rotation * self.height + self.root

    def to_dict(self) -> dict:
        return {"root": self.root.tolist(), "up": self.up.tolist(), "height": self.height,
                "rotation": self.rotation.tolist()}

    @staticmethod
    def from_dict(d: dict) -> "Frame":
        return Frame(np.asarray(d["root"], np.float64), np.asarray(d["up"], np.float64),
                     float(d["height"]), np.asarray(d["rotation"], np.float64))


# =============================================================================================
# Helpers that build a Frame from a cloud: up-axis estimation, root choice, cloud transforms.
# =============================================================================================
_UP_SAMPLE = 40_000        # points used by the up estimator (deterministic subsample)
_ROOT_SAMPLE = 60_000      # points used for the connected-component analysis of --root auto
_ROOT_GRAPH_K = 10         # neighbours per sample in that analysis
_ROOT_FAR = 0.10           # --root X,Y,Z must lie within this fraction of the plant size
LOW_UP_CONFIDENCE = 0.35  # below this, estimate_up was wrong in some benchmark runs (benchmarks/up_axis.py)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of (..., 4) quaternions (w, x, y, z); broadcasts, float64."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def similarity_parts(m: np.ndarray, name: str = "m") -> tuple[float, np.ndarray, np.ndarray]:
    """Split a 4x4 similarity ``x' = s R x + t`` into (s, R (3, 3), t (3,)), float64.

    Raises ParameterError when ``m`` is not a similarity (shear, non-uniform scale, reflection,
    projective last row).
    """
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ParameterError(name, "a finite 4x4 matrix", getattr(m, "shape", m))
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise ParameterError(name, "an affine matrix with last row (0, 0, 0, 1)", m[3].tolist())
    a = m[:3, :3]
    det = float(np.linalg.det(a))
    if det <= 0:
        raise ParameterError(name, "a similarity with positive determinant (no reflection)", det)
    s = det ** (1.0 / 3.0)
    r = a / s
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6):
        raise ParameterError(name, "a similarity (rotation * uniform scale + translation)",
                             "a matrix with shear or non-uniform scale")
    return s, r, m[:3, 3].copy()


def transform_cloud(cloud: GaussianCloud, m: np.ndarray, allow_affine: bool = False) -> GaussianCloud:
    """Apply the 4x4 transform ``m`` (column vectors: ``x' = m @ [x, 1]``) to every Gaussian.

    For a similarity ``x' = s R x + t``: means are mapped, quaternions are left-multiplied by
    the rotation's quaternion (their length is kept, so unnormalised input stays unnormalised),
    ``log_scales += log(s)``; opacities and extras are unchanged. With ``allow_affine`` any
    invertible affine map is accepted: covariances ``A S A^T`` are eigen-decomposed into new
    unit quaternions and scales (Gaussian axes are then re-sorted; exact in the covariance).

    SH coefficients are NOT rotated: the view-dependent terms (degree >= 1) stay expressed in
    the old frame's directions (the DC colour, which is what this tool uses, is unaffected).
    Rotating them needs the Wigner D-matrices of each band; renderers of the transformed cloud
    will show slightly wrong view-dependent highlights.

    Returns a new cloud (float32 arrays); ``file_index``/``file_count`` are kept.
    """
    m = np.asarray(m, np.float64)
    try:
        s, r, t = similarity_parts(m)
    except ParameterError:
        if not allow_affine:
            raise
        return _transform_affine(cloud, m)
    from leaffit_usd.splats.cloud import matrix_to_quat

    qr = matrix_to_quat(r[None])[0]
    means = (cloud.means.astype(np.float64) @ (s * r).T + t).astype(np.float32)
    quats = quat_multiply(qr, cloud.quats.astype(np.float64)).astype(np.float32)
    log_scales = (cloud.log_scales.astype(np.float64) + np.log(s)).astype(np.float32)
    return GaussianCloud(means=means, log_scales=log_scales, quats=quats,
                         opacity_logits=cloud.opacity_logits.copy(), sh=cloud.sh.copy(),
                         extra={k: v.copy() for k, v in cloud.extra.items()},
                         file_index=cloud.file_index.copy(), file_count=cloud.file_count)


def _transform_affine(cloud: GaussianCloud, m: np.ndarray) -> GaussianCloud:
    from leaffit_usd.splats.cloud import matrix_to_quat

    if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise ParameterError("transform", "an affine 4x4 matrix", m.tolist())
    a = m[:3, :3]
    if abs(np.linalg.det(a)) < 1e-300:
        raise ParameterError("transform", "an invertible matrix", "a singular matrix")
    means = (cloud.means.astype(np.float64) @ a.T + m[:3, 3]).astype(np.float32)
    rq = quat_to_matrix(cloud.rotations.astype(np.float64))
    s2 = np.exp(2.0 * cloud.log_scales.astype(np.float64))
    cov = np.einsum("nij,nj,nkj->nik", rq, s2, rq)
    cov = np.einsum("ij,njk,lk->nil", a, cov, a)
    w, v = np.linalg.eigh(cov)
    v[np.linalg.det(v) < 0, :, 0] *= -1.0  # proper rotations
    return GaussianCloud(
        means=means, log_scales=(0.5 * np.log(np.maximum(w, 1e-300))).astype(np.float32),
        quats=matrix_to_quat(v).astype(np.float32), opacity_logits=cloud.opacity_logits.copy(),
        sh=cloud.sh.copy(), extra={k: v_.copy() for k, v_ in cloud.extra.items()},
        file_index=cloud.file_index.copy(), file_count=cloud.file_count)


# ---- up axis -----------------------------------------------------------------------------------
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
    """Drop rows whose k-th neighbour is much farther than typical (floaters).

    p : (M, 3 + C); neighbours by the first 3 columns (positions). Returns (M', 3 + C).
    """
    from scipy.spatial import cKDTree

    if len(p) <= 4 * k:
        return p
    d, _ = cKDTree(p[:, :3]).query(p[:, :3], k=k + 1)
    dk = d[:, -1]
    keep = dk <= factor * np.median(dk)
    return p[keep] if keep.sum() > len(p) // 2 else p


def _plane_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to unit vector ``u``."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], axis=1)


_BANDS = (0.05, 0.10, 0.15, 0.20, 0.25)
_OFFSET_WEIGHT = 0.1
_FLAT_WEIGHT = 0.05
_CANOPY_CHECK_DEG = 40.0
_COARSE_DIRS = 300      # directions of the coarse search over the sphere
_COARSE_POINTS = 4000   # points of the coarse search
_STARTS = 5             # distinct coarse minima refined (random coarse sample)
_VOXEL_STARTS = 3       # distinct coarse minima refined (spatially even coarse sample)


def _root_score(p: np.ndarray, u: np.ndarray) -> tuple[float, np.ndarray]:  # noqa: C901
    """How well ``u`` explains 'narrow stem at the bottom, under a wide canopy'. Lower is better.

    p : (M, 3) float64 (floaters removed); u : (3,) unit. Returns (score, root estimate (3,)).
    With heights ``h = p @ u`` (robust extent from the 0.1/99.9 percentiles) and horizontal
    distances measured in the plane perpendicular to ``u``:

    * width term: for bottom bands of 3, 6, 10 and 15 % of the extent, the 90th-percentile
      horizontal distance of the band's points from the band's own centre -- a stem is narrow
      in every horizontal direction, a leaf tip seen "from below" is a widening sheet;
    * offset term (weight 0.3): horizontal distance of the lowest band's centre from the
      canopy's centre (median of the points above 30 % of the extent);

    both divided by the canopy radius (90th-percentile horizontal distance of all points);

    * flatness term (weight 0.05, absolute): ``1 - sqrt(l_min / l_max)`` of the horizontal
      covariance of the 10 % band -- a stem's cut is round, a leaf tip seen edge-on is a line
      (without it, pointed leaf tips won a quarter of the synthetic plants).
    """
    normals = p[:, 3:6] if p.shape[1] == 6 else None
    p = p[:, :3]
    h = p @ u
    lo, hi = np.quantile(h, [0.001, 0.999])
    ext = hi - lo
    if ext <= 0:
        return np.inf, p.mean(0)
    basis = _plane_basis(u)
    x = p @ basis
    canopy = h > lo + 0.3 * ext
    c = np.median(x[canopy], axis=0) if canopy.sum() >= 10 else np.median(x, axis=0)
    radius = np.quantile(np.linalg.norm(x - c, axis=1), 0.9)
    if radius <= 0:
        return np.inf, p.mean(0)
    widths, centre0, flat = [], None, 0.0
    for f in _BANDS:
        band = (h >= lo) & (h <= lo + f * ext)
        if band.sum() < 3:
            band = h <= np.partition(h, 3)[3]
        xb = x[band]
        cb = np.median(xb, axis=0)
        if centre0 is None:
            centre0 = cb
        widths.append(np.quantile(np.linalg.norm(xb - cb, axis=1), 0.9))
        if f == _BANDS[1] and len(xb) >= 5:
            ev = np.linalg.eigvalsh(np.cov(xb.T))
            flat = 1.0 - np.sqrt(max(ev[0], 0.0) / max(ev[1], 1e-300))
            if normals is not None:
                nb = normals[band] @ basis  # (k, 2): a stem's surface normals go all round
                ev = np.linalg.eigvalsh(nb.T @ nb / len(nb))
                flat += 1.0 - np.sqrt(max(ev[0], 0.0) / max(ev[1], 1e-300))
    offset = np.linalg.norm(centre0 - c)
    score = (np.mean(widths) + _OFFSET_WEIGHT * offset) / radius + _FLAT_WEIGHT * flat
    root = basis @ centre0 + u * lo
    return float(score), root


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
            basis = _plane_basis(u)
            for ang in np.linspace(0, 2 * np.pi, 8, endpoint=False):
                d = np.cos(cone) * u + np.sin(cone) * (basis @ [np.cos(ang), np.sin(ang)])
                d /= np.linalg.norm(d)
                sc = _root_score(p, d)[0]
                if sc < score - 1e-9:
                    score, u, improved = sc, d, True
    return u, score


def estimate_up_with_confidence(points: np.ndarray, normals: np.ndarray | None = None) -> UpEstimate:
    """Estimate the up axis of a plant capture in an arbitrary (SfM) frame.

    points : (N, 3) float, input frame (Gaussian centres). Deterministic.
    normals : optional (N, 3) unit vectors, input frame: each Gaussian's shortest axis (see
        :func:`gaussian_normals`); adds the cue "a stem's surface normals point all round".

    Cues (no learning): a plant's root end is narrow (one stem) and lies under the canopy's
    centre, while leaves spread wide above. :func:`_root_score` measures this for a direction
    (lower is better). Principal axes are not reliable candidates (an asymmetric plant's axis is
    often 20-30 degrees off every principal axis and the score is sharp), so the score is
    evaluated on 300 directions spread over the sphere on two 4k-point subsamples (a random one
    and a spatially even one, which keeps a thin stem's points); the best distinct minima
    (> 30 degrees apart; five and three) are refined by a pattern search on the sphere (cones of
    12 and 6 degrees), re-scored on a 40k-point random subsample, and the best is refined there
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
    p = _remove_isolated(_subsample(p[np.isfinite(p).all(1)], _UP_SAMPLE))
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


def gaussian_normals(cloud: GaussianCloud) -> np.ndarray:
    """(N, 3) float32, input frame: each Gaussian's shortest axis (its surface normal when flat)."""
    r = quat_to_matrix(cloud.rotations)
    k = np.argmin(cloud.log_scales, axis=1)
    return np.ascontiguousarray(r[np.arange(len(cloud)), :, k])


# ---- root ----------------------------------------------------------------------------------------
def plant_size(points: np.ndarray) -> float:
    """Robust size of a capture: diagonal of the 0.5-99.5 percentile box, input units."""
    p = np.asarray(points, np.float64)
    lo, hi = np.quantile(p, [0.005, 0.995], axis=0)
    return float(np.linalg.norm(hi - lo))


class MainBlob:
    """The largest connected blob of a capture (the plant without its floaters).

    Connectivity is computed on a deterministic subsample (<= 60k points): each sample is linked
    to its 10 nearest neighbours closer than 4x the median 4-NN spacing (O(n k) edges whatever
    the density). A point belongs to the blob when its nearest sample does and is closer than
    that radius. :meth:`contains` classifies any points; querying only the few points that
    matter (the lowest, the highest) keeps a 1M-Gaussian capture fast.
    """

    def __init__(self, points: np.ndarray):
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        p = np.asarray(points, np.float64)
        n = len(p)
        self.trivial = n < 20
        if self.trivial:
            return
        if n > _ROOT_SAMPLE:
            sidx = np.sort(np.random.default_rng(0).choice(n, _ROOT_SAMPLE, replace=False))
        else:
            sidx = np.arange(n)
        s = p[sidx]
        self.tree = cKDTree(s)
        d, nb = self.tree.query(s, k=min(_ROOT_GRAPH_K + 1, len(s)))
        self.radius = 4.0 * float(np.median(d[:, min(4, d.shape[1] - 1)]))
        if self.radius <= 0:
            self.trivial = True
            return
        ok = d[:, 1:] <= self.radius
        rows = np.repeat(np.arange(len(s)), d.shape[1] - 1)[ok.ravel()]
        g = coo_matrix((np.ones(len(rows)), (rows, nb[:, 1:].ravel()[ok.ravel()])),
                       shape=(len(s), len(s)))
        _, lab = connected_components(g, directed=False)
        self.sample_in = lab == np.bincount(lab).argmax()

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(M, 3) input frame -> (M,) bool."""
        q = np.asarray(points, np.float64).reshape(-1, 3)
        if self.trivial:
            return np.ones(len(q), bool)
        d, near = self.tree.query(q, k=1)
        return self.sample_in[near] & (d <= self.radius)

    def extreme(self, points: np.ndarray, h: np.ndarray, lowest: bool, batch: int = 4096) -> int:
        """Index of the lowest (or highest) point by ``h`` that belongs to the blob."""
        key = h if lowest else -h
        if len(key) > batch:  # usually the answer is among the first few: avoid a full sort
            first = np.argpartition(key, batch)[:batch]
            first = first[np.argsort(key[first], kind="stable")]
            inside = np.flatnonzero(self.contains(points[first]))
            if len(inside):
                return int(first[inside[0]])
        order = np.argsort(key, kind="stable")
        for start in range(0, len(order), batch):
            idx = order[start:start + batch]
            inside = np.flatnonzero(self.contains(points[idx]))
            if len(inside):
                return int(idx[inside[0]])
        return int(order[0])


def _main_component_mask(points: np.ndarray) -> np.ndarray:
    """(N,) bool: points that belong to the largest connected blob (see :class:`MainBlob`)."""
    return MainBlob(points).contains(points)


def _height_range(points: np.ndarray, up: np.ndarray, blob: MainBlob) -> tuple[int, int, np.ndarray]:
    h = np.asarray(points, np.float64) @ up
    return blob.extreme(points, h, True), blob.extreme(points, h, False), h


def auto_root_index(points: np.ndarray, up: np.ndarray, blob: MainBlob | None = None) -> int:
    """Index of the root Gaussian: the bottom of the plant along ``up``, robust to floaters.

    points : (N, 3) input frame; up : (3,) input frame. Among the points of the largest
    connected blob (:class:`MainBlob`), take those within 1 % of the plant's extent above its
    lowest point and return the one nearest to their median (the middle of the stem's cut, not
    a stray edge Gaussian).
    """
    p = np.asarray(points, np.float64)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    blob = blob or MainBlob(p)
    lo, hi, h = _height_range(p, up, blob)
    ext = float(h[hi] - h[lo])
    cand = np.flatnonzero(h <= h[lo] + 0.01 * ext)
    low = cand[blob.contains(p[cand])]
    if len(low) == 0:
        return lo
    med = np.median(p[low], axis=0)
    return int(low[np.argmin(np.linalg.norm(p[low] - med, axis=1))])


def resolve_root(cloud: GaussianCloud, spec: str | None = None, root_index: int | None = None,
                 up: np.ndarray | None = None, _blob: MainBlob | None = None) -> int:
    """The root Gaussian's index into ``cloud`` (0..len(cloud)-1) from the CLI's root options.

    spec : ``"X,Y,Z"`` (the Gaussian nearest to that point, input frame -- what a click picks;
        an error when the point is farther than 10 % of the plant size from every Gaussian),
        ``"auto"`` or None (the lowest point along ``up``, see :func:`auto_root_index`).
    root_index : ``--root-index I``, a Gaussian's position in the input FILE (file order, the
        identity used everywhere); an error when out of range or dropped at load. Exclusive
        with a ``spec`` other than auto/None.
    up : (3,) input frame, needed for auto (estimated when None).
    Raises ParameterError.
    """
    from scipy.spatial import cKDTree

    spec_t = None if spec is None else str(spec).strip()
    if up is None and root_index is not None and np.ndim(root_index) == 1 and np.size(root_index) == 3:
        up, root_index = root_index, None  # called as resolve_root(cloud, spec, up) (TEAM.md form)
    if root_index is not None:
        if spec_t not in (None, "", "auto"):
            raise ParameterError("--root-index", "either --root or --root-index, not both",
                                 f"--root {spec} --root-index {root_index}")
        try:
            i = int(root_index)
        except (TypeError, ValueError):
            raise ParameterError("--root-index", "an integer", root_index) from None
        if i != root_index or not 0 <= i < cloud.file_count:
            raise ParameterError("--root-index", f"an index in 0..{cloud.file_count - 1}", root_index)
        pos = np.searchsorted(cloud.file_index, i)
        if pos >= len(cloud) or cloud.file_index[pos] != i:
            raise ParameterError("--root-index", "a Gaussian that was kept at load "
                                 "(this one was dropped as invalid)", i)
        return int(pos)
    if spec_t in (None, "", "auto"):
        if up is None:
            up = estimate_up(cloud.means, gaussian_normals(cloud))
        return auto_root_index(cloud.means, up, _blob)
    try:
        xyz = np.asarray([float(c) for c in spec_t.split(",")], np.float64)
    except ValueError:
        raise ParameterError("--root", "'auto' or a point X,Y,Z in the input frame", spec) from None
    if xyz.shape != (3,) or not np.isfinite(xyz).all():
        raise ParameterError("--root", "'auto' or a point X,Y,Z in the input frame", spec)
    d, i = cKDTree(cloud.means).query(xyz, k=1)
    size = plant_size(cloud.means)
    if d > _ROOT_FAR * size:
        raise ParameterError("--root", f"a point near the plant (nearest Gaussian is {d:.4g} away, "
                             f"more than 10% of the plant size {size:.4g})", spec)
    return int(i)


class FrameChoice(NamedTuple):
    """Result of :func:`make_frame`: the frame and the root Gaussian's index into the cloud."""

    frame: Frame
    root_index: int


def make_frame(cloud: GaussianCloud, up=None, root: str | None = "auto",
               root_index: int | None = None) -> FrameChoice:
    """Build the input -> working Frame for the pipeline from a cloud and the CLI's options.

    up : None/"auto" (estimated, logged with its confidence), an axis/vector string for
        :func:`parse_up`, or a (3,) vector, input frame.
    root, root_index : as in :func:`resolve_root`.
    The frame's origin is the root Gaussian's centre; height is the extent above it of the
    largest connected blob (floaters do not count).
    """
    import logging

    log = logging.getLogger("leaffit_usd")
    if up is None or (isinstance(up, str) and up.strip().lower() == "auto"):
        est = estimate_up_with_confidence(cloud.means, gaussian_normals(cloud))
        u = est.up
        log.info("estimated up axis (%.3f, %.3f, %.3f), confidence %.2f%s", *u, est.confidence,
                 "" if est.confidence >= LOW_UP_CONFIDENCE else " (low: pass --up to be sure)")
    elif isinstance(up, str):
        u = parse_up(up)
    else:
        u = np.asarray(up, np.float64)
        if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-12:
            raise ParameterError("up", "a non-zero (3,) vector", up)
        u = u / np.linalg.norm(u)
    blob = MainBlob(cloud.means)
    ri = resolve_root(cloud, root, root_index, u, _blob=blob)
    # height: the plant's extent above the root, floaters excluded
    _, hi, _ = _height_range(cloud.means, u, blob)
    pts = cloud.means[[ri, hi]]
    frame = Frame.from_root_up(pts, cloud.means[ri].astype(np.float64), u)
    return FrameChoice(frame, ri)
