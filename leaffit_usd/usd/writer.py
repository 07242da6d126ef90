"""PlantAsset -> USD stage (.usda, .usdc, .usdz). The layout is documented in docs/usd_layout.md.

::

    /<Plant>                      Xform, defaultPrim, kind = component, assetInfo, customData;
                                  payload @./<name>.geom.usdc@ (everything below but BakedLeaves)
        Looks/                    Scope
            LeafFront, LeafBack   Material: UsdPreviewSurface <- UsdUVTexture(file) <- primvars:st
            Stem                  Material: UsdPreviewSurface, constant colour
        Leaves                    PointInstancer, apiSchemas = [LeafFitMLSDeformerAPI]
            Prototypes/TemplateLeaf   Mesh (the ONE template), GeomSubsets front/back -> materials
        Stem                      Mesh (cylinders)
        BakedLeaves               only in variant leafRepresentation = baked: payload
                                  @./<name>.baked.usdc@ with one Mesh per leaf

Conventions (the only place they are converted): PlantAsset quaternions are (w, x, y, z); Gf
quaternions store (x, y, z, w) in memory. Matrices in customData are Gf.Matrix4d, USD's
row-vector convention (``x' = x * M``), i.e. the transpose of our column-vector numpy 4x4s.

Outputs are atomic: every file is built in a temporary directory beside the target and moved
into place only when all of them were written; the stage file itself is moved last.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.usd import schema as S
from leaffit_usd.version import __version__
from leaffit_usd.usd.asset import PlantAsset
from leaffit_usd.usd.vt import extent, matrix4d, quat_arrays, vec3f_array
from leaffit_usd.usd.wind import template_flutter, wind_data

log = logging.getLogger("leaffit_usd")

FORMATS = (".usda", ".usdc", ".usd", ".usdz")
#: "jpg+mask": colour as JPEG, the alpha cut-out as a grey PNG beside it (``mask_path``);
#: "jpg": colour only (the mesh outline is the leaf's outline); "png": one RGBA file
TEXTURE_FORMATS = ("jpg+mask", "jpg", "png")
MASK_SUFFIX = ".mask.png"


def mask_path(texture: str) -> str:
    """The alpha mask written beside a ``jpg+mask`` colour texture (same folder, same stem):
    ``./textures/p.front.jpg`` -> ``./textures/p.front.mask.png``."""
    suffix = Path(texture).suffix
    return (texture[:-len(suffix)] if suffix else texture) + MASK_SUFFIX
STEM_COLOR = (0.23, 0.30, 0.12)   # linear RGB of the stem material
LEAF_ROUGHNESS = 0.6
ZIP_EPOCH = 946728000   # 2000-01-01 12:00 UTC: fixed timestamps inside .usdz packages


@dataclass
class LeafTextures:
    """The two leaf textures. front, back : (H, W, 3|4) uint8 (straight alpha), row 0 = top (v = 1)."""

    front: np.ndarray
    back: np.ndarray


@dataclass
class WriteOptions:
    """How the stage is written.

    texture_format : "jpg+mask" (default: colour as JPEG, the alpha cut-out as a grey PNG mask
        beside it, wired to opacity with opacityThreshold 0.5, so the leaf's fine serration
        shows; a 512^2 leaf ~40 KB + 10 KB against ~600 KB as RGBA PNG), "png" (one RGBA file,
        lossless) or "jpg" (colour only; alpha dropped: the mesh outline is the leaf's outline)
    texture_max_size : textures larger than this (pixels, longest side) are downsampled
    jpeg_quality : 1..100
    baked : write the baked-leaves payload (variant leafRepresentation = baked): True, False or
        "auto" (default: a sidecar file beside .usda/.usdc; left out of .usdz, the compact
        delivery format, where it would triple the size -- pass True to pack it)
    prim_name : name of the plant prim (default: the output file's stem, made a valid identifier)
    """

    texture_format: str = "jpg+mask"
    texture_max_size: int = 1024
    jpeg_quality: int = 90
    baked: bool | str = "auto"
    prim_name: str | None = None

    def validate(self) -> "WriteOptions":
        """Raise ParameterError (named after convert's flags) for a value out of range."""
        if self.texture_format not in TEXTURE_FORMATS:
            raise ParameterError("--texture-format", " or ".join(TEXTURE_FORMATS), self.texture_format)
        if not (16 <= int(self.texture_max_size) <= 16384):
            raise ParameterError("--texture-size", "an integer in 16..16384", self.texture_max_size)
        if not 1 <= int(self.jpeg_quality) <= 100:
            raise ParameterError("jpeg_quality", "an integer in 1..100", self.jpeg_quality)
        if self.baked not in (True, False, "auto"):
            raise ParameterError("--baked", "auto, yes or no", self.baked)
        return self


@dataclass
class WriteResult:
    """What was written. files : {role: path}; sizes : {role: bytes}; total_bytes : int."""

    path: Path
    files: dict = field(default_factory=dict)
    sizes: dict = field(default_factory=dict)

    @property
    def total_bytes(self) -> int:
        return int(sum(self.sizes.values()))


# ----------------------------------------------------------------------------------------------
# public entry point


def write_stage(path, asset: PlantAsset, textures: LeafTextures | None = None,
                options: WriteOptions | None = None, leaves: np.ndarray | None = None,
                lod_leaves: list | None = None) -> WriteResult:
    """Write ``asset`` as a USD stage at ``path`` (.usda/.usdc/.usd/.usdz), atomically.

    textures : the front/back leaf images, or None (materials then use a constant green and no
        texture files are written; the asset's own texture paths are kept if set).
    leaves : (L, V, 3) float, the explicit leaves in the asset frame with their sheets apart
        (``runtime.evaluator.asset_leaves(asset, separate_sheets=True)``): the leaves' extent
        and the baked payload. Required when the asset has leaves (this module only writes).
    lod_leaves : the same for each of ``asset.lods`` ((L, V_k, 3) each, from that level's
        template), or None: then the baked representation shows LOD0's leaves at every level.
    For .usda/.usdc the textures go to ``textures/<name>.front.<ext>``, the geometry payload to
    ``<name>.geom.usdc`` and the baked payload to ``<name>.baked.usdc`` beside the stage (relative
    paths); for .usdz all of them are packed.
    Returns a :class:`WriteResult`. Raises ParameterError for an unknown extension or option.
    """
    options = options or WriteOptions()
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise ParameterError("output", f"a file ending in {', '.join(FORMATS)}", str(path))
    options.validate()
    _check_asset(asset)
    leaves = _check_leaves(asset, leaves)

    from pxr import Tf

    name = options.prim_name or Tf.MakeValidIdentifier(path.stem) or "Plant"
    stem = path.stem
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{stem}.", dir=path.parent))
    try:
        rel = {}  # role -> relative path inside tmp (and beside / inside the output)
        if textures is not None:
            ext_t = "jpg" if options.texture_format == "jpg+mask" else options.texture_format
            for role, img in (("front", textures.front), ("back", textures.back)):
                r = f"textures/{stem}.{role}.{ext_t}"
                _write_texture(tmp / r, img, options)
                rel[f"texture_{role}"] = r
                if options.texture_format == "jpg+mask":
                    _write_texture(tmp / mask_path(r), _alpha_of(img), options)
                    rel[f"texture_{role}_mask"] = mask_path(r)
            front_tex, back_tex = "./" + rel["texture_front"], "./" + rel["texture_back"]
        else:
            front_tex, back_tex = asset.front_texture, asset.back_texture
        want_baked = (ext != ".usdz") if options.baked == "auto" else bool(options.baked)
        baked_rel = f"{stem}.baked.usdc" if want_baked and asset.n_leaves else None
        if baked_rel:
            write_baked_layer(tmp / baked_rel, asset, leaves, lod_leaves)
            rel["baked"] = baked_rel
        main_rel = f"{stem}.usdc" if ext == ".usdz" else path.name
        rel["geometry"] = f"{stem}.geom.usdc"
        has_alpha = "" if textures is None else {"png": "a", "jpg+mask": "mask"}.get(
            options.texture_format, "")
        # a text stage keeps only the interface as text: the variants' arrays (the LODs) go to a
        # crate sublayer beside it (the same layer stack, so the same composed stage)
        variants_rel = f"{stem}.variants.usdc" if ext == ".usda" and (baked_rel or asset.lods) else None
        if variants_rel:
            rel["variants"] = variants_rel
        _write_main_layer(tmp / main_rel, asset, leaves, name, front_tex, back_tex, has_alpha,
                          "./" + baked_rel if baked_rel else None, bool(lod_leaves),
                          tmp / rel["geometry"], "./" + rel["geometry"], variants_rel)
        result = WriteResult(path=path)
        if ext == ".usdz":
            pkg = tmp / path.name
            _package_usdz(pkg, tmp, [main_rel] + [v for k, v in sorted(rel.items())])
            for k, v in [("stage", main_rel)] + sorted(rel.items()):
                result.sizes[k] = (tmp / v).stat().st_size
            os.replace(pkg, path)
            result.files = {"stage": path}
            result.sizes = {"usdz": path.stat().st_size, **{f"packed_{k}": v for k, v in result.sizes.items()}}
        else:
            for k, v in sorted(rel.items()):  # sidecars first, the stage last
                dst = path.parent / v
                dst.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp / v, dst)
                result.files[k] = dst
                result.sizes[k] = dst.stat().st_size
            os.replace(tmp / main_rel, path)
            result.files["stage"] = path
            result.sizes["stage"] = path.stat().st_size
        return result
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ----------------------------------------------------------------------------------------------
# checks


def _check_asset(a: PlantAsset) -> None:
    V, L, K = len(a.template_points), a.n_leaves, len(a.template_controls)
    checks = [
        ("template_points", a.template_points.shape == (V, 3) and V > 0, "(V, 3), V > 0", a.template_points.shape),
        ("template_faces", a.template_faces.ndim == 2 and a.template_faces.shape[1] == 3 and len(a.template_faces) > 0,
         "(F, 3), F > 0", a.template_faces.shape),
        ("template_normals", a.template_normals.shape == (V, 3), f"({V}, 3)", a.template_normals.shape),
        ("template_uvs", a.template_uvs.shape == (V, 2), f"({V}, 2)", a.template_uvs.shape),
        ("template_side", a.template_side.shape == (V,), f"({V},)", a.template_side.shape),
        ("template_controls", a.template_controls.shape == (K, 3) and K > 0, "(K, 3), K > 0", a.template_controls.shape),
        ("targets", a.targets.shape == (L, K, 3), f"({L}, {K}, 3)", a.targets.shape),
        ("positions", a.positions.shape == (L, 3), f"({L}, 3)", a.positions.shape),
        ("orientations", a.orientations.shape == (L, 4), f"({L}, 4)", a.orientations.shape),
        ("scales", a.scales.shape == (L, 3), f"({L}, 3)", a.scales.shape),
        ("leaf_labels", a.leaf_labels.shape == (L,), f"({L},)", a.leaf_labels.shape),
        ("asset_to_input", np.shape(a.asset_to_input) == (4, 4), "(4, 4)", np.shape(a.asset_to_input)),
    ]
    for name, ok, expected, got in checks:
        if not ok:
            raise ParameterError(f"asset.{name}", expected, got)
    if a.template_faces.size and (a.template_faces.min() < 0 or a.template_faces.max() >= V):
        raise ParameterError("asset.template_faces", f"indices in 0..{V - 1}",
                             f"range {a.template_faces.min()}..{a.template_faces.max()}")
    if a.stem_faces.size and (a.stem_faces.min() < 0 or a.stem_faces.max() >= len(a.stem_points)):
        raise ParameterError("asset.stem_faces", f"indices in 0..{len(a.stem_points) - 1}",
                             f"range {a.stem_faces.min()}..{a.stem_faces.max()}")
    if a.stem_colors is not None and np.shape(a.stem_colors) != np.shape(a.stem_points):
        raise ParameterError("asset.stem_colors", f"({len(a.stem_points)}, 3) or None", np.shape(a.stem_colors))
    for name in ("template_points", "targets", "positions", "orientations", "scales", "stem_points"):
        if not np.isfinite(getattr(a, name)).all():
            raise ParameterError(f"asset.{name}", "finite values", "NaN or inf entries")


# ----------------------------------------------------------------------------------------------
# textures


def _check_leaves(a: PlantAsset, leaves) -> np.ndarray:
    """The explicit leaves as a (L, V, 3) float32 array, or ParameterError."""
    L, V = a.n_leaves, len(a.template_points)
    if leaves is None and L == 0:
        return np.zeros((0, V, 3), np.float32)
    if leaves is None:
        raise ParameterError("leaves", "the explicit leaves (runtime.evaluator.asset_leaves)", None)
    arr = np.asarray(leaves)
    if arr.shape != (L, V, 3) or not np.isfinite(arr).all():
        raise ParameterError("leaves", f"a finite ({L}, {V}, 3) array", arr.shape)
    return arr.astype(np.float32)


def _alpha_of(img: np.ndarray) -> np.ndarray:
    """(H, W, 1) uint8 alpha of an (H, W, 3|4) uint8 texture (255 without an alpha channel)."""
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 4:
        return np.ascontiguousarray(img[:, :, 3:4])
    return np.full(img.shape[:2] + (1,), 255, np.uint8)


def _write_texture(path: Path, img: np.ndarray, options: WriteOptions) -> None:
    """Write an (H, W, 1|3|4) uint8 texture, downsampled to texture_max_size (jpg drops alpha)."""
    from leaffit_usd.image_io import write_image

    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or img.dtype != np.uint8:
        raise ParameterError("texture", "an (H, W, 3|4) uint8 image", f"{img.dtype} {img.shape}")
    write_image(path, img, max_size=int(options.texture_max_size), jpeg_quality=int(options.jpeg_quality))


# ----------------------------------------------------------------------------------------------
# main layer


TINT_PRIMVAR = "leaffit:tint"   # color3f per instance (PointInstancer) / per leaf Mesh (baked)
# wind (usd.wind): per instance on the PointInstancer, per vertex on the stem
WIND_PIVOT, WIND_AXIS = "leaffit:windPivot", "leaffit:windAxis"
WIND_NODE, WIND_PHASE, WIND_BEND = "leaffit:windNode", "leaffit:windPhase", "leaffit:windBend"
WIND_FLUTTER = "leaffit:windFlutter"   # per vertex, baked leaves


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


def single_sheet(a: PlantAsset) -> bool:
    """True when the template has faces on one side only: that sheet must be drawn doubleSided."""
    sides = np.unique(_face_sides(a)) if len(a.template_faces) else np.zeros(0)
    return len(sides) < 2


def _face_sides(a: PlantAsset) -> np.ndarray:
    """(F,) uint8 side of every template face (majority of its vertices)."""
    return (a.template_side[a.template_faces].astype(np.int32).sum(1) >= 2).astype(np.uint8)


def _author_template_mesh(stage, path: str, a: PlantAsset, looks: str):
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(single_sheet(a))
    _set_template_geometry(mesh, a)
    _bind_sides(stage, mesh, _face_sides(a), looks)
    mesh.GetPrim().SetCustomDataByKey("leaffit:role", "template")
    return mesh


def _set_template_geometry(mesh, a) -> None:
    """Points (drawn), topology, normals, st and leaffit:side of the template Mesh from ``a`` (a
    PlantAsset or, for a level of detail, a copy carrying that level's template arrays)."""
    from pxr import Sdf, UsdGeom, Vt

    drawn = a.drawn_template_points()
    mesh.CreatePointsAttr(vec3f_array(drawn))
    mesh.CreateExtentAttr(extent(drawn))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(a.template_faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(a.template_faces, np.int32).ravel()))
    mesh.CreateNormalsAttr(vec3f_array(a.template_normals))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    pv = UsdGeom.PrimvarsAPI(mesh)
    st = pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(a.template_uvs, np.float32)))
    side = pv.CreatePrimvar("leaffit:side", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex)
    side.Set(Vt.IntArray.FromNumpy(np.asarray(a.template_side).astype(np.int32)))


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def stem_material_color(a: PlantAsset) -> tuple:
    """Linear RGB of the stem material: the mean of the stem's vertex colours, else STEM_COLOR."""
    if a.stem_colors is not None and len(a.stem_colors):
        return tuple(float(x) for x in _srgb_to_linear(np.asarray(a.stem_colors)).mean(0))
    return STEM_COLOR


