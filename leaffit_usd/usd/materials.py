"""The stage's materials (UsdPreviewSurface): the leaf sides with their textures, alpha cut-out
and per-leaf tint; vertex-coloured ones (stem, pot, soil); the front/back GeomSubsets that bind
them; sRGB -> linear. Used by :mod:`leaffit_usd.usd.writer`."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from leaffit_usd.usd.asset import PlantAsset

MASK_SUFFIX = ".mask.png"
STEM_COLOR = (0.23, 0.30, 0.12)   # linear RGB of the stem material
LEAF_ROUGHNESS = 0.6
TINT_PRIMVAR = "leaffit:tint"   # color3f per instance (PointInstancer) / per leaf Mesh (baked)


def mask_path(texture: str) -> str:
    """The alpha mask written beside a ``jpg+mask`` colour texture (same folder, same stem):
    ``./textures/p.front.jpg`` -> ``./textures/p.front.mask.png``."""
    suffix = Path(texture).suffix
    return (texture[:-len(suffix)] if suffix else texture) + MASK_SUFFIX

def make_material(stage, path: str, texture: str | None, color, has_alpha: bool | str = False,
                  tint: bool = False):
    """UsdPreviewSurface material; with a texture, diffuseColor (and opacity) read it via primvars:st.

    has_alpha : False / "" (opaque), True / "a" (opacity = the texture's alpha) or "mask"
        (opacity = the grey mask file beside the texture, :func:`mask_path`, its r channel);
        either alpha with opacityThreshold 0.5 (a cut-out).

    tint : multiply the texture by the per-leaf primvar ``leaffit:tint`` (color3f, linear): a
        UsdPrimvarReader_float3 (fallback (1, 1, 1)) feeds UsdUVTexture's ``scale``, the one
        multiplication UsdPreviewSurface networks have (rgb = texel * scale + bias)."""
    from pxr import Gf, Sdf, UsdShade

    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(LEAF_ROUGHNESS)
    surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    if not texture:
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        return mat
    reader = UsdShade.Shader.Define(stage, f"{path}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, f"{path}/Texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    if tint:
        tr = UsdShade.Shader.Define(stage, f"{path}/TintReader")
        tr.CreateIdAttr("UsdPrimvarReader_float3")
        tr.CreateInput("varname", Sdf.ValueTypeNames.String).Set(TINT_PRIMVAR)
        tr.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(1.0, 1.0, 1.0))
        tr.CreateOutput("result", Sdf.ValueTypeNames.Float3)
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).ConnectToSource(tr.ConnectableAPI(), "result")
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    if has_alpha == "mask":
        mask = UsdShade.Shader.Define(stage, f"{path}/Mask")
        mask.CreateIdAttr("UsdUVTexture")
        mask.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(mask_path(texture)))
        mask.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        mask.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
        mask.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
        mask.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
        mask.CreateOutput("r", Sdf.ValueTypeNames.Float)
        surf.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(mask.ConnectableAPI(), "r")
        surf.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    elif has_alpha:
        tex.CreateOutput("a", Sdf.ValueTypeNames.Float)
        surf.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "a")
        surf.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    return mat

def vertex_colour_material(stage, path: str, color: tuple, per_vertex: bool):
    """UsdPreviewSurface of linear RGB ``color``; with ``per_vertex`` its diffuseColor reads the
    mesh's displayColor primvar, ``color`` the fallback."""
    from pxr import Gf, Sdf, UsdShade

    mat = make_material(stage, path, None, color, False)
    if not per_vertex:
        return mat
    surf = UsdShade.Shader(stage.GetPrimAtPath(f"{path}/PreviewSurface"))
    reader = UsdShade.Shader.Define(stage, f"{path}/ColorReader")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
    reader.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(*color))
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    surf.GetInput("diffuseColor").ConnectToSource(reader.ConnectableAPI(), "result")
    return mat

def make_stem_material(stage, path: str, a: PlantAsset):
    """UsdPreviewSurface whose diffuseColor reads the stem's vertex colours (primvar
    displayColor, linear) with their mean as the fallback; a constant colour without them."""
    return vertex_colour_material(stage, path, stem_material_color(a),
                                  a.stem_colors is not None and len(a.stem_colors) > 0)

def stem_material_color(a: PlantAsset) -> tuple:
    """Linear RGB of the stem material: the mean of the stem's vertex colours, else STEM_COLOR."""
    if a.stem_colors is not None and len(a.stem_colors):
        return tuple(float(x) for x in srgb_to_linear(np.asarray(a.stem_colors)).mean(0))
    return STEM_COLOR

def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)

def bind_sides(stage, mesh, face_side: np.ndarray, looks: str | None):
    """GeomSubsets 'front'/'back' (family materialBind) and, if looks is given, their bindings."""
    from pxr import UsdGeom, UsdShade, Vt

    for side, name, mat in ((0, "front", "LeafFront"), (1, "back", "LeafBack")):
        idx = np.flatnonzero(face_side == side).astype(np.int32)
        sub = UsdGeom.Subset.CreateGeomSubset(mesh, name, UsdGeom.Tokens.face,
                                              Vt.IntArray.FromNumpy(idx), "materialBind",
                                              UsdGeom.Tokens.nonOverlapping)
        if looks:
            api = UsdShade.MaterialBindingAPI.Apply(sub.GetPrim())
            api.Bind(UsdShade.Material(stage.GetPrimAtPath(f"{looks}/{mat}")))
    UsdGeom.Subset.SetFamilyType(mesh, "materialBind", UsdGeom.Tokens.partition)
