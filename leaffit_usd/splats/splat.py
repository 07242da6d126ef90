"""Reader for the antimatter15 ``.splat`` format (the WebGL viewer's, also written by many tools).

No maintained Python library reads it: gsply (our library for the other compressed formats)
does not support ``.splat``, and gaussforge's ``read()`` fails with ``std::bad_cast`` on every
SH-degree-0 input, which every ``.splat`` is. The layout is small and fixed, so it is decoded
here from the format's description (antimatter15/splat, ``convert.py`` and ``main.js``):

* no header; N records of 32 bytes, little endian;
* bytes 0-11  position x, y, z as float32 (input units, the capture's own frame);
* bytes 12-23 scales as float32, *linear* standard deviations (exp of the PLY's ``scale_i``);
* bytes 24-27 RGBA as uint8: RGB = 255 * (0.5 + SH_C0 * f_dc) clipped, A = 255 * sigmoid(opacity);
* bytes 28-31 rotation as uint8, (w, x, y, z) of the unit quaternion, byte = q * 128 + 128
  (decoded as (byte - 128) / 128 then normalised).

What is lost against an INRIA PLY: all SH bands above the DC term, colour and opacity to 8
bits, rotation to 8 bits per component; positions and scales are kept as float32. Writers
usually sort the records (by size times opacity), so Gaussian identity is the ``.splat`` file's
order, not the order of the PLY it was made from.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats.cloud import SH_C0, GaussianCloud, drop_invalid

RECORD_BYTES = 32
_RECORD = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
_ALPHA_EPS = 0.5 / 255  # a byte of 0 or 255 stands for opacity within half a step of 0 or 1


def read_splat(path: str | os.PathLike, drop_bad: bool = True) -> GaussianCloud:
    """Read an antimatter15 ``.splat`` file into a GaussianCloud (input frame, file order, SH degree 0).

    Raises ``InputFileError`` for an empty file, a size that is not a whole number of 32-byte
    records, or records whose scales are not positive finite numbers (not a ``.splat`` file).
    """
    path = Path(path)
    size = path.stat().st_size
    if size == 0:
        raise InputFileError(path, "is empty (0 bytes)")
    if size % RECORD_BYTES:
        raise InputFileError(path, f"not a .splat file: {size} bytes is not a whole number of "
                                   f"{RECORD_BYTES}-byte records (truncated?)")
    rec = np.fromfile(path, dtype=_RECORD)
    n = len(rec)
    scales = rec["scale"].astype(np.float64)
    bad_scale = ~(np.isfinite(scales) & (scales > 0)).all(1)
    if bad_scale.mean() > 0.5:
        raise InputFileError(path, f"not a .splat file: {int(bad_scale.sum())} of {n} records have "
                                   f"scales that are not positive numbers")
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.where(bad_scale[:, None], np.nan, np.log(np.where(scales > 0, scales, 1.0)))
    rgba = rec["rgba"].astype(np.float64) / 255.0
    alpha = np.clip(rgba[:, 3], _ALPHA_EPS, 1.0 - _ALPHA_EPS)
    q = (rec["rot"].astype(np.float64) - 128.0) / 128.0
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), 0.0)  # zero -> dropped as invalid
    cloud = GaussianCloud(
        means=np.ascontiguousarray(rec["pos"], np.float32),
        log_scales=log_scales.astype(np.float32),
        quats=q.astype(np.float32),
        opacity_logits=np.log(alpha / (1.0 - alpha)).astype(np.float32),
        sh=((rgba[:, None, :3] - 0.5) / SH_C0).astype(np.float32),
    )
    return drop_invalid(cloud, str(path)) if drop_bad else cloud