def _author_pot(stage, root: str, looks: str, pot) -> None:
    """``Pot`` and ``Soil`` Meshes (``mesh.pot``; convert --pot), vertex-coloured, asset frame;
    customData leaffit:role "pot" / "soil": never leaves or stem."""
    from pxr import Sdf, UsdGeom, UsdShade, Vt

    from leaffit_usd.geometry.normals import vertex_normals

    for name, pts, faces, cols in (("Pot", pot.pot_points, pot.pot_faces, pot.pot_colors),
                                   ("Soil", pot.soil_points, pot.soil_faces, pot.soil_colors)):
        if not len(pts) or not len(faces):
            continue
        mesh = UsdGeom.Mesh.Define(stage, f"{root}/{name}")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreatePointsAttr(vec3f_array(pts))
        mesh.CreateExtentAttr(extent(pts))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, np.int32).ravel()))
        mesh.CreateNormalsAttr(vec3f_array(vertex_normals(pts, faces, undefined=(0.0, 0.0, 1.0))))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        lin = _srgb_to_linear(np.asarray(cols))
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                UsdGeom.Tokens.vertex).Set(vec3f_array(lin))
        mat = vertex_colour_material(stage, f"{looks}/{name}", tuple(float(x) for x in lin.mean(0)), True)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        mesh.GetPrim().SetCustomDataByKey("leaffit:role", name.lower())


