"""glTF / GLB export: the leaves equal ``bake``'s, frames and units, instancing, tint, the Khronos
validator (0 errors), determinism and the command's failure modes."""
import json
import struct

import numpy as np
import pytest

from leaffit_usd.cli import main
from leaffit_usd.export.gltf import (GltfOptions, asset_to_gltf, build_gltf, read_glb_leaves,
                                     write_gltf)
from leaffit_usd.export.validator import find_validator, validate_gltf

from .conftest import make_asset

needs_validator = pytest.mark.skipif(find_validator() is None,
                                     reason="Khronos glTF validator missing (node + 'make setup')")


def _glb_json(path):
    data = path.read_bytes()
    assert data[:4] == b"glTF" and struct.unpack_from("<I", data, 4)[0] == 2
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + n])


def _accessor(gltf, blob, i):
    import pygltflib as g

    a = gltf.accessors[i]
    v = gltf.bufferViews[a.bufferView]
    dt = {g.FLOAT: np.float32, g.UNSIGNED_SHORT: np.uint16, g.UNSIGNED_INT: np.uint32}[a.componentType]
    n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a.type]
    return np.frombuffer(blob, dt, a.count * n, (v.byteOffset or 0) + (a.byteOffset or 0)).reshape(a.count, n)


def test_glb_leaves_equal_bake(tinted_stage, tmp_path):
    """export -> .glb and bake -> baked.usda from the same stage: the same leaves (float32)."""
    from leaffit_usd.runtime.bake import read_baked_usd

    glb, baked = tmp_path / "p.glb", tmp_path / "baked.usda"
    assert main(["export", str(tinted_stage), "-o", str(glb), "-q"]) == 0
    assert main(["bake", str(tinted_stage), "-o", str(baked), "-q"]) == 0
    pos, faces, extras = read_glb_leaves(glb)
    bv, bf, ids = read_baked_usd(baked)
    assert pos.shape == bv.shape and len(pos) == extras["verticesPerLeaf"] * len(extras["leafLabels"])
    scale = np.abs(bv).max()
    np.testing.assert_allclose(pos, bv, rtol=0, atol=1e-6 * scale)
    # the same triangles (front primitive then back primitive: a permutation of bake's)
    key = lambda f: np.sort(np.sort(f, 1).view([("", f.dtype)] * 3).ravel())  # noqa: E731
    assert np.array_equal(key(faces.astype(np.int64)), key(bf.astype(np.int64)))


def test_frame_metres_y_up():
    """A Z-up centimetre stage lands in metres, +Y up: x' = 0.01 (x, z, -y)."""
    from leaffit_usd.runtime.evaluator import evaluate

    a, tex = make_asset(up_axis="Z", meters_per_unit=0.01)
    g = asset_to_gltf(a)
    np.testing.assert_allclose(g[:3, :3], 0.01 * np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]))
    gltf, _ = build_gltf(a, tex)
    blob = gltf.binary_blob()
    leaves = next(n for n in gltf.nodes if n.name == "Leaves")
    pos = _accessor(gltf, blob, gltf.meshes[leaves.mesh].primitives[0].attributes.POSITION)
    ev = evaluate(a, frame="asset", separate_sheets=True).vertices
    np.testing.assert_allclose(pos, 0.01 * ev[:, [0, 2, 1]] * [1, 1, -1], atol=1e-7)
    # the rendered plant stands on +Y: its stem spans the height, its lowest point near the root
    assert pos[:, 1].max() > 0 and np.isclose(gltf.accessors[
        gltf.meshes[leaves.mesh].primitives[0].attributes.POSITION].max[1], pos[:, 1].max())


def test_instanced_is_the_rigid_placement(tinted, tmp_path):
    """EXT_mesh_gpu_instancing: T R S applied to the template = positions + R s x (drawn sheets)."""
    from leaffit_usd.runtime.evaluator import instance_matrices
    from leaffit_usd.geometry.quaternion import quat_to_matrix

    a, tex = tinted
    out = tmp_path / "i.glb"
    res = write_gltf(out, a, tex, GltfOptions(instanced=True))
    assert res.layout == "instanced"
    import pygltflib

    gltf = pygltflib.GLTF2().load(str(out))
    blob = gltf.binary_blob()
    assert "EXT_mesh_gpu_instancing" in gltf.extensionsUsed
    assert "EXT_mesh_gpu_instancing" not in (gltf.extensionsRequired or [])
    node = next(n for n in gltf.nodes if n.name == "Leaves")
    attrs = node.extensions["EXT_mesh_gpu_instancing"]["attributes"]
    t, r, s = (_accessor(gltf, blob, attrs[k]).astype(np.float64) for k in ("TRANSLATION", "ROTATION", "SCALE"))
    tmpl = _accessor(gltf, blob, gltf.meshes[node.mesh].primitives[0].attributes.POSITION)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 1, atol=1e-6)
    R = quat_to_matrix(np.c_[r[:, 3:], r[:, :3]])
    placed = np.einsum("lij,vj->lvi", R, tmpl * 1.0) * s[:, None, :] + t[:, None, :]
    M = instance_matrices(a.positions, a.orientations, a.scales)
    pts = a.drawn_template_points().astype(np.float64)
    want = np.einsum("lij,vj->lvi", M[:, :3, :3], pts) + M[:, None, :3, 3]
    np.testing.assert_allclose(placed, want, atol=1e-5 * np.abs(want).max())
    np.testing.assert_allclose(_accessor(gltf, blob, attrs["_COLOR_0"]), a.tints, atol=1e-7)


