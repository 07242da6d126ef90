"""3DGS input/output: the GaussianCloud value, PLY and USD readers/writers, frames, the splat renderer."""
from __future__ import annotations

import os
from pathlib import Path

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.frame import Frame
from leaffit_usd.splats.ply import read_ply, write_ply

__all__ = ["GaussianCloud", "Frame", "read_ply", "write_ply", "load_cloud", "detect_format",
           "SUPPORTED_SUFFIXES"]

SUPPORTED_SUFFIXES = (".ply", ".usd", ".usda", ".usdc", ".usdz")


def detect_format(path: str | os.PathLike) -> str:
    """'ply' or 'usd' for an existing file, from its first bytes, else from its extension.

    Raises ``InputFileError`` for a missing path, a directory, an empty file, or a file that is
    neither (with the supported extensions in the message).
    """
    path = Path(path)
    if path.is_dir():
        raise InputFileError(path, "is a directory; give a .ply or .usd/.usda/.usdc/.usdz file")
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
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith(b"PXR-USDC") or head.startswith(b"#usda") or head.startswith(b"PK\x03\x04"):
        return "usd"
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return "ply"  # the PLY reader explains what is wrong with the content
    if suffix in (".usd", ".usda", ".usdc", ".usdz"):
        return "usd"
    raise InputFileError(path, f"unknown file type {suffix or '(no extension)'!r}; expected a 3DGS "
                               f"PLY or a USD file ({', '.join(SUPPORTED_SUFFIXES)})")


def load_cloud(path: str | os.PathLike, prim: str | None = None, drop_bad: bool = True) -> GaussianCloud:
    """Load a 3DGS capture (INRIA PLY or USD ``ParticleField3DGaussianSplat``) as a GaussianCloud.

    The format is chosen by content (magic bytes), then by extension. ``prim`` selects the splat
    prim of a USD stage holding several (an error for a PLY). Input frame, file order; a few
    invalid Gaussians are dropped with a warning (see ``drop_invalid``). Raises ``InputFileError``.
    """
    kind = detect_format(path)
    if kind == "ply":
        if prim is not None:
            raise InputFileError(path, "--prim applies to USD files only; this is a PLY file")
        return read_ply(path, drop_bad=drop_bad)
    from leaffit_usd.splats.usd_io import read_usd_splats

    return read_usd_splats(path, prim=prim, drop_bad=drop_bad)
