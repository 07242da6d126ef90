"""write_stage / read_stage round trip, formats, atomicity, readers without the plug-in."""
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from leaffit_usd.errors import InputFileError, ParameterError
from leaffit_usd.runtime.evaluator import asset_leaves
from leaffit_usd.usd import writer as W
from leaffit_usd.usd.reader import read_stage
from leaffit_usd.usd.validate import validate_file

ARRAYS = ("template_points", "template_faces", "template_normals", "template_uvs", "template_side",
          "template_controls", "targets", "positions", "orientations", "scales", "leaf_labels",
          "stem_points", "stem_faces", "asset_to_input")


@pytest.mark.parametrize("ext", ["usda", "usdc", "usdz"])
def test_round_trip_and_usd_validation(tmp_path, asset, textures, ext):
    out = tmp_path / f"plant.{ext}"
    res = W.write_stage(out, asset, textures, W.WriteOptions(baked=True),
                        leaves=asset_leaves(asset, separate_sheets=True))
    assert out.is_file() and res.total_bytes > 0
    b = read_stage(out)
    for name in ARRAYS:
        x, y = getattr(asset, name), getattr(b, name)
        assert x.shape == y.shape, name
        np.testing.assert_allclose(y, x, rtol=1e-6, atol=1e-7, err_msg=name)
    assert b.sigma == pytest.approx(asset.sigma) and b.reg == pytest.approx(asset.reg)
    assert b.front_texture == "./textures/plant.front.jpg"      # jpg+mask, the default
    assert b.back_texture == "./textures/plant.back.jpg"
    assert b.metadata["input_sha256"] == asset.metadata["input_sha256"]
    rep = validate_file(out)
    assert rep.count("error") == 0, [str(f) for f in rep.findings]
    assert rep.count("warning") == 0, [str(f) for f in rep.findings]
    if ext == "usdz":
        names = zipfile.ZipFile(out).namelist()
        assert names[0] == "plant.usdc"
        assert {"textures/plant.front.jpg", "textures/plant.back.jpg", "textures/plant.front.mask.png",
                "textures/plant.back.mask.png", "plant.baked.usdc"} <= set(names)
        assert all(i.compress_type == zipfile.ZIP_STORED for i in zipfile.ZipFile(out).infolist())
        assert sorted(p.name for p in tmp_path.iterdir()) == ["plant.usdz"]
    else:
        assert (tmp_path / "textures" / "plant.front.jpg").is_file()
        assert (tmp_path / "textures" / "plant.front.mask.png").is_file()
        assert (tmp_path / "plant.baked.usdc").is_file()


def test_layout_counts(tmp_path, asset, textures):
    from pxr import Usd, UsdGeom

    out = tmp_path / "p.usda"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    # the geometry is a payload: a scene opening the plant unloaded sees the interface only
    lazy = Usd.Stage.Open(str(out), Usd.Stage.LoadNone)
    assert Usd.ModelAPI(lazy.GetDefaultPrim()).GetKind() == "component"
    assert Usd.ModelAPI(lazy.GetDefaultPrim()).GetAssetName() == "p"
    assert lazy.GetDefaultPrim().HasAuthoredPayloads()
    assert not [p for p in Usd.PrimRange(lazy.GetDefaultPrim()) if p.IsA(UsdGeom.Mesh)]
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    assert Usd.ModelAPI(root).GetKind() == "component"
    assert UsdGeom.GetStageUpAxis(stage) == "Y"
    meshes = [p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh)]
    assert sorted(p.GetName() for p in meshes) == ["Stem", "TemplateLeaf"]  # exactly one template
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(f"{root.GetPath()}/Leaves"))
    L, K = asset.n_leaves, asset.targets.shape[1]
    assert len(inst.GetPositionsAttr().Get()) == L
    assert inst.GetOrientationsAttr().GetTypeName() == "quath[]"
    pv = UsdGeom.PrimvarsAPI(inst).GetPrimvar("leaffit:targets")
    assert pv.GetElementSize() == K and pv.GetInterpolation() == "vertex"
    assert np.asarray(pv.Get()).size == L * K * 3
    cd = root.GetCustomDataByKey("leaffit")
    assert {"toolVersion", "inputSha256", "assetToInput", "params", "metadataJson"} <= set(cd)


