"""geometry.outliers: the floater test."""
import numpy as np

from leaffit_usd.geometry.outliers import inlier_mask


def test_floaters_are_outliers():
    rng = np.random.default_rng(0)
    blob = rng.normal(size=(500, 3))
    far = np.array([[50.0, 0, 0], [0, -40.0, 0]])
    keep = inlier_mask(np.concatenate([blob, far]), factor=4.0)
    assert not keep[-2:].any()
    assert keep[:-2].mean() > 0.98


def test_inlier_mask_degenerate_cases():
    assert inlier_mask(np.zeros((5, 3)), 4.0).all()          # fewer than k + 2 points
    assert inlier_mask(np.zeros((50, 3)), 4.0).all()         # median distance 0
    p = np.random.default_rng(1).normal(size=(50, 3))
    p[0] = 100
    assert inlier_mask(p, 0.0).all()                         # factor 0 switches it off
    assert not inlier_mask(p, 4.0)[0]
