"""Does isolation keep the plant? On every plant we can generate or read, the share of the
plant's own Gaussians (ground truth: label >= 0; floaters, -1, and scene, -2, excluded) that
``convert``'s isolation keeps, with no options (``isolate_stage``: isolation, then the guard that
keeps a capture whole rather than lose its plant).

Sets: our generator's benchmark suite (14 plants), its capture-like plants (pot, soil, table,
clutter) and capture-realism plants (a pot with soil, real-capture Gaussians); and, when
``../shared/plants`` exists, paper8, hard4 and heliosdev8 at each ``--seeds`` and the paper8
``--scene`` plants. Printed per set: plants, the smallest kept share and where, how many keep
under ``TARGET``, how many the guard kept whole; every plant under the target by name.

    .venv/bin/python benchmarks/isolation_keep.py [--seeds 1 2 3] [--gaussians 60000]
        [--out benchmarks/results/isolation_keep.json]
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

TARGET = 0.995


def kept_share(cloud, labels) -> dict:
    """Isolation as ``convert`` runs it on ``cloud``; labels (N,) ground truth in cloud order."""
    from leaffit_usd.isolate.stage import isolate_stage

    t0 = time.perf_counter()
    _, iso = isolate_stage(cloud)
    plant = np.asarray(labels) >= 0
    kept = np.asarray(iso.classes) == 0
    return {"kept": round(float(kept[plant].mean()), 5), "seconds": round(time.perf_counter() - t0, 2),
            "up_source": iso.up_source, "kept_whole": "kept_whole" in iso.params,
            "removed": iso.removed()}


def generated_sets(gaussians: int):
    """(set name, plant name, cloud, labels) of our own generator's plants."""
    from samples.generate import benchmark_suite, capture_suite, make_plant

    for name, spec, seed in benchmark_suite(gaussians):
        cloud, gt = make_plant(spec, seed)
        yield "suite", name, cloud, gt.labels
    for name, spec, seed in capture_suite(gaussians):
        cloud, gt = make_plant(spec, seed)
        yield "capture", name, cloud, gt.labels


def external_sets(seeds):
    """(set name, plant name, cloud, labels) of ../shared/plants' sets, when present."""
    import external_plants as ext
    from leaffit_usd.splats import load_cloud

    if ext.shared_plants_dir() is None:
        print("../shared/plants is absent: the external sets are skipped")
        return
    for set_name in ("paper8", "hard4", "heliosdev8", "scene"):
        for seed in seeds:
            folder = ext.ensure_set(set_name, seed)
            for d in ext.plants(folder):
                cloud = load_cloud(d / "point_cloud.ply")
                with np.load(d / "gt.npz", allow_pickle=True) as z:
                    labels = np.asarray(z["labels"])[np.asarray(cloud.file_index)]
                yield f"{set_name}-{seed}", d.name, cloud, labels


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--gaussians", type=int, default=60_000)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "isolation_keep.json"))
    args = ap.parse_args(argv)
    from benchmarks.machine import machine_info

    rows = []
    for source in (generated_sets(args.gaussians), external_sets(args.seeds)):
        for set_name, name, cloud, labels in source:
            r = {"set": set_name, "plant": name, **kept_share(cloud, labels)}
            rows.append(r)
            flag = "" if r["kept"] >= TARGET else "   < target"
            print(f"{set_name:14s} {name:26s} kept {100 * r['kept']:7.3f} %  up from {r['up_source'] or '-':5s}"
                  f"{'  KEPT WHOLE' if r['kept_whole'] else ''}{flag}", flush=True)
    print(f"\n{'set':14s} {'plants':>6s} {'min kept %':>10s}  {'< 99.5 %':>8s}  kept whole  worst")
    summary = {}
    for s in dict.fromkeys(r["set"] for r in rows):
        rs = [r for r in rows if r["set"] == s]
        worst = min(rs, key=lambda r: r["kept"])
        summary[s] = {"plants": len(rs), "min_kept": worst["kept"], "worst": worst["plant"],
                      "under_target": sum(r["kept"] < TARGET for r in rs),
                      "kept_whole": sum(r["kept_whole"] for r in rs)}
        print(f"{s:14s} {len(rs):6d} {100 * worst['kept']:10.3f}  {summary[s]['under_target']:8d}  "
              f"{summary[s]['kept_whole']:10d}  {worst['plant']}")
    Path(args.out).write_text(json.dumps({"machine": machine_info(), "target": TARGET,
                                          "summary": summary, "plants": rows}, indent=1) + "\n")
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
