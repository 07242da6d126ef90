"""Geometry of a capture's surfaces that isolation measures: planes (RANSAC and least squares),
in-plane patches on a grid, circles and angular coverage, the samples' neighbourhood graph and its
components. Input frame and units; every reduction element-wise (no threaded BLAS), so the same
bits come out at any thread count (see :mod:`leaffit_usd.isolate.scene`)."""
from __future__ import annotations

import numpy as np

from leaffit_usd.geometry.sampling import voxel_centroids

def heights(p: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    """(M,) signed distances ``p . n + d`` of (M, 3) points, element-wise (no BLAS: the same
    bits at any thread count)."""
    return p[:, 0] * n[0] + p[:, 1] * n[1] + p[:, 2] * n[2] + d


def fit_plane(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through (M, 3) points -> (unit normal (3,), d) with n.x + d = 0, the
    normal's largest component positive. Element-wise sums and a 3x3 eigen-solve (no threaded
    BLAS reduction over M)."""
    c = p.sum(0) / len(p)
    q = p - c
    cov = np.array([[(q[:, i] * q[:, j]).sum() for j in range(3)] for i in range(3)])
    n = np.linalg.eigh(cov)[1][:, 0]
    n = n / np.linalg.norm(n)
    if n[int(np.argmax(np.abs(n)))] < 0:
        n = -n
    return n, -float(n @ c)


def voxel_down(p: np.ndarray, target: int) -> tuple[np.ndarray, float]:
    """Area-even subsample of (M, 3) points: the centroid of each occupied voxel, about
    ``target`` of them (surfaces: voxel count ~ 1 / size^2, adapted in a few steps).
    Returns ((V, 3) centroids in voxel-key order, the voxel size)."""
    lo, hi = np.quantile(p, [0.005, 0.995], axis=0)
    size = (float(np.linalg.norm(hi - lo)) or 1.0) / 100.0
    for _ in range(8):
        cen, _, cnt = voxel_centroids(p, size)
        ratio = len(cnt) / target
        if 0.7 <= ratio <= 1.4:
            break
        size *= np.sqrt(ratio)
    return cen, float(size)


def ransac_plane(v: np.ndarray, thr: float, iterations: int, rng: np.random.Generator,
                  score_size: int = 1500) -> tuple[np.ndarray, float]:
    """The plane (unit normal (3,), d) with most of (V, 3) points within ``thr``, among
    ``iterations`` planes through 3 random points, each scored on the same ``score_size`` random
    points (a large plane's share is estimated to a few percent: enough to rank hypotheses; the
    winner is refined on all points by the caller)."""
    m = len(v)
    score = v if m <= score_size else v[np.sort(rng.choice(m, score_size, replace=False))]
    tri = rng.integers(0, m, size=(int(iterations), 3))
    a = v[tri[:, 0]]
    nrm = np.cross(v[tri[:, 1]] - a, v[tri[:, 2]] - a)
    ln = np.sqrt((nrm ** 2).sum(1))
    ok = ln > 0
    nrm, a = nrm[ok] / ln[ok, None], a[ok]
    d = -(nrm * a).sum(1)
    counts = np.zeros(len(nrm), np.int64)
    for j in range(0, len(nrm), 256):
        sl = slice(j, j + 256)
        h = (score[:, 0:1] * nrm[None, sl, 0] + score[:, 1:2] * nrm[None, sl, 1]
             + score[:, 2:3] * nrm[None, sl, 2] + d[None, sl])
        counts[sl] = (np.abs(h) <= thr).sum(0)
    if not len(counts):
        return np.array([0.0, 0.0, 1.0]), 0.0
    best = int(np.argmax(counts))  # the first of equals: deterministic
    return nrm[best], float(d[best])


#: the local linking radius is at most this x the global one (a part sampled up to 16x more
#: sparsely than the median holds together; sparser than that is another object or floaters)
MAX_SPARSE = 4.0


def knn_graph(s: np.ndarray, link: float, k_more: int = 0, local: bool = False) -> tuple:
    """The samples' (M, 3) 10-NN graph with edges shorter than ``link`` x the median 4-NN
    distance: (rows (E,) int64, cols (E,) int64, that radius, the sorted distances (M, k) to the
    max(11, ``k_more``) nearest samples, itself first, the local radii (M,)).

    The local radius of a sample follows the density around it: ``link`` x the median 4-NN
    distance of its 10 nearest samples (itself included), between the global radius and
    ``MAX_SPARSE`` x it. With ``local`` an edge is kept when it is shorter than the local radius
    at both ends: a sparsely sampled part of a plant (uneven density, 12x sparser) then holds
    together, while an isolated floater, whose nearest samples are dense plant, still links to
    nothing."""
    from leaffit_usd.geometry.knn import knn

    m = len(s)
    if m < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), 0.0, np.zeros((m, 1)), np.zeros(m)
    k = min(11, m)
    d, nb = knn(s, min(max(k, k_more), m))
    d4 = d[:, min(4, k - 1)]
    radius = link * float(np.median(d4))
    r = np.clip(link * np.median(d4[nb[:, :k]], axis=1), radius, MAX_SPARSE * radius)
    if local:
        ok = d[:, 1:k] <= np.minimum(r[:, None], r[nb[:, 1:k]])
    else:
        ok = d[:, 1:k] <= radius
    return np.repeat(np.arange(m), k - 1)[ok.ravel()], nb[:, 1:k][ok], radius, d, r


def components(edges: tuple, mask: np.ndarray) -> np.ndarray:
    """Connected components of the samples in ``mask`` (M,) bool, over the graph ``edges``
    (rows, cols) restricted to them -> (K,) int64 labels of ``np.flatnonzero(mask)``, ranked by
    size (0 = largest; ties by first sample)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    idx = np.flatnonzero(mask)
    if not len(idx):
        return np.zeros(0, np.int64)
    rows, cols = edges[0], edges[1]
    keep = mask[rows] & mask[cols]
    pos = np.cumsum(mask) - 1  # sample -> index among the masked ones
    g = coo_matrix((np.ones(int(keep.sum()), np.int8), (pos[rows[keep]], pos[cols[keep]])),
                   shape=(len(idx), len(idx)))
    _, lab = connected_components(g, directed=False)
    order = np.argsort(-np.bincount(lab), kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[lab].astype(np.int64)


def largest_patch(xy: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The largest 8-connected patch of occupied ``cell``-sized squares of (M, 2) in-plane points:
    (its points (M,) bool, the dilated patch as a grid (X, Y) bool, (grid origin, cell))."""
    lo = xy.min(0) - cell
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(0) + 2)
    if shape[0] * shape[1] > 16_000_000:  # a few far-off inliers: coarser cells
        return largest_patch(xy, cell * 2)
    occ = np.zeros(shape, bool)
    occ[ij[:, 0], ij[:, 1]] = True
    patch = largest_component_8(occ)
    return patch[ij[:, 0], ij[:, 1]], dilate_8(patch), (lo, cell)


def largest_component_8(grid: np.ndarray) -> np.ndarray:
    """(X, Y) bool: the largest 8-connected component of the True cells of ``grid`` (X, Y) bool
    (ties: the one whose first cell comes first in row-major order; all False if none), as
    ``scipy.ndimage.label`` with a 3x3 structure and an argmax of the sizes would give. On
    scipy's sparse graph components, already loaded here: ``scipy.ndimage`` costs ~0.08 s of
    import, which a ``segment`` run of a few seconds otherwise pays for this one call."""
    out = np.zeros(grid.shape, bool)
    cells = np.flatnonzero(grid)  # row-major order
    if not len(cells):
        return out
    index = np.full(grid.size, -1, np.int64)
    index[cells] = np.arange(len(cells))
    index = index.reshape(grid.shape)
    rows, cols = [], []
    nx, ny = grid.shape
    for dx, dy in ((0, 1), (1, -1), (1, 0), (1, 1)):  # each 8-neighbour pair once: a and a + (dx, dy)
        a = index[:nx - dx, max(0, -dy):ny - max(0, dy)]
        b = index[dx:, max(0, dy):ny - max(0, -dy)]
        both = (a >= 0) & (b >= 0)
        rows.append(a[both])
        cols.append(b[both])
    rank = components((np.concatenate(rows), np.concatenate(cols)), np.ones(len(cells), bool))
    out.ravel()[cells[rank == 0]] = True
    return out


def dilate_8(grid: np.ndarray) -> np.ndarray:
    """(X, Y) bool: ``grid`` dilated by one cell in all 8 directions (outside counts as False),
    as ``scipy.ndimage.binary_dilation`` with a 3x3 structure."""
    pad = np.pad(grid, 1)
    out = np.zeros_like(grid)
    for dx in range(3):
        for dy in range(3):
            out |= pad[dx:dx + grid.shape[0], dy:dy + grid.shape[1]]
    return out


def in_grid(xy: np.ndarray, grid: np.ndarray, frame: tuple) -> np.ndarray:
    """(M,) bool: which (M, 2) in-plane points fall in a True cell of ``grid``."""
    lo, cell = frame
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    ok = (ij >= 0).all(1) & (ij[:, 0] < grid.shape[0]) & (ij[:, 1] < grid.shape[1])
    out = np.zeros(len(xy), bool)
    out[ok] = grid[ij[ok, 0], ij[ok, 1]]
    return out


def span(xy: np.ndarray) -> float:
    """Width of (M, 2) in-plane points: the larger 5-95 % quantile range of the two axes."""
    if len(xy) < 2:
        return 0.0
    return float(np.max(np.subtract(*np.quantile(xy, [0.95, 0.05], axis=0))))


def circle_fit(xy: np.ndarray, iters: int = 4) -> tuple[np.ndarray, float, np.ndarray]:
    """Trimmed Kasa circle fit of (M, 2) points -> (centre (2,), radius, inlier mask (M,))."""
    keep = np.ones(len(xy), bool)
    c, r = xy.mean(0), 0.0
    for _ in range(iters):
        q = xy[keep]
        if len(q) < 6:
            break
        a = np.c_[2 * q, np.ones(len(q))]
        b = (q ** 2).sum(1)
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        c = sol[:2]
        r = float(np.sqrt(max(sol[2] + c @ c, 0.0)))
        res = np.abs(np.linalg.norm(xy - c, axis=1) - r)
        mad = float(np.median(res[keep])) * 1.4826 + 1e-12
        keep = res <= max(2.5 * mad, 0.02 * r)
    return c, r, keep


def angular_coverage(xy: np.ndarray, c: np.ndarray, bins: int = 24) -> float:
    """Fraction of ``bins`` angular sectors around ``c`` holding at least one of (M, 2) points."""
    if len(xy) == 0:
        return 0.0
    a = np.arctan2(xy[:, 1] - c[1], xy[:, 0] - c[0])
    k = np.floor((a + np.pi) / (2 * np.pi) * bins).astype(int) % bins
    return len(np.unique(k)) / bins