def _author_wind(pv, w) -> None:
    """The per-instance wind primvars of the leaves' PointInstancer (``usd.wind``): pivot (the
    petiole base) and axis (base to apex), asset frame; the stem skeleton node each leaf hangs
    from; its phase in [0, 1)."""
    from pxr import Sdf, UsdGeom, Vt

    pv.CreatePrimvar(WIND_PIVOT, Sdf.ValueTypeNames.Point3fArray, UsdGeom.Tokens.vertex).Set(vec3f_array(w.pivots))
    pv.CreatePrimvar(WIND_AXIS, Sdf.ValueTypeNames.Vector3fArray, UsdGeom.Tokens.vertex).Set(vec3f_array(w.axes))
    pv.CreatePrimvar(WIND_NODE, Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex).Set(
        Vt.IntArray.FromNumpy(np.asarray(w.nodes, np.int32)))
    pv.CreatePrimvar(WIND_PHASE, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy(np.asarray(w.phases, np.float32)))


def _author_stem_wind(mesh, a: PlantAsset, w) -> None:
    """The stem's wind data: ``primvars:leaffit:windBend`` per vertex (the distance along the
    skeleton from the root, 0..1) and the skeleton the leaves' ``windNode`` indexes (constant
    primvars ``leaffit:skeletonPoints`` (asset frame) and ``leaffit:skeletonParents``)."""
    from pxr import Sdf, UsdGeom, Vt

    pv = UsdGeom.PrimvarsAPI(mesh)
    pv.CreatePrimvar(WIND_BEND, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy(np.asarray(w.stem_bend, np.float32)))
    if a.skeleton_points is not None and len(a.skeleton_points):
        pv.CreatePrimvar("leaffit:skeletonPoints", Sdf.ValueTypeNames.Point3fArray,
                         UsdGeom.Tokens.constant).Set(vec3f_array(a.skeleton_points))
        pv.CreatePrimvar("leaffit:skeletonParents", Sdf.ValueTypeNames.IntArray,
                         UsdGeom.Tokens.constant).Set(Vt.IntArray.FromNumpy(np.asarray(a.skeleton_parents, np.int32)))


