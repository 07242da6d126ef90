"""Ray picking of Gaussians: an AABB bounding volume hierarchy and an exact ray–ellipsoid test.

As in the paper (Implementation Details), each Gaussian is bounded by its ellipsoid truncated at
``k = 3`` standard deviations, ``{x : (x - mu)^T Sigma^-1 (x - mu) <= k^2}``, and a ray query
returns the first Gaussian whose ellipsoid the ray enters.

Choice of implementation (numpy only, no compiled extension):

* **Build** — a linear BVH: Gaussians are sorted along a 30-bit Morton curve of their centres
  and grouped into leaves of ``leaf_size`` consecutive Gaussians; the tree above them is a
  complete binary tree stored implicitly in heap order (node ``k`` has children ``2k`` and
  ``2k + 1``, leaves occupy ``[P, 2P)``). Boxes are reduced bottom-up, one vectorised
  ``minimum``/``maximum`` per level. 100k Gaussians build in ~0.1 s.
* **Query** — a breadth-first traversal, one tree level at a time: the slab test runs on the
  whole frontier of nodes at once (a "packet" of nodes instead of a packet of rays), so a query
  costs ``depth`` (~14 for 100k) small numpy calls instead of thousands of Python steps.
  The Gaussians of the leaves reached are then tested exactly (ray–ellipsoid in the Gaussian's
  whitened frame) and the nearest entry point wins.
* open3d's ``RaycastingScene`` would need triangulated ellipsoid proxies, which are not exact at
  the silhouettes (a click at the rim picks a neighbour); an exact test is cheap here, so we use
  our own traversal.

Conventions: rays and Gaussians are in the same frame (the input frame in the viewer). A ray
whose origin lies inside a Gaussian's ellipsoid does not hit that Gaussian (entry points only,
like back-face culling), so a camera inside a large floater still picks what it looks at.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError

TRUNCATION = 3.0  # the paper's truncation scale: bound each Gaussian at 3 sigma


@dataclass(frozen=True)
class PickResult:
    """First Gaussian hit by a ray.

    index : int, Gaussian index into the arrays the BVH was built on (-1 when nothing is hit)
    t : float, ray parameter of the entry point (distance if the direction is unit), inf on a miss
    """

    index: int
    t: float

    @property
    def hit(self) -> bool:
        return self.index >= 0


def _morton_codes(points: np.ndarray) -> np.ndarray:
    """(N,) uint64 30-bit Morton codes of (N, 3) points quantised to a 1024^3 grid of their bbox."""
    lo, hi = points.min(0), points.max(0)
    q = ((points - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).astype(np.uint64)
    q = np.clip(q, 0, 1023)

    def spread(v):  # insert two zero bits between each of the 10 bits
        v = (v | (v << np.uint64(16))) & np.uint64(0x030000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x0300F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x030C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x09249249)
        return v

    return (spread(q[:, 0]) << np.uint64(2)) | (spread(q[:, 1]) << np.uint64(1)) | spread(q[:, 2])


def ellipsoid_whitening(scales: np.ndarray, rotations: np.ndarray, k: float = TRUNCATION) -> np.ndarray:
    """(N, 3, 3) float64 maps ``A`` with ``|A (x - mu)| <= 1`` exactly inside the k-sigma ellipsoid.

    scales : (N, 3) standard deviations (linear, > 0); rotations : (N, 3, 3) columns = local axes.
    ``A = diag(1 / (k s)) R^T``.
    """
    s = np.maximum(np.asarray(scales, np.float64), 1e-30) * k
    r = np.asarray(rotations, np.float64)
    return np.transpose(r, (0, 2, 1)) / s[:, :, None]


def ray_ellipsoid_entry(origin, direction, means, whitening) -> np.ndarray:
    """Entry parameter t >= 0 of a ray into each ellipsoid; inf where missed or origin inside.

    origin, direction : (3,) float, same frame as ``means`` (direction need not be unit);
    means : (M, 3); whitening : (M, 3, 3) from :func:`ellipsoid_whitening`. Returns (M,) float64.
    """
    o = np.einsum("mij,mj->mi", whitening, np.asarray(origin, np.float64) - means)
    d = np.einsum("mij,j->mi", whitening, np.asarray(direction, np.float64))
    a = np.einsum("mi,mi->m", d, d)
    b = np.einsum("mi,mi->m", o, d)
    c = np.einsum("mi,mi->m", o, o) - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t0 = (-b - np.sqrt(disc)) / a
    ok = (disc >= 0) & (c > 0) & (t0 >= 0) & (a > 0)
    return np.where(ok, t0, np.inf)


class GaussianBVH:
    """Bounding volume hierarchy over 3D Gaussians bounded at ``k`` sigma; first-hit ray queries.

    means : (N, 3) float, any frame (rays must be given in the same frame)
    scales : (N, 3) float, standard deviations (linear, not log), same units
    rotations : (N, 3, 3) float, columns are the local axes (``GaussianCloud.rotation_matrices()``)
    pickable : optional (N,) bool; Gaussians set to False are never returned (e.g. low opacity)
    leaf_size : Gaussians per BVH leaf (8 is a good trade-off for numpy)
    """

    def __init__(self, means, scales, rotations, pickable=None, leaf_size: int = 8,
                 k: float = TRUNCATION):
        means = np.asarray(means, np.float64)
        n = len(means)
        if means.ndim != 2 or means.shape[1] != 3:
            raise ParameterError("means", "an (N, 3) array", means.shape)
        scales = np.asarray(scales, np.float64)
        rotations = np.asarray(rotations, np.float64)
        if scales.shape != (n, 3):
            raise ParameterError("scales", f"an ({n}, 3) array", scales.shape)
        if rotations.shape != (n, 3, 3):
            raise ParameterError("rotations", f"an ({n}, 3, 3) array", rotations.shape)
        if leaf_size < 1:
            raise ParameterError("leaf_size", "a positive integer", leaf_size)
        keep = np.ones(n, bool) if pickable is None else np.asarray(pickable, bool).copy()
        keep &= np.isfinite(means).all(1) & np.isfinite(scales).all(1) & np.isfinite(rotations).all((1, 2))
        ids = np.flatnonzero(keep)
        self.n = n
        self.k = float(k)
        self.leaf_size = int(leaf_size)
        # Axis-aligned half extent of the k-sigma ellipsoid: k * sqrt(Sigma_ii), exact.
        cov_diag = np.einsum("nij,nj->ni", rotations[ids] ** 2, scales[ids] ** 2)
        half = self.k * np.sqrt(cov_diag)
        centres = means[ids]
        if len(ids):
            order = np.argsort(_morton_codes(centres), kind="stable")
        else:
            order = np.zeros(0, np.int64)
        self.order = ids[order]  # (M,) original indices in BVH order
        self.means = centres[order]
        self.whitening = ellipsoid_whitening(scales[self.order], rotations[self.order], self.k)
        m = len(self.order)
        n_leaves = max(1, -(-m // self.leaf_size))
        p = 1 << int(np.ceil(np.log2(n_leaves))) if n_leaves > 1 else 1
        self.n_leaf_nodes = p
        self.depth = int(np.log2(p))
        # Leaf boxes: pad to p * leaf_size with empty (NaN) boxes; fmin/fmax skip NaN, and a
        # slab test against a NaN box is False, so empty leaves and subtrees are never entered.
        pad = p * self.leaf_size - m
        lo = np.concatenate([self.means - half[order], np.full((pad, 3), np.nan)])
        hi = np.concatenate([self.means + half[order], np.full((pad, 3), np.nan)])
        # Inflate by a relative epsilon so float rounding in the slab test stays conservative.
        eps = 1e-9 * (1.0 + (np.abs(self.means).max() if m else 0.0))
        box_lo = np.empty((2 * p, 3))
        box_hi = np.empty((2 * p, 3))
        with np.errstate(invalid="ignore"):
            box_lo[p:] = np.fmin.reduce(lo.reshape(p, self.leaf_size, 3), axis=1) - eps
            box_hi[p:] = np.fmax.reduce(hi.reshape(p, self.leaf_size, 3), axis=1) + eps
        level = p
        while level > 1:
            parents = np.arange(level // 2, level)
            box_lo[parents] = np.fmin(box_lo[2 * parents], box_lo[2 * parents + 1])
            box_hi[parents] = np.fmax(box_hi[2 * parents], box_hi[2 * parents + 1])
            level //= 2
        box_lo[0] = np.nan
        box_hi[0] = np.nan
        self.box_lo, self.box_hi = box_lo, box_hi
        self.n_pickable = m

    @staticmethod
    def from_cloud(cloud, pickable=None, **kw) -> "GaussianBVH":
        """BVH over a :class:`~leaffit_usd.splats.cloud.GaussianCloud` (its frame: input)."""
        return GaussianBVH(cloud.means, cloud.scales, cloud.rotation_matrices(), pickable=pickable, **kw)

    def candidates(self, origin, direction, t_max: float = np.inf) -> np.ndarray:
        """(C,) int64 positions in BVH order of Gaussians whose leaf box the ray crosses."""
        o = np.asarray(origin, np.float64)
        d = np.asarray(direction, np.float64)
        d = np.where(np.abs(d) < 1e-300, 1e-300, d)
        inv = 1.0 / d
        nodes = np.array([1], np.int64)
        for lvl in range(self.depth + 1):
            # NaN (empty) boxes give NaN slab values and fail every comparison below.
            t1 = (self.box_lo[nodes] - o) * inv
            t2 = (self.box_hi[nodes] - o) * inv
            tnear = np.minimum(t1, t2).max(1)
            tfar = np.maximum(t1, t2).min(1)
            nodes = nodes[(tnear <= tfar) & (tfar >= 0) & (tnear <= t_max)]
            if nodes.size == 0:
                return np.zeros(0, np.int64)
            if lvl < self.depth:
                nodes = np.concatenate([2 * nodes, 2 * nodes + 1])
        leaves = nodes - self.n_leaf_nodes
        pos = (leaves[:, None] * self.leaf_size + np.arange(self.leaf_size)).ravel()
        return pos[pos < self.n_pickable]

    def pick(self, origin, direction, t_max: float = np.inf) -> PickResult:
        """First Gaussian whose k-sigma ellipsoid the ray ``origin + t * direction`` (t >= 0) enters.

        origin, direction : (3,) float, the BVH's frame. Returns :class:`PickResult`.
        """
        o = np.asarray(origin, np.float64).reshape(3)
        d = np.asarray(direction, np.float64).reshape(3)
        if not (np.isfinite(o).all() and np.isfinite(d).all()) or not np.any(d):
            raise ParameterError("ray", "a finite origin and a non-zero finite direction", (o.tolist(), d.tolist()))
        pos = self.candidates(o, d, t_max)
        if pos.size == 0:
            return PickResult(-1, float("inf"))
        t = ray_ellipsoid_entry(o, d, self.means[pos], self.whitening[pos])
        j = int(np.argmin(t))
        if not np.isfinite(t[j]) or t[j] > t_max:
            return PickResult(-1, float("inf"))
        # Ties (identical Gaussians): the lowest original index wins, as in the brute force.
        best = pos[t == t[j]]
        return PickResult(int(self.order[best].min()), float(t[j]))


def pick_brute_force(means, scales, rotations, origin, direction, pickable=None,
                     k: float = TRUNCATION) -> PickResult:
    """Reference: exact test against every Gaussian (O(N)); for tests and benchmarks."""
    means = np.asarray(means, np.float64)
    w = ellipsoid_whitening(scales, rotations, k)
    t = ray_ellipsoid_entry(origin, direction, means, w)
    if pickable is not None:
        t = np.where(np.asarray(pickable, bool), t, np.inf)
    j = int(np.argmin(t)) if len(t) else -1
    if j < 0 or not np.isfinite(t[j]):
        return PickResult(-1, float("inf"))
    return PickResult(int(np.flatnonzero(t == t[j]).min()), float(t[j]))
