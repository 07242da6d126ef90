"""Segmentation benchmark: the paper's Table 1 (Acc, mIoU, mF1, PQ, time; mean and std).

Our suite: ours (the blades method, :mod:`leaffit_usd.segment.blades`, the default), the apex
method (the paper's march with our fixes, the previous default), the paper's rules exactly, and
the training-free Euclidean-density baseline (``benchmarks/baselines/segmentation.py``) on the
generated plants (``samples.benchmark_suite()``, ground truth from the generator; ground-truth up
and root), by group: the paper's "elliptic" set (its six plants), and by the generator's leaf
family: elliptic, lobed, long-thin, other (cordate, mixed) and the hard overlap plants. Time is
the segmentation only (normals + segment_plant from working-frame points), wall clock, with the
process CPU time beside it (on a shared machine the wall clock mostly measures the others).

``--external`` also runs the external sets of ../shared/plants (benchmarks/seg_external.py: the
root given as a click, the up axis estimated; skipped with a message when ../shared is absent),
ours beside the paper's rules, with the per-leaf confidence's ROC AUC.

    .venv/bin/python benchmarks/segmentation.py [--gaussians 100000] [--only NAME ...]
        [--methods ours ours_apex ours_paper_rules baseline] [--external [SET ...]] [--seeds 1 2 3]

Writes benchmarks/results/segmentation.json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leaffit_usd.metrics import segmentation_scores  # noqa: E402
from leaffit_usd.segment.auto import SegmentParams, segment_plant, working_normals  # noqa: E402
from benchmarks.baselines.segmentation import segment_density  # noqa: E402
from leaffit_usd.splats.frame import make_frame  # noqa: E402

PAPER_ELLIPTIC = ["rubber_tree", "green_pepper", "golden_pothos", "black_pearl_pepper", "ruby_leaf",
                  "white_flag_bush"]
METRICS = ["acc", "miou", "mf1", "pq", "time"]


def category(spec) -> str:
    if spec.hard or spec.overlap != "none":
        return "overlap"
    return {"elliptic": "elliptic", "lobed": "lobed", "thin": "long-thin"}.get(spec.kind, "other")


def run_one(name, spec, seed, methods):
    from samples.generate import make_plant

    cloud, gt = make_plant(spec, seed)
    out = {"name": name, "kind": spec.kind, "overlap": spec.overlap, "category": category(spec),
           "leaves": int(gt.labels.max()), "gaussians": len(cloud)}
    t0 = time.perf_counter()
    fc = make_frame(cloud, up=gt.up, root=None, root_index=int(gt.root_index))
    pts = fc.frame.to_working(cloud.means)
    out["frame_time"] = time.perf_counter() - t0
    for meth in methods:
        t0, c0 = time.perf_counter(), time.process_time()
        if meth == "ours":
            nrm = working_normals(cloud, fc.frame.rotation)
            seg = segment_plant(pts, fc.root_index, SegmentParams(), normals=nrm)
            labels = seg.labels
        elif meth == "ours_apex":  # the previous default: the paper's march with our fixes
            labels = segment_plant(pts, fc.root_index, SegmentParams(method="apex"),
                                   normals=working_normals(cloud, fc.frame.rotation)).labels
        elif meth == "ours_paper_rules":  # the paper's algorithm exactly
            labels = segment_plant(pts, fc.root_index, SegmentParams.paper()).labels
        else:
            labels = segment_density(pts, fc.root_index).labels
        el, cpu = time.perf_counter() - t0, time.process_time() - c0
        sc = segmentation_scores(cloud.to_file_order(labels), gt.labels)
        out[meth] = {**sc.as_dict(), "time": el, "cpu_time": cpu}
    return out


def table(rows, methods, title):
    lines = [title,
             f"{'Method':<22}" + "".join(f"{h:>16}" for h in ["Acc", "mIoU", "mF1", "PQ", "Time (s)"]),
             f"{'':<22}" + "".join(f"{'Mean':>9}{'Std':>7}" for _ in METRICS)]
    summary = {}
    for meth in methods:
        vals = {m: np.array([r[meth][m] for r in rows]) for m in METRICS}
        summary[meth] = {m: {"mean": float(v.mean()), "std": float(v.std())} for m, v in vals.items()}
        cells = []
        for m in METRICS:
            f = "{:9.3f}{:7.3f}" if m == "time" else "{:9.2f}{:7.2f}"
            cells.append(f.format(vals[m].mean(), vals[m].std()))
        label = {"ours": "Ours (blades)", "baseline": "Euclidean Density",
                 "ours_paper_rules": "Paper rules (apex)",
                 "ours_apex": "Ours, apex method"}[meth]
        lines.append(f"{label:<22}" + "".join(cells))
    return "\n".join(lines), summary


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, default=100_000)
    ap.add_argument("--only", nargs="*", help="plant names from samples.benchmark_suite()")
    ap.add_argument("--methods", nargs="*",
                    default=["ours", "ours_apex", "ours_paper_rules", "baseline"],
                    help="ours (the blades method, the default), ours_apex (the paper's apex -> "
                         "tree -> petiole march with our fixes, the previous default), "
                         "ours_paper_rules (the paper's algorithm exactly), baseline")
    ap.add_argument("--external", nargs="*", metavar="SET",
                    help="also run the external sets of ../shared/plants (paper8 hard4 heliosdev8 "
                         "when given without names; skipped with a message when absent), with "
                         "the root given and the up axis estimated, as a new user would")
    ap.add_argument("--seeds", nargs="*", type=int, default=[1, 2, 3],
                    help="seeds of the external sets (1 2 3)")
    ap.add_argument("--suite-seeds", type=int, default=1, metavar="N",
                    help="run each suite plant at N seeds of the generator: its own seed s, then "
                         "s+100, s+200, ... (1: the fixed suite; more: is a gap between two "
                         "methods on the fixed suite larger than the seed-to-seed spread?)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/segmentation.json"))
    args = ap.parse_args(argv)
    if args.suite_seeds < 1:
        ap.error("--suite-seeds must be >= 1")
    from samples.generate import benchmark_suite

    suite = [s for s in benchmark_suite(args.gaussians) if not args.only or s[0] in args.only]
    import open3d  # noqa: F401  - warm the imports (open3d alone takes 1-3 s) out of the timings
    from leaffit_usd.geometry.sampling import farthest_point_sampling

    farthest_point_sampling(np.random.default_rng(0).random((3000, 3)), 100)
    rows = []
    for name, spec, seed, k in [(n, sp, sd + 100 * k, k) for n, sp, sd in suite
                                for k in range(args.suite_seeds)]:
        r = run_one(name, spec, seed, args.methods)
        r["seed"], r["seed_set"] = seed, k
        rows.append(r)
        print(f"{name:<20} {r['category']:<10} L={r['leaves']:<3}"
              + (f" seed {seed:<4}" if args.suite_seeds > 1 else "") + "  ".join(
            f"{m}: Acc {r[m]['acc']:6.2f} mIoU {r[m]['miou']:6.2f} PQ {r[m]['pq']:6.2f} "
            f"({r[m]['n_pred'] - 1}/{r['leaves']} leaves) {r[m]['time']:.2f}s" for m in args.methods),
            flush=True)
    groups = {"paper elliptic set (6 presets)": [r for r in rows if r["name"] in PAPER_ELLIPTIC]}
    for cat in ["elliptic", "lobed", "long-thin", "other", "overlap"]:
        groups[f"{cat} plants"] = [r for r in rows if r["category"] == cat]
    groups["all plants"] = rows
    result = {"gaussians": args.gaussians, "params": SegmentParams().__dict__, "plants": rows,
              "groups": {}}
    print()
    for title, rs in groups.items():
        if not rs:
            continue
        names = list(dict.fromkeys(r["name"] for r in rs))
        seeds = f" ({args.suite_seeds} seeds each)" if args.suite_seeds > 1 else ""
        text, summ = table(rs, args.methods, f"== {title}{seeds}: {', '.join(names)}")
        print(text)
        for k in range(args.suite_seeds if args.suite_seeds > 1 else 0):  # one line per seed set
            at = [r for r in rs if r["seed_set"] == k]
            print(f"   seeds s+{100 * k:<4}" + "".join(
                f"  {m}: " + " / ".join(f"{np.mean([r[m][x] for r in at]):.2f}" for x in ("acc", "miou", "pq"))
                for m in args.methods))
        print()
        result["groups"][title] = {"plants": names, **summ}
    times = np.array([r["ours"]["time"] for r in rows]) if "ours" in args.methods else np.zeros(0)
    if len(times):
        cpu = np.array([r["ours"]["cpu_time"] for r in rows])
        fr = np.array([r["frame_time"] for r in rows])
        try:
            load = os.getloadavg()[0]
        except OSError:
            load = float("nan")
        print(f"ours: median wall time {np.median(times):.3f} s, median CPU time {np.median(cpu):.3f} s "
              f"per plant ({args.gaussians} Gaussians; frame set-up {np.median(fr):.3f} s more; "
              f"{os.cpu_count()} cores, load average {load:.1f} at the end)")
        result["ours_median_time"] = float(np.median(times))
        result["ours_median_cpu_time"] = float(np.median(cpu))
        result["load_average"] = load
    if args.external is not None:
        result["external"] = run_external(args.external or ["paper8", "hard4", "heliosdev8"], args.seeds)
    from benchmarks.machine import machine_info

    result["machine"] = machine_info()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")


def run_external(sets, seeds) -> dict:
    """The external sets (benchmarks/seg_external.py), one table row per set, ours beside the
    paper's rules; tuned on: samples/ and heliosdev8 seed 1 (see README)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import external_plants
    import seg_external

    if external_plants.shared_plants_dir() is None:
        print("../shared/plants is absent: the external sets are skipped")
        return {}
    out = {}
    for name in sets:
        rows = {m: [] for m in ("ours", "paper")}
        for seed in seeds:
            for folder in external_plants.plants(external_plants.ensure_set(name, seed)):
                for m in rows:
                    r = seg_external.run_plant(folder, paper_rules=(m == "paper"))
                    rows[m].append({**r, "seed": seed})
                print(f"{name}-{seed} {folder.name:<26} ours mIoU {rows['ours'][-1]['miou']:6.2f} "
                      f"({rows['ours'][-1]['time']:.1f}s)  paper rules mIoU {rows['paper'][-1]['miou']:6.2f}",
                      flush=True)
        out[name] = {m: {"summary": seg_external.summary(v), "plants": v} for m, v in rows.items()}
    print(f"\n== external sets, seeds {seeds}: Acc / mIoU / mF1 / PQ (mean over plants), "
          "confidence ROC AUC (wrong leaf = IoU < 0.5)")
    print(f"{'set':<12}{'plants':>7}  {'ours':<34}{'AUC':>6}  paper rules")
    for name, v in out.items():
        o, p = v["ours"]["summary"], v["paper"]["summary"]
        print(f"{name:<12}{o['n']:>7}  {o['acc']:6.2f} {o['miou']:6.2f} {o['mf1']:6.2f} {o['pq']:6.2f}"
              f"{'':>6}{o['auc']:8.3f}  {p['acc']:6.2f} {p['miou']:6.2f} {p['mf1']:6.2f} {p['pq']:6.2f}")
    return out


if __name__ == "__main__":
    main()
