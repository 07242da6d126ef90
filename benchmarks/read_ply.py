"""Reading a 1,000,000-Gaussian 3DGS PLY (SH degree 3): time and peak memory.

    python benchmarks/read_ply.py [--gaussians 1000000] [--runs 5] [--keep DIR]

Writes a binary INRIA PLY (x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2 rot_0..3,
62 float32 = 248 bytes a Gaussian) to a temporary directory, then reads it ``--runs`` times,
each in a fresh Python process (so the file-system cache is warm but nothing else is shared),
measuring the wall time of ``leaffit_usd.splats.read_ply`` and the process's peak resident set
size (``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which includes the interpreter and numpy,
about 40 MB). Target (issue 2): median < 2 s and peak < 1 GB. Prints a table and writes
benchmarks/results/read_ply.json.
"""
from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leaffit_usd.io_util import atomic_write_bytes  # noqa: E402

TARGET_SECONDS = 2.0
TARGET_BYTES = 1 << 30

_CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from leaffit_usd.splats import read_ply
t1 = time.perf_counter()
cloud = read_ply(sys.argv[1])
t2 = time.perf_counter()
rss_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
print(json.dumps({"read_seconds": t2 - t1, "import_seconds": t1 - t0, "gaussians": len(cloud),
                  "sh_degree": cloud.sh_degree, "peak_rss_bytes": rss_kb * 1024,
                  "cloud_bytes": cloud.nbytes}))
"""


def write_big_ply(path: Path, n: int, seed: int = 0) -> None:
    """A synthetic n-Gaussian SH-degree-3 PLY written in chunks (bounded memory)."""
    from leaffit_usd.splats.cloud import GaussianCloud
    from leaffit_usd.splats.ply import ply_dtype

    rng = np.random.default_rng(seed)
    proto = GaussianCloud(means=np.zeros((1, 3), np.float32), log_scales=np.zeros((1, 3), np.float32),
                          quats=np.ones((1, 4), np.float32), opacity_logits=np.zeros(1, np.float32),
                          sh=np.zeros((1, 16, 3), np.float32))
    dtype = ply_dtype(proto)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
              *[f"property float {name}" for name in dtype.names], "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        chunk = 200_000
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            block = rng.normal(size=(m, len(dtype.names))).astype("<f4")
            block[:, dtype.names.index("rot_0")] += 2.0
            f.write(block.tobytes())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--keep", default=None, help="write the PLY here and keep it")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/read_ply.json"))
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="leaffit-bench-") as tmp:
        path = Path(args.keep or tmp) / f"bench_{args.gaussians}.ply"
        path.parent.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        write_big_ply(path, args.gaussians)
        size = path.stat().st_size
        print(f"wrote {path} ({size / 1e6:.0f} MB) in {time.perf_counter() - t:.1f} s")
        runs = []
        for i in range(args.runs):
            r = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True,
                               text=True, cwd=ROOT, timeout=600)
            if r.returncode != 0:
                sys.stderr.write(r.stderr)
                return 1
            runs.append(json.loads(r.stdout))
            print(f"  run {i + 1}: {runs[-1]['read_seconds']:.3f} s, "
                  f"peak RSS {runs[-1]['peak_rss_bytes'] / 2**20:.0f} MiB", flush=True)
    secs = np.array([r["read_seconds"] for r in runs])
    rss = np.array([r["peak_rss_bytes"] for r in runs])
    summary = {
        "gaussians": args.gaussians, "sh_degree": runs[0]["sh_degree"], "file_bytes": size,
        "runs": args.runs, "median_seconds": float(np.median(secs)), "min_seconds": float(secs.min()),
        "max_seconds": float(secs.max()), "median_peak_rss_bytes": int(np.median(rss)),
        "cloud_bytes": runs[0]["cloud_bytes"],
        "throughput_mb_per_s": float(size / 1e6 / np.median(secs)),
        "target_seconds": TARGET_SECONDS, "target_peak_rss_bytes": TARGET_BYTES,
        "meets_target": bool(np.median(secs) < TARGET_SECONDS and np.median(rss) < TARGET_BYTES),
        "machine": f"{platform.machine()} {platform.processor() or ''} python {platform.python_version()}".strip(),
    }
    print()
    print(f"| {'Gaussians':>10} | {'SH':>2} | {'file (MB)':>9} | {'read median (s)':>15} | "
          f"{'min..max (s)':>12} | {'peak RSS (MiB)':>14} | {'target':>18} |")
    print(f"| {'-' * 10} | {'-' * 2} | {'-' * 9} | {'-' * 15} | {'-' * 12} | {'-' * 14} | {'-' * 18} |")
    print(f"| {args.gaussians:>10,} | {summary['sh_degree']:>2} | {size / 1e6:>9.0f} | "
          f"{summary['median_seconds']:>15.3f} | {secs.min():>5.2f}..{secs.max():<5.2f} | "
          f"{summary['median_peak_rss_bytes'] / 2**20:>14.0f} | "
          f"{'< 2 s, < 1 GB ' + ('OK' if summary['meets_target'] else 'MISSED'):>18} |")
    atomic_write_bytes(args.out, json.dumps({"summary": summary, "runs": runs}, indent=1).encode())
    print(f"wrote {args.out}")
    return 0 if summary["meets_target"] else 1


if __name__ == "__main__":
    sys.exit(main())
