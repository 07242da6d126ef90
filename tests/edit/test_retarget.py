"""Cross-species retargeting: cages, correspondences and the silhouette IoU criterion."""
import numpy as np
import pytest

from leaffit_usd.edit.cage import boundary_loop, leaf_cage
from leaffit_usd.edit.retarget import RetargetParams, retarget_asset, silhouette_ious
from leaffit_usd.errors import UserError
from tests.edit.leaves import asset_from_sheet, sheet


def test_cage_is_ccw_from_apex_through_left_to_base():
    pts, faces = sheet("ellipse")
    cage = leaf_cage(pts, faces, n_side=16)
    assert cage.shape == (30, 2)
    np.testing.assert_allclose(cage[0], [1, 0], atol=0.02)      # apex
    np.testing.assert_allclose(cage[15], [0, 0], atol=0.02)     # base
    assert (cage[1:15, 1] > 0).all() and (cage[16:, 1] < 0).all()
    seg = np.linalg.norm(np.diff(cage[:16], axis=0), axis=1)
    assert seg.std() / seg.mean() < 0.05                        # uniform by arc length


def test_boundary_loop_of_closed_mesh_is_refused():
    tet = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    with pytest.raises(UserError):
        boundary_loop(tet)


def test_degenerate_outline_has_no_apex():
    pts = np.c_[np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)]
    faces = np.array([[i, i + 1, i + 2] for i in range(8)])
    with pytest.raises(UserError):
        leaf_cage(pts, faces)


def test_identity_retarget_keeps_instances():
    pts, faces = sheet("ellipse")
    asset = asset_from_sheet(pts, faces)
    new, report = retarget_asset(asset, asset, RetargetParams(n_samples=300))
    assert report["iou_min"] > 0.95


@pytest.mark.parametrize("src", ["lanceolate", "heart", "lobed"])
def test_cross_species_retarget_covers_every_silhouette(src):
    tp, tf = sheet("ellipse", seed=1)
    target = asset_from_sheet(tp, tf, n_leaves=6, seed=2)
    sp, sf = sheet(src, seed=3)
    sp = sp * 0.6  # another species, another size
    source = asset_from_sheet(sp, sf, n_leaves=1, seed=4)
    new, report = retarget_asset(target, source)
    assert report["instances"] == 6
    assert report["iou_min"] >= 0.8, report["iou"]
    # the template is now the source's, instance placement untouched
    np.testing.assert_array_equal(new.template_points, source.template_points)
    np.testing.assert_array_equal(new.positions, target.positions)
    assert np.isfinite(new.targets).all()
    np.testing.assert_allclose(silhouette_ious(target, new), report["iou"])


def _leaf_capture(n=4000, petiole_at_low_end=True, seed=0, width=0.35):
    """Gaussian centres of a blade (length 1) plus a thin petiole (length 0.3) at one end."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1, n)
    half = width * np.sin(np.pi * t) ** 0.7
    blade = np.c_[t, rng.uniform(-1, 1, n) * half, 0.01 * rng.normal(size=n)]
    s = rng.uniform(0, 1, n // 10)
    pet = np.c_[-0.3 * s, 0.005 * rng.normal(size=len(s)), 0.005 * rng.normal(size=len(s))]
    pts = np.vstack([blade, pet])
    if not petiole_at_low_end:
        pts[:, 0] = 1.0 - pts[:, 0]
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return pts @ rot.T + rng.normal(size=3)


@pytest.mark.parametrize("low", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_source_leaf_base_is_the_petiole_end(low, seed):
    from leaffit_usd.edit.source_leaf import find_base_apex

    pts = _leaf_capture(petiole_at_low_end=low, seed=seed)
    b, a = find_base_apex(pts)
    # petiole tip is 1.3 from the apex; the base found must be the petiole end
    assert np.linalg.norm(pts[b] - pts[a]) > 1.2
    n_blade = 4000
    assert b >= n_blade  # a petiole Gaussian


def test_round_source_leaf_has_no_apex():
    from leaffit_usd.edit.source_leaf import find_base_apex

    rng = np.random.default_rng(0)
    r, a = np.sqrt(rng.uniform(0, 1, 3000)), rng.uniform(0, 2 * np.pi, 3000)
    disc = np.c_[r * np.cos(a), r * np.sin(a), 0.01 * rng.normal(size=3000)]
    with pytest.raises(UserError):
        find_base_apex(disc)
    with pytest.raises(UserError):
        find_base_apex(disc[:10])