def test_tint_becomes_color_0(tinted, tmp_path):
    a, tex = tinted
    out = tmp_path / "t.glb"
    write_gltf(out, a, tex)
    import pygltflib

    gltf = pygltflib.GLTF2().load(str(out))
    blob = gltf.binary_blob()
    prim = gltf.meshes[next(n for n in gltf.nodes if n.name == "Leaves").mesh].primitives[0]
    col = _accessor(gltf, blob, prim.attributes.COLOR_0)
    V = len(a.template_points)
    np.testing.assert_allclose(col.reshape(a.n_leaves, V, 3), np.repeat(a.tints[:, None], V, 1), atol=1e-7)
    write_gltf(tmp_path / "n.glb", a, tex, GltfOptions(tint=False))
    assert "COLOR_0" not in json.dumps(_glb_json(tmp_path / "n.glb"))


@needs_validator
def test_bright_tints_split_into_texture_gain(tmp_path):
    """Tints above 1 (a leaf brighter than the template): COLOR_0 stays in [0, 1] (0 validator
    errors) and texture x COLOR_0 keeps the product wherever the texture does not saturate."""
    from leaffit_usd.export.gltf import _gain_texture, split_tints
    from leaffit_usd.image_io import srgb_to_linear

    a, tex = make_asset()
    a.tints = (a.tints * 1.8).astype(np.float32)
    col, gain = split_tints(a)
    assert col.max() <= 1 and np.all(gain > 1)
    np.testing.assert_allclose(col * gain, a.tints, rtol=1e-6)
    t0 = srgb_to_linear(tex.front[..., :3] / 255.0)
    t1 = srgb_to_linear(_gain_texture(tex.front, gain)[..., :3] / 255.0)
    ok = (t0 * gain < 0.95) & (t0 > 0.05)
    np.testing.assert_allclose(t1[ok], (t0 * gain)[ok], rtol=0.05)
    out = tmp_path / "bright.glb"
    write_gltf(out, a, tex)
    v = validate_gltf(out)
    assert v.errors == 0, v.messages[:5]


def test_materials_two_sheets_pbr(tinted, tmp_path):
    a, tex = tinted
    write_gltf(tmp_path / "j.glb", a, tex)
    write_gltf(tmp_path / "p.glb", a, tex, GltfOptions(texture_format="png"))
    j, p = _glb_json(tmp_path / "j.glb"), _glb_json(tmp_path / "p.glb")
    names = [m["name"] for m in j["materials"]]
    assert names == ["LeafFront", "LeafBack", "Stem"]
    for m in j["materials"]:
        assert m.get("doubleSided", False) is False and m["pbrMetallicRoughness"]["metallicFactor"] == 0
    assert {i["mimeType"] for i in j["images"]} == {"image/jpeg"}
    assert {i["mimeType"] for i in p["images"]} == {"image/png"}
    assert [m.get("alphaMode", "OPAQUE") for m in p["materials"]] == ["MASK", "MASK", "OPAQUE"]
    prims = [m for m in j["meshes"] if m["name"] == "Leaves"][0]["primitives"]
    assert [pr["material"] for pr in prims] == [0, 1]
    assert j["asset"]["generator"].startswith("leaffit-usd")


def test_deterministic_and_gltf_json(tinted, tmp_path):
    a, tex = tinted
    (tmp_path / "b").mkdir()
    write_gltf(tmp_path / "a.glb", a, tex)
    write_gltf(tmp_path / "b" / "a.glb", a, tex)
    assert (tmp_path / "a.glb").read_bytes() == (tmp_path / "b" / "a.glb").read_bytes()
    write_gltf(tmp_path / "a.gltf", a, tex)
    doc = json.loads((tmp_path / "a.gltf").read_text())
    assert doc["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")
    pos, _, _ = read_glb_leaves(tmp_path / "a.gltf")
    pos2, _, _ = read_glb_leaves(tmp_path / "a.glb")
    assert np.array_equal(pos, pos2)


@needs_validator
@pytest.mark.parametrize("kw", [{}, {"instanced": True}, {"texture_format": "png"}])
def test_khronos_validator_zero_errors(tinted, tmp_path, kw):
    a, tex = tinted
    for ext in (".glb", ".gltf") if not kw else (".glb",):
        out = tmp_path / f"v{ext}"
        write_gltf(out, a, tex, GltfOptions(**kw))
        v = validate_gltf(out)
        assert v.errors == 0, v.messages
        assert v.warnings == 0, v.messages


@needs_validator
def test_validator_catches_a_broken_file(tinted, tmp_path):
    """The validator test can fail: a GLB with an out-of-range index is reported."""
    a, tex = tinted
    gltf, _ = build_gltf(a, tex)
    blob = bytearray(gltf.binary_blob())
    prim = gltf.meshes[0].primitives[0]
    acc = gltf.accessors[prim.indices]
    off = gltf.bufferViews[acc.bufferView].byteOffset
    struct.pack_into("<H", blob, off, 65000)
    gltf.set_binary_blob(bytes(blob))
    out = tmp_path / "bad.glb"
    out.write_bytes(b"".join(gltf.save_to_bytes()))
    v = validate_gltf(out)
    assert v.errors >= 1 and "ACCESSOR_INDEX_OOB" in v.codes(0)


def test_export_errors(tinted_stage, tmp_path, capsys):
    assert main(["export", str(tinted_stage), "-o", str(tmp_path / "x.obj")]) == 2
    assert main(["export", str(tmp_path / "missing.usda"), "-o", str(tmp_path / "x.glb")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "x.obj" in err
    assert not (tmp_path / "x.glb").exists()


def test_untextured_plant(tmp_path):
    """A stage without textures still exports (flat colour materials) and has no images."""
    a, _ = make_asset(tints=False)
    write_gltf(tmp_path / "u.glb", a, None)
    j = _glb_json(tmp_path / "u.glb")
    assert "images" not in j and j["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"][:3] != [1, 1, 1]
