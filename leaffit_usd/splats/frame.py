"""Frames: input (the capture's own), working (the paper's normalised units), asset (USD).

Working frame convention: the root is at the origin, the plant's up direction is +Z, and the
plant height (extent of the Gaussians along up, from the root) is 1. Every algorithm parameter
(N_s, tau, delta, epsilon, sigma ...) is defined in these units.

``Frame.input_to_working`` is a 4x4 similarity ``x_w = s * R @ (x_in - root)``; its inverse maps
any result back to the input frame exactly (up to float rounding).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError

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
