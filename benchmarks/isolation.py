"""Isolation benchmark: does a capture that keeps its pot, soil, table and clutter give the same
result as the trimmed plant?

For every plant, the capture-like file (``samples.capture_suite()``: pot, soil, table, clutter,
back wall; and, when ``../shared/plants`` exists, the external generator's ``--scene`` plants)
and the same plant without its surroundings go through what ``convert`` does with no options:
isolation -> frame (up, root) -> automatic segmentation. Printed per plant:

* isolation precision / recall per class against the ground truth (samples: plant, ground, pot,
  soil, background, floater; external: plant / scene / floater, its GT has no finer classes),
  the share of the Gaussians kept as the plant that are GT scene ("scene kept": what would put
  asset geometry outside the plant), and the share of the trimmed plant's own Gaussians that
  isolation removed; isolation's CPU seconds (user + sys, all threads);
* up-axis error (degrees) and root error (fraction of the plant height) on the capture;
* segmentation scores (Acc / mIoU / PQ, ``../shared/plants/eval_seg.py`` when present, else
  ``leaffit_usd.metrics``) on the capture and on the trimmed plant, and their mIoU difference;
  the trimmed plant also in the capture's frame ("trimF": the capture's up axis, and the trimmed
  Gaussian nearest the capture's root), so that "cap" vs "trimF" (ΔF) is what isolation changes
  and "trimF" vs "trim" what the frame changes (the trimmed plant's own estimated up axis can be
  far off: then its auto root lands elsewhere and the leaves differ for that reason alone);
  and two attribution runs on the capture (see :func:`run_pipeline`): "same" (the trimmed
  plant's Gaussians in the capture's file order) and "nocue" (the isolated plant without the
  scene's frame cues);
* with ``--convert``: the whole ``convert`` of the capture, baked (leaves + stem, input frame),
  and how much of the asset lies outside the plant: the largest distance of an asset vertex from
  the nearest GT plant Gaussian, and the share of vertices farther than 5 % of the plant height.

    .venv/bin/python benchmarks/isolation.py [--set samples|external|all] [--convert]
        [--gaussians 60000] [--only NAME ...] [--ext-dir DIR] [--ext-seeds 1 2 3]

Writes benchmarks/results/isolation.json.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "plants"

from benchmarks.machine import machine_info  # noqa: E402
from leaffit_usd.isolate import CLASS_NAMES  # noqa: E402
from leaffit_usd.pipeline import auto_segment, frame_from_isolation, isolate_stage  # noqa: E402
from leaffit_usd.segment.auto import SegmentParams  # noqa: E402
from leaffit_usd.splats import load_cloud  # noqa: E402
from leaffit_usd.splats.transform import transform_cloud  # noqa: E402
from leaffit_usd.splats.frame import make_frame  # noqa: E402


def _eval_seg():
    path = SHARED / "eval_seg.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("eval_seg", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


EVAL = _eval_seg()


def seg_scores(gt_labels, pred_labels) -> dict:
    if EVAL is not None:
        s = EVAL.score(np.asarray(gt_labels), np.asarray(pred_labels))
        return {k: round(100 * float(s[k]), 2) for k in ("Acc", "mIoU", "PQ")}
    from leaffit_usd.metrics import segmentation_scores

    s = segmentation_scores(np.where(gt_labels < 0, -1, gt_labels), np.maximum(pred_labels, 0))
    return {"Acc": round(100 * s["acc"], 2), "mIoU": round(100 * s["miou"], 2), "PQ": round(100 * s["pq"], 2)}


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _segment(cloud_in, plant, choice) -> tuple[np.ndarray, int]:
    """Automatic segmentation of ``plant`` (a subset of ``cloud_in``) in ``choice``'s frame:
    (labels in file order, -1 = not in ``plant``; leaf count)."""
    cw = transform_cloud(plant, choice.frame.input_to_working)
    seg = auto_segment(cw, choice.root_index, SegmentParams())
    labels = np.full(cloud_in.file_count, -1, np.int64)
    labels[plant.file_index] = seg.labels
    return labels, int(seg.n_leaves)


def _pipeline(cloud_in) -> dict:
    """isolate -> frame -> segment with the defaults on a loaded cloud (or a subset of one)."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    plant, iso = isolate_stage(cloud_in)
    t_iso, cpu_iso = time.perf_counter() - t0, time.process_time() - c0
    choice = frame_from_isolation(plant, iso, cloud=cloud_in)
    t1 = time.perf_counter()
    labels, leaves = _segment(cloud_in, plant, choice)
    t_seg = time.perf_counter() - t1
    classes = cloud_in.to_file_order(np.asarray(iso.classes, np.uint8), fill=255)
    root = plant.means[choice.root_index].astype(np.float64)
    return {"labels": labels, "classes": classes, "up": np.asarray(choice.frame.up, float), "root": root,
            "up_source": iso.up_source, "t_isolate": t_iso, "cpu_isolate": cpu_iso,
            "t_segment": t_seg, "leaves": leaves, "iso": iso, "plant": plant, "cloud": cloud_in}


