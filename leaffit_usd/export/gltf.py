"""PlantAsset -> glTF 2.0 (.glb binary, or a self-contained .gltf), written with pygltflib.

Two layouts:

* **evaluated** (default): the explicit leaves, exactly as ``leaffit-usd bake`` evaluates them
  (``runtime.evaluator.evaluate(asset, frame="asset", separate_sheets=True)``: every template
  vertex deformed by its leaf's MLS field and placed, front and back sheets pushed apart by the
  stage's sheetOffset), plus the stem::

      scene -> <Plant> node (extras.leaffit: leaf labels, vertices per leaf, assetToInput, ...)
                 ├── Leaves node -> mesh "Leaves": primitive 0 = front sheets (LeafFront),
                 │                  primitive 1 = back sheets (LeafBack); shared vertex arrays
                 │                  POSITION, NORMAL, TEXCOORD_0 and COLOR_0 (the per-leaf tint),
                 │                  leaf-major: leaf j owns vertices j*V .. (j+1)*V - 1
                 └── Stem node   -> mesh "Stem" (material Stem, constant colour)

* **instanced** (``GltfOptions(instanced=True)``): the template leaf once (both sheets) on a node
  with ``EXT_mesh_gpu_instancing`` (TRANSLATION, ROTATION, SCALE per leaf, and ``_COLOR_0`` for
  the tint, which three.js reads as instance colours). Only the rigid placement survives: glTF
  has no MLS deformer, so every leaf is the template's shape (the per-leaf deformation is lost).

glTF has no back-face texture, so, as in the USD stage, each side is its own sheet with its own
material (``doubleSided: false``). Materials are metallic-roughness PBR: metallic 0, roughness
``LEAF_ROUGHNESS``, baseColorTexture = the leaf texture (sRGB), baseColor x COLOR_0 (the tint,
linear) in every conforming renderer (tints above 1 are split between COLOR_0 and a texture
gain: :func:`split_tints`). PNG textures keep their alpha and use
``alphaMode: MASK`` with cutoff 0.5 (the USD stage's opacityThreshold); JPEG ones are OPAQUE
(the mesh outline is the leaf outline).

Frames: glTF is metres, +Y up, right-handed. ``asset_to_gltf`` maps the stage's asset frame
(``upAxis`` Y or Z, ``metersPerUnit``) there; a Y-up metre stage maps by the identity.
Texture coordinates: glTF's v runs down the image, USD's st up, so TEXCOORD_0 = (s, 1 - t).

Output is deterministic (same asset, same bytes) and atomic (temp file + rename).
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.io_util import atomic_write_bytes
from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.geometry.quaternion import matrix_to_quat, quat_to_matrix
from leaffit_usd.runtime.evaluator import BakedLeaves, evaluate
from leaffit_usd.usd.wind import wind_data
from leaffit_usd.version import __version__
from leaffit_usd.usd.asset import PlantAsset

GLTF_FORMATS = (".glb", ".gltf")
TEXTURE_FORMATS = ("jpg", "png", "jpg+mask")   # jpg+mask (the USD writer's default) -> png here
INSTANCING_EXT = "EXT_mesh_gpu_instancing"
LEAF_ROUGHNESS = 0.6
STEM_COLOR = (0.23, 0.30, 0.12)        # linear RGB (the USD stage's Stem material)
LEAF_FALLBACK_COLOR = (0.1, 0.35, 0.08)  # linear RGB when the plant has no textures
ALPHA_CUTOFF = 0.5

# glTF component types / buffer targets (the spec's numbers)
_FLOAT, _UINT16, _UINT32 = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass
class GltfOptions:
    """How the glTF file is written.

    instanced : False (default) = the evaluated leaves (exact, one mesh); True = the template once
        + EXT_mesh_gpu_instancing (rigid placement only, the per-leaf deformation is lost)
    texture_format : "jpg" (default, compact, OPAQUE) or "png" (alpha kept, alphaMode MASK);
        "jpg+mask" (the USD stage's default) is written as "png": a glTF material has one base
        colour texture, its alpha the cut-out
    texture_max_size : longest side of the embedded textures, pixels
    jpeg_quality : 1..100
    tint : write the per-leaf tint (COLOR_0 / _COLOR_0) when the asset has one
    name : name of the root node (default: the output file's stem)
    """

    instanced: bool = False
    texture_format: str = "jpg"
    texture_max_size: int = 1024
    jpeg_quality: int = 90
    tint: bool = True
    name: str | None = None

    def validate(self) -> None:
        if self.texture_format not in TEXTURE_FORMATS:
            raise ParameterError("--texture-format", " or ".join(TEXTURE_FORMATS), self.texture_format)
        if not (16 <= int(self.texture_max_size) <= 16384):
            raise ParameterError("--texture-size", "an integer in 16..16384", self.texture_max_size)
        if not (1 <= int(self.jpeg_quality) <= 100):
            raise ParameterError("jpeg_quality", "an integer in 1..100", self.jpeg_quality)


@dataclass
class GltfResult:
    """What was written: path, size in bytes, layout ("evaluated" | "instanced"), counts."""

    path: Path
    bytes: int
    layout: str
    leaves: int
    vertices: int
    triangles: int


def _wind_instance_attributes(b, wind, G: np.ndarray, rG: np.ndarray) -> dict:
    """EXT_mesh_gpu_instancing attributes of the wind (``usd.wind``): _WINDPIVOT, _WINDAXIS
    (glTF frame; G asset -> glTF, rG its rotation) and _WIND = (0, bend, phase) per leaf."""
    pivots = np.asarray(wind.pivots, np.float64) @ G[:3, :3].T + G[:3, 3]
    L = len(pivots)
    return {"_WINDPIVOT": b.accessor(pivots.astype(np.float32), "VEC3", None),
            "_WINDAXIS": b.accessor((np.asarray(wind.axes, np.float64) @ rG.T).astype(np.float32), "VEC3", None),
            "_WIND": b.accessor(np.column_stack([np.zeros(L), wind.leaf_bend, wind.phases]).astype(np.float32),
                                "VEC3", None)}


def _stem_node(b, asset, G: np.ndarray, wind, stem_mat: int, children: list, counts: dict) -> None:
    """The stem as a node (appended to ``children``) with its wind bend per vertex (_WIND)."""
    if not (len(asset.stem_points) and len(asset.stem_faces)):
        return
    sv = np.asarray(asset.stem_points, np.float64) @ G[:3, :3].T + G[:3, 3]
    sf = np.asarray(asset.stem_faces, np.int64)
    attrs = {"POSITION": b.accessor(sv.astype(np.float32), "VEC3", minmax=True),
             "NORMAL": b.accessor(_unit_normals(sv, sf), "VEC3"),
             "_WIND": b.accessor(np.column_stack([np.zeros(len(sv)), wind.stem_bend,
                                                  np.zeros(len(sv))]).astype(np.float32), "VEC3")}
    prim = b.g.Primitive(attributes=b.g.Attributes(**attrs), indices=b.indices(sf, len(sv)),
                         material=stem_mat)
    children.append(b.node(name="Stem", mesh=b.mesh("Stem", [prim])))
    counts["vertices"] += len(sv)
    counts["triangles"] += len(sf)


def _pot_nodes(b, pot, G: np.ndarray, children: list, counts: dict) -> None:
    """The Pot and Soil meshes (``mesh.pot``; convert --pot) as nodes (appended to ``children``),
    vertex-coloured (COLOR_0, linear) on white; G : asset -> glTF frame."""
    if pot is None:
        return
    for part, pts, faces, cols in (("Pot", pot.pot_points, pot.pot_faces, pot.pot_colors),
                                   ("Soil", pot.soil_points, pot.soil_faces, pot.soil_colors)):
        if not len(pts) or not len(faces):
            continue
        pv = np.asarray(pts, np.float64) @ G[:3, :3].T + G[:3, 3]
        pf = np.asarray(faces, np.int64)
        c = np.asarray(cols, np.float64)
        lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)
        attrs = {"POSITION": b.accessor(pv.astype(np.float32), "VEC3", minmax=True),
                 "NORMAL": b.accessor(_unit_normals(pv, pf), "VEC3"),
                 "COLOR_0": b.accessor(lin, "VEC3")}
        prim = b.g.Primitive(attributes=b.g.Attributes(**attrs), indices=b.indices(pf, len(pv)),
                             material=b.material(part, (1.0, 1.0, 1.0), None, False))
        children.append(b.node(name=part, mesh=b.mesh(part, [prim])))
        counts["vertices"] += len(pv)
        counts["triangles"] += len(pf)


def asset_to_gltf(asset: PlantAsset) -> np.ndarray:
    """(4, 4) float64 similarity, asset frame -> glTF frame (metres, +Y up, right-handed):
    metersPerUnit x (identity for a Y-up stage; (x, y, z) -> (x, z, -y) for a Z-up one)."""
    md = asset.metadata or {}
    mpu = float(md.get("meters_per_unit", 1.0) or 1.0)
    up = str(md.get("up_axis", "Y")).upper()
    if up == "Y":
        r = np.eye(3)
    elif up == "Z":
        r = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    else:
        raise ParameterError("asset up axis", "'Y' or 'Z'", up)
    m = np.eye(4)
    m[:3, :3] = mpu * r
    return m


def evaluated_leaves(asset: PlantAsset) -> BakedLeaves:
    """The leaves (and stem) the evaluated glTF holds, in the glTF frame: ``bake``'s evaluation
    (asset frame, sheets separated) mapped by :func:`asset_to_gltf`. vertices (L*V, 3) float64."""
    baked = evaluate(asset, frame="asset", separate_sheets=True)
    g = asset_to_gltf(asset)
    baked.vertices = baked.vertices @ g[:3, :3].T + g[:3, 3]
    baked.stem_vertices = np.asarray(baked.stem_vertices, np.float64) @ g[:3, :3].T + g[:3, 3]
    baked.frame = "gltf"
    return baked


def split_tints(asset: PlantAsset) -> tuple[np.ndarray | None, np.ndarray]:
    """The per-leaf tint as glTF can store it: (COLOR_0 values (L, 3) float32 in [0, 1] or None,
    texture gain (3,) float64 >= 1).

    glTF colours must lie in [0, 1] (the validator's ACCESSOR_NON_CLAMPED), but a leaf brighter
    than the template has a tint above 1. So the embedded textures are scaled (in linear RGB) by
    g = max(1, the largest tint per channel) and COLOR_0 = tint / g: texture x COLOR_0 is the
    USD stage's texture x tint, except in texels the gain pushes past 1 (clipped).
    """
    t = getattr(asset, "tints", None)
    if t is None:
        return None, np.ones(3)
    t = np.asarray(t, np.float64).reshape(-1, 3)
    if len(t) != asset.n_leaves or not np.isfinite(t).all():
        return None, np.ones(3)
    t = np.maximum(t, 0.0)
    g = np.maximum(1.0, t.max(0)) if len(t) else np.ones(3)
    return (t / g).astype(np.float32), g


def _gain_texture(img: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """(H, W, 3|4) uint8 sRGB image with its colour multiplied by ``gain`` (3,) in linear RGB."""
    if np.all(gain == 1.0):
        return img
    from leaffit_usd.image_io import linear_to_srgb, srgb_to_linear

    out = np.array(img, copy=True)
    lin = srgb_to_linear(out[..., :3] / 255.0) * gain
    out[..., :3] = np.clip(np.round(linear_to_srgb(lin) * 255.0), 0, 255).astype(np.uint8)
    return out


def _unit_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float32 unit vertex normals; +Y where undefined (glTF requires unit length)."""
    return vertex_normals(points, faces, undefined=np.array([0.0, 1.0, 0.0])).astype(np.float32)


def _unit_template_normals(n: np.ndarray) -> np.ndarray:
    """The template's authored normals made unit length (+Y where zero), float32."""
    n = np.asarray(n, np.float64).reshape(-1, 3)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-12, n / np.maximum(norm, 1e-30), [0.0, 1.0, 0.0]).astype(np.float32)


def _encode_texture(img: np.ndarray, options: GltfOptions) -> tuple[bytes, str]:
    """(H, W, 3|4) uint8 image -> (encoded bytes, MIME type), downsampled to texture_max_size."""
    from leaffit_usd.image_io import write_image

    fmt = "png" if options.texture_format == "jpg+mask" else options.texture_format
    with tempfile.TemporaryDirectory(prefix="leaffit-gltf-") as d:
        p = Path(d) / f"t.{fmt}"
        write_image(p, img, max_size=int(options.texture_max_size),
                    jpeg_quality=int(options.jpeg_quality))
        data = p.read_bytes()
    return data, ("image/jpeg" if fmt == "jpg" else "image/png")


class _Builder:
    """Accumulates one binary buffer (4-byte aligned views) and the glTF object lists."""

    def __init__(self):
        import pygltflib as g

        self.g = g
        self.blob = bytearray()
        self.gltf = g.GLTF2(asset=g.Asset(version="2.0", generator=f"leaffit-usd {__version__}"))

    def view(self, data: bytes, target: int | None = None) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        off = len(self.blob)
        self.blob += data
        self.gltf.bufferViews.append(self.g.BufferView(buffer=0, byteOffset=off, byteLength=len(data),
                                                       target=target))
        return len(self.gltf.bufferViews) - 1

    def accessor(self, arr: np.ndarray, type_: str, target: int | None = _ARRAY_BUFFER,
                 minmax: bool = False) -> int:
        arr = np.ascontiguousarray(arr)
        ctype = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint16): _UINT16,
                 np.dtype(np.uint32): _UINT32}[arr.dtype]
        v = self.view(arr.tobytes(), target)
        flat = arr.reshape(len(arr), -1)
        acc = self.g.Accessor(bufferView=v, componentType=ctype, count=int(len(arr)), type=type_)
        if minmax:
            acc.min = [float(x) for x in flat.min(0)]
            acc.max = [float(x) for x in flat.max(0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def indices(self, faces: np.ndarray, n_vertices: int) -> int:
        dt = np.uint16 if n_vertices <= 65535 else np.uint32
        return self.accessor(np.asarray(faces).reshape(-1).astype(dt), "SCALAR", _ELEMENT_ARRAY_BUFFER)

    def image_texture(self, img: np.ndarray, name: str, options: GltfOptions) -> int:
        g = self.g
        data, mime = _encode_texture(img, options)
        v = self.view(data)
        self.gltf.images.append(g.Image(bufferView=v, mimeType=mime, name=name))
        if not self.gltf.samplers:   # linear + mipmaps, clamped like the USD stage's textures
            self.gltf.samplers.append(g.Sampler(magFilter=9729, minFilter=9987,
                                                wrapS=33071, wrapT=33071))
        self.gltf.textures.append(g.Texture(sampler=0, source=len(self.gltf.images) - 1, name=name))
        return len(self.gltf.textures) - 1

    def material(self, name: str, color, texture: int | None, alpha_mask: bool) -> int:
        g = self.g
        pbr = g.PbrMetallicRoughness(baseColorFactor=[*map(float, color), 1.0] if texture is None
                                     else [1.0, 1.0, 1.0, 1.0],
                                     metallicFactor=0.0, roughnessFactor=LEAF_ROUGHNESS)
        if texture is not None:
            pbr.baseColorTexture = g.TextureInfo(index=texture)
        mat = g.Material(name=name, pbrMetallicRoughness=pbr, doubleSided=False,
                         alphaMode="MASK" if alpha_mask else "OPAQUE",
                         alphaCutoff=ALPHA_CUTOFF if alpha_mask else None)
        self.gltf.materials.append(mat)
        return len(self.gltf.materials) - 1

    def mesh(self, name: str, primitives: list) -> int:
        self.gltf.meshes.append(self.g.Mesh(name=name, primitives=primitives))
        return len(self.gltf.meshes) - 1

    def node(self, **kw) -> int:
        self.gltf.nodes.append(self.g.Node(**kw))
        return len(self.gltf.nodes) - 1

    def finish(self, root: int) -> "object":
        g = self.g
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.buffers.append(g.Buffer(byteLength=len(self.blob)))
        self.gltf.scenes.append(g.Scene(nodes=[root]))
        self.gltf.scene = 0
        self.gltf.set_binary_blob(bytes(self.blob))
        return self.gltf


def _face_sides(asset: PlantAsset) -> np.ndarray:
    """(F,) bool, True for back-sheet template faces (majority of their vertices)."""
    f = np.asarray(asset.template_faces, np.int64)
    return asset.template_side[f].astype(np.int32).sum(1) >= 2


def _gltf_uvs(uvs: np.ndarray) -> np.ndarray:
    uv = np.asarray(uvs, np.float32).reshape(-1, 2).copy()
    uv[:, 1] = 1.0 - uv[:, 1]
    return uv


def build_gltf(asset: PlantAsset, textures=None, options: GltfOptions | None = None,
               name: str = "Plant"):
    """The glTF document (``pygltflib.GLTF2`` with its binary blob set) for ``asset``.

    textures : an object with ``front`` and ``back`` (H, W, 3|4) uint8 images (row 0 = top), e.g.
        ``usd.writer.LeafTextures``; None = constant-colour leaf materials.
    Returns (gltf, counts) with counts = {"vertices", "triangles"}.
    """
    options = options or GltfOptions()
    options.validate()
    b = _Builder()
    L = asset.n_leaves
    V = len(asset.template_points)
    alpha = textures is not None and options.texture_format in ("png", "jpg+mask")
    tints, gain = split_tints(asset) if options.tint else (None, np.ones(3))
    mats = []
    for side, img in (("LeafFront", getattr(textures, "front", None)),
                      ("LeafBack", getattr(textures, "back", None))):
        tex = b.image_texture(_gain_texture(np.asarray(img), gain), side, options) \
            if img is not None else None
        mats.append(b.material(side, LEAF_FALLBACK_COLOR, tex, alpha))
    stem_mat = b.material("Stem", STEM_COLOR, None, False)
    back = _face_sides(asset)
    G = asset_to_gltf(asset)
    children, counts = [], {"vertices": 0, "triangles": 0}
    extras = {"leafLabels": np.asarray(asset.leaf_labels, np.int64).tolist(),
              "verticesPerLeaf": int(V), "layout": "instanced" if options.instanced else "evaluated",
              "assetToInput": (np.asarray(asset.asset_to_input, np.float64)
                               @ np.linalg.inv(G)).ravel(order="F").tolist(),
              "inputSha256": str((asset.metadata or {}).get("input_sha256", "")),
              "textureGain": [float(x) for x in gain],
              "toolVersion": str((asset.metadata or {}).get("tool_version", __version__))}
    wind = wind_data(asset)
    extras["wind"] = WIND_EXTRAS
    if L and not options.instanced:
        baked = evaluated_leaves(asset)
        verts = np.asarray(baked.vertices, np.float32)
        faces = np.asarray(baked.faces, np.int64).reshape(L, -1, 3)
        attrs = {"POSITION": b.accessor(verts, "VEC3", minmax=True),
                 "NORMAL": b.accessor(_unit_normals(baked.vertices, baked.faces), "VEC3"),
                 "TEXCOORD_0": b.accessor(np.tile(_gltf_uvs(asset.template_uvs), (L, 1)), "VEC2")}
        if tints is not None:
            attrs["COLOR_0"] = b.accessor(np.repeat(tints, V, axis=0), "VEC3")
        attrs["_WIND"] = b.accessor(np.column_stack([
            np.tile(wind.flutter, L), np.repeat(wind.leaf_bend, V), np.repeat(wind.phases, V)]).astype(np.float32), "VEC3")
        prims = []
        for s in (0, 1):
            sel = faces[:, back == bool(s)].reshape(-1, 3)
            if len(sel):
                prims.append(b.g.Primitive(attributes=b.g.Attributes(**attrs),
                                           indices=b.indices(sel, len(verts)), material=mats[s]))
        children.append(b.node(name="Leaves", mesh=b.mesh("Leaves", prims)))
        counts["vertices"] += len(verts)
        counts["triangles"] += len(faces) * faces.shape[1]
    elif L:
        pts = asset.drawn_template_points()
        attrs = {"POSITION": b.accessor(np.asarray(pts, np.float32), "VEC3", minmax=True),
                 "NORMAL": b.accessor(_unit_template_normals(asset.template_normals), "VEC3"),
                 "TEXCOORD_0": b.accessor(_gltf_uvs(asset.template_uvs), "VEC2")}
        f = np.asarray(asset.template_faces, np.int64)
        prims = [b.g.Primitive(attributes=b.g.Attributes(**attrs),
                               indices=b.indices(f[back == bool(s)], len(pts)), material=mats[s])
                 for s in (0, 1) if (back == bool(s)).any()]
        # instance transforms in the glTF frame: G (T R S) = T' R' S' (G a similarity)
        mpu = float(np.cbrt(np.linalg.det(G[:3, :3])))
        rG = G[:3, :3] / mpu
        q = np.asarray(asset.orientations, np.float64)
        R = rG[None] @ quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
        wxyz = matrix_to_quat(R)
        inst = {"TRANSLATION": b.accessor((np.asarray(asset.positions, np.float64) @ G[:3, :3].T
                                           + G[:3, 3]).astype(np.float32), "VEC3", None),
                "ROTATION": b.accessor(np.ascontiguousarray(np.c_[wxyz[:, 1:], wxyz[:, :1]], np.float32),
                                       "VEC4", None),
                "SCALE": b.accessor((mpu * np.asarray(asset.scales, np.float64)).astype(np.float32),
                                    "VEC3", None)}
        if tints is not None:
            inst["_COLOR_0"] = b.accessor(tints, "VEC3", None)
        inst.update(_wind_instance_attributes(b, wind, G, rG))
        attrs["_WIND"] = b.accessor(np.column_stack([wind.flutter, np.zeros((len(pts), 2))]).astype(np.float32),
                                    "VEC3")
        children.append(b.node(name="Leaves", mesh=b.mesh("TemplateLeaf", prims),
                               extensions={INSTANCING_EXT: {"attributes": inst}}))
        b.gltf.extensionsUsed.append(INSTANCING_EXT)
        counts["vertices"] += len(pts) * L
        counts["triangles"] += len(f) * L
    _stem_node(b, asset, G, wind, stem_mat, children, counts)
    _pot_nodes(b, getattr(asset, "pot", None), G, children, counts)
    root = b.node(name=name, children=children, extras={"leaffit": extras})
    return b.finish(root), counts


#: what the glTF's wind attributes hold (also in the root node's extras, for readers)
WIND_EXTRAS = {
    "_WIND": "per vertex: (leaf flutter 0 at the base -> 1 at the apex, branch bend 0 at the root "
             "-> 1 at the farthest stem node, per-leaf phase in [0, 1))",
    "_WINDPIVOT, _WINDAXIS": "per instance (EXT_mesh_gpu_instancing): the petiole base and the "
                             "unit base-to-apex axis, glTF frame",
}


def write_gltf(path, asset: PlantAsset, textures=None, options: GltfOptions | None = None) -> GltfResult:
    """Write ``asset`` as .glb (binary) or .gltf (JSON, buffer and images embedded as data URIs),
    atomically. Raises ParameterError for another extension or bad options."""
    import pygltflib

    options = options or GltfOptions()
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in GLTF_FORMATS:
        raise ParameterError("output", f"a file ending in {' or '.join(GLTF_FORMATS)}", str(path))
    name = options.name or _node_name(path.stem)
    gltf, counts = build_gltf(asset, textures, options, name=name)
    if ext == ".glb":
        data = b"".join(gltf.save_to_bytes())
    else:
        gltf.convert_buffers(pygltflib.BufferFormat.DATAURI)
        data = gltf.to_json(separators=(",", ":")).encode()
    atomic_write_bytes(path, data)
    return GltfResult(path=path, bytes=len(data), layout="instanced" if options.instanced else "evaluated",
                      leaves=asset.n_leaves, **counts)


def _node_name(stem: str) -> str:
    import re

    s = re.sub(r"[^A-Za-z0-9_]", "_", stem) or "Plant"
    return s if not s[0].isdigit() else f"_{s}"


def read_glb_leaves(path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read back the evaluated leaves of a .glb/.gltf written by :func:`write_gltf`:
    (positions (L*V, 3) float32 glTF frame, faces (L*F, 3) int64 front then back primitive,
    the root node's extras["leaffit"])."""
    import pygltflib

    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    if blob is None:   # .gltf with a data-URI buffer
        gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
        blob = gltf.binary_blob()

    def arr(i):
        a = gltf.accessors[i]
        v = gltf.bufferViews[a.bufferView]
        dt = {_FLOAT: np.float32, _UINT16: np.uint16, _UINT32: np.uint32}[a.componentType]
        n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a.type]
        off = (v.byteOffset or 0) + (a.byteOffset or 0)
        return np.frombuffer(blob, dt, a.count * n, off).reshape(a.count, n)

    root = gltf.nodes[gltf.scenes[gltf.scene or 0].nodes[0]]
    leaves = next((gltf.nodes[c] for c in root.children or [] if gltf.nodes[c].name == "Leaves"), None)
    if leaves is None:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), root.extras.get("leaffit", {})
    mesh = gltf.meshes[leaves.mesh]
    pos = arr(mesh.primitives[0].attributes.POSITION)
    faces = np.concatenate([arr(p.indices).reshape(-1, 3).astype(np.int64) for p in mesh.primitives])
    return pos, faces, root.extras.get("leaffit", {})
