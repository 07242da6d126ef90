"""glTF delivery and per-leaf appearance, per plant: the GLB through the Khronos validator, and
the per-leaf colour error (CIE76 ΔE*ab, ``leaffit_usd.export.appearance``) of the asset against
the input with and without the per-leaf tint.

Plants: the bundled samples (samples/plants) and the external generator's paper8 preset
(``../shared/plants/make_plants.py --seed 1 --preset paper8``, generated into --ext-dir when
missing; skipped with a message when ../shared/plants is absent). Every plant is converted with
its ground-truth labels, root and up (the figures are about the asset, not the segmentation) to
a .usdc stage; the GLBs (evaluated and --instanced) are exported from that stage.

    .venv/bin/python benchmarks/appearance_gltf.py [--plants rubber_tree ...] [--no-ext]
        [--steps 10] [--out /tmp/leaffit_gltf] [--screenshot docs/gltf_three.png]

--steps: registration steps (default 10, with 2 refinement iterations: the colour figures hardly
depend on the fit's last millimetres, and the 200-step fit takes minutes per plant on a loaded
2-core machine). Writes benchmarks/results/appearance_gltf.json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from leaffit_usd.io_util import atomic_write_bytes  # noqa: E402

SHARED = ROOT.parent / "shared" / "plants"


def ext_plants(ext_dir: Path) -> list[tuple[str, Path, Path]]:
    """(name, ply, gt) of the paper8 seed-1 plants, generating them when missing; [] with a
    message when ../shared/plants is absent or generation fails."""
    if not (SHARED / "make_plants.py").is_file():
        print(f"external plants skipped: {SHARED} is absent")
        return []
    if not (ext_dir / "index.json").is_file():
        r = subprocess.run([sys.executable, str(SHARED / "make_plants.py"), "--out", str(ext_dir),
                            "--seed", "1", "--preset", "paper8"], capture_output=True, text=True)
        if r.returncode != 0:
            print(f"external plants skipped: make_plants.py failed: {r.stderr.strip()[-300:]}")
            return []
    index = json.loads((ext_dir / "index.json").read_text())
    return [(p["name"], ext_dir / p["ply"], ext_dir / p["gt"]) for p in index["plants"]]


def sample_plants(names=None) -> list[tuple[str, Path, Path]]:
    d = ROOT / "samples" / "plants"
    out = []
    for ply in sorted(d.glob("*.ply")):
        if names and ply.stem not in names:
            continue
        out.append((ply.stem, ply, d / f"{ply.stem}.gt.npz"))
    return out


def run_plant(name, ply, gt, out_dir: Path, steps: int) -> dict:
    from leaffit_usd.commands.export import export
    from leaffit_usd.export.appearance import leaf_color_errors
    from leaffit_usd.export.validator import find_validator, validate_gltf
    from leaffit_usd.pipeline import ConvertOptions, convert, load_labels
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.usd.reader import open_stage, read_stage_object, read_texture
    from leaffit_usd.usd.validate import validate_file

    z = np.load(gt)
    from leaffit_usd.fit.params import FitParams

    opts = ConvertOptions(labels=str(gt), root=np.asarray(z["root"], np.float64),
                          up=np.asarray(z["up"], np.float64), fit=FitParams(steps=steps, refine=2))
    stage_path = out_dir / name / f"{name}.usdc"
    t0 = time.perf_counter()
    rep = convert(ply, stage_path, opts)
    t_convert = time.perf_counter() - t0
    usd_errors = validate_file(stage_path).count("error")
    row = {"plant": name, "leaves": rep["counts"]["leaves"], "convert_s": round(t_convert, 1),
           "usd_validation_errors": usd_errors}
    for layout in ("evaluated", "instanced"):
        glb = out_dir / name / f"{name}.{layout}.glb"
        t0 = time.perf_counter()
        info = export(stage_path, glb, instanced=layout == "instanced")
        row[f"{layout}_export_s"] = round(time.perf_counter() - t0, 2)
        row[f"{layout}_bytes"] = info["bytes"]
        if find_validator() is not None:
            v = validate_gltf(glb)
            row[f"{layout}_gltf"] = {"errors": v.errors, "warnings": v.warnings, "infos": v.infos,
                                     "hints": v.hints, "warning_codes": v.codes(1),
                                     "info_codes": v.codes(2)}
    # per-leaf colour error against the input, with and without the tint
    stage = open_stage(stage_path)
    asset = read_stage_object(stage, stage_path)
    front = read_texture(stage, asset.front_texture)
    cloud = load_cloud(ply)
    labels = load_labels(gt, cloud)
    de_t = leaf_color_errors(asset, front, cloud, labels, tinted=True)
    de_u = leaf_color_errors(asset, front, cloud, labels, tinted=False)
    ok = np.isfinite(de_t) & np.isfinite(de_u)
    row.update({"deltaE_tint": np.round(de_t[ok], 2).tolist(), "deltaE_no_tint": np.round(de_u[ok], 2).tolist(),
                "median_deltaE_tint": round(float(np.median(de_t[ok])), 2) if ok.any() else None,
                "median_deltaE_no_tint": round(float(np.median(de_u[ok])), 2) if ok.any() else None,
                "tints": np.round(np.asarray(asset.tints), 3).tolist() if asset.tints is not None else None})
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plants", nargs="*", default=None, help="sample names (default: all)")
    ap.add_argument("--no-ext", action="store_true", help="skip the external paper8 plants")
    ap.add_argument("--ext-dir", default="/tmp/leaffit_ext/paper8-1")
    ap.add_argument("--out", default="/tmp/leaffit_gltf")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--screenshot", default=None, help="render the first plant's GLB with three.js here")
    args = ap.parse_args(argv)
    from leaffit_usd.export.validator import find_validator

    if find_validator() is None:
        print("note: the Khronos glTF validator is not installed (make setup); no validator columns")
    sets = [("samples", sample_plants(args.plants))]
    if not args.no_ext and not args.plants:
        sets.append(("paper8 seed 1", ext_plants(Path(args.ext_dir))))
    out_dir = Path(args.out)
    results = {}
    for set_name, plants in sets:
        if not plants:
            continue
        print(f"\n{set_name}")
        print(f"{'plant':16s} {'leaves':>6s} {'GLB err/warn/info':>17s} {'inst err/warn/info':>18s} "
              f"{'GLB MB':>7s} {'inst MB':>7s} {'USD err':>7s} {'ΔE no tint':>10s} {'ΔE tint':>8s}")
        rows = []
        for name, ply, gt in plants:
            row = run_plant(name, ply, gt, out_dir, args.steps)
            rows.append(row)

            def evi(k):
                g = row.get(f"{k}_gltf")
                return f"{g['errors']}/{g['warnings']}/{g['infos']}" if g else "-"
            print(f"{name:16s} {row['leaves']:6d} {evi('evaluated'):>17s} {evi('instanced'):>18s} "
                  f"{row['evaluated_bytes'] / 1e6:7.2f} {row['instanced_bytes'] / 1e6:7.2f} "
                  f"{row['usd_validation_errors']:7d} {row['median_deltaE_no_tint']:10.2f} "
                  f"{row['median_deltaE_tint']:8.2f}", flush=True)
        all_t = np.concatenate([r["deltaE_tint"] for r in rows])
        all_u = np.concatenate([r["deltaE_no_tint"] for r in rows])
        print(f"{'all leaves':16s} {len(all_t):6d} median per-leaf ΔE*ab: without tint "
              f"{np.median(all_u):.2f}, with tint {np.median(all_t):.2f}")
        results[set_name] = {"plants": rows, "leaves": int(len(all_t)),
                             "median_deltaE_no_tint": round(float(np.median(all_u)), 2),
                             "median_deltaE_tint": round(float(np.median(all_t)), 2)}
    if args.screenshot and sets[0][1]:
        from leaffit_usd.viewer.gltf_view import render_glb

        name = sets[0][1][0][0]
        r = render_glb(out_dir / name / f"{name}.evaluated.glb", png=args.screenshot, size=640)
        print(f"screenshot {args.screenshot}: leaves cover {100 * r['leaves']['fraction']:.1f}% "
              f"of the view, page errors {len(r['pageErrors'])}")
    results["params"] = {"fit_steps": args.steps, "refine": 2, "labels": "ground truth",
                         "metric": "CIE76 ΔE*ab of the mean colour over co-covered pixels, "
                                   "leaf frame, seen from its upper side"}
    out = ROOT / "benchmarks" / "results" / "appearance_gltf.json"
    atomic_write_bytes(out, (json.dumps(results, indent=1) + "\n").encode())
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