def test_baked_variant_matches_deformer(tmp_path, asset, textures):
    from pxr import Usd, UsdGeom, UsdShade

    out = tmp_path / "p.usdc"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    vset = root.GetVariantSets().GetVariantSet("leafRepresentation")
    assert vset.GetVariantSelection() == "deformer"
    assert stage.GetPrimAtPath(f"{root.GetPath()}/BakedLeaves").IsValid() is False
    vset.SetVariantSelection("baked")
    expect = asset_leaves(asset, separate_sheets=True)
    assert np.abs(expect - asset_leaves(asset)).max() <= asset.metadata["sheet_offset"] * asset.scales.max()
    for j in range(asset.n_leaves):
        leaf = stage.GetPrimAtPath(f"{root.GetPath()}/BakedLeaves/leaf_{j:04d}")
        np.testing.assert_allclose(np.asarray(UsdGeom.Mesh(leaf).GetPointsAttr().Get()), expect[j],
                                   rtol=1e-6, atol=1e-6)
        assert len(UsdGeom.Mesh(leaf).GetFaceVertexIndicesAttr().Get()) == asset.template_faces.size
        front = stage.GetPrimAtPath(f"{leaf.GetPath()}/front")
        mat, _ = UsdShade.MaterialBindingAPI(front).ComputeBoundMaterial()
        assert mat.GetPrim().GetName() == "LeafFront"


def test_failed_write_leaves_nothing(tmp_path, asset, textures, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(W, "_write_main_layer", boom)
    for ext in ("usda", "usdz"):
        with pytest.raises(RuntimeError):
            W.write_stage(tmp_path / f"p.{ext}", asset, textures,
                          leaves=asset_leaves(asset, separate_sheets=True))
    assert list(tmp_path.iterdir()) == []


def test_bad_arguments_raise(tmp_path, asset, textures):
    with pytest.raises(ParameterError):
        W.write_stage(tmp_path / "p.obj", asset, textures)
    with pytest.raises(ParameterError):
        W.write_stage(tmp_path / "p.usda", asset, textures, W.WriteOptions(texture_format="tga"))
    import dataclasses
    broken = dataclasses.replace(asset, targets=asset.targets[:, :-1])
    with pytest.raises(ParameterError, match="targets"):
        W.write_stage(tmp_path / "p.usda", broken, textures)
    broken = dataclasses.replace(asset, template_faces=asset.template_faces + 10_000)
    with pytest.raises(ParameterError, match="template_faces"):
        W.write_stage(tmp_path / "p.usda", broken, textures)
    assert list(tmp_path.iterdir()) == []


def test_reader_rejects_non_plants(tmp_path):
    with pytest.raises(InputFileError):
        read_stage(tmp_path / "missing.usda")
    (tmp_path / "junk.usda").write_text("not usd")
    with pytest.raises(InputFileError):
        read_stage(tmp_path / "junk.usda")
    (tmp_path / "empty.usda").write_text('#usda 1.0\ndef Xform "A" {}\n')
    with pytest.raises(InputFileError, match="not a LeafFit plant"):
        read_stage(tmp_path / "empty.usda")


def test_png_textures_keep_alpha_and_downsample(tmp_path, asset, textures):
    import OpenImageIO as oiio

    big = W.LeafTextures(np.repeat(np.repeat(textures.front, 4, 0), 4, 1), textures.back)
    W.write_stage(tmp_path / "p.usda", asset, big, W.WriteOptions(texture_format="png", texture_max_size=128),
                  leaves=asset_leaves(asset, separate_sheets=True))
    spec = oiio.ImageInput.open(str(tmp_path / "textures" / "p.front.png")).spec()
    assert (spec.width, spec.height, spec.nchannels) == (128, 128, 4)
    from pxr import Usd, UsdShade
    stage = Usd.Stage.Open(str(tmp_path / "p.usda"))
    surf = UsdShade.Shader(stage.GetPrimAtPath("/p/Looks/LeafFront/PreviewSurface"))
    assert surf.GetInput("opacity").HasConnectedSource() and surf.GetInput("opacityThreshold").Get() == 0.5


def test_jpg_mask_textures_keep_the_cut_out(tmp_path, asset, textures):
    """jpg+mask (the default): a JPEG colour file and a one-channel PNG mask whose r drives
    opacity; the reader puts the mask back into alpha exactly (the colour within JPEG's loss)."""
    import OpenImageIO as oiio
    from pxr import Usd, UsdShade

    from leaffit_usd.usd.reader import open_stage, read_texture

    rgba = np.array(textures.front, np.uint8, copy=True)
    rgba[..., 3] = 0
    rgba[4:-4, 6:-6, 3] = 255
    rgba[4, 6:-6, 3] = 128
    W.write_stage(tmp_path / "p.usda", asset, W.LeafTextures(rgba, rgba.copy()),
                  leaves=asset_leaves(asset, separate_sheets=True))
    spec = oiio.ImageInput.open(str(tmp_path / "textures" / "p.front.mask.png")).spec()
    assert spec.nchannels == 1
    assert oiio.ImageInput.open(str(tmp_path / "textures" / "p.front.jpg")).spec().nchannels == 3
    back = read_texture(open_stage(tmp_path / "p.usda"), "./textures/p.front.jpg")
    np.testing.assert_array_equal(back[..., 3], rgba[..., 3])
    assert np.abs(back[..., :3].astype(int) - rgba[..., :3]).mean() < 6
    stage = Usd.Stage.Open(str(tmp_path / "p.usda"))
    surf = UsdShade.Shader(stage.GetPrimAtPath("/p/Looks/LeafFront/PreviewSurface"))
    src = surf.GetInput("opacity").GetConnectedSources()[0][0]
    assert src.source.GetPath().name == "Mask" and src.sourceName == "r"


def test_png_textures_keep_straight_alpha(tmp_path, asset, textures):
    """Semi-transparent texels keep their colour on disk and read back exactly (the writer used to
    let OpenImageIO divide colour by alpha on write, clipping it at 255)."""
    from leaffit_usd.usd.reader import open_stage, read_texture

    front = np.array(textures.front[..., :3], np.uint8, copy=True)
    alpha = np.full(front.shape[:2] + (1,), 128, np.uint8)
    alpha[0, 0] = 0
    rgba = np.concatenate([front, alpha], 2)
    rgba[0, 0, :3] = (200, 100, 50)
    W.write_stage(tmp_path / "p.usda", asset, W.LeafTextures(rgba, rgba.copy()),
                  W.WriteOptions(texture_format="png", texture_max_size=16384),
                  leaves=asset_leaves(asset, separate_sheets=True))
    back = read_texture(open_stage(tmp_path / "p.usda"), "./textures/p.front.png")
    np.testing.assert_array_equal(back, rgba)


def test_plain_pxr_reads_every_value_without_the_plugin(tmp_path, asset, textures):
    """A reader that never imports leaffit_usd (no schema plug-in) still sees all authored values."""
    out = tmp_path / "p.usda"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    code = (
        "import sys\nfrom pxr import Usd\n"
        "s = Usd.Stage.Open(sys.argv[1])\n"
        "p = s.GetPrimAtPath(s.GetDefaultPrim().GetPath().AppendChild('Leaves'))\n"
        "print(p.HasAPI('LeafFitMLSDeformerAPI'))\n"
        "for n in ['leaffit:mls:sigma', 'leaffit:mls:regularizer', 'leaffit:mls:controlPointCount',\n"
        "          'leaffit:mls:variant', 'leaffit:mls:kernel']:\n"
        "    a = p.GetAttribute(n); print(n, a.HasAuthoredValue(), a.Get())\n"
        "print(len(p.GetAttribute('primvars:leaffit:targets').Get()))\n"
    )
    # a clean environment: importing leaffit_usd here named the plug-in in PXR_PLUGINPATH_NAME
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    r = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, check=True,
                       env=env)
    lines = r.stdout.split("\n")
    assert lines[0] == "False"      # the plug-in is not known there ...
    assert all(" True " in l for l in lines[1:6]), r.stdout   # ... but every value is authored
    assert int(lines[6]) == asset.targets.shape[0] * asset.targets.shape[1]


