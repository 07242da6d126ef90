"""The baked payload layer: one Mesh per leaf (asset frame) sharing topology, UVs and subsets
through an inherited class, with each leaf's tint and wind; the main layer's 'baked' variant
and LOD variants point at it (:mod:`leaffit_usd.usd.writer`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from leaffit_usd.usd.asset import PlantAsset
from leaffit_usd.usd.vt import extent, vec3f_array
from leaffit_usd.usd.materials import TINT_PRIMVAR, bind_sides
from leaffit_usd.usd.parts import (WIND_AXIS, WIND_BEND, WIND_FLUTTER, WIND_NODE, WIND_PHASE, WIND_PIVOT,
                                   check_leaves, face_sides, single_sheet, stage_units)
from leaffit_usd.usd.wind import template_flutter, wind_data


def write_baked_layer(out: Path, a: PlantAsset, leaves: np.ndarray, lod_leaves: list | None = None) -> None:
    """The baked payload layer: one Mesh per leaf (asset frame), sharing topology/UVs/subsets
    through an inherited class. leaves : (L, V, 3) as :func:`write_stage` takes them.

    The class prim sits under the payload's root prim so the inherit arc is remapped when the
    payload is loaded; material bindings are authored by the main layer's 'baked' variant.
    """
    from pxr import Usd, UsdGeom

    leaves = check_leaves(a, leaves)
    stage = Usd.Stage.CreateNew(str(out))
    stage_units(stage, a)
    root = UsdGeom.Xform.Define(stage, "/BakedLeaves")
    stage.SetDefaultPrim(root.GetPrim())
    topo_path = f"/BakedLeaves/{baked_topology(0)}"
    wind = wind_data(a)
    author_baked_topology(stage, topo_path, a, single_sheet(a))
    author_baked_leaves(stage, "/BakedLeaves", topo_path, leaves, a.leaf_labels, leaf_tints(a), wind)
    # coarser levels of detail: one inactive group each (the main layer's LOD variant
    # deactivates the LOD0 leaves and activates its group)
    for k, lod in enumerate(a.lods if lod_leaves else [], start=1):
        la = a.at_lod(k)
        lv = check_leaves(la, lod_leaves[k - 1]).astype(np.float32)
        tp = f"/BakedLeaves/{baked_topology(k)}"
        author_baked_topology(stage, tp, la, False)
        grp = UsdGeom.Xform.Define(stage, f"/BakedLeaves/LOD{k}")
        author_baked_leaves(stage, f"/BakedLeaves/LOD{k}", tp, lv, a.leaf_labels, None, wind)
        grp.GetPrim().SetActive(False)
    stage.GetRootLayer().Save()


def author_baked_topology(stage, path: str, a: PlantAsset, double_sided: bool) -> None:
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
    bind_sides(stage, mesh, face_sides(a), None)


def author_baked_leaves(stage, parent: str, topo_path: str, leaves: np.ndarray, labels,
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


def baked_topology(k: int) -> str:
    """Name of the class prim holding the baked leaves' shared topology at level of detail k."""
    return "LeafTopology" if k == 0 else f"LeafTopologyLOD{k}"


def set_leaf_tint(mesh, tint) -> None:
    """Author one leaf Mesh's tint: ``primvars:leaffit:tint`` (read by the leaf materials) and
    ``primvars:displayColor`` (what viewers without our materials, e.g. Blender's colour
    attribute, show), both constant color3f, linear RGB."""
    from pxr import Gf, Sdf, UsdGeom

    c = Gf.Vec3f(*map(float, np.asarray(tint, np.float64).reshape(3)))
    pv = UsdGeom.PrimvarsAPI(mesh)
    pv.CreatePrimvar(TINT_PRIMVAR, Sdf.ValueTypeNames.Color3f, UsdGeom.Tokens.constant).Set(c)
    UsdGeom.Gprim(mesh.GetPrim()).CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([c])


def leaf_tints(a: PlantAsset) -> np.ndarray | None:
    """(L, 3) float32 per-leaf tint, or None when the asset has none (or a wrong count)."""
    t = getattr(a, "tints", None)
    if t is None:
        return None
    t = np.asarray(t, np.float32).reshape(-1, 3)
    return t if len(t) == a.n_leaves and np.isfinite(t).all() else None
