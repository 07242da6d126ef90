"""k-nearest-neighbour helpers (scipy's cKDTree, both cores) and nearest-sample interpolation."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

WORKERS = -1  # cKDTree.query workers: all cores


def knn(points: np.ndarray, k: int, queries: np.ndarray | None = None, tree: cKDTree | None = None):
    """The ``k`` nearest ``points`` of each query (Euclidean).

    points : (N, 3) float, any frame; queries : (Q, 3) float, same frame (default: ``points``,
    then each point's own index comes first). Returns (dist (Q, k) float64, idx (Q, k) int64),
    k clipped to N.
    """
    points = np.asarray(points, np.float64)
    tree = cKDTree(points) if tree is None else tree
    k = int(min(k, len(points)))
    q = points if queries is None else np.asarray(queries, np.float64)
    d, i = tree.query(q, k=k, workers=WORKERS)
    if k == 1:
        d, i = d[:, None], i[:, None]
    return d, i.astype(np.int64)


def interpolation_matrix(samples: np.ndarray, queries: np.ndarray, k: int = 4,
                         allowed: np.ndarray | None = None, tree: cKDTree | None = None) -> sp.csr_matrix:
    """Sparse (Q, S) matrix W of inverse-distance weights: ``W @ f_samples`` ~ f at ``queries``.

    samples : (S, 3), queries : (Q, 3), same frame. Each row sums to 1 and uses the ``k`` nearest
    samples (a query on a sample gets exactly that sample's value). ``allowed`` : (S,) bool,
    samples that may be used (others get weight 0 unless a query has no allowed neighbour among
    its k nearest, then its nearest allowed sample is used).
    """
    samples = np.asarray(samples, np.float64)
    queries = np.asarray(queries, np.float64)
    k = int(min(k, len(samples)))
    d, idx = knn(samples, k, queries, tree)
    w = 1.0 / np.maximum(d, 1e-12) ** 2
    exact = d[:, 0] < 1e-12
    w[exact] = 0.0
    w[exact, 0] = 1.0
    if allowed is not None:
        ok = allowed[idx]
        w = np.where(ok, w, 0.0)
        none = ~ok.any(1)
        if none.any():
            sub = np.flatnonzero(allowed)
            if len(sub):
                _, j = cKDTree(samples[sub]).query(queries[none], k=1)
                idx[none, 0] = sub[j]
                w[none] = 0.0
                w[none, 0] = 1.0
    s = w.sum(1, keepdims=True)
    w = np.divide(w, s, out=np.zeros_like(w), where=s > 0)
    rows = np.repeat(np.arange(len(queries)), k)
    return sp.csr_matrix((w.ravel(), (rows, idx.ravel())), shape=(len(queries), len(samples)))
