"""Wind: each leaf turned about its axis through its pivot by the CPU evaluator (its MLS targets
turned) and by the GLSL deformer (the evaluated point turned) agree to float tolerance at a given
time; the turn keeps every leaf's shape; the data the stage carries (pivot, axis, node, phase;
per-vertex flutter and bend) is what the module says."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.runtime.evaluator import evaluate
from leaffit_usd.runtime.shader import GLDeformer, create_headless_context, validate_static, vertex_shader_source
from leaffit_usd.usd.wind import (WindParams, leaf_phases, rotate_about, skeleton_distances,
                                  skeleton_from_segments, wind_data)
from samples.synthetic.runtime import synthetic_asset
from tests.runtime.test_glsl import TOL_GLSL, relative_error


@pytest.fixture(scope="module")
def asset():
    return synthetic_asset(n_leaves=9, n_vertices=400, K=24, seed=3)


@pytest.mark.parametrize("variant", ["controls", "weights"])
def test_cpu_equals_glsl_with_wind(asset, variant):
    try:
        ctx = create_headless_context()
    except RuntimeError as e:
        pytest.skip(f"no headless OpenGL context: {e}")
    d = GLDeformer(ctx, variant, wind=True)
    try:
        for t in (0.0, 0.37, 1.9):
            w = WindParams(time=t, strength=0.6, frequency=1.3)
            cpu = evaluate(asset, frame="asset", wind=w).vertices.reshape(asset.n_leaves, -1, 3)
            gpu = d.deform(asset, wind=w)
            assert relative_error(gpu, cpu) < TOL_GLSL
        rest = evaluate(asset, frame="asset").vertices.reshape(asset.n_leaves, -1, 3)
        assert relative_error(d.deform(asset), rest) < TOL_GLSL   # no moment given: at rest
        moved = evaluate(asset, frame="asset", wind=WindParams(0.37, 0.6, 1.3)).vertices
        assert np.abs(moved - rest.reshape(moved.shape)).max() > 1e-3   # the wind did move them
    finally:
        d.release()
        ctx.release()


def test_the_wind_glsl_compiles_statically():
    r = validate_static(vertex_shader_source("controls", wind=True))
    if not r.available:
        pytest.skip(r.output)
    assert r.ok, r.output


def test_a_turn_keeps_each_leaf_shape_and_its_pivot(asset):
    rest = evaluate(asset, frame="asset").vertices.reshape(asset.n_leaves, -1, 3)
    moved = evaluate(asset, frame="asset", wind=WindParams(0.2, 0.5, 1.0)).vertices.reshape(rest.shape)
    dr = np.linalg.norm(rest[:, :, None] - rest[:, None, :10], axis=3)
    dm = np.linalg.norm(moved[:, :, None] - moved[:, None, :10], axis=3)
    assert np.abs(dr - dm).max() < 1e-6 * np.abs(dr).max()     # rigid: distances kept
    w = wind_data(asset)
    turned = rotate_about(w.pivots[:, None].astype(np.float64), w.pivots.astype(np.float64),
                          w.axes.astype(np.float64), np.full(asset.n_leaves, 0.7))
    assert np.allclose(turned[:, 0], w.pivots, atol=1e-6)       # the pivot stays put


def test_wind_data_is_what_the_module_says(asset):
    w = wind_data(asset)
    L = asset.n_leaves
    assert w.pivots.shape == w.axes.shape == (L, 3) and np.allclose(np.linalg.norm(w.axes, axis=1), 1)
    assert ((w.phases >= 0) & (w.phases < 1)).all() and len(set(np.round(w.phases, 6))) == L
    assert np.array_equal(leaf_phases(asset.leaf_labels), w.phases)
    x = np.asarray(asset.template_points, np.float64)[:, 0]
    assert len(w.flutter) == len(x) and w.flutter.max() == 1.0 and w.flutter.min() >= 0.0
    order = np.argsort(x)
    assert (np.diff(w.flutter[order]) >= 0).all()   # grows from the base (x = 0) to the apex


def test_skeleton_distances_follow_the_parents():
    starts = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 1.0]])
    ends = np.array([[0, 0, 1], [0, 0, 2], [1, 0, 1.0]])
    pts, par = skeleton_from_segments(starts, ends, np.array([-1, 0, 0]))
    assert np.array_equal(par, [-1, 0, 1, 1])
    assert np.allclose(skeleton_distances(pts, par), [0, 1, 2, 2])
