"""Geometry retargeting across species (paper Sec. "Geometry retargeting across species").

Replace a plant's template leaf by another species' leaf while every instance keeps its placement
and overall shape:

1. orthographic views of the source (new) and target (current) template sheets in their PCA
   frames (template local frames: +X base -> apex, +Z normal); depth maps by rasterisation;
2. a 2D cage around each leaf from its outline, cut at apex and base (``edit.cage``);
3. interior samples of the source (farthest point sampling) carried into the target cage by mean
   value coordinates (``edit.mvc``), lifted to 3D with the source and target depths: dense 3D
   pairs (x_src, x_tar);
4. for every instance j the target points are moved by that instance's current MLS field,
   y_j = MLS_j(x_tar), and the new targets q'_j of the new template's K control points p' solve
   the linear least-squares problem  min |A'(x_src) q' - y_j|^2 + mu |q' - q0_j|^2  (affine MLS is
   linear in q, ``fit.mls``), q0_j being the control points carried the same way. This is the
   paper's "fit an MLS deformation to the dense correspondences", solved in closed form for all
   instances at once.
"""
from __future__ import annotations

import dataclasses
import logging

import numpy as np
from scipy import ndimage

from leaffit_usd.edit.cage import leaf_cage
from leaffit_usd.edit.mvc import transfer
from leaffit_usd.edit.raster import iou, rasterize
from leaffit_usd.errors import UserError
from leaffit_usd.fit.mls import deform, mls_weights
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.usd.asset import PlantAsset

log = logging.getLogger("leaffit_usd")


@dataclasses.dataclass
class RetargetParams:
    """n_side: cage vertices per side; n_samples: interior correspondences; res: depth map size (px);
    mu: Tikhonov weight towards the carried control points (relative to mean diag of A'^T A')."""

    n_side: int = 32
    n_samples: int = 512
    res: int = 256
    mu: float = 1e-3


def front_sheet(asset: PlantAsset) -> tuple[np.ndarray, np.ndarray]:
    """The single-sheet template (front copy): (S, 3) float64 points, (G, 3) int64 faces."""
    front = np.asarray(asset.template_side) == 0
    idx = np.flatnonzero(front)
    remap = np.full(len(front), -1, np.int64)
    remap[idx] = np.arange(len(idx))
    faces = remap[np.asarray(asset.template_faces, np.int64)]
    faces = faces[(faces >= 0).all(1)]
    if len(faces) == 0:
        raise UserError("the template has no front-side faces")
    return np.asarray(asset.template_points, np.float64)[idx], faces


def _depth_lookup(points, faces, xy, res):
    """Depth (z) of the sheet under each xy (P, 2); nearest covered pixel where xy falls outside."""
    lo, hi = points[:, :2].min(0), points[:, :2].max(0)
    pad = 0.02 * (hi - lo).max()
    bounds = (lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad)
    r = rasterize(points, faces, res, res, bounds)
    if not r.mask.any():
        raise UserError("the leaf sheet covers no pixel in its PCA view")
    _, (ri, ci) = ndimage.distance_transform_edt(~r.mask, return_indices=True)
    depth = r.depth[ri, ci]
    col = np.clip(((xy[:, 0] - bounds[0]) / (bounds[1] - bounds[0]) * res).astype(int), 0, res - 1)
    row = np.clip(((bounds[3] - xy[:, 1]) / (bounds[3] - bounds[2]) * res).astype(int), 0, res - 1)
    return depth[row, col]


def leaf_length(points: np.ndarray) -> float:
    """Distance from the base (origin) to the farthest point of the sheet, template units."""
    return float(np.linalg.norm(points[:, :2], axis=1).max())


