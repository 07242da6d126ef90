"""Run every benchmark in turn (``make bench``); each prints its table and writes
benchmarks/results/<name>.json. Heavy: about an hour on 2 cores. Pass names to run a subset:

    .venv/bin/python benchmarks/run_all.py segmentation deformation
"""
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ["read_ply", "up_axis", "segmentation", "deformation", "fit_time", "mesh", "size", "evaluator", "manual",
         "editing"]


def main(names):
    failed = []
    for name in names or ORDER:
        print(f"\n===== benchmarks/{name}.py =====", flush=True)
        t = time.perf_counter()
        rc = subprocess.call([sys.executable, str(HERE / f"{name}.py")])
        print(f"===== {name}: exit {rc}, {time.perf_counter() - t:.0f} s", flush=True)
        if rc:
            failed.append(name)
    if failed:
        print("failed:", ", ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
