"""Readers of plain point clouds (laser, MVS or phone scans): PLY ``x y z [rgb]``, ASCII
``.xyz`` / ``.txt`` / ``.pts``, and LAS / LAZ (laspy, the ``[scans]`` extra).

Each returns a GaussianCloud with one Gaussian per point, in file order, built by
:func:`leaffit_usd.splats.points.gaussians_from_points` (shape and orientation from the point's
neighbourhood, size from the local spacing, opacity ``points.OPACITY``, the file's colour or grey).
Per-point properties other than position and colour (a ``label``, ``intensity``,
``classification``, normals...) are kept verbatim in ``cloud.extra``, one value per point in
file order, so a benchmark can read labels back against the file.

Colour, as RGB in [0, 1]:

* PLY ``red green blue`` (also ``r g b``, ``diffuse_red...``): ``uchar`` / 255, ``ushort`` / 65535,
  float as it is when no value exceeds 1, else / 255;
* ASCII: columns ``x y z`` (3), ``x y z intensity`` (4), ``x y z r g b`` (6), ``x y z intensity r g
  b`` (7, Leica PTS), ``x y z r g b nx ny nz`` (9); any other count >= 3 keeps the columns after
  ``x y z`` as ``column_3``, ``column_4``... Colour values are 0-255 when any exceeds 1, else 0-1
  floats;
* LAS: ``red green blue`` (16 bit) / 65535; when no value exceeds 255 the writer stored 8-bit
  values (a common shortcut) and they are / 255; all zero (a point format with RGB fields left
  unset) is no colour (grey).

Positions are float32 in the GaussianCloud: georeferenced coordinates (UTM, 10^5-10^6 units)
keep only centimetres, so such scans should be recentred first (a warning says so).
"""
from __future__ import annotations

import logging
import os
import re
import struct
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats.cloud import GaussianCloud, drop_invalid
from leaffit_usd.splats.points import gaussians_from_points

log = logging.getLogger("leaffit_usd")

SCANS_INSTALL_HINT = "pip install 'leaffit-usd[scans]'"
ASCII_SUFFIXES = (".xyz", ".txt", ".pts")
LAS_SUFFIXES = (".las", ".laz")
_COLOR_NAMES = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
_FAR = 1e4  # |centre| / extent above this: float32 positions lose the scan's detail


def points_to_cloud(points: np.ndarray, colors: np.ndarray | None, extra: dict, path,
                    drop_bad: bool = True) -> GaussianCloud:
    """Gaussians from points (see the module doc) with ``extra`` attached.

    points : (N, 3) float, input frame; colors : (N, 3) float RGB in [0, 1] or None;
    extra : name -> (N,) array, kept verbatim. Raises InputFileError for too few points.
    """
    p = np.asarray(points, np.float64)
    ok = np.isfinite(p).all(1) if p.ndim == 2 and p.shape[1:] == (3,) else None
    if ok is not None and ok.any():
        lo, hi = p[ok].min(0), p[ok].max(0)
        extent = float(np.max(hi - lo))
        if extent > 0 and float(np.abs((lo + hi) / 2).max()) > _FAR * extent:
            log.warning("%s: the points are %.3g units from the origin and span %.3g: float32 "
                        "positions lose detail; recentre the scan first", path, float(np.abs(lo).max()), extent)
    cloud = gaussians_from_points(p, colors, source=str(path))
    cloud.extra = {k: np.ascontiguousarray(v) for k, v in extra.items()}
    return drop_invalid(cloud, str(path)) if drop_bad else cloud


def _scaled_color(table: np.ndarray, path) -> np.ndarray:
    """(N, 3) RGB in [0, 1] from (N, 3) colour values in the file's convention (module doc)."""
    c = np.asarray(table, np.float64)
    top = float(np.nanmax(c)) if c.size else 0.0
    if top <= 1.0:
        return c
    if top <= 255.0:
        return c / 255.0
    if top <= 65535.0:
        return c / 65535.0
    raise InputFileError(path, f"colour values up to {top:g}; expected 0-1, 0-255 or 0-65535")


