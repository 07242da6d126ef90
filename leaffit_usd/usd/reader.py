"""USD stage -> PlantAsset (the inverse of ``usd.writer``; layout in docs/usd_layout.md).

Works without the schema plug-in too: every deformer value is read from authored attributes
(by name), never from schema fallbacks. The geometry payload is loaded; the baked-leaves payload
is not composed (the 'deformer' variant is selected).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.geometry.quaternion import from_xyzw
from leaffit_usd.usd import schema as S
from leaffit_usd.usd.asset import PlantAsset, offset_sheets


def open_stage(path, load_payloads: bool = True):
    """Open a stage (payloads loaded: the plant's geometry is one; the 'baked' variant's payload
    is composed only when that variant is selected). Raises InputFileError."""
    from pxr import Tf, Usd

    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such file")
    try:
        stage = Usd.Stage.Open(str(p), Usd.Stage.LoadAll if load_payloads else Usd.Stage.LoadNone)
    except Tf.ErrorException as e:
        reason = re.findall(r"'([^']*)'\s*$", str(e).strip())
        raise InputFileError(p, "not a readable USD file" + (f" ({reason[-1]})" if reason else "")) from None
    if stage is None:
        raise InputFileError(p, "not a readable USD file")
    select_representation(stage, "deformer")
    select_variant(stage, "LOD", "LOD0")   # the full-detail geometry (LOD0 is the default)
    return stage


def select_variant(stage, set_name: str, name: str) -> None:
    """Select variant ``name`` of the default prim's variant set ``set_name`` in the stage's
    session layer (never saved); no-op when the set or the variant does not exist."""
    from pxr import Usd

    root = stage.GetDefaultPrim()
    if not root:
        return
    vset = root.GetVariantSets().GetVariantSet(set_name)
    if vset and vset.IsValid() and name in vset.GetVariantNames() and vset.GetVariantSelection() != name:
        with Usd.EditContext(stage, stage.GetSessionLayer()):
            vset.SetVariantSelection(name)


def select_representation(stage, name: str = "deformer") -> None:
    """Select variant ``name`` of leafRepresentation in the stage's session layer (never saved):
    the 'baked' variant deactivates the PointInstancer, so readers look at 'deformer'."""
    from pxr import Usd

    root = stage.GetDefaultPrim()
    if not root:
        return
    vset = root.GetVariantSets().GetVariantSet("leafRepresentation")
    if vset and vset.IsValid() and name in vset.GetVariantNames() and vset.GetVariantSelection() != name:
        with Usd.EditContext(stage, stage.GetSessionLayer()):
            vset.SetVariantSelection(name)


def find_instancer(stage):
    """The LeafFit PointInstancer prim: the one carrying the deformer's control points."""
    from pxr import Usd, UsdGeom

    root = stage.GetDefaultPrim()
    candidates = []
    for prim in Usd.PrimRange(root if root else stage.GetPseudoRoot()):
        if prim.IsA(UsdGeom.PointInstancer) and prim.HasAttribute(S.ATTR_CONTROLS):
            candidates.append(prim)
    return candidates[0] if candidates else None


def _np(value, dtype, shape_tail=()):
    if value is None:
        return np.zeros((0, *shape_tail), dtype)
    a = np.asarray(value, dtype)
    return a.reshape(-1, *shape_tail) if shape_tail else a.reshape(-1)


def _get(prim, name, default=None):
    a = prim.GetAttribute(name)
    if not a or not a.HasAuthoredValue():
        return default
    return a.Get()


def read_stage(path) -> PlantAsset:
    """Read a LeafFit stage (.usda/.usdc/.usdz) into a PlantAsset (asset frame).

    Raises InputFileError if the file is unreadable or not a LeafFit plant.
    """
    return read_stage_object(open_stage(path), path)


