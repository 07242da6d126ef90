"""Validate a LeafFit stage: USD's own validators (pxr.UsdValidation, every registered one) plus
our checks of the layout (docs/usd_layout.md), in the manner of usdchecker.

Every finding carries a severity (``error`` > ``warning`` > ``info``), a rule name (``usd:<USD
validator name>`` or ``leaffit:<rule>``), the prim/property path (or layer) it is about, and a
message. A file *fails* when it has at least one error (``strict``: or a warning).

USD's validators run once per variant of ``leafRepresentation`` (deformer, baked), with payloads
loaded, so the baked geometry is checked too.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from leaffit_usd.usd import schema as S

SEVERITIES = ("error", "warning", "info")


@dataclass(frozen=True)
class Finding:
    """One problem. severity : error | warning | info; rule : 'usd:...' or 'leaffit:...'."""

    severity: str
    rule: str
    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.severity.upper():7s} {self.rule}  {self.path or '-'}: {self.message}"


@dataclass
class ValidationReport:
    """All findings for one file."""

    file: str
    findings: list = field(default_factory=list)

    def count(self, severity: str) -> int:
        return sum(f.severity == severity for f in self.findings)

    def failed(self, strict: bool = False) -> bool:
        return self.count("error") > 0 or (strict and self.count("warning") > 0)

    def to_dict(self) -> dict:
        return {"file": self.file, "errors": self.count("error"), "warnings": self.count("warning"),
                "findings": [asdict(f) for f in self.findings]}


def validate_file(path, run_usd: bool = True, run_layout: bool = True) -> ValidationReport:
    """Validate the stage at ``path``. Raises InputFileError if it cannot be opened at all."""
    from leaffit_usd.usd.reader import open_stage

    report = ValidationReport(file=str(path))
    stage = open_stage(path, load_payloads=True)
    if run_usd:
        report.findings += usd_validation(stage)
    if run_layout:
        report.findings += layout_findings(stage)
    # de-duplicate (the same USD finding can come from both variants), keep order
    seen, unique = set(), []
    for f in report.findings:
        if f not in seen:
            seen.add(f)
            unique.append(f)
    report.findings = unique
    return report


# ----------------------------------------------------------------------------------------------
# USD's validation framework


def usd_validation(stage) -> list[Finding]:
    """Run every registered pxr.UsdValidation validator, once per leafRepresentation variant."""
    from pxr import UsdValidation

    reg = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators())
    out = _usd_errors(ctx.Validate(stage))
    from leaffit_usd.usd.reader import select_representation, select_variant

    root = stage.GetDefaultPrim()
    vset = root.GetVariantSets().GetVariantSet("leafRepresentation") if root else None
    lods = root.GetVariantSets().GetVariantSet("LOD") if root else None
    sets = root.GetVariantSets() if root else None
    reps = (vset.GetVariantNames() if sets and sets.HasVariantSet("leafRepresentation") else []) or [None]
    levels = (lods.GetVariantNames() if sets and sets.HasVariantSet("LOD") else []) or [None]
    if len(reps) * len(levels) > 1:
        orig_rep = vset.GetVariantSelection() if reps != [None] else None
        orig_lod = lods.GetVariantSelection() if levels != [None] else None
        try:
            for rep in reps:
                for lod in levels:
                    if (rep, lod) == (orig_rep, orig_lod):
                        continue
                    # session layer: the file is not touched
                    if rep is not None:
                        select_representation(stage, rep)
                    if lod is not None:
                        select_variant(stage, "LOD", lod)
                    tag = ", ".join(x for x in (rep, lod) if x)
                    out += [Finding(f.severity, f.rule, f.path, f"{f.message} [variant {tag}]")
                            for f in _usd_errors(ctx.Validate(stage))]
        finally:
            if orig_rep is not None:
                select_representation(stage, orig_rep)
            if orig_lod is not None:
                select_variant(stage, "LOD", orig_lod)
    return out


def _usd_errors(errors) -> list[Finding]:
    from pxr import UsdValidation

    sev = {UsdValidation.ValidationErrorType.Error: "error",
           UsdValidation.ValidationErrorType.Warn: "warning",
           UsdValidation.ValidationErrorType.Info: "info"}
    out = []
    for e in errors:
        if e.HasNoError():
            continue
        v = e.GetValidator()
        name = v.GetMetadata().name if v else e.GetName()
        sites = []
        for s in e.GetSites():
            if s.IsPrim():
                sites.append(str(s.GetPrim().GetPath()))
            elif s.IsProperty():
                sites.append(str(s.GetProperty().GetPath()))
            elif s.GetLayer():
                sites.append(s.GetLayer().identifier)
        out.append(Finding(sev.get(e.GetType(), "info"), f"usd:{name}", ", ".join(sites),
                           " ".join(e.GetMessage().split())))
    return out


# ----------------------------------------------------------------------------------------------
# our layout rules


def layout_findings(stage) -> list[Finding]:
    """Check the LeafFit layout (see docs/usd_layout.md). Each rule is named ``leaffit:<rule>``."""
    from leaffit_usd.usd.reader import find_instancer

    out: list[Finding] = []

    def add(sev, rule, path, msg):
        out.append(Finding(sev, f"leaffit:{rule}", str(path), msg))

    root = _check_plant(stage, add)
    if root is None:
        return out
    inst_prim = find_instancer(stage)
    if inst_prim is None:
        add("error", "Instancer", root.GetPath(), "no PointInstancer with authored "
            f"{S.ATTR_CONTROLS} under the plant")
        return out
    meshes, L = _check_instancer(stage, inst_prim, add)
    K = _check_deformer(inst_prim, add)
    _check_targets(inst_prim, L, K, add)
    if meshes:
        _check_template_mesh(stage, root, meshes[0], add)
    _check_stem(root, add)
    _check_baked(stage, root, L, add)
    return out


def _check_plant(stage, add):
    """The plant prim (defaultPrim, kind, units, provenance); returns it, or None."""
    from pxr import Kind, Usd

    root = stage.GetDefaultPrim()
    if not root:
        add("error", "DefaultPrim", "/", "the stage has no defaultPrim (the plant)")
        return None
    if Usd.ModelAPI(root).GetKind() != Kind.Tokens.component:
        add("error", "PlantKind", root.GetPath(), f"the plant prim's kind is "
            f"'{Usd.ModelAPI(root).GetKind()}', expected 'component'")
    layer = stage.GetRootLayer()
    if not layer.pseudoRoot.HasInfo("upAxis") or not layer.pseudoRoot.HasInfo("metersPerUnit"):
        add("error", "StageUnits", layer.identifier, "upAxis and metersPerUnit must both be authored")
    cd = root.GetCustomDataByKey("leaffit")
    if not cd:
        add("warning", "Provenance", root.GetPath(), "no customData['leaffit'] (parameters, input "
            "hash, transform back to the input frame, tool version)")
    else:
        for key in ("toolVersion", "inputSha256", "assetToInput", "params"):
            if key not in cd:
                add("warning", "Provenance", root.GetPath(), f"customData['leaffit'] lacks '{key}'")
    return root


def _check_instancer(stage, inst_prim, add) -> tuple[list, int]:
    """The PointInstancer and its ONE template prototype: (Mesh prototype paths, L instances)."""
    from pxr import Usd, UsdGeom

    ip = inst_prim.GetPath()
    inst = UsdGeom.PointInstancer(inst_prim)
    if not inst_prim.HasAPI(S.API_NAME):
        add("warning", "DeformerAPI", ip, f"{S.API_NAME} is not applied")

    # the ONE template prototype
    protos = inst.GetPrototypesRel().GetTargets()
    meshes = [p for p in protos if stage.GetPrimAtPath(p) and stage.GetPrimAtPath(p).IsA(UsdGeom.Mesh)]
    if len(protos) != 1 or len(meshes) != 1:
        add("error", "OneTemplate", ip, f"expected exactly one Mesh prototype, found {len(protos)} "
            f"prototypes ({len(meshes)} Mesh)")
    rel = inst_prim.GetRelationship(S.ATTR_TEMPLATE_REL)
    tmpl_targets = rel.GetTargets() if rel else []
    if protos and tmpl_targets and tmpl_targets[0] != protos[0]:
        add("error", "OneTemplate", ip, f"{S.ATTR_TEMPLATE_REL} targets {tmpl_targets[0]}, "
            f"the prototype is {protos[0]}")
    n_template_meshes = sum(1 for p in Usd.PrimRange(inst_prim) if p.IsA(UsdGeom.Mesh))
    if n_template_meshes != 1:
        add("error", "OneTemplate", ip, f"{n_template_meshes} Mesh prims under the instancer, expected 1")

    positions = inst.GetPositionsAttr().Get()
    L = len(positions) if positions is not None else 0
    idx = inst.GetProtoIndicesAttr().Get()
    if idx is None or len(idx) != L or (L and np.any(np.asarray(idx) != 0)):
        add("error", "InstanceArrays", ip, f"protoIndices must be {L} zeros")
    for name, attr in (("orientations", inst.GetOrientationsAttr()), ("scales", inst.GetScalesAttr())):
        v = attr.Get()
        if v is None or len(v) != L:
            add("error", "InstanceArrays", attr.GetPath(), f"expected {L} values, found "
                f"{0 if v is None else len(v)}")
    if inst.GetOrientationsAttr().GetTypeName().type.typeName != "VtArray<GfQuath>":
        add("warning", "Orientations", inst.GetOrientationsAttr().GetPath(), "orientations should be quath[]")
    qf = inst.GetOrientationsfAttr()
    q = qf.Get() if qf.HasAuthoredValue() else inst.GetOrientationsAttr().Get()
    if q is not None and len(q):
        qn = np.linalg.norm(np.asarray(q, np.float64), axis=1)
        if np.any(np.abs(qn - 1) > 1e-2):
            add("warning", "Orientations", ip, f"{int((np.abs(qn - 1) > 1e-2).sum())} orientations are not unit quaternions")

    return meshes, L


def _check_deformer(inst_prim, add) -> int:
    """The deformer's values (K, sigma, reg ...); returns K, the template's control points."""
    ip = inst_prim.GetPath()
    controls = inst_prim.GetAttribute(S.ATTR_CONTROLS).Get()
    K_auth = inst_prim.GetAttribute(S.ATTR_K)
    K = len(controls) if controls is not None else 0
    if not K_auth or not K_auth.HasAuthoredValue():
        add("warning", "DeformerValues", ip, f"{S.ATTR_K} is not authored (readers without the plug-in need it)")
    elif K_auth.Get() != K:
        add("error", "DeformerValues", K_auth.GetPath(), f"K = {K_auth.Get()} but {K} template control points")
    for name in (S.ATTR_SIGMA, S.ATTR_REG, S.ATTR_VARIANT, S.ATTR_KERNEL, S.ATTR_TARGETS_PRIMVAR):
        a = inst_prim.GetAttribute(name)
        if not a or not a.HasAuthoredValue():
            add("warning", "DeformerValues", ip, f"{name} is not authored (readers without the plug-in "
                "would see only a fallback)")
    for name in (S.ATTR_SIGMA, S.ATTR_REG):
        a = inst_prim.GetAttribute(name)
        if a and a.Get() is not None and not (np.isfinite(a.Get()) and a.Get() > 0):
            add("error", "DeformerValues", a.GetPath(), f"must be positive, is {a.Get()}")

    return K


def _check_targets(inst_prim, L: int, K: int, add) -> None:
    """The per-instance targets primvar: float3[], vertex, elementSize K, L x K finite values."""
    from pxr import UsdGeom

    ip = inst_prim.GetPath()
    pv_name = inst_prim.GetAttribute(S.ATTR_TARGETS_PRIMVAR)
    pv_name = str(pv_name.Get()) if pv_name and pv_name.Get() else S.TARGETS_PRIMVAR
    pv = UsdGeom.Primvar(inst_prim.GetAttribute(pv_name))
    if not pv or not pv.GetAttr().IsValid():
        add("error", "TargetsPrimvar", ip, f"no {pv_name} primvar")
    else:
        tv = pv.Get()
        if pv.GetTypeName() != "float3[]":
            add("error", "TargetsPrimvar", pv.GetAttr().GetPath(), f"type {pv.GetTypeName()}, expected float3[]")
        if pv.GetInterpolation() != UsdGeom.Tokens.vertex:
            add("error", "TargetsPrimvar", pv.GetAttr().GetPath(), f"interpolation '{pv.GetInterpolation()}', expected 'vertex'")
        if pv.GetElementSize() != K:
            add("error", "TargetsPrimvar", pv.GetAttr().GetPath(), f"elementSize {pv.GetElementSize()}, expected K = {K}")
        n = 0 if tv is None else len(tv)
        if n != L * K:
            add("error", "TargetsPrimvar", pv.GetAttr().GetPath(), f"{n} values, expected {L} instances x {K} = {L * K}")
        elif n and not np.isfinite(np.asarray(tv, np.float64)).all():
            add("error", "TargetsPrimvar", pv.GetAttr().GetPath(), "NaN or inf values")


def _check_template_mesh(stage, root, mesh_path, add) -> None:
    """The template Mesh (triangles, UVs), its materials and texture paths."""
    from pxr import UsdGeom, UsdShade

    mp = stage.GetPrimAtPath(mesh_path)
    mesh = UsdGeom.Mesh(mp)
    pts = mesh.GetPointsAttr().Get()
    V = 0 if pts is None else len(pts)
    counts = mesh.GetFaceVertexCountsAttr().Get()
    fvi = mesh.GetFaceVertexIndicesAttr().Get()
    if V == 0 or counts is None or not len(counts):
        add("error", "TemplateMesh", mp.GetPath(), "the template has no points or faces")
    else:
        if np.any(np.asarray(counts) != 3):
            add("error", "TemplateMesh", mp.GetPath(), "faces must be triangles")
        f = np.asarray(fvi)
        if f.size and (f.min() < 0 or f.max() >= V):
            add("error", "TemplateMesh", mp.GetPath(), f"face indices outside 0..{V - 1}")
        st = UsdGeom.PrimvarsAPI(mp).GetPrimvar("st")
        if not st or st.Get() is None or len(st.Get()) != V:
            add("error", "TemplateMesh", mp.GetPath(), "primvars:st must hold one UV per vertex")
        if mesh.GetSubdivisionSchemeAttr().Get() != UsdGeom.Tokens.none:
            add("warning", "TemplateMesh", mp.GetPath(), "subdivisionScheme should be 'none'")
    bound = {}
    for sub in UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "materialBind"):
        mat, _ = UsdShade.MaterialBindingAPI(sub.GetPrim()).ComputeBoundMaterial()
        bound[sub.GetPrim().GetName()] = mat
    for side in ("front", "back"):
        if not bound.get(side):
            add("error", "Materials", mp.GetPath(), f"no material bound to the '{side}' face subset")
        elif not _has_preview_surface(bound[side]):
            add("error", "Materials", bound[side].GetPath(), "material has no UsdPreviewSurface surface")
        elif not _reads_st(bound[side]):
            add("warning", "Materials", bound[side].GetPath(), "no UsdUVTexture read through primvars:st")
    _check_textures(root, add)


def _check_textures(root, add) -> None:
    """Every UsdUVTexture's file: relative and resolvable."""
    from pxr import Usd, UsdShade

    for p in Usd.PrimRange(root):
        if p.GetTypeName() == "Shader" and UsdShade.Shader(p).GetIdAttr().Get() == "UsdUVTexture":
            f = UsdShade.Shader(p).GetInput("file")
            v = f.Get() if f else None
            if v is not None and v.path and (v.path.startswith("/") or ":" in v.path.split("/")[0]):
                add("warning", "RelativeTextures", f.GetAttr().GetPath(), f"absolute texture path '{v.path}'")
            if v is not None and v.path and not v.resolvedPath:
                add("error", "Textures", f.GetAttr().GetPath(), f"texture '{v.path}' does not resolve")


