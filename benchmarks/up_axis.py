"""Up-axis and auto-root accuracy on randomly rotated generated plants (and the external plants).

    python benchmarks/up_axis.py [--seeds 3] [--gaussians 60000] [--set samples|external|all]
        [--ext-seeds 1 2 3]

For every plant of ``samples.benchmark_suite()`` and ``--seeds`` random global frames each
(the generator places each plant by a random similarity, like an SfM reconstruction), runs
``estimate_up_with_confidence`` on the Gaussian centres and normals (``--points-only``: centres
only) and ``resolve_root`` (automatic root) with
the estimated up; reports the angle to the true up, the root's distance to the true root
(fraction of plant height) and the confidence. Writes benchmarks/results/up_axis.json.

``--set external`` (or ``all``): the external plants of ``../shared/plants`` (``$LEAFFIT_SHARED_PLANTS``;
skipped with a message when absent): paper8, hard4 and heliosdev8 at ``--ext-seeds`` as generated
(trimmed plants), and paper8 ``--scene`` captures (pot, soil, table, clutter), whose isolated plant
is estimated alone ("scene") -- what ``convert`` would do if no table were found; with the table,
convert takes the table's normal ("table" column). Up error against the generator's up, the
confidence, and the estimator's CPU seconds (user + sys, all threads). Cached in
``$LEAFFIT_EXT_CACHE`` (the scene captures in ``iso-paper8-SEED/scene`` as benchmarks/isolation.py
makes them, else ``scene-SEED``).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leaffit_usd.io_util import atomic_write_bytes  # noqa: E402
from leaffit_usd.splats.root import resolve_root  # noqa: E402
from leaffit_usd.splats.up_axis import estimate_up_with_confidence  # noqa: E402
from samples import benchmark_suite, make_plant  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="random frames per plant")
    ap.add_argument("--gaussians", type=int, default=60_000)
    ap.add_argument("--points-only", action="store_true",
                    help="estimate from the centres only (no Gaussian-normal cue)")
    ap.add_argument("--set", choices=("samples", "external", "all"), default="samples")
    ap.add_argument("--ext-seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/up_axis.json"))
    args = ap.parse_args(argv)
    out = {}
    if args.set in ("samples", "all"):
        out.update(run_samples(args))
    if args.set in ("external", "all"):
        out["external"] = run_external(args.ext_seeds, args.points_only)
    atomic_write_bytes(args.out, json.dumps(out, indent=1).encode())
    print(f"wrote {args.out}")
    return 0


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _estimate(cloud, points_only: bool):
    t = time.process_time()
    est = estimate_up_with_confidence(cloud.means, None if points_only else cloud.shortest_axes())
    return est, time.process_time() - t


def run_external(seeds, points_only: bool = False) -> dict:
    """Up error of every external plant (trimmed sets, and the scene captures' isolated plants)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import external_plants as ext
    from leaffit_usd.pipeline import isolate_stage
    from leaffit_usd.splats import load_cloud

    if ext.shared_plants_dir() is None:
        print("../shared/plants is absent: external plants skipped")
        return {}
    rows = []
    print(f"\n{'set':<14} {'plant':<24} {'up err (deg)':>12} {'conf':>6} {'cpu (s)':>7} {'table err':>9}")
    for name in ("paper8", "hard4", "heliosdev8", "scene"):
        for seed in seeds:
            folder = ext.cache_dir() / f"iso-paper8-{seed}" / "scene"
            if name != "scene" or not (folder / "index.json").is_file():
                folder = ext.ensure_set(name, seed)
            for f in ext.plants(folder):
                gt = np.load(f / "gt.npz")
                cloud = load_cloud(f / "point_cloud.ply")
                table = None
                if name == "scene":
                    cloud, iso = isolate_stage(cloud)
                    table = None if iso.up is None else _angle(iso.up, gt["up"])
                est, cpu = _estimate(cloud, points_only)
                err = _angle(est.up, gt["up"])
                rows.append({"set": name, "seed": seed, "plant": f.name, "up_error_deg": round(err, 2),
                             "confidence": round(est.confidence, 3), "cpu_s": round(cpu, 3),
                             "table_up_error_deg": None if table is None else round(table, 2)})
                print(f"{name + '-' + str(seed):<14} {f.name:<24} {err:>12.2f} {est.confidence:>6.2f} {cpu:>7.2f}"
                      + (f" {table:>9.2f}" if table is not None else ""), flush=True)
    summary = {}
    for name in ("paper8", "hard4", "heliosdev8", "scene"):
        e = np.array([r["up_error_deg"] for r in rows if r["set"] == name])
        if len(e):
            summary[name] = {"plants": len(e), "median_deg": round(float(np.median(e)), 2),
                             "max_deg": round(float(e.max()), 2), "within_10deg": int((e <= 10).sum()),
                             "within_30deg": int((e <= 30).sum())}
    cpu = [r["cpu_s"] for r in rows]
    summary["cpu_median_s"] = round(float(np.median(cpu)), 3) if cpu else None
    print()
    for k, v in summary.items():
        print(f"{k:<12} {v}")
    return {"summary": summary, "runs": rows}


def run_samples(args) -> dict:
    rows = []
    print(f"{'plant':<20} {'seed':>5} {'up err (deg)':>12} {'conf':>6} {'root err (h)':>12} {'time (s)':>8}")
    for name, spec, seed in benchmark_suite(args.gaussians):
        for k in range(args.seeds):
            s = seed * 1000 + k
            cloud, gt = make_plant(dataclasses.replace(spec), s)
            t = time.perf_counter()
            normals = None if args.points_only else cloud.shortest_axes()
            est = estimate_up_with_confidence(cloud.means, normals)
            dt = time.perf_counter() - t
            err = float(np.degrees(np.arccos(np.clip(est.up @ gt.up, -1, 1))))
            ri = resolve_root(cloud, None, None, est.up)
            rerr = float(np.linalg.norm(cloud.means[ri] - gt.root) / gt.height)
            rows.append({"plant": name, "seed": s, "up_error_deg": err, "confidence": est.confidence,
                         "root_error_height": rerr, "seconds": dt})
            print(f"{name:<20} {s:>5} {err:>12.1f} {est.confidence:>6.2f} {rerr:>12.3f} {dt:>8.2f}", flush=True)
    e = np.array([r["up_error_deg"] for r in rows])
    re = np.array([r["root_error_height"] for r in rows])
    conf = np.array([r["confidence"] for r in rows])
    summary = {
        "runs": len(rows), "up_error_median_deg": float(np.median(e)),
        "up_error_p90_deg": float(np.quantile(e, 0.9)),
        "up_within_15deg": float((e < 15).mean()), "up_within_30deg": float((e < 30).mean()),
        "root_error_median_height": float(np.median(re)),
        "root_within_5pct": float((re < 0.05).mean()),
        "confident_runs (conf>=0.2)": int((conf >= 0.2).sum()),
        "confident_within_30deg": float((e[conf >= 0.2] < 30).mean()) if (conf >= 0.2).any() else None,
    }
    print()
    for k, v in summary.items():
        print(f"{k:<32} {v:.3f}" if isinstance(v, float) else f"{k:<32} {v}")
    return {"summary": summary, "runs": rows}


if __name__ == "__main__":
    sys.exit(main())
