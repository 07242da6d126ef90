"""The root layer of a plant stage: the asset's interface only (the plant prim with its kind,
assetInfo, provenance in customData, the payload of the geometry layer) and its variant sets,
``leafRepresentation`` (deformer | baked) and ``LOD``, which the writer may put in a crate
sublayer. Used by :mod:`leaffit_usd.usd.writer`."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from leaffit_usd.usd.asset import PlantAsset
from leaffit_usd.usd.baked import baked_topology
from leaffit_usd.usd.parts import face_sides, set_stem_geometry, set_template_geometry, stage_units
from leaffit_usd.usd.vt import matrix4d
from leaffit_usd.version import __version__


def write_root_layer(out: Path, a: PlantAsset, name: str, geom_rel: str, baked_rel: str | None,
                      baked_lods: bool, tmpl, variants_rel: str | None = None) -> None:
    """The root layer ``out``: the asset's interface; the geometry arrives through the payload
    ``geom_rel``; the leafRepresentation and LOD variant sets. tmpl : the template leaf Mesh of
    the geometry layer. variants_rel : author the variant sets in this crate sublayer (beside
    ``out``) instead of the root layer: a .usda root stays a small, readable text file."""
    from pxr import Kind, Sdf, Usd, UsdGeom

    root = f"/{name}"
    stage = Usd.Stage.CreateNew(str(out))
    stage_units(stage, a)
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
            topo = stage.OverridePrim(f"{root}/BakedLeaves/{baked_topology(k)}")
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
                set_template_geometry(mesh, la)
                sides = face_sides(la)
                for side, nm in ((0, "front"), (1, "back")):
                    sub = UsdGeom.Subset(stage.OverridePrim(tmpl.GetPath().AppendChild(nm)))
                    sub.CreateIndicesAttr(Vt.IntArray.FromNumpy(np.flatnonzero(sides == side).astype(np.int32)))
                if len(a.stem_points) and len(la.stem_points):
                    set_stem_geometry(UsdGeom.Mesh(stage.OverridePrim(f"{root}/Stem")), la)
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