def read_stage_object(stage, path="<stage>") -> PlantAsset:
    """Like :func:`read_stage` for an already opened ``pxr.Usd.Stage`` (edits included)."""
    from pxr import UsdGeom

    inst_prim = find_instancer(stage)
    if inst_prim is None:
        raise InputFileError(path, "not a LeafFit plant (no PointInstancer with "
                                   f"{S.ATTR_CONTROLS})")
    inst = UsdGeom.PointInstancer(inst_prim)
    rel = inst_prim.GetRelationship(S.ATTR_TEMPLATE_REL)
    targets = rel.GetTargets() if rel else []
    if not targets:
        targets = inst.GetPrototypesRel().GetTargets()
    if not targets:
        raise InputFileError(path, f"{inst_prim.GetPath()}: no template mesh")
    tmpl_prim = stage.GetPrimAtPath(targets[0])
    mesh = UsdGeom.Mesh(tmpl_prim)
    if not tmpl_prim or not tmpl_prim.IsA(UsdGeom.Mesh):
        raise InputFileError(path, f"{targets[0]}: the template is not a Mesh")

    points = _np(mesh.GetPointsAttr().Get(), np.float32, (3,))
    counts = _np(mesh.GetFaceVertexCountsAttr().Get(), np.int32)
    if counts.size and not np.all(counts == 3):
        raise InputFileError(path, f"{tmpl_prim.GetPath()}: template faces must be triangles")
    faces = _np(mesh.GetFaceVertexIndicesAttr().Get(), np.int32, (3,))
    normals = _np(mesh.GetNormalsAttr().Get(), np.float32, (3,))
    pv = UsdGeom.PrimvarsAPI(tmpl_prim)
    st = pv.GetPrimvar("st")
    uvs = _np(st.Get() if st else None, np.float32, (2,))
    side_pv = pv.GetPrimvar("leaffit:side")
    side = _np(side_pv.Get() if side_pv else None, np.int32).astype(np.uint8)
    if len(side) != len(points):
        side = np.zeros(len(points), np.uint8)

    # the prototype's points are drawn with the sheets pushed apart by sheetOffset; the MLS rest
    # points (PlantAsset.template_points) are the coplanar sheets: undo the push
    off = float(_get(inst_prim, S.ATTR_SHEET_OFFSET, 0.0) or 0.0)
    if off > 0 and len(normals) == len(points):
        points = offset_sheets(points, normals, -off)
    controls = _np(_get(inst_prim, S.ATTR_CONTROLS), np.float32, (3,))
    K = int(_get(inst_prim, S.ATTR_K, len(controls)))
    primvar_name = str(_get(inst_prim, S.ATTR_TARGETS_PRIMVAR, S.TARGETS_PRIMVAR))
    tg = inst_prim.GetAttribute(primvar_name)
    tq = _np(tg.Get() if tg else None, np.float32, (3,))
    pos = _np(inst.GetPositionsAttr().Get(), np.float32, (3,))
    L = len(pos)
    if K <= 0 or len(controls) != K or len(tq) != L * K:
        raise InputFileError(path, f"{inst_prim.GetPath()}: expected {L} x {K} target control "
                                   f"points in {primvar_name}, found {len(tq)}")
    qf = inst.GetOrientationsfAttr().Get() if inst.GetOrientationsfAttr().HasAuthoredValue() else None
    q = qf if qf is not None and len(qf) == L else inst.GetOrientationsAttr().Get()
    xyzw = _np(q, np.float32, (4,)) if q is not None and len(q) else np.tile([0, 0, 0, 1], (L, 1))
    orient = from_xyzw(np.asarray(xyzw, np.float32))
    scales_v = inst.GetScalesAttr().Get()
    scales = _np(scales_v, np.float32, (3,)) if scales_v is not None and len(scales_v) else np.ones((L, 3), np.float32)
    lab_pv = UsdGeom.PrimvarsAPI(inst_prim).GetPrimvar("leaffit:leafLabel")
    labels = _np(lab_pv.Get() if lab_pv else None, np.int32)
    if len(labels) != L:
        ids = inst.GetIdsAttr().Get()
        labels = np.asarray(ids, np.int32) if ids is not None and len(ids) == L else np.arange(1, L + 1, dtype=np.int32)

    tint_pv = UsdGeom.PrimvarsAPI(inst_prim).GetPrimvar("leaffit:tint")
    tint_v = tint_pv.Get() if tint_pv and tint_pv.HasAuthoredValue() else None
    tints = _np(tint_v, np.float32, (3,)) if tint_v is not None else None
    if tints is not None and len(tints) != L:
        tints = None

    root = stage.GetDefaultPrim() or inst_prim.GetParent()
    stem_pts, stem_faces = _read_stem(root)
    metadata, asset_to_input = _read_metadata(stage, root)
    front_tex, back_tex = _template_textures(mesh)

    return PlantAsset(
        template_points=points, template_faces=faces, template_normals=normals,
        template_uvs=uvs, template_side=side, template_controls=controls,
        targets=tq.reshape(L, K, 3), positions=pos, orientations=orient, scales=scales,
        leaf_labels=labels,
        sigma=float(_get(inst_prim, S.ATTR_SIGMA, 0.1)), reg=float(_get(inst_prim, S.ATTR_REG, 0.01)),
        stem_points=stem_pts, stem_faces=stem_faces, asset_to_input=asset_to_input,
        front_texture=front_tex, back_texture=back_tex, metadata=metadata,
        tints=tints, stem_colors=_stem_colors(root, len(stem_pts)), lods=_read_lods(stage, tmpl_prim, root, off),
        **_skeleton(root), pot=_read_pot(root),
    )


