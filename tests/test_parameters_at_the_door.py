"""A value a later stage could not honour is refused before any work: control points above the
GLSL deformer's limit, level-of-detail budgets that are not coarser than the mesh."""
from __future__ import annotations

import pytest

from leaffit_usd.cli import main
from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.params import MAX_K, FitParams
from leaffit_usd.mesh.params import MeshParams
from leaffit_usd.splats import write_ply
from tests.splats.plyfiles import small_cloud


def test_k_above_the_glsl_limit_exits_2_with_one_line(tmp_path, capsys):
    write_ply(small_cloud(300, seed=1), tmp_path / "c.ply")
    code = main(["convert", str(tmp_path / "c.ply"), "-o", str(tmp_path / "p.usda"), "-K", str(MAX_K + 36)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "at most 64" in err[0]
    assert not (tmp_path / "p.usda").exists()
    FitParams(K=MAX_K).validate()


def test_lod_budgets_must_be_coarser():
    with pytest.raises(ParameterError, match="below the vertex budget"):
        MeshParams(vertex_budget=256, lod_vertices=(512, 128)).validate()
    with pytest.raises(ParameterError, match="below the last"):
        MeshParams(lod_vertices=(128, 512)).validate()
    # the default levels follow the vertex budget (--vertex-budget 256 made LOD1 equal LOD0)
    assert MeshParams().lod_budgets() == (512, 128)
    assert MeshParams(vertex_budget=256).lod_budgets() == (64, 16)
    assert MeshParams(vertex_budget=20).lod_budgets() == ()
    MeshParams(vertex_budget=256).validate()


def test_the_glsl_snippet_is_built_for_the_same_limit():
    from leaffit_usd.runtime.shader import vertex_shader_source

    assert f"#define LEAFFIT_MAX_K {MAX_K}" in vertex_shader_source()


def test_one_seed_reaches_every_stage():
    from leaffit_usd.cli import build_parser
    from leaffit_usd.commands.convert import options_from_args

    args = build_parser().parse_args(["convert", "x.ply", "-o", "x.usda", "--seed", "7"])
    o = options_from_args(args)
    assert o.fit.seed == o.segment.seed == o.isolate.seed == 7
