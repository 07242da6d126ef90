"""Values produced by ``mesh``: the template leaf mesh with its two textures, and the stem."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class TemplateMesh:
    """The two-sided template leaf, template local frame (see ``fit.result``), working units.

    points : (V, 3) float32, vertices; the front copy is points[:V/2], the back copy points[V/2:]
        (duplicated per side so each side has its own UVs and split normals)
    faces : (F, 3) int32, triangles; front faces wind counter-clockwise seen from +Z
    normals : (V, 3) float32, per-vertex normals (front +Z-ish, back -Z-ish)
    uvs : (V, 2) float32, texture coordinates in [0, 1]^2 (see the UV convention below)
    side : (V,) uint8, 0 = front vertex, 1 = back vertex
    front_texture, back_texture : (H, W, 4) uint8 RGBA images (straight alpha), row 0 = top (v = 1)
    sheet_points, sheet_faces : the single-sheet mesh before duplication ((S, 3), (G, 3))
    report : quality figures (counts, distances, holes, coverage)
    lods : coarser levels of detail (LOD1, LOD2, ...), each a :class:`TemplateLOD`

    UV convention: each side has its own texture; ``uvs`` of front vertices index
    ``front_texture`` and of back vertices ``back_texture``. USD's st has v up, so texel row
    r covers v in [1 - (r+1)/H, 1 - r/H].
    """

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    side: np.ndarray
    front_texture: np.ndarray
    back_texture: np.ndarray
    sheet_points: np.ndarray
    sheet_faces: np.ndarray
    report: dict = field(default_factory=dict)
    lods: list = field(default_factory=list)


@dataclass
class TemplateLOD:
    """A coarser level of detail of the two-sided template (same frame, layout and textures as
    :class:`TemplateMesh`): points (V, 3), faces (F, 3), normals (V, 3), uvs (V, 2), side (V,)."""

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    side: np.ndarray


@dataclass
class StemMesh:
    """One level of detail of the stem mesh, working frame.

    points : (P, 3) float32; faces : (G, 3) int32, outward; colors : (P, 3) float32 sRGB in
    [0, 1] from the stem's Gaussians, or None
    """

    points: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None


@dataclass
class Stem:
    """The stem as swept tubes, working frame.

    starts, ends : (E, 3) float32, axis segments between consecutive rings of every tube
    radii_start, radii_end : (E,) float32, tube radius at each end, working units
    parent : (E,) int64, index of the parent segment (previous ring of the same tube; for a
        branch's first segment, the parent tube's segment it grows from; -1 at the root)
    points, faces : the LOD0 triangle mesh of all tubes ((P, 3) float32, (F, 3) int32)
    colors : (P, 3) float32 sRGB vertex colours from the stem Gaussians, or None
    lods : coarser levels of detail (LOD1, LOD2, ...), each a :class:`StemMesh`
    info : how it was built (skeleton kind, node and tube counts, radii priors)
    """

    starts: np.ndarray
    ends: np.ndarray
    radii_start: np.ndarray
    radii_end: np.ndarray
    parent: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None
    lods: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
