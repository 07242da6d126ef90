"""Editing benchmark (paper Sec. "Post Editing of Plant"): a texture decal made once on the template
shows on every leaf, and cross-species retargeting keeps every leaf's silhouette.

For each pair (plant, source species) it converts both sample plants (or reuses stages given with
--stages DIR holding NAME.usda), then

* retexture: a decal at the middle of the front texture; the evaluated leaves are rasterised
  with their UVs and the fraction of leaves on which decal texels are visible is counted;
* retarget: the plant's template replaced by the source plant's template; per-instance
  silhouette IoU in the instance's PCA (local xy) view, before vs after; the new stage is validated.

Pictures (docs/): ``editing_decal.png`` (before | after, top view) and ``editing_retarget.png``
(before | after, top view). Results: benchmarks/results/editing.json.

    .venv/bin/python benchmarks/editing.py [--stages DIR] [--out DIR]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PAIRS = [("rubber_tree", "cotton_rose"), ("rubber_tree", "lucky_bamboo"), ("cotton_rose", "rubber_tree")]


def decal_image(size=128):
    """A red disc with a white ring and a yellow bar: an asymmetric, easy-to-spot decal (RGBA)."""
    y, x = np.mgrid[0:size, 0:size] / (size - 1) * 2 - 1
    r = np.hypot(x, y)
    img = np.zeros((size, size, 4), np.float32)
    img[r < 0.95] = [1, 1, 1, 1]
    img[r < 0.75] = [0.85, 0.05, 0.1, 1]
    bar = (np.abs(y) < 0.15) & (x > -0.6) & (x < 0.6)
    img[bar & (r < 0.75)] = [1, 0.9, 0.1, 1]
    return img


def render_plant(plant, view, width=480):
    from leaffit_usd.edit.preview import render_leaves, view_rotation
    from leaffit_usd.runtime.evaluator import evaluate

    a = plant.asset
    baked = evaluate(a, frame="asset")
    n = a.n_leaves
    verts = np.vstack([baked.vertices, baked.stem_vertices])
    faces = np.vstack([baked.faces, baked.stem_faces + len(baked.vertices)])
    uvs = np.vstack([np.tile(a.template_uvs, (n, 1)), np.zeros((len(baked.stem_vertices), 2))])
    side = np.r_[np.tile(a.template_side, n), np.full(len(baked.stem_vertices), 2, np.uint8)]
    img, face = render_leaves(verts, faces, uvs, side, plant.front, plant.back,
                              view_rotation(str(a.metadata.get("up_axis", "Y")), view), width=width)
    leaf_of_face = np.r_[np.repeat(np.arange(n), len(a.template_faces)), np.full(len(baked.stem_faces), -1)]
    return img, np.where(face >= 0, leaf_of_face[np.maximum(face, 0)], -1)


def decal_in_own_view(plant) -> int:
    """How many leaves show decal texels when each is rendered alone in its local (PCA) view."""
    from leaffit_usd.edit.preview import render_leaves
    from leaffit_usd.fit.mls import deform, mls_weights

    a = plant.asset
    w = mls_weights(a.template_controls, a.template_points, a.sigma, a.reg)
    local = deform(w, a.targets.astype(np.float64))            # (L, V, 3) instance local frame
    front = np.asarray(a.template_side) == 0
    faces = a.template_faces[front[a.template_faces].all(1)]
    count = 0
    for j in range(a.n_leaves):
        img, _ = render_leaves(local[j], faces, a.template_uvs, a.template_side, plant.front,
                               plant.back, np.eye(3), width=256)
        red = (img[..., 0] > 0.6) & (img[..., 1] < 0.25) & (img[..., 2] < 0.3)
        count += int(red.sum() > 20)
    return count


def side_by_side(a, b):
    h = max(a.shape[0], b.shape[0])
    pad = lambda im: np.pad(im, ((0, h - im.shape[0]), (0, 8), (0, 0)), constant_values=1.0)  # noqa: E731
    return np.concatenate([pad(a), pad(b)], axis=1)


def main(argv=None) -> int:
    from leaffit_usd.image_io import write_image
    from leaffit_usd.edit.plant_io import load_plant, save_plant
    from leaffit_usd.edit.retarget import retarget_asset
    from leaffit_usd.edit.texture import overlay_decal
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.usd.validate import validate_file

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", help="folder with already converted NAME.usda stages")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--docs", default=str(ROOT / "docs"))
    args = ap.parse_args(argv)
    work = Path(args.stages) if args.stages else Path(tempfile.mkdtemp(prefix="leaffit_edit_"))
    names = sorted({n for pair in PAIRS for n in pair})
    for n in names:
        if not (work / f"{n}.usda").exists():
            t = time.perf_counter()
            convert(ROOT / "samples" / "plants" / f"{n}.ply", work / f"{n}.usda", ConvertOptions())
            print(f"converted {n} in {time.perf_counter() - t:.1f} s")
    results = {"decal": {}, "retarget": []}

    # texture edit: once on the template, visible on every leaf
    plant = load_plant(work / "rubber_tree.usda")
    before, _ = render_plant(plant, "top")
    plant.front = overlay_decal(plant.front, decal_image(), uv=(0.5, 0.5), scale=0.18)
    plant.back = overlay_decal(plant.back, decal_image(), uv=(0.5, 0.5), scale=0.18)
    edited_path = work / "rubber_tree_decal.usda"
    save_plant(plant, edited_path)
    edited = load_plant(edited_path)
    after, leaf_px = render_plant(edited, "top")
    red = (after[..., 0] > 0.6) & (after[..., 1] < 0.25) & (after[..., 2] < 0.3)
    visible = [int(red[leaf_px == j].sum()) for j in range(edited.asset.n_leaves)]
    seen = [j for j in range(edited.asset.n_leaves) if (leaf_px == j).sum() > 200]
    own = decal_in_own_view(edited)
    results["decal"] = {"leaves": edited.asset.n_leaves, "leaves_showing_decal_own_view": own,
                        "leaves_visible_from_top": len(seen),
                        "leaves_showing_decal": int(sum(visible[j] > 0 for j in seen)),
                        "decal_pixels_per_leaf": visible,
                        "validation_errors": validate_file(edited_path).count("error")}
    write_image(Path(args.docs) / "editing_decal.png",
              (np.clip(side_by_side(before, after), 0, 1) * 255 + 0.5).astype(np.uint8))

    # retargeting across species
    for target, source in PAIRS:
        tp, sp = load_plant(work / f"{target}.usda"), load_plant(work / f"{source}.usda")
        t = time.perf_counter()
        new_asset, rep = retarget_asset(tp.asset, sp.asset)
        dt = time.perf_counter() - t
        out = work / f"{target}_as_{source}.usda"
        tp2 = load_plant(work / f"{target}.usda")
        tp2.asset, tp2.front, tp2.back, tp2.texture_format = new_asset, sp.front, sp.back, sp.texture_format
        save_plant(tp2, out)
        row = {"plant": target, "source_species": source, "instances": rep["instances"],
               "iou_min": round(rep["iou_min"], 4), "iou_mean": round(rep["iou_mean"], 4),
               "instances_iou_ge_0.8": int(sum(v >= 0.8 for v in rep["iou"])),
               "seconds": round(dt, 2), "validation_errors": validate_file(out).count("error")}
        results["retarget"].append(row)
        if (target, source) == PAIRS[0]:
            b, _ = render_plant(tp, "top")
            a, _ = render_plant(load_plant(out), "top")
            write_image(Path(args.docs) / "editing_retarget.png",
                      (np.clip(side_by_side(b, a), 0, 1) * 255 + 0.5).astype(np.uint8))

    d = results["decal"]
    print(f"\nTexture edit: decal on the template -> shows on {d['leaves_showing_decal_own_view']} of "
          f"{d['leaves']} leaves (each leaf rendered alone, from its upper side); in the top view of the "
          f"whole plant on {d['leaves_showing_decal']} of the {d['leaves_visible_from_top']} leaves "
          f"with > 200 visible pixels (the others have their middle hidden under leaves above); "
          f"validation errors {d['validation_errors']}")
    print("\nRetargeting across species (silhouette IoU per instance, PCA view)")
    print(f"{'plant':<14}{'source species':<16}{'leaves':>7}{'IoU min':>9}{'IoU mean':>10}{'>=0.8':>7}"
          f"{'time s':>8}{'val.err':>8}")
    for r in results["retarget"]:
        print(f"{r['plant']:<14}{r['source_species']:<16}{r['instances']:>7}{r['iou_min']:>9.3f}"
              f"{r['iou_mean']:>10.3f}{r['instances_iou_ge_0.8']:>7}{r['seconds']:>8.2f}{r['validation_errors']:>8}")
    out = Path(args.out) / "editing.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
