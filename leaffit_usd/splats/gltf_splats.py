"""Reader of glTF 2.0 splats, ``KHR_gaussian_splatting`` (``.glb`` or ``.gltf``), with pygltflib.

What the extension stores (Khronos glTF, extensions/2.0/Khronos/KHR_gaussian_splatting, ratified),
per Gaussian, as attributes of a ``POINTS`` primitive whose ``extensions`` hold
``KHR_gaussian_splatting`` (the attribute names are :data:`ATTR`):

* ``POSITION``  VEC3 float, the mean, in the mesh's space;
* ``KHR_gaussian_splatting:ROTATION``  VEC4 unit quaternion **(x, y, z, w)** (float, or normalized
  byte/short) -> our (w, x, y, z) through :func:`leaffit_usd.geometry.quaternion.from_xyzw`;
* ``KHR_gaussian_splatting:SCALE``  VEC3 **linear** standard deviations (float, byte/short,
  normalized or not) -> ``log``. The review drafts (and writers before mid-2026, e.g. PlayCanvas
  splat-transform before its PR #268) stored log scales; linear scales are never negative, so a
  SCALE accessor with a negative value is read as log-space, with a warning;
* ``KHR_gaussian_splatting:OPACITY``  SCALAR in [0, 1] (float or normalized ubyte/ushort) -> logit;
* ``KHR_gaussian_splatting:SH_DEGREE_l_COEF_n``  VEC3 float (r, g, b), degree ``l`` 0-3, ``n`` =
  0..2l in the order m = -l..l: our ``sh[:, l*l + n]`` (the INRIA coefficient order). Degree 0 is
  the DC term; without it ``COLOR_0`` (the fallback colour, RGB in [0, 1] = SH_C0 * dc + 0.5, as
  splat-transform writes it) gives the DC term.

File order is the default scene's nodes depth first, each node's mesh primitives in order (a
file without nodes: meshes in order). A node's world transform is applied to its Gaussians
(:func:`leaffit_usd.splats.transform.transform_cloud`: rotations, scales and SH rotated too), so
the cloud is in the glTF scene's frame (+Y up by glTF convention; the input frame here). The
``colorSpace`` is not converted (the SH are used as stored). Quantised data from compression
extensions (``KHR_spz_gaussian_splats_compression`` ...) is not read: such a file stops with a
one-line error naming the extension.
"""
from __future__ import annotations

import base64
import logging
import os
import struct
import urllib.parse
import warnings
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError, ParameterError
from leaffit_usd.geometry.quaternion import from_xyzw, quat_to_matrix
from leaffit_usd.splats.cloud import SH_C0, GaussianCloud, drop_invalid

log = logging.getLogger("leaffit_usd")

EXTENSION = "KHR_gaussian_splatting"
ATTR = {"position": "POSITION", "color": "COLOR_0",
        "rotation": f"{EXTENSION}:ROTATION", "scale": f"{EXTENSION}:SCALE",
        "opacity": f"{EXTENSION}:OPACITY"}


def sh_attribute(degree: int, coef: int) -> str:
    """The attribute name of SH coefficient ``coef`` (0..2*degree) of ``degree`` (0..3)."""
    return f"{EXTENSION}:SH_DEGREE_{degree}_COEF_{coef}"


POINTS_MODE = 0
_COMPONENT = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_NORM = {"i1": 127.0, "u1": 255.0, "i2": 32767.0, "u2": 65535.0}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _buffer(gltf, i: int, path: Path, cache: dict) -> bytes:
    if i in cache:
        return cache[i]
    buf = gltf.buffers[i]
    if buf.uri is None:
        data = gltf.binary_blob() or b""
    elif buf.uri.startswith("data:"):
        data = base64.b64decode(buf.uri.split(",", 1)[1])
    else:
        target = path.parent / urllib.parse.unquote(buf.uri)
        if not target.is_file():
            raise InputFileError(path, f"buffer {i} file {buf.uri!r} not found beside it")
        data = target.read_bytes()
    cache[i] = data
    return data


