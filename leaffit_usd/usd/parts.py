"""The prims of a plant stage, authored one by one (:mod:`leaffit_usd.usd.writer` assembles
them): the template leaf Mesh, the stem Mesh with its wind bend and skeleton, the pot and soil
Meshes, the leaves' wind primvars; the stage's units; the explicit leaves' checks."""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.usd.asset import PlantAsset
from leaffit_usd.usd.vt import extent, vec3f_array
from leaffit_usd.usd.materials import bind_sides, srgb_to_linear, vertex_colour_material

# wind (usd.wind): per instance on the PointInstancer, per vertex on the stem
WIND_PIVOT, WIND_AXIS = "leaffit:windPivot", "leaffit:windAxis"
WIND_NODE, WIND_PHASE, WIND_BEND = "leaffit:windNode", "leaffit:windPhase", "leaffit:windBend"
WIND_FLUTTER = "leaffit:windFlutter"   # per vertex, baked leaves


def author_pot(stage, root: str, looks: str, pot) -> None:
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
        lin = srgb_to_linear(np.asarray(cols))
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                UsdGeom.Tokens.vertex).Set(vec3f_array(lin))
        mat = vertex_colour_material(stage, f"{looks}/{name}", tuple(float(x) for x in lin.mean(0)), True)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        mesh.GetPrim().SetCustomDataByKey("leaffit:role", name.lower())


def author_wind(pv, w) -> None:
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


def author_stem_wind(mesh, a: PlantAsset, w) -> None:
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


def set_stem_geometry(mesh, a: PlantAsset) -> None:
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
        dc.Set(vec3f_array(srgb_to_linear(a.stem_colors)))


def author_template_mesh(stage, path: str, a: PlantAsset, looks: str):
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(single_sheet(a))
    set_template_geometry(mesh, a)
    bind_sides(stage, mesh, face_sides(a), looks)
    mesh.GetPrim().SetCustomDataByKey("leaffit:role", "template")
    return mesh


def set_template_geometry(mesh, a) -> None:
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


def face_sides(a: PlantAsset) -> np.ndarray:
    """(F,) uint8 side of every template face (majority of its vertices)."""
    return (a.template_side[a.template_faces].astype(np.int32).sum(1) >= 2).astype(np.uint8)


def single_sheet(a: PlantAsset) -> bool:
    """True when the template has faces on one side only: that sheet must be drawn doubleSided."""
    sides = np.unique(face_sides(a)) if len(a.template_faces) else np.zeros(0)
    return len(sides) < 2


def check_leaves(a: PlantAsset, leaves) -> np.ndarray:
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


def stage_units(stage, a: PlantAsset) -> None:
    from pxr import UsdGeom

    up = str(a.metadata.get("up_axis", "Y")).upper()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(a.metadata.get("meters_per_unit", 1.0)))
