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

import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.usd import schema as S
from leaffit_usd.usd.asset import PlantAsset
from leaffit_usd.usd.vt import extent, quat_arrays, vec3f_array
from leaffit_usd.usd.baked import leaf_tints, set_leaf_tint, write_baked_layer  # noqa: F401 (API)
from leaffit_usd.usd.materials import (MASK_SUFFIX, STEM_COLOR, TINT_PRIMVAR,  # noqa: F401 (API)
                                       make_material, make_stem_material, mask_path)
from leaffit_usd.usd.parts import (author_pot, author_stem_wind, author_template_mesh, author_wind,
                                   check_leaves, set_stem_geometry, stage_units)
from leaffit_usd.usd.root_layer import write_root_layer
from leaffit_usd.usd.wind import wind_data

log = logging.getLogger("leaffit_usd")

FORMATS = (".usda", ".usdc", ".usd", ".usdz")
ZIP_EPOCH = 946728000   # 2000-01-01 12:00 UTC: fixed timestamps inside .usdz packages
#: "jpg+mask": colour as JPEG, the alpha cut-out as a grey PNG beside it (``mask_path``);
#: "jpg": colour only (the mesh outline is the leaf's outline); "png": one RGBA file
TEXTURE_FORMATS = ("jpg+mask", "jpg", "png")


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
    leaves = check_leaves(asset, leaves)

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
    write_root_layer(out, a, name, geom_rel, baked_rel, baked_lods, tmpl, variants_rel)
    del geo


def _write_geometry_layer(geom_out: Path, main_name: str, a: PlantAsset, leaves: np.ndarray,
                          name: str, front_tex: str, back_tex: str, has_alpha: str):
    """The payload layer ``geom_out``: /<name> with Looks, the Leaves instancer and the Stem.
    Returns (the open stage, the template leaf Mesh)."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(geom_out))
    stage_units(stage, a)
    root = f"/{name}"
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, root).GetPrim())
    tints = leaf_tints(a)

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
        set_stem_geometry(stem, a)
        author_stem_wind(stem, a, wind)
        UsdShade.MaterialBindingAPI.Apply(stem.GetPrim()).Bind(stem_mat)
        stem.GetPrim().SetCustomDataByKey("leaffit:role", "stem")
    if a.pot is not None:
        author_pot(stage, root, looks, a.pot)

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
    tmpl = author_template_mesh(stage, f"{inst_path}/Prototypes/TemplateLeaf", a, looks)
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
    author_wind(pv, wind)
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


def _attr(prim, name, type_name, value, uniform=False):
    from pxr import Sdf
    a = prim.CreateAttribute(name, type_name, custom=False,
                             variability=Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying)
    a.Set(value)
    return a


# ----------------------------------------------------------------------------------------------
# baked payload layer


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
