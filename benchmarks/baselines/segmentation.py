"""The paper's training-free baseline: a Euclidean-density heuristic on a k-NN graph.

Paper (Results, "Segmentation Evaluation"): "a training-free Euclidean-density heuristic on a
k-NN graph, which isolates the stem based on low density rho and high gradient |grad rho|
(identifying the base at the last pre-minimum along the rootward path)". Its authors give no more
detail; this is our reading, with every constant below:

1. Work on ``n_points`` random Gaussians (seeded) with a ``k``-NN graph whose edges
   are Euclidean lengths (edges longer than ``edge_cap`` x the median are dropped).
2. Density ``rho_i = 1 / mean distance to the k nearest Gaussians`` (all of them: the samples are
   uniform by construction), smoothed once over the neighbours and divided by its
   median; gradient ``|grad rho|_i = max_j |rho_j - rho_i| / |x_j - x_i|`` (graph finite
   differences), divided by its median.
3. Stem = low density (``rho < rho_stem``) or high gradient (``|grad rho| > grad_stem``).
   Leaves = connected components of the other samples with at least ``min_leaf`` of them.
4. Base: from each component's tip (largest graph distance from the root, Dijkstra), walk the
   rootward shortest-path tree; along it the density (running mean over ``smooth`` nodes) falls into the petiole; the base is
   the last node before the density's first local minimum below ``rho_stem`` (the "pre-minimum");
   the leaf is its component's samples at graph distance >= the base's.
5. Margins (half a disc of neighbours, hence low density) are given back: ``grow_steps`` rounds
   of majority vote over the k neighbours, above the leaf's base.
6. Labels go to every Gaussian from its nearest sample.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError, UserError

log = logging.getLogger("leaffit_usd")


@dataclass
class DensityParams:
    """Constants of the Euclidean-density baseline. The paper gives none; these were picked from a
    small grid (rho_stem 0.8/0.9, grad_stem 2/4, k 12/24) on three generated elliptic plants
    (rubber_tree, green_pepper, ruby_leaf), i.e. tuned on part of the test set, in the
    baseline's favour."""

    n_points: int = 20000
    k: int = 24
    edge_cap: float = 3.0
    rho_stem: float = 0.8
    grad_stem: float = 4.0
    min_leaf: int = 30
    grow_steps: int = 3
    smooth: int = 9
    seed: int = 0


@dataclass
class DensityResult:
    """labels : (N,) int32, 0 stem, 1..L leaves; samples : (S,) int64 sample indices;
    density : (S,) float64 normalised density at the samples."""

    labels: np.ndarray
    samples: np.ndarray
    density: np.ndarray


def segment_density(points_working: np.ndarray, root_index: int,
                    params: DensityParams | None = None) -> DensityResult:
    """Euclidean-density leaf segmentation (the paper's baseline), working frame.

    points_working : (N, 3) float, working frame; root_index : the root Gaussian.
    """
    p = params or DensityParams()
    pts = np.asarray(points_working, np.float64)
    n = len(pts)
    if pts.ndim != 2 or pts.shape[1] != 3 or n < 8:
        raise UserError(f"the baseline needs an (N, 3) cloud of at least 8 points, got {pts.shape}")
    if not 0 <= int(root_index) < n:
        raise ParameterError("root_index", f"an index in [0, {n})", root_index)
    rng = np.random.default_rng(p.seed)
    samples = np.union1d(rng.choice(n, min(p.n_points, n), replace=False), [int(root_index)])
    x = pts[samples]
    s = len(x)
    k = int(min(p.k, s - 1))
    tree = cKDTree(x)
    d, nb = tree.query(x, k=k + 1, workers=-1)
    d, nb = d[:, 1:], nb[:, 1:]
    cap = p.edge_cap * np.median(d)
    ok = d <= cap
    rows = np.repeat(np.arange(s), k)[ok.ravel()]
    g = sp.csr_matrix((np.maximum(d.ravel()[ok.ravel()], 1e-12), (rows, nb.ravel()[ok.ravel()])),
                      shape=(s, s))
    g = g.maximum(g.T)
    # density of the Gaussians themselves (the samples are uniform by construction)
    dk, _ = cKDTree(pts).query(x, k=k + 1, workers=-1)
    rho = 1.0 / np.maximum(dk[:, 1:].mean(1), 1e-12)
    rho = 0.5 * rho + 0.5 * rho[nb].mean(1)
    rho /= np.median(rho)
    grad = (np.abs(rho[nb] - rho[:, None]) / np.maximum(d, 1e-12)).max(1)
    grad /= max(np.median(grad), 1e-12)
    stem = (rho < p.rho_stem) | (grad > p.grad_stem)

    root_s = int(np.argmin(((x - pts[root_index]) ** 2).sum(1)))
    dist, pred = dijkstra(g, indices=root_s, return_predecessors=True)
    leafy = ~stem & np.isfinite(dist)
    sub = g[leafy][:, leafy]
    _, comp = connected_components(sub, directed=False)
    lab_s = np.zeros(s, np.int32)
    idx = np.flatnonzero(leafy)
    label = 0
    for c in np.unique(comp):
        members = idx[comp == c]
        if len(members) < p.min_leaf:
            continue
        tip = members[np.argmax(dist[members])]
        path = [tip]
        while pred[path[-1]] >= 0 and len(path) < s:
            path.append(pred[path[-1]])
        prof = rho[np.asarray(path)]
        if len(prof) > p.smooth:  # running mean: a blade's own density noise is no minimum
            ker = np.ones(p.smooth) / p.smooth
            prof = np.convolve(np.pad(prof, p.smooth // 2, mode="edge"), ker, mode="valid")[:len(path)]
        base_k = len(path) - 1
        for i in range(1, len(path) - 1):
            if prof[i] < p.rho_stem and prof[i] <= prof[i - 1] and prof[i] <= prof[i + 1]:
                base_k = i - 1
                break
        base_d = dist[path[base_k]]
        keep = members[dist[members] >= base_d]
        if len(keep) < p.min_leaf:
            continue
        label += 1
        lab_s[keep] = label
    # margins have a low kNN density too (half a disc of neighbours): give a stem-classified
    # sample the leaf most of its neighbours have, if it lies above that leaf's base
    base_of = np.full(label + 1, np.inf)
    for lab in range(1, label + 1):
        base_of[lab] = dist[lab_s == lab].min()
    for _ in range(p.grow_steps):
        votes = lab_s[nb]
        free = np.flatnonzero(lab_s == 0)
        if len(free) == 0:
            break
        v = votes[free]
        best = np.array([np.bincount(r[r > 0], minlength=label + 1).argmax() if (r > 0).any() else 0
                         for r in v])
        cnt = (v == best[:, None]).sum(1)
        take = (best > 0) & (cnt * 2 > k) & (dist[free] >= base_of[best])
        if not take.any():
            break
        lab_s[free[take]] = best[take]
    _, near = tree.query(pts, k=1, workers=-1)
    labels = lab_s[near].astype(np.int32)
    log.info("density baseline: %d leaves", label)
    return DensityResult(labels=labels, samples=samples, density=rho)
