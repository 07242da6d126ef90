"""The GLSL deformer, run for real: compiled and executed headless (moderngl, EGL, Mesa llvmpipe
on the CPU), vertices captured by transform feedback and compared with the CPU evaluator."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.runtime.evaluator import evaluate
from leaffit_usd.runtime.shader import (SNIPPET, VARIANTS, GLDeformer, create_headless_context,
                                        snippet_source, validate_static, vertex_shader_source)
from samples.synthetic.runtime import synthetic_asset

TOL_GLSL = 1e-5   # max |GLSL - CPU| per leaf, as a fraction of that leaf's bounding-box diagonal


def relative_error(gpu: np.ndarray, cpu: np.ndarray) -> float:
    """gpu, cpu : (L, V, 3). Max over leaves of max vertex distance / leaf diagonal."""
    size = np.linalg.norm(cpu.max(1) - cpu.min(1), axis=1)
    return float((np.linalg.norm(gpu - cpu, axis=2).max(1) / size).max())


@pytest.fixture(scope="module")
def ctx():
    try:
        c = create_headless_context()
    except RuntimeError as e:
        pytest.skip(f"no headless OpenGL context: {e}")
    yield c
    c.release()


@pytest.fixture(scope="module")
def asset():
    return synthetic_asset(n_leaves=12, n_vertices=600, K=32, seed=7)


def test_snippet_is_shipped_and_included():
    text = snippet_source()
    assert "vec3 leaffit_mls(vec3 v, int K, float sigma, float reg, int instance)" in text
    for v in VARIANTS:
        src = vertex_shader_source(v)
        assert src.startswith("#version 430") and "#leaffit_include" not in src
        assert text in src
        assert ("#define LEAFFIT_USE_WEIGHTS" in src) == (v == "weights")
    assert SNIPPET.exists()
    with pytest.raises(ParameterError):
        vertex_shader_source("similarity")


@pytest.mark.parametrize("variant", VARIANTS)
def test_static_glslang(variant):
    r = validate_static(vertex_shader_source(variant))
    if not r.available:
        pytest.skip(r.output)
    assert r.ok, r.output


def test_static_glslang_rejects_a_broken_shader():
    src = vertex_shader_source().replace("vec3 x = inverse(P)", "vec3 x = inverse(P, 1)")
    r = validate_static(src)
    if not r.available:
        pytest.skip(r.output)
    assert not r.ok and "inverse" in r.output


@pytest.mark.parametrize("variant", VARIANTS)
def test_gpu_matches_cpu_asset_frame(ctx, asset, variant):
    gl = GLDeformer(ctx, variant)
    gpu = gl.deform(asset)
    assert ctx.error == "GL_NO_ERROR"
    cpu = evaluate(asset, frame="asset").vertices.reshape(gpu.shape)
    assert np.abs(gpu).max() > 0.1 and np.count_nonzero(gpu) > 0.9 * gpu.size  # not silent zeros
    err = relative_error(gpu, cpu)
    print(f"{variant}: max |GLSL - CPU| / leaf size = {err:.2e}")
    assert err <= TOL_GLSL
    gl.release()


def test_gpu_matches_cpu_input_frame(ctx, asset):
    gl = GLDeformer(ctx)
    gpu = gl.deform(asset, model=asset.asset_to_input)
    cpu = evaluate(asset).vertices.reshape(gpu.shape)
    assert relative_error(gpu, cpu) <= TOL_GLSL
    gl.release()


def test_gpu_flat_template_singular_moment_matrix(ctx):
    """A coplanar template makes the affine moment matrix singular; the shared regulariser
    keeps GLSL and CPU in agreement."""
    flat = synthetic_asset(n_leaves=4, n_vertices=400, seed=8, curvature=0.0)
    assert np.ptp(flat.template_points[:, 2]) == 0
    gpu = GLDeformer(ctx).deform(flat)
    cpu = evaluate(flat, frame="asset").vertices.reshape(gpu.shape)
    assert np.isfinite(gpu).all() and relative_error(gpu, cpu) <= TOL_GLSL


def test_comparison_catches_a_wrong_kernel(ctx, asset):
    """The check has teeth: a shader run with another sigma is far outside the tolerance."""
    gpu = GLDeformer(ctx).deform(dataclasses.replace(asset, sigma=asset.sigma * 1.5))
    cpu = evaluate(asset, frame="asset").vertices.reshape(gpu.shape)
    assert relative_error(gpu, cpu) > 100 * TOL_GLSL


@pytest.mark.parametrize("K", [8, 64])
def test_gpu_matches_cpu_other_K(ctx, K):
    a = synthetic_asset(n_leaves=3, n_vertices=400, K=K, seed=9)
    gpu = GLDeformer(ctx).deform(a)
    cpu = evaluate(a, frame="asset").vertices.reshape(gpu.shape)
    assert relative_error(gpu, cpu) <= TOL_GLSL


def test_too_many_control_points_rejected(ctx):
    a = synthetic_asset(n_leaves=1, n_vertices=300, K=65, seed=9)
    with pytest.raises(ParameterError, match="K"):
        GLDeformer(ctx).deform(a)
