"""Segmentation on the labelled real scans of ``../shared/real`` (plants that exist, scanned by
other people: ``maize_scanner/``, 12 maize shoots from a handheld scanner; ``tomato_seedling/``,
one MVS tomato seedling at two dates). The issue's protocol: the root given as a click, the up
axis estimated; every scan point becomes one Gaussian from its neighbourhood
(``splats.points.gaussians_from_points``). Scored by the shared evaluator
(``../shared/plants/eval_seg.py``: labels in file order, -1 ignored).

The click (a rule on the ground-truth labels, the same for every scan): the stem's base is the
end of the stem away from the leaves. The stem points' principal axis is oriented from the stem
centroid towards the leaf points' centroid; of the stem points within 2 % of the stem's extent
along that axis from its low end, the one nearest to their median is the click (the middle of
the stem's cut, as a user would click it).

Per plant: Acc / mIoU / PQ, leaves found / true, the share of points labelled stem against the
truth's (the failure this guards against: whole leaves swallowed by the stem), time; the means
per set and over all.

    .venv/bin/python benchmarks/real_scans.py [--only NAME ...] [--method blades|apex]
        [--paper-rules] [--out FILE.json]

Writes benchmarks/results/real_scans.json. Skips with a message when ``../shared/real`` is absent.
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

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real"
SETS = ("maize_scanner", "tomato_seedling")


def read_scan(path: Path):
    """(points (N, 3) float64, colours (N, 3) in [0, 1] or None, labels (N,) int64) of a labelled
    PLY (``x y z [red green blue] label``), file order."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"].data
    pts = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    names = v.dtype.names
    rgb = None
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float64)
        rgb = rgb / (255.0 if rgb.max() > 1.0 else 1.0)
    return pts, rgb, np.asarray(v["label"]).astype(np.int64)


def stem_base_click(pts: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(3,) the click on the stem's base (see the module docstring): the stem's low end along its
    principal axis, oriented away from the leaves."""
    stem, leaf = pts[labels == 0], pts[labels > 0]
    c = stem.mean(0)
    _, _, vt = np.linalg.svd(stem - c, full_matrices=False)
    axis = vt[0] * (1.0 if (leaf.mean(0) - c) @ vt[0] >= 0 else -1.0)
    t = (stem - c) @ axis
    low = stem[t <= t.min() + 0.02 * np.ptp(t)]
    med = np.median(low, axis=0)
    return low[np.argmin(np.linalg.norm(low - med, axis=1))]


def run_scan(path: Path, method: str = "blades", paper_rules: bool = False) -> dict:
    """Segment one labelled scan under the protocol; scores and counts (percentages)."""
    import external_plants as ext
    from leaffit_usd.segment.auto import SegmentParams, segment_plant, working_normals
    from leaffit_usd.splats.frame import make_frame
    from leaffit_usd.splats.points import gaussians_from_points

    evs = ext.load_module("eval_seg")
    pts, rgb, gl = read_scan(path)
    click = stem_base_click(pts, gl)
    t0 = time.perf_counter()
    cloud = gaussians_from_points(pts, rgb, source=path.name)
    fc = make_frame(cloud, up=None, root=click)
    prm = SegmentParams.paper() if paper_rules else SegmentParams(method=method)
    seg = segment_plant(fc.frame.to_working(cloud.means), fc.root_index, prm,
                        normals=working_normals(cloud, fc.frame.rotation))
    el = time.perf_counter() - t0
    pred = cloud.to_file_order(seg.labels, fill=0).astype(np.int64)
    sc = evs.score(gl, pred)
    known = gl >= 0
    return {"name": path.stem, "set": path.parent.name, "points": int(len(gl)),
            "gt_leaves": int(gl.max()), "pred_leaves": int(len(np.unique(pred[pred > 0]))),
            "acc": 100 * sc["Acc"], "miou": 100 * sc["mIoU"], "pq": 100 * sc["PQ"],
            "stem_pred": 100 * float((pred[known] == 0).mean()),
            "stem_true": 100 * float((gl[known] == 0).mean()),
            "leaves_to_stem": leaves_to_stem(gl, pred), "time": el}


def leaves_to_stem(gt: np.ndarray, pred: np.ndarray) -> int:
    """How many ground-truth leaves have most of their points labelled stem."""
    return int(sum((pred[gt == g] == 0).mean() > 0.5 for g in np.unique(gt[gt > 0])))


def means(rows: list[dict]) -> dict:
    keys = ("acc", "miou", "pq", "stem_pred", "stem_true", "time")
    return {**{k: float(np.mean([r[k] for r in rows])) for k in keys}, "n": len(rows),
            "leaves_to_stem": int(sum(r["leaves_to_stem"] for r in rows))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="scan names (substrings)")
    ap.add_argument("--method", default="blades", choices=("blades", "apex"))
    ap.add_argument("--paper-rules", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/real_scans.json"))
    args = ap.parse_args(argv)
    if not REAL.is_dir():
        print(f"{REAL} is absent: the real scans are skipped")
        return 0
    result = {"protocol": "root = GT stem-base click, up estimated", "method":
              "paper" if args.paper_rules else args.method, "sets": {}}
    allrows = []
    for s in SETS:
        rows = []
        for f in sorted((REAL / s).glob("*.ply")):
            if args.only and not any(o in f.stem for o in args.only):
                continue
            r = run_scan(f, args.method, args.paper_rules)
            rows.append(r)
            print(f"{s:<16}{r['name']:<18} n={r['points']:<6} leaves {r['pred_leaves']:>2}/{r['gt_leaves']:<2} "
                  f"Acc {r['acc']:6.2f} mIoU {r['miou']:6.2f} PQ {r['pq']:6.2f} "
                  f"stem {r['stem_pred']:5.1f}% (true {r['stem_true']:4.1f}%) "
                  f"leaves->stem {r['leaves_to_stem']} {r['time']:.1f}s", flush=True)
        if rows:
            m = means(rows)
            result["sets"][s] = {"mean": m, "plants": rows}
            allrows += rows
            print(f"== {s} ({m['n']} scans): Acc {m['acc']:.2f} mIoU {m['miou']:.2f} PQ {m['pq']:.2f} "
                  f"stem {m['stem_pred']:.1f}% (true {m['stem_true']:.1f}%) "
                  f"leaves->stem {m['leaves_to_stem']}", flush=True)
    if allrows:
        m = means(allrows)
        result["mean"] = m
        print(f"== all ({m['n']} scans): Acc {m['acc']:.2f} mIoU {m['miou']:.2f} PQ {m['pq']:.2f}")
    from benchmarks.machine import machine_info

    result["machine"] = machine_info()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
