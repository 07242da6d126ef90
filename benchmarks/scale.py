"""Scale benchmark: one plant at 100k, 1M and 5M Gaussians through ``convert`` with no options.

The plant is the external generator's (``../shared/plants/make_plants.py --preset paper8
--count 1 --gaussians N``: the same capsicum, denser), or with ``--samples`` our own
(``samples.generate``, rubber_tree). Every conversion runs in its own process (so its peak
memory is its own): wall and CPU time (user + sys of all threads) of ``convert``, wall time per
stage (the convert report's timings), peak resident memory per stage (``VmHWM``, reset at each
stage's start through ``/proc/self/clear_refs``; the run's peak is the largest), and the leaf
shape error of the baked leaves against the GT meshes (Corr-l2 / CD / HD x10 and matched
leaves, ``../shared/plants/eval_deform.py``), at the evaluator's default 10,000 surface samples
per leaf and at ``--eval-samples`` (300,000): at 10,000 the sampling itself moves a plant's HD by
up to 0.003 (sd 0.001) and its Corr-l2 sits on a floor of ~0.005, both larger than what changes between
sizes. ``--labels gt`` converts with the GT labels
(``convert --labels``), so the shape error is the fit's, not the segmentation's. On the shared
2-core machine wall time depends on the other jobs: compare CPU times too. The done-when
of issue 13: 1M within 2.5x the 100k wall time and under 2 GB; 5M under 8 GB; shape error no
worse than at 100k.

    .venv/bin/python benchmarks/scale.py [--sizes 100000 1000000 5000000] [--seeds 1 2 3] [--samples]
                                         [--labels auto|gt|both]

Writes benchmarks/results/scale.json. Skips with a message when ``../shared/plants`` is absent
(unless ``--samples``).
"""
from __future__ import annotations

import argparse
import importlib.util
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
SHARED = ROOT.parent / "shared" / "plants"

_CHILD = r"""
import json, sys, time, logging
logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
from leaffit_usd import pipeline
from leaffit_usd.commands.bake import bake

def _hwm():  # peak resident set size since the last reset (bytes; Linux /proc)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0

def _reset_hwm():
    try:
        open("/proc/self/clear_refs", "w").write("5")
    except OSError:
        pass

stage_peak = {}
_stage = pipeline._Timer.stage
def stage(self, name, what):  # wrap each convert stage: its own peak RSS
    ctx = _stage(self, name, what)
    class _C:
        def __enter__(s):
            _reset_hwm()
            return ctx.__enter__()
        def __exit__(s, *a):
            stage_peak[name] = _hwm()
            return ctx.__exit__(*a)
    return _C()
pipeline._Timer.stage = stage

t0, c0 = time.perf_counter(), time.process_time()
opts = pipeline.ConvertOptions(labels=sys.argv[5] if len(sys.argv) > 5 else None)
rep = pipeline.convert(sys.argv[1], sys.argv[2], opts)
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
# resetting VmHWM also resets ru_maxrss: the run's peak is the largest stage peak
peak = max([_hwm(), *stage_peak.values()])
bake(sys.argv[2], sys.argv[3])
rep.get("isolation", {}).pop("classes", None)
json.dump({"wall_s": wall, "peak_bytes": peak, "cpu_s": cpu, "stage_peak_bytes": stage_peak,
           "report": rep}, open(sys.argv[4], "w"))
"""

def _load(name):
    path = SHARED / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def make_external(n: int, cache: Path, seed: int = 1) -> tuple[Path, Path]:
    """The paper8 capsicum of generator seed ``seed`` at ``n`` Gaussians, from
    ``external_plants``' cache (``$LEAFFIT_EXT_CACHE``; generated once: ~2 min per million
    Gaussians)."""
    from benchmarks.external_plants import ensure_set, plants

    d = plants(ensure_set("paper8", seed, gaussians=n, count=1))[0]
    return d / "point_cloud.ply", d / "gt.npz"


def make_samples(n: int, cache: Path, seed: int = 1) -> tuple[Path, Path]:
    from samples.generate import make_plant, preset, save_plant

    d = cache / "samples"
    name = f"rubber_tree_{n}" + (f"_s{seed}" if seed != 1 else "")
    if not (d / f"{name}.ply").is_file():
        cloud, gt = make_plant(preset("rubber_tree", gaussians=n), seed)
        save_plant(cloud, gt, d, name)
    return d / f"{name}.ply", d / f"{name}.gt.npz"


