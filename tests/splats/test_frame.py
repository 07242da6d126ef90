"""splats.frame: the input <-> working similarity."""
import numpy as np
import pytest

from leaffit_usd.splats.frame import Frame, rotation_to_z


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0.3, -0.8, 0.1)])
def test_rotation_to_z(up):
    r = rotation_to_z(np.array(up, float))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0)
    np.testing.assert_allclose(r @ (np.array(up) / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)


def test_frame_round_trip_and_units():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3)) * 3 + 7
    up = np.array([0.2, 0.9, -0.1])
    lowest = int(np.argmin(pts @ up))
    f = Frame.from_root_up(pts, pts[lowest], up)
    w = f.to_working(pts)
    np.testing.assert_allclose(w[lowest], 0, atol=1e-12)
    assert w[:, 2].max() == pytest.approx(1.0)
    np.testing.assert_allclose(f.to_input(w), pts, atol=1e-10)
    h = np.c_[pts, np.ones(100)]
    np.testing.assert_allclose((h @ f.input_to_working.T)[:, :3], w, atol=1e-10)
    np.testing.assert_allclose(f.working_to_input @ f.input_to_working, np.eye(4), atol=1e-12)
    assert Frame.from_dict(f.to_dict()).height == f.height
