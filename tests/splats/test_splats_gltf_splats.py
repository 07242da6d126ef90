"""glTF ``KHR_gaussian_splatting`` (leaffit_usd.splats.gltf_splats): files built here with pygltflib
as the ratified extension defines them (ROTATION xyzw, linear SCALE, OPACITY in [0, 1], SH per
coefficient), read back through ``load_cloud``; expected values computed here in float64."""
import base64
import json

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from leaffit_usd.cli import main
from leaffit_usd.splats import FORMAT_NAMES, detect_format, load_cloud

N = 200
EXT = "KHR_gaussian_splatting"
FLOAT, BYTE, UBYTE, SHORT, USHORT = 5126, 5120, 5121, 5122, 5123


def gaussians(seed=0, degree=1):
    r = np.random.default_rng(seed)
    q = r.normal(size=(N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {"pos": r.uniform(-1, 1, (N, 3)), "quat_xyzw": q, "scale": np.exp(r.uniform(-6, -2, (N, 3))),
            "opacity": r.uniform(0.05, 0.95, N), "sh": r.normal(0, 0.5, (N, (degree + 1) ** 2, 3))}


def build(g, path, *, node=None, quantize=False, data_uri=False, scale_values=None, drop=(), extra_attrs=None):
    """A glTF/GLB with one POINTS primitive carrying ``g`` (pygltflib writes it)."""
    blob, views, accessors, attrs = bytearray(), [], [], {}

    def add(name, arr, ctype=FLOAT, normalized=False):
        arr = np.asarray(arr)
        a = arr.reshape(len(arr), -1)
        kind = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}[a.shape[1]]
        np_t = {FLOAT: "<f4", BYTE: "i1", UBYTE: "u1", SHORT: "<i2", USHORT: "<u2"}[ctype]
        raw = np.ascontiguousarray(a, np_t).tobytes()
        while len(blob) % 4:
            blob.append(0)
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
        blob.extend(raw)
        acc = pygltflib.Accessor(bufferView=len(views) - 1, componentType=ctype, count=len(a), type=kind,
                                 normalized=normalized or None)
        if name == "POSITION":
            acc.min, acc.max = a.min(0).tolist(), a.max(0).tolist()
        accessors.append(acc)
        if name not in drop:
            attrs[name] = len(accessors) - 1

    add("POSITION", g["pos"])
    if quantize:
        add(f"{EXT}:ROTATION", np.round(g["quat_xyzw"] * 32767), SHORT, True)
        add(f"{EXT}:OPACITY", np.round(g["opacity"] * 255), UBYTE, True)
    else:
        add(f"{EXT}:ROTATION", g["quat_xyzw"])
        add(f"{EXT}:OPACITY", g["opacity"])
    add(f"{EXT}:SCALE", g["scale"] if scale_values is None else scale_values)
    degree = int(round(np.sqrt(g["sh"].shape[1]))) - 1
    for l in range(degree + 1):  # noqa: E741
        for c in range(2 * l + 1):
            add(f"{EXT}:SH_DEGREE_{l}_COEF_{c}", g["sh"][:, l * l + c])
    for k, v in (extra_attrs or {}).items():
        add(k, v)
    a = pygltflib.Attributes()
    for k, v in attrs.items():
        setattr(a, k, v)
    prim = pygltflib.Primitive(attributes=a, mode=0, extensions={EXT: {"kernel": "ellipse",
                                                                        "colorSpace": "srgb_rec709_display"}})
    gl = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"), extensionsUsed=[EXT],
                         meshes=[pygltflib.Mesh(primitives=[prim])],
                         nodes=[node or pygltflib.Node(mesh=0)], scenes=[pygltflib.Scene(nodes=[0])], scene=0,
                         bufferViews=views, accessors=accessors)
    if data_uri:
        uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
        gl.buffers = [pygltflib.Buffer(byteLength=len(blob), uri=uri)]
        gl.save_json(str(path))
    else:
        gl.buffers = [pygltflib.Buffer(byteLength=len(blob))]
        gl.set_binary_blob(bytes(blob))
        gl.save_binary(str(path))
    return path


def _check(c, g, pos_tol=1e-6):
    assert len(c) == N
    assert np.abs(c.means - g["pos"]).max() < pos_tol
    assert np.allclose(c.scales, g["scale"], rtol=1e-5)
    assert np.allclose(c.opacities, g["opacity"], atol=1e-6)
    want = np.c_[g["quat_xyzw"][:, 3], g["quat_xyzw"][:, :3]]  # (w, x, y, z)
    got = c.rotations.astype(np.float64)
    sign = np.where((got * want).sum(1, keepdims=True) < 0, -1, 1)
    assert np.abs(got * sign - want).max() < 1e-6
    assert np.allclose(c.sh, g["sh"], atol=1e-6)


