"""Frames: input (the capture's own), working (the paper's normalised units), asset (USD).

Working frame convention: the root is at the origin, the plant's up direction is +Z, and the
plant height (extent of the Gaussians along up, from the root) is 1. Every algorithm parameter
(N_s, tau, delta, epsilon, sigma ...) is defined in these units.

``Frame.input_to_working`` is a 4x4 similarity ``x_w = s * R @ (x_in - root)``; its inverse maps
any result back to the input frame exactly (up to float rounding). :func:`make_frame` builds it
from a cloud (up axis from ``splats.up_axis``, root from ``splats.root``); the CLI parses the
user's --up / --root strings (``commands._args``) before they reach it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.root import MainBlob, height_range, resolve_root
from leaffit_usd.splats.up_axis import LOW_UP_CONFIDENCE, estimate_up_with_confidence


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


class FrameChoice(NamedTuple):
    """Result of :func:`make_frame`: the frame and the root Gaussian's index into the cloud."""

    frame: Frame
    root_index: int


def make_frame(cloud: GaussianCloud, up: np.ndarray | None = None, root: np.ndarray | None = None,
               root_index: int | None = None) -> FrameChoice:
    """Build the input -> working Frame for the pipeline from a cloud and the user's choices.

    up : None (estimated, logged with its confidence) or a (3,) non-zero vector, input frame.
    root : None (the lowest point along up) or a (3,) point, input frame (nearest Gaussian);
        root_index : a Gaussian's index in the input file; see :func:`splats.root.resolve_root`.
    The frame's origin is the root Gaussian's centre; height is the extent above it of the
    largest connected blob (floaters do not count). An estimated up is turned round when the
    root the user gave lies nearer the blob's top than its bottom along it.
    """
    import logging

    log = logging.getLogger("leaffit_usd")
    if up is None:
        est = estimate_up_with_confidence(cloud.means, cloud.shortest_axes())
        u = est.up
        log.info("estimated up axis (%.3f, %.3f, %.3f), confidence %.2f%s", *u, est.confidence,
                 "" if est.confidence >= LOW_UP_CONFIDENCE else " (low: pass --up to be sure)")
    else:
        try:
            u = np.asarray(up, np.float64)
        except (TypeError, ValueError):
            raise ParameterError("up", "a non-zero (3,) vector", up) from None
        if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-12:
            raise ParameterError("up", "a non-zero (3,) vector", up)
        u = u / np.linalg.norm(u)
    blob = MainBlob(cloud.means)
    ri = resolve_root(cloud, root, root_index, u, blob=blob)
    # height: the plant's extent above the root, floaters excluded
    lo, hi, h = height_range(cloud.means, u, blob)
    if up is None and (root is not None or root_index is not None) and h[hi] - h[ri] < h[ri] - h[lo]:
        # the root the user gave is the plant's bottom: an estimated up that puts it nearer the
        # top than the bottom points the wrong way (a sparse scan's estimate can)
        u = -u
        log.info("up axis turned to (%.3f, %.3f, %.3f): the root you gave lies at the other end",
                 *u)
        lo, hi, h = height_range(cloud.means, u, blob)
    pts = cloud.means[[ri, hi]]
    frame = Frame.from_root_up(pts, cloud.means[ri].astype(np.float64), u)
    return FrameChoice(frame, ri)
