"""Mean value coordinates: known answers and invariants."""
import numpy as np
import pytest

from leaffit_usd.edit.mvc import mean_value_coordinates, transfer
from leaffit_usd.errors import UserError


def star(m=12, seed=0):
    """A non-convex, star-shaped cage (counter-clockwise)."""
    rng = np.random.default_rng(seed)
    a = np.linspace(0, 2 * np.pi, m, endpoint=False)
    r = 1.0 + 0.4 * rng.uniform(-1, 1, m)
    return np.c_[r * np.cos(a), r * np.sin(a)]


def test_partition_of_unity_and_linear_precision_inside():
    cage = star()
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, (200, 2))
    lam = mean_value_coordinates(cage, pts)
    np.testing.assert_allclose(lam.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(lam @ cage, pts, atol=1e-10)
    # linear functions are reproduced
    f = cage @ np.array([2.0, -3.0]) + 0.5
    np.testing.assert_allclose(lam @ f, pts @ np.array([2.0, -3.0]) + 0.5, atol=1e-10)
    # inside a star-shaped polygon seen from its kernel, MVC are positive
    assert (mean_value_coordinates(cage, np.zeros((1, 2))) > 0).all()


def test_square_centre_known_answer():
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    np.testing.assert_allclose(mean_value_coordinates(sq, [[0.5, 0.5]]), [[0.25] * 4], atol=1e-12)


def test_interpolation_at_vertices_and_edges():
    cage = star()
    lam = mean_value_coordinates(cage, cage)
    np.testing.assert_allclose(lam, np.eye(len(cage)), atol=1e-12)
    mid = 0.3 * cage[2] + 0.7 * cage[3]
    lam = mean_value_coordinates(cage, mid[None])
    expect = np.zeros(len(cage))
    expect[2], expect[3] = 0.3, 0.7
    np.testing.assert_allclose(lam[0], expect, atol=1e-9)


def test_outside_points_still_reproduce_linear_functions():
    cage = star()
    pts = np.array([[3.0, 0.2], [-2.5, 2.0]])
    lam = mean_value_coordinates(cage, pts)
    assert np.isfinite(lam).all()
    np.testing.assert_allclose(lam @ cage, pts, atol=1e-8)


def test_orientation_does_not_matter():
    cage = star()
    pts = np.random.default_rng(2).uniform(-0.4, 0.4, (20, 2))
    a = mean_value_coordinates(cage, pts)
    b = mean_value_coordinates(cage[::-1], pts)[:, ::-1]
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_transfer_between_cages_maps_affinely_for_affine_cages():
    cage = star()
    m, t = np.array([[1.5, 0.2], [-0.3, 0.7]]), np.array([2.0, 1.0])
    pts = np.random.default_rng(3).uniform(-0.4, 0.4, (50, 2))
    np.testing.assert_allclose(transfer(cage, cage @ m + t, pts), pts @ m + t, atol=1e-10)


def test_bad_cages_are_refused():
    with pytest.raises(UserError):
        mean_value_coordinates(np.zeros((2, 2)), np.zeros((1, 2)))
    with pytest.raises(UserError):
        mean_value_coordinates(star(), np.zeros((3, 3)))
    with pytest.raises(UserError):
        transfer(star(12), star(10), np.zeros((1, 2)))
