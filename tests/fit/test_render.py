"""Tests of the CPU splat renderer (leaffit_usd.splats.render) against its float64 reference."""
import numpy as np
import pytest
import torch

from leaffit_usd.errors import ParameterError
from leaffit_usd.splats.render import (ALPHA_MAX, RenderResult, fit_bounds, render_orthographic,
                                       render_orthographic_np, render_reference)

ATOL64 = 1e-10   # tiled torch float64 vs numpy float64 reference
ATOL32 = 2e-5    # float32 path vs float64 reference (colour/alpha in [0, 1])


def _random_gaussians(rng, n, spread=0.6, size=0.2):
    m = rng.uniform(-spread, spread, (n, 3))
    a = rng.normal(size=(n, 3, 3)) * size
    cov = a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(3)
    return m, cov, rng.uniform(size=(n, 3)), rng.uniform(0.2, 0.95, n)


@pytest.mark.parametrize("from_below,antialias", [(False, False), (True, False), (False, True)])
def test_matches_reference_float64(from_below, antialias):
    rng = np.random.default_rng(0)
    m, cov, col, op = _random_gaussians(rng, 25, size=0.03 if antialias else 0.2)
    b = (-1.2, 1.3, -1.1, 1.0)                      # non-square pixels, size not a tile multiple
    ref = render_reference(m, cov, col, op, 37, 29, b, background=[0.1, 0.2, 0.3],
                           from_below=from_below, antialias=antialias)
    out = render_orthographic(*(torch.tensor(x) for x in (m, cov, col, op)), 37, 29, b,
                              background=[0.1, 0.2, 0.3], from_below=from_below,
                              antialias=antialias)
    for r, o in zip(ref, out):
        assert o.dtype == torch.float64
        np.testing.assert_allclose(o.numpy(), r, atol=ATOL64)


def _square_of_splats(per_side: int, half: float = 1.0):
    """A flat square [-half, half]^2 covered by a per_side^2 grid of round splats of sigma 0.6
    spacing (a surface and its splats: denser captures have more, smaller splats)."""
    sp = 2 * half / per_side
    g = -half + sp * (np.arange(per_side) + 0.5)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    m = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    cov = np.tile(np.diag([(0.6 * sp) ** 2, (0.6 * sp) ** 2, 1e-8]), (len(m), 1, 1))
    return m, cov, np.full((len(m), 3), 0.5), np.full(len(m), 0.9)


def test_antialias_keeps_a_surfaces_silhouette_as_its_splats_shrink():
    """Mip-Splatting's 2D filter: a square seen at 64 px renders (alpha >= 0.5) at about its
    true size (+6 % from the splats' spread past the last centres) whether its splats are
    2.4 px or 0.15 px (sigma); 3DGS's plain dilation grows the dense one's silhouette by 16 %
    (each sub-pixel splat a ~0.55 px blob of full opacity)."""
    b, W = (-1.5, 1.5, -1.5, 1.5), 64
    true_px = (2.0 / 3.0 * W) ** 2
    area = {}
    for per_side in (16, 64, 256):                  # splat sigma 2.4, 0.6 and 0.15 px
        for aa in (False, True):
            r = render_orthographic_np(*_square_of_splats(per_side), W, W, b, antialias=aa)
            area[per_side, aa] = float((r.alpha >= 0.5).sum()) / true_px
    assert area[16, True] == pytest.approx(area[16, False], abs=0.01)   # large splats: as before
    for per_side in (16, 64, 256):
        assert abs(area[per_side, True] - 1.0) < 0.08
    assert area[256, False] > 1.12


def test_numpy_wrapper_float32_and_small_chunks():
    rng = np.random.default_rng(1)
    m, cov, col, op = _random_gaussians(rng, 40)
    ref = render_reference(m, cov, col, op, 50, 40, (-1, 1, -1, 1))
    out = render_orthographic_np(m, cov, col, op, 50, 40, (-1, 1, -1, 1))
    assert out.color.shape == (40, 50, 3) and out.depth.shape == (40, 50) and out.alpha.dtype == np.float32
    np.testing.assert_allclose(out.color, ref.color, atol=ATOL32)
    np.testing.assert_allclose(out.alpha, ref.alpha, atol=ATOL32)
    # tiny memory chunks give the same image (chunking is only a memory bound)
    small = render_orthographic(*(torch.tensor(x) for x in (m, cov, col, op)), 50, 40, (-1, 1, -1, 1),
                                max_elements=1)
    np.testing.assert_allclose(small.color.numpy(), ref.color, atol=ATOL64)


