"""Which 3DGS file format a path holds, and readers for the compressed formats.

Formats (the key :func:`detect_format` returns -> what reads it):

* ``ply``            INRIA 3DGS PLY                  -> :mod:`leaffit_usd.splats.ply` (ours)
* ``ply_2dgs``, ``ply_gof`` 2DGS (no ``scale_2``) and Gaussian Opacity Fields (``filter_3D``)
  PLYs                                                -> the same reader, see
  :mod:`leaffit_usd.splats.ply_variants`
* ``ply_points``     a point-cloud PLY (``x y z [rgb]``, no 3DGS properties),
  ``xyz`` ASCII points (``.xyz`` / ``.txt`` / ``.pts``), ``las`` LAS / LAZ (laspy, ``[scans]``
  extra)                                              -> :mod:`leaffit_usd.splats.scans`: one
  Gaussian per point from its neighbourhood (:mod:`leaffit_usd.splats.points`)
* ``gltf``           glTF / GLB with ``KHR_gaussian_splatting`` -> :mod:`leaffit_usd.splats.gltf_splats`
* ``compressed_ply`` PlayCanvas / SuperSplat compressed PLY (``element chunk`` + packed uint32
  vertex records, 8-bit SH)                           -> gsply (``[formats]`` extra)
* ``spz``            Niantic SPZ, v1-v3 (gzip) and v4 (``NGSP`` container, zstd) -> gsply
* ``sog``            PlayCanvas SOG v1/v2: a ``.sog`` ZIP bundle, or an unbundled ``meta.json``
  (or its folder) with WebP images beside it          -> gsply (+ imagecodecs for WebP)
* ``splat``          antimatter15 ``.splat``, 32-byte records, no header
  -> :mod:`leaffit_usd.splats.splat` (ours: no maintained library reads it, see there)
* ``usd``            USD ``ParticleField3DGaussianSplat`` -> :mod:`leaffit_usd.splats.usd_io`

Library choice: gsply (OpsiClear, MIT, pinned in the ``[formats]`` extra) reads PLY,
compressed PLY, SPZ v1-v4 and SOG v1/v2 into one container already in the INRIA
parameterisation (log scales, logit opacities, SH DC, (w, x, y, z) quaternions), and its
decoders agree with PlayCanvas's splat-transform, the formats' reference writer, to the
formats' quantisation (tests/splats/test_splats_formats.py). gaussforge also covers ``.splat``
and ``.ksplat`` but its ``read()`` fails on SH-degree-0 data (every ``.splat``, any SH-0 capture).

Detection is by content (magic bytes, the PLY header's properties, the ZIP's member names), then
by extension; ``.splat`` and the ASCII point lists have no magic, so they are recognised by
their extension only.
"""
from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats.cloud import SH_C0, GaussianCloud, drop_invalid
from leaffit_usd.splats.ply_variants import ply_kind

_FROM_POINTS = "Gaussians built from each point's neighbourhood"
FORMAT_NAMES = {
    "ply": "INRIA 3DGS PLY",
    "ply_2dgs": "2DGS PLY (surfels, thin third scale added)",
    "ply_gof": "Gaussian Opacity Fields PLY (3D filter applied)",
    "ply_points": f"point cloud (PLY x y z [rgb]), {_FROM_POINTS}",
    "xyz": f"point cloud (ASCII x y z [rgb]), {_FROM_POINTS}",
    "las": f"point cloud (LAS/LAZ), {_FROM_POINTS}",
    "gltf": "glTF KHR_gaussian_splatting",
    "compressed_ply": "compressed PLY (PlayCanvas/SuperSplat)",
    "spz": "SPZ (Niantic)",
    "sog": "SOG (PlayCanvas)",
    "splat": ".splat (antimatter15)",
    "usd": "USD ParticleField3DGaussianSplat",
}
SUPPORTED_SUFFIXES = (".ply", ".compressed.ply", ".spz", ".sog", ".splat", ".glb", ".gltf",
                      ".xyz", ".txt", ".pts", ".las", ".laz", ".usd", ".usda", ".usdc", ".usdz")