def _set_stem_geometry(mesh, a: PlantAsset) -> None:
    """Points, topology, smooth vertex normals and (when known) displayColor of the stem Mesh."""
    from pxr import Sdf, UsdGeom, Vt

    from leaffit_usd.geometry.normals import vertex_normals

    mesh.CreatePointsAttr(vec3f_array(a.stem_points))
    mesh.CreateExtentAttr(extent(a.stem_points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(a.stem_faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(a.stem_faces, np.int32).ravel()))
    n = vertex_normals(a.stem_points, a.stem_faces, undefined=(0.0, 0.0, 1.0))
    mesh.CreateNormalsAttr(vec3f_array(n))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    if a.stem_colors is not None and len(a.stem_colors) == len(a.stem_points):
        dc = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                     UsdGeom.Tokens.vertex)
        dc.Set(vec3f_array(_srgb_to_linear(a.stem_colors)))


def make_stem_material(stage, path: str, a: PlantAsset):
    """UsdPreviewSurface whose diffuseColor reads the stem's vertex colours (primvar
    displayColor, linear) with their mean as the fallback; a constant colour without them."""
    return vertex_colour_material(stage, path, stem_material_color(a),
                                  a.stem_colors is not None and len(a.stem_colors) > 0)


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


def _bind_sides(stage, mesh, face_side: np.ndarray, looks: str | None):
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


def _stage_units(stage, a: PlantAsset) -> None:
    from pxr import UsdGeom

    up = str(a.metadata.get("up_axis", "Y")).upper()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(a.metadata.get("meters_per_unit", 1.0)))


