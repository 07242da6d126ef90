"""Registration time and memory for a whole plant (issue budget: a 14-leaf, 100k-Gaussian plant in
< 30 s on 2 cores, < 4 GB): ``fit_leaves`` with the paper defaults (K = 32, 200 Adam steps) on
the generated rubber tree, ground-truth segmentation, median of several runs in one process.

    .venv/bin/python benchmarks/fit_time.py [--runs 3] [--gaussians 100000] [--outline-weight W]

Writes benchmarks/results/fit_time.json.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from benchmarks.deformation import load_plant
    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.fit.register import fit_leaves
    from samples import benchmark_suite

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--gaussians", type=int, default=100_000)
    ap.add_argument("--plant", default="rubber_tree")
    ap.add_argument("--outline-weight", type=float, default=FitParams().outline_weight,
                    help="FitParams.outline_weight (0 = the outline term off; default: the default)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "fit_time.json"))
    args = ap.parse_args(argv)
    spec, seed = next((s, sd) for n, s, sd in benchmark_suite() if n == args.plant)
    from dataclasses import replace

    cw, seg, *_ = load_plant(replace(spec, gaussians=args.gaussians), seed)
    times = []
    for _ in range(args.runs):
        t = time.perf_counter()
        fits = fit_leaves(cw, seg, FitParams(outline_weight=args.outline_weight))
        times.append(time.perf_counter() - t)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    out = {"plant": args.plant, "gaussians": len(cw), "leaves": int(seg.n_leaves), "K": fits.K,
           "steps": FitParams().steps, "outline_weight": args.outline_weight, "runs": times, "median_s": statistics.median(times),
           "peak_rss_bytes": rss, "loadavg": os.getloadavg(), "rigid_fallbacks": int(fits.fallback.sum())}
    print(f"fit_leaves: {args.plant}, {len(cw)} Gaussians, {seg.n_leaves} leaves, K={fits.K}, "
          f"{FitParams().steps} steps: median {out['median_s']:.1f} s over {args.runs} runs "
          f"({', '.join(f'{t:.1f}' for t in times)}), peak RSS {rss / 2**20:.0f} MiB, "
          f"load average {out['loadavg'][0]:.1f}")
    dst = Path(args.out)
    dst.write_text(json.dumps(out, indent=1))
    print(f"wrote {dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
