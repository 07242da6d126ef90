"""The one MLS formulation: known answers, invariants, numpy == torch, gradients."""
import numpy as np
import pytest
import torch

from leaffit_usd.fit.mls import deform, deform_points, mls_weights, mls_weights_torch


@pytest.fixture
def leaf():
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.1, 0.1, (32, 3))
    p[:, 2] *= 0.02  # nearly flat, like a leaf template: singular affine moment without reg
    v = rng.uniform(-0.1, 0.1, (400, 3))
    v[:, 2] *= 0.02
    return p, v


def test_rows_are_a_partition_of_unity(leaf):
    p, v = leaf
    a = mls_weights(p, v)
    assert a.shape == (400, 32)
    np.testing.assert_allclose(a.sum(1), 1.0, atol=1e-12)


def test_translation_is_reproduced_exactly(leaf):
    p, v = leaf
    t = np.array([0.3, -0.2, 0.05])
    a = mls_weights(p, v)
    np.testing.assert_allclose(deform(a, p + t) - deform(a, p), np.broadcast_to(t, v.shape), atol=1e-12)


def test_identity_targets_nearly_reproduce_points(leaf):
    # the regulariser shrinks the affine part slightly: along the sheet the error stays far below
    # the leaf size (0.2); across it, it damps the field's derivative on purpose (``fit.mls``),
    # so a point moves onto the handles' local plane, never farther than the sheet's thickness
    p, v = leaf
    err = np.abs(deform_points(p, p, v) - v)
    assert err[:, :2].max() < 0.005 * 0.2
    assert err[:, 2].max() < 0.004  # p and v each within +-0.002 of the plane


def test_affine_targets_follow_the_affine_map_in_plane(leaf):
    p, v = leaf
    m = np.array([[1.2, 0.3, 0.0], [-0.1, 0.8, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([0.1, 0.2, 0.3])
    err = np.abs(deform_points(p, p @ m + t, v) - (v @ m + t))
    assert err[:, :2].max() < 0.005 * 0.2 and err[:, 2].max() < 0.004


def test_flat_template_with_far_points_stays_finite():
    p = np.zeros((8, 3))
    p[:, 0] = np.linspace(0, 1, 8)  # collinear control points
    v = np.array([[5.0, 5.0, 5.0], [0.5, 0.0, 0.0]])
    a = mls_weights(p, v, sigma=0.01)  # exponent underflows without the shift
    assert np.isfinite(a).all()


def test_batched_deform_matches_per_leaf_loop(leaf):
    p, v = leaf
    rng = np.random.default_rng(1)
    q = p[None] + rng.normal(scale=0.01, size=(5, 32, 3))
    a = mls_weights(p, v)
    batched = deform(a, q)
    for j in range(5):
        np.testing.assert_allclose(batched[j], deform_points(p, q[j], v), atol=1e-12)


def test_torch_matches_numpy_float64_and_float32(leaf):
    p, v = leaf
    ref = mls_weights(p, v)
    got64 = mls_weights_torch(torch.tensor(p), torch.tensor(v)).numpy()
    np.testing.assert_allclose(got64, ref, rtol=1e-10, atol=1e-12)
    got32 = mls_weights_torch(torch.tensor(p, dtype=torch.float32), torch.tensor(v, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(got32, ref, atol=1e-4)


def test_torch_gradients_gradcheck():
    rng = np.random.default_rng(2)
    p = torch.tensor(rng.uniform(-0.1, 0.1, (6, 3)), requires_grad=True)
    v = torch.tensor(rng.uniform(-0.1, 0.1, (4, 3)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: mls_weights_torch(a, b), (p, v))