def _accessor(gltf, index: int, path: Path, cache: dict) -> np.ndarray:
    """(count, components) float64 values of accessor ``index`` (normalized types scaled as glTF)."""
    if not 0 <= index < len(gltf.accessors):
        raise InputFileError(path, f"attribute refers to accessor {index}, the file has {len(gltf.accessors)}")
    acc = gltf.accessors[index]
    ctype, ncomp = _COMPONENT.get(acc.componentType), _NCOMP.get(acc.type)
    if ctype is None or ncomp is None:
        raise InputFileError(path, f"accessor {index}: unsupported {acc.type} / componentType {acc.componentType}")
    if acc.sparse is not None or acc.bufferView is None:
        raise InputFileError(path, f"accessor {index}: sparse or buffer-less accessors are not read")
    view = gltf.bufferViews[acc.bufferView]
    data = _buffer(gltf, view.buffer, path, cache)
    elem = ncomp * np.dtype(ctype).itemsize
    stride = view.byteStride or elem
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    need = start + stride * (acc.count - 1) + elem if acc.count else start
    if need > len(data) or need > (view.byteOffset or 0) + view.byteLength:
        raise InputFileError(path, f"accessor {index}: truncated ({acc.count} elements need {need} "
                                   f"bytes, the buffer holds {len(data)})")
    raw = data[start:need] + b"\0" * (stride - elem)
    dt = np.dtype({"names": ["v"], "formats": [(np.dtype("<" + ctype), (ncomp,))], "offsets": [0],
                   "itemsize": stride})
    v = np.frombuffer(raw, dtype=dt, count=acc.count)["v"].astype(np.float64).reshape(acc.count, ncomp)
    if acc.normalized and ctype in _NORM:
        v = np.maximum(v / _NORM[ctype], -1.0)
    return v


