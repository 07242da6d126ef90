"""Evaluator speed (issue 6, Done when): 1,000 leaves x 2,048 vertices x K = 32 in < 100 ms.

Paper, Sec. "GPU instancing and memory footprint": the per-leaf compute is O(|V| K) and
parallelisable. This measures the CPU reference evaluator (``leaffit_usd.runtime.evaluator``) on
a synthetic plant of that size, median of ``--repeats`` runs after one warm-up:

  weights            mls_weights for the template, once per asset          (V x K)
  deform             MLS of all leaves: one (V, K) @ (K, 3 L) product       (per frame)
  deform+transform   + PointInstancer transforms (asset frame)              (per frame)  <- target
                     (default order: transforms applied to the K targets before deform; the
                     literal order, transforms on the V vertices after it, is timed too)
  evaluate()         the public call: weights + deform + transform to the input frame + faces
  GLSL (llvmpipe)    the shader on Mesa's CPU rasteriser, transform feedback (with --gl)

Usage:  .venv/bin/python benchmarks/evaluator.py [--repeats 15] [--gl]
Writes benchmarks/results/evaluator.json. The machine's load average is recorded: the 2 cores
may be shared, so re-run on a quiet machine before quoting a figure.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.machine import machine_info  # noqa: E402
from leaffit_usd.runtime.evaluator import LeafEvaluator, evaluate, instance_matrices  # noqa: E402
from samples.synthetic.runtime import synthetic_asset  # noqa: E402

TARGET_MS = 100.0


def timeit(fn, repeats: int) -> dict:
    fn()  # warm-up (page faults, BLAS thread start)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(1e3 * (time.perf_counter() - t))
    return {"median_ms": statistics.median(ts), "min_ms": min(ts), "max_ms": max(ts),
            "runs": len(ts)}


def blas_info() -> str:
    try:
        from threadpoolctl import threadpool_info
        return ", ".join(f"{i['internal_api']} x{i['num_threads']}" for i in threadpool_info())
    except Exception:  # noqa: BLE001 - informative only
        return "unknown"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--leaves", type=int, default=1000)
    ap.add_argument("--vertices", type=int, default=2048)
    ap.add_argument("-K", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--gl", action="store_true", help="also time the GLSL shader on llvmpipe")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "evaluator.json"))
    args = ap.parse_args(argv)

    load_before = os.getloadavg()
    asset = synthetic_asset(args.leaves, args.vertices, args.K, seed=0)
    L, V, K = asset.n_leaves, len(asset.template_points), args.K
    ev = LeafEvaluator.from_asset(asset)
    M = instance_matrices(asset.positions, asset.orientations, asset.scales)

    rows = {
        "weights (once per asset)": timeit(lambda: LeafEvaluator.from_asset(asset), args.repeats),
        "deform (MLS only)": timeit(lambda: ev.deform_local(asset.targets), args.repeats),
        "deform+transform float64": timeit(lambda: ev.evaluate(asset.targets, M), args.repeats),
        "deform+transform float32 out": timeit(
            lambda: ev.evaluate(asset.targets, M, out_dtype=np.float32), args.repeats),
        "deform+transform, order='points' (literal)": timeit(
            lambda: ev.evaluate(asset.targets, M, order="points"), args.repeats),
        "evaluate() input frame float64": timeit(lambda: evaluate(asset), args.repeats),
        "evaluate() input frame float32": timeit(lambda: evaluate(asset, dtype=np.float32),
                                                 args.repeats),
    }
    gl_error = None
    if args.gl:
        try:
            from leaffit_usd.runtime.shader import GLDeformer
            for variant in ("controls", "weights"):
                gl = GLDeformer(variant=variant)
                rows[f"GLSL {variant} (llvmpipe, incl. upload+readback)"] = timeit(
                    lambda: gl.deform(asset), max(3, args.repeats // 3))
                gpu = gl.deform(asset)
                cpu = evaluate(asset, frame="asset").vertices.reshape(gpu.shape)
                size = np.linalg.norm(cpu.max(1) - cpu.min(1), axis=1)
                rows[f"GLSL {variant} (llvmpipe, incl. upload+readback)"]["max_rel_error"] = float(
                    (np.linalg.norm(gpu - cpu, axis=2).max(1) / size).max())
                gl.release()
        except RuntimeError as e:
            gl_error = str(e)
    load_after = os.getloadavg()

    target_row = "deform+transform float64"
    passed = rows[target_row]["median_ms"] < TARGET_MS
    print(f"Evaluator speed: {L} leaves x {V} vertices x K={K} "
          f"({L * V:,} vertices, {L * V * K * 3:,} multiply-adds)")
    print(f"cores: {os.cpu_count()}  BLAS: {blas_info()}  load avg before/after: "
          f"{load_before[0]:.2f}/{load_after[0]:.2f}")
    print(f"{'step':<52} {'median ms':>10} {'min':>8} {'max':>8}")
    for name, r in rows.items():
        print(f"{name:<52} {r['median_ms']:>10.1f} {r['min_ms']:>8.1f} {r['max_ms']:>8.1f}"
              + (f"   max err {r['max_rel_error']:.1e} x leaf" if "max_rel_error" in r else ""))
    if gl_error:
        print(f"GLSL skipped: {gl_error}")
    print(f"target: '{target_row}' < {TARGET_MS:.0f} ms -> {'PASS' if passed else 'FAIL'}")

    result = {
        "benchmark": "evaluator", "leaves": L, "vertices_per_leaf": V, "K": K,
        "target_ms": TARGET_MS, "target_row": target_row, "pass": bool(passed),
        "rows": rows, "blas": blas_info(),
        "loadavg_before": load_before, "loadavg_after": load_after,
        "machine": machine_info(), "gl_error": gl_error,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
