"""The up estimate's leaf-normal check of a low-confidence answer (splats.up_axis)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from leaffit_usd.splats import up_axis as U
from leaffit_usd.splats.up_axis import LOW_UP_CONFIDENCE, estimate_up_with_confidence
from tests.splats.splat_synth import make_plant


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(abs(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _goblet(rng, n_stem=300, n_cap=3000):
    """A bare 'plant' along +z: a thin stem (z in [0, 0.5], radius 0.01, normals all round) under
    a wide cap of leaves (z in [0.5, 1], radius up to 0.5, normals within ~25 degrees of z).
    Returns (M, 6) float64 centred points with unit normals."""
    a = rng.uniform(0, 2 * np.pi, n_stem)
    stem = np.c_[0.01 * np.cos(a), 0.01 * np.sin(a), rng.uniform(0, 0.5, n_stem)]
    stem_n = np.c_[np.cos(a), np.sin(a), np.zeros(n_stem)]
    r, b = 0.5 * np.sqrt(rng.uniform(0, 1, n_cap)), rng.uniform(0, 2 * np.pi, n_cap)
    cap = np.c_[r * np.cos(b), r * np.sin(b), 0.5 + 0.5 * r + rng.normal(0, 0.02, n_cap)]
    cap_n = _unit(np.c_[rng.normal(0, 0.3, (n_cap, 2)), np.ones(n_cap)])
    cap_n[rng.uniform(size=n_cap) < 0.5] *= -1  # Gaussian normals are unsigned
    p = np.r_[np.c_[stem, stem_n], np.c_[cap, cap_n]]
    p[:, :3] -= p[:, :3].mean(0)
    return p


def test_normal_axis_clear_for_leaves_facing_up_not_for_blades_on_edge():
    rng = np.random.default_rng(0)
    up = _unit(np.array([0.3, -0.5, 0.8]))
    rot = Rotation.align_vectors([up], [[0, 0, 1]])[0].as_matrix()
    facing = _unit(np.c_[rng.normal(0, 0.3, (4000, 2)), np.ones(4000)]) @ rot.T
    axis, ratio = U._normal_axis(facing * rng.choice([-1, 1], (4000, 1)))
    assert _angle(axis, up) < 3 and ratio > 5
    # grass blades stand on edge: normals spread around the horizontal plane
    t = rng.uniform(0, 2 * np.pi, 4000)
    on_edge = _unit(np.c_[np.cos(t), np.sin(t), rng.normal(0, 0.3, 4000)]) @ rot.T
    assert U._normal_axis(on_edge)[1] < U._NORMAL_AXIS_RATIO


def test_end_width_finds_the_stem_end():
    p = _goblet(np.random.default_rng(1))
    z = np.array([0.0, 0, 1])
    w_up, w_down = U._end_width(p, z), U._end_width(p, -z)
    assert w_up < U._END_RATIO * w_down, (w_up, w_down)


def test_leaf_normal_check_turns_a_wrong_low_confidence_up():
    rng = np.random.default_rng(2)
    rot = Rotation.random(random_state=3).as_matrix()
    p = _goblet(rng)
    p = np.c_[p[:, :3] @ rot.T, p[:, 3:] @ rot.T]
    up = rot @ [0, 0, 1]
    # a horizontal answer, or one 135 degrees off (as the grape's was), is turned to the leaves'
    # axis, pointing away from the stem
    for wrong in (rot @ _unit(np.array([1.0, 0.2, 0.1])), rot @ _unit(np.array([1.0, 0.0, -1.0]))):
        fixed = U._leaf_normal_check(p, wrong)
        assert fixed is not None and np.degrees(np.arccos(np.clip(fixed @ up, -1, 1))) < 5
    # an answer within 30 degrees of the axis is kept
    near = rot @ _unit(np.array([0.3, 0.0, 1.0]))
    assert U._leaf_normal_check(p, near) is None
    # no clear normal axis (blades on edge): no opinion
    t = rng.uniform(0, 2 * np.pi, len(p))
    q = np.c_[p[:, :3], np.c_[np.cos(t), np.sin(t), 0.2 * rng.normal(size=len(p))] @ rot.T]
    q[:, 3:] = _unit(q[:, 3:])
    assert U._leaf_normal_check(q, rot @ [1.0, 0, 0]) is None
    # both ends alike (a cap on either side of a stem): no opinion
    mirrored = np.r_[p, np.c_[-p[:, :3], p[:, 3:]]]
    assert U._leaf_normal_check(mirrored, rot @ [1.0, 0, 0]) is None


def test_low_confidence_plant_gets_its_up_from_the_leaves():
    """A generated plant (thin leaves, all overlaps) whose root score is a coin toss: the old
    estimate was 69 degrees off; the leaves' normals and the narrow stem end give the up."""
    from samples import make_plant as make_sample
    from samples.generate import PlantSpec

    cloud, gt = make_sample(PlantSpec(kind="thin", leaves=15, overlap="all", gaussians=20_000), 14000)
    est = estimate_up_with_confidence(cloud.means, cloud.shortest_axes())
    assert np.degrees(np.arccos(np.clip(est.up @ gt.up, -1, 1))) < 10
    assert est.confidence < LOW_UP_CONFIDENCE  # still reported as shaky
    # the root follows the new up: near the stem base
    assert np.linalg.norm(est.root - gt.root) < 0.05 * gt.height


def test_points_only_estimate_skips_the_check(monkeypatch):
    sp = make_plant(4)
    monkeypatch.setattr(U, "_leaf_normal_check", lambda *a: pytest.fail("no normals, no check"))
    estimate_up_with_confidence(sp.cloud.means)
