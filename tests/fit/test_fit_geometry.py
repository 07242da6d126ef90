"""PCA leaf frames, denoising and the deformation metrics."""
import numpy as np
import pytest
import trimesh

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.denoise import DenoiseParams, denoise_leaf
from leaffit_usd.geometry.pca import leaf_frame, pca, to_local
from leaffit_usd.metrics.deformation import (mesh_metrics, point_metrics, sample_surface,
                                             surface_distance)

TOL = 1e-9


def _plane_points(rng, n=2000, tilt=0.3):
    xy = rng.uniform([-0.1, -0.04], [0.1, 0.04], (n, 2))
    p = np.c_[xy, np.zeros(n)]
    c, s = np.cos(tilt), np.sin(tilt)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])        # tilted about y
    return p @ R.T + [0.3, 0.1, 0.5], R


def test_pca_axes_descending():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3)) * [3.0, 1.0, 0.1]
    r = pca(p)
    assert r.variances[0] > r.variances[1] > r.variances[2]
    assert abs(r.axes[0] @ [1, 0, 0]) > 0.99 and abs(r.axes[2] @ [0, 0, 1]) > 0.99


def test_leaf_frame_axes():
    rng = np.random.default_rng(1)
    p, R = _plane_points(rng)
    base = np.array([0.3, 0.1, 0.5]) - R[:, 0] * 0.1
    apex = np.array([0.3, 0.1, 0.5]) + R[:, 0] * 0.1 + R[:, 2] * 0.02   # off-plane apex
    m = leaf_frame(p, base, apex)
    rot = m[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_allclose(m[:3, 3], base)
    assert rot[:, 2] @ R[:, 2] > 0.999                  # normal = plane normal ...
    assert rot[2, 2] > 0                                 # ... towards +Z (upper side)
    assert rot[:, 0] @ R[:, 0] > 0.999                   # +X base -> apex, in the plane
    local = to_local(m, p)
    assert np.abs(local[:, 2]).max() < 1e-9             # the leaf plane is local z = 0
    # reversing base and apex flips X (and Y), never the normal
    m2 = leaf_frame(p, apex, base)
    assert m2[:3, 0] @ rot[:, 0] < -0.999 and m2[:3, 2] @ rot[:, 2] > 0.999


def test_leaf_frame_degenerate_inputs_are_finite():
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    m = leaf_frame(line, line[0], line[-1])
    assert np.isfinite(m).all() and np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(m[:3, 0], [1, 0, 0], atol=1e-12)
    m = leaf_frame(np.zeros((1, 3)), np.zeros(3), np.zeros(3))
    assert np.isfinite(m).all()
    # vertical leaf: the normal is horizontal and oriented away from the plant axis
    rng = np.random.default_rng(2)
    yz = rng.uniform(-0.05, 0.05, (300, 2))
    p = np.c_[np.full(300, 0.4), yz[:, 0], 0.5 + yz[:, 1]]
    m = leaf_frame(p, p[np.argmin(p[:, 2])], p[np.argmax(p[:, 2])])
    assert m[0, 2] > 0.99


def test_denoise_removes_outliers_and_flattens():
    rng = np.random.default_rng(3)
    p, R = _plane_points(rng, 3000)
    noisy = p + R[:, 2] * rng.normal(0, 0.002, (len(p), 1))
    outl = p[:20] + R[:, 2] * 0.05                        # 5 cm off the blade (sigma = 0.1)
    pts = np.vstack([noisy, outl])
    res = denoise_leaf(pts, DenoiseParams())
    assert res.keep[:len(noisy)].mean() > 0.97
    assert not res.keep[len(noisy):].any()
    off_in = np.abs((noisy - p[0]) @ R[:, 2]).mean()
    off_out = np.abs((res.points - p[0]) @ R[:, 2]).mean()
    assert off_out < 0.5 * off_in                         # ~3x less normal noise
    assert res.points.shape == (int(res.keep.sum()), 3)


def test_denoise_small_and_capped():
    p = np.random.default_rng(4).normal(size=(3, 3))
    r = denoise_leaf(p)
    assert r.keep.all() and np.allclose(r.points, p)
    # an isotropic blob is all "outliers" by residual: at most max_removed go
    blob = np.random.default_rng(5).normal(size=(500, 3))
    r = denoise_leaf(blob, DenoiseParams(sigma=0.1, max_removed=0.2))
    assert (~r.keep).sum() <= 100 and np.isfinite(r.points).all()


def test_denoise_neighbourhood_keeps_its_share_of_a_denser_leaf():
    # the same noisy leaf at 4x the density: a fixed k averages the noise over a 4x smaller
    # patch; k scaled by n / reference_points keeps the patch (and denoises as well or better)
    from leaffit_usd.fit.denoise import neighbor_count

    prm = DenoiseParams(reference_points=2000)
    assert neighbor_count(1500, prm) == 24 and neighbor_count(2000, prm) == 24
    assert neighbor_count(8000, prm) == 96 and neighbor_count(10, prm) == 10
    assert neighbor_count(8000, DenoiseParams(reference_points=0)) == 24
    off = {}
    for n in (2000, 8000):
        rng = np.random.default_rng(6)
        p, R = _plane_points(rng, n)
        noisy = p + R[:, 2] * rng.normal(0, 0.002, (n, 1))
        for name, prm_ in (("fixed", DenoiseParams(reference_points=0)), ("share", prm)):
            res = denoise_leaf(noisy, prm_)
            off[name, n] = np.abs((res.points - p[0]) @ R[:, 2]).mean()
    assert off["share", 2000] == off["fixed", 2000]            # sparse leaf: unchanged
    assert off["share", 8000] < 0.7 * off["fixed", 8000]
    assert off["share", 8000] <= off["share", 2000]


def test_denoise_fits_its_planes_at_anchors_on_a_dense_leaf(monkeypatch):
    # a curved noisy blade of 6000 with 30 floaters: local planes at 1500 anchors (every point
    # projected onto its nearest anchor's plane) denoise about as well as a plane at every point,
    # remove the same floaters, never fit more than 1500 planes, and do not depend on file order
    import leaffit_usd.fit.denoise as dn

    rng = np.random.default_rng(8)
    n = 6000
    xy = rng.uniform([-0.06, -0.03], [0.06, 0.03], (n, 2))
    surf = lambda q: 4.0 * q[:, 0] ** 2 + 3.0 * q[:, 0] * q[:, 1]       # curved, 0.02 of sag
    pts = np.c_[xy, surf(xy) + rng.normal(0, 0.0015, n)]
    pts[:30, 2] += 0.04
    rows = []
    real = dn._local_planes
    monkeypatch.setattr(dn, "_local_planes", lambda q, *a: rows.append(len(q)) or real(q, *a))
    err = {}
    for pp in (0, 1500):
        rows.clear()
        r = denoise_leaf(pts, DenoiseParams(reference_points=1500, plane_points=pp))
        assert not r.keep[:30].any() and r.keep[30:].mean() > 0.97
        err[pp] = np.abs(r.points[:, 2] - surf(r.points)).mean()
        assert max(rows) == (len(pts) if pp == 0 else 1500)
    raw = np.abs(pts[30:, 2] - surf(pts[30:])).mean()
    assert err[1500] < 1.1 * err[0] and err[1500] < 0.3 * raw
    perm = rng.permutation(n)
    a, b = denoise_leaf(pts, DenoiseParams(reference_points=1500, plane_points=1500)), \
        denoise_leaf(pts[perm], DenoiseParams(reference_points=1500, plane_points=1500))
    inv = np.argsort(perm)
    assert np.array_equal(a.keep, b.keep[inv])
    pos = np.cumsum(b.keep) - 1                                   # row of each kept input
    assert np.allclose(a.points, b.points[pos[inv][a.keep]], atol=1e-12)
    # a leaf no larger than plane_points: a plane at every point, the same bytes as 0
    small = pts[:1400]
    for x, y in zip(denoise_leaf(small, DenoiseParams(plane_points=1500)),
                    denoise_leaf(small, DenoiseParams(plane_points=0))):
        assert np.array_equal(x, y)


def test_denoise_params_are_validated():
    from leaffit_usd.errors import ParameterError
    from leaffit_usd.fit.params import FitParams

    for bad in (dict(neighbors=2), dict(neighbors=2.5), dict(reference_points=-1),
                dict(plane_points=-1)):
        with pytest.raises(ParameterError):
            FitParams(denoise=DenoiseParams(**bad)).validate()


def test_metrics_known_answers():
    m = trimesh.creation.icosphere(3)
    zero = mesh_metrics(m.vertices, m.faces, m.vertices, m.faces, n=2000)
    assert zero.corr < 1e-6 and zero.hd < 1e-6
    big = mesh_metrics(m.vertices * 1.1, m.faces, m.vertices, m.faces, n=2000)
    # the icosphere's vertices are on the unit sphere, faces slightly inside: ~0.1
    assert big.corr == pytest.approx(0.1, abs=0.005)
    assert big.cd == pytest.approx(2 * 0.1**2, rel=0.1)
    assert big.hd == pytest.approx(0.1, abs=0.01)
    assert big.scaled().corr == pytest.approx(10 * big.corr)
    shifted = point_metrics(np.zeros((1, 3)), np.array([[0.0, 0, 2], [0, 0, 3]]))
    assert shifted.corr == 2 and shifted.hd == 3 and shifted.cd == 4 + (4 + 9) / 2
    d = surface_distance(np.array([[0.0, 0, 2]]), m.vertices, m.faces)
    assert d[0] == pytest.approx(1.0, abs=0.01)


def test_sample_surface_area_uniform_and_deterministic():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0, 0], [3, 0, 0], [3, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])       # unit square (area 1) + triangle (area 1)
    a = sample_surface(v, f, 4000, seed=1)
    assert abs((a[:, 0] > 1).mean() - 0.5) < 0.05
    np.testing.assert_array_equal(a, sample_surface(v, f, 4000, seed=1))


@pytest.mark.parametrize("args", [
    (np.zeros((3, 3)), np.zeros((0, 3), int)),
    (np.zeros((3, 3)), np.array([[0, 1, 3]])),
    (np.zeros((3, 2)), np.array([[0, 1, 2]])),
    (np.zeros((3, 3)), np.array([[0, 1, 2]])),            # zero area
])
def test_sample_surface_rejects_bad_mesh(args):
    with pytest.raises(ParameterError):
        sample_surface(*args, n=10)


def test_point_metrics_rejects_empty():
    with pytest.raises(ParameterError):
        point_metrics(np.zeros((0, 3)), np.zeros((2, 3)))