def test_usdz_leaves_baked_payload_out_by_default(tmp_path, asset, textures):
    W.write_stage(tmp_path / "p.usdz", asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    names = zipfile.ZipFile(tmp_path / "p.usdz").namelist()
    assert "p.baked.usdc" not in names and len(names) == 6 and "p.geom.usdc" in names  # + 2 masks
    assert "leafRepresentation" not in (tmp_path / "p.usdz").read_bytes().decode("latin-1")
    assert validate_file(tmp_path / "p.usdz").count("error") == 0


def test_deterministic_bytes(tmp_path, asset, textures):
    W.write_stage(tmp_path / "a" / "p.usdz", asset, textures,
                  leaves=asset_leaves(asset, separate_sheets=True))
    W.write_stage(tmp_path / "b" / "p.usdz", asset, textures,
                  leaves=asset_leaves(asset, separate_sheets=True))
    assert (tmp_path / "a" / "p.usdz").read_bytes() == (tmp_path / "b" / "p.usdz").read_bytes()


def test_reader_and_validator_work_when_baked_is_the_saved_selection(tmp_path, asset, textures):
    """'baked' deactivates the PointInstancer (Blender 4.2 crashes on an invisible one); readers
    select 'deformer' in their session layer, so a file saved with 'baked' selected still reads."""
    from pxr import Usd

    out = tmp_path / "p.usda"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    root.GetVariantSets().GetVariantSet("leafRepresentation").SetVariantSelection("baked")
    assert not stage.GetPrimAtPath(f"{root.GetPath()}/Leaves").IsActive()
    stage.GetRootLayer().Save()
    b = read_stage(out)
    assert b.n_leaves == asset.n_leaves
    rep = validate_file(out)
    assert rep.count("error") == 0, [str(f) for f in rep.findings]
    assert 'string leafRepresentation = "baked"' in out.read_text()   # the file was not touched