def shape_error(gt_path: Path, leaves_npz: Path, n_samples: int = 10000, seed: int = 0) -> dict:
    """``eval_deform``'s leaf shape error of the baked leaves against the GT meshes, with
    ``n_samples`` random surface samples per leaf (the evaluator's default: 10,000) drawn with
    sampling seed ``seed`` (its default: 0)."""
    if not SHARED.is_dir():
        return {}
    ev = _load("eval_deform")
    g = np.load(gt_path)
    if "plant_height" not in g.files:  # samples GT: adapt to the evaluator's keys
        tmp = Path(tempfile.mkdtemp()) / "gt.npz"
        np.savez(tmp, leaf_vertices=g["leaf_vertices"], leaf_faces=g["leaf_faces"],
                 leaf_vertex_ids=g["leaf_vertex_ids"], plant_height=np.float64(g["height"]))
        gt_path = tmp
    r = ev.evaluate_files(str(gt_path), str(leaves_npz), n_samples=n_samples, seed=seed)
    keep = {k: r[k] for k in r if isinstance(r[k], (int, float)) and not isinstance(r[k], bool)}
    keep["per_leaf"] = [{k: (round(v, 5) if isinstance(v, float) else v) for k, v in lf.items()}
                        for lf in r.get("leaves", [])]
    return keep


def _up_error(up, gt_path: Path):
    """Angle (degrees) between the conversion's up axis and the GT's (file frame), or None."""
    g = np.load(gt_path)
    if "up" not in g.files:
        return None
    a, b = np.asarray(up, np.float64), np.asarray(g["up"], np.float64)
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return round(float(np.degrees(np.arccos(np.clip(c, -1, 1)))), 2)