@pytest.mark.parametrize("data_uri", [False, True])
def test_round_trip(tmp_path, data_uri):
    g = gaussians()
    p = build(g, tmp_path / ("s.gltf" if data_uri else "s.glb"), data_uri=data_uri)
    assert detect_format(p) == "gltf"
    c = load_cloud(p)
    _check(c, g)
    assert c.sh_degree == 1


def test_quantized_rotation_and_opacity(tmp_path):
    g = gaussians(1, degree=0)
    c = load_cloud(build(g, tmp_path / "q.glb", quantize=True))
    assert np.abs(c.opacities - g["opacity"]).max() <= 0.5 / 255 + 1e-6
    want = np.c_[g["quat_xyzw"][:, 3], g["quat_xyzw"][:, :3]]
    got = c.rotations.astype(np.float64)
    assert np.abs(got * np.where((got * want).sum(1, keepdims=True) < 0, -1, 1) - want).max() < 4 / 32767


def test_node_transform_is_applied(tmp_path):
    g = gaussians(2, degree=0)
    rot = Rotation.from_euler("xyz", [30, -20, 75], degrees=True)
    node = pygltflib.Node(mesh=0, translation=[0.5, -2.0, 3.0], rotation=rot.as_quat().tolist(), scale=[2.0] * 3)
    c = load_cloud(build(g, tmp_path / "n.glb", node=node))
    assert np.abs(c.means - (2.0 * rot.apply(g["pos"]) + [0.5, -2.0, 3.0])).max() < 1e-5
    assert np.allclose(c.scales, 2.0 * g["scale"], rtol=1e-5)
    want = (rot * Rotation.from_quat(g["quat_xyzw"])).as_matrix()
    assert np.abs(c.rotation_matrices() - want).max() < 1e-5


def test_draft_log_scales_are_recognised(tmp_path, caplog):
    g = gaussians(3, degree=0)
    c = load_cloud(build(g, tmp_path / "old.glb", scale_values=np.log(g["scale"])))
    assert np.allclose(c.scales, g["scale"], rtol=1e-5)
    assert "log scales" in caplog.text


def test_color_0_stands_in_for_a_missing_dc(tmp_path):
    g = gaussians(4, degree=0)
    rgb = np.clip(0.5 + 0.28209479177387814 * g["sh"][:, 0], 0, 1)
    p = build(g, tmp_path / "c.glb", drop=(f"{EXT}:SH_DEGREE_0_COEF_0",), extra_attrs={"COLOR_0": np.c_[rgb, g["opacity"]]})
    assert np.abs(load_cloud(p).colors - rgb).max() < 1e-6


def test_inspect_names_gltf(tmp_path, capsys):
    p = build(gaussians(), tmp_path / "s.glb")
    assert main(["inspect", str(p), "--json", "--up", "+y"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["format"] == "gltf" and js["format_name"] == FORMAT_NAMES["gltf"] and js["gaussians"] == N


def test_bad_gltf_files_exit_2_with_one_line(tmp_path, capsys):
    g = gaussians(5, degree=0)
    ok = build(g, tmp_path / "ok.glb")
    bad = {}
    (tmp_path / "cut.glb").write_bytes(ok.read_bytes()[:-800])
    bad["cut.glb"] = "truncated"
    build(g, tmp_path / "noscale.glb", drop=(f"{EXT}:SCALE",))
    bad["noscale.glb"] = "missing KHR_gaussian_splatting:SCALE"
    mesh = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"), meshes=[pygltflib.Mesh(primitives=[
        pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0))])])
    mesh.save_json(str(tmp_path / "mesh.gltf"))
    bad["mesh.gltf"] = "no KHR_gaussian_splatting primitive"
    (tmp_path / "junk.glb").write_bytes(b"glTF" + bytes(range(200)))
    bad["junk.glb"] = "not a readable GLB"
    gl = json.loads(build(g, tmp_path / "s.gltf", data_uri=True).read_text())
    gl["accessors"][1]["count"] = 10 * N
    (tmp_path / "long.gltf").write_text(json.dumps(gl))
    bad["long.gltf"] = "truncated"
    for name, fragment in bad.items():
        try:
            code = main(["inspect", str(tmp_path / name), "--up", "+z"])
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, (name, err)
        assert fragment in err, (name, err)
