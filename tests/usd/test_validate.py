"""Every layout rule of ``leaffit-usd validate`` fails on a stage broken in that one way."""
import pytest

from leaffit_usd.cli import main
from leaffit_usd.usd.validate import validate_file


@pytest.fixture()
def good(stage_path):
    return stage_path


def _edit(path, fn):
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    fn(stage, stage.GetDefaultPrim().GetPath())
    for layer in stage.GetUsedLayers():   # the root layer and the geometry payload
        if layer.dirty and not layer.anonymous:
            layer.Save()


def _geom_layer(s, r):
    """The layer holding the plant's geometry (the payload), where removals must happen."""
    return s.GetPrimAtPath(r.AppendChild("Leaves")).GetPrimStack()[0].layer


def _no_default(s, r):
    s.GetRootLayer().ClearDefaultPrim()


def _kind(s, r):
    from pxr import Usd
    Usd.ModelAPI(s.GetPrimAtPath(r)).SetKind("group")


def _units(s, r):
    s.GetRootLayer().pseudoRoot.ClearInfo("metersPerUnit")


def _two_protos(s, r):
    from pxr import UsdGeom
    m = UsdGeom.Mesh.Define(s, r.AppendPath("Leaves/Prototypes/Other"))
    UsdGeom.PointInstancer(s.GetPrimAtPath(r.AppendChild("Leaves"))).GetPrototypesRel().AddTarget(m.GetPath())


def _proto_idx(s, r):
    from pxr import UsdGeom
    a = UsdGeom.PointInstancer(s.GetPrimAtPath(r.AppendChild("Leaves"))).GetProtoIndicesAttr()
    a.Set(list(a.Get())[:-1])


def _elem_size(s, r):
    from pxr import UsdGeom
    UsdGeom.PrimvarsAPI(s.GetPrimAtPath(r.AppendChild("Leaves"))).GetPrimvar("leaffit:targets").SetElementSize(3)


def _interp(s, r):
    from pxr import UsdGeom
    UsdGeom.PrimvarsAPI(s.GetPrimAtPath(r.AppendChild("Leaves"))).GetPrimvar("leaffit:targets").SetInterpolation("constant")


def _targets_count(s, r):
    a = s.GetPrimAtPath(r.AppendChild("Leaves")).GetAttribute("primvars:leaffit:targets")
    a.Set(list(a.Get())[:-1])


def _k_mismatch(s, r):
    s.GetPrimAtPath(r.AppendChild("Leaves")).GetAttribute("leaffit:mls:controlPointCount").Set(7)


def _sigma(s, r):
    s.GetPrimAtPath(r.AppendChild("Leaves")).GetAttribute("leaffit:mls:sigma").Set(-1.0)


def _no_st(s, r):
    layer = _geom_layer(s, r)      # a payload is not in the local layer stack: edit it with Sdf
    prim = layer.GetPrimAtPath(r.AppendPath("Leaves/Prototypes/TemplateLeaf"))
    prim.RemoveProperty(prim.properties["primvars:st"])


def _unbind(s, r):
    from pxr import UsdShade
    UsdShade.MaterialBindingAPI(s.GetPrimAtPath(r.AppendPath("Leaves/Prototypes/TemplateLeaf/back"))).UnbindAllBindings()


def _cylinder(s, r):
    from pxr import UsdGeom
    UsdGeom.Cylinder.Define(s, r.AppendChild("StemCyl"))


def _provenance(s, r):
    s.GetPrimAtPath(r).ClearCustomDataByKey("leaffit")


def _float_orient(s, r):
    # re-type 'orientations' as quatf[] at the Sdf level (the schema says quath[])
    from pxr import Sdf
    spec = _geom_layer(s, r).GetAttributeAtPath(r.AppendPath("Leaves.orientations"))
    value = spec.default
    parent = spec.owner
    parent.RemoveProperty(spec)
    new = Sdf.AttributeSpec(parent, "orientations", Sdf.ValueTypeNames.QuatfArray)
    new.default = [__import__("pxr").Gf.Quatf(q) for q in value]


CASES = [
    (_no_default, "leaffit:DefaultPrim", "error"),
    (_kind, "leaffit:PlantKind", "error"),
    (_units, "leaffit:StageUnits", "error"),
    (_two_protos, "leaffit:OneTemplate", "error"),
    (_proto_idx, "leaffit:InstanceArrays", "error"),
    (_elem_size, "leaffit:TargetsPrimvar", "error"),
    (_interp, "leaffit:TargetsPrimvar", "error"),
    (_targets_count, "leaffit:TargetsPrimvar", "error"),
    (_k_mismatch, "leaffit:DeformerValues", "error"),
    (_sigma, "leaffit:DeformerValues", "error"),
    (_no_st, "leaffit:TemplateMesh", "error"),
    (_unbind, "leaffit:Materials", "error"),
    (_cylinder, "leaffit:StemAsMesh", "warning"),
    (_provenance, "leaffit:Provenance", "warning"),
    (_float_orient, "usd:usdValidation:AttributeTypeMismatch", "error"),
]


@pytest.mark.parametrize("mutate,rule,severity", CASES, ids=[c[1].split(":")[-1] + "-" + c[0].__name__ for c in CASES])
def test_rule_fails_on_broken_stage(good, mutate, rule, severity):
    assert validate_file(good).findings == []
    _edit(good, mutate)
    found = [f for f in validate_file(good).findings if f.rule == rule]
    assert found, f"{rule} not reported"
    assert any(f.severity == severity for f in found)
    assert all(f.path for f in found)


def test_missing_texture_and_baked_payload(good, tmp_path):
    (tmp_path / "textures" / "p.front.jpg").unlink()
    (tmp_path / "p.baked.usdc").unlink()
    rep = validate_file(good)
    rules = {f.rule for f in rep.findings if f.severity == "error"}
    assert "leaffit:Textures" in rules
    assert "leaffit:BakedVariant" in rules
    assert "usd:usdUtilsValidators:MissingReferenceValidator" in rules


def test_cli_exit_codes(good, tmp_path, capsys):
    assert main(["validate", str(good)]) == 0
    _edit(good, _elem_size)
    assert main(["validate", "--json", str(tmp_path / "v.json"), str(good)]) == 1
    out = capsys.readouterr().out
    assert "leaffit:TargetsPrimvar" in out and "/p/Leaves.primvars:leaffit:targets" in out
    assert (tmp_path / "v.json").is_file()
    assert main(["validate", str(tmp_path / "nope.usda")]) == 2
    good2 = tmp_path / "w.usda"
    good2.write_text('#usda 1.0\n(\n upAxis = "Y"\n metersPerUnit = 1\n defaultPrim = "A"\n)\ndef Xform "A" (kind = "component") {}\n')
    assert main(["validate", "-q", str(good2)]) == 1
