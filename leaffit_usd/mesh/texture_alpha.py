"""From a premultiplied splat render to an RGBA texture: straight colour, a cleaned cut-out
alpha with a one-texel anti-aliased rim, colours dilated over the whole image (mip-maps never
bleed background into the leaf), and the inpainted fallback for sparse captures."""
from __future__ import annotations

import numpy as np


def _dilate_colors(rgb: np.ndarray, solid: np.ndarray) -> np.ndarray:
    """Every non-solid texel takes the colour of its nearest solid texel (edge padding to infinity)."""
    from scipy.ndimage import distance_transform_edt

    if solid.all() or not solid.any():
        return rgb
    _, (ri, ci) = distance_transform_edt(~solid, return_indices=True)
    return rgb[ri, ci]


def _clean_mask(mask: np.ndarray, sheet_mask: np.ndarray) -> np.ndarray:
    """Closing (disk of radius ``max(2, size/128)`` texels: closes nicks where the capture's
    margin is sparse, keeps serration teeth), holes filled, within the sheet (+2 texels),
    components smaller than 1 % of the largest removed."""
    from scipy.ndimage import binary_closing, binary_dilation, binary_fill_holes, label

    if not mask.any():
        return mask
    rc = max(2, int(round(max(mask.shape) / 128)))
    yy, xx = np.mgrid[-rc:rc + 1, -rc:rc + 1]
    disk = xx * xx + yy * yy <= rc * rc
    m = binary_closing(np.pad(mask, rc + 1), structure=disk)[rc + 1:-rc - 1, rc + 1:-rc - 1] | mask
    if sheet_mask.any():
        yy, xx = np.mgrid[-2:3, -2:3]
        m &= binary_dilation(sheet_mask, structure=xx * xx + yy * yy <= 4)
    m = binary_fill_holes(m)
    lab, n = label(m)
    if n > 1:
        sizes = np.bincount(lab.ravel())[1:]
        m = np.isin(lab, 1 + np.flatnonzero(sizes >= 0.01 * sizes.max()))
    return m


def side_texture(color: np.ndarray, alpha: np.ndarray, thr: float, sheet_mask: np.ndarray):
    """RGBA float (H, W, 4) straight alpha from a premultiplied render (color (H, W, 3), alpha
    (H, W)), and the splat coverage of the sheet's silhouette."""

    straight = color / np.maximum(alpha, 1e-6)[..., None]
    straight = np.clip(straight, 0.0, 1.0)
    # opaque inside (pin-holes and one-or-two-texel nicks closed), specks off the rim dropped
    solid = _clean_mask(alpha > thr, sheet_mask)
    # a one-texel anti-aliased rim: texels just outside the cut take alpha / thr, the rest 0
    from scipy.ndimage import distance_transform_edt

    rim = (distance_transform_edt(~solid) <= 1.5) & ~solid if solid.any() else np.zeros_like(solid)
    a = np.where(solid, 1.0, np.where(rim, np.clip(alpha / thr, 0.0, 1.0), 0.0))
    # nothing outside the sheet is ever drawn: keep alpha within the sheet's silhouette (+1 texel,
    # the bilinear rim) so splats beyond the rim (or stray ones) never reach the image border; the
    # outline itself lies on the whole splat set's silhouette (outline_fit.py), so a widened
    # bake subset's softer edge does not move the cut-out
    if sheet_mask.any():
        a = np.where(distance_transform_edt(~sheet_mask) <= 1.0, a, 0.0)
    cover = float((alpha > thr)[sheet_mask].mean()) if sheet_mask.any() else 0.0
    rgb = _dilate_colors(straight, alpha > 0.9 * thr)
    return np.concatenate([rgb, a[..., None]], -1), cover


def inpainted(tex: np.ndarray, sheet_mask: np.ndarray, thr: float) -> np.ndarray:
    """Colour of the covered texels spread over the whole image; alpha = the sheet silhouette."""
    solid = tex[..., 3] > thr
    rgb = _dilate_colors(tex[..., :3], solid) if solid.any() else np.full_like(tex[..., :3], 0.3)
    return np.concatenate([rgb, sheet_mask[..., None].astype(np.float64)], -1)
