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
