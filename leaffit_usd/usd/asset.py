"""The PlantAsset value: everything a LeafFit USD stage holds, as arrays (asset frame).

``usd.writer`` writes it, ``usd.reader`` reads it back, ``runtime`` evaluates it. Instance
transforms follow UsdGeom.PointInstancer: a template point x (template local frame) of instance j
lands at  positions[j] + rotate(orientations[j], scales[j] * MLS_j(x))  in the asset frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PlantAsset:
    """A LeafFit plant.

    template_points : (V, 3) float32, template mesh vertices (both sides), template local frame
    template_faces : (F, 3) int32
    template_normals : (V, 3) float32
    template_uvs : (V, 2) float32
    template_side : (V,) uint8, 0 front / 1 back
    template_controls : (K, 3) float32, MLS source control points p, template local frame
    targets : (L, K, 3) float32, per-instance MLS targets q_j, instance local frame (pre-scale)
    positions : (L, 3) float32, instance translations, asset frame
    orientations : (L, 4) float32 unit quaternions (w, x, y, z)
    scales : (L, 3) float32, instance scales
    leaf_labels : (L,) int32, segmentation label of each instance
    sigma, reg : MLS kernel width and regulariser (template local units)
    stem_points : (P, 3) float32, asset frame;  stem_faces : (G, 3) int32
    asset_to_input : (4, 4) float64, asset frame -> the input capture's frame
    front_texture, back_texture : texture file paths as authored (relative to the stage)
    metadata : parameters, input hash, tool version
    stem_colors : (P, 3) float32 sRGB vertex colours of the stem (from its Gaussians), or None
    lods : coarser levels of detail, each an :class:`AssetLOD` (LOD1, LOD2, ...); the fields
        above are LOD0
    tints : (L, 3) float32 or None, per-leaf linear-RGB gain multiplied into the template texture
        (``mesh.appearance``; USD ``primvars:leaffit:tint``, glTF ``COLOR_0``); None = no tint
    skeleton_points : (S, 3) float32, asset frame, the stem skeleton's nodes (node 0 the root),
        or None; skeleton_parents : (S,) int32, each node's parent (-1 at the root), or None
        (the wind data hangs every leaf on a node: ``usd.wind``)
    pot : the pot and soil meshes in the asset frame (``mesh.pot.PotMesh``'s fields) or None
        (``convert --pot``; never part of the leaves or the stem)
    """

    template_points: np.ndarray
    template_faces: np.ndarray
    template_normals: np.ndarray
    template_uvs: np.ndarray
    template_side: np.ndarray
    template_controls: np.ndarray
    targets: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    scales: np.ndarray
    leaf_labels: np.ndarray
    sigma: float
    reg: float
    stem_points: np.ndarray
    stem_faces: np.ndarray
    asset_to_input: np.ndarray
    front_texture: str = ""
    back_texture: str = ""
    metadata: dict = field(default_factory=dict)
    stem_colors: np.ndarray | None = None
    lods: list = field(default_factory=list)
    tints: np.ndarray | None = None
    skeleton_points: np.ndarray | None = None
    skeleton_parents: np.ndarray | None = None
    pot: object | None = None

    @property
    def n_leaves(self) -> int:
        return int(len(self.targets))

    def at_lod(self, k: int) -> "PlantAsset":
        """A copy whose template and stem are those of level of detail ``k`` (0 = this one)."""
        import dataclasses

        if k == 0:
            return self
        lod = self.lods[k - 1]
        return dataclasses.replace(
            self, template_points=lod.template_points, template_faces=lod.template_faces,
            template_normals=lod.template_normals, template_uvs=lod.template_uvs,
            template_side=lod.template_side, stem_points=lod.stem_points,
            stem_faces=lod.stem_faces, stem_colors=lod.stem_colors, lods=[])

    @property
    def sheet_offset(self) -> float:
        """Front/back sheet separation (template units; 0 = coplanar), ``metadata["sheet_offset"]``.

        The MLS rest sheets (``template_points``) coincide; the stage draws the prototype with
        each vertex moved by sheet_offset/2 along its own normal (:func:`offset_sheets`), and
        explicit leaves push each sheet apart the same way (``runtime.evaluator.asset_leaves``).
        """
        return float((self.metadata or {}).get("sheet_offset", 0.0) or 0.0)

    def drawn_template_points(self) -> np.ndarray:
        """(V, 3) float32 prototype points as a stage draws them: the rest points moved by
        sheet_offset/2 along their own unit normals (front up, back down)."""
        off = self.sheet_offset
        return offset_sheets(self.template_points, self.template_normals, off) if off > 0 else \
            np.asarray(self.template_points, np.float32)


def offset_sheets(points: np.ndarray, normals: np.ndarray, offset: float) -> np.ndarray:
    """Move every vertex by offset/2 along its own (unit) normal: (V, 3) float32.

    points, normals : (V, 3) template local frame; a negative offset undoes a positive one.
    """
    n = np.asarray(normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return (np.asarray(points, np.float64) + 0.5 * offset * n).astype(np.float32)

@dataclass
class AssetLOD:
    """One coarser level of detail: the template (same layout as PlantAsset's template_* fields,
    template local frame, same textures) and the stem (asset frame)."""

    template_points: np.ndarray
    template_faces: np.ndarray
    template_normals: np.ndarray
    template_uvs: np.ndarray
    template_side: np.ndarray
    stem_points: np.ndarray
    stem_faces: np.ndarray
    stem_colors: np.ndarray | None = None
