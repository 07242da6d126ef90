"""Write evaluated leaves (``BakedLeaves``) to disk: the ``leaves.npz`` format below, or a
plain USD stage with one Mesh per leaf for tools that cannot run the deformer.

npz keys (all written by :func:`write_npz`; the first three are the contract):
    vertices         (L*V, 3) float32 (or float64), in ``frame``
    faces            (L*F, 3) int32, indices into ``vertices``
    leaf_vertex_ids  (L*V,) int32, instance index 0..L-1 of each vertex
    leaf_labels      (L,) int32, segmentation label of each instance
    normals          (L*V, 3) float32, area-weighted vertex normals of the deformed leaves
    uvs              (L*V, 2) float32, template texture coordinates (front/back sheets: ``side``)
    side             (L*V,) uint8, 0 = front-sheet vertex, 1 = back-sheet vertex
    stem_vertices    (P, 3), stem_faces (G, 3) int32, the stem mesh in ``frame`` (may be empty)
    frame            0-d str, "input" (the capture's frame) or "asset" (the USD stage's frame)
    sheet_offset     0-d float, front/back sheet separation applied (template units; 0 = coplanar)
The file is byte-deterministic (fixed zip timestamps).

baked USD layout (``write_baked_usd``)::

    /<Plant>            Xform, defaultPrim, kind = component, customData["leaffit"] (frame, source)
        Looks/LeafFront, LeafBack, Stem     UsdPreviewSurface (textures of the source stage)
        Leaves/leaf_0000 ...                Mesh per instance: points, normals, primvars:st,
                                            GeomSubsets front/back -> LeafFront/LeafBack,
                                            primvars:leaffit:leafLabel (constant)
        Stem                                Mesh
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from leaffit_usd.io_util import atomic_path
from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.runtime.evaluator import BakedLeaves

NPZ_FORMATS = (".npz",)
USD_FORMATS = (".usda", ".usdc", ".usd")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def npz_arrays(baked: BakedLeaves, template_uvs: np.ndarray, template_side: np.ndarray) -> dict:
    """The arrays of the npz file (see the module docstring), in writing order."""
    L = baked.n_leaves
    return {
        "vertices": baked.vertices,
        "faces": baked.faces.astype(np.int32),
        "leaf_vertex_ids": baked.leaf_vertex_ids.astype(np.int32),
        "leaf_labels": baked.leaf_labels.astype(np.int32),
        "normals": vertex_normals(baked.vertices, baked.faces).astype(np.float32),
        "uvs": np.tile(np.asarray(template_uvs, np.float32).reshape(-1, 2), (L, 1)),
        "side": np.tile(np.asarray(template_side, np.uint8).reshape(-1), L),
        "stem_vertices": baked.stem_vertices,
        "stem_faces": baked.stem_faces.astype(np.int32),
        "frame": np.array(baked.frame),
        "sheet_offset": np.array(float(baked.metadata.get("sheet_offset", 0.0))),
    }


def _default_mode(path) -> None:
    """Give a finished temporary file the mode a plain open() would (mkstemp makes it 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def write_npz(path, arrays: dict) -> None:
    """Write ``arrays`` as an .npz (np.load reads it), atomically and byte-deterministically."""
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
            for name, value in arrays.items():
                info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                with zf.open(info, "w", force_zip64=True) as fh:
                    np.lib.format.write_array(fh, np.asarray(value, order="C"), allow_pickle=False)
        _default_mode(tmp)


def _texture_path(texture: str, source: Path, out_dir: Path) -> str:
    """Re-express a texture path authored in ``source`` relative to ``out_dir``."""
    if not texture:
        return ""
    src = source.resolve()
    if src.suffix.lower() == ".usdz":      # a file inside the package: package-relative path
        inner = texture[2:] if texture.startswith("./") else texture
        return f"{os.path.relpath(src, out_dir.resolve())}[{inner}]"
    if os.path.isabs(texture):
        return texture
    full = (src.parent / texture).resolve()
    return "./" + os.path.relpath(full, out_dir.resolve()).replace(os.sep, "/")


def write_baked_usd(path, baked: BakedLeaves, asset, source=None, name: str | None = None) -> None:
    """One Mesh per leaf (+ the stem) as a plain USD stage (.usda/.usdc/.usd), atomically.

    asset : the PlantAsset ``baked`` was evaluated from (UVs, sides, textures, stage metadata)
    source : path of the stage it was read from (texture paths are re-expressed relative to
        ``path``); None keeps the texture paths as authored
    """
    from pxr import Tf, Usd, UsdGeom

    from leaffit_usd.usd.writer import STEM_COLOR, make_material

    path = Path(path)
    L = baked.n_leaves
    name = name or Tf.MakeValidIdentifier(path.stem) or "Plant"

    def tex(t):
        return _texture_path(t, Path(source), path.parent) if source is not None else t

    with atomic_path(path) as tmp:
        stage = Usd.Stage.CreateInMemory()
        root = _baked_root(stage, name, baked, asset.metadata or {}, source)
        looks = f"{root}/Looks"
        UsdGeom.Scope.Define(stage, looks)
        green = (0.1, 0.35, 0.08)
        tints = getattr(asset, "tints", None)
        tints = tints if tints is not None and len(tints) == L else None
        mats = [make_material(stage, f"{looks}/LeafFront", tex(asset.front_texture) or None, green,
                              tint=tints is not None),
                make_material(stage, f"{looks}/LeafBack", tex(asset.back_texture) or None, green,
                              tint=tints is not None)]
        stem_mat = make_material(stage, f"{looks}/Stem", None, STEM_COLOR)
        UsdGeom.Scope.Define(stage, f"{root}/Leaves")
        _write_leaf_meshes(stage, f"{root}/Leaves", baked, asset, mats, tints)
        if len(baked.stem_vertices) and len(baked.stem_faces):
            _write_stem_mesh(stage, f"{root}/Stem", baked, stem_mat)
        stage.GetRootLayer().documentation = (
            f"LeafFit plant baked to explicit meshes ({L} leaves, {baked.frame} frame) by "
            "leaffit-usd bake")
        stage.GetRootLayer().Export(str(tmp))
        _default_mode(tmp)


def _baked_root(stage, name: str, baked: BakedLeaves, md: dict, source) -> str:
    """Stage metadata (up axis, metres per unit: the asset's, or +Y / 1 for the capture's own
    frame) and the root Xform with its customData; returns the root's path."""
    from pxr import Kind, Usd, UsdGeom

    if baked.frame == "asset":
        up = str(md.get("up_axis", "Y")).upper()
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, float(md.get("meters_per_unit", 1.0)))
    else:   # the capture's own frame: no known up axis or unit
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = f"/{name}"
    plant = UsdGeom.Xform.Define(stage, root).GetPrim()
    stage.SetDefaultPrim(plant)
    Usd.ModelAPI(plant).SetKind(Kind.Tokens.component)
    plant.SetCustomDataByKey("leaffit", {
        "baked": True, "frame": baked.frame, "leafCount": int(baked.n_leaves),
        "sheetOffset": float(baked.metadata.get("sheet_offset", 0.0)),
        "source": str(source) if source is not None else "",
        "inputSha256": str(md.get("input_sha256", "")),
    })
    return root


