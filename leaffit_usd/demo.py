"""The one-command demo: ``python -m leaffit_usd.demo IN.ply OUTDIR`` (``make demo``).

Loads the capture, prints the ``inspect`` summary, writes ``OUTDIR/quicklook.png`` (two
orthographic views of the Gaussian centres in the working frame: front looking along +Y, side
looking along -X, each Gaussian a small disc in its DC colour), runs the whole conversion
(``pipeline.convert``, progress on stderr) to ``OUTDIR/<name>.usda``, validates it, and writes
``OUTDIR/leaves.png``: the textured leaves as the CPU evaluator produces them (top and front
views). Exit code 2 with one line for a missing or malformed input.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from leaffit_usd.errors import UserError
from leaffit_usd.image_io import write_image

log = logging.getLogger("leaffit_usd")

BACKGROUND = (0.12, 0.12, 0.13)


def splat_points(points: np.ndarray, colors: np.ndarray, depth: np.ndarray, width: int,
                 height: int, bounds: tuple[float, float, float, float], radius: int = 1,
                 background=BACKGROUND) -> np.ndarray:
    """Tiny point splatting: each point a disc of ``radius`` pixels, the nearest wins.

    points : (N, 2) float, image-plane coordinates (x right, y up), same units as ``bounds``
    colors : (N, 3) float RGB in [0, 1]; depth : (N,) float, larger = nearer the viewer
    bounds : (xmin, xmax, ymin, ymax) mapped to the image; row 0 is the top (ymax).
    Returns (height, width, 3) float32.
    """
    xmin, xmax, ymin, ymax = bounds
    img = np.empty((height, width, 3), np.float32)
    img[:] = background
    if len(points) == 0:
        return img
    px = (points[:, 0] - xmin) / max(xmax - xmin, 1e-30) * (width - 1)
    py = (ymax - points[:, 1]) / max(ymax - ymin, 1e-30) * (height - 1)
    offs = [(dx, dy) for dx in range(-radius, radius + 1) for dy in range(-radius, radius + 1)
            if dx * dx + dy * dy <= radius * radius + radius]
    cols, rows, src = [], [], []
    ix, iy = np.rint(px).astype(np.int64), np.rint(py).astype(np.int64)
    for dx, dy in offs:
        cols.append(ix + dx)
        rows.append(iy + dy)
        src.append(np.arange(len(points)))
    cols, rows, src = np.concatenate(cols), np.concatenate(rows), np.concatenate(src)
    ok = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    pix, src = rows[ok] * width + cols[ok], src[ok]
    order = np.lexsort((-depth[src], pix))  # by pixel, nearest first
    first = np.unique(pix[order], return_index=True)[1]
    win = order[first]
    img.reshape(-1, 3)[pix[win]] = colors[src[win]]
    return img


def quicklook(points_working: np.ndarray, colors: np.ndarray, size: int = 512) -> np.ndarray:
    """Two orthographic views side by side: (size, 2 * size, 3) uint8.

    points_working : (N, 3) working frame (root at origin, up +Z, height 1);
    colors : (N, 3) RGB in [0, 1]. Left: front view (x right, z up, looking along +Y);
    right: side view (y right, z up, looking along -X). Both views share one scale.
    """
    p = np.asarray(points_working, np.float64)
    c = np.clip(np.asarray(colors, np.float32), 0, 1)
    lo, hi = np.quantile(p, [0.002, 0.998], axis=0) if len(p) else (np.zeros(3), np.ones(3))
    half = 0.55 * max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-9)
    cz = 0.5 * (lo[2] + hi[2])
    cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
    radius = 1 if len(p) > 20_000 else 2
    front = splat_points(p[:, [0, 2]], c, -p[:, 1], size, size,
                         (cx - half, cx + half, cz - half, cz + half), radius)
    side = splat_points(p[:, [1, 2]], c, p[:, 0], size, size,
                        (cy - half, cy + half, cz - half, cz + half), radius)
    img = np.concatenate([front, side], axis=1)
    img[:, size - 1: size + 1] = 0.35  # separator
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def run(input_path: str, outdir: str, size: int = 512, convert: bool = True) -> list[Path]:
    """Load, summarise (printed), write the quick-look PNG, convert. Returns the written paths."""
    from leaffit_usd.commands.inspect import format_table, summarize
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.splats.frame import make_frame

    cloud = load_cloud(input_path)
    summary = summarize(input_path, cloud=cloud)
    print(format_table(summary))
    choice = make_frame(cloud, up=np.asarray(summary["up"]["vector"]))
    pw = choice.frame.to_working(cloud.means)
    out = Path(outdir)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    png = out / "quicklook.png"
    write_image(png, quicklook(pw, cloud.colors, size))
    written = [png]
    if convert:
        written += convert_and_preview(input_path, out, size)
    return written


def convert_and_preview(input_path: str, out: Path, size: int = 512) -> list[Path]:
    """Full conversion to ``out/<name>.usda`` + validation + a textured preview of the leaves."""
    from leaffit_usd.edit.plant_io import load_plant
    from leaffit_usd.edit.preview import render_leaves, view_rotation
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.runtime.evaluator import evaluate
    from leaffit_usd.usd.validate import validate_file

    stage = out / f"{Path(input_path).stem}.usda"
    report = convert(input_path, stage, ConvertOptions())
    print(f"\nconverted in {report['timings']['total']:.1f} s: {report['counts']['leaves']} leaves, "
          f"template {report['counts']['template_vertices']} vertices, K = {report['counts']['K']}")
    checked = validate_file(stage)
    print(f"validate: {'ok' if not checked.failed() else 'FAILED'} "
          f"({checked.count('error')} errors, {checked.count('warning')} warnings)")
    plant = load_plant(stage)
    a = plant.asset
    baked = evaluate(a, frame="asset")
    n = a.n_leaves
    uvs, side = np.tile(a.template_uvs, (n, 1)), np.tile(a.template_side, n)
    verts = np.vstack([baked.vertices, baked.stem_vertices])
    faces = np.vstack([baked.faces, baked.stem_faces + len(baked.vertices)])
    stem_uv = np.zeros((len(baked.stem_vertices), 2))   # the stem: side 2 = flat stem colour
    up = str(a.metadata.get("up_axis", "Y"))
    views = []
    for view in ("top", "front"):
        img, _ = render_leaves(verts, faces, np.vstack([uvs, stem_uv]),
                               np.r_[side, np.full(len(stem_uv), 2, side.dtype)],
                               plant.front, plant.back, view_rotation(up, view), width=size)
        views.append(img)
    h = max(v.shape[0] for v in views)
    views = [np.pad(v, ((0, h - v.shape[0]), (0, 0), (0, 0)), constant_values=1.0) for v in views]
    png = out / "leaves.png"
    write_image(png, (np.clip(np.concatenate(views, axis=1), 0, 1) * 255 + 0.5).astype(np.uint8))
    files = [stage] + [Path(p) for k, p in sorted(report["outputs"].items()) if k != "stage"]
    return files + [png]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m leaffit_usd.demo",
                                 description="Load a 3DGS plant, print a summary and a quick look, "
                                             "convert it to a LeafFit USD asset, preview its leaves.")
    ap.add_argument("input", metavar="IN", help="3DGS capture (.ply or USD)")
    ap.add_argument("outdir", metavar="OUTDIR", help="directory for the outputs (created)")
    ap.add_argument("--size", type=int, default=512, help="pixels per view (default 512)")
    ap.add_argument("--no-convert", action="store_true", help="only the summary and quick look")
    args = ap.parse_args(argv)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        written = run(args.input, args.outdir, args.size, convert=not args.no_convert)
    except UserError as e:
        sys.stderr.write(f"leaffit-usd demo: error: {e}\n")
        return 2
    print()
    for p in written:
        print(f"wrote {p} ({p.stat().st_size:,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
