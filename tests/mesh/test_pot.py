"""The pot as a mesh: a surface of revolution fitted to a pot's Gaussians (outward, closed at the
bottom, near them) and a soil disc at the soil's surface, coloured from the Gaussians."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.mesh.pot import build_pot, chamfer


def _tapered_pot(n=6000, seed=0, axis=(0.0, 0.0, 1.0)):
    """Gaussian centres on a tapered pot wall (radius 0.10 at the bottom to 0.14 at the rim,
    0.2 tall) and its bottom, plus soil near the top; a two-coloured wall (red below 0.1)."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0, 0.2, n)
    a = rng.uniform(0, 2 * np.pi, n)
    r = 0.10 + 0.2 * h + 0.002 * rng.normal(size=n)
    wall = np.c_[r * np.cos(a), r * np.sin(a), h]
    col = np.where((h < 0.1)[:, None], [[0.8, 0.2, 0.1]], [[0.9, 0.9, 0.9]])
    rs = 0.13 * np.sqrt(rng.uniform(0, 1, 2000))
    a2 = rng.uniform(0, 2 * np.pi, 2000)
    soil = np.c_[rs * np.cos(a2), rs * np.sin(a2), 0.17 + 0.001 * rng.normal(size=2000)]
    return wall, col, soil, np.tile([0.2, 0.12, 0.06], (2000, 1))


def test_the_lathe_lies_on_the_pot_and_faces_out():
    wall, col, soil, scol = _tapered_pot()
    pot = build_pot(wall, col, soil, scol, np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert chamfer(pot.pot_points, pot.pot_faces, wall) < 0.01 * 0.2 * 5   # under 1 % of a 1-unit plant
    n = vertex_normals(pot.pot_points, pot.pot_faces)
    side = np.abs(pot.pot_points[:, 2] - 0.1) < 0.08
    radial = pot.pot_points[side, :2] / np.linalg.norm(pot.pot_points[side, :2], axis=1, keepdims=True)
    assert (np.einsum("ij,ij->i", n[side, :2], radial) > 0).mean() > 0.99   # outward
    # the colours follow the wall: red at the bottom, white at the top
    low, high = pot.pot_points[:, 2] < 0.05, pot.pot_points[:, 2] > 0.15
    assert pot.pot_colors[low, 0].mean() > 0.7 and pot.pot_colors[low, 1].mean() < 0.35
    assert pot.pot_colors[high].mean() > 0.8
    # the soil disc at the soil's height, inside the rim, facing up
    assert np.allclose(pot.soil_points[:, 2], 0.17, atol=0.005)
    assert np.linalg.norm(pot.soil_points[:, :2], axis=1).max() < 0.14
    sn = vertex_normals(pot.soil_points, pot.soil_faces)
    assert (sn[:, 2] > 0.9).all()


@pytest.mark.parametrize("axis", [(0.0, 0.0, -1.0), (0.3, -0.8, 0.5)])
def test_any_axis_gives_an_outward_lathe(axis):
    u = np.asarray(axis) / np.linalg.norm(axis)
    wall, col, soil, scol = _tapered_pot(seed=1)
    # rotate the pot so that its axis is u
    from leaffit_usd.geometry.plane import plane_basis
    R = np.c_[plane_basis(u), u]
    pot = build_pot(wall @ R.T, col, soil @ R.T, scol, u, np.zeros(3))
    n = vertex_normals(pot.pot_points, pot.pot_faces)
    rel = pot.pot_points - np.outer(pot.pot_points @ u, u)
    mid = np.abs(pot.pot_points @ u - 0.1) < 0.08
    assert (np.einsum("ij,ij->i", n[mid], rel[mid]) > 0).mean() > 0.99


def test_too_few_gaussians_give_no_pot():
    wall, col, soil, scol = _tapered_pot(n=20)
    assert build_pot(wall, col, soil, scol, np.array([0, 0, 1.0]), np.zeros(3)) is None
