"""Stage for ``make dcc-check``: prints 'PATH LEAVES EXPECTED.json' for blender_check.py
(the JSON holds each instance's 4x4 transform in the stage's frame), then the path of a copy
with the 'baked' variant selected (written beside it; '-' without one), then one
'LODk=PATH#N' per ``LOD`` variant (a copy with that level selected, N = the template leaf's
point count there), comma-separated.

    python tests/usd/dcc/make_stage.py [PLANT.usda]

Without an argument, writes the synthetic 5-leaf plant of the usd tests (real template mesh
layout, textures, stem, baked payload, three levels of detail) to build/dcc/plant.usda; with
one, reports that file.
"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from leaffit_usd.usd.reader import read_stage  # noqa: E402


def main() -> int:
    import numpy as np

    if len(sys.argv) > 1 and sys.argv[1]:
        path = Path(sys.argv[1])
    else:
        import synthetic as syn

        from leaffit_usd.runtime.evaluator import asset_leaves
        from leaffit_usd.usd.assemble import asset_from_results
        from leaffit_usd.usd.writer import LeafTextures, write_stage

        from leaffit_usd.mesh.result import StemMesh

        t = syn.template_mesh(tex=256)
        t.lods = [syn.coarser_template(t, 60), syn.coarser_template(t, 20)]
        s = syn.stem()
        s.lods = [StemMesh(points=s.points[::2].copy(), faces=np.array([[0, 1, 2]], np.int32)),
                  StemMesh(points=s.points[:3].copy(), faces=np.array([[0, 1, 2]], np.int32))]
        asset = asset_from_results(t, syn.leaf_fits(t), s, syn.frame(), up_axis="Y")
        asset.tints = np.random.default_rng(0).uniform(0.5, 1.0, (asset.n_leaves, 3)).astype(np.float32)
        path = HERE.parent.parent.parent / "build" / "dcc" / "plant.usda"
        write_stage(path, asset, LeafTextures(t.front_texture, t.back_texture),
                    leaves=asset_leaves(asset, separate_sheets=True),
                    lod_leaves=[asset_leaves(asset.at_lod(k), separate_sheets=True) for k in (1, 2)])
    import json

    from leaffit_usd.geometry.quaternion import quat_to_matrix

    a = read_stage(path)
    m = np.zeros((a.n_leaves, 4, 4))
    m[:, :3, :3] = quat_to_matrix(a.orientations.astype(np.float64)) * a.scales[:, None, :]
    m[:, :3, 3] = a.positions
    m[:, 3, 3] = 1
    up = a.metadata.get("up_axis", "Y")
    expect = path.with_suffix(".instances.json")
    expect.write_text(json.dumps({"up_axis": up, "matrices": m.tolist(), "tinted": a.tints is not None}))
    # the same stage with leafRepresentation = baked selected (what an artist picks for exact shapes)
    from pxr import Usd
    stage = Usd.Stage.Open(str(path))
    vset = stage.GetDefaultPrim().GetVariantSets().GetVariantSet("leafRepresentation")
    baked = ""
    if vset and "baked" in vset.GetVariantNames():
        vset.SetVariantSelection("baked")
        baked = path.with_name(path.stem + ".baked_selected.usda")
        stage.GetRootLayer().Export(str(baked))
        vset.ClearVariantSelection()
    print(path.resolve(), a.n_leaves, expect.resolve(), baked or "-", ",".join(lod_copies(stage, path)))
    return 0


def lod_copies(stage, path: Path) -> list[str]:
    """One copy of the stage per ``LOD`` variant, that variant selected (written beside it), as
    'LODk=PATH#N' with N the template leaf's point count in that variant (payload loaded)."""
    from pxr import UsdGeom

    vset = stage.GetDefaultPrim().GetVariantSets().GetVariantSet("LOD")
    out = []
    for name in (vset.GetVariantNames() if vset else []):
        vset.SetVariantSelection(name)
        mesh = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and "TemplateLeaf" in p.GetName()]
        n = len(UsdGeom.Mesh(mesh[0]).GetPointsAttr().Get()) if mesh else -1
        copy = path.with_name(f"{path.stem}.{name}_selected.usda")
        stage.GetRootLayer().Export(str(copy))
        out.append(f"{name}={copy.resolve()}#{n}")
    if vset:
        vset.ClearVariantSelection()
    return out


if __name__ == "__main__":
    sys.exit(main())
