"""Whole-process time of ``leaffit-usd segment`` (issue: <= 4 s per 100k-Gaussian plant and <= 25 s
for 1M, median, on 2 cores), with the up axis given and estimated, beside the process CPU time
(user + sys of the child: on a shared machine the wall clock mostly measures the other processes).

    .venv/bin/python benchmarks/segment_time.py [--repeats 5] [--sizes 100000 1000000]

Plants: ``make_plants.py --gaussians N`` (paper8, seed 1, the first plant) from ../shared/plants
when it is there, else the samples generator's rubber tree at N Gaussians. Writes
benchmarks/results/segment_time.json.
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


def plant_file(n: int, tmp: Path) -> tuple[Path, str | None]:
    """(PLY path, the up axis as X,Y,Z or None) of a plant with about ``n`` Gaussians."""
    import external_plants as ext

    if ext.shared_plants_dir() is not None:
        folder = ext.ensure_set("paper8", 1, gaussians=n, count=1)
        first = ext.plants(folder)[0]
        up = np.load(first / "gt.npz")["up"]
        return first / "point_cloud.ply", ",".join(f"{v:.6f}" for v in up)
    from samples.generate import benchmark_suite, make_plant
    from leaffit_usd.splats.ply import write_ply

    name, spec, seed = benchmark_suite(n)[0]
    cloud, gt = make_plant(spec, seed)
    path = tmp / f"{name}_{n}.ply"
    write_ply(cloud, path)
    return path, ",".join(f"{v:.6f}" for v in gt.up)


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
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/segment_time.json"))
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for n in args.sizes:
            ply, up = plant_file(n, tmp)
            for mode, u in (("up given", up), ("up estimated", None)):
                if mode not in args.modes:
                    continue
                runs = [run_once(ply, u, tmp / "labels.npz") for _ in range(args.repeats)]
                wall = float(np.median([r[0] for r in runs]))
                cpu = float(np.median([r[1] for r in runs]))
                rows.append({"gaussians": n, "mode": mode, "wall_median": wall, "cpu_median": cpu,
                             "runs": runs})
                print(f"{n:>9} Gaussians, {mode:<13}: median wall {wall:6.2f} s, CPU {cpu:6.2f} s "
                      f"({args.repeats} runs)", flush=True)
    load = os.getloadavg()[0]
    print(f"{os.cpu_count()} cores, load average {load:.1f} at the end")
    Path(args.out).write_text(json.dumps({"rows": rows, "load_average": load}, indent=1))


if __name__ == "__main__":
    main()
