"""Segmentation on the external plant sets (``../shared/plants``): the issue's protocol, as a new
user would run it: the root given as a click (the ground-truth stem base, input frame), the up
axis estimated. Scored by the shared evaluator (``eval_seg.score``: Acc / mIoU / mF1 / PQ) and the
per-leaf confidence by ROC AUC (a predicted leaf is wrong when its best IoU against a
ground-truth leaf is < 0.5).

    .venv/bin/python benchmarks/seg_external.py [--sets paper8 hard4 heliosdev8] [--seeds 1 2 3]
        [--paper-rules] [--only NAME ...] [--out FILE.json]

Used by benchmarks/segmentation.py (``--external``); runnable on its own.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import external_plants as ext  # noqa: E402


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` ranking ``positive`` first (Mann-Whitney U, ties
    count half). NaN when one class is empty."""
    scores, positive = np.asarray(scores, float), np.asarray(positive, bool)
    pos, neg = scores[positive], scores[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    gt = (pos[:, None] > neg[None]).sum() + 0.5 * (pos[:, None] == neg[None]).sum()
    return float(gt / (len(pos) * len(neg)))


def leaf_ious(pred: np.ndarray, gt: np.ndarray) -> dict:
    """Per predicted leaf id (> 0): its best IoU against any ground-truth leaf (floaters ignored)."""
    keep = gt >= -0
    out = {}
    for lab in np.unique(pred[pred > 0]):
        m = (pred == lab) & keep
        best = 0.0
        for g in np.unique(gt[m & (gt > 0)]):
            gm = (gt == g)
            best = max(best, float((m & gm).sum() / max(1, (m | (gm & keep)).sum())))
        out[int(lab)] = best
    return out


def run_plant(folder: Path, paper_rules: bool = False, given_up: bool = False) -> dict:
    from leaffit_usd.segment.auto import SegmentParams, segment_plant, working_normals
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.splats.frame import make_frame

    evs = ext.load_module("eval_seg")
    gt = np.load(folder / "gt.npz", allow_pickle=True)
    t0 = time.perf_counter()
    cloud = load_cloud(str(folder / "point_cloud.ply"))
    root = np.asarray(gt["root"], np.float64)  # a click on the stem base, input frame
    fc = make_frame(cloud, up=gt["up"] if given_up else None, root=root)
    pts = fc.frame.to_working(cloud.means)
    prm = SegmentParams.paper() if paper_rules else SegmentParams()
    seg = segment_plant(pts, fc.root_index, prm, normals=working_normals(cloud, fc.frame.rotation))
    el = time.perf_counter() - t0
    pred = cloud.to_file_order(seg.labels, fill=0).astype(np.int64)
    gl = gt["labels"].astype(np.int64)
    sc = evs.score(gl, pred)
    up_err = float(np.degrees(np.arccos(np.clip(
        np.dot(fc.frame.up, gt["up"])
        / np.linalg.norm(gt["up"]), -1, 1))))
    ious = leaf_ious(pred, gl)
    conf = getattr(seg, "confidence", None)
    leaves = [{"label": k, "iou": v,
               "confidence": None if conf is None or k - 1 >= len(conf) else float(conf[k - 1])}
              for k, v in ious.items()]
    return {"name": folder.name, "species": str(gt["species"]) if "species" in gt else folder.name,
            "gaussians": int(len(gl)), "gt_leaves": int(gl.max()), "pred_leaves": int(pred.max()),
            "acc": 100 * sc["Acc"], "miou": 100 * sc["mIoU"], "mf1": 100 * sc["mF1"],
            "pq": 100 * sc["PQ"], "time": el, "up_error_deg": up_err, "leaves": leaves}


def summary(rows: list[dict]) -> dict:
    out = {m: float(np.mean([r[m] for r in rows])) for m in ("acc", "miou", "mf1", "pq")}
    lv = [lf for r in rows for lf in r["leaves"] if lf["confidence"] is not None]
    out["auc"] = roc_auc([lf["confidence"] for lf in lv], [lf["iou"] >= 0.5 for lf in lv]) if lv else float("nan")
    out["n"] = len(rows)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", nargs="*", default=["paper8", "hard4", "heliosdev8"])
    ap.add_argument("--seeds", nargs="*", type=int, default=[1, 2, 3])
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--paper-rules", action="store_true")
    ap.add_argument("--given-up", action="store_true",
                    help="use the ground-truth up axis (a quicker check; the issue's protocol estimates it)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    if ext.shared_plants_dir() is None:
        print("../shared/plants is absent: external sets skipped")
        return 0
    allrows = {}
    for s in args.sets:
        rows = []
        for seed in args.seeds:
            for f in ext.plants(ext.ensure_set(s, seed)):
                if args.only and not any(o in f.name for o in args.only):
                    continue
                r = run_plant(f, args.paper_rules, args.given_up)
                r["seed"] = seed
                rows.append(r)
                print(f"{s}-{seed} {r['name']:<24} L={r['gt_leaves']:<3} pred={r['pred_leaves']:<3} "
                      f"Acc {r['acc']:6.2f} mIoU {r['miou']:6.2f} PQ {r['pq']:6.2f} up {r['up_error_deg']:5.1f} "
                      f"{r['time']:.1f}s", flush=True)
        if rows:
            sm = summary(rows)
            allrows[s] = {"summary": sm, "plants": rows}
            print(f"== {s} seeds {args.seeds}: Acc {sm['acc']:.2f} mIoU {sm['miou']:.2f} "
                  f"mF1 {sm['mf1']:.2f} PQ {sm['pq']:.2f} confidence AUC {sm['auc']:.3f} ({sm['n']} plants)",
                  flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(allrows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