# ---- PLY ---------------------------------------------------------------------------------
def read_points_ply(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Gaussians from a point-cloud PLY (``x y z``, optional colour, any other scalar properties)."""
    from leaffit_usd.splats.ply import read_vertex_table

    path = Path(path)
    data = read_vertex_table(path)
    names = data.dtype.names
    rgb_names = next((c for c in _COLOR_NAMES if all(k in names for k in c)), None)
    colors = None
    if rgb_names is not None:
        kinds = {data.dtype[k].kind + str(data.dtype[k].itemsize) for k in rgb_names}
        table = np.stack([data[k].astype(np.float64) for k in rgb_names], axis=1)
        colors = (table / 255.0 if kinds == {"u1"} else table / 65535.0 if kinds == {"u2"}
                  else _scaled_color(table, path))
    used = {"x", "y", "z", *(rgb_names or ())}
    extra = {k: data[k].copy() for k in names if k not in used}
    points = np.stack([data[k].astype(np.float64) for k in ("x", "y", "z")], axis=1)
    return points_to_cloud(points, colors, extra, path, drop_bad)


# ---- ASCII -------------------------------------------------------------------------------
_SPLIT = re.compile(r"[,\s;]+")
_XYZRGB = {"x", "y", "z", "r", "g", "b"}


def _ascii_layout(path: Path) -> tuple[int, str | None, int]:
    """(rows to skip at the top, delimiter for np.loadtxt or None = whitespace, columns)."""
    skip = 0
    with open(path, "r", encoding="utf-8", errors="replace") as f:
        for line in f:
            text = line.strip()
            if not text or text.startswith("#") or text.startswith("//"):
                skip += 1
                continue
            tokens = [t for t in _SPLIT.split(text) if t]
            if len(tokens) == 1 and re.fullmatch(r"\d+", tokens[0]):  # .pts: the point count
                skip += 1
                continue
            delim = "," if "," in text else ";" if ";" in text else None
            return skip, delim, len(tokens)
    raise InputFileError(path, "holds no points (only comments or blank lines)")


def read_ascii_points(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Gaussians from an ASCII point list (``.xyz`` / ``.txt`` / ``.pts``; columns in the module doc).

    Whitespace, comma or semicolon separated; lines starting with ``#`` (and a leading ``//``
    line) are comments; a ``.pts`` first line holding the point count is skipped.
    """
    path = Path(path)
    skip, delim, ncol = _ascii_layout(path)
    if ncol < 3:
        raise InputFileError(path, f"first data line has {ncol} value(s); expected at least x y z")
    try:
        table = np.loadtxt(path, dtype=np.float64, comments=("#", "//"), delimiter=delim,
                           skiprows=skip, ndmin=2, encoding="utf-8")
    except ValueError as e:
        raise InputFileError(path, f"bad point list: {str(e).splitlines()[0]}") from None
    if table.shape[1] != ncol:
        raise InputFileError(path, f"rows have {table.shape[1]} values, the first has {ncol}")
    cols = {3: ("x", "y", "z"), 4: ("x", "y", "z", "intensity"), 6: ("x", "y", "z", "r", "g", "b"),
            7: ("x", "y", "z", "intensity", "r", "g", "b"),
            9: ("x", "y", "z", "r", "g", "b", "nx", "ny", "nz")}.get(ncol)
    if cols is None:
        cols = ("x", "y", "z", *(f"column_{i}" for i in range(3, ncol)))
    idx = {k: i for i, k in enumerate(cols)}
    colors = _scaled_color(table[:, [idx["r"], idx["g"], idx["b"]]], path) if "r" in idx else None
    extra = {k: np.ascontiguousarray(table[:, i]) for k, i in idx.items() if k not in _XYZRGB}
    return points_to_cloud(table[:, :3], colors, extra, path, drop_bad)


# ---- LAS / LAZ ---------------------------------------------------------------------------
def _import_laspy(path):
    try:
        import laspy  # noqa: PLC0415 - optional dependency (the [scans] extra)
    except ImportError:
        raise InputFileError(path, "reading LAS/LAZ files needs the optional 'scans' extra; "
                                   f"install it with: {SCANS_INSTALL_HINT}") from None
    return laspy


def _check_las_header(path: Path) -> None:
    """Refuse a file whose LAS public header block is implausible before laspy reads it (laspy can
    loop for a long time over garbage VLR counts). Offsets from the LAS 1.0-1.4 specifications."""
    with open(path, "rb") as f:
        head = f.read(227)
    size = path.stat().st_size
    if len(head) < 227 or head[:4] != b"LASF":
        raise InputFileError(path, "not a LAS/LAZ file (no 'LASF' header of 227 bytes)")
    major, minor = head[24], head[25]
    header_size, offset, n_vlr = struct.unpack_from("<HII", head, 94)
    fmt_id, rec_len = head[104] & 0x3F, struct.unpack_from("<H", head, 105)[0]
    problems = []
    if major != 1 or minor > 4:
        problems.append(f"version {major}.{minor}")
    if not 227 <= header_size <= offset <= size:
        problems.append(f"header size {header_size} / point data offset {offset} in a {size}-byte file")
    if fmt_id > 10 or rec_len == 0:
        problems.append(f"point format {fmt_id} with {rec_len}-byte records")
    if n_vlr * 54 > max(offset - header_size, 0):
        problems.append(f"{n_vlr} variable-length records in {offset - header_size} bytes")
    if problems:
        raise InputFileError(path, f"not a readable LAS/LAZ file ({'; '.join(problems)})")


def read_las(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Gaussians from a LAS or LAZ file (laspy; LAZ through its lazrs backend).

    Positions are the scaled, offset coordinates (``las.x``...), input units. Kept in ``extra``:
    ``intensity``, ``classification`` and every extra-bytes dimension, verbatim.
    """
    path = Path(path)
    laspy = _import_laspy(path)
    _check_las_header(path)
    try:
        las = laspy.read(path)
    except ImportError:
        raise InputFileError(path, "reading LAZ files needs the optional 'scans' extra (lazrs); "
                                   f"install it with: {SCANS_INSTALL_HINT}") from None
    except Exception as e:  # noqa: BLE001 - laspy raises LaspyException, OSError, ValueError...
        msg = str(e).strip().splitlines()
        if "LazBackend" in str(e) or "lazrs" in str(e):  # LAZ without a decompressor installed
            raise InputFileError(path, "reading LAZ files needs the optional 'scans' extra (lazrs); "
                                       f"install it with: {SCANS_INSTALL_HINT}") from None
        raise InputFileError(path, f"not a readable LAS/LAZ file ({type(e).__name__}: "
                                   f"{msg[0] if msg else ''})") from None
    points = np.stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                       np.asarray(las.z, np.float64)], axis=1)
    dims = set(las.point_format.dimension_names)
    colors = None
    if {"red", "green", "blue"} <= dims:
        rgb = np.stack([np.asarray(las[k], np.float64) for k in ("red", "green", "blue")], axis=1)
        top = rgb.max() if rgb.size else 0.0
        colors = None if top == 0 else rgb / (255.0 if top <= 255 else 65535.0)  # all 0: no colour
    extra = {k: np.array(las[k]) for k in ("intensity", "classification") if k in dims}
    for k in las.point_format.extra_dimension_names:
        extra[k] = np.array(las[k])
    return points_to_cloud(points, colors, extra, path, drop_bad)
