"""The triangle rasteriser: coverage area, depth order, interpolation."""
import numpy as np

from leaffit_usd.edit.raster import iou, rasterize


def square(z=0.0):
    p = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return p, f


def test_coverage_matches_area():
    p, f = square()
    r = rasterize(p, f, 100, 100, (-0.5, 1.5, -0.5, 1.5))
    assert abs(r.mask.sum() - 2500) <= 100  # a unit square in a 2x2 window at 100x100 px
    # the square occupies the bottom-left... in pixel terms rows 25..74, cols 25..74
    assert r.mask[50, 50] and not r.mask[10, 50] and not r.mask[50, 90]


def test_nearest_surface_wins_and_interpolates():
    p1, f1 = square(0.0)
    p2, f2 = square(0.5)
    p = np.vstack([p1, p2])
    f = np.vstack([f1, f2 + 4])
    r = rasterize(p, f, 32, 32, (0, 1, 0, 1))
    assert np.nanmin(r.depth) == 0.5 and (r.face >= 2).all()
    ramp = r.interpolate(p[:, :1], f)[..., 0]   # x interpolated = the pixel centre's x
    cols = (np.arange(32) + 0.5) / 32
    np.testing.assert_allclose(ramp, np.broadcast_to(cols, (32, 32)), atol=1e-9)


def test_iou():
    a = np.zeros((4, 4), bool)
    a[:2] = True
    b = np.zeros((4, 4), bool)
    b[1:3] = True
    assert iou(a, b) == 4 / 12
    assert iou(a, a) == 1.0