def run_pipeline(path, gt_labels=None) -> dict:
    """isolate -> frame -> segment with the defaults; labels in file order (-1 = removed).

    With ``gt_labels`` (file order) also two attribution runs on the same capture:
    "same" -- the whole pipeline on the capture less its GT scene Gaussians (label -2): the
    trimmed plant's very Gaussians (plant and floaters) in the capture's file order, so "same" vs
    "trim" is the pipeline's sensitivity to file order alone, and "cap" vs "same" is what the
    scene changes; "nocue" -- the plant isolation kept, segmented in a frame estimated from it
    alone (no table up, no stem base at the soil): "cap" vs "nocue" is what the scene's cues
    change, "nocue" vs "same" what the kept set's differences change."""

    cloud_in = load_cloud(path)
    out = _pipeline(cloud_in)
    if gt_labels is not None:
        keep = np.asarray(gt_labels)[np.asarray(cloud_in.file_index)] >= -1  # cloud order
        out["labels_same"] = _pipeline(cloud_in.subset(keep))["labels"]
        out["labels_nocue"], _ = _segment(cloud_in, out["plant"], make_frame(out["plant"]))
    return out


def class_scores(gt_class, pred_class, names) -> dict:
    out = {}
    for c, name in names:
        g, p = np.isin(gt_class, c), np.isin(pred_class, c)
        tp = int((g & p).sum())
        out[name] = {"gt": int(g.sum()), "pred": int(p.sum()),
                     "precision": round(tp / p.sum(), 4) if p.sum() else None,
                     "recall": round(tp / g.sum(), 4) if g.sum() else None}
    return out


def baked_vertices(stage, npz) -> np.ndarray:
    """(N, 3) float64: the asset's leaf and stem vertices, input frame (``bake`` to ``npz``)."""
    from leaffit_usd.commands.bake import bake

    bake(stage, npz)
    z = np.load(npz)
    verts = [z["vertices"]]
    if "stem_vertices" in z.files and len(z["stem_vertices"]):
        verts.append(z["stem_vertices"])
    return np.concatenate(verts).astype(np.float64)


def asset_outside(scene_path, gt_labels, gt_plant_pts, height, workdir) -> dict:
    """convert with no options, bake (input frame), distance of asset vertices from the plant."""
    from scipy.spatial import cKDTree

    from leaffit_usd.pipeline import convert

    out = Path(workdir) / "asset.usda"
    t0 = time.perf_counter()
    rep = convert(scene_path, out)
    t_conv = time.perf_counter() - t0
    v = baked_vertices(out, Path(workdir) / "leaves.npz")
    d, _ = cKDTree(gt_plant_pts).query(v, k=1)
    d = d / height
    return {"convert_s": round(t_conv, 1), "leaves": rep["counts"]["leaves"],
            "max_dist_over_height": round(float(d.max()), 4),
            "p99_dist_over_height": round(float(np.quantile(d, 0.99)), 4),
            "share_beyond_5pct": round(float((d > 0.05).mean()), 5),
            "removed": rep["isolation"]["removed"]}


def plants_samples(gaussians: int, cache: Path, only):
    from samples.generate import capture_suite, make_plant, save_plant
    import dataclasses

    out = []
    for name, spec, seed in capture_suite(gaussians):
        if only and name not in only:
            continue
        trimmed = dataclasses.replace(spec, scene=False)
        for nm, sp in ((name, spec), (name + "_trimmed", trimmed)):
            if not (cache / f"{nm}.ply").is_file():
                cloud, gt = make_plant(sp, seed)
                save_plant(cloud, gt, cache, nm)
        from samples.generate import load_ground_truth

        gt = load_ground_truth(cache / f"{name}.gt.npz")
        gtt = load_ground_truth(cache / f"{name}_trimmed.gt.npz")
        out.append({"set": "samples", "name": name, "scene": cache / f"{name}.ply",
                    "trimmed": cache / f"{name}_trimmed.ply", "gt_labels": gt.labels,
                    "gt_class": gt.scene_class, "gt_labels_trimmed": gtt.labels, "up": gt.up,
                    "root": gt.root, "height": gt.height})
    return out


