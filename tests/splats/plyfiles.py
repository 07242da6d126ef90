"""Builders of valid and malformed 3DGS PLY/USD files for the foundation tests."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.ply import _PLY_NAME, ply_dtype, write_ply


def small_cloud(n: int = 200, sh_degree: int = 0, seed: int = 0, extra: bool = False) -> GaussianCloud:
    """A random cloud (not a plant): values drawn so every float32 bit pattern path is exercised."""
    rng = np.random.default_rng(seed)
    c = (sh_degree + 1) ** 2
    ex = {}
    if extra:
        ex = {"nx": rng.normal(size=n).astype(np.float32), "ny": np.zeros(n, np.float32),
              "nz": np.ones(n, np.float32), "label": rng.integers(0, 9, n).astype(np.uint8),
              "conf": rng.normal(size=n).astype(np.float64), "cluster": rng.integers(-5, 5, n).astype(np.int32)}
    return GaussianCloud(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(-4, 1, (n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.normal(0, 3, n).astype(np.float32),
        sh=rng.normal(size=(n, c, 3)).astype(np.float32),
        extra=ex,
    )


def write_ply_order(cloud: GaussianCloud, path, order: str = ">") -> Path:
    """Write a binary PLY with the given byte order ('>' big endian) -- our writer only writes '<'."""
    path = Path(path)
    tmp = path.with_suffix(".le.ply")
    write_ply(cloud, tmp)
    from leaffit_usd.splats.ply import read_ply

    src = read_ply(tmp, drop_bad=False)
    le = np.fromfile(tmp, dtype=ply_dtype(cloud, "<"), offset=_header_len(tmp))
    be = le.astype(ply_dtype(cloud, order))
    fmt = "binary_big_endian" if order == ">" else "binary_little_endian"
    header = ["ply", f"format {fmt} 1.0", f"element vertex {len(src)}",
              *[f"property {_PLY_NAME[be.dtype[n].str[1:]]} {n}" for n in be.dtype.names], "end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + be.tobytes())
    tmp.unlink()
    return path


def _header_len(path) -> int:
    raw = Path(path).read_bytes()[:1 << 16]
    end = raw.index(b"end_header")
    return raw.index(b"\n", end) + 1


def raw_ply(path, names, rows, fmt="binary_little_endian", types=None, extra_header=()) -> Path:
    """Write a PLY with the given property names and float32 rows (N, len(names))."""
    path = Path(path)
    rows = np.asarray(rows, np.float32).reshape(-1, len(names))
    types = types or ["float"] * len(names)
    header = ["ply", f"format {fmt} 1.0", *extra_header, f"element vertex {len(rows)}",
              *[f"property {t} {n}" for t, n in zip(types, names)], "end_header"]
    body = rows.astype("<f4").tobytes() if fmt.startswith("binary") else \
        "".join(" ".join(f"{v:.9g}" for v in r) + "\n" for r in rows).encode()
    path.write_bytes(("\n".join(header) + "\n").encode() + body)
    return path


INRIA = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
          "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def inria_rows(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(n, len(INRIA))).astype(np.float32)
    r[:, INRIA.index("rot_0")] += 3.0  # well away from zero
    return r
