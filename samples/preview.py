"""Quick-look PNG of a generated plant (point splats, painter's order; canonical frame views).

    python -m samples.preview samples/plants/rubber_tree.ply -o rubber_tree.png [--labels]

Three orthographic views side by side: front (looking along +Y), side (along -X), top (down -Z).
With ``--labels`` points are coloured by ground-truth label instead of their RGB.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from leaffit_usd.splats.ply import read_ply
from samples.generate import load_ground_truth


def _label_colours(labels: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(7)
    pal = rng.uniform(0.2, 1.0, (labels.max() + 2, 3))
    c = pal[np.maximum(labels, 0)]
    c[labels == 0] = (0.45, 0.3, 0.15)
    c[labels < 0] = (1.0, 0.0, 1.0)
    return c


def render_views(points: np.ndarray, colours: np.ndarray, size: int = 420) -> np.ndarray:
    """(H, 3*W, 3) float32 image of canonical-frame points (front | side | top)."""
    views = [(0, 2, 1, -1), (1, 2, 0, 1), (0, 1, 2, 1)]  # (u axis, v axis, depth axis, depth sign)
    lo, hi = points.min(0), points.max(0)
    ext = float((hi - lo).max()) * 1.05
    ctr = 0.5 * (lo + hi)
    tiles = []
    for ua, va, da, sgn in views:
        img = np.full((size, size, 3), 0.96, np.float32)
        u = ((points[:, ua] - ctr[ua]) / ext + 0.5) * (size - 1)
        v = (0.5 - (points[:, va] - ctr[va]) / ext) * (size - 1)
        order = np.argsort(sgn * points[:, da])  # far first, near last (near wins)
        ui, vi = np.clip(u[order].astype(int), 0, size - 2), np.clip(v[order].astype(int), 0, size - 2)
        c = colours[order]
        for du in (0, 1):
            for dv in (0, 1):
                img[vi + dv, ui + du] = c
        tiles.append(img)
    return np.concatenate(tiles, axis=1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m samples.preview", description=__doc__.splitlines()[0])
    p.add_argument("ply")
    p.add_argument("-o", "--out", required=True)
    p.add_argument("--labels", action="store_true", help="colour by ground-truth label")
    p.add_argument("--size", type=int, default=420)
    a = p.parse_args(argv)
    cloud = read_ply(a.ply)
    gt = load_ground_truth(Path(a.ply).with_suffix("").as_posix() + ".gt.npz")
    M = np.linalg.inv(gt.canonical_to_input)
    pts = cloud.means.astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    col = _label_colours(gt.labels) if a.labels else cloud.colors
    keep = (gt.labels >= 0) | (gt.labels == -2) if not a.labels else np.ones(len(pts), bool)
    img = render_views(pts[keep], col[keep], a.size)
    from leaffit_usd.image_io import write_image

    write_image(a.out, img)
    return 0


if __name__ == "__main__":
    sys.exit(main())