def _write_main_layer(out: Path, a: PlantAsset, leaves: np.ndarray, name: str, front_tex: str,
                      back_tex: str, has_alpha: str, baked_rel: str | None, baked_lods: bool,
                      geom_out: Path, geom_rel: str, variants_rel: str | None = None) -> None:
    """Two layers: ``geom_out`` (Looks, Leaves, Stem under /<name>, its defaultPrim) and the root
    layer ``out``: the /<name> interface prim (kind, assetInfo, customData, variant sets) whose
    payload ``geom_rel`` brings the geometry in, so a scene can load the plant lazily. Variant
    opinions (LOD, leafRepresentation) in the root layer are stronger than the payload's."""
    # the geometry stage stays open while the root layer refers to its template Mesh
    geo, tmpl = _write_geometry_layer(geom_out, out.name, a, leaves, name, front_tex, back_tex,
                                      has_alpha)
    _write_root_layer(out, a, name, geom_rel, baked_rel, baked_lods, tmpl, variants_rel)
    del geo


def _write_geometry_layer(geom_out: Path, main_name: str, a: PlantAsset, leaves: np.ndarray,
                          name: str, front_tex: str, back_tex: str, has_alpha: str):
    """The payload layer ``geom_out``: /<name> with Looks, the Leaves instancer and the Stem.
    Returns (the open stage, the template leaf Mesh)."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(geom_out))
    _stage_units(stage, a)
    root = f"/{name}"
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, root).GetPrim())
    tints = _tints(a)

    looks = f"{root}/Looks"
    UsdGeom.Scope.Define(stage, looks)
    green = (0.1, 0.35, 0.08)
    tinted = tints is not None
    make_material(stage, f"{looks}/LeafFront", front_tex or None, green, has_alpha, tinted)
    make_material(stage, f"{looks}/LeafBack", back_tex or None, green, has_alpha, tinted)
    stem_mat = make_stem_material(stage, f"{looks}/Stem", a)
    wind = wind_data(a)
    tmpl = _author_leaf_instancer(stage, f"{root}/Leaves", a, leaves, looks, tints, wind)

    if len(a.stem_points) and len(a.stem_faces):
        stem = UsdGeom.Mesh.Define(stage, f"{root}/Stem")
        stem.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        _set_stem_geometry(stem, a)
        _author_stem_wind(stem, a, wind)
        UsdShade.MaterialBindingAPI.Apply(stem.GetPrim()).Bind(stem_mat)
        stem.GetPrim().SetCustomDataByKey("leaffit:role", "stem")
    if a.pot is not None:
        _author_pot(stage, root, looks, a.pot)

    stage.GetRootLayer().documentation = (
        f"LeafFit plant geometry: the payload of ./{main_name} (open that file)")
    stage.GetRootLayer().Save()
    return stage, tmpl


def _author_leaf_instancer(stage, inst_path: str, a: PlantAsset, leaves: np.ndarray, looks: str,
                           tints, wind):
    """The leaves: one template Mesh prototype + a PointInstancer with the MLS deformer
    (LeafFitMLSDeformerAPI, targets, labels, tints, wind: ``usd.wind.WindData``). leaves :
    (L, V, 3) explicit leaves, for the extent. Returns the template Mesh."""
    from pxr import Sdf, UsdGeom, Vt

    inst = UsdGeom.PointInstancer.Define(stage, inst_path)
    UsdGeom.Scope.Define(stage, f"{inst_path}/Prototypes")
    tmpl = _author_template_mesh(stage, f"{inst_path}/Prototypes/TemplateLeaf", a, looks)
    inst.CreatePrototypesRel().SetTargets([tmpl.GetPath()])
    L, K = a.n_leaves, len(a.template_controls)
    inst.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(L, np.int32)))
    inst.CreatePositionsAttr(vec3f_array(a.positions))
    qh, qf = quat_arrays(a.orientations) if L else (Vt.QuathArray(), Vt.QuatfArray())
    inst.CreateOrientationsAttr(qh)     # quath: what Blender reads
    inst.CreateOrientationsfAttr(qf)    # float precision: preferred by USD when authored
    inst.CreateScalesAttr(vec3f_array(a.scales))
    inst.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.asarray(a.leaf_labels, np.int64)))
    pv = UsdGeom.PrimvarsAPI(inst)
    tg = pv.CreatePrimvar("leaffit:targets", Sdf.ValueTypeNames.Float3Array, UsdGeom.Tokens.vertex, K)
    tg.Set(vec3f_array(a.targets))
    lab = pv.CreatePrimvar("leaffit:leafLabel", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex)
    lab.Set(Vt.IntArray.FromNumpy(np.asarray(a.leaf_labels, np.int32)))
    if tints is not None:
        pv.CreatePrimvar(TINT_PRIMVAR, Sdf.ValueTypeNames.Color3fArray,
                         UsdGeom.Tokens.vertex).Set(vec3f_array(tints))
    _author_wind(pv, wind)
    inst.CreateExtentAttr(extent(leaves))
    ip = inst.GetPrim()
    ip.SetCustomDataByKey("leaffit:role", "leaves")
    ip.ApplyAPI(S.API_NAME)
    ip.CreateRelationship(S.ATTR_TEMPLATE_REL, custom=False).SetTargets([tmpl.GetPath()])
    _attr(ip, S.ATTR_CONTROLS, Sdf.ValueTypeNames.Point3fArray, vec3f_array(a.template_controls))
    _attr(ip, S.ATTR_K, Sdf.ValueTypeNames.Int, int(K))
    _attr(ip, S.ATTR_TARGETS_PRIMVAR, Sdf.ValueTypeNames.Token, S.TARGETS_PRIMVAR)
    _attr(ip, S.ATTR_VARIANT, Sdf.ValueTypeNames.Token, "affine", uniform=True)
    _attr(ip, S.ATTR_KERNEL, Sdf.ValueTypeNames.Token, "gaussian", uniform=True)
    _attr(ip, S.ATTR_SIGMA, Sdf.ValueTypeNames.Float, float(a.sigma))
    _attr(ip, S.ATTR_REG, Sdf.ValueTypeNames.Float, float(a.reg))
    _attr(ip, S.ATTR_SHEET_OFFSET, Sdf.ValueTypeNames.Float, a.sheet_offset)
    _attr(ip, S.ATTR_VERSION, Sdf.ValueTypeNames.Int, S.DEFORMER_VERSION, uniform=True)
    return tmpl


def _write_root_layer(out: Path, a: PlantAsset, name: str, geom_rel: str, baked_rel: str | None,
                      baked_lods: bool, tmpl, variants_rel: str | None = None) -> None:
    """The root layer ``out``: the asset's interface; the geometry arrives through the payload
    ``geom_rel``; the leafRepresentation and LOD variant sets. tmpl : the template leaf Mesh of
    the geometry layer. variants_rel : author the variant sets in this crate sublayer (beside
    ``out``) instead of the root layer: a .usda root stays a small, readable text file."""
    from pxr import Kind, Sdf, Usd, UsdGeom

    root = f"/{name}"
    stage = Usd.Stage.CreateNew(str(out))
    _stage_units(stage, a)
    plant = UsdGeom.Xform.Define(stage, root).GetPrim()
    stage.SetDefaultPrim(plant)
    Usd.ModelAPI(plant).SetKind(Kind.Tokens.component)
    Usd.ModelAPI(plant).SetAssetName(name)
    Usd.ModelAPI(plant).SetAssetVersion(str(a.metadata.get("tool_version", __version__)))
    Usd.ModelAPI(plant).SetAssetIdentifier(Sdf.AssetPath(f"./{out.name}"))
    plant.SetCustomDataByKey("leaffit", _custom_data(a))
    plant.GetPayloads().AddPayload(geom_rel)
    vlayer = None
    if variants_rel:
        vlayer = Sdf.Layer.CreateNew(str(out.parent / variants_rel))
        stage.GetRootLayer().subLayerPaths.append("./" + variants_rel)
        stage.SetEditTarget(Usd.EditTarget(vlayer))
    if baked_rel:
        _author_baked_variant(stage, plant, a, root, baked_rel, baked_lods)
    if a.lods:
        _author_lod_variants(stage, plant, a, tmpl, root, bool(baked_rel) and baked_lods)
    if vlayer is not None:
        vlayer.documentation = f"LeafFit plant variants (LOD, leafRepresentation) of ./{out.name}"
        vlayer.Save()
        stage.SetEditTarget(Usd.EditTarget(stage.GetRootLayer()))
    stage.GetRootLayer().documentation = (
        "LeafFit plant: one template leaf Mesh deformed per instance by affine MLS "
        "(LeafFitMLSDeformerAPI); written by leaffit-usd")
    stage.GetRootLayer().Save()


def _author_baked_variant(stage, plant, a: PlantAsset, root: str, baked_rel: str,
                          baked_lods: bool) -> None:
    """Variant set ``leafRepresentation`` (deformer, the default | baked): explicit leaves for
    tools without the deformer, a variant whose geometry is the payload file ``baked_rel``."""
    from pxr import UsdGeom, UsdShade

    looks = f"{root}/Looks"
    vset = plant.GetVariantSets().AddVariantSet("leafRepresentation")
    vset.AddVariant("deformer")
    vset.AddVariant("baked")
    vset.SetVariantSelection("baked")
    with vset.GetVariantEditContext():
        baked = UsdGeom.Xform.Define(stage, f"{root}/BakedLeaves")
        baked.GetPrim().GetPayloads().AddPayload(baked_rel)
        baked.GetPrim().SetCustomDataByKey("leaffit:role", "baked")
        # deactivate (not hide) the instancer: Blender 4.2 crashes importing an invisible
        # PointInstancer next to other meshes; readers force the 'deformer' variant
        stage.OverridePrim(f"{root}/Leaves").SetActive(False)
        for k in range(len(a.lods) + 1 if baked_lods else 1):
            topo = stage.OverridePrim(f"{root}/BakedLeaves/{_baked_topology(k)}")
            for side, mat in (("front", "LeafFront"), ("back", "LeafBack")):
                sub = stage.OverridePrim(f"{topo.GetPath()}/{side}")
                UsdShade.MaterialBindingAPI.Apply(sub).Bind(
                    UsdShade.Material(stage.GetPrimAtPath(f"{looks}/{mat}")))
    vset.SetVariantSelection("deformer")


def _author_lod_variants(stage, plant, a: PlantAsset, tmpl, root: str, baked: bool) -> None:
    """Variant set ``LOD`` on the plant: LOD0 (default) is the geometry authored above; LODk
    overrides the template Mesh (points, topology, normals, st, side subsets) and the stem Mesh
    with level k's arrays. With the baked representation, a nested ``leafRepresentation``
    variant inside LODk switches the payload's leaves to its LODk group."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    # local opinions are stronger than variant opinions: LOD0's geometry moves into its variant
    layer = stage.GetEditTarget().GetLayer()
    tpath = tmpl.GetPath()
    varying = {tpath: _TEMPLATE_ATTRS, tpath.AppendChild("front"): ("indices",),
               tpath.AppendChild("back"): ("indices",)}
    if len(a.stem_points):
        varying[plant.GetPath().AppendChild("Stem")] = _STEM_ATTRS
    for path, attrs in varying.items():
        spec = layer.GetPrimAtPath(path)
        for nm in attrs:
            if spec is not None and nm in spec.properties:
                spec.RemoveProperty(spec.properties[nm])
    # LOD first: its nested overs must be stronger than the leafRepresentation subtree (whose
    # payload keeps the coarser groups inactive)
    vset = plant.GetVariantSets().AddVariantSet("LOD", Usd.ListPositionFrontOfPrependList)
    names = [f"LOD{k}" for k in range(len(a.lods) + 1)]
    for nm in names:
        vset.AddVariant(nm)
    for k, lod in enumerate([None] + list(a.lods)):
        la = a.at_lod(k)
        vset.SetVariantSelection(names[k])
        with vset.GetVariantEditContext():
            # LOD0 is the geometry payload itself (payload opinions are weaker than variants')
            if k > 0:
                mesh = UsdGeom.Mesh(stage.OverridePrim(tmpl.GetPath()))
                _set_template_geometry(mesh, la)
                sides = _face_sides(la)
                for side, nm in ((0, "front"), (1, "back")):
                    sub = UsdGeom.Subset(stage.OverridePrim(tmpl.GetPath().AppendChild(nm)))
                    sub.CreateIndicesAttr(Vt.IntArray.FromNumpy(np.flatnonzero(sides == side).astype(np.int32)))
                if len(a.stem_points) and len(la.stem_points):
                    _set_stem_geometry(UsdGeom.Mesh(stage.OverridePrim(f"{root}/Stem")), la)
            if baked and k > 0:
                rep = plant.GetVariantSets().AddVariantSet("leafRepresentation")
                rep.AddVariant("baked")
        if baked and k > 0:
            # edit /Plant{LOD=LODk}{leafRepresentation=baked} explicitly: a variant edit context
            # would follow the composed selection ('deformer')
            nested = Sdf.Path(f"{root}{{LOD={names[k]}}}{{leafRepresentation=baked}}BakedLeaves")
            for j in range(a.n_leaves):
                Sdf.CreatePrimInLayer(layer, nested.AppendChild(f"leaf_{j:04d}")).active = False
            Sdf.CreatePrimInLayer(layer, nested.AppendChild(names[k])).active = True
    vset.SetVariantSelection(names[0])
    spec = layer.GetPrimAtPath(plant.GetPath())
    order = list(spec.variantSetNameList.prependedItems)
    if "LOD" in order:
        spec.variantSetNameList.prependedItems = ["LOD"] + [n for n in order if n != "LOD"]


