"""Pipeline results (working frame) -> PlantAsset (asset frame).

Frames (``splats.frame``, docs/architecture.md): the fit, mesh and stem results are in the *working* frame (root at the
origin, up +Z, plant height 1). The *asset* frame is what the USD stage uses:

    x_asset = s_a * R_a @ x_working

with R_a = identity for ``up_axis='Z'`` and a -90 degree turn about X (working +Z -> asset +Y)
for ``up_axis='Y'``, and s_a the asset units per working unit:

* ``height_m`` given: the plant is ``height_m`` metres tall, s_a = height_m / meters_per_unit;
* otherwise the input capture's own units are kept (s_a = frame.height, input units per working
  unit), labelled with ``meters_per_unit`` (default 1: the capture is assumed to be in metres).

``PlantAsset.asset_to_input`` = frame.working_to_input @ (working <- asset), so every output maps
back to the input capture exactly.

Instances follow UsdGeom.PointInstancer: leaf j's similarity ``leaf_to_working[j]`` (rotation R_j,
uniform scale s_j, translation t_j) becomes positions[j] = s_a R_a t_j, orientations[j] =
quat(R_a R_j), scales[j] = s_a s_j (uniform). Targets stay in the instance local frame (template
units), so the rigid part and the MLS deformation compose.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.usd.wind import skeleton_from_segments
from leaffit_usd.version import __version__
from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.result import LeafFits
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.mesh.result import Stem, TemplateMesh
from leaffit_usd.serialize import jsonable
from leaffit_usd.splats.frame import Frame
from leaffit_usd.usd.asset import AssetLOD, PlantAsset

# Distance between the front and back sheets where they are drawn without the deformer (the
# prototype Mesh's points) and in the baked leaves, as a fraction of the template's largest extent
# (each side moves half of it along its own normal). Keeps viewers that draw back faces (Blender
# ignores doubleSided = false) from z-fighting; 0.1% of a 10 cm leaf is 0.1 mm, far above a
# 24-bit depth buffer's resolution at viewing distance, far below anything visible.
# The MLS itself always runs on the coplanar rest sheets (PlantAsset.template_points): pushed
# through the affine MLS, an offset along the normal is scaled by the fit's arbitrary normal
# response and the back sheet pokes through the front (measured: up to 67% of a leaf's vertices
# on rubber_tree).
DEFAULT_SHEET_OFFSET = 1e-3


def working_to_asset(up_axis: str = "Y", scale: float = 1.0) -> np.ndarray:
    """(4, 4) float64 similarity, working frame -> asset frame (see module docstring)."""
    up = str(up_axis).upper()
    if up == "Z":
        r = np.eye(3)
    elif up == "Y":
        r = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # working +Z -> asset +Y
    else:
        raise ParameterError("up_axis", "'Y' or 'Z'", up_axis)
    if not (np.isfinite(scale) and scale > 0):
        raise ParameterError("scale", "a positive number", scale)
    m = np.eye(4)
    m[:3, :3] = scale * r
    return m


def asset_scale(frame: Frame, meters_per_unit: float = 1.0, height_m: float | None = None) -> float:
    """Asset units per working unit (see module docstring)."""
    if not (np.isfinite(meters_per_unit) and meters_per_unit > 0):
        raise ParameterError("--meters-per-unit", "a positive number", meters_per_unit)
    if height_m is not None:
        if not (np.isfinite(height_m) and height_m > 0):
            raise ParameterError("--height", "a positive height in metres", height_m)
        return float(height_m) / float(meters_per_unit)
    return float(frame.height)


def split_similarity(m: np.ndarray):
    """(L, 4, 4) similarities -> rotations (L, 3, 3), uniform scales (L,), translations (L, 3).

    The linear part is projected onto the nearest rotation (SVD), so slightly non-orthogonal
    input from float32 round trips is tolerated. Raises ParameterError for a reflection or a
    zero scale.
    """
    m = np.asarray(m, np.float64)
    lin = m[:, :3, :3]
    det = np.linalg.det(lin)
    if not np.all(np.isfinite(det)) or np.any(det <= 0):
        raise ParameterError("leaf_to_working", "proper similarities (positive determinant)",
                             f"determinants {det[~(det > 0)][:3].tolist()}")
    s = np.cbrt(det)
    u, _, vt = np.linalg.svd(lin / s[:, None, None])
    rot = u @ vt
    return rot, s, m[:, :3, 3].copy()


def asset_from_results(template: TemplateMesh, fits: LeafFits, stem: Stem | None, frame: Frame,
                       up_axis: str = "Y", meters_per_unit: float = 1.0,
                       height_m: float | None = None, sheet_offset: float = DEFAULT_SHEET_OFFSET,
                       input_sha256: str = "", params: dict | None = None,
                       extra_metadata: dict | None = None, pot=None) -> PlantAsset:
    """Assemble the PlantAsset (asset frame) from the stage results (working frame).

    template : TemplateMesh, template local frame; fits : LeafFits; stem : Stem or None
    (no stem geometry); frame : the input <-> working similarity.
    sheet_offset : front/back sheet separation as a fraction of the template's largest extent;
        recorded (metadata["sheet_offset"], in template units) and applied by the writer to the
        prototype's drawn points and to the baked leaves, never to the MLS rest points.
    params : the parameters used, recorded in the stage's customData.
    pot : a ``mesh.pot.PotMesh`` (working frame) or None.
    """
    s_a = asset_scale(frame, meters_per_unit, height_m)
    w2a = working_to_asset(up_axis, s_a)
    r_a = w2a[:3, :3] / s_a
    a2w = np.linalg.inv(w2a)
    asset_to_input = frame.working_to_input @ a2w

    L = len(fits.leaf_labels)
    if fits.targets.shape != (L, fits.K, 3) or fits.leaf_to_working.shape != (L, 4, 4):
        raise ParameterError("fits", f"targets (L, K, 3) and leaf_to_working (L, 4, 4) with L={L}",
                             f"{fits.targets.shape} and {fits.leaf_to_working.shape}")
    if L:
        rot, s, t = split_similarity(fits.leaf_to_working)
    else:
        rot, s, t = np.zeros((0, 3, 3)), np.zeros(0), np.zeros((0, 3))
    positions = (s_a * t @ r_a.T).astype(np.float32)
    orientations = matrix_to_quat(r_a[None] @ rot).astype(np.float32) if L else np.zeros((0, 4), np.float32)
    scales = np.repeat((s_a * s)[:, None], 3, axis=1).astype(np.float32)

    pts = np.asarray(template.points, np.float32)
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    offset = float(sheet_offset) * extent
    tpl_points = pts.copy()

    stem_points, stem_faces, stem_colors = _stem_arrays(stem, s_a, r_a)
    skeleton, skeleton_parents = _skeleton(stem, s_a, r_a)
    lods = _asset_lods(template, stem, s_a, r_a)

    metadata = {
        "tool": "leaffit-usd",
        "tool_version": __version__,
        "input_sha256": input_sha256,
        "up_axis": str(up_axis).upper(),
        "meters_per_unit": float(meters_per_unit),
        "height_m": None if height_m is None else float(height_m),
        "asset_units_per_working_unit": s_a,
        "frame": frame.to_dict(),
        "sheet_offset": offset,
        "template_label": int(fits.template_label),
        "fit_errors": np.asarray(fits.errors, np.float64).round(7).tolist(),
        "fit_fallback": np.asarray(fits.fallback, bool).tolist(),
        "params": jsonable(params or {"fit": fits.params}),
    }
    if extra_metadata:
        metadata.update(jsonable(extra_metadata))
    return PlantAsset(
        template_points=tpl_points,
        template_faces=np.asarray(template.faces, np.int32),
        template_normals=np.asarray(template.normals, np.float32),
        template_uvs=np.asarray(template.uvs, np.float32),
        template_side=np.asarray(template.side, np.uint8),
        template_controls=np.asarray(fits.template_controls, np.float32),
        targets=np.asarray(fits.targets, np.float32),
        positions=positions,
        orientations=orientations,
        scales=scales,
        leaf_labels=np.asarray(fits.leaf_labels, np.int32),
        sigma=float(fits.sigma),
        reg=float(fits.reg),
        stem_points=stem_points,
        stem_faces=stem_faces,
        asset_to_input=asset_to_input,
        metadata=metadata,
        stem_colors=stem_colors,
        lods=lods,
        skeleton_points=skeleton,
        skeleton_parents=skeleton_parents,
        pot=None if pot is None else _pot_to_asset(pot, s_a, r_a),
    )


def _stem_arrays(m, s_a: float, r_a: np.ndarray):
    """A stem mesh (LOD) in the asset frame: (points (P, 3) float32, faces (G, 3) int32, colours
    (P, 3) float32 or None); empty without one."""
    if m is None or not len(m.points):
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), None
    c = getattr(m, "colors", None)
    return ((s_a * np.asarray(m.points, np.float64) @ r_a.T).astype(np.float32),
            np.asarray(m.faces, np.int32), None if c is None else np.asarray(c, np.float32))


def _asset_lods(template, stem, s_a: float, r_a: np.ndarray) -> list:
    """The coarser levels of detail (AssetLOD per level; a level the template or the stem lacks
    repeats LOD0's)."""
    t_lods = list(getattr(template, "lods", []) or [])
    s_lods = list(getattr(stem, "lods", []) or []) if stem is not None else []
    lods = []
    for k in range(max(len(t_lods), len(s_lods))):
        t = t_lods[k] if k < len(t_lods) else template
        sp, sf, sc = _stem_arrays(s_lods[k] if k < len(s_lods) else stem, s_a, r_a)
        lods.append(AssetLOD(template_points=np.asarray(t.points, np.float32),
                             template_faces=np.asarray(t.faces, np.int32),
                             template_normals=np.asarray(t.normals, np.float32),
                             template_uvs=np.asarray(t.uvs, np.float32),
                             template_side=np.asarray(t.side, np.uint8),
                             stem_points=sp, stem_faces=sf, stem_colors=sc))
    return lods


def _skeleton(stem, s_a: float, r_a: np.ndarray):
    """The stem skeleton (``usd.wind.skeleton_from_segments``) in the asset frame: (points (S, 3)
    float32, parents (S,) int32); empty without a stem."""
    if stem is None:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.int32)
    pts, parents = skeleton_from_segments(stem.starts, stem.ends, stem.parent)
    return (s_a * np.asarray(pts, np.float64) @ r_a.T).astype(np.float32), parents


def _pot_to_asset(pot, s_a: float, r_a: np.ndarray):
    """The PotMesh (working frame) in the asset frame (a copy)."""
    import dataclasses

    def move(p):
        return (s_a * np.asarray(p, np.float64) @ r_a.T).astype(np.float32)
    return dataclasses.replace(pot, pot_points=move(pot.pot_points), soil_points=move(pot.soil_points))
