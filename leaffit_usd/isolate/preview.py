"""A picture of what isolation removed: three orthographic views (front, side, top) of the
capture, up = the isolation's up (else the cloud's longest principal axis). Kept plant Gaussians
in their own colour, removed ones by class: ground blue-grey, pot orange, soil brown, background
violet, floater red. Plain numpy raster, written with ``image_io.write_image``.
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.isolate.result import PLANT, Isolation

CLASS_COLOURS = np.array([[0.0, 0.0, 0.0],      # plant: its own colour
                          [0.55, 0.62, 0.75],   # ground
                          [0.95, 0.55, 0.15],   # pot
                          [0.45, 0.28, 0.12],   # soil
                          [0.60, 0.35, 0.85],   # background
                          [0.95, 0.10, 0.10]])  # floater


def render_isolation(cloud, iso: Isolation, size: int = 480, max_points: int = 400_000) -> np.ndarray:
    """(size, 3 * size, 3) float32 RGB in [0, 1]: front | side | top views of ``cloud`` (input
    frame) coloured by ``iso.classes``."""
    pts = np.asarray(cloud.means, np.float64)
    cls = np.asarray(iso.classes)
    if len(pts) > max_points:  # deterministic thinning of huge captures
        idx = np.sort(np.random.default_rng(0).choice(len(pts), max_points, replace=False))
        pts, cls, col = pts[idx], cls[idx], cloud.colors[idx]
    else:
        col = cloud.colors
    col = np.where((cls == PLANT)[:, None], col, CLASS_COLOURS[cls]).astype(np.float32)
    c = np.median(pts, axis=0)
    q = pts - c
    if iso.up is not None:
        up = np.asarray(iso.up, np.float64)
    else:
        up = np.linalg.svd(q[:: max(1, len(q) // 20000)], full_matrices=False)[2][0]
    a = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = np.cross(up, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    local = np.stack([q @ e1, q @ e2, q @ up], 1)
    lo, hi = np.quantile(local, [0.002, 0.998], axis=0)
    ext = float((hi - lo).max()) * 1.08 or 1.0
    ctr = 0.5 * (lo + hi)
    tiles = []
    for ua, va, da, sgn in ((0, 2, 1, -1), (1, 2, 0, 1), (0, 1, 2, 1)):
        img = np.full((size, size, 3), 0.97, np.float32)
        u = ((local[:, ua] - ctr[ua]) / ext + 0.5) * (size - 1)
        v = (0.5 - (local[:, va] - ctr[va]) / ext) * (size - 1)
        ok = (u >= 0) & (u < size - 1) & (v >= 0) & (v < size - 1)
        order = np.flatnonzero(ok)[np.argsort(sgn * local[ok, da], kind="stable")]
        ui, vi = u[order].astype(int), v[order].astype(int)
        img[vi, ui] = col[order]
        tiles.append(img)
        tiles.append(np.full((size, 4, 3), 0.6, np.float32))
    return np.concatenate(tiles[:-1], axis=1)


def write_isolation_preview(path, cloud, iso: Isolation, size: int = 480) -> None:
    """Render :func:`render_isolation` and write it atomically (``image_io.write_image``: PNG,
    JPEG or EXR by the suffix; ImageError otherwise)."""
    from leaffit_usd.image_io import write_image

    write_image(path, render_isolation(cloud, iso, size))
