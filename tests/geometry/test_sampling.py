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


def test_position_order_sample_ignores_the_order():
    """The same points shuffled give the same sample (a seeded choice by file index would not);
    fewer points than asked for: all of them."""
    from leaffit_usd.geometry.sampling import position_order_sample

    rng = np.random.default_rng(2)
    p = rng.normal(size=(5000, 3))
    perm = rng.permutation(len(p))
    a = position_order_sample(p, 700, seed=4)
    b = position_order_sample(p[perm], 700, seed=4)
    assert len(a) == 700 and np.all(np.diff(a) > 0)
    assert set(a.tolist()) == set(perm[b].tolist())
    assert np.array_equal(position_order_sample(p[:300], 700, seed=4), np.arange(300))
    # sample_at_most: the same sample, and 0 = no limit
    from leaffit_usd.geometry.sampling import sample_at_most
    assert np.array_equal(sample_at_most(p, 700, seed=4), a)
    assert np.array_equal(sample_at_most(p, 0), np.arange(5000))


def test_position_order_is_lexsorts_order_with_ties():
    """x first, then y, then z, then the index -- also inside runs of equal x (float32 captures
    have them) and for exact duplicates; a sort by x alone fails this."""
    from leaffit_usd.geometry.sampling import position_order

    rng = np.random.default_rng(3)
    for n, step in ((1, None), (50, None), (5000, None), (5000, 0.05), (5000, 2.0)):
        p = rng.normal(size=(n, 3)).astype(np.float32).astype(np.float64)
        if step is not None:  # coarse grids: many equal x, and equal (x, y)
            p = np.round(p / step) * step
        p[rng.integers(0, n, n // 5)] = p[rng.integers(0, n, n // 5)]  # exact duplicates
        assert np.array_equal(position_order(p), np.lexsort(p.T[::-1])), (n, step)


def test_grid_order_visits_cells_z_major_each_cell_contiguous():
    from leaffit_usd.geometry.sampling import grid_order

    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (5000, 3)) * [1.0, 0.5, 2.0]
    o = grid_order(p, cells=8)
    assert np.array_equal(np.sort(o), np.arange(len(p)))              # a permutation
    size = (p.max(0) - p.min(0)).max() / 8
    c = np.floor((p[o] - p.min(0)) / size).astype(int)
    key = (c[:, 2] * 100 + c[:, 1]) * 100 + c[:, 0]
    assert np.all(np.diff(key) >= 0)                                  # cells in z, y, x order
    same = np.flatnonzero(np.diff(key) == 0)
    assert np.all(o[same + 1] > o[same])                              # stable within a cell
    assert len(grid_order(np.zeros((0, 3)))) == 0
    assert np.array_equal(grid_order(np.zeros((4, 3))), np.arange(4))  # one point, any number


def test_voxel_centroids_are_each_voxels_mean_whatever_the_origin():
    """Each centroid is the mean of the points in its voxel (checked one voxel at a time), the
    counts add up to the points, and an origin inside the points (negative voxel indices)
    partitions them by the grid through that origin."""
    from leaffit_usd.geometry.sampling import voxel_centroids

    rng = np.random.default_rng(4)
    p = rng.uniform(-1, 1, (3000, 3))
    for origin in (None, np.array([0.05, -0.2, 0.3])):
        cen, inv, cnt = voxel_centroids(p, 0.25, origin)
        assert cnt.sum() == len(p) and len(cen) == len(cnt) == inv.max() + 1
        o = p.min(0) if origin is None else origin
        key = np.floor((p - o) / 0.25).astype(int)
        for v in range(len(cen)):
            members = inv == v
            assert len(np.unique(key[members], axis=0)) == 1       # one voxel of that grid
            np.testing.assert_allclose(cen[v], p[members].mean(0), rtol=0, atol=1e-12)
        assert len(np.unique(key, axis=0)) == len(cen)


def test_canonical_order_puts_shuffled_points_in_one_order_cell_by_cell():
    """The same points in any order come out as the same sequence of positions (a grid order
    alone keeps the given order inside each cell and fails this), and each grid cell's points
    are contiguous."""
    from leaffit_usd.geometry.sampling import canonical_order

    rng = np.random.default_rng(4)
    p = np.round(rng.normal(size=(4000, 3)), 2)      # ties in x and (x, y)
    perm = rng.permutation(len(p))
    a, b = p[canonical_order(p, 8)], p[perm][canonical_order(p[perm], 8)]
    assert np.array_equal(a, b)
    assert sorted(canonical_order(p, 8).tolist()) == list(range(len(p)))
    size = float(np.ptp(p, 0).max()) / 8
    cell = np.floor((a - a.min(0)) / size).astype(np.int64) @ np.array([1, 100, 10000])
    assert len(np.unique(cell)) == (np.diff(cell) != 0).sum() + 1   # no cell visited twice
