"""INRIA 3DGS PLY reader and writer (binary little/big endian and ASCII).

Layout written: ``x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3`` then any extra
properties, all float32 except extras (original type). Reading is one ``np.fromfile`` into a
structured array, so a 1M-Gaussian file loads in well under a second.

:func:`read_ply` also reads the 2DGS (no ``scale_2``) and Gaussian Opacity Fields (``filter_3D``)
layouts, converted as :mod:`leaffit_usd.splats.ply_variants` says; a plain point-cloud PLY is
refused here and read by :func:`leaffit_usd.splats.load_cloud` (through
:func:`read_vertex_table`).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.io_util import atomic_path
from leaffit_usd.splats.cloud import REST_COUNTS, GaussianCloud, drop_invalid
from leaffit_usd.splats.ply_variants import apply_3d_filter, ply_kind, surfel_third_scale

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_NAME = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
             "u4": "uint", "f4": "float", "f8": "double"}
_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
_MAX_HEADER = 1 << 20


def _parse_header(f, path):
    """Return (format, vertex_count, [(name, dtype-str)], header_bytes, elements before vertex)."""
    magic = f.read(4)
    if magic[:3] != b"ply":
        raise InputFileError(path, "not a PLY file (no 'ply' magic at the start)")
    f.seek(0)
    raw = b""
    while b"end_header" not in raw:
        chunk = f.read(4096)
        if not chunk or len(raw) > _MAX_HEADER:
            raise InputFileError(path, "malformed PLY header: no 'end_header' line")
        raw += chunk
    end = raw.index(b"end_header")
    nl = raw.find(b"\n", end)
    if nl < 0:
        raise InputFileError(path, "malformed PLY header: 'end_header' line is not terminated")
    header_len = nl + 1
    try:
        text = raw[:end].decode("ascii")
    except UnicodeDecodeError:
        raise InputFileError(path, "malformed PLY header: not ASCII text") from None
    fmt, elements, current = None, [], None
    for lineno, line in enumerate(text.splitlines()[1:], start=2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) < 2 or tok[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise InputFileError(path, f"malformed PLY header: unknown format line {line!r}")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not re.fullmatch(r"\d+", tok[2]):
                raise InputFileError(path, f"malformed PLY header: bad element line {line!r}")
            current = [tok[1], int(tok[2]), []]
            elements.append(current)
        elif tok[0] == "property":
            if current is None:
                raise InputFileError(path, f"malformed PLY header: property before any element (line {lineno})")
            if len(tok) >= 2 and tok[1] == "list":
                current[2].append((tok[-1], "list"))
                continue
            if len(tok) != 3 or tok[1] not in _TYPES:
                raise InputFileError(path, f"malformed PLY header: bad property line {line!r}")
            current[2].append((tok[2], _TYPES[tok[1]]))
        else:
            raise InputFileError(path, f"malformed PLY header: unexpected line {line!r}")
    if fmt is None:
        raise InputFileError(path, "malformed PLY header: no 'format' line")
    vertex = [e for e in elements if e[0] == "vertex"]
    if not vertex:
        raise InputFileError(path, "PLY has no 'vertex' element (no Gaussians)")
    before = elements[: elements.index(vertex[0])]
    return fmt, vertex[0][1], vertex[0][2], header_len, before


def read_ply(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Read an INRIA 3DGS PLY (or a 2DGS or GOF one) into a GaussianCloud (input frame, file order).

    A 2DGS surfel gets a thin third scale and a GOF file's ``filter_3D`` is applied to scales and
    opacities (:mod:`leaffit_usd.splats.ply_variants`). Raises ``InputFileError`` (a ``UserError``) for anything that is not a usable 3DGS PLY:
    not PLY, malformed header, missing properties, non-numeric properties, truncated data,
    no Gaussians. With ``drop_bad`` a few NaN/Inf or zero-quaternion Gaussians are dropped with
    a warning (their file positions stay in ``file_index``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file")
    with open(path, "rb") as f:
        fmt, count, props, header_len, before = _parse_header(f, path)
        if any(n for _, n, _ in before):
            raise InputFileError(path, "PLY has data elements before 'vertex'; not a 3DGS file")
        names = [n for n, _ in props]
        kind = ply_kind(names)
        if kind == "ply_points":
            raise InputFileError(path, "is a point-cloud PLY (x y z, no 3DGS properties); load it with "
                                       "leaffit_usd.splats.load_cloud, which builds Gaussians from it")
        missing = [n for n in _REQUIRED if n not in names and not (kind == "ply_2dgs" and n == "scale_2")]
        if missing:
            raise InputFileError(path, f"not a 3DGS PLY: missing properties {', '.join(missing)}")
        lists = [n for n, t in props if t == "list"]
        if lists:
            raise InputFileError(path, f"unsupported list property {lists[0]!r} in 'vertex'")
        if len(set(names)) != len(names):
            raise InputFileError(path, "duplicate property names in 'vertex'")
        if count == 0:
            raise InputFileError(path, "contains no Gaussians")
        if fmt == "ascii":
            data = _read_ascii(f, path, count, props, header_len)
            layout = _Layout(data.dtype, path)
            cloud = layout.allocate(count)
            layout.fill(cloud, data, 0)
            del data
        else:
            order = "<" if fmt == "binary_little_endian" else ">"
            dtype = np.dtype([(n, order + t) for n, t in props])
            expected = count * dtype.itemsize
            available = path.stat().st_size - header_len
            if available < expected:
                raise InputFileError(
                    path, f"truncated: header declares {count} Gaussians ({expected} bytes), "
                          f"file holds {available} bytes of data")
            layout = _Layout(dtype, path)
            cloud = layout.allocate(count)
            f.seek(header_len)
            # Read in chunks straight into the cloud's arrays: peak memory is the cloud plus
            # one chunk (not the cloud plus the whole file as a structured array).
            for start in range(0, count, _CHUNK):
                k = min(_CHUNK, count - start)
                block = np.fromfile(f, dtype=dtype, count=k)
                if len(block) != k:
                    raise InputFileError(path, f"truncated: could read only {start + len(block)} "
                                               f"of {count} Gaussians")
                layout.fill(cloud, block, start)
    if kind == "ply_2dgs":
        cloud.log_scales[:, 2] = surfel_third_scale(cloud.log_scales[:, :2])
    elif kind == "ply_gof":
        f = cloud.extra.pop("filter_3D")
        cloud.log_scales, cloud.opacity_logits = apply_3d_filter(cloud.log_scales, cloud.opacity_logits, f)
    return drop_invalid(cloud, str(path)) if drop_bad else cloud


def read_vertex_table(path: str | os.PathLike) -> np.ndarray:
    """Every property of a PLY's ``vertex`` element as a structured array (N,), native byte order.

    For point-cloud PLYs (any properties, scalar only). Raises ``InputFileError`` for what
    :func:`read_ply` refuses (not PLY, malformed header, list properties, truncated data).
    """
    path = Path(path)
    with open(path, "rb") as f:
        fmt, count, props, header_len, before = _parse_header(f, path)
        if any(n for _, n, _ in before):
            raise InputFileError(path, "PLY has data elements before 'vertex'; not a point cloud")
        lists = [n for n, t in props if t == "list"]
        if lists:
            raise InputFileError(path, f"unsupported list property {lists[0]!r} in 'vertex'")
        if len({n for n, _ in props}) != len(props):
            raise InputFileError(path, "duplicate property names in 'vertex'")
        if count == 0:
            raise InputFileError(path, "contains no points")
        if fmt == "ascii":
            return _read_ascii(f, path, count, props, header_len)
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, order + t) for n, t in props])
        f.seek(header_len)
        data = np.fromfile(f, dtype=dtype, count=count)
    if len(data) != count:
        raise InputFileError(path, f"truncated: header declares {count} points, file holds {len(data)}")
    return data.astype(dtype.newbyteorder("="))


_CHUNK = 131_072  # Gaussians per read (32 MB at SH degree 3)


def _read_ascii(f, path, count, props, header_len):
    f.seek(header_len)
    try:
        table = np.loadtxt(f, dtype=np.float64, max_rows=count, ndmin=2)
    except ValueError as e:
        raise InputFileError(path, f"bad ASCII PLY data: {str(e).splitlines()[0]}") from None
    if table.shape[0] < count:
        raise InputFileError(path, f"truncated: header declares {count} Gaussians, file holds {table.shape[0]}")
    if table.shape[1] != len(props):
        raise InputFileError(path, f"bad ASCII PLY data: {table.shape[1]} values a row, header declares {len(props)}")
    data = np.empty(count, dtype=[(n, t) for n, t in props])
    for i, (n, _) in enumerate(props):
        data[n] = table[:, i]
    return data


class _Layout:
    """Where each 3DGS property of a PLY vertex record goes in a GaussianCloud.

    When every property is a 4-byte float (the INRIA layout), a record block is viewed as an
    (k, P) float32 table and whole column groups are gathered at once (fast); otherwise field
    by field.
    """

    def __init__(self, dtype: np.dtype, path):
        names = list(dtype.names)
        n_rest = sum(1 for n in names if n.startswith("f_rest_"))
        degree = {v: k for k, v in REST_COUNTS.items()}.get(n_rest)
        if degree is None:
            raise InputFileError(path, f"{n_rest} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0-3)")
        missing_rest = [f"f_rest_{i}" for i in range(n_rest) if f"f_rest_{i}" not in names]
        if missing_rest:
            raise InputFileError(path, f"not a 3DGS PLY: missing properties {', '.join(missing_rest)}")
        self.dtype = dtype
        self.m = n_rest // 3
        known = set(_REQUIRED) | {f"f_rest_{i}" for i in range(n_rest)}
        self.extra = [k for k in names if k not in known]
        kinds = {dtype[k].kind + str(dtype[k].itemsize) for k in names}
        self.scale_names = tuple(k for k in ("scale_0", "scale_1", "scale_2") if k in names)
        self.uniform = kinds == {"f4"} and dtype.itemsize == 4 * len(names)
        self.float_order = dtype[names[0]].byteorder if self.uniform else None
        col = {k: i for i, k in enumerate(names)}
        self.groups = {
            "means": [col[k] for k in ("x", "y", "z")],
            "log_scales": [col[k] for k in self.scale_names],
            "quats": [col[k] for k in ("rot_0", "rot_1", "rot_2", "rot_3")],
            "dc": [col[k] for k in ("f_dc_0", "f_dc_1", "f_dc_2")],
            "opacity": col["opacity"],
            # f_rest is channel-major: all coefficients of R, then G, then B
            "rest": [[col[f"f_rest_{c * self.m + j}"] for j in range(self.m)] for c in range(3)],
        }
        self.names = {"means": ("x", "y", "z"), "log_scales": self.scale_names,
                      "quats": ("rot_0", "rot_1", "rot_2", "rot_3"), "dc": ("f_dc_0", "f_dc_1", "f_dc_2")}

    def allocate(self, n: int) -> GaussianCloud:
        return GaussianCloud(
            means=np.empty((n, 3), np.float32), log_scales=np.empty((n, 3), np.float32),
            quats=np.empty((n, 4), np.float32), opacity_logits=np.empty(n, np.float32),
            sh=np.empty((n, 1 + self.m, 3), np.float32),
            extra={k: np.empty(n, self.dtype[k].newbyteorder("=")) for k in self.extra})

    def fill(self, cloud: GaussianCloud, block: np.ndarray, start: int) -> None:
        sl = slice(start, start + len(block))
        g = self.groups
        if self.uniform:
            t = block.view(np.dtype(self.dtype[0].str)).reshape(len(block), -1)
            cloud.means[sl] = t[:, g["means"]]
            cloud.log_scales[sl, :len(self.scale_names)] = t[:, g["log_scales"]]
            cloud.quats[sl] = t[:, g["quats"]]
            cloud.opacity_logits[sl] = t[:, g["opacity"]]
            cloud.sh[sl, 0, :] = t[:, g["dc"]]
            for c in range(3 if self.m else 0):
                cloud.sh[sl, 1:, c] = t[:, g["rest"][c]]
        else:
            for attr in ("means", "log_scales", "quats"):
                dst = getattr(cloud, attr)
                for i, k in enumerate(self.names[attr]):
                    dst[sl, i] = block[k]
            cloud.opacity_logits[sl] = block["opacity"]
            for i, k in enumerate(self.names["dc"]):
                cloud.sh[sl, 0, i] = block[k]
            for c in range(3 if self.m else 0):
                for j in range(self.m):
                    cloud.sh[sl, 1 + j, c] = block[f"f_rest_{c * self.m + j}"]
        for k in self.extra:
            cloud.extra[k][sl] = block[k]


def ply_dtype(cloud: GaussianCloud, order: str = "<") -> np.dtype:
    """The structured dtype :func:`write_ply` writes for ``cloud`` (INRIA property order)."""
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    extra = dict(cloud.extra)
    for k in ("nx", "ny", "nz"):
        fields.append((k, extra.pop(k).dtype.str[1:] if k in extra else "f4"))
    fields += [(f"f_dc_{i}", "f4") for i in range(3)]
    fields += [(f"f_rest_{i}", "f4") for i in range(3 * (cloud.sh.shape[1] - 1))]
    fields += [("opacity", "f4")] + [(f"scale_{i}", "f4") for i in range(3)]
    fields += [(f"rot_{i}", "f4") for i in range(4)]
    fields += [(k, v.dtype.str[1:]) for k, v in extra.items()]
    return np.dtype([(n, order + t) for n, t in fields])


def write_ply(cloud: GaussianCloud, path: str | os.PathLike, ascii: bool = False) -> None:
    """Write ``cloud`` as an INRIA 3DGS PLY (binary little endian by default), atomically."""
    dtype = ply_dtype(cloud)
    data = np.zeros(len(cloud), dtype=dtype)
    for i, k in enumerate("xyz"):
        data[k] = cloud.means[:, i]
    for k, v in cloud.extra.items():
        data[k] = v
    for i in range(3):
        data[f"f_dc_{i}"] = cloud.sh[:, 0, i]
        data[f"scale_{i}"] = cloud.log_scales[:, i]
    m = cloud.sh.shape[1] - 1
    rest = cloud.sh[:, 1:, :].transpose(0, 2, 1).reshape(len(cloud), 3 * m)
    for i in range(3 * m):
        data[f"f_rest_{i}"] = rest[:, i]
    data["opacity"] = cloud.opacity_logits
    for i in range(4):
        data[f"rot_{i}"] = cloud.quats[:, i]
    fmt = "ascii" if ascii else "binary_little_endian"
    header = [
        "ply", f"format {fmt} 1.0", f"element vertex {len(cloud)}",
        *[f"property {_PLY_NAME[dtype[n].str[1:]]} {n}" for n in dtype.names],
        "end_header",
    ]
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if ascii:
            np.savetxt(f, _struct_to_table(data), fmt=_ascii_formats(dtype))
        else:
            data.tofile(f)


def _struct_to_table(data):
    return np.stack([data[n].astype(np.float64) for n in data.dtype.names], axis=1)


def _ascii_formats(dtype):
    # float32 needs 9 significant digits to round-trip exactly; float64 needs 17
    return [("%.9g" if dtype[n].kind == "f" and dtype[n].itemsize == 4 else
             "%.17g" if dtype[n].kind == "f" else "%d") for n in dtype.names]
