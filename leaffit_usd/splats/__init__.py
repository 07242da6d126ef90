"""3DGS input/output: the GaussianCloud value, PLY and USD readers/writers, point-cloud and glTF
readers, frames, the splat renderer."""
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
    """Load a 3DGS capture or a point-cloud scan as a GaussianCloud (see :mod:`leaffit_usd.splats.formats`).

    3DGS: INRIA PLY (also 2DGS surfels, given a thin third scale, and Gaussian Opacity Fields,
    its ``filter_3D`` applied: :mod:`~leaffit_usd.splats.ply_variants`), compressed PLY, SPZ, SOG,
    ``.splat``, glTF ``KHR_gaussian_splatting`` (``.glb`` / ``.gltf``) or USD
    ``ParticleField3DGaussianSplat``. Point clouds: PLY ``x y z [rgb]``, ASCII ``.xyz`` / ``.txt``
    / ``.pts``, LAS / LAZ (the ``[scans]`` extra). A point becomes one Gaussian
    (:func:`~leaffit_usd.splats.points.gaussians_from_points`): its axes from the covariance of
    its 16 nearest neighbours (the smallest is the surface normal), its two in-plane scales with a
    geometric mean of half the point's mean distance to its 6 nearest neighbours, its thickness at
    least 0.05 x its largest scale, opacity 0.9, the file's colour or grey; the point's other
    properties (labels...) are kept in ``extra`` in file order. A scan needs at least 200
    distinct points.

    The format is chosen by content (magic bytes, the PLY header's properties), then by
    extension. ``prim`` selects the splat prim of a USD stage holding several (an error for other formats). Input frame, file order; a
    few invalid Gaussians are dropped with a warning (see ``drop_invalid``). Raises
    ``InputFileError`` (also when a compressed format needs the ``[formats]`` extra, or LAS/LAZ
    the ``[scans]`` extra).
    """
    kind = detect_format(path)
    if kind != "usd" and prim is not None:
        raise InputFileError(path, f"--prim applies to USD files only; this is a {FORMAT_NAMES[kind]} file")
    if kind in ("ply", "ply_2dgs", "ply_gof"):
        return read_ply(path, drop_bad=drop_bad)
    if kind in ("ply_points", "xyz", "las"):
        from leaffit_usd.splats import scans

        reader = {"ply_points": scans.read_points_ply, "xyz": scans.read_ascii_points,
                  "las": scans.read_las}[kind]
        return reader(path, drop_bad=drop_bad)
    if kind == "gltf":
        from leaffit_usd.splats.gltf_splats import read_gltf_splats

        return read_gltf_splats(path, drop_bad=drop_bad)
    if kind == "splat":
        from leaffit_usd.splats.splat import read_splat

        return read_splat(path, drop_bad=drop_bad)
    if kind in ("compressed_ply", "spz", "sog"):
        from leaffit_usd.splats.formats import read_with_gsply

        return read_with_gsply(path, kind, drop_bad=drop_bad)
    from leaffit_usd.splats.usd_io import read_usd_splats

    return read_usd_splats(path, prim=prim, drop_bad=drop_bad)