def _node_matrix(node) -> np.ndarray:
    """(4, 4) float64 local transform of a node (column vectors)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T  # glTF stores column-major
    m = np.eye(4)
    t, r, s = node.translation or [0, 0, 0], node.rotation or [0, 0, 0, 1], node.scale or [1, 1, 1]
    m[:3, :3] = quat_to_matrix(from_xyzw(np.asarray(r, np.float64)[None]))[0] * np.asarray(s, np.float64)
    m[:3, 3] = t
    return m


def _mesh_instances(gltf) -> list[tuple[int, np.ndarray]]:
    """(mesh index, world matrix) in file order (module doc)."""
    if not gltf.nodes:
        return [(i, np.eye(4)) for i in range(len(gltf.meshes))]
    scene = gltf.scene if gltf.scene is not None else 0
    if gltf.scenes and 0 <= scene < len(gltf.scenes):
        roots = list(gltf.scenes[scene].nodes or [])
    else:
        children = {c for n in gltf.nodes for c in (n.children or [])}
        roots = [i for i in range(len(gltf.nodes)) if i not in children]
    out, stack = [], [(i, np.eye(4)) for i in reversed(roots)]
    seen = 0
    while stack:
        i, parent = stack.pop()
        seen += 1
        if seen > 100_000 or not 0 <= i < len(gltf.nodes):
            break  # a cycle or a bad index: the nodes read so far stand
        node = gltf.nodes[i]
        world = parent @ _node_matrix(node)
        if node.mesh is not None:
            out.append((node.mesh, world))
        stack.extend((c, world) for c in reversed(node.children or []))
    return out


def _primitive_cloud(gltf, prim, path: Path, cache: dict, where: str) -> GaussianCloud:
    attrs = {k: v for k, v in vars(prim.attributes).items() if v is not None}
    ext = (prim.extensions or {}).get(EXTENSION) or {}
    missing = [ATTR[k] for k in ("position", "rotation", "scale", "opacity") if ATTR[k] not in attrs]
    if missing:
        nested = ", ".join((ext.get("extensions") or {}).keys())
        raise InputFileError(path, f"{where}: missing {', '.join(missing)}" +
                             (f" (data compressed with {nested}, which is not read)" if nested else ""))
    if prim.mode not in (None, POINTS_MODE):
        raise InputFileError(path, f"{where}: mode {prim.mode}; {EXTENSION} primitives are POINTS (0)")
    if ext.get("kernel", "ellipse") != "ellipse":
        log.warning("%s: %s kernel %r read as the ellipse kernel", path, where, ext.get("kernel"))
    get = lambda k: _accessor(gltf, attrs[k], path, cache)  # noqa: E731
    means, quats, scales, opac = get(ATTR["position"]), get(ATTR["rotation"]), get(ATTR["scale"]), get(ATTR["opacity"])
    n = len(means)
    for name, a, c in (("POSITION", means, 3), ("ROTATION", quats, 4), ("SCALE", scales, 3), ("OPACITY", opac, 1)):
        if a.shape != (n, c):
            raise InputFileError(path, f"{where}: {name} has shape {a.shape}, expected ({n}, {c})")
    degree = 0
    while degree < 3 and sh_attribute(degree + 1, 0) in attrs:
        degree += 1
    sh = np.zeros((n, (degree + 1) ** 2, 3))
    for l in range(degree + 1):  # noqa: E741 - the SH degree
        for c in range(2 * l + 1):
            k = sh_attribute(l, c)
            if k not in attrs:
                if l == 0 and ATTR["color"] in attrs:
                    sh[:, 0] = (get(ATTR["color"])[:, :3] - 0.5) / SH_C0
                    continue
                raise InputFileError(path, f"{where}: missing {k} (SH degree {l} must be complete)")
            sh[:, l * l + c] = get(k)
    if (scales < 0).any():
        log.warning("%s: %s SCALE holds negative values: read as log scales (a pre-ratification "
                    "%s file)", path, where, EXTENSION)
        log_scales = scales
    else:
        log_scales = np.log(np.maximum(scales, 1e-30))
    op = np.clip(opac[:, 0], 1e-6, 1 - 1e-6)
    return GaussianCloud(means=means.astype(np.float32), log_scales=log_scales.astype(np.float32),
                         quats=from_xyzw(quats).astype(np.float32),
                         opacity_logits=np.log(op / (1 - op)).astype(np.float32), sh=sh.astype(np.float32))


def _load(path: Path):
    import pygltflib  # noqa: PLC0415 - only glTF inputs need it

    with open(path, "rb") as f:
        head = f.read(12)
    if head[:4] == b"glTF":
        version, length = struct.unpack_from("<II", head.ljust(12, b"\0"), 4)
        if version != 2:
            raise InputFileError(path, f"not a readable GLB file (container version {version}; 2 expected)")
        if length > path.stat().st_size:
            raise InputFileError(path, f"truncated: the GLB header declares {length} bytes, the file "
                                       f"holds {path.stat().st_size}")
    try:
        with warnings.catch_warnings():  # pygltflib warns on odd chunks; the error line says it
            warnings.simplefilter("ignore")
            gltf = pygltflib.GLTF2().load(str(path))
    except Exception as e:  # noqa: BLE001 - pygltflib raises anything on a bad file
        first = (str(e).strip().splitlines() or [""])[0]
        raise InputFileError(path, f"not a readable glTF file ({type(e).__name__}: {first})") from None
    if gltf is None:
        raise InputFileError(path, "not a readable glTF file")
    return gltf


def read_gltf_splats(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Read every ``KHR_gaussian_splatting`` primitive of a glTF / GLB into one GaussianCloud.

    Input frame = the glTF scene's (node transforms applied), file order as the module doc says.
    Raises ``InputFileError`` for a file pygltflib cannot parse, no splat primitive, missing or
    truncated attributes, compressed splat data.
    """
    from leaffit_usd.splats.transform import transform_cloud

    path = Path(path)
    gltf = _load(path)
    parts, cache = [], {}
    for m, world in _mesh_instances(gltf):
        if not 0 <= m < len(gltf.meshes):
            raise InputFileError(path, f"a node refers to mesh {m}, the file has {len(gltf.meshes)}")
        for j, prim in enumerate(gltf.meshes[m].primitives):
            if EXTENSION not in (prim.extensions or {}):
                continue
            cloud = _primitive_cloud(gltf, prim, path, cache, f"mesh {m} primitive {j}")
            if not np.allclose(world, np.eye(4), atol=1e-12):
                try:
                    cloud = transform_cloud(cloud, world, allow_affine=True)
                except ParameterError as e:
                    raise InputFileError(path, f"mesh {m}: unusable node transform ({e})") from None
            parts.append(cloud)
    if not parts:
        raise InputFileError(path, f"holds no {EXTENSION} primitive (a glTF without Gaussian splats)")
    c = max(p.sh.shape[1] for p in parts)
    sh = np.concatenate([np.pad(p.sh, ((0, 0), (0, c - p.sh.shape[1]), (0, 0))) for p in parts])
    cloud = GaussianCloud(means=np.concatenate([p.means for p in parts]),
                          log_scales=np.concatenate([p.log_scales for p in parts]),
                          quats=np.concatenate([p.quats for p in parts]),
                          opacity_logits=np.concatenate([p.opacity_logits for p in parts]), sh=sh)
    return drop_invalid(cloud, str(path)) if drop_bad else cloud
