"""Asset size per sample plant: .usdz (geometry + textures) and .usda (+ sidecars) vs the input PLY.

The paper reports 1.13 MB for a ~14-leaf plant (.usdz with textures). Prints one row per plant
and writes benchmarks/results/size.json. The default .usdz leaves the baked-leaves payload out;
the table shows both ("usdz" = the default, "usdz+baked" = packed with --baked yes), the
.usda with its sidecar files, and the UsdValidation error count over the three outputs.

    .venv/bin/python benchmarks/size.py [--plants rubber_tree ...] [--labels-gt] [--out DIR]

--labels-gt uses each sample's ground-truth labels (samples/plants/<name>.gt.npz) instead of the
automatic segmentation, so the figure measures the asset format, not segmentation quality.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from leaffit_usd.io_util import atomic_write_bytes  # noqa: E402
from leaffit_usd.fit.params import FitParams  # noqa: E402
from leaffit_usd.pipeline import ConvertOptions, convert  # noqa: E402
from leaffit_usd.usd.writer import WriteOptions  # noqa: E402

PAPER_USDZ_BYTES = 1.13e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plants", nargs="*", default=None, help="sample names (default: all in samples/plants)")
    ap.add_argument("--labels-gt", action="store_true", help="use the ground-truth labels")
    ap.add_argument("--out", default="/tmp/leaffit_size", help="where the converted assets go")
    ap.add_argument("--texture-format", default="jpg", choices=["jpg", "png"])
    ap.add_argument("--steps", type=int, default=None,
                    help="fit steps (default: the paper's 200). File sizes do not depend on it: the "
                         "same arrays are written whatever the step count; only the wait does")
    args = ap.parse_args(argv)
    plants_dir = ROOT / "samples" / "plants"
    names = args.plants or sorted(p.stem for p in plants_dir.glob("*.ply"))
    out_dir = Path(args.out)
    rows = []
    print(f"{'plant':16s} {'leaves':>6s} {'PLY MB':>8s} {'usdz MB':>8s} {'ratio':>7s} "
          f"{'usdz+baked MB':>13s} {'usda+side MB':>12s} {'tex KB':>7s} {'errors':>6s} {'time s':>7s}")
    for name in names:
        ply = plants_dir / f"{name}.ply"
        labels = plants_dir / f"{name}.gt.npz" if args.labels_gt else None
        fit = FitParams() if args.steps is None else FitParams(steps=args.steps)
        opts = ConvertOptions(labels=str(labels) if labels else None, fit=fit,
                              write=WriteOptions(texture_format=args.texture_format, baked=True))
        t0 = time.perf_counter()
        rep = convert(ply, out_dir / name / f"{name}.usdz", opts)
        dt = time.perf_counter() - t0
        files = rep["sizes"]["files"]
        usdz_baked = rep["sizes"]["output_bytes"]
        baked = files.get("packed_baked", 0)
        tex = files.get("packed_texture_front", 0) + files.get("packed_texture_back", 0)
        # the same asset re-written (no re-fit): default .usdz (no baked payload) and .usda + sidecars
        from leaffit_usd.api import open_plant
        from leaffit_usd.usd.validate import validate_file
        plant = open_plant(out_dir / name / f"{name}.usdz")
        opt = WriteOptions(texture_format=args.texture_format, texture_max_size=16384)
        compact = plant.export(out_dir / name / "compact" / f"{name}.usdz", opt)
        usda = plant.export(out_dir / name / "usda" / f"{name}.usda", opt)
        usdz = compact.path.stat().st_size
        errors = {k: validate_file(p).count("error") for k, p in
                  (("usdz", compact.path), ("usdz_baked", out_dir / name / f"{name}.usdz"), ("usda", usda.path))}
        row = {
            "plant": name, "leaves": rep["counts"]["leaves"], "gaussians": rep["counts"]["gaussians"],
            "ply_bytes": rep["sizes"]["input_bytes"], "usdz_bytes": usdz,
            "usdz_with_baked_bytes": usdz_baked, "baked_payload_bytes": baked,
            "texture_bytes": tex, "usda_with_sidecars_bytes": usda.total_bytes,
            "ratio_ply_to_usdz": round(rep["sizes"]["input_bytes"] / usdz, 2),
            "ratio_ply_to_usdz_with_baked": round(rep["sizes"]["input_bytes"] / usdz_baked, 2),
            "under_paper_1_13MB": usdz < PAPER_USDZ_BYTES,
            "validation_errors": errors,
            "template_vertices": rep["counts"]["template_vertices"], "K": rep["counts"]["K"],
            "labels": "ground truth" if labels else "automatic", "fit_steps": rep["params"]["fit"]["steps"],
            "convert_seconds": round(dt, 1),
        }
        rows.append(row)
        print(f"{name:16s} {row['leaves']:6d} {row['ply_bytes'] / 1e6:8.2f} {usdz / 1e6:8.3f} "
              f"{row['ratio_ply_to_usdz']:6.1f}x {usdz_baked / 1e6:13.3f} "
              f"{usda.total_bytes / 1e6:12.3f} {tex / 1e3:7.1f} {sum(errors.values()):6d} {dt:7.1f}", flush=True)
    out = ROOT / "benchmarks" / "results" / "size.json"
    atomic_write_bytes(out, (json.dumps({"paper_usdz_bytes": PAPER_USDZ_BYTES, "plants": rows}, indent=2) + "\n").encode())
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