_TEMPLATE_ATTRS = ("points", "extent", "faceVertexCounts", "faceVertexIndices", "normals",
                   "primvars:st", "primvars:leaffit:side")
_STEM_ATTRS = ("points", "extent", "faceVertexCounts", "faceVertexIndices", "normals",
               "primvars:displayColor")


def _baked_topology(k: int) -> str:
    """Name of the class prim holding the baked leaves' shared topology at level of detail k."""
    return "LeafTopology" if k == 0 else f"LeafTopologyLOD{k}"


def _attr(prim, name, type_name, value, uniform=False):
    from pxr import Sdf
    a = prim.CreateAttribute(name, type_name, custom=False,
                             variability=Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying)
    a.Set(value)
    return a


def _custom_data(a: PlantAsset) -> dict:
    md = a.metadata or {}
    params = md.get("params", {})
    return {
        "toolVersion": str(md.get("tool_version", __version__)),
        "inputSha256": str(md.get("input_sha256", "")),
        "assetToInput": matrix4d(a.asset_to_input),
        "params": _flat_params(params),
        "metadataJson": json.dumps(md, sort_keys=True, allow_nan=True),
    }


def _flat_params(params, prefix="") -> dict:
    """Nested parameter dicts -> a USD dictionary of scalars (lists become JSON strings)."""
    out = {}
    for k, v in (params or {}).items():
        if isinstance(v, dict):
            out[str(k)] = _flat_params(v)
        elif isinstance(v, bool):
            out[str(k)] = bool(v)
        elif isinstance(v, int):
            out[str(k)] = int(v)
        elif isinstance(v, float):
            out[str(k)] = float(v)
        elif v is None:
            out[str(k)] = "None"
        elif isinstance(v, str):
            out[str(k)] = v
        else:
            out[str(k)] = json.dumps(v)
    return out


