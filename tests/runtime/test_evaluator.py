"""CPU reference evaluator: against an independent per-leaf loop, USD's own instance transforms,
the MLS invariants (identity and affine targets), frames, faces and input validation."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from leaffit_usd.errors import ParameterError, UserError
from leaffit_usd.fit.mls import deform_points
from leaffit_usd.runtime.evaluator import (BakedLeaves, LeafEvaluator, evaluate,
                                           instance_matrices)
from samples.synthetic.runtime import random_quaternions, synthetic_asset

# Tolerances, relative to the leaf size (bounding-box diagonal of the template) unless noted.
TOL_FLOAT64 = 1e-10      # two float64 evaluations of the same formula
TOL_IDENTITY = 2e-3      # q = p: the regulariser (0.03 sigma) pulls vertices along the sheet by ~ (reg sigma)^2 / lambda


def leaf_size(points) -> float:
    pts = np.asarray(points, np.float64)
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


@pytest.fixture(scope="module")
def asset():
    return synthetic_asset(n_leaves=7, n_vertices=400, K=32, seed=1)


def rotate_wxyz(q, v):
    """Independent quaternion rotation (Hamilton product q v q*), (4,), (N, 3)."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q)
    w, u = q[0], q[1:]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def test_matches_independent_per_leaf_loop(asset):
    baked = evaluate(asset, frame="asset")
    V = len(asset.template_points)
    size = leaf_size(asset.template_points)
    for j in range(asset.n_leaves):
        local = deform_points(asset.template_controls, asset.targets[j], asset.template_points,
                              asset.sigma, asset.reg)
        expect = asset.positions[j] + rotate_wxyz(asset.orientations[j], asset.scales[j] * local)
        got = baked.vertices[j * V:(j + 1) * V]
        assert np.abs(got - expect).max() <= TOL_FLOAT64 * size * 10
        assert (baked.leaf_vertex_ids[j * V:(j + 1) * V] == j).all()


def test_input_frame_is_asset_to_input_of_asset_frame(asset):
    a = evaluate(asset, frame="asset")
    b = evaluate(asset)                               # default: input frame
    assert b.frame == "input" and a.frame == "asset"
    m = asset.asset_to_input
    expect = a.vertices @ m[:3, :3].T + m[:3, 3]
    scale = abs(np.linalg.det(m[:3, :3])) ** (1 / 3)
    assert np.abs(b.vertices - expect).max() <= 1e-9 * scale * leaf_size(a.vertices)
    assert np.allclose(b.stem_vertices, asset.stem_points @ m[:3, :3].T + m[:3, 3], atol=1e-6)
    assert not np.allclose(a.vertices, b.vertices)    # the transform was really applied


def test_instance_transforms_match_usd_pointinstancer():
    """Our PointInstancer semantics agree with USD's ComputeInstanceTransformsAtTime.

    Float quaternions (``orientationsf``) so that they are unit to float precision: USD does not
    normalise them (it builds the matrix from q as given), we do.
    """
    from pxr import Gf, Usd, UsdGeom, Vt

    rng = np.random.default_rng(5)
    n = 5
    quats = random_quaternions(n, rng).astype(np.float32)
    pos = rng.normal(size=(n, 3)).astype(np.float32)
    scl = rng.uniform(0.3, 2.0, (n, 3)).astype(np.float32)
    scl[1, 0] *= -1                                    # a mirrored instance too
    stage = Usd.Stage.CreateInMemory()
    pi = UsdGeom.PointInstancer.Define(stage, "/P")
    UsdGeom.Xform.Define(stage, "/P/proto")
    pi.CreatePrototypesRel().AddTarget("/P/proto")
    pi.CreateProtoIndicesAttr(Vt.IntArray([0] * n))
    pi.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in pos]))
    pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, s)) for s in scl]))
    pi.CreateOrientationsfAttr(Vt.QuatfArray([Gf.Quatf(float(q[0]), Gf.Vec3f(*map(float, q[1:])))
                                              for q in quats]))
    usd = pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())
    usd = np.array([np.array(m) for m in usd]).transpose(0, 2, 1)   # row-vector -> column
    ours = instance_matrices(pos, quats, scl)
    assert np.abs(ours - usd).max() < 1e-5
    # and a wrong convention (x, y, z, w) would not pass
    assert np.abs(instance_matrices(pos, quats[:, [1, 2, 3, 0]], scl) - usd).max() > 0.1


