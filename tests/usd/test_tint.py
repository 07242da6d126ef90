"""Per-leaf tint in the USD stage: the PointInstancer primvar, the material reading it, the baked
variant's displayColor, the reader, and UsdValidation at 0 errors; plus the asset structure
(assetInfo, kind, payload, relative paths, doubleSided)."""
import dataclasses

import numpy as np
import pytest

from leaffit_usd.runtime.evaluator import asset_leaves


@pytest.fixture()
def tinted_asset(asset):
    rng = np.random.default_rng(2)
    return dataclasses.replace(asset, tints=rng.uniform(0.4, 1.3, (asset.n_leaves, 3)).astype(np.float32))


def _write(tmp_path, a, textures, name="p.usda"):
    from leaffit_usd.usd import writer as W

    out = tmp_path / name
    W.write_stage(out, a, textures, leaves=asset_leaves(a, separate_sheets=True))
    return out


def test_tint_primvar_and_material(tmp_path, tinted_asset, textures):
    from pxr import Usd, UsdGeom, UsdShade

    out = _write(tmp_path, tinted_asset, textures)
    stage = Usd.Stage.Open(str(out))
    inst = stage.GetPrimAtPath("/p/Leaves")
    pv = UsdGeom.PrimvarsAPI(inst).GetPrimvar("leaffit:tint")
    assert pv and pv.GetTypeName() == "color3f[]" and pv.GetInterpolation() == "vertex"
    np.testing.assert_allclose(np.asarray(pv.Get()), tinted_asset.tints, atol=1e-7)
    for side in ("LeafFront", "LeafBack"):
        mat = UsdShade.Material(stage.GetPrimAtPath(f"/p/Looks/{side}"))
        tex = UsdShade.Shader(stage.GetPrimAtPath(f"/p/Looks/{side}/Texture"))
        src = tex.GetInput("scale").GetConnectedSources()[0][0]
        reader = UsdShade.Shader(src.source.GetPrim())
        assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3"
        assert reader.GetInput("varname").Get() == "leaffit:tint"
        assert tuple(reader.GetInput("fallback").Get()) == (1.0, 1.0, 1.0)
        # the tinted texture is what feeds diffuseColor
        surf = mat.ComputeSurfaceSource()[0]
        d = surf.GetInput("diffuseColor").GetConnectedSources()[0][0]
        assert d.source.GetPath() == tex.GetPath()


def test_tint_round_trip_and_baked_display_color(tmp_path, tinted_asset, textures):
    from pxr import Usd, UsdGeom

    from leaffit_usd.usd.reader import read_stage

    out = _write(tmp_path, tinted_asset, textures)
    back = read_stage(out)
    np.testing.assert_allclose(back.tints, tinted_asset.tints, atol=1e-7)
    stage = Usd.Stage.Open(str(out))
    stage.GetDefaultPrim().GetVariantSet("leafRepresentation").SetVariantSelection("baked")
    leaves = [p for p in stage.GetPrimAtPath("/p/BakedLeaves").GetChildren() if p.GetName().startswith("leaf_")]
    assert len(leaves) == tinted_asset.n_leaves
    for j, p in enumerate(leaves):
        dc = UsdGeom.Gprim(p).GetDisplayColorPrimvar()
        assert dc.GetInterpolation() == "constant"
        np.testing.assert_allclose(np.asarray(dc.Get())[0], tinted_asset.tints[j], atol=1e-7)
        t = UsdGeom.PrimvarsAPI(p).GetPrimvar("leaffit:tint").Get()
        np.testing.assert_allclose(np.asarray(t), tinted_asset.tints[j], atol=1e-7)


def test_untinted_stage_has_no_tint(tmp_path, asset, textures):
    from pxr import Usd, UsdGeom

    from leaffit_usd.usd.reader import read_stage

    out = _write(tmp_path, asset, textures)
    stage = Usd.Stage.Open(str(out))
    assert not UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/p/Leaves")).HasPrimvar("leaffit:tint")
    assert not stage.GetPrimAtPath("/p/Looks/LeafFront/TintReader")
    assert read_stage(out).tints is None


def test_tinted_stage_validates(tmp_path, tinted_asset, textures):
    from leaffit_usd.usd.validate import validate_file

    out = _write(tmp_path, tinted_asset, textures)
    rep = validate_file(out)
    assert rep.count("error") == 0, [str(f) for f in rep.findings]


def test_bake_usd_carries_tint(tmp_path, tinted_asset, textures):
    from pxr import Usd, UsdGeom

    from leaffit_usd.cli import main

    out = _write(tmp_path, tinted_asset, textures)
    assert main(["bake", str(out), "-o", str(tmp_path / "b.usda"), "-q"]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "b.usda"))
    leaf = stage.GetPrimAtPath(f"{stage.GetDefaultPrim().GetPath()}/Leaves/leaf_0001")
    np.testing.assert_allclose(np.asarray(UsdGeom.Gprim(leaf).GetDisplayColorPrimvar().Get())[0],
                               tinted_asset.tints[1], atol=1e-7)


def test_asset_structure(tmp_path, tinted_asset, textures):
    """kind component, assetInfo {name, version, identifier}, relative asset paths, doubleSided
    false on the two-sheet template, opacityThreshold with alpha textures."""
    from pxr import Kind, Sdf, Usd, UsdGeom, UsdShade

    from leaffit_usd.usd import writer as W

    out = tmp_path / "p.usda"
    W.write_stage(out, tinted_asset, textures, W.WriteOptions(texture_format="png"),
                  leaves=asset_leaves(tinted_asset, separate_sheets=True))
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    model = Usd.ModelAPI(root)
    assert model.GetKind() == Kind.Tokens.component
    assert model.GetAssetName() == "p" and model.GetAssetVersion()
    assert model.GetAssetIdentifier().path == "./p.usda"
    layer = stage.GetRootLayer()
    for dep in layer.GetCompositionAssetDependencies() + [
            s.GetInput("file").Get().path for s in map(UsdShade.Shader, Usd.PrimRange(root))
            if s and s.GetIdAttr().Get() == "UsdUVTexture"]:
        assert dep.startswith("./"), dep
    tmpl = UsdGeom.Mesh(stage.GetPrimAtPath("/p/Leaves/Prototypes/TemplateLeaf"))
    assert tmpl.GetDoubleSidedAttr().Get() is False
    surf = UsdShade.Shader(stage.GetPrimAtPath("/p/Looks/LeafFront/PreviewSurface"))
    assert surf.GetInput("opacityThreshold").Get() == pytest.approx(0.5)
    # a template with one sheet only is drawn double-sided
    a = tinted_asset
    front = a.template_side[a.template_faces].sum(1) < 2
    one = dataclasses.replace(a, template_faces=a.template_faces[front])
    W.write_stage(tmp_path / "one.usda", one, textures, leaves=asset_leaves(one, separate_sheets=True))
    s1 = Usd.Stage.Open(str(tmp_path / "one.usda"))
    assert UsdGeom.Mesh(s1.GetPrimAtPath("/one/Leaves/Prototypes/TemplateLeaf")).GetDoubleSidedAttr().Get() is True
    assert Sdf  # noqa