# ----------------------------------------------------------------------------------------------
# baked payload layer


def _tints(a: PlantAsset) -> np.ndarray | None:
    """(L, 3) float32 per-leaf tint, or None when the asset has none (or a wrong count)."""
    t = getattr(a, "tints", None)
    if t is None:
        return None
    t = np.asarray(t, np.float32).reshape(-1, 3)
    return t if len(t) == a.n_leaves and np.isfinite(t).all() else None


def set_leaf_tint(mesh, tint) -> None:
    """Author one leaf Mesh's tint: ``primvars:leaffit:tint`` (read by the leaf materials) and
    ``primvars:displayColor`` (what viewers without our materials, e.g. Blender's colour
    attribute, show), both constant color3f, linear RGB."""
    from pxr import Gf, Sdf, UsdGeom

    c = Gf.Vec3f(*map(float, np.asarray(tint, np.float64).reshape(3)))
    pv = UsdGeom.PrimvarsAPI(mesh)
    pv.CreatePrimvar(TINT_PRIMVAR, Sdf.ValueTypeNames.Color3f, UsdGeom.Tokens.constant).Set(c)
    UsdGeom.Gprim(mesh.GetPrim()).CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([c])


def write_baked_layer(out: Path, a: PlantAsset, leaves: np.ndarray, lod_leaves: list | None = None) -> None:
    """The baked payload layer: one Mesh per leaf (asset frame), sharing topology/UVs/subsets
    through an inherited class. leaves : (L, V, 3) as :func:`write_stage` takes them.

    The class prim sits under the payload's root prim so the inherit arc is remapped when the
    payload is loaded; material bindings are authored by the main layer's 'baked' variant.
    """
    from pxr import Usd, UsdGeom

    leaves = _check_leaves(a, leaves)
    stage = Usd.Stage.CreateNew(str(out))
    _stage_units(stage, a)
    root = UsdGeom.Xform.Define(stage, "/BakedLeaves")
    stage.SetDefaultPrim(root.GetPrim())
    topo_path = f"/BakedLeaves/{_baked_topology(0)}"
    wind = wind_data(a)
    _author_baked_topology(stage, topo_path, a, single_sheet(a))
    _author_baked_leaves(stage, "/BakedLeaves", topo_path, leaves, a.leaf_labels, _tints(a), wind)
    # coarser levels of detail: one inactive group each (the main layer's LOD variant
    # deactivates the LOD0 leaves and activates its group)
    for k, lod in enumerate(a.lods if lod_leaves else [], start=1):
        la = a.at_lod(k)
        lv = _check_leaves(la, lod_leaves[k - 1]).astype(np.float32)
        tp = f"/BakedLeaves/{_baked_topology(k)}"
        _author_baked_topology(stage, tp, la, False)
        grp = UsdGeom.Xform.Define(stage, f"/BakedLeaves/LOD{k}")
        _author_baked_leaves(stage, f"/BakedLeaves/LOD{k}", tp, lv, a.leaf_labels, None, wind)
        grp.GetPrim().SetActive(False)
    stage.GetRootLayer().Save()