def test_known_answer_orientation_and_occlusion():
    """Row 0 is ymax, column 0 is xmin; from above the higher Gaussian hides the lower one."""
    cov = np.tile(np.diag([1e-3, 1e-3, 1e-3]), (3, 1, 1))
    m = np.array([[-0.45, 0.45, 0.0],     # centre of pixel (row 5, col 5): red
                  [0.55, -0.55, 0.1],     # centre of pixel (15, 15): green, above ...
                  [0.55, -0.55, -0.1]])   # ... a blue one
    col = np.eye(3)
    op = np.full(3, 0.99)
    top = render_orthographic_np(m, cov, col, op, 20, 20, (-1, 1, -1, 1))
    assert top.color[5, 5].argmax() == 0 and top.alpha[5, 5] == pytest.approx(0.99)
    assert top.color[15, 15].argmax() == 1
    assert top.depth[15, 15] == pytest.approx((0.1 * 0.99 - 0.1 * 0.01 * 0.99) / (1 - 0.01 * 0.01), abs=1e-5)
    bottom = render_orthographic_np(m, cov, col, op, 20, 20, (-1, 1, -1, 1), from_below=True)
    assert bottom.color[15, 15].argmax() == 2          # not mirrored: same pixel, other side
    assert bottom.color[5, 5].argmax() == 0
    assert top.alpha.max() <= 1 - (1 - ALPHA_MAX) ** 2 + 1e-6
    assert top.alpha[0, 19] == 0 and top.depth[0, 19] == 0     # empty pixel


def test_gradcheck_float64():
    rng = np.random.default_rng(2)
    m, cov, col, op = _random_gaussians(rng, 6, size=0.25)
    ts = [torch.tensor(x, requires_grad=True) for x in (m, cov, col, op)]

    def f(mm, cc, co, oo):
        r = render_orthographic(mm, 0.5 * (cc + cc.transpose(1, 2)), co, oo, 12, 10, (-1, 1, -1, 1))
        return r.color, r.depth, r.alpha

    assert torch.autograd.gradcheck(f, ts, atol=1e-6, rtol=1e-4)


def test_empty_and_offscreen():
    out = render_orthographic_np(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0),
                                 8, 8, (0, 1, 0, 1))
    assert out.alpha.shape == (8, 8) and not out.alpha.any()
    out = render_orthographic_np(np.array([[5.0, 5, 0]]), np.eye(3)[None] * 1e-4, np.ones((1, 3)),
                                 np.ones(1) * 0.5, 8, 8, (0, 1, 0, 1))
    assert not out.alpha.any() and np.isfinite(out.depth).all()


@pytest.mark.parametrize("kwargs", [
    dict(means=np.zeros((2, 2))),
    dict(cov=np.zeros((3, 3, 3))),
    dict(opacities=np.zeros(3)),
    dict(width=0),
    dict(bounds=(1, 0, 0, 1)),
    dict(bounds=(0, 1, 0)),
])
def test_bad_input_raises(kwargs):
    args = dict(means=np.zeros((2, 3)), cov=np.tile(np.eye(3), (2, 1, 1)), colors=np.zeros((2, 3)),
                opacities=np.ones(2) * 0.5, width=4, height=4, bounds=(0, 1, 0, 1))
    args.update(kwargs)
    with pytest.raises(ParameterError):
        render_orthographic_np(**args)


def test_fit_bounds_contains_points_square_pixels():
    pts = np.array([[0.0, 0.0], [2.0, 0.5]])
    b = fit_bounds(pts, 64, 32)
    assert b[0] < 0 and b[1] > 2 and b[2] < 0 and b[3] > 0.5
    assert (b[1] - b[0]) / 64 == pytest.approx((b[3] - b[2]) / 32)
    assert isinstance(render_orthographic_np(np.zeros((1, 3)), np.eye(3)[None] * 1e-3, np.ones((1, 3)),
                                             np.ones(1) * .5, 4, 4, (-1, 1, -1, 1)), RenderResult)