def _write_leaf_meshes(stage, parent: str, baked: BakedLeaves, asset, mats, tints) -> None:
    """``parent/leaf_0000`` ...: one Mesh per leaf (points, normals, st, label, tint), its faces
    in front / back GeomSubsets bound to ``mats`` (front, back)."""
    from pxr import Sdf, UsdGeom, UsdShade, Vt

    from leaffit_usd.usd.writer import set_leaf_tint

    V = len(asset.template_points)
    faces_t = np.asarray(asset.template_faces, np.int32)
    face_side = (asset.template_side[faces_t].astype(np.int32).sum(1) >= 2) if len(faces_t) else \
        np.zeros(0, bool)
    uvs = Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(asset.template_uvs, np.float32).reshape(-1, 2))
    normals = vertex_normals(baked.vertices, baked.faces).astype(np.float32)
    counts = Vt.IntArray.FromNumpy(np.full(len(faces_t), 3, np.int32))
    subsets = [Vt.IntArray.FromNumpy(np.flatnonzero(face_side == s).astype(np.int32))
               for s in (0, 1)]
    F = len(faces_t)
    for j in range(baked.n_leaves):
        pts = np.asarray(baked.vertices[j * V:(j + 1) * V], np.float32)
        mesh = UsdGeom.Mesh.Define(stage, f"{parent}/leaf_{j:04d}")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateDoubleSidedAttr(False)
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
        mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(0), pts.max(0)])))
        mesh.CreateFaceVertexCountsAttr(counts)
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(
            np.ascontiguousarray(baked.faces[j * F:(j + 1) * F] - j * V, np.int32).ravel()))
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals[j * V:(j + 1) * V]))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        pv = UsdGeom.PrimvarsAPI(mesh)
        pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                         UsdGeom.Tokens.vertex).Set(uvs)
        pv.CreatePrimvar("leaffit:leafLabel", Sdf.ValueTypeNames.Int,
                         UsdGeom.Tokens.constant).Set(int(baked.leaf_labels[j]))
        if tints is not None:
            set_leaf_tint(mesh, tints[j])
        for s, (sub_name, mat) in enumerate(zip(("front", "back"), mats)):
            sub = UsdGeom.Subset.CreateGeomSubset(mesh, sub_name, UsdGeom.Tokens.face,
                                                  subsets[s], "materialBind",
                                                  UsdGeom.Tokens.nonOverlapping)
            UsdShade.MaterialBindingAPI.Apply(sub.GetPrim()).Bind(mat)
        UsdGeom.Subset.SetFamilyType(mesh, "materialBind", UsdGeom.Tokens.partition)


