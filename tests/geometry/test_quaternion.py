"""geometry.quaternion: (w, x, y, z) products, matrices, USD/scipy (x, y, z, w) order."""
import numpy as np
from scipy.spatial.transform import Rotation

from leaffit_usd.geometry.quaternion import (from_xyzw, matrix_to_quat, normalize, quat_multiply,
                                             quat_to_matrix, to_xyzw)


def wxyz(r):
    return np.roll(r.as_quat(), 1, axis=1)


def test_quat_multiply_matches_scipy():
    a, b = Rotation.random(5, random_state=1), Rotation.random(5, random_state=2)
    got = quat_multiply(wxyz(a), wxyz(b))
    want = wxyz(a * b)
    assert np.allclose(np.abs(np.sum(got * want, 1)), 1.0)


def test_matrix_round_trip_and_sign():
    r = Rotation.random(20, random_state=3)
    q = matrix_to_quat(r.as_matrix())
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q), r.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(q * wxyz(r), 1)), 1.0, atol=1e-12)


def test_xyzw_order_and_normalize():
    q = np.array([[2.0, 0.0, 0.0, 0.0], [0.1, 0.2, 0.3, 0.4], [0.0, 0.0, 0.0, 0.0]])
    assert np.array_equal(from_xyzw(to_xyzw(q)), q)
    assert np.array_equal(to_xyzw(q)[1], [0.2, 0.3, 0.4, 0.1])
    n = normalize(q)
    np.testing.assert_allclose(n[0], [1, 0, 0, 0])
    np.testing.assert_allclose(np.linalg.norm(n[1]), 1.0)
    assert np.array_equal(n[2], np.zeros(4))  # a zero quaternion stays zero
    assert to_xyzw(q.astype(np.float32)).dtype == np.float32