def plants_external(ext_dir: Path, seeds, only):
    """paper8 ``--scene`` plants and the same without ``--scene``, per seed, generated once into
    ``ext_dir/iso-paper8-SEED/{scene,plain}``."""
    if not SHARED.is_dir():
        print(f"skipping the external plants: {SHARED} is absent", file=sys.stderr)
        return []
    out = []
    for seed in seeds:
        scene_dir, plain_dir = ext_dir / f"iso-paper8-{seed}" / "scene", ext_dir / f"iso-paper8-{seed}" / "plain"
        for d, extra in ((scene_dir, ["--scene"]), (plain_dir, [])):
            if not (d / "index.json").is_file():
                cmd = [_external_python(), str(SHARED / "make_plants.py"), "--out", str(d), "--seed",
                       str(seed), "--preset", "paper8", "--quiet", *extra]
                print("generating:", " ".join(cmd), file=sys.stderr)
                subprocess.run(cmd, check=True)
        for entry in json.loads((scene_dir / "index.json").read_text())["plants"]:
            name = entry["name"]
            if only and name not in only:
                continue
            g = np.load(scene_dir / name / "gt.npz")
            gt = np.asarray(g["labels"])
            cls = np.where(gt >= 0, 0, np.where(gt == -1, 5, 4))  # plant / floater / scene
            out.append({"set": f"external-s{seed}", "name": name if seed == 1 else f"{name}-s{seed}",
                        "scene": scene_dir / name / "point_cloud.ply",
                        "trimmed": plain_dir / name / "point_cloud.ply", "gt_labels": gt,
                        "gt_class": cls,
                        "gt_labels_trimmed": np.asarray(np.load(plain_dir / name / "gt.npz")["labels"]),
                        "up": np.asarray(g["up"]), "root": np.asarray(g["root"]),
                        "height": float(g["plant_height"])})
    return out


