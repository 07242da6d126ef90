"""Image files (the one reader and writer): textures, decals, previews, quick-looks.

In memory an image is (H, W, C) with row 0 = top, C = 3 (RGB) or 4 (RGBA, straight -- not
premultiplied -- alpha); uint8 in 0..255 or float in [0, 1], sRGB-encoded. On disk the format
follows the file's suffix: PNG (8-bit sRGB, alpha kept), JPEG (8-bit, alpha dropped), EXR (half
float, RGB linear, alpha as is). Writes are atomic (temp + rename). Every failure, reading or
writing, raises :class:`ImageError`.
"""
from __future__ import annotations

import os

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.io_util import atomic_path

WRITE_FORMATS = ("png", "jpg", "exr")
PNG_LEVEL, PNG_FILTER = 7, 32   # zlib level and libpng row filter (32: "up"); see write_image


class ImageError(InputFileError):
    """An image file could not be read or written; the message names the file."""


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (the IEC 61966-2-1 curve), same shape."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """Linear values -> sRGB-encoded values in [0, 1] (clipped first), same shape."""
    c = np.clip(c, 0, 1)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)


def image_format(path) -> str:
    """The image format a path's suffix names, lower case ('jpeg' -> 'jpg'; '' without one)."""
    ext = os.path.splitext(os.fspath(path))[1].lower().lstrip(".")
    return {"jpeg": "jpg"}.get(ext, ext)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Any image OpenImageIO reads -> (H, W, 4) float32 RGBA in [0, 1], sRGB-encoded, straight alpha.

    Grey images are expanded to RGB, images without alpha get alpha = 1, and EXR (linear)
    colours are encoded to sRGB. Raises :class:`ImageError` (missing file, not an image).
    """
    import OpenImageIO as oiio

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageError(path, "no such image file")
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # keep straight alpha (no premultiplication)
    buf = oiio.ImageBuf(path, 0, 0, config)
    if buf.has_error or buf.spec().width == 0:
        raise ImageError(path, "cannot read image: " + (buf.geterror().splitlines() or ["unknown format"])[0])
    px = np.asarray(buf.get_pixels(oiio.FLOAT), np.float32)
    if px.ndim == 2:
        px = px[:, :, None]
    c = px.shape[2]
    if c == 1:
        px = np.repeat(px, 3, axis=2)
    elif c == 2:  # grey + alpha
        px = np.concatenate([np.repeat(px[:, :, :1], 3, 2), px[:, :, 1:]], axis=2)
    if px.shape[2] == 3:
        px = np.concatenate([px, np.ones_like(px[:, :, :1])], axis=2)
    px = px[:, :, :4]
    if image_format(path) == "exr":
        px[..., :3] = linear_to_srgb(px[..., :3])
    return np.clip(px, 0.0, 1.0)


def read_image_u8(path: str | os.PathLike) -> np.ndarray:
    """:func:`read_image` as (H, W, 4) uint8 (rounded)."""
    return np.clip(np.round(read_image(path).astype(np.float64) * 255.0), 0, 255).astype(np.uint8)


def image_has_alpha(path: str | os.PathLike) -> bool:
    """True when the image file carries an alpha channel. Raises :class:`ImageError`."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(os.fspath(path))
    if buf.has_error:
        raise ImageError(path, "cannot read image: " + (buf.geterror().splitlines() or ["unknown format"])[0])
    spec = buf.spec()
    return spec.alpha_channel >= 0 or spec.nchannels in (2, 4)


def _to_u8(img: np.ndarray) -> np.ndarray:
    if img.dtype == np.uint8:
        return img
    return (np.clip(np.asarray(img, np.float64), 0, 1) * 255 + 0.5).astype(np.uint8)


def write_image(path: str | os.PathLike, image: np.ndarray, max_size: int | None = None,
                jpeg_quality: int = 90) -> str:
    """Write an (H, W, 1|3|4) image (uint8, or float in [0, 1]) atomically; returns the path.
    One channel is grey (e.g. an alpha mask beside a JPEG colour texture).

    The format is the suffix's (:data:`WRITE_FORMATS`). ``max_size``: downsample (keeping the
    aspect) so the longest side is at most this many pixels. Raises :class:`ImageError`.
    """
    import OpenImageIO as oiio

    fmt = image_format(path)
    if fmt not in WRITE_FORMATS:
        raise ImageError(path, f"cannot write images of type {fmt or '(no suffix)'!r}; "
                               f"use {', '.join(WRITE_FORMATS)}")
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4):
        raise ImageError(path, f"expected an (H, W, 1|3|4) image, got shape {img.shape}")
    if fmt == "exr":
        f = img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else 1.0)
        f[..., :3] = srgb_to_linear(np.clip(f[..., :3], 0, 1))
        data, pixel = np.ascontiguousarray(f), oiio.HALF
    else:
        data, pixel = np.ascontiguousarray(_to_u8(img)), oiio.UINT8
        if fmt == "jpg" and data.shape[2] == 4:
            data = np.ascontiguousarray(data[:, :, :3])
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT if pixel == oiio.HALF else oiio.UINT8)
    if c == 4:
        spec.alpha_channel = 3
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, c), data)
    if max_size is not None and max(h, w) > int(max_size):
        f = int(max_size) / max(h, w)
        roi = oiio.ROI(0, max(1, round(w * f)), 0, max(1, round(h * f)), 0, 1, 0, c)
        buf = oiio.ImageBufAlgo.resize(buf, roi=roi)
    m = buf.specmod()
    # straight alpha as is: without this OIIO un-premultiplies on write, which would destroy
    # the colours of transparent texels (a texture's dilated mip-map padding)
    m.attribute("oiio:UnassociatedAlpha", 1)
    if fmt == "png":
        m.attribute("oiio:ColorSpace", "sRGB")
        # zlib level 7 with libpng's "up" row filter (PNG_FILTER_UP = 32) instead of level 9 with
        # adaptive filtering: the same size (the 26 textures of benchmarks/render.py's 13 plants:
        # 580 KB mean both ways, each within -4.3 % .. +3.7 %) in a tenth of the time (0.40 s
        # against 3.72 s per 1024^2 RGBA texture, benchmarks/png_encode.py). A leaf texture's
        # rows change slowly (smooth colour, dilated padding), so the row above predicts a row
        # well; level 9's longer match search buys little on top of that filter but time.
        m.attribute("png:compressionLevel", PNG_LEVEL)
        m.attribute("png:filter", PNG_FILTER)
    elif fmt == "jpg":
        m.attribute("Compression", f"jpeg:{int(jpeg_quality)}")
    else:
        m.attribute("oiio:ColorSpace", "lin_rec709")
        m.attribute("compression", "zip")
    buf.set_write_format(pixel)
    with atomic_path(path) as tmp:
        if not buf.write(os.fspath(tmp)):
            raise ImageError(path, "cannot write image: " + buf.geterror())
    return os.fspath(path)
