"""Heat-method geodesics: accuracy against known answers, batching, domains, bad input."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.heat import GeodesicSolver, compute_distance, voxel_subsample
from leaffit_usd.geometry.knn import interpolation_matrix

TOL_PLANE = 0.02   # mean abs error, unit square sampled by 4000 points (h ~ 0.016)
TOL_SPHERE = 0.04  # mean abs error in radians, unit sphere, 6000 points


def _plane(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    return np.c_[rng.random((n, 2)), np.zeros(n)]


def test_plane_distance_is_euclidean():
    p = _plane()
    d = GeodesicSolver(p).distance(0)
    ex = np.linalg.norm(p - p[0], axis=1)
    assert d[0] == 0
    assert np.abs(d - ex).mean() < TOL_PLANE
    assert np.corrcoef(d, ex)[0, 1] > 0.998


def test_sphere_great_circle():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(6000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    d = compute_distance(v, 0)
    ex = np.arccos(np.clip(v @ v[0], -1, 1))
    assert np.abs(d - ex).mean() < TOL_SPHERE
    assert abs(d.max() - np.pi) < 0.15


def test_thin_chain_gets_arc_length():
    # a 1-D chain (a petiole a sample wide) cannot be triangulated: kNN edges carry it
    rng = np.random.default_rng(2)
    t = np.linspace(0, 1, 300)
    p = np.c_[t, 1e-4 * rng.random(300), 1e-4 * rng.random(300)]
    s = GeodesicSolver(p)
    assert s.n_components == 1
    assert np.abs(s.distance(0) - t).max() < 0.02


def test_batch_equals_single_and_multisource():
    p = _plane(2000)
    s = GeodesicSolver(p)
    D = s.distances([0, 5, [0, 5]])
    assert np.allclose(D[:, 0], s.distance(0))
    assert np.allclose(D[:, 1], s.distance(5))
    # multi-source ~ the minimum of the single-source distances
    assert np.abs(D[:, 2] - np.minimum(D[:, 0], D[:, 1])).mean() < 1.5 * TOL_PLANE


def test_disconnected_component_is_unreachable():
    a = _plane(1500)
    b = _plane(1500, seed=3) + [5.0, 0, 0]
    s = GeodesicSolver(np.r_[a, b])
    d = s.distance(0)
    assert s.n_components == 2
    assert np.isfinite(d[:1500]).all() and np.isinf(d[1500:]).all()


def test_domain_subsample_transfers_to_every_point():
    p = _plane(20000, seed=4)
    s = GeodesicSolver(p, domain=3000)
    assert 2500 < len(s.domain) < 3600
    d = s.distance(7)
    assert d.shape == (20000,) and d[7] == 0
    ex = np.linalg.norm(p - p[7], axis=1)
    assert np.abs(d - ex).mean() < 2 * TOL_PLANE


def test_orientation_aware_blocks_shortcut_between_stacked_sheets():
    # two parallel sheets 0.02 apart joined only at x = 0 by a vertical wall: without normals
    # the heat method short-cuts across the gap; with normals the path goes round by the wall
    rng = np.random.default_rng(5)
    n = 3000
    lo = np.c_[rng.random(n), rng.random(n) * 0.3, np.zeros(n)]
    hi = np.c_[rng.random(n), rng.random(n) * 0.3, np.full(n, 0.02)]
    wall = np.c_[np.zeros(200), rng.random(200) * 0.3, rng.random(200) * 0.02]
    pts = np.r_[lo, hi, wall]
    nrm = np.r_[np.tile([0, 0, 1.0], (2 * n, 1)), np.tile([1.0, 0, 0], (200, 1))]
    src = int(np.argmin(np.linalg.norm(lo - [1, 0.15, 0], axis=1)))
    tgt = n + int(np.argmin(np.linalg.norm(hi - [1, 0.15, 0.02], axis=1)))
    plain = GeodesicSolver(pts).distance(src)[tgt]
    aware = GeodesicSolver(pts, nrm).distance(src)[tgt]
    assert plain < 0.3           # short-cut (true path ~2.02)
    assert aware > 1.7


def test_duplicates_are_harmless():
    p = _plane(1000)
    p = np.r_[p, p[:200]]
    d = GeodesicSolver(p).distance(0)
    assert np.isfinite(d).all()
    assert np.allclose(d[1000:], d[:200], atol=1e-9)


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.zeros((5, 2)), np.array([[0, 0, np.nan]] * 5)])
def test_bad_points_rejected(bad):
    with pytest.raises(ParameterError):
        GeodesicSolver(bad)


def test_bad_sources_and_options_rejected():
    s = GeodesicSolver(_plane(300))
    with pytest.raises(ParameterError):
        s.distance(300)
    with pytest.raises(ParameterError):
        s.distance([])
    with pytest.raises(ParameterError):
        GeodesicSolver(_plane(300), t_coef=0)
    with pytest.raises(ParameterError):
        GeodesicSolver(_plane(300), normals=np.zeros((2, 3)))


def test_voxel_subsample_and_interpolation():
    p = _plane(5000)
    idx = voxel_subsample(p, 1000)
    assert 800 < len(idx) < 1200 and np.all(np.diff(idx) > 0)
    W = interpolation_matrix(p[idx], p, k=4)
    f = p[idx, 0] * 2 + 1  # a linear function is reproduced closely
    assert np.allclose(W.sum(1), 1)
    assert np.abs(W @ f - (p[:, 0] * 2 + 1)).max() < 0.08
    assert np.allclose((W @ f)[idx], f)


def test_voxel_subsample_ignores_point_order_and_pose():
    """The same points in another order, or rotated, scaled and moved, give the same subset (a
    grid in the points' own principal frame; per voxel the point nearest its centre). The first
    point of each voxel in a frame-aligned grid fails both."""
    rng = np.random.default_rng(3)
    p = rng.normal(size=(20000, 3)) * [3.0, 2.0, 0.5]
    ref = set(voxel_subsample(p, 4000).tolist())
    perm = rng.permutation(len(p))
    assert set(perm[voxel_subsample(p[perm], 4000)].tolist()) == ref
    c, s_ = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, c, -s_], [0, s_, c]])
    assert set(voxel_subsample(p @ rot.T * 2.5 + [4, -1, 7], 4000).tolist()) == ref


def test_bridge_joins_a_small_gap_only():
    a = _plane(1500)
    near = _plane(1500, seed=6) + [1.15, 0, 0]   # 0.15 gap (~6 spacings)
    far = _plane(1500, seed=7) + [3.0, 0, 0]     # 1.0 gap
    pts = np.r_[a, near, far]
    s = GeodesicSolver(pts, bridge_gap=0.25)
    assert len(s.bridges) == 1 and s.n_components == 2
    d = s.distance(0)
    assert np.isfinite(d[:3000]).all() and np.isinf(d[3000:]).all()
    # reached through the one bridge: beyond it, distance grows with the distance from it
    e = s.domain[s.bridges[0]]
    cross = d[e].max()
    assert d[1500:3000].min() >= cross - 1e-6
    assert np.abs(d[1500:3000] - cross - np.linalg.norm(near - pts[e[np.argmax(d[e])]], axis=1)).mean() < 0.05
    plain = GeodesicSolver(pts)
    assert plain.n_components == 3 and len(plain.bridges) == 0


def test_adjacency_graph():
    s = GeodesicSolver(_plane(500))
    a = s.adjacency()
    assert (a != a.T).nnz == 0 and a.shape == (500, 500)
    w = s.adjacency(lengths=True)
    r = np.repeat(np.arange(500), np.diff(w.indptr))
    assert np.allclose(w.data, np.linalg.norm(s._x[r] - s._x[w.indices], axis=1))


def test_domain_lookups():
    """The public domain API the segmentation uses: positions, nearest domain point, kNN."""
    p = _plane(6000, seed=5)
    s = GeodesicSolver(p, domain=1000)
    m = len(s.domain)
    assert np.array_equal(s.domain_points, p[s.domain])
    assert np.array_equal(s.nearest_domain(s.domain), np.arange(m))
    q = np.arange(0, 6000, 7)
    near = s.nearest_domain(q)
    brute = np.argmin(((p[q][:, None] - s.domain_points[None]) ** 2).sum(-1), axis=1)
    assert near.shape == q.shape and np.array_equal(near, brute)
    assert int(s.nearest_domain(int(s.domain[3]))) == 3
    nb = s.domain_neighbors(s.domain_points[10], 8)
    d = np.linalg.norm(s.domain_points - s.domain_points[10], axis=1)
    assert nb.shape == (8,) and nb[0] == 10 and np.all(np.diff(d[nb]) >= 0)
    assert np.array_equal(np.sort(d[nb]), np.sort(d)[:8])
    assert s.domain_neighbors(s.domain_points[10], 1).shape == (1,)


def test_unique_rows_equals_numpy_unique_rows():
    """unique_rows (one int64 code per row) gives np.unique(axis=0): the same rows, the same
    lexicographic order, for 1-3 columns, small and large ranges, and no rows."""
    from leaffit_usd.geometry.heat import unique_rows

    rng = np.random.default_rng(1)
    for c in (1, 2, 3):
        for m in (1, 2, 7, 6000):
            a = rng.integers(0, m, (500, c))
            np.testing.assert_array_equal(unique_rows(a, m), np.unique(a, axis=0))
    assert unique_rows(np.zeros((0, 3), np.int64), 5).shape == (0, 3)