def _check_stem(root, add) -> None:
    """Stem: Mesh geometry, never UsdGeom.Cylinder (Blender drops its material)."""
    from pxr import Usd, UsdGeom

    for p in Usd.PrimRange(root):
        if p.IsA(UsdGeom.Cylinder):
            add("warning", "StemAsMesh", p.GetPath(), "Cylinder prim: DCCs drop its material; use Mesh")



def _check_baked(stage, root, L: int, add) -> None:
    """The baked representation, if offered: L leaf meshes and the instancer switched off."""
    from pxr import Usd, UsdGeom

    from leaffit_usd.usd.reader import find_instancer

    vset = root.GetVariantSets().GetVariantSet("leafRepresentation")
    if vset and vset.IsValid() and "baked" in vset.GetVariantNames():
        from leaffit_usd.usd.reader import select_representation

        original = vset.GetVariantSelection()
        try:
            select_representation(stage, "baked")
            from leaffit_usd.usd.reader import select_variant

            lods = root.GetVariantSets().GetVariantSet("LOD")
            levels = (lods.GetVariantNames() if root.GetVariantSets().HasVariantSet("LOD") else []) or [None]
            orig_lod = lods.GetVariantSelection() if levels != [None] else None
            for lod in levels:
                if lod is not None:
                    select_variant(stage, "LOD", lod)
                baked = [p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh) and not p.IsAbstract()
                         and "/BakedLeaves/" in str(p.GetPath()) and p.GetName().startswith("leaf_")]
                if len(baked) != L:
                    add("error", "BakedVariant", root.GetPath(), f"variant 'baked'{' ' + lod if lod else ''} "
                        f"has {len(baked)} leaf meshes, expected {L}")
            if orig_lod is not None:
                select_variant(stage, "LOD", orig_lod)
            inst_after = find_instancer(stage)
            if inst_after is not None and inst_after.IsActive():
                add("warning", "BakedVariant", root.GetPath(), "variant 'baked' leaves the "
                    "PointInstancer active: DCCs would show every leaf twice")
        finally:
            select_representation(stage, original)


def _has_preview_surface(material) -> bool:
    from pxr import UsdShade
    src = material.ComputeSurfaceSource()
    shader = src[0] if src else None
    return bool(shader) and UsdShade.Shader(shader.GetPrim()).GetIdAttr().Get() == "UsdPreviewSurface"


def _reads_st(material) -> bool:
    from pxr import Usd, UsdShade
    ok_tex = ok_reader = False
    for p in Usd.PrimRange(material.GetPrim()):
        sh = UsdShade.Shader(p)
        if not sh:
            continue
        if sh.GetIdAttr().Get() == "UsdUVTexture":
            ok_tex = True
        if sh.GetIdAttr().Get() == "UsdPrimvarReader_float2":
            v = sh.GetInput("varname")
            ok_reader = ok_reader or (v is not None and str(v.Get()) == "st")
    return ok_tex and ok_reader