def _print_means(rows: list, sizes: list, modes: list) -> None:
    """Per size and label mode, the shape error averaged over the seeds that ran it."""
    keys = ("corr_l2", "chamfer", "hausdorff", "outline")
    for mode in modes:
        for n in sizes:
            for field, label in (("shape", ""), ("shape_fine", ", fine sampling")):
                got = [r[field] for r in rows if r["gaussians"] == n and r["labels"] == mode
                       and r.get(field)]
                if got:
                    m = {k: float(np.mean([g[k] for g in got])) for k in keys}
                    print(f"mean of {len(got)} plants, {n:>9,d} Gaussians ({mode} labels{label}): Corr "
                          f"{m['corr_l2']:.5f} CD {m['chamfer']:.7f} HD {m['hausdorff']:.4f} OE {m['outline']:.4f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[100_000, 1_000_000, 5_000_000])
    ap.add_argument("--samples", action="store_true", help="our generator instead of the external one")
    ap.add_argument("--labels", choices=("auto", "gt", "both"), default="auto",
                    help="segmentation: automatic, the GT labels (convert --labels: the fit, mesh "
                         "and bake measured apart from the segmentation), or a row of each")
    ap.add_argument("--seeds", type=int, nargs="*", default=[1],
                    help="generator seeds: one plant each (the paper8 capsicum of that seed), every "
                         "size; with several, the mean shape error per size is printed too (one "
                         "plant's Hausdorff distance is a maximum, and moves by +-0.01 between two "
                         "samplings of the same surface)")
    ap.add_argument("--eval-samples", type=int, default=300_000, metavar="N",
                    help="also score the leaves with N surface samples per leaf (0: only the "
                         "evaluator's default 10,000). At 10,000 a plant's Hausdorff distance (x10, "
                         "mean over its leaves) moves by up to 0.003 (sd 0.001) between samplings "
                         "of the same meshes, more than the differences between sizes; at 300,000 "
                         "two samplings agree within 0.0003")
    ap.add_argument("--eval-spread", type=int, default=8, metavar="K",
                    help="score the same leaves at the default 10,000 samples with K sampling seeds "
                         "and print the HD's range (how much of a difference between sizes the "
                         "default sampling can resolve; 0: off)")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "leaffit-scale-bench"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/scale.json"))
    a = ap.parse_args(argv)
    if not a.samples and not SHARED.is_dir():
        print(f"skipping: {SHARED} is absent (use --samples for our own plant)", file=sys.stderr)
        return 0
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    modes = ["auto", "gt"] if a.labels == "both" else [a.labels]
    for seed, n, mode in [(sd, n, m) for sd in a.seeds for n in a.sizes for m in modes]:
        t0 = time.perf_counter()
        ply, gt = (make_samples if a.samples else make_external)(n, cache, seed)
        t_gen = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as td:
            out, leaves, res = Path(td) / "plant.usda", Path(td) / "leaves.npz", Path(td) / "r.json"
            env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")}
            extra = [str(gt)] if mode == "gt" else []     # gt.npz holds 'labels' (file order)
            proc = subprocess.run([sys.executable, "-c", _CHILD, str(ply), str(out), str(leaves), str(res),
                                   *extra], env=env, capture_output=True, text=True)
            if proc.returncode != 0:
                print(proc.stderr[-3000:], file=sys.stderr)
                rows.append({"seed": seed, "gaussians": n, "labels": mode,
                             "error": proc.stderr.strip().splitlines()[-1:]})
                continue
            r = json.loads(res.read_text())
            err = shape_error(gt, leaves)
            fine = shape_error(gt, leaves, a.eval_samples) if a.eval_samples > 0 else {}
            # sampling seed 0 is the evaluator's default: the score above
            hds = ([err["hausdorff"]] + [shape_error(gt, leaves, seed=k)["hausdorff"]
                                         for k in range(1, a.eval_spread)]) if err and a.eval_spread > 0 else []
        rep = r["report"]
        row = {"seed": seed, "gaussians": n, "labels": mode, "gaussians_loaded": rep["counts"]["gaussians_loaded"],
               "wall_s": round(r["wall_s"], 1), "cpu_s": round(r["cpu_s"], 1),
               "peak_gb": round(r["peak_bytes"] / 1e9, 3), "leaves": rep["counts"]["leaves"],
               "timings": rep["timings"],
               "stage_peak_gb": {k: round(v / 1e9, 3) for k, v in r["stage_peak_bytes"].items()}, "shape": err,
               "shape_fine": {**{k: fine[k] for k in ("corr_l2", "chamfer", "hausdorff", "outline") if k in fine},
                              "n_samples": a.eval_samples} if fine else None,
               "hd_sampling_spread": {"seeds": len(hds), "min": float(np.min(hds)), "max": float(np.max(hds)),
                                      "mean": float(np.mean(hds)), "sd": float(np.std(hds))} if hds else None,
               "generate_s": round(t_gen, 1),
               "isolation_removed": rep["isolation"]["removed"],
               "fit_error_per_leaf": rep["fit"]["per_leaf"],
               "rigid_fallback_leaves": rep["counts"]["rigid_fallback_leaves"],
               "up_error_deg": _up_error(rep["frame"]["up"], gt),
               "bake": {k: rep["mesh_report"].get(k) for k in
                        ("template_gaussians", "bake_gaussians", "bake_widen")},
               "mesh_timings": rep["mesh_report"].get("timings")}
        rows.append(row)
        print(f"seed {seed} {n:>9,d} Gaussians ({mode} labels): wall {row['wall_s']:7.1f} s, CPU {row['cpu_s']:7.1f} s, peak {row['peak_gb']:.2f} GB, "
              f"{row['leaves']} leaves, stages " + ", ".join(f"{k} {v:.1f}" for k, v in rep["timings"].items())
              + "; stage peaks GB " + ", ".join(f"{k} {v:.2f}" for k, v in row["stage_peak_gb"].items())
              + ("  Corr %.5f CD %.6f HD %.4f OE %.4f matched %s" % (
                  err.get("corr_l2", np.nan), err.get("chamfer", np.nan), err.get("hausdorff", np.nan),
                  err.get("outline", np.nan), err.get("n_matched")) if err else "")
              + ("; at %d samples per leaf: Corr %.5f CD %.7f HD %.4f OE %.4f" % (
                  a.eval_samples, fine["corr_l2"], fine["chamfer"], fine["hausdorff"], fine["outline"])
                 if fine else "")
              + ("; HD over %d samplings of 10,000: %.4f-%.4f (mean %.4f, sd %.4f)" % (
                  len(hds), np.min(hds), np.max(hds), np.mean(hds), np.std(hds)) if hds else ""), flush=True)
    for seed, mode in [(sd, m) for sd in a.seeds for m in modes]:
        mine = [r for r in rows if r["seed"] == seed and r["labels"] == mode and "wall_s" in r]
        base = next((r for r in mine if r["gaussians"] == min(a.sizes)), None)
        for r in mine if base else []:
            r["wall_vs_smallest"] = round(r["wall_s"] / base["wall_s"], 2)
            r["cpu_vs_smallest"] = round(r["cpu_s"] / base["cpu_s"], 2)
    if len(a.seeds) > 1:
        _print_means(rows, a.sizes, modes)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    from benchmarks.machine import machine_info

    Path(a.out).write_text(json.dumps({"plant": "samples rubber_tree" if a.samples else "make_plants paper8 #0",
                                       "rows": rows, "machine": machine_info()}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
