"""Texture edits on the template's front/back textures (they reach every leaf through the shared UVs).

Images are (H, W, 4) float32 RGBA in [0, 1], straight (not premultiplied) alpha, row 0 = top
(v = 1), as ``mesh.result.TemplateMesh`` stores them. Image work is done with OpenImageIO's
ImageBufAlgo (resize, warp, over, fillholes_pushpull); numpy only moves pixels in and out.
"""
from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
from OpenImageIO import ImageBufAlgo as iba

from leaffit_usd.errors import ParameterError


def _to_buf(img: np.ndarray) -> oiio.ImageBuf:
    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    if c == 4:
        spec.alpha_channel = 3
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, c), np.ascontiguousarray(img, np.float32))
    return buf


def _from_buf(buf: oiio.ImageBuf) -> np.ndarray:
    return np.asarray(buf.get_pixels(oiio.FLOAT), np.float32).reshape(
        buf.spec().height, buf.spec().width, buf.spec().nchannels)


def _premultiply(img):
    out = img.copy()
    out[..., :3] *= out[..., 3:4]
    return out


def _unpremultiply(img):
    out = img.copy()
    a = out[..., 3:4]
    out[..., :3] = np.where(a > 1e-6, out[..., :3] / np.maximum(a, 1e-6), 0.0)
    return out


# ---- edits ----------------------------------------------------------------------------------
def resize_image(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """(h, w, C) float image resampled to (height, width, C) with OIIO's filtered resize."""
    dst = oiio.ImageBuf(oiio.ImageSpec(width, height, img.shape[2], oiio.FLOAT))
    iba.resize(dst, _to_buf(img))
    return _from_buf(dst)


def replace_texture(template: np.ndarray, new_image: np.ndarray, new_has_alpha: bool = False) -> np.ndarray:
    """The new image resized to the template's resolution (OIIO resize, filtered).

    template : (H, W, 4) the current texture; new_image : (h, w, 4) any size.
    The alpha (leaf silhouette) is the template's unless ``new_has_alpha``.
    """
    out = np.clip(resize_image(new_image, *template.shape[:2]), 0, 1)
    if not new_has_alpha:
        out[..., 3] = template[..., 3]
    return out


def overlay_decal(texture: np.ndarray, decal: np.ndarray, uv=(0.5, 0.5), scale: float = 0.25,
                  rotation_deg: float = 0.0) -> np.ndarray:
    """Composite ``decal`` (h, w, 4) over ``texture`` (H, W, 4) ('over', premultiplied).

    uv : decal centre in texture coordinates, (u, v) in [0, 1]^2 (v up);
    scale : decal width as a fraction of the texture width (aspect kept);
    rotation_deg : counter-clockwise rotation in the UV plane.
    The texture's alpha (silhouette) is kept: the decal shows only on the leaf.
    """
    u, v = float(uv[0]), float(uv[1])
    if not (0.0 <= u <= 1.0 and 0.0 <= v <= 1.0):
        raise ParameterError("--uv", "a decal centre inside the UV square [0,1]^2", (u, v))
    if not (np.isfinite(scale) and scale > 0):
        raise ParameterError("--scale", "a positive fraction of the texture width", scale)
    H, W = texture.shape[:2]
    h, w = decal.shape[:2]
    s = scale * W / w
    th = np.deg2rad(rotation_deg)
    c, sn = np.cos(th), np.sin(th)
    # pixel coordinates (x right, y down): rotation CCW in UV is clockwise-looking in y-down pixels
    rot = np.array([[c, sn], [-sn, c]])
    centre_dst = np.array([u * W, (1.0 - v) * H])
    centre_src = np.array([w / 2.0, h / 2.0])
    lin = rot * s
    t = centre_dst - lin @ centre_src
    # OIIO's warp takes a 3x3 matrix in row-vector convention: [x y 1] @ M
    m = np.eye(3)
    m[:2, :2] = lin.T
    m[2, :2] = t
    placed = oiio.ImageBuf(oiio.ImageSpec(W, H, 4, oiio.FLOAT))
    iba.warp(placed, _to_buf(_premultiply(decal)), tuple(m.ravel()), filtername="lanczos3",
             wrap="black")
    comp = oiio.ImageBuf(oiio.ImageSpec(W, H, 4, oiio.FLOAT))
    iba.over(comp, placed, _to_buf(_premultiply(texture)))
    out = np.clip(_unpremultiply(np.clip(_from_buf(comp), 0, 1)), 0, 1)
    out[..., 3] = texture[..., 3]
    return out


def masked_fill(texture: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Repaint the masked region from its surroundings (OIIO push-pull hole filling).

    mask : (H, W) bool or float (> 0.5 = repaint). Pixels outside the leaf (alpha 0) do not
    contribute colour; the texture's alpha is kept.
    """
    mask = np.asarray(mask)
    if mask.shape != texture.shape[:2]:
        raise ParameterError("--mask", f"a mask of the texture's size {texture.shape[1]}x{texture.shape[0]}",
                             f"{mask.shape[1] if mask.ndim > 1 else '?'}x{mask.shape[0]}")
    m = mask > 0.5 if mask.dtype != bool else mask
    holes = _premultiply(texture)
    holes[m] = 0.0
    filled = oiio.ImageBuf(oiio.ImageSpec(texture.shape[1], texture.shape[0], 4, oiio.FLOAT))
    if not iba.fillholes_pushpull(filled, _to_buf(holes)):
        raise RuntimeError("fillholes_pushpull failed: " + filled.geterror())
    out = texture.copy()
    out[m, :3] = np.clip(_unpremultiply(_from_buf(filled))[m, :3], 0, 1)
    return out
