"""The root Gaussian of a plant capture: the bottom of the largest connected blob along up, or
the Gaussian nearest a given point, or a given file index. Input frame throughout."""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.sampling import position_order_sample
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.up_axis import estimate_up

_ROOT_SAMPLE = 60_000      # points used for the connected-component analysis of --root auto
                           # (20k is 0.4 s faster at 100k but loses sparse parts of unevenly
                           # sampled plants: hard4 apple's root and height changed)
_ROOT_GRAPH_K = 10         # neighbours per sample in that analysis
_ROOT_FAR = 0.10           # --root X,Y,Z must lie within this fraction of the plant size
_JOIN_SHARE = 0.002        # a component of at least this share of the samples can join the blob
_JOIN_GAP = 0.15           # ... when within this fraction of the largest one's size of the blob


def plant_size(points: np.ndarray) -> float:
    """Robust size of a capture: diagonal of the 0.5-99.5 percentile box, input units."""
    p = np.asarray(points, np.float64)
    lo, hi = np.quantile(p, [0.005, 0.995], axis=0)
    return float(np.linalg.norm(hi - lo))


class MainBlob:
    """The plant's connected blob in a capture: its largest connected component, with the large
    components near it (the plant without its floaters).

    Connectivity is computed on a deterministic, file-order-free subsample (<= 60k points): each
    sample is linked to its 10 nearest neighbours closer than 4x the median 4-NN spacing (O(n k)
    edges whatever the density). A plant is often several such components: a thin or sparsely
    sampled stem, a hole in uneven density or a gap where a petiole meets the stem cuts it
    (the trimmed rubber tree's stem and lower leaves were 12k of 60k samples apart from the
    canopy's 38k, so the "lowest point" was a leaf tip 0.42 x the height above the stem base).
    So components of at least ``_JOIN_SHARE`` of the samples join the largest when they lie
    within ``_JOIN_GAP`` x its size (bounding-box diagonal) of what has joined, transitively;
    floaters (single Gaussians, small clumps) and far objects stay out. A point belongs to the
    blob when its nearest sample does and is closer than the linking radius. :meth:`contains`
    classifies any points; querying only the few points that matter (the lowest, the highest)
    keeps a 1M-Gaussian capture fast.
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
        s = p[position_order_sample(p, _ROOT_SAMPLE, seed=0)]  # the same blob in any file order
        self.tree = cKDTree(s)
        d, nb = self.tree.query(s, k=min(_ROOT_GRAPH_K + 1, len(s)), workers=-1)
        self.radius = 4.0 * float(np.median(d[:, min(4, d.shape[1] - 1)]))
        if self.radius <= 0:
            self.trivial = True
            return
        ok = d[:, 1:] <= self.radius
        rows = np.repeat(np.arange(len(s)), d.shape[1] - 1)[ok.ravel()]
        g = coo_matrix((np.ones(len(rows)), (rows, nb[:, 1:].ravel()[ok.ravel()])),
                       shape=(len(s), len(s)))
        _, lab = connected_components(g, directed=False)
        self.sample_in = _join_near_components(s, lab)

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


def _join_near_components(s: np.ndarray, lab: np.ndarray) -> np.ndarray:
    """(M,) bool: the samples ``s`` (M, 3) of the largest component (labels ``lab`` (M,)) and of
    the components of at least ``_JOIN_SHARE`` x M samples within ``_JOIN_GAP`` x the largest
    one's bounding-box diagonal of it or of one that joined it (transitively). Ties between
    equal-sized components go to the lowest label (deterministic: labels follow sample order)."""
    from scipy.spatial import cKDTree

    cnt = np.bincount(lab)
    joined = np.zeros(len(cnt), bool)
    joined[int(cnt.argmax())] = True
    inside = joined[lab]
    big = np.flatnonzero((cnt >= max(_JOIN_SHARE * len(s), 2)) & ~joined)
    if not len(big):
        return inside
    gap = _JOIN_GAP * float(np.linalg.norm(np.ptp(s[inside], axis=0)))
    new = inside
    for _ in range(len(big)):  # grow by the large components near what joined last
        cand = np.isin(lab, big[~joined[big]])
        if not cand.any():
            break
        dist, _ = cKDTree(s[new]).query(s[cand], k=1, distance_upper_bound=gap)
        near = np.unique(lab[cand][np.isfinite(dist)])
        if not len(near):
            break
        joined[near] = True
        new = np.isin(lab, near)
        inside = inside | new
    return inside


def height_range(points: np.ndarray, up: np.ndarray, blob: MainBlob) -> tuple[int, int, np.ndarray]:
    """(index of the lowest, index of the highest point of the blob, (N,) heights ``points @ up``)."""
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
    lo, hi, h = height_range(p, up, blob)
    ext = float(h[hi] - h[lo])
    cand = np.flatnonzero(h <= h[lo] + 0.01 * ext)
    low = cand[blob.contains(p[cand])]
    if len(low) == 0:
        return lo
    med = np.median(p[low], axis=0)
    return int(low[np.argmin(np.linalg.norm(p[low] - med, axis=1))])


def resolve_root(cloud: GaussianCloud, point: np.ndarray | None = None, root_index: int | None = None,
                 up: np.ndarray | None = None, blob: MainBlob | None = None) -> int:
    """The root Gaussian's index into ``cloud`` (0..len(cloud)-1) from one of three choices.

    point : (3,) input frame: the Gaussian nearest to that point (what a click picks); an error
        when the point is farther than 10 % of the plant size from every Gaussian.
    root_index : a Gaussian's position in the input FILE (file order, the identity used
        everywhere); an error when out of range or dropped at load. Exclusive with ``point``.
    Neither: the lowest point along ``up`` (:func:`auto_root_index`; ``up`` (3,) input frame is
        estimated when None).
    Raises ParameterError (named after the CLI's --root / --root-index).
    """
    from scipy.spatial import cKDTree

    if root_index is not None:
        if point is not None:
            raise ParameterError("--root-index", "either --root or --root-index, not both",
                                 f"--root {point} --root-index {root_index}")
        try:
            i = int(root_index)
        except (TypeError, ValueError):
            raise ParameterError("--root-index", "an integer", root_index) from None
        if i != root_index or not 0 <= i < cloud.file_count:
            raise ParameterError("--root-index", f"an index in 0..{cloud.file_count - 1}", root_index)
        hit = np.flatnonzero(cloud.file_index == i)  # the cloud need not be in file order
        if not len(hit):
            raise ParameterError("--root-index", "a Gaussian that was kept at load "
                                 "(this one was dropped as invalid)", i)
        return int(hit[0])
    if point is None:
        if up is None:
            up = estimate_up(cloud.means, cloud.shortest_axes())
        return auto_root_index(cloud.means, up, blob)
    xyz = np.asarray(point, np.float64)
    if xyz.shape != (3,) or not np.isfinite(xyz).all():
        raise ParameterError("--root", "'auto' or a point X,Y,Z in the input frame", point)
    d, i = cKDTree(cloud.means).query(xyz, k=1)
    size = plant_size(cloud.means)
    if d > _ROOT_FAR * size:
        raise ParameterError("--root", f"a point near the plant (nearest Gaussian is {d:.4g} away, "
                             f"more than 10% of the plant size {size:.4g})", ",".join(f"{c:g}" for c in xyz))
    return int(i)