def _author_baked_topology(stage, path: str, a: PlantAsset, double_sided: bool) -> None:
    """The class prim ``path`` the baked leaves of one level inherit: faces, st, side subsets."""
    from pxr import Sdf, UsdGeom, Vt

    topo = stage.CreateClassPrim(path)
    topo.SetTypeName("Mesh")
    mesh = UsdGeom.Mesh(topo)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(double_sided)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(a.template_faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(a.template_faces, np.int32).ravel()))
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(a.template_uvs, np.float32)))
    # leaf flutter per vertex, the same for every leaf (it follows the template: usd.wind)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(WIND_FLUTTER, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy(template_flutter(a.template_points)))
    _bind_sides(stage, mesh, _face_sides(a), None)


def _author_baked_leaves(stage, parent: str, topo_path: str, leaves: np.ndarray, labels,
                         tints, wind) -> None:
    """``parent/leaf_0000`` ...: one Mesh per leaf inheriting ``topo_path``, with its points
    ((L, V, 3) ``leaves``), extent, label ((L,) ``labels``), if given tint ((L, 3)), and its
    wind (``usd.wind.WindData``: constant primvars pivot, axis, node, phase, bend)."""
    from pxr import Gf, Sdf, UsdGeom

    for j in range(len(leaves)):
        leaf = UsdGeom.Mesh.Define(stage, f"{parent}/leaf_{j:04d}")
        leaf.GetPrim().GetInherits().AddInherit(topo_path)
        leaf.CreatePointsAttr(vec3f_array(leaves[j]))
        leaf.CreateExtentAttr(extent(leaves[j]))
        leaf.GetPrim().SetCustomDataByKey("leaffit:leafLabel", int(labels[j]))
        if tints is not None:
            set_leaf_tint(leaf, tints[j])
        pv, c = UsdGeom.PrimvarsAPI(leaf), UsdGeom.Tokens.constant
        pv.CreatePrimvar(WIND_PIVOT, Sdf.ValueTypeNames.Point3f, c).Set(Gf.Vec3f(*map(float, wind.pivots[j])))
        pv.CreatePrimvar(WIND_AXIS, Sdf.ValueTypeNames.Vector3f, c).Set(Gf.Vec3f(*map(float, wind.axes[j])))
        pv.CreatePrimvar(WIND_NODE, Sdf.ValueTypeNames.Int, c).Set(int(wind.nodes[j]))
        pv.CreatePrimvar(WIND_PHASE, Sdf.ValueTypeNames.Float, c).Set(float(wind.phases[j]))
        pv.CreatePrimvar(WIND_BEND, Sdf.ValueTypeNames.Float, c).Set(float(wind.leaf_bend[j]))


# ----------------------------------------------------------------------------------------------
# usdz


def _package_usdz(pkg: Path, base: Path, files: list[str]) -> None:
    """Pack ``files`` (relative to base, the root layer first) into an uncompressed, aligned usdz."""
    from pxr import Sdf

    for rel in files:  # the zip entries carry the files' mtimes: fix them for byte-identical output
        os.utime(base / rel, (ZIP_EPOCH, ZIP_EPOCH))
    writer = Sdf.ZipFileWriter.CreateNew(str(pkg))
    for rel in files:
        writer.AddFile(str(base / rel), rel)
    writer.Save()
