"""Import a LeafFit stage into Blender (bpy module, headless) and check what a DCC user sees.

Run with the bpy venv (``make dcc-check``), NOT under pytest:

    build/dcc-venv/bin/python tests/usd/dcc/blender_check.py plant.usda LEAVES [EXPECTED.json [BAKED.usda|- [LODS]]]

Checks: the PointInstancer arrives as EXPECTED_LEAVES instances of the template leaf; the
template mesh has two material slots (front, back) whose node trees read an image texture that
loaded (non-zero size); the stem mesh exists; instance transforms equal the stage's; and, with
the 'baked' variant selected (its payload loaded), one mesh per leaf with both materials, no
instances on top and, for a tinted plant, the tint as a ``displayColor`` attribute; and for each
level of detail (LODS = 'LODk=PATH#N,...', copies with that ``LOD`` variant selected, from
make_stage.py) the template leaf arrives from the geometry payload with N vertices, with every
instance and the stem.
Prints one line per check; exit 1 on failure.
"""
import sys

import bpy


def main(path: str, expected: int, expect_json: str | None = None, baked_path: str | None = None,
         lods: str | None = None) -> int:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    res = bpy.ops.wm.usd_import(filepath=path)
    if "FINISHED" not in res:
        print(f"FAIL import: {res}")
        return 1
    ok = True

    def check(cond, msg):
        nonlocal ok
        print(("ok   " if cond else "FAIL ") + msg)
        ok &= bool(cond)

    meshes = {o.name: o for o in bpy.data.objects if o.type == "MESH"}
    print("objects:", sorted((o.name, o.type) for o in bpy.data.objects))
    tmpl = next((o for n, o in meshes.items() if "TemplateLeaf" in n), None)
    check(tmpl is not None, "template leaf mesh imported")
    if tmpl is not None:
        mats = [s.material for s in tmpl.material_slots if s.material]
        check(len(mats) == 2, f"template has 2 material slots ({[m.name for m in mats]})")
        for m in mats:
            imgs = [n.image for n in m.node_tree.nodes if n.type == "TEX_IMAGE" and n.image] if m.use_nodes else []
            check(bool(imgs) and all(i.size[0] > 0 and i.size[1] > 0 for i in imgs),
                  f"material {m.name} reads a loaded image texture "
                  f"({[(i.filepath, tuple(i.size)) for i in imgs]})")
    check(any("Stem" in n for n in meshes), "stem mesh imported")
    dg = bpy.context.evaluated_depsgraph_get()
    n_inst = sum(1 for inst in dg.object_instances
                 if inst.is_instance and "TemplateLeaf" in inst.object.name)
    check(n_inst == expected, f"{n_inst} leaf instances, expected {expected}")
    import json

    if expect_json:
        import numpy as np
        data = json.load(open(expect_json))
        want = np.asarray(data["matrices"])
        if data["up_axis"] == "Y":  # Blender converts a Y-up stage to Z-up: +90 degrees about X
            conv = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])
            want = conv @ want
        got = np.array([np.array(inst.matrix_world) for inst in dg.object_instances
                        if inst.is_instance and "TemplateLeaf" in inst.object.name])
        if len(got) == len(want):
            errs = []
            for w in want:  # match by translation (Blender's instance order is its own)
                k = np.argmin(np.linalg.norm(got[:, :3, 3] - w[:3, 3], axis=1))
                errs.append(np.abs(got[k] - w).max() / max(np.abs(w[:3, :3]).max(), 1e-12))
            # quath orientations: ~1e-3 relative
            check(max(errs) < 5e-3, f"instance transforms match the stage (max rel. error {max(errs):.1e})")
    if baked_path:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        res = bpy.ops.wm.usd_import(filepath=baked_path)
        check("FINISHED" in res, f"import with leafRepresentation = baked ({res})")
        leaves = [o for o in bpy.data.objects if o.type == "MESH" and o.name.startswith("leaf_")]
        check(len(leaves) == expected, f"baked variant: {len(leaves)} leaf meshes, expected {expected}")
        slots = {len([s for s in o.material_slots if s.material]) for o in leaves}
        check(slots == {2}, f"baked leaves have front and back materials (slot counts {slots})")
        dg = bpy.context.evaluated_depsgraph_get()
        n = sum(1 for inst in dg.object_instances if inst.is_instance)
        check(n == 0, f"baked variant: no instanced leaves on top ({n})")
        if expect_json and json.load(open(expect_json)).get("tinted"):
            have = [o.name for o in leaves if "displayColor" in o.data.attributes]
            check(len(have) == len(leaves),
                  f"baked leaves carry the tint as a displayColor attribute ({len(have)}/{len(leaves)})")
    for item in [x for x in (lods or "").split(",") if x]:
        name, rest = item.split("=", 1)
        lod_path, n_points = rest.rsplit("#", 1)
        bpy.ops.wm.read_factory_settings(use_empty=True)
        res = bpy.ops.wm.usd_import(filepath=lod_path)
        check("FINISHED" in res, f"{name}: import ({res})")
        objs = [o for o in bpy.data.objects if o.type == "MESH"]
        tmpl = next((o for o in objs if "TemplateLeaf" in o.name), None)
        got = len(tmpl.data.vertices) if tmpl is not None else -1
        # the template leaf lives in the geometry payload: its points arriving means the
        # payload was loaded, at this level's resolution
        check(got == int(n_points), f"{name}: template leaf with {got} vertices from the payload, "
                                    f"expected {n_points}")
        dg = bpy.context.evaluated_depsgraph_get()
        n = sum(1 for inst in dg.object_instances if inst.is_instance and "TemplateLeaf" in inst.object.name)
        check(n == expected, f"{name}: {n} leaf instances, expected {expected}")
        stem = next((o for o in objs if "Stem" in o.name), None)
        check(stem is not None and len(stem.data.vertices) > 0,
              f"{name}: stem mesh ({len(stem.data.vertices) if stem is not None else 0} vertices)")
    return 0 if ok else 1


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    opt = [a if a not in ("", "-") else None for a in argv[2:]] + [None] * 3
    sys.exit(main(argv[0], int(argv[1]), opt[0], opt[1], opt[2]))