def _read_pot(root):
    """The ``Pot`` and ``Soil`` Meshes (``convert --pot``) as a ``mesh.pot.PotMesh`` (asset
    frame, sRGB vertex colours), or None."""
    from pxr import UsdGeom

    from leaffit_usd.mesh.pot import PotMesh

    parts = {}
    for name in ("Pot", "Soil"):
        prim = root.GetChild(name) if root else None
        if not prim or not prim.IsA(UsdGeom.Mesh):
            parts[name] = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros((0, 3), np.float32))
            continue
        m = UsdGeom.Mesh(prim)
        pts = _np(m.GetPointsAttr().Get(), np.float32, (3,))
        faces = _np(m.GetFaceVertexIndicesAttr().Get(), np.int32, (3,))
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        lin = np.clip(np.asarray(pv.Get(), np.float64).reshape(-1, 3), 0, 1) if pv and pv.HasValue() \
            else np.full((len(pts), 3), 0.5)
        srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055).astype(np.float32)
        parts[name] = (pts, faces, srgb)
    if not len(parts["Pot"][0]):
        return None
    return PotMesh(*parts["Pot"], *parts["Soil"])


def _skeleton(root) -> dict:
    """The stem skeleton (``skeleton_points`` (S, 3) float32, ``skeleton_parents`` (S,) int32)
    from the Stem's constant primvars, or Nones (a stage without wind data)."""
    from pxr import UsdGeom

    prim = root.GetChild("Stem") if root else None
    out = {"skeleton_points": None, "skeleton_parents": None}
    if not prim:
        return out
    pv = UsdGeom.PrimvarsAPI(prim)
    pts, par = pv.GetPrimvar("leaffit:skeletonPoints"), pv.GetPrimvar("leaffit:skeletonParents")
    if pts and par and pts.HasValue() and par.HasValue():
        p, q = _np(pts.Get(), np.float32, (3,)), np.asarray(par.Get(), np.int32)
        if len(p) == len(q):
            out.update(skeleton_points=p, skeleton_parents=q)
    return out


def _read_stem(root) -> tuple[np.ndarray, np.ndarray]:
    """The stem Mesh under the plant: (P, 3) float32 points, (G, 3) int32 faces (empty if none)."""
    from pxr import UsdGeom

    stem_pts, stem_faces = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    for child in root.GetChildren():
        if child.IsA(UsdGeom.Mesh) and (child.GetCustomDataByKey("leaffit:role") == "stem"
                                        or child.GetName() == "Stem"):
            sm = UsdGeom.Mesh(child)
            stem_pts = _np(sm.GetPointsAttr().Get(), np.float32, (3,))
            stem_faces = _np(sm.GetFaceVertexIndicesAttr().Get(), np.int32, (3,))
            break
    return stem_pts, stem_faces


def _read_metadata(stage, root) -> tuple[dict, np.ndarray]:
    """(metadata dict, (4, 4) asset_to_input) from the plant's customData['leaffit']."""
    from pxr import UsdGeom

    cd = root.GetCustomDataByKey("leaffit") or {}
    metadata = {}
    if "metadataJson" in cd:
        try:
            metadata = json.loads(cd["metadataJson"])
        except ValueError:
            metadata = {}
    m = cd.get("assetToInput")
    asset_to_input = np.asarray(m, np.float64).T.copy() if m is not None else np.eye(4)
    if not metadata:
        metadata = {"tool_version": cd.get("toolVersion", ""), "input_sha256": cd.get("inputSha256", "")}
    metadata.setdefault("up_axis", str(UsdGeom.GetStageUpAxis(stage)))
    metadata.setdefault("meters_per_unit", float(UsdGeom.GetStageMetersPerUnit(stage)))
    return metadata, asset_to_input


def _template_textures(mesh) -> tuple[str, str]:
    """(front, back) texture paths as authored on the materials bound to the face subsets."""
    from pxr import UsdGeom, UsdShade

    front_tex = back_tex = ""
    for subset in UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "materialBind"):
        mat, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
        tex = _material_texture(mat) if mat else ""
        if subset.GetPrim().GetName() == "front":
            front_tex = tex
        elif subset.GetPrim().GetName() == "back":
            back_tex = tex
    return front_tex, back_tex


def _stem_colors(root, n: int):
    """(n, 3) float32 sRGB stem vertex colours from the Stem's displayColor (linear), or None."""
    from pxr import UsdGeom

    prim = root.GetChild("Stem") if root else None
    if not prim or not n:
        return None
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if not pv or not pv.HasValue():
        return None
    lin = np.clip(np.asarray(pv.Get(), np.float64).reshape(-1, 3), 0, 1)
    if len(lin) != n:
        return None
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055).astype(np.float32)


