"""3DGS input/output: the GaussianCloud value, PLY and USD readers/writers, frames, the splat renderer."""
from __future__ import annotations

import os

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.formats import FORMAT_NAMES, SUPPORTED_SUFFIXES, detect_format
from leaffit_usd.splats.frame import Frame
from leaffit_usd.splats.ply import read_ply, write_ply

__all__ = ["GaussianCloud", "Frame", "read_ply", "write_ply", "load_cloud", "detect_format",
           "FORMAT_NAMES", "SUPPORTED_SUFFIXES"]


def load_cloud(path: str | os.PathLike, prim: str | None = None, drop_bad: bool = True) -> GaussianCloud:
    """Load a 3DGS capture as a GaussianCloud: INRIA PLY, compressed PLY, SPZ, SOG, ``.splat`` or
    USD ``ParticleField3DGaussianSplat`` (see :mod:`leaffit_usd.splats.formats`).

    The format is chosen by content (magic bytes), then by extension. ``prim`` selects the splat
    prim of a USD stage holding several (an error for other formats). Input frame, file order; a
    few invalid Gaussians are dropped with a warning (see ``drop_invalid``). Raises
    ``InputFileError`` (also when a compressed format needs the ``[formats]`` extra).
    """
    kind = detect_format(path)
    if kind != "usd" and prim is not None:
        raise InputFileError(path, f"--prim applies to USD files only; this is a {FORMAT_NAMES[kind]} file")
    if kind == "ply":
        return read_ply(path, drop_bad=drop_bad)
    if kind == "splat":
        from leaffit_usd.splats.splat import read_splat

        return read_splat(path, drop_bad=drop_bad)
    if kind in ("compressed_ply", "spz", "sog"):
        from leaffit_usd.splats.formats import read_with_gsply

        return read_with_gsply(path, kind, drop_bad=drop_bad)
    from leaffit_usd.splats.usd_io import read_usd_splats

    return read_usd_splats(path, prim=prim, drop_bad=drop_bad)