def retarget_asset(asset: PlantAsset, source: PlantAsset, params: RetargetParams = RetargetParams()):
    """A new PlantAsset whose template is ``source``'s template, fitted to every instance of ``asset``.

    Returns (new_asset, report) where report has per-instance silhouette IoU in the leaf's PCA view.
    Textures: the caller points the new asset at the source's textures.
    """
    tp, tf = front_sheet(asset)
    sp, sf = front_sheet(source)
    cage_t = leaf_cage(tp, tf, params.n_side)
    cage_s = leaf_cage(sp, sf, params.n_side)
    # dense correspondences: interior samples of the source, carried into the target cage
    k_samples = min(params.n_samples, len(sp))
    xs = sp[farthest_point_sampling(sp, k_samples)]
    xt2 = transfer(cage_s, cage_t, xs[:, :2])
    xt = np.c_[xt2, _depth_lookup(tp, tf, xt2, params.res)]
    # new control points and their carried positions
    K = asset.template_controls.shape[0]
    p_new = sp[farthest_point_sampling(sp, K)]
    if len(p_new) < 4:
        raise UserError("the source leaf has too few vertices for control points")
    pc2 = transfer(cage_s, cage_t, p_new[:, :2])
    pc = np.c_[pc2, _depth_lookup(tp, tf, pc2, params.res)]
    # every instance's current MLS field applied to the target points
    p_old = np.asarray(asset.template_controls, np.float64)
    q_old = np.asarray(asset.targets, np.float64)
    y = deform(mls_weights(p_old, xt, asset.sigma, asset.reg), q_old)          # (L, M, 3)
    q0 = deform(mls_weights(p_old, pc, asset.sigma, asset.reg), q_old)         # (L, K, 3)
    sigma_new = asset.sigma * leaf_length(sp) / max(leaf_length(tp), 1e-12)
    a = mls_weights(p_new, xs, sigma_new, asset.reg)                           # (M, K)
    ata = a.T @ a
    mu = params.mu * float(np.mean(np.diag(ata)))
    lhs = ata + mu * np.eye(len(p_new))
    rhs = np.einsum("mk,lmc->lkc", a, y) + mu * q0
    q_new = np.linalg.solve(lhs[None], rhs)                                    # (L, K, 3)
    new = dataclasses.replace(
        asset,
        template_points=np.asarray(source.template_points, np.float32),
        template_faces=np.asarray(source.template_faces, np.int32),
        template_normals=np.asarray(source.template_normals, np.float32),
        template_uvs=np.asarray(source.template_uvs, np.float32),
        template_side=np.asarray(source.template_side, np.uint8),
        template_controls=p_new.astype(np.float32),
        targets=q_new.astype(np.float32),
        sigma=float(sigma_new),
        front_texture=source.front_texture,
        back_texture=source.back_texture,
        metadata={**asset.metadata, "retargeted_from": source.metadata.get("input_sha256", "")},
    )
    ious = silhouette_ious(asset, new, params.res)
    report = {"instances": int(len(q_new)), "iou_min": float(ious.min()) if len(ious) else 1.0,
              "iou_mean": float(ious.mean()) if len(ious) else 1.0, "iou": ious.tolist(),
              "K": int(len(p_new)), "correspondences": int(len(xs)), "sigma": float(sigma_new)}
    log.info("retarget: %d instances, silhouette IoU min %.3f mean %.3f", len(q_new),
             report["iou_min"], report["iou_mean"])
    return new, report


def instance_sheets(asset: PlantAsset) -> tuple[np.ndarray, np.ndarray]:
    """Every instance's deformed front sheet in its own local frame (pre-scale): (L, S, 3), faces."""
    pts, faces = front_sheet(asset)
    w = mls_weights(asset.template_controls, pts, asset.sigma, asset.reg)
    return deform(w, np.asarray(asset.targets, np.float64)), faces


def silhouette_ious(before: PlantAsset, after: PlantAsset, res: int = 256) -> np.ndarray:
    """(L,) IoU of each instance's silhouette before/after, in the instance's local xy (PCA) view."""
    a, fa = instance_sheets(before)
    b, fb = instance_sheets(after)
    out = np.empty(len(a))
    for j in range(len(a)):
        both = np.vstack([a[j], b[j]])
        lo, hi = both[:, :2].min(0), both[:, :2].max(0)
        pad = 0.02 * (hi - lo).max()
        bounds = (lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad)
        out[j] = iou(rasterize(a[j], fa, res, res, bounds).mask, rasterize(b[j], fb, res, res, bounds).mask)
    return out