def _read_lods(stage, tmpl_prim, root, sheet_offset: float) -> list:
    """The coarser levels of detail of the ``LOD`` variant set (LOD1, LOD2, ...) as AssetLODs,
    each read with that variant selected in the session layer (the file is not touched)."""
    from pxr import UsdGeom

    from leaffit_usd.usd.asset import AssetLOD

    if not root or not root.GetVariantSets().HasVariantSet("LOD"):
        return []
    vset = root.GetVariantSets().GetVariantSet("LOD")
    names = sorted((n for n in vset.GetVariantNames() if n.startswith("LOD") and n[3:].isdigit()
                    and int(n[3:]) > 0), key=lambda n: int(n[3:]))
    original = vset.GetVariantSelection()
    out = []
    try:
        for nm in names:
            select_variant(stage, "LOD", nm)
            mesh = UsdGeom.Mesh(tmpl_prim)
            pts = _np(mesh.GetPointsAttr().Get(), np.float32, (3,))
            nrm = _np(mesh.GetNormalsAttr().Get(), np.float32, (3,))
            if sheet_offset > 0 and len(nrm) == len(pts):
                pts = offset_sheets(pts, nrm, -sheet_offset)
            pv = UsdGeom.PrimvarsAPI(tmpl_prim)
            st, sd = pv.GetPrimvar("st"), pv.GetPrimvar("leaffit:side")
            side = _np(sd.Get() if sd else None, np.int32).astype(np.uint8)
            stem = root.GetChild("Stem")
            sp = _np(UsdGeom.Mesh(stem).GetPointsAttr().Get(), np.float32, (3,)) if stem else np.zeros((0, 3), np.float32)
            sf = _np(UsdGeom.Mesh(stem).GetFaceVertexIndicesAttr().Get(), np.int32, (3,)) if stem else np.zeros((0, 3), np.int32)
            out.append(AssetLOD(template_points=pts,
                                template_faces=_np(mesh.GetFaceVertexIndicesAttr().Get(), np.int32, (3,)),
                                template_normals=nrm, template_uvs=_np(st.Get() if st else None, np.float32, (2,)),
                                template_side=side if len(side) == len(pts) else np.zeros(len(pts), np.uint8),
                                stem_points=sp, stem_faces=sf, stem_colors=_stem_colors(root, len(sp))))
    finally:
        select_variant(stage, "LOD", original or "LOD0")
    return out


def _material_texture(material) -> str:
    """The authored file path of the UsdUVTexture feeding the material's diffuseColor ('' if none)."""
    from pxr import Usd, UsdShade

    for prim in Usd.PrimRange(material.GetPrim()):
        shader = UsdShade.Shader(prim)
        if shader and shader.GetIdAttr().Get() == "UsdUVTexture":
            f = shader.GetInput("file")
            v = f.Get() if f else None
            return v.path if v is not None else ""
    return ""


def read_texture(stage, asset_path: str) -> np.ndarray | None:
    """Decode a texture referenced by the stage (also inside a .usdz) -> (H, W, 4) uint8 RGBA
    (straight alpha, ``image_io.read_image_u8``), or None when it cannot be resolved or read.
    A ``jpg+mask`` texture's alpha is its mask file (``usd.writer.mask_path``)."""
    from leaffit_usd.usd.writer import mask_path

    img = _read_image_asset(stage, asset_path)
    if img is None or asset_path.endswith(".png"):
        return img
    mask = _read_image_asset(stage, mask_path(asset_path))
    if mask is not None and mask.shape[:2] == img.shape[:2]:
        img = img.copy()
        img[..., 3] = mask[..., 0]
    return img


def has_mask(stage, asset_path: str) -> bool:
    """Whether the texture ``asset_path`` has a ``jpg+mask`` alpha mask beside it."""
    from pxr import Ar

    from leaffit_usd.usd.writer import mask_path

    if not asset_path or asset_path.endswith(".png"):
        return False
    layer = stage.GetRootLayer()
    return bool(Ar.GetResolver().Resolve(layer.ComputeAbsolutePath(mask_path(asset_path))))


def _read_image_asset(stage, asset_path: str) -> np.ndarray | None:
    """(H, W, 4) uint8 of an image the stage refers to (resolved, also inside a .usdz), or None."""
    import os
    import tempfile

    from pxr import Ar

    from leaffit_usd.image_io import ImageError, read_image_u8

    if not asset_path:
        return None
    layer = stage.GetRootLayer()
    resolved = Ar.GetResolver().Resolve(layer.ComputeAbsolutePath(asset_path))
    if not resolved:
        return None
    asset = Ar.GetResolver().OpenAsset(resolved)
    if asset is None:
        return None
    data = bytes(asset.GetBuffer())
    suffix = Path(asset_path).suffix
    fd, tmp = tempfile.mkstemp(suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        try:
            img = read_image_u8(tmp)
        except ImageError:
            return None
        return None if img.size == 0 else img
    finally:
        os.unlink(tmp)
