"""Parameters of the stem stage (:class:`StemParams`); lengths in working units (plant height 1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError


SKELETONS = ("auto", "gaussians", "tree")


@dataclass
class StemParams:
    """Stem parameters, working units (plant height = 1).

    root_radius, petiole_radius : radius at the root and at the petioles for the tree prior
        (Leonardo's rule); ``None`` = estimated from the capture. With the Gaussian skeleton they
        only fill in where the capture has no Gaussians to measure.
    skeleton : "gaussians" (level sets of the stem Gaussians), "tree" (the segmentation's
        rootward tree, the paper's) or "auto" (Gaussians; the tree when fewer than
        ``min_gaussians`` stem Gaussians are usable)
    level_width : level-set spacing of the Gaussian skeleton (working units)
    neighbours : k of the stem Gaussians' neighbour graph
    min_gaussians : fewest stem Gaussians for the Gaussian skeleton
    prune : terminal spurs shorter than ``prune`` x level_width are dropped
    base_level_ratio : level sets are at least this x the base's radius wide
    reach_level_ratio : ... and this x the median distance of a stem Gaussian to its
        ``neighbours``-th neighbour
    axis_smoothing : the axis spline smooths out wiggles shorter than about 2 pi x this x
        level_width
    leonardo_weight : weight of Leonardo's rule against the measured radii (relative rows)
    smooth_weight : weight of the radius smoothness along a stream
    sides : vertices per ring (LOD0; 8, was 12: a tube a few pixels wide does not show its
        facets, and the stem was the largest part of the asset, 0.44 of a 9-leaf plant's 0.66 MB
        .usdz at 12 sides and rings a radius apart)
    ring_spacing : ring spacing along the axis, multiple of the local radius (clamped to
        [0.25, 2] x level_width; 2, was 1: the axis is smooth on that scale, and the clamp keeps
        bends resolved)
    tip_length : length of the rounded tip, multiple of the tip radius
    root_cap : close the base with a flat disk (off by default: a potted plant's stem goes into
        the soil, and a disk as wide as a thick base sticks out of the true surface)
    estimate_ball : radius of the neighbourhood used by the tree prior's estimates
    """

    root_radius: float | None = None
    petiole_radius: float | None = None
    skeleton: str = "auto"
    level_width: float = 0.01
    neighbours: int = 10
    min_gaussians: int = 60
    prune: float = 0.5
    axis_smoothing: float = 0.5
    base_level_ratio: float = 0.75
    reach_level_ratio: float = 1.0
    leonardo_weight: float = 1.0
    smooth_weight: float = 1.0
    sides: int = 8
    ring_spacing: float = 2.0
    tip_length: float = 1.5
    root_cap: bool = False
    estimate_ball: float = 0.05

    def validate(self) -> None:
        for name in ("root_radius", "petiole_radius"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive radius (working units) or None", v)
        if self.skeleton not in SKELETONS:
            raise ParameterError("skeleton", " or ".join(SKELETONS), self.skeleton)
        if int(self.sides) < 3:
            raise ParameterError("sides", "an integer >= 3", self.sides)
        if int(self.neighbours) < 2:
            raise ParameterError("neighbours", "an integer >= 2", self.neighbours)
        for name in ("level_width", "ring_spacing", "estimate_ball"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive number", v)
        for name in ("prune", "axis_smoothing", "base_level_ratio", "reach_level_ratio", "leonardo_weight",
                     "smooth_weight", "tip_length"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(name, "a number >= 0", v)