def test_identity_targets_reproduce_template():
    a = synthetic_asset(n_leaves=3, n_vertices=300, seed=2)
    L = a.n_leaves
    a = dataclasses.replace(
        a, targets=np.repeat(a.template_controls[None], L, 0),
        positions=np.zeros((L, 3), np.float32), scales=np.ones((L, 3), np.float32),
        orientations=np.tile(np.array([1, 0, 0, 0], np.float32), (L, 1)))
    baked = evaluate(a, frame="asset")
    V = len(a.template_points)
    err = np.abs(baked.vertices.reshape(L, V, 3) - a.template_points[None])
    # along the sheet (template x, y) the regulariser pulls vertices by ~ (reg sigma)^2 / lambda;
    # across it (z) it damps the field's derivative on purpose (fit.mls), so a curved template's
    # vertices move a little towards their handles' local plane: within a tenth of its height range
    assert err[..., :2].max() <= TOL_IDENTITY * leaf_size(a.template_points)
    assert err[..., 2].max() <= 0.1 * np.ptp(a.template_points[:, 2])
    assert err.max() > 0    # the regulariser does move points a little: it is really applied


@pytest.mark.parametrize("reg", [0.0, 0.01])
def test_affine_targets_give_the_affine_map(reg):
    """Affine MLS is linear in q with rows of A summing to 1: targets p B + c give
    f_identity(v) B + c exactly; with reg = 0 on a non-coplanar template, f_identity(v) = v."""
    rng = np.random.default_rng(3)
    a = synthetic_asset(n_leaves=2, n_vertices=300, seed=4, reg=reg, dtype=np.float64)
    B = np.eye(3) + 0.4 * rng.normal(size=(3, 3))
    c = rng.normal(size=3)
    p = np.asarray(a.template_controls, np.float64)
    ev = LeafEvaluator.from_asset(a)
    ident = ev.deform_local(p[None])[0]
    affine = ev.deform_local((p @ B + c)[None])[0]
    size = leaf_size(a.template_points)
    assert np.abs(affine - (ident @ B + c)).max() <= 1e-12 * 100 * size
    if reg == 0.0:
        assert np.abs(affine - (a.template_points @ B + c)).max() <= 1e-8 * size


def test_faces_offsets_and_mirrored_winding(asset):
    scales = np.array(asset.scales, copy=True)
    scales[2, 1] *= -1                                          # instance 2 mirrors
    a = dataclasses.replace(asset, scales=scales)
    baked = evaluate(a, frame="asset", dtype=np.float32)
    F, V = len(a.template_faces), len(a.template_points)
    assert baked.vertices.dtype == np.float32 and baked.faces.dtype == np.int32
    assert baked.faces.shape == (a.n_leaves * F, 3)
    for j in range(a.n_leaves):
        verts, faces = baked.leaf(j)
        expect = a.template_faces[:, ::-1] if j == 2 else a.template_faces
        assert (faces == expect).all() and len(verts) == V
    # winding keeps front faces' normals on the side the deformed +Z template normal points to
    verts, faces = baked.leaf(2)
    n = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    M = instance_matrices(a.positions[2:3], a.orientations[2:3], a.scales[2:3])[0, :3, :3]
    front = a.template_side[a.template_faces[:, 0]] == 0
    up = np.linalg.inv(M).T @ np.array([0, 0, 1.0])           # normal transform of +Z
    assert (n[front] @ up > 0).mean() > 0.9


def test_reused_evaluator_and_animation(asset):
    ev = LeafEvaluator.from_asset(asset)
    a = evaluate(asset, evaluator=ev)
    b = evaluate(asset)
    assert np.array_equal(a.vertices, b.vertices)
    moved = dataclasses.replace(asset, targets=asset.targets * 1.1)
    c = evaluate(moved, evaluator=ev)
    assert not np.allclose(c.vertices, a.vertices)