def _external_python() -> str:
    """A Python with the external generator's needs (numpy, scipy, pillow, plyfile)."""
    for cand in (Path.home() / ".cache/leaffit-plants/heliosvenv/bin/python", Path(sys.executable)):
        if cand.is_file() and subprocess.run([str(cand), "-c", "import PIL, plyfile, scipy"],
                                             capture_output=True).returncode == 0:
            return str(cand)
    raise SystemExit("the external generator needs pillow and plyfile (pip install pillow plyfile)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", choices=("samples", "external", "all"), default="all")
    ap.add_argument("--gaussians", type=int, default=60_000, help="plant Gaussians of the samples (60000)")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--convert", action="store_true", help="also run the whole convert on each capture")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "leaffit-isolation-bench"))
    ap.add_argument("--ext-dir", default=os.environ.get("LEAFFIT_EXT_CACHE"),
                    help="external plants' cache (default $LEAFFIT_EXT_CACHE, else CACHE/external)")
    ap.add_argument("--ext-seeds", type=int, nargs="+", default=[1], help="paper8 seeds (1)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/isolation.json"))
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    plants = []
    if a.set in ("samples", "all"):
        plants += plants_samples(a.gaussians, cache / "samples", a.only)
    if a.set in ("external", "all"):
        plants += plants_external(Path(a.ext_dir) if a.ext_dir else cache / "external", a.ext_seeds,
                                  a.only)
    rows = []
    hdr = (f"{'plant':24s} {'up°':>5s} {'root':>6s} {'cap':>6s} {'same':>6s} {'nocue':>6s} "
           f"{'trim':>6s} {'Δ':>6s} {'trimF':>6s} {'ΔF':>6s} {'plant P/R':>11s} {'scene kept':>10s} {'trim lost':>9s} "
           f"{'iso cpu':>7s}")
    print(hdr)
    for pl in plants:
        cap = run_pipeline(pl["scene"], pl["gt_labels"])
        trim = run_pipeline(pl["trimmed"])
        s_cap = seg_scores(pl["gt_labels"], cap["labels"])
        s_trim = seg_scores(pl["gt_labels_trimmed"], trim["labels"])
        s_gt = seg_scores(pl["gt_labels"], cap["labels_same"])
        s_nc = seg_scores(pl["gt_labels"], cap["labels_nocue"])
        # the trimmed plant in the capture's frame (its up axis, the trimmed Gaussian nearest its
        # root): "cap" vs this is what isolation changes, "trim" vs this what the frame changes
        s_tf = seg_scores(pl["gt_labels_trimmed"], _segment(trim["cloud"], trim["plant"], make_frame(
            trim["plant"], up=cap["up"], root=cap["root"]))[0])
        if pl["set"] == "samples":
            names = [(i, n) for i, n in enumerate(CLASS_NAMES)]
        else:
            names = [(0, "plant"), ([1, 2, 3, 4], "scene"), (5, "floater")]
        pred = cap["classes"].astype(np.int64)
        cs = class_scores(pl["gt_class"], pred, names)
        gtt = pl["gt_labels_trimmed"]
        lost = float(((trim["classes"] != 0) & (gtt >= 0)).sum() / max((gtt >= 0).sum(), 1))
        kept = pred == 0
        # "no asset geometry outside the plant", on the Gaussians: the share of those kept as the
        # plant that are GT scene (table, pot, soil, clutter; floaters are counted apart)
        gc = np.asarray(pl["gt_class"])
        scene_kept = float((kept & np.isin(gc, [1, 2, 3, 4])).sum() / max(kept.sum(), 1))
        floater_kept = float((kept & (gc == 5)).sum() / max(kept.sum(), 1))
        up_err = angle_deg(cap["up"], pl["up"])
        root_err = float(np.linalg.norm(cap["root"] - pl["root"]) / pl["height"])
        row = {"set": pl["set"], "name": pl["name"], "up_error_deg": round(up_err, 2),
               "up_source": cap["up_source"], "root_error_over_height": round(root_err, 4),
               "seg_capture": s_cap, "seg_trimmed": s_trim, "seg_same_gaussians": s_gt,
               "seg_no_cues": s_nc, "seg_trimmed_capture_frame": s_tf,
               "miou_delta_capture_frame": round(s_cap["mIoU"] - s_tf["mIoU"], 2),
               "miou_delta": round(s_cap["mIoU"] - s_trim["mIoU"], 2),
               "leaves_capture": cap["leaves"], "leaves_trimmed": trim["leaves"],
               "classes": cs, "trimmed_plant_lost": round(lost, 5),
               "kept_scene_share": round(scene_kept, 5), "kept_floater_share": round(floater_kept, 5),
               "trimmed_removed": trim["iso"].removed(),
               "isolate_s": round(cap["t_isolate"], 2), "isolate_cpu_s": round(cap["cpu_isolate"], 2),
               "segment_s": round(cap["t_segment"], 2), "gaussians": int(len(pl["gt_labels"]))}
        if a.convert:
            gl = np.asarray(pl["gt_labels"])
            pts = load_cloud(pl["scene"]).means
            plant_pts = pts[np.asarray(gl)[:len(pts)] >= 0] if len(pts) == len(gl) else pts
            with tempfile.TemporaryDirectory() as td:
                row["asset"] = asset_outside(pl["scene"], gl, plant_pts, pl["height"], td)
        rows.append(row)
        pc = cs["plant"]
        print(f"{pl['name']:24s} {up_err:5.2f} {root_err:6.3f} {s_cap['mIoU']:6.2f} {s_gt['mIoU']:6.2f} "
              f"{s_nc['mIoU']:6.2f} {s_trim['mIoU']:6.2f} {row['miou_delta']:+6.2f} "
              f"{s_tf['mIoU']:6.2f} {row['miou_delta_capture_frame']:+6.2f} "
              f"{pc['precision']:.3f}/{pc['recall']:.3f} {scene_kept:10.5f} {lost:9.4f} "
              f"{cap['cpu_isolate']:7.2f}" + (f"  asset max {row['asset']['max_dist_over_height']:.3f} H, "
                                              f">5%H {row['asset']['share_beyond_5pct']:.4f}"
                                              if "asset" in row else ""), flush=True)
    summary = {}
    for st in sorted({r["set"] for r in rows}):
        rs = [r for r in rows if r["set"] == st]
        summary[st] = {
            "plants": len(rs),
            "mean_miou_capture": round(float(np.mean([r["seg_capture"]["mIoU"] for r in rs])), 2),
            "mean_miou_trimmed": round(float(np.mean([r["seg_trimmed"]["mIoU"] for r in rs])), 2),
            "max_abs_miou_delta": round(float(np.max([abs(r["miou_delta"]) for r in rs])), 2),
            "max_up_error_deg": round(float(np.max([r["up_error_deg"] for r in rs])), 2),
            "max_trimmed_plant_lost": round(float(np.max([r["trimmed_plant_lost"] for r in rs])), 5),
            "max_kept_scene_share": round(float(np.max([r["kept_scene_share"] for r in rs])), 5),
            "within_2_miou": int(sum(abs(r["miou_delta"]) <= 2 for r in rs)),
            "within_2_miou_capture_frame": int(sum(abs(r["miou_delta_capture_frame"]) <= 2 for r in rs)),
        }
        if all("asset" in r for r in rs):
            summary[st]["max_asset_dist_over_height"] = max(r["asset"]["max_dist_over_height"] for r in rs)
            summary[st]["max_asset_share_beyond_5pct"] = max(r["asset"]["share_beyond_5pct"] for r in rs)
        print(st, json.dumps(summary[st]))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps({"summary": summary, "plants": rows,
                                       "evaluator": "eval_seg.py" if EVAL else "leaffit_usd.metrics",
                                       "machine": machine_info()},
                                      indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
