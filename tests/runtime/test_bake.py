"""``leaffit-usd bake``: the written leaves equal the evaluator's, formats, frames, exit codes."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.cli import main
from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.runtime.bake import read_baked_usd
from leaffit_usd.runtime.evaluator import evaluate
from leaffit_usd.runtime.evaluator import asset_leaves
from samples.synthetic.runtime import synthetic_asset
from leaffit_usd.usd.reader import read_stage
from leaffit_usd.usd.writer import LeafTextures, write_stage


def _textures():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (16, 16, 4), dtype=np.uint8)
    return LeafTextures(front=img, back=img[::-1].copy())


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    d = tmp_path_factory.mktemp("plant")
    path = d / "plant.usda"
    asset = synthetic_asset(n_leaves=5, n_vertices=300, seed=11)
    asset.metadata["sheet_offset"] = 3e-4          # as convert records it (template units)
    write_stage(path, asset, _textures(), leaves=asset_leaves(asset, separate_sheets=True))
    return path


def run_cli(*args) -> int:
    return main(["bake", "-q", *map(str, args)])


def test_npz_equals_evaluator(plant, tmp_path):
    out = tmp_path / "leaves.npz"
    assert run_cli(plant, "-o", out) == 0
    expect = evaluate(read_stage(plant), dtype=np.float32)         # default frame: input
    with np.load(out) as z:
        assert str(z["frame"]) == "input" and float(z["sheet_offset"]) == 0.0
        assert z["vertices"].dtype == np.float32
        for key in ("vertices", "faces", "leaf_vertex_ids", "leaf_labels", "stem_vertices",
                    "stem_faces"):
            assert np.array_equal(z[key], getattr(expect, key)), key
        assert z["uvs"].shape == (len(expect.vertices), 2)
        assert np.allclose(np.linalg.norm(z["normals"], axis=1), 1, atol=1e-5)


def test_npz_asset_frame_float64_and_deterministic(plant, tmp_path):
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert run_cli(plant, "-o", a, "--frame", "asset", "--float64") == 0
    assert run_cli(plant, "-o", b, "--frame", "asset", "--float64") == 0
    assert a.read_bytes() == b.read_bytes()
    expect = evaluate(read_stage(plant), frame="asset")
    with np.load(a) as z:
        assert str(z["frame"]) == "asset" and z["vertices"].dtype == np.float64
        assert np.array_equal(z["vertices"], expect.vertices)
    with np.load(tmp_path / "a.npz") as za:
        inp = evaluate(read_stage(plant)).vertices
        assert not np.allclose(za["vertices"], inp)       # the frames really differ


def test_baked_usd_equals_evaluator_and_validates(plant, tmp_path):
    from pxr import Usd, UsdShade, UsdValidation

    out = tmp_path / "sub" / "baked.usda"
    assert run_cli(plant, "-o", out) == 0             # default: asset frame, separated sheets
    expect = evaluate(read_stage(plant), frame="asset", dtype=np.float32, separate_sheets=True)
    v, f, ids = read_baked_usd(out)
    assert np.array_equal(v, expect.vertices)
    assert np.array_equal(f, expect.faces) and np.array_equal(ids, expect.leaf_vertex_ids)

    stage = Usd.Stage.Open(str(out))
    assert stage.GetDefaultPrim() and Usd.ModelAPI(stage.GetDefaultPrim()).GetKind() == "component"
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    errors = [e for e in ctx.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]
    assert not errors, [e.GetMessage() for e in errors]
    # textures of the source stage resolve from the baked file's own directory
    files = [UsdShade.Shader(p).GetInput("file").Get() for p in stage.Traverse()
             if p.GetName() == "Texture"]
    assert len(files) == 2 and all(a.resolvedPath for a in files)


def test_baked_usd_matches_the_writers_baked_payload(plant, tmp_path):
    """The usd writer's own baked variant and this command agree (float32 round-off)."""
    from pxr import Usd, UsdGeom

    payload = plant.parent / "plant.baked.usdc"
    if not payload.exists():
        pytest.skip("the writer wrote no baked payload")
    stage = Usd.Stage.Open(str(payload))
    leaves = [p for p in stage.GetDefaultPrim().GetChildren() if p.IsA(UsdGeom.Mesh)]
    theirs = np.concatenate([np.asarray(UsdGeom.Mesh(p).GetPointsAttr().Get()) for p in leaves])
    ours = evaluate(read_stage(plant), frame="asset", separate_sheets=True).vertices
    assert theirs.shape == ours.shape
    assert np.abs(theirs - ours).max() <= 1e-6 * np.ptp(ours, axis=0).max()
    coplanar = evaluate(read_stage(plant), frame="asset").vertices
    assert np.abs(theirs - coplanar).max() > 1e-5 * np.ptp(ours, axis=0).max()  # offset seen


def test_usdz_input_textures_resolve(tmp_path):
    from pxr import Usd, UsdShade

    src = tmp_path / "pkg" / "plant.usdz"
    asset = synthetic_asset(n_leaves=2, n_vertices=200, seed=12)
    write_stage(src, asset, _textures(), leaves=asset_leaves(asset, separate_sheets=True))
    out = tmp_path / "out" / "baked.usdc"
    assert run_cli(src, "-o", out) == 0
    stage = Usd.Stage.Open(str(out))
    files = [UsdShade.Shader(p).GetInput("file").Get() for p in stage.Traverse()
             if p.GetName() == "Texture"]
    assert len(files) == 2 and all(a.resolvedPath for a in files), files


@pytest.mark.parametrize("make_input, output", [
    (lambda d: d / "missing.usda", "x.npz"),                               # no such file
    (lambda d: (d / "junk.usda").write_text("hello") and d / "junk.usda", "x.npz"),  # not USD
    (lambda d: _plain_usd(d / "cube.usda"), "x.npz"),                     # USD, not LeafFit
    (lambda d: _plain_usd(d / "cube.usda"), "x.obj"),                      # bad output format
])
def test_bad_input_exit_2_no_output(tmp_path, capsys, make_input, output):
    src = make_input(tmp_path)
    assert run_cli(src, "-o", tmp_path / output) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("leaffit-usd bake: error:") and "\n" not in err
    assert not (tmp_path / output).exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".x.")]   # no temp left


def test_refuses_to_overwrite_the_input(plant, capsys):
    assert run_cli(plant, "-o", plant) == 2
    assert "--output" in capsys.readouterr().err


def test_usage_errors_exit_2(plant, tmp_path):
    with pytest.raises(SystemExit) as e:
        run_cli(plant)                                                     # -o missing
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        run_cli(plant, "-o", tmp_path / "x.npz", "--frame", "world")
    assert e.value.code == 2


def test_vertex_normals_of_a_flat_square():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 5, 5]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    n = vertex_normals(v, f)
    assert np.allclose(n[:4], [0, 0, 1]) and np.allclose(n[4], 0)
    assert np.allclose(vertex_normals(v, f[:, ::-1])[:4], [0, 0, -1])


def _plain_usd(path):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Cube.Define(stage, "/Cube")
    stage.GetRootLayer().Save()
    return path
