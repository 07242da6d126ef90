"""asset_from_results: working -> asset frame, instances, provenance."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.mls import deform, mls_weights
from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.geometry.quaternion import quat_to_matrix
from leaffit_usd.runtime.evaluator import asset_leaves
from leaffit_usd.usd.assemble import asset_from_results, split_similarity, working_to_asset


def leaves_working(template, fits):
    """(L, V, 3) leaves in the working frame: leaf_to_working @ MLS(template)."""
    A = mls_weights(fits.template_controls, template.points, fits.sigma, fits.reg)
    local = deform(A, fits.targets.astype(np.float64))
    m = fits.leaf_to_working
    return np.einsum("lij,lvj->lvi", m[:, :3, :3], local) + m[:, None, :3, 3]


def leaves_asset(a, points=None):
    """(L, V, 3) leaves in the asset frame by PointInstancer semantics."""
    pts = a.template_points if points is None else points
    A = mls_weights(a.template_controls, pts, a.sigma, a.reg)
    local = deform(A, a.targets.astype(np.float64)) * a.scales[:, None, :]
    R = quat_to_matrix(a.orientations.astype(np.float64))
    return np.einsum("lij,lvj->lvi", R, local) + a.positions[:, None, :]


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_instances_map_back_to_input_frame(results, up):
    t, f, s, fr = results
    a = asset_from_results(t, f, s, fr, up_axis=up, sheet_offset=0.0)
    w = leaves_working(t, f)
    expect_in = fr.to_input(w.reshape(-1, 3))
    got = leaves_asset(a).reshape(-1, 3)
    got_in = got @ a.asset_to_input[:3, :3].T + a.asset_to_input[:3, 3]
    size = np.ptp(expect_in, axis=0).max()
    assert np.abs(got_in - expect_in).max() < 1e-5 * size
    # up axis: the plant grows along the stage's up axis
    axis = {"Y": 1, "Z": 2}[up]
    assert np.ptp(got[:, axis]) == pytest.approx(np.ptp(w.reshape(-1, 3)[:, 2]) * fr.height, rel=1e-4)
    assert a.metadata["up_axis"] == up


def test_height_sets_real_size(results):
    t, f, s, fr = results
    a = asset_from_results(t, f, s, fr, up_axis="Z", meters_per_unit=0.01, height_m=0.5)
    # working height 1 -> 0.5 m = 50 cm (metersPerUnit 0.01)
    assert a.metadata["asset_units_per_working_unit"] == pytest.approx(50.0)
    np.testing.assert_allclose(a.stem_points[:, 2].max(), 50 * s.points[:, 2].max(), rtol=1e-5)
    assert a.metadata["meters_per_unit"] == 0.01


def test_bad_units_and_axes_raise(results):
    t, f, s, fr = results
    with pytest.raises(ParameterError):
        asset_from_results(t, f, s, fr, up_axis="X")
    with pytest.raises(ParameterError):
        asset_from_results(t, f, s, fr, meters_per_unit=0)
    with pytest.raises(ParameterError):
        asset_from_results(t, f, s, fr, height_m=-1)
    with pytest.raises(ParameterError):
        working_to_asset("Y", float("nan"))


def test_split_similarity_rejects_reflection():
    m = np.eye(4)[None].repeat(2, 0)
    m[1, :3, :3] = np.diag([2.0, 2.0, -2.0])
    with pytest.raises(ParameterError):
        split_similarity(m)
    m[1, :3, :3] = 2 * np.eye(3)
    r, s, t = split_similarity(m)
    np.testing.assert_allclose(s, [1, 2])
    np.testing.assert_allclose(r[1], np.eye(3))


def test_rest_sheets_coplanar_drawn_and_baked_sheets_apart(results, asset, tmp_path):
    """MLS rest points: front/back coincide; the prototype as drawn and the baked leaves: apart,
    with the back sheet behind the front one on every vertex of every leaf."""
    from pxr import Usd, UsdGeom

    from leaffit_usd.usd import writer as W
    from leaffit_usd.usd.reader import read_stage

    t = results[0]
    V2 = len(t.points) // 2
    np.testing.assert_array_equal(asset.template_points[:V2], asset.template_points[V2:])
    off = asset.metadata["sheet_offset"]
    assert off > 0
    W.write_stage(tmp_path / "p.usda", asset, leaves=asset_leaves(asset, separate_sheets=True))
    stage = Usd.Stage.Open(str(tmp_path / "p.usda"))
    drawn = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/p/Leaves/Prototypes/TemplateLeaf")).GetPointsAttr().Get())
    np.testing.assert_allclose(drawn[:V2, 2] - drawn[V2:, 2], off, rtol=1e-3)
    np.testing.assert_allclose(read_stage(tmp_path / "p.usda").template_points, asset.template_points, atol=1e-7)
    baked = asset_leaves(asset, separate_sheets=True)
    n = vertex_normals(baked, asset.template_faces)[:, :V2]
    sep = ((baked[:, :V2] - baked[:, V2:]) * n).sum(2) / asset.scales[:, :1]
    assert sep.min() > 0.9 * off and sep.max() < 1.1 * off
    assert asset.n_leaves == len(results[1].leaf_labels)
    assert asset.metadata["input_sha256"] == "ab" * 32
