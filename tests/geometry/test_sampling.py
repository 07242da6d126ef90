"""geometry.sampling: farthest point sampling."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.sampling import _fps_numpy, farthest_point_sampling


def test_fps_fast_path_equals_reference_set():
    p = np.random.default_rng(1).normal(size=(5000, 3))
    fast = farthest_point_sampling(p, 300)
    ref = np.sort(_fps_numpy(p, 300, 0))
    np.testing.assert_array_equal(fast, ref)


def test_fps_is_spread_out():
    # FPS of a dense grid picks points whose min pairwise distance is far above random sampling
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, 30)] * 2), -1).reshape(-1, 2)
    p = np.c_[g, np.zeros(len(g))]
    idx = farthest_point_sampling(p, 50)
    q = p[idx]
    d = np.linalg.norm(q[:, None] - q[None], axis=-1) + np.eye(50) * 9
    assert d.min() > 0.08  # random picks of 50 of 900 grid points come within one grid step (0.034)


def test_fps_bad_k_and_duplicates():
    with pytest.raises(ParameterError):
        farthest_point_sampling(np.zeros((5, 3)), 0)
    dup = np.zeros((10, 3))
    assert len(farthest_point_sampling(dup, 20)) == 1
