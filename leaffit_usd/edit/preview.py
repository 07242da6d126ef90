"""Textured previews of a plant's explicit leaves (the CPU evaluator's output), for checking that a
template texture edit reaches every leaf and for README pictures. Orthographic, nearest texel,
alpha-tested at 0.5 (as a game engine's cut-out leaf material would be)."""
from __future__ import annotations

import numpy as np

from leaffit_usd.edit.raster import rasterize


def view_rotation(up: str = "Y", view: str = "top") -> np.ndarray:
    """(3, 3) rotation from the asset frame to a view frame (x right, y up, +z towards the viewer).

    up : the stage's up axis ("Y" or "Z"); view : "top" (looking down the up axis) or "front"
    (looking horizontally).
    """
    if up.upper() == "Z":
        base = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]) if view == "top" else \
            np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    else:
        base = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]) if view == "top" else np.eye(3)
    return base


def render_leaves(vertices, faces, uvs, side, front_tex, back_tex, rotation, width=512,
                  background=(1.0, 1.0, 1.0), solid=(0.23, 0.30, 0.12)):
    """Render textured triangles.

    vertices : (P, 3) float, asset frame; faces : (F, 3) int; uvs : (P, 2) float in [0, 1]
    (v up); side : (P,) 0 front / 1 back — picks the texture, 2 = untextured (``solid`` colour,
    e.g. the stem); *_tex : (H, W, 4) float RGBA
    rotation : (3, 3) asset -> view frame (see :func:`view_rotation`)
    Returns ((h, width, 3) float32 image, (h, width) int64 visible face index or -1).
    """
    v = np.asarray(vertices, np.float64) @ np.asarray(rotation).T
    lo, hi = v[:, :2].min(0), v[:, :2].max(0)
    pad = 0.03 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    height = max(1, int(round(width * (hi[1] - lo[1]) / (hi[0] - lo[0]))))
    faces = np.asarray(faces, np.int64)
    # alpha test per pixel: rasterise, look the texel up, then drop transparent hits by
    # re-rasterising without faces whose hit was transparent would be costly; instead
    # composite the nearest opaque hit by peeling the front layer where alpha < 0.5.
    img = np.tile(np.asarray(background, np.float32), (height, width, 1))
    face_img = np.full((height, width), -1, np.int64)
    remaining = np.ones(len(faces), bool)
    todo = np.ones((height, width), bool)
    for _ in range(4):  # a few depth layers are enough for leaves seen through cut-out edges
        idx = np.flatnonzero(remaining)
        if len(idx) == 0:
            break
        r = rasterize(v, faces[idx], width, height, (lo[0], hi[0], lo[1], hi[1]))
        hit = r.mask & todo
        if not hit.any():
            break
        f = idx[r.face[hit]]
        b = r.bary[hit]
        uv = np.einsum("pk,pkc->pc", b, np.asarray(uvs, np.float64)[faces[f]])
        s = np.asarray(side)[faces[f, 0]]
        rgba = np.where(s[:, None] == 0, _sample(front_tex, uv), _sample(back_tex, uv))
        rgba = np.where(s[:, None] >= 2, np.r_[solid, 1.0].astype(np.float32), rgba)
        opaque = rgba[:, 3] >= 0.5
        rows, cols = np.nonzero(hit)
        img[rows[opaque], cols[opaque]] = rgba[opaque, :3]
        face_img[rows[opaque], cols[opaque]] = f[opaque]
        todo[rows[opaque], cols[opaque]] = False
        # faces hit only transparently are peeled away for the next layer
        seen = np.zeros(len(faces), bool)
        seen[f[~opaque]] = True
        seen[f[opaque]] = False
        remaining &= ~seen
        if not (~opaque).any():
            break
    return img, face_img


def _sample(tex, uv):
    h, w = tex.shape[:2]
    col = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    row = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    return np.asarray(tex, np.float32)[row, col]
