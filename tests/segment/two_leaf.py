"""A synthetic two-leaf plant and a heat stand-in for the manual-segmentation tests (fixtures
``plant`` and ``heat``, used through tests/segment and tests/viewer conftest.py)."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.splats.cloud import GaussianCloud


class HeatStandIn:
    """Stand-in for ``leaffit_usd.geometry.heat.GeodesicSolver`` (same interface) on potpourri3d.

    Used until the project's solver lands; tests pass it as ``solver_factory``.
    """

    def __init__(self, points, normals=None):  # normals: accepted, ignored
        import potpourri3d as pp3d

        self._solver = pp3d.PointCloudHeatSolver(np.asarray(points, np.float64))

    def distance(self, source) -> np.ndarray:
        return self._solver.compute_distance(int(source))


def solver_factory():
    """The project's solver when it exists, else the stand-in above."""
    try:
        from leaffit_usd.geometry.heat import GeodesicSolver  # noqa: F401
        return GeodesicSolver
    except ImportError:
        return HeatStandIn


def two_leaf_plant(n_leaf: int = 1500, n_stem: int = 300, seed: int = 0):
    """A stem (z in [0, 0.5]) with two flat elliptic leaves sprouting left and right at its top.

    Returns (cloud: GaussianCloud, truth (N,) int32 labels: 0 stem, 1 left leaf, 2 right leaf,
    tips (2,) int64 index of each leaf's tip Gaussian, bases (2,) int64 near each petiole).
    Units: plant height ~1.
    """
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 0.5, n_stem)
    ang = rng.uniform(0, 2 * np.pi, n_stem)
    stem = np.c_[0.01 * np.cos(ang), 0.01 * np.sin(ang), z]
    leaves, truth, quats = [stem], [np.zeros(n_stem, np.int32)], [np.tile([1.0, 0, 0, 0], (n_stem, 1))]
    for lab, side in ((1, -1.0), (2, 1.0)):
        u = rng.uniform(0, 1, n_leaf * 2)
        v = rng.uniform(-1, 1, n_leaf * 2)
        keep = np.abs(v) <= np.sin(np.pi * u) ** 0.8
        u, v = u[keep][:n_leaf], v[keep][:n_leaf]
        x = side * (0.02 + 0.45 * u)
        y = 0.12 * v
        zz = 0.5 + 0.25 * u + 0.05 * np.sin(np.pi * u)  # rising, slightly curved blade
        leaves.append(np.c_[x, y, zz])
        truth.append(np.full(len(u), lab, np.int32))
        # flat Gaussians in the blade's tangent plane: local z (smallest axis) = blade normal
        dzdx = side * (0.25 + 0.05 * np.pi * np.cos(np.pi * u)) / 0.45
        phi = np.arctan2(-dzdx, 1.0)
        quats.append(np.c_[np.cos(phi / 2), np.zeros_like(phi), np.sin(phi / 2), np.zeros_like(phi)])
    means = np.concatenate(leaves).astype(np.float32)
    truth = np.concatenate(truth)
    q = np.concatenate(quats)
    n = len(means)
    scales = np.full((n, 3), 0.004)
    scales[truth > 0, 2] = 0.0008  # leaf Gaussians are flat
    scales[truth == 0] = [0.003, 0.003, 0.008]  # stem Gaussians are long along the stem (z)
    colors = np.where(truth[:, None] == 0, [0.4, 0.3, 0.2], [0.2, 0.6, 0.2]) + rng.uniform(-0.05, 0.05, (n, 3))
    cloud = GaussianCloud.from_activated(means, scales, q, np.full(n, 0.9), colors=np.clip(colors, 0, 1))
    tips = np.array([np.argmin(means[:, 0]), np.argmax(means[:, 0])], np.int64)
    base_pts = np.array([[-0.05, 0, 0.51], [0.05, 0, 0.51]])
    bases = np.array([np.argmin(np.linalg.norm(means - b, axis=1) + 10 * (truth != i + 1))
                      for i, b in enumerate(base_pts)], np.int64)
    return cloud, truth, tips, bases


@pytest.fixture(scope="session")
def plant():
    return two_leaf_plant()


@pytest.fixture(scope="session")
def heat():
    return solver_factory()