def test_result_shapes(asset):
    baked = evaluate(asset)
    L, V = asset.n_leaves, len(asset.template_points)
    assert isinstance(baked, BakedLeaves) and baked.n_leaves == L
    assert baked.vertices.shape == (L * V, 3) and baked.vertices.dtype == np.float64
    assert baked.leaf_vertex_ids.shape == (L * V,) and baked.leaf_vertex_ids.dtype == np.int32
    assert (baked.leaf_labels == asset.leaf_labels).all()
    assert baked.faces.min() == 0 and baked.faces.max() == L * V - 1


@pytest.mark.parametrize("change, name", [
    (lambda a: {"targets": a.targets[:, :5]}, "targets"),
    (lambda a: {"positions": a.positions[:-1]}, "positions"),
    (lambda a: {"orientations": a.orientations[:, :3]}, "orientations"),
    (lambda a: {"orientations": np.zeros_like(a.orientations)}, "orientations"),
    (lambda a: {"scales": a.scales[:, :1]}, "scales"),
    (lambda a: {"leaf_labels": a.leaf_labels[:2]}, "leaf_labels"),
    (lambda a: {"template_faces": a.template_faces + len(a.template_points)}, "template_faces"),
    (lambda a: {"targets": np.where(np.arange(3) == 0, np.nan, a.targets)}, "targets"),
    (lambda a: {"template_controls": a.template_controls[:3]}, "template_controls"),
    (lambda a: {"sigma": 0.0}, "sigma"),
    (lambda a: {"asset_to_input": np.eye(3)}, "asset_to_input"),
])
def test_validation_names_the_argument(asset, change, name):
    bad = dataclasses.replace(asset, **change(asset))
    with pytest.raises(ParameterError) as e:
        evaluate(bad)
    assert e.value.name == name
    assert isinstance(e.value, UserError)


def test_bad_frame_is_rejected(asset):
    with pytest.raises(ParameterError, match="frame"):
        evaluate(asset, frame="world")


def test_empty_plant():
    a = synthetic_asset(n_leaves=0, n_vertices=100)
    baked = evaluate(a)
    assert baked.vertices.shape == (0, 3) and baked.faces.shape == (0, 3)


def test_separated_sheets():
    """separate_sheets pushes front/back copies of each template vertex apart by offset x scale,
    front along its deformed normal; without it (default) the two sheets coincide."""
    a = synthetic_asset(n_leaves=3, n_vertices=400, seed=6)
    half = len(a.template_points) // 2
    off = 2e-3
    a.metadata["sheet_offset"] = off
    V, L = len(a.template_points), a.n_leaves
    flat = evaluate(a, frame="asset").vertices.reshape(L, V, 3)
    assert np.allclose(flat[:, :half], flat[:, half:])
    sep = evaluate(a, frame="asset", separate_sheets=True)
    v = sep.vertices.reshape(L, V, 3)
    gap = np.linalg.norm(v[:, :half] - v[:, half:], axis=2)
    expect = off * a.scales[:, :1]
    assert np.allclose(np.median(gap, axis=1), expect[:, 0], rtol=0.05)
    assert sep.metadata["sheet_offset"] == off
    # the front sheet moved towards its outward normal (side of the front faces)
    from leaffit_usd.geometry.normals import vertex_normals
    n = vertex_normals(flat.reshape(-1, 3), sep.faces).reshape(L, V, 3)
    assert (np.einsum("lvc,lvc->lv", v[:, :half] - flat[:, :half], n[:, :half]) > 0).mean() > 0.95
    # the input frame gets the same push, mapped by asset_to_input
    inp = evaluate(a, separate_sheets=True).vertices
    m = a.asset_to_input
    assert np.allclose(inp, sep.vertices @ m[:3, :3].T + m[:3, 3], atol=1e-9)


def test_transform_order_controls_equals_points(asset):
    """Placing the targets before deform == placing the deformed vertices (affine MLS)."""
    ev = LeafEvaluator.from_asset(asset)
    M = instance_matrices(asset.positions, asset.orientations, asset.scales)
    M = np.einsum("ij,ljk->lik", asset.asset_to_input, M)
    a = ev.evaluate(asset.targets, M, order="controls")
    b = ev.evaluate(asset.targets, M, order="points")
    assert a.flags["C_CONTIGUOUS"] and b.flags["C_CONTIGUOUS"]
    assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    with pytest.raises(ParameterError):
        ev.evaluate(asset.targets, M, order="vertices")
