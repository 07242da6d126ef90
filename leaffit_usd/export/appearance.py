"""How close a delivered leaf's colour is to the captured leaf: per-leaf CIE ΔE*ab (1976).

For leaf j both are rendered in the leaf's own instance frame, looking down its +Z (the upper,
front side), at ``res`` x ``res`` pixels over the same bounds:

* the **input leaf**: its Gaussians (segmentation label j) moved into that frame, splatted with
  the project's orthographic renderer (``splats.render``);
* the **asset leaf**: the evaluated leaf (template deformed by the leaf's MLS targets), front
  sheet rasterised (``edit.raster``), texels of the front texture, multiplied by the leaf's tint
  in linear RGB (``tinted=True``) or not.

The two mean colours over the pixels both cover (alpha > 0.5) are compared in CIELAB (sRGB, D65):
ΔE*ab = |Lab_input - Lab_asset|. About 1 is a just-noticeable difference, 2-10 visible at a
glance, beyond that the colours read as different.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.image_io import linear_to_srgb, srgb_to_linear
from leaffit_usd.mesh.appearance import sample_texture

_D65 = np.array([0.95047, 1.0, 1.08883])
_RGB2XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                     [0.2126729, 0.7151522, 0.0721750],
                     [0.0193339, 0.1191920, 0.9503041]])


def linear_to_lab(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB (..., 3) in [0, 1] -> CIELAB (..., 3), D65 white."""
    xyz = np.asarray(rgb, np.float64) @ _RGB2XYZ.T / _D65
    e = 216 / 24389
    f = np.where(xyz > e, np.cbrt(xyz), (24389 / 27 * xyz + 16) / 116)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]),
                     200 * (f[..., 1] - f[..., 2])], -1)


def delta_e76(lin_a: np.ndarray, lin_b: np.ndarray) -> np.ndarray:
    """CIE 1976 ΔE*ab between linear-sRGB colours (..., 3)."""
    return np.linalg.norm(linear_to_lab(lin_a) - linear_to_lab(lin_b), axis=-1)


def _similarity_inverse(m: np.ndarray) -> np.ndarray:
    return np.linalg.inv(np.asarray(m, np.float64))


def leaf_color_errors(asset, front_texture: np.ndarray, cloud_input, labels: np.ndarray,
                      tinted: bool = True, res: int = 96, min_pixels: int = 30) -> np.ndarray:
    """(L,) float64 per-leaf ΔE*ab between the input leaf and the asset leaf (module docstring);
    NaN for a leaf with fewer than ``min_pixels`` co-covered pixels.

    asset : PlantAsset (``tints`` used when ``tinted`` and present)
    front_texture : (H, W, 3|4) uint8, the asset's front texture (row 0 = top)
    cloud_input : GaussianCloud in the input capture's frame (``asset.asset_to_input`` maps to it)
    labels : (N,) int, segmentation label per Gaussian of ``cloud_input`` (``asset.leaf_labels``'
        numbering; 0 = not a leaf)
    """
    from leaffit_usd.edit.raster import rasterize
    from leaffit_usd.runtime.evaluator import LeafEvaluator, instance_matrices
    from leaffit_usd.splats.render import render_orthographic_np

    labels = np.asarray(labels)
    if labels.shape != (len(cloud_input),):
        raise ParameterError("labels", f"({len(cloud_input)},) one per Gaussian", labels.shape)
    L = asset.n_leaves
    tints = getattr(asset, "tints", None) if tinted else None
    if tints is not None:
        tints = np.asarray(tints, np.float64).reshape(-1, 3)
    ev = LeafEvaluator.from_asset(asset)
    local = ev.deform_local(asset.targets)                               # (L, V, 3)
    faces = np.asarray(asset.template_faces, np.int64)
    front_faces = faces[asset.template_side[faces].astype(np.int32).sum(1) < 2]
    uvs = np.asarray(asset.template_uvs, np.float64)
    M = instance_matrices(asset.positions, asset.orientations, asset.scales)
    input_to_asset = _similarity_inverse(asset.asset_to_input)
    means = np.asarray(cloud_input.means, np.float64)
    cov = np.asarray(cloud_input.covariances(), np.float64)
    colors = np.asarray(cloud_input.colors, np.float64)
    opac = np.asarray(cloud_input.opacities, np.float64)
    out = np.full(L, np.nan)
    for j in range(L):
        idx = np.flatnonzero(labels == asset.leaf_labels[j])
        if len(idx) < 10:
            continue
        T = _similarity_inverse(M[j]) @ input_to_asset                  # input -> instance local
        A = T[:3, :3]
        g_means = means[idx] @ A.T + T[:3, 3]
        g_cov = np.einsum("ij,njk,lk->nil", A, cov[idx], A)
        leaf = local[j]
        lo = np.minimum(leaf[:, :2].min(0), np.percentile(g_means[:, :2], 1, axis=0))
        hi = np.maximum(leaf[:, :2].max(0), np.percentile(g_means[:, :2], 99, axis=0))
        c, half = 0.5 * (lo + hi), 0.55 * float((hi - lo).max())
        bounds = (c[0] - half, c[0] + half, c[1] - half, c[1] + half)
        r = render_orthographic_np(g_means, g_cov, colors[idx], opac[idx], res, res, bounds)
        g_alpha = np.asarray(r.alpha, np.float64)
        g_rgb = np.asarray(r.color, np.float64) / np.maximum(g_alpha, 1e-6)[..., None]
        ras = rasterize(leaf, front_faces, res, res, bounds)
        uv = ras.interpolate(uvs, front_faces)[ras.mask]
        tex_rgb, tex_a = sample_texture(front_texture, uv)
        lin = srgb_to_linear(tex_rgb)
        if tints is not None:
            lin = np.clip(lin * tints[j], 0.0, 1.0)
        a_lin = np.zeros((res, res, 3))
        a_lin[ras.mask] = lin
        a_cov = np.zeros((res, res), bool)
        a_cov[ras.mask] = tex_a >= 0.5
        both = a_cov & (g_alpha > 0.5)
        if both.sum() < min_pixels:
            continue
        mean_in = srgb_to_linear(np.clip(g_rgb[both], 0, 1)).mean(0)
        mean_as = a_lin[both].mean(0)
        out[j] = float(delta_e76(mean_in, mean_as))
    return out


__all__ = ["delta_e76", "leaf_color_errors", "linear_to_lab", "linear_to_srgb"]
