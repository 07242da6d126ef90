"""The Segmentation value (contract between ``segment`` and every later stage)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DOUBTFUL_CONFIDENCE = 0.5  # a leaf whose confidence is below this is worth a look ('edit' marks it)


@dataclass
class Segmentation:
    """Leaf instances of one plant; indices refer to the GaussianCloud the segmentation ran on.

    labels : (N,) int32, 0 = stem/unassigned, 1..L = leaf instances
    root_index : int, the root Gaussian
    apex_indices : (A,) int64, every detected apex (Gaussian indices)
    apex_labels : (A,) int32, the leaf each apex was grouped into (0 = none)
    leaf_tip : (L,) int64, primary apex of leaf l+1 (largest D_r among its apexes)
    leaf_base : (L,) int64, Gaussian at the detected petiole base of leaf l+1
    tree_nodes : (S,) int64, Gaussians of the rootward tree (FPS samples on some path)
    tree_parent : (S,) int64, index into tree_nodes of each node's parent (-1 for the root)
    tree_leaf : (S,) int32, leaf label a tree node lies in (0 = stem part of the tree)
    dist_root : (N,) float32, heat-method geodesic distance from the root, working units
    confidence : (L,) float64 in [0, 1], how sure the segmentation is of leaf l+1 (see
        :func:`leaffit_usd.segment.blades.leaf_confidence`; 1 for every leaf when the method gives
        none, e.g. the paper's apex method or labels read from a file)
    params : the parameters used (N_s, N_k, tau, delta, epsilon, rho, ...)
    """

    labels: np.ndarray
    root_index: int
    apex_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    apex_labels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    leaf_tip: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    leaf_base: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    tree_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    tree_parent: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    tree_leaf: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    dist_root: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    params: dict = field(default_factory=dict)
    confidence: np.ndarray | None = None

    def __post_init__(self):
        if self.confidence is None:
            self.confidence = np.ones(self.n_leaves, np.float64)

    @property
    def n_leaves(self) -> int:
        return int(self.labels.max(initial=0))

    def leaf_indices(self, label: int) -> np.ndarray:
        """(M,) int64 Gaussian indices of leaf ``label`` (1..L)."""
        return np.flatnonzero(self.labels == label)
