"""SH evaluation and rotation (leaffit_usd.splats.sh)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from leaffit_usd.splats.cloud import SH_C0, GaussianCloud
from leaffit_usd.splats.sh import eval_sh, rotate_sh, sh_basis, sh_rotation


def _dirs(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_basis_is_orthonormal_real_sh():
    """The 3DGS basis is the orthonormal real SH: the Gram matrix over the sphere is identity."""
    d = _dirs(400_000, 1)
    y = sh_basis(d, 3)
    gram = 4 * np.pi * (y.T @ y) / len(d)
    np.testing.assert_allclose(gram, np.eye(16), atol=0.02)


def test_dc_only_is_the_clouds_colour():
    c = GaussianCloud.from_activated(np.zeros((5, 3)), np.ones((5, 3)), np.tile([1.0, 0, 0, 0], (5, 1)),
                                     np.full(5, 0.5), colors=np.linspace(0.1, 0.9, 15).reshape(5, 3))
    np.testing.assert_allclose(eval_sh(c.sh, [0, 0, 1.0]), c.colors, atol=1e-6)
    assert abs(sh_basis(np.array([[0, 0, 1.0]]), 0)[0, 0] - SH_C0) < 1e-15


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotation_moves_view_dependent_colour_with_the_scene(degree):
    rng = np.random.default_rng(degree)
    sh = rng.normal(0, 0.3, (40, (degree + 1) ** 2, 3)).astype(np.float32)
    r = Rotation.random(random_state=degree).as_matrix()
    d = _dirs(40, degree + 10)
    # colour seen along r d in the rotated scene == colour along d before
    np.testing.assert_allclose(eval_sh(rotate_sh(sh, r), d @ r.T), eval_sh(sh, d), atol=2e-6)
    # without the rotation the view-dependent colour is wrong (the test can fail)
    assert np.abs(eval_sh(sh, d @ r.T) - eval_sh(sh, d)).max() > 0.05


def test_rotation_matrices_are_orthogonal_and_compose():
    r1, r2 = Rotation.random(2, random_state=4).as_matrix()
    d1, d2, d12 = sh_rotation(r1), sh_rotation(r2), sh_rotation(r2 @ r1)
    np.testing.assert_allclose(d1 @ d1.T, np.eye(16), atol=1e-12)
    np.testing.assert_allclose(d2 @ d1, d12, atol=1e-12)
    np.testing.assert_allclose(sh_rotation(np.eye(3)), np.eye(16), atol=1e-12)
    sh = np.random.default_rng(0).normal(size=(3, 9, 3)).astype(np.float32)
    assert rotate_sh(sh, np.eye(3)).tobytes() == sh.tobytes()  # identity: bit-exact
