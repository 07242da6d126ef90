"""Per-leaf appearance: how each leaf's colour differs from the one template texture.

Every leaf of a LeafFit asset shows the same two textures (the paper's stated limitation: all
leaves look identical in colour). Here each leaf gets a *tint*, a per-channel linear-RGB gain
that, multiplied into the template texture, reproduces the leaf's own mean colour:

    tint_j[c] = sum_i w_i lin(g_i[c]) / sum_i w_i lin(T(uv_i)[c])         (c = R, G, B)

over leaf j's Gaussians i (colour g_i, opacity w_i), where uv_i is the texture coordinate of the
point of leaf j's fitted mesh closest to Gaussian i (the template sheet deformed by the leaf's
MLS field and placed by its similarity, working frame) and T is the texture of the side the
Gaussian lies on (front if it is above the surface along the face normal, back otherwise).
``lin`` is the sRGB transfer function (Gaussian colours and textures are display-referred sRGB;
gains multiply light, so they are measured in linear RGB). A leaf with fewer than
``min_gaussians`` usable samples keeps tint (1, 1, 1).

This is the least-squares gain for the mean only (colour statistics beyond the mean, such as a
spatial gradient across the leaf, are not modelled).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.mls import deform, mls_weights
from leaffit_usd.fit.result import LeafFits
from leaffit_usd.image_io import srgb_to_linear
from leaffit_usd.mesh.result import TemplateMesh

MAX_TINT = 4.0   # a gain beyond this is a mis-segmented leaf or a black texel region, not colour


@dataclass
class LeafTints:
    """Per-leaf tints, one row per fit (``LeafFits`` row order).

    tints : (L, 3) float32, linear-RGB gains multiplied into the template texture (1 = no change)
    samples : (L,) int32, Gaussians that contributed to each leaf's estimate
    """

    tints: np.ndarray
    samples: np.ndarray
    params: dict = field(default_factory=dict)


def sample_texture(tex: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-texel look-up. tex : (H, W, 3|4) uint8, row 0 = top (v = 1); uv : (N, 2) USD st.
    Returns (rgb (N, 3) float64 sRGB in [0, 1], alpha (N,) float64; 1 for an RGB texture)."""
    t = np.asarray(tex)
    h, w = t.shape[:2]
    uv = np.asarray(uv, np.float64)
    col = np.clip(np.floor(uv[:, 0] * w), 0, w - 1).astype(np.int64)
    row = np.clip(np.floor((1.0 - uv[:, 1]) * h), 0, h - 1).astype(np.int64)
    px = t[row, col].astype(np.float64) / 255.0
    alpha = px[:, 3] if t.shape[2] == 4 else np.ones(len(px))
    return px[:, :3], alpha


def closest_on_mesh(points: np.ndarray, verts: np.ndarray, faces: np.ndarray):
    """Closest surface point of a triangle mesh (open3d RaycastingScene).

    Returns (face (N,) int64, barycentric (N, 3) float64, signed distance (N,) float64 along the
    face normal, + on the side the counter-clockwise winding faces)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    r = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, np.float32)))
    cp = r["points"].numpy().astype(np.float64)
    n = r["primitive_normals"].numpy().astype(np.float64)
    fid = r["primitive_ids"].numpy().astype(np.int64)
    buv = r["primitive_uvs"].numpy().astype(np.float64)          # weights of vertices 1 and 2
    bary = np.column_stack([1.0 - buv.sum(1), buv[:, 0], buv[:, 1]])
    return fid, bary, ((np.asarray(points, np.float64) - cp) * n).sum(1)


def measure_leaf_tints(cloud_working, labels: np.ndarray, fits: LeafFits, template: TemplateMesh,
                       min_gaussians: int = 20, min_alpha: float = 0.5) -> LeafTints:
    """Per-leaf tints (module docstring) of every fitted leaf.

    cloud_working : GaussianCloud, working frame (the cloud the fit ran on)
    labels : (N,) int, segmentation label of every Gaussian of ``cloud_working`` (0 = stem)
    fits : LeafFits; template : TemplateMesh (its front sheet and textures)
    min_alpha : texels below this alpha (outside the template's outline) are not used
    """
    labels = np.asarray(labels)
    if labels.shape != (len(cloud_working),):
        raise ParameterError("labels", f"({len(cloud_working)},) one label per Gaussian", labels.shape)
    S = len(template.sheet_points)
    sheet = np.asarray(template.points[:S], np.float64)                 # front copy, rest sheet
    faces = np.asarray(template.sheet_faces, np.int64)
    uv_front = np.asarray(template.uvs[:S], np.float64)
    uv_back = np.asarray(template.uvs[S:2 * S], np.float64)
    A = mls_weights(np.asarray(fits.template_controls, np.float64), sheet, fits.sigma, fits.reg)
    local = deform(A, np.asarray(fits.targets, np.float64))             # (L, S, 3)
    means = np.asarray(cloud_working.means, np.float64)
    colors = np.asarray(cloud_working.colors, np.float64)
    opac = np.asarray(cloud_working.opacities, np.float64)
    L = len(fits.leaf_labels)
    tints = np.ones((L, 3), np.float64)
    samples = np.zeros(L, np.int32)
    for j, lab in enumerate(np.asarray(fits.leaf_labels)):
        idx = np.flatnonzero(labels == lab)
        if len(idx) < min_gaussians or not len(faces):
            continue
        M = np.asarray(fits.leaf_to_working[j], np.float64)
        verts = local[j] @ M[:3, :3].T + M[:3, 3]
        fid, bary, sd = closest_on_mesh(means[idx], verts, faces)
        tri = faces[fid]
        front = sd >= 0
        uv = np.where(front[:, None],
                      np.einsum("nk,nkc->nc", bary, uv_front[tri]),
                      np.einsum("nk,nkc->nc", bary, uv_back[tri]))
        rgb_f, a_f = sample_texture(template.front_texture, uv)
        rgb_b, a_b = sample_texture(template.back_texture, uv)
        tex = np.where(front[:, None], rgb_f, rgb_b)
        ok = np.where(front, a_f, a_b) >= min_alpha
        if ok.sum() < min_gaussians:
            continue
        w = opac[idx][ok]
        num = (w[:, None] * srgb_to_linear(np.clip(colors[idx][ok], 0.0, 1.0))).sum(0)
        den = (w[:, None] * srgb_to_linear(tex[ok])).sum(0)
        tints[j] = np.where(den > 1e-9, num / np.maximum(den, 1e-12), 1.0)
        samples[j] = int(ok.sum())
    return LeafTints(tints=np.clip(tints, 0.0, MAX_TINT).astype(np.float32), samples=samples,
                     params={"min_gaussians": int(min_gaussians), "min_alpha": float(min_alpha),
                             "space": "linear sRGB gain"})
