"""The stage's LOD variant set (LOD0 default, coarser template and stem) and the stem's colours."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import synthetic as syn  # noqa: E402

from leaffit_usd.mesh.result import StemMesh  # noqa: E402
from leaffit_usd.runtime.evaluator import asset_leaves  # noqa: E402
from leaffit_usd.usd import writer as W  # noqa: E402
from leaffit_usd.usd.assemble import asset_from_results  # noqa: E402
from leaffit_usd.usd.reader import read_stage, select_representation, select_variant  # noqa: E402
from leaffit_usd.usd.validate import validate_file  # noqa: E402


@pytest.fixture(scope="module")
def lod_asset():
    t = syn.template_mesh()
    f = syn.leaf_fits(t)
    s = syn.stem()
    s.colors = np.tile([0.8, 0.2, 0.1], (len(s.points), 1)).astype(np.float32)
    t.lods = [syn.coarser_template(t, 60), syn.coarser_template(t, 20)]
    s.lods = [StemMesh(points=s.points[::2].copy(), faces=np.array([[0, 1, 2]], np.int32),
                       colors=s.colors[::2].copy()),
              StemMesh(points=s.points[:3].copy(), faces=np.array([[0, 1, 2]], np.int32), colors=None)]
    a = asset_from_results(t, f, s, syn.frame(), up_axis="Y", input_sha256="cd" * 32)
    return a, W.LeafTextures(t.front_texture, t.back_texture)


def _write(out, a, tex, options=None):
    W.write_stage(out, a, tex, options, leaves=asset_leaves(a, separate_sheets=True),
                  lod_leaves=[asset_leaves(a.at_lod(k), separate_sheets=True) for k in (1, 2)])


def test_lod_variants_author_each_level_and_validate(tmp_path, lod_asset):
    from pxr import Usd, UsdGeom

    a, tex = lod_asset
    out = tmp_path / "p.usda"
    _write(out, a, tex, W.WriteOptions(baked=True))
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    vset = root.GetVariantSets().GetVariantSet("LOD")
    assert vset.GetVariantNames() == ["LOD0", "LOD1", "LOD2"] and vset.GetVariantSelection() == "LOD0"
    expect = [(len(a.template_points), len(a.stem_points))] + \
             [(len(l.template_points), len(l.stem_points)) for l in a.lods]
    for k, (nv, ns) in enumerate(expect):
        select_variant(stage, "LOD", f"LOD{k}")
        tmpl = UsdGeom.Mesh(stage.GetPrimAtPath(f"{root.GetPath()}/Leaves/Prototypes/TemplateLeaf"))
        stem = UsdGeom.Mesh(stage.GetPrimAtPath(f"{root.GetPath()}/Stem"))
        assert len(tmpl.GetPointsAttr().Get()) == nv and len(stem.GetPointsAttr().Get()) == ns
        # the side subsets partition the level's faces
        subs = UsdGeom.Subset.GetGeomSubsets(tmpl, UsdGeom.Tokens.face, "materialBind")
        n_f = len(tmpl.GetFaceVertexIndicesAttr().Get()) // 3
        assert sorted(np.concatenate([np.asarray(s.GetIndicesAttr().Get()) for s in subs]).tolist()) == list(range(n_f))
        # the baked representation shows every leaf once, at this level's resolution
        select_representation(stage, "baked")
        stage.Load()
        leaves = [p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh) and not p.IsAbstract()
                  and "/BakedLeaves/" in str(p.GetPath())]
        assert len(leaves) == a.n_leaves
        assert [len(UsdGeom.Mesh(p).GetPointsAttr().Get()) for p in leaves] == [nv] * a.n_leaves, (k, str(leaves[0].GetPath()))
        select_representation(stage, "deformer")
    rep = validate_file(out)
    assert rep.count("error") == 0, [str(f) for f in rep.findings]


def test_lods_and_stem_colours_read_back(tmp_path, lod_asset):
    a, tex = lod_asset
    out = tmp_path / "p.usdc"
    _write(out, a, tex)
    b = read_stage(out)
    assert len(b.template_points) == len(a.template_points)    # LOD0 is what readers see
    assert len(b.lods) == 2
    for x, y in zip(a.lods, b.lods):
        np.testing.assert_array_equal(x.template_faces, y.template_faces)
        np.testing.assert_allclose(x.template_points, y.template_points, atol=1e-6)
        np.testing.assert_allclose(x.stem_points, y.stem_points, atol=1e-6)
    np.testing.assert_allclose(b.stem_colors, a.stem_colors, atol=2e-3)
    assert b.lods[1].stem_colors is None


def test_stem_material_reads_vertex_colours(tmp_path, lod_asset):
    from pxr import Usd, UsdShade

    a, tex = lod_asset
    out = tmp_path / "p.usda"
    _write(out, a, tex)
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim().GetPath()
    mat, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(f"{root}/Stem")).ComputeBoundMaterial()
    surf = mat.ComputeSurfaceSource()[0]
    src = surf.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    reader = UsdShade.Shader(src.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3"
    assert reader.GetInput("varname").Get() == "displayColor"
    # linear fallback = the mean colour (sRGB 0.8, 0.2, 0.1 -> linear)
    fb = np.asarray(reader.GetInput("fallback").Get())
    assert fb == pytest.approx([0.6038, 0.0331, 0.0100], abs=2e-3)


def test_a_usda_root_stays_text_small_with_its_variants_in_a_crate_sublayer(tmp_path, lod_asset):
    """.usda output: the root layer is the interface only (no arrays); the LOD and
    leafRepresentation variants, with the coarser levels' arrays, are in ``p.variants.usdc``,
    a sublayer of the root (one layer stack), so the composed stage is the .usdc one's."""
    from pxr import Sdf, Usd, UsdGeom

    a, tex = lod_asset
    _write(tmp_path / "p.usda", a, tex, W.WriteOptions(baked=True))
    _write(tmp_path / "c" / "p.usdc", a, tex, W.WriteOptions(baked=True))
    root = Sdf.Layer.FindOrOpen(str(tmp_path / "p.usda"))
    assert list(root.subLayerPaths) == ["./p.variants.usdc"]
    assert "point3f[]" not in (tmp_path / "p.usda").read_text()
    assert Sdf.Layer.FindOrOpen(str(tmp_path / "p.variants.usdc")).GetFileFormat().formatId == "usdc"
    assert not (tmp_path / "c" / "p.variants.usdc").exists()   # a crate root holds them itself
    for k in range(3):
        counts = []
        for path in (tmp_path / "p.usda", tmp_path / "c" / "p.usdc"):
            stage = Usd.Stage.Open(str(path))
            select_variant(stage, "LOD", f"LOD{k}")
            r = stage.GetDefaultPrim().GetPath()
            counts.append(len(UsdGeom.Mesh(stage.GetPrimAtPath(f"{r}/Stem")).GetPointsAttr().Get()))
        assert counts[0] == counts[1]
    assert validate_file(tmp_path / "p.usda").count("error") == 0
