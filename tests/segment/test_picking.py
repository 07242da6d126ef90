"""BVH ray picking vs the brute-force exact reference."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.segment.picking import (GaussianBVH, PickResult, ellipsoid_whitening, pick_brute_force,
                                         ray_ellipsoid_entry)
from leaffit_usd.geometry.quaternion import quat_to_matrix


def random_gaussians(n, seed=0, scale=0.01):
    rng = np.random.default_rng(seed)
    means = rng.random((n, 3))
    scales = np.exp(rng.normal(np.log(scale), 0.6, (n, 3)))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return means, scales, quat_to_matrix(q)


def test_matches_brute_force_on_random_rays():
    means, scales, rots = random_gaussians(5000)
    bvh = GaussianBVH(means, scales, rots)
    rng = np.random.default_rng(1)
    hits = 0
    for _ in range(300):
        o = rng.normal(size=3) * 2 + 0.5
        aim = means[rng.integers(len(means))] if rng.random() < 0.7 else rng.random(3) * 1.4 - 0.2
        d = aim - o
        got = bvh.pick(o, d)
        ref = pick_brute_force(means, scales, rots, o, d)
        assert got.index == ref.index
        if ref.hit:
            hits += 1
            assert got.t == pytest.approx(ref.t, rel=1e-12)
    assert hits > 150  # the test exercises hits, not only misses


def test_hits_the_nearest_of_two_stacked_gaussians_exactly_at_the_rim():
    # two spheres (sigma 0.1) on the x axis; 3 sigma radius = 0.3
    means = np.array([[2.0, 0, 0], [0.0, 0, 0]])
    scales = np.full((2, 3), 0.1)
    rots = np.repeat(np.eye(3)[None], 2, 0)
    bvh = GaussianBVH(means, scales, rots)
    r = bvh.pick([-5, 0, 0], [1, 0, 0])
    assert r.index == 1 and r.t == pytest.approx(4.7)
    # just inside / just outside the 3-sigma silhouette of Gaussian 1 (exact test, not a box)
    assert bvh.pick([-5, 0.2999, 0], [1, 0, 0]).index == 1
    assert bvh.pick([-5, 0.3001, 0], [1, 0, 0]).index == -1
    # the AABB corner region is a miss for an exact ellipsoid test
    assert bvh.pick([-5, 0.25, 0.25], [1, 0, 0]).index == -1
    # from the other side, Gaussian 0 is first
    assert bvh.pick([5, 0, 0], [-1, 0, 0]).index == 0


def test_anisotropic_ellipsoid_uses_rotation():
    rot = quat_to_matrix(np.array([[np.cos(np.pi / 8), 0, 0, np.sin(np.pi / 8)]]))  # 45 deg about z
    bvh = GaussianBVH(np.zeros((1, 3)), np.array([[1.0, 0.01, 0.01]]), rot)
    # long axis along (1, 1, 0)/sqrt2, 3 sigma = 3: a ray down -z through (1.5, 1.5, .) hits
    assert bvh.pick([1.5, 1.5, 5], [0, 0, -1]).hit
    assert not bvh.pick([1.5, -1.5, 5], [0, 0, -1]).hit


def test_origin_inside_is_not_a_hit_and_pickable_mask():
    means, scales, rots = random_gaussians(500, seed=3)
    big = np.array([[0.5, 0.5, 0.5]]), np.array([[0.3, 0.3, 0.3]]), np.eye(3)[None]
    m = np.concatenate([means, big[0]])
    s = np.concatenate([scales, big[1]])
    r = np.concatenate([rots, big[2]])
    bvh = GaussianBVH(m, s, r)
    res = bvh.pick([0.5, 0.5, 0.5], [1, 0.1, 0.05])
    assert res.index != 500
    assert res.index == pick_brute_force(m, s, r, [0.5, 0.5, 0.5], [1, 0.1, 0.05]).index
    # masked Gaussians are never returned
    first = bvh.pick([-3, 0.5, 0.5], [1, 0, 0]).index
    assert first >= 0
    mask = np.ones(len(m), bool)
    mask[first] = False
    masked = GaussianBVH(m, s, r, pickable=mask).pick([-3, 0.5, 0.5], [1, 0, 0])
    assert masked.index != first
    assert masked.index == pick_brute_force(m, s, r, [-3, 0.5, 0.5], [1, 0, 0], pickable=mask).index


def test_miss_empty_and_tiny_clouds():
    means, scales, rots = random_gaussians(3)
    bvh = GaussianBVH(means, scales, rots)
    assert bvh.pick([0, 0, 10], [0, 0, 1]) == PickResult(-1, float("inf"))
    empty = GaussianBVH(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    assert not empty.pick([0, 0, 0], [1, 0, 0]).hit
    one = GaussianBVH(np.zeros((1, 3)), np.full((1, 3), 0.1), np.eye(3)[None])
    assert one.pick([0, 0, -1], [0, 0, 1]).index == 0


def test_whitening_maps_the_3_sigma_surface_to_the_unit_sphere():
    _, scales, rots = random_gaussians(50, seed=5)
    w = ellipsoid_whitening(scales, rots)
    axis_pts = 3 * scales[:, 0, None] * rots[:, :, 0]  # 3 sigma along the first local axis
    assert np.allclose(np.linalg.norm(np.einsum("nij,nj->ni", w, axis_pts), axis=1), 1.0)
    t = ray_ellipsoid_entry([0, 0, -5], [0, 0, 1], np.zeros((1, 3)), np.eye(3)[None] / 1.0)
    assert t[0] == pytest.approx(4.0)


@pytest.mark.parametrize("bad", [
    dict(means=np.zeros((4, 2))),
    dict(scales=np.zeros((3, 3))),
    dict(rotations=np.zeros((4, 3))),
    dict(leaf_size=0),
])
def test_validation(bad):
    args = dict(means=np.zeros((4, 3)), scales=np.ones((4, 3)), rotations=np.repeat(np.eye(3)[None], 4, 0))
    args.update(bad)
    with pytest.raises(ParameterError):
        GaussianBVH(**args)


def test_bad_ray_is_refused():
    means, scales, rots = random_gaussians(10)
    with pytest.raises(ParameterError):
        GaussianBVH(means, scales, rots).pick([0, 0, 0], [0, 0, 0])
    with pytest.raises(ParameterError):
        GaussianBVH(means, scales, rots).pick([np.nan, 0, 0], [1, 0, 0])


def test_from_cloud(plant):
    cloud = plant[0]
    bvh = GaussianBVH.from_cloud(cloud)
    i = 1234
    o = cloud.means[i] + np.array([0, 0, 5.0])
    r = bvh.pick(o, [0, 0, -1])
    ref = pick_brute_force(cloud.means, cloud.scales, cloud.rotation_matrices(), o, [0, 0, -1])
    assert r.hit and r.index == ref.index
