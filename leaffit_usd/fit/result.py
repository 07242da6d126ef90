"""The LeafFits value (contract between ``fit`` and ``mesh``/``usd``/``runtime``).

Leaf local frame: origin at the leaf's petiole base, +X from base towards the apex, +Z the leaf
normal (PCA smallest axis, oriented to the upper side), working units. ``leaf_to_working`` maps
local -> working frame and is a similarity (rotation, translation, uniform scale); the uniform
scale is the leaf's size relative to the template, so a DCC that ignores the deformer still shows
every leaf rigidly placed at about the right size. Target control points are in the instance's
local frame *before* that scale, i.e. in template units, so

    leaf_j(v) = leaf_to_working[j] @ MLS(template_controls -> targets[j])(v)

for any template vertex v (template local frame).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LeafFits:
    """Per-leaf MLS registrations of one template leaf.

    template_label : int, the leaf label (1..L) used as template
    template_points : (M, 3) float32, template leaf's denoised Gaussian centres, template local frame
    template_gaussians : (M,) int64, their indices in the GaussianCloud
    template_controls : (K, 3) float32, template control points p, template local frame
    leaf_labels : (L,) int32, the leaf label of each fit (row j)
    targets : (L, K, 3) float32, target control points q_j, instance local frame (template units)
    leaf_to_working : (L, 4, 4) float64 similarity, instance local -> working frame
    errors : (L,) float32, final Chamfer distance of each fit, working units
    fallback : (L,) bool, True where the fit fell back to rigid (degenerate leaf)
    sigma, reg : MLS kernel width and regulariser (see ``fit.mls``)
    params : the parameters used (K, steps, lr, lambda, ...)
    """

    template_label: int
    template_points: np.ndarray
    template_gaussians: np.ndarray
    template_controls: np.ndarray
    leaf_labels: np.ndarray
    targets: np.ndarray
    leaf_to_working: np.ndarray
    errors: np.ndarray
    fallback: np.ndarray
    sigma: float = 0.1
    reg: float = 0.01
    params: dict = field(default_factory=dict)

    @property
    def K(self) -> int:
        return int(self.template_controls.shape[0])
