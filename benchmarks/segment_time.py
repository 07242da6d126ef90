"""Whole-process time of ``leaffit-usd segment`` (issue: <= 4 s per 100k-Gaussian plant and <= 25 s
for 1M, median, on 2 cores), with the up axis given and estimated, beside the process CPU time
(user + sys of the child: on a shared machine the wall clock mostly measures the other processes).

    .venv/bin/python benchmarks/segment_time.py [--repeats 5] [--sizes 100000 1000000] [--plants 8]

Plants: ``make_plants.py --gaussians N`` (paper8, seed 1, the first ``--plants`` of its 8
species: capsicum, soybean, redbud, apple, groundcherry, almond, grape, sorghum) from
../shared/plants when it is there, else the first ``--plants`` of the samples generator's suite
at N Gaussians. Per plant and mode: the median of ``--repeats`` runs; the summary line per size
and mode is the median over the plants (the issue's "median ``segment`` command per
100k-Gaussian plant"). Writes benchmarks/results/segment_time.json.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def plant_files(n: int, count: int, tmp: Path) -> list[tuple[str, Path, str | None]]:
    """(name, PLY path, the up axis as X,Y,Z or None) of ``count`` plants of about ``n``
    Gaussians each."""
    import external_plants as ext

    if ext.shared_plants_dir() is not None:
        folder = ext.ensure_set("paper8", 1, gaussians=n, count=count)
        out = []
        for d in ext.plants(folder)[:count]:
            up = np.load(d / "gt.npz")["up"]
            out.append((d.name, d / "point_cloud.ply", ",".join(f"{v:.6f}" for v in up)))
        return out
    from samples.generate import benchmark_suite, make_plant
    from leaffit_usd.splats.ply import write_ply

    out = []
    for name, spec, seed in benchmark_suite(n)[:count]:
        cloud, gt = make_plant(spec, seed)
        path = tmp / f"{name}_{n}.ply"
        write_ply(cloud, path)
        out.append((name, path, ",".join(f"{v:.6f}" for v in gt.up)))
    return out


def run_once(ply: Path, up: str | None, out: Path) -> tuple[float, float]:
    cmd = [sys.executable, "-m", "leaffit_usd", "segment", str(ply), "-o", str(out), "-q"]
    if up:
        cmd.append(f"--up={up}")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", nargs="*", type=int, default=[100_000, 1_000_000])
    ap.add_argument("--modes", nargs="*", default=["up given", "up estimated"])
    ap.add_argument("--plants", type=int, default=1,
                    help="time the first N plants of the set at each size (8 = all of paper8)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/segment_time.json"))
    args = ap.parse_args(argv)
    rows, summary = [], []
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for n in args.sizes:
            plants = plant_files(n, args.plants, tmp)
            for mode in args.modes:
                per_plant = []
                for name, ply, up in plants:
                    u = up if mode == "up given" else None
                    runs = [run_once(ply, u, tmp / "labels.npz") for _ in range(args.repeats)]
                    wall = float(np.median([r[0] for r in runs]))
                    cpu = float(np.median([r[1] for r in runs]))
                    rows.append({"gaussians": n, "plant": name, "mode": mode, "wall_median": wall,
                                 "cpu_median": cpu, "runs": runs})
                    per_plant.append((wall, cpu))
                    print(f"{n:>9} Gaussians, {name:<16} {mode:<13}: median wall {wall:6.2f} s, "
                          f"CPU {cpu:6.2f} s ({args.repeats} runs)", flush=True)
                wall = float(np.median([w for w, _ in per_plant]))
                cpu = float(np.median([c for _, c in per_plant]))
                summary.append({"gaussians": n, "mode": mode, "plants": len(per_plant),
                                "wall_median": wall, "cpu_median": cpu,
                                "wall_max": float(max(w for w, _ in per_plant))})
                print(f"{n:>9} Gaussians, median of {len(per_plant)} plants, {mode:<13}: wall {wall:6.2f} s "
                      f"(max {summary[-1]['wall_max']:.2f}), CPU {cpu:6.2f} s", flush=True)
    load = os.getloadavg()[0]
    print(f"{os.cpu_count()} cores, load average {load:.1f} at the end")
    from benchmarks.machine import machine_info

    Path(args.out).write_text(json.dumps({"rows": rows, "summary": summary, "load_average": load,
                                          "machine": machine_info()}, indent=1))


if __name__ == "__main__":
    main()