def _write_stem_mesh(stage, prim_path: str, baked: BakedLeaves, material) -> None:
    """The stem as one Mesh at ``prim_path``, bound to ``material``."""
    from pxr import UsdGeom, UsdShade, Vt

    sv = np.asarray(baked.stem_vertices, np.float32)
    stem = UsdGeom.Mesh.Define(stage, prim_path)
    stem.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    stem.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(sv))
    stem.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([sv.min(0), sv.max(0)])))
    stem.CreateFaceVertexCountsAttr(
        Vt.IntArray.FromNumpy(np.full(len(baked.stem_faces), 3, np.int32)))
    stem.CreateFaceVertexIndicesAttr(
        Vt.IntArray.FromNumpy(np.ascontiguousarray(baked.stem_faces, np.int32).ravel()))
    UsdShade.MaterialBindingAPI.Apply(stem.GetPrim()).Bind(material)


def read_baked_usd(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read back what :func:`write_baked_usd` wrote: (vertices (L*V, 3) float32,
    faces (L*F, 3) int32, leaf_vertex_ids (L*V,) int32), leaves in prim order."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    verts, faces, ids = [], [], []
    leaves = stage.GetPrimAtPath(root.GetPath().AppendChild("Leaves"))
    offset = 0
    for j, prim in enumerate(leaves.GetChildren() if leaves else []):
        mesh = UsdGeom.Mesh(prim)
        p = np.asarray(mesh.GetPointsAttr().Get(), np.float32).reshape(-1, 3)
        f = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int32).reshape(-1, 3)
        verts.append(p)
        faces.append(f + offset)
        ids.append(np.full(len(p), j, np.int32))
        offset += len(p)
    if not verts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.int32)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(ids)