INSTALL_HINT = "pip install 'leaffit-usd[formats]'"
_USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
_GZIP, _NGSP, _ZIP = b"\x1f\x8b", b"NGSP", b"PK\x03\x04"


def _ply_kind(path: Path) -> str:
    """``compressed_ply`` when the PLY header declares PlayCanvas's ``chunk`` element and packed
    vertex fields, else :func:`~leaffit_usd.splats.ply_variants.ply_kind` of the vertex properties."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    header = head if end < 0 else head[:end]
    if b"element chunk" in header and b"packed_position" in header:
        return "compressed_ply"
    names, in_vertex = [], False
    for line in header.decode("ascii", "replace").splitlines():
        tok = line.split()
        if tok[:1] == ["element"]:
            in_vertex = tok[1:2] == ["vertex"]
        elif tok[:1] == ["property"] and in_vertex and len(tok) >= 3:
            names.append(tok[-1])
    return ply_kind(names)


def _zip_has_meta(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return "meta.json" in z.namelist()
    except (zipfile.BadZipFile, OSError, ValueError):
        return False


def detect_format(path: str | os.PathLike) -> str:
    """One of :data:`FORMAT_NAMES`' keys for an existing file (or SOG folder).

    Raises ``InputFileError`` for a missing path, a directory that is not an unbundled SOG, an
    empty file, or a file of no known kind (the message lists the supported extensions).
    """
    path = Path(path)
    if path.is_dir():
        if (path / "meta.json").is_file():
            return "sog"
        raise InputFileError(path, "is a directory; give a 3DGS file "
                                   f"({', '.join(SUPPORTED_SUFFIXES)}) or an unbundled SOG folder")
    if not path.exists():
        raise InputFileError(path, "no such file")
    if not path.is_file():
        raise InputFileError(path, "is not a regular file")
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as e:
        raise InputFileError(path, f"cannot be read ({e.strerror or e})") from None
    if not head:
        raise InputFileError(path, "is empty (0 bytes)")
    name, suffix = path.name.lower(), path.suffix.lower()
    if head.startswith(b"ply"):
        return _ply_kind(path)
    if head.startswith(b"glTF"):
        return "gltf"
    if head.startswith(b"LASF"):
        return "las"
    if head.startswith(b"PXR-USDC") or head.startswith(b"#usda"):
        return "usd"
    if head.startswith(_ZIP):
        if suffix == ".sog" or _zip_has_meta(path):
            return "sog"
        return "usd"  # .usdz is a ZIP too; the USD reader explains what is wrong
    if head.startswith(_GZIP) or head.startswith(_NGSP):
        return "spz"
    if name == "meta.json" or (suffix == ".json" and head.lstrip().startswith(b"{")):
        return "sog"
    # no magic we know: the extension decides, and that format's reader says what is wrong
    if name.endswith(".compressed.ply"):
        return "compressed_ply"
    if suffix == ".ply":
        return "ply"
    if suffix in (".spz", ".sog", ".splat"):
        return suffix[1:]
    if suffix in _USD_SUFFIXES:
        return "usd"
    if suffix in (".glb", ".gltf"):
        return "gltf"
    if suffix in (".las", ".laz"):
        return "las"
    if suffix in (".xyz", ".txt", ".pts"):
        return "xyz"
    raise InputFileError(path, f"unknown file type {suffix or '(no extension)'!r}; expected a 3DGS "
                               f"file or a point cloud ({', '.join(SUPPORTED_SUFFIXES)})")


def _import_gsply(path, kind: str):
    try:
        import gsply  # noqa: PLC0415 - optional dependency
    except ImportError:
        raise InputFileError(path, f"reading {FORMAT_NAMES[kind]} files needs the optional "
                                   f"'formats' extra; install it with: {INSTALL_HINT}") from None
    return gsply


def _first_line(e: BaseException, path=None) -> str:
    text = str(e).replace(f": {path}", "").strip().splitlines() if path else str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0]}" if text else type(e).__name__


def read_with_gsply(path: str | os.PathLike, kind: str, drop_bad: bool = True) -> GaussianCloud:
    """Read a compressed PLY, SPZ or SOG file with gsply into a GaussianCloud (input frame, file order).

    The file's own parameterisation is kept as gsply returns it (log scales, logit opacities,
    SH coefficients; quaternions (w, x, y, z)). Raises ``InputFileError`` when the extra is not
    installed (naming the install command) or the file cannot be decoded.
    """
    path = Path(path)
    gsply = _import_gsply(path, kind)
    readers = {"compressed_ply": gsply.plyread, "spz": gsply.read_spz,
               "sog": getattr(gsply, "sogread", None)}
    if kind not in readers:
        raise ValueError(f"read_with_gsply: unsupported kind {kind!r}")
    target = path
    if kind == "sog" and path.is_file() and path.suffix.lower() != ".sog" and path.name != "meta.json":
        if _zip_has_meta(path):  # a bundle under another name: gsply dispatches on the suffix
            target = path.read_bytes()
        else:
            raise InputFileError(path, "not a SOG file: neither a .sog bundle nor a meta.json")
    if kind == "sog" and path.is_file() and path.name == "meta.json":
        _check_sog_meta(path)
    try:
        data = readers[kind](target)
    except ImportError:  # SOG's WebP decoder or SPZ v4's zstd missing from a partial install
        raise InputFileError(path, f"reading {FORMAT_NAMES[kind]} files needs the optional "
                                   f"'formats' extra; install it with: {INSTALL_HINT}") from None
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 - any failure inside the decoder means a bad file
        raise InputFileError(path, f"not a readable {FORMAT_NAMES[kind]} file ({_first_line(e, path)})") from None
    cloud = gsdata_to_cloud(data, path)
    return drop_invalid(cloud, str(path)) if drop_bad else cloud


def _check_sog_meta(path: Path) -> None:
    try:
        json.loads(path.read_text("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputFileError(path, f"not a SOG meta.json ({_first_line(e)})") from None


def gsdata_to_cloud(data, path) -> GaussianCloud:
    """A gsply ``GSData`` -> GaussianCloud (contiguous float32 copies, INRIA parameterisation).

    ``data.shN`` is (N, K, 3) with K = (degree + 1)**2 - 1 bands, coefficient-major like our
    ``sh[:, 1:, :]``. Linear scales/opacities or RGB DC (gsply tracks which) are converted.
    """
    n = len(data.means)
    shapes = {"means": (n, 3), "scales": (n, 3), "quats": (n, 4), "opacities": (n,), "sh0": (n, 3)}
    for k, shape in shapes.items():
        a = getattr(data, k)
        if a is None or tuple(np.shape(a)) != shape:
            raise InputFileError(path, f"decoded {k} has shape {None if a is None else np.shape(a)}, "
                                       f"expected {shape}")
    shn = data.shN if data.shN is not None else np.zeros((n, 0, 3), np.float32)
    if shn.ndim != 3 or shn.shape[0] != n or shn.shape[2] != 3 or shn.shape[1] not in (0, 3, 8, 15):
        raise InputFileError(path, f"decoded SH coefficients have shape {shn.shape}")
    scales = np.asarray(data.scales, np.float64)
    if not data.is_scales_ply:
        scales = np.log(np.maximum(scales, 1e-30))
    op = np.asarray(data.opacities, np.float64)
    if not data.is_opacities_ply:
        op = np.clip(op, 1e-6, 1 - 1e-6)
        op = np.log(op / (1 - op))
    dc = np.asarray(data.sh0, np.float64)
    if not data.is_sh0_sh:
        dc = (dc - 0.5) / SH_C0
    sh = np.empty((n, 1 + shn.shape[1], 3), np.float32)
    sh[:, 0] = dc
    sh[:, 1:] = shn
    return GaussianCloud(
        means=np.ascontiguousarray(data.means, np.float32),
        log_scales=scales.astype(np.float32),
        quats=np.ascontiguousarray(data.quats, np.float32),
        opacity_logits=op.astype(np.float32),
        sh=sh,
    )
