"""Up-axis and auto-root accuracy on randomly rotated generated plants.

    python benchmarks/up_axis.py [--seeds 3] [--gaussians 60000]

For every plant of ``samples.benchmark_suite()`` and ``--seeds`` random global frames each
(the generator places each plant by a random similarity, like an SfM reconstruction), runs
``estimate_up_with_confidence`` on the Gaussian centres and normals (``--points-only``: centres
only) and ``resolve_root`` (automatic root) with
the estimated up; reports the angle to the true up, the root's distance to the true root
(fraction of plant height) and the confidence. Writes benchmarks/results/up_axis.json.
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
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/up_axis.json"))
    args = ap.parse_args(argv)
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
    atomic_write_bytes(args.out, json.dumps({"summary": summary, "runs": rows}, indent=1).encode())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
