"""Tables of the external segmentation runs (the JSON files ``seg_external.py --out`` writes):
per set Acc / mIoU / mF1 / PQ (mean over plants), per seed mIoU, the confidence's ROC AUC, and
paper8's simple-leaf subset (without grape and sorghum), as the issue reports them.

    .venv/bin/python benchmarks/seg_tables.py RUN.json [RUN.json ...] [--replace FIX.json]

``--replace``: plants in FIX.json (same set, seed and name) replace those of the runs (a rerun
of a few plants after a fix that changes nothing for the others).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import seg_external  # noqa: E402

SIMPLE_EXCLUDE = ("grape", "sorghum")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--replace", nargs="*", default=[])
    args = ap.parse_args(argv)
    sets: dict = {}
    for f in args.runs:
        for name, v in json.loads(Path(f).read_text()).items():
            sets.setdefault(name, []).extend(v["plants"])
    for f in args.replace:
        for name, v in json.loads(Path(f).read_text()).items():
            fix = {(p["seed"], p["name"]): p for p in v["plants"]}
            sets[name] = [fix.get((p["seed"], p["name"]), p) for p in sets.get(name, [])]
    groups = {}
    for name, rows in sets.items():
        groups[name] = rows
        if name == "paper8":
            groups["paper8 simple leaves"] = [r for r in rows
                                              if not any(x in r["name"] for x in SIMPLE_EXCLUDE)]
    print(f"{'set':<22}{'plants':>7}{'Acc':>8}{'mIoU':>8}{'mF1':>8}{'PQ':>8}{'AUC':>8}   mIoU by seed")
    for name, rows in groups.items():
        s = seg_external.summary(rows)
        seeds = sorted({r["seed"] for r in rows})
        by_seed = "  ".join(
            f"{sd}: {sum(r['miou'] for r in rows if r['seed'] == sd) / max(1, sum(r['seed'] == sd for r in rows)):.1f}"
            for sd in seeds)
        print(f"{name:<22}{s['n']:>7}{s['acc']:8.2f}{s['miou']:8.2f}{s['mf1']:8.2f}{s['pq']:8.2f}"
              f"{s['auc']:8.3f}   {by_seed}")
    worst = sorted((r for rows in sets.values() for r in rows), key=lambda r: r["miou"])[:6]
    print("lowest plants: " + ", ".join(f"{r['name']} (seed {r['seed']}) {r['miou']:.1f}" for r in worst))
    times = sorted(r["time"] for rows in sets.values() for r in rows)
    print(f"per plant, load + frame (up estimated) + segment, in-process: median {times[len(times) // 2]:.1f} s "
          "(on a machine shared with other jobs)")


if __name__ == "__main__":
    main()
