"""leaffit_usd.open_plant: read, edit (control points, transforms, textures), save, export."""
import numpy as np
import pytest

import leaffit_usd
from leaffit_usd.errors import ParameterError, UserError
from leaffit_usd.runtime.evaluator import asset_leaves
from leaffit_usd.usd import writer as W
from leaffit_usd.usd.reader import read_stage


def test_read_matches_asset(stage_path, asset):
    plant = leaffit_usd.open_plant(stage_path)
    assert plant.n_leaves == asset.n_leaves and plant.K == asset.targets.shape[1]
    np.testing.assert_allclose(plant.control_points(2), asset.targets[2])
    leaf = plant.leaf(1)
    assert leaf.label == asset.leaf_labels[1]
    np.testing.assert_allclose(plant.leaf_vertices(), asset_leaves(asset), atol=1e-6)
    # input frame: asset_to_input applied
    vin = plant.leaf_vertices(0, frame="input")
    m = asset.asset_to_input
    np.testing.assert_allclose(vin, asset_leaves(asset)[0] @ m[:3, :3].T + m[:3, 3], atol=1e-6)
    with pytest.raises(ParameterError):
        plant.control_points(asset.n_leaves)


def test_edit_control_point_save_and_baked_refresh(stage_path, asset):
    from pxr import Usd, UsdGeom

    plant = leaffit_usd.open_plant(stage_path)
    q = plant.control_points(3)
    plant.set_control_point(3, 5, q[5] + [0.0, 0.0, 0.02])
    plant.set_leaf_transform(1, position=[1.0, 2.0, 3.0], scale=2.0)
    before = asset_leaves(asset)
    after = plant.leaf_vertices()
    assert np.abs(after[3] - before[3]).max() > 1e-3          # leaf 3 moved ...
    np.testing.assert_allclose(after[0], before[0], atol=1e-6)  # ... leaf 0 did not
    plant.save()
    b = read_stage(stage_path)
    np.testing.assert_allclose(b.targets[3, 5], q[5] + [0, 0, 0.02], atol=1e-6)
    np.testing.assert_allclose(b.positions[1], [1, 2, 3])
    np.testing.assert_allclose(b.scales[1], [2, 2, 2])
    # the baked variant follows the edit
    stage = Usd.Stage.Open(str(stage_path))
    root = stage.GetDefaultPrim()
    root.GetVariantSets().GetVariantSet("leafRepresentation").SetVariantSelection("baked")
    pts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath(f"{root.GetPath()}/BakedLeaves/leaf_0003")).GetPointsAttr().Get())
    np.testing.assert_allclose(pts, asset_leaves(plant.asset, separate_sheets=True)[3], atol=1e-5)


def test_swap_texture_and_export_usdz(stage_path, tmp_path):
    plant = leaffit_usd.open_plant(stage_path)
    img = np.zeros((32, 32, 4), np.uint8)
    img[..., 0] = 255
    img[..., 3] = 255
    rel = plant.set_texture("front", img)
    assert (tmp_path / rel).is_file()
    plant.save()
    assert read_stage(stage_path).front_texture == rel
    res = plant.export(tmp_path / "out" / "e.usdz")
    b = read_stage(res.path)
    assert b.front_texture.endswith((".png", ".jpg"))
    from leaffit_usd.usd.validate import validate_file
    assert validate_file(res.path).count("error") == 0
    with pytest.raises(ParameterError):
        plant.set_texture("top", img)


def test_usdz_is_read_only(tmp_path, asset, textures):
    out = tmp_path / "p.usdz"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    plant = leaffit_usd.open_plant(out)
    assert plant.n_leaves == asset.n_leaves
    with pytest.raises(UserError):
        plant.save()
