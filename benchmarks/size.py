"""Asset size table: the .usdz and .glb of every sample and shared plant against the input as
PLY, SPZ and ``.splat``, with what each byte of the .usdz is for, and render fidelity.

Plants: the committed samples (``samples/plants/*.ply``), the paper8 plants of the shared cache
(``~/.cache/leaffit-plants/sets/paper8-1``, when present) and the real houseplant
(``../shared/real/houseplant.splat``, ``--up -y``; skipped with a message when absent). Each is
converted once with the default options to ``.usdz`` (``--labels-gt``: the samples' and paper8's
ground-truth labels, so the figure measures the format, not the segmentation); the ``.glb`` is
exported from that stage (``leaffit-usd export``: the evaluated leaves + stem, textures as PNG
with the cut-out), so the two formats hold the same asset.

Input sizes, for the same Gaussians (after loading: the file's own count):

* PLY: the INRIA binary PLY (the file itself when the input is one, else ``splats.write_ply``);
* ``.splat``: antimatter15's layout, 32 bytes a Gaussian (no header), SH dropped;
* SPZ: Niantic's layout (v2: a 16-byte header; 24-bit fixed-point positions, 8-bit opacity,
  colour, log-scales and rotation, 8-bit SH rest coefficients), gzip level 9, packed here from
  the cloud's arrays (the repo has no SPZ writer; quantised as the format does, so its size is
  the format's to within the gzip stream's own variation).

Per plant the .usdz's share by part (stage layer, geometry payload, textures, masks) comes from
the writer's report; ``ratio`` = PLY / .usdz. The last lines: the median ratio, and the render
fidelity (silhouette IoU min, PSNR, SSIM) of the plants ``benchmarks/render.py`` measured
(its results JSON; ``--render-before B.json`` prints that run beside, so size is never bought
with looks).

    .venv/bin/python benchmarks/size.py [--plants a,b] [--sets samples,paper8,real] [--labels-gt]
        [--out DIR] [--render-before B.json]

Writes benchmarks/results/size.json.
"""
from __future__ import annotations

import argparse
import gzip
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from leaffit_usd.io_util import atomic_write_bytes  # noqa: E402

PAPER_USDZ_BYTES = 1.13e6
PAPER8 = Path.home() / ".cache" / "leaffit-plants" / "sets" / "paper8-1"
HOUSEPLANT = ROOT.parent / "shared" / "real" / "houseplant.splat"
SPLAT_BYTES_PER_GAUSSIAN = 32


def spz_bytes(cloud) -> int:
    """Bytes of the cloud as SPZ (v2 layout, gzip 9): see the module doc.

    cloud : GaussianCloud (any frame). Positions as 24-bit fixed point with 12 fractional bits
    (the format's default), the other attributes 8-bit, attribute-major as SPZ stores them."""
    m = np.asarray(cloud.means, np.float64)
    n = len(m)
    fixed = np.clip(np.round(m * 4096.0), -(1 << 23), (1 << 23) - 1).astype(np.int64) & 0xFFFFFF
    pos = np.stack([(fixed >> s) & 0xFF for s in (0, 8, 16)], -1).astype(np.uint8)
    u8 = lambda x: np.clip(np.round(x), 0, 255).astype(np.uint8)  # noqa: E731
    alpha = u8(np.asarray(cloud.opacities, np.float64) * 255)
    color = u8((np.asarray(cloud.sh[:, 0, :], np.float64) * 0.15 + 0.5) * 255)  # SPZ's DC scale
    scale = u8((np.asarray(cloud.log_scales, np.float64) + 10.0) * 16.0)
    q = np.asarray(cloud.rotations, np.float64)
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    rot = u8((q[:, 1:] * 127.5) + 127.5)
    sh = u8(np.asarray(cloud.sh[:, 1:, :], np.float64).reshape(n, -1) * 128 + 128)
    body = b"".join(a.tobytes() for a in (pos, alpha, color, scale, rot, sh))
    return len(gzip.compress(b"\0" * 16 + body, 9))


def input_sizes(src: Path, cloud) -> dict:
    """{ply, splat, spz} bytes of the input's Gaussians (the PLY: the file, or written)."""
    if src.suffix.lower() == ".ply":
        ply = src.stat().st_size
    else:
        from leaffit_usd.splats.ply import write_ply

        with tempfile.TemporaryDirectory() as d:
            write_ply(cloud, Path(d) / "c.ply")
            ply = (Path(d) / "c.ply").stat().st_size
    return {"ply": ply, "splat": SPLAT_BYTES_PER_GAUSSIAN * len(cloud), "spz": spz_bytes(cloud)}


def plants(sets: list[str], names: list[str] | None, labels_gt: bool):
    """(name, input path, labels path or None, up or None) of the plants asked for."""
    out = []
    if "samples" in sets:
        d = ROOT / "samples" / "plants"
        for ply in sorted(d.glob("*.ply")):
            gt = d / f"{ply.stem}.gt.npz"
            out.append((ply.stem, ply, gt if labels_gt and gt.is_file() else None, None))
    if "paper8" in sets:
        if PAPER8.is_dir():
            for p in sorted(PAPER8.glob("*/point_cloud.ply")):
                gt = p.parent / "gt.npz"
                out.append((p.parent.name, p, gt if labels_gt else None, None))
        else:
            print(f"paper8: skipped ({PAPER8} is absent)")
    if "real" in sets:
        if HOUSEPLANT.is_file():
            out.append(("houseplant", HOUSEPLANT, None, (0.0, -1.0, 0.0)))
        else:
            print(f"houseplant: skipped ({HOUSEPLANT} is absent)")
    return [p for p in out if names is None or p[0] in names]


def measure(name: str, src: Path, labels, up, out_dir: Path) -> dict:
    """Convert one plant to .usdz, export its .glb; the sizes and the .usdz's parts."""
    from leaffit_usd.commands.export import export
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.usd.validate import validate_file

    usdz = out_dir / name / f"{name}.usdz"
    opts = ConvertOptions(labels=str(labels) if labels else None,
                          up=None if up is None else np.asarray(up, float))
    t0 = time.perf_counter()
    rep = convert(src, usdz, opts)
    dt = time.perf_counter() - t0
    glb = out_dir / name / f"{name}.glb"
    export(usdz, glb, texture_format="png")
    files = rep["sizes"]["files"]
    parts = {"stage": files.get("packed_stage", 0), "geometry": files.get("packed_geometry", 0),
             "textures": sum(v for k, v in files.items() if k.startswith("packed_texture") and
                             not k.endswith("_mask")),
             "masks": sum(v for k, v in files.items() if k.endswith("_mask"))}
    inp = input_sizes(src, load_cloud(src))
    size = usdz.stat().st_size
    return {"plant": name, "leaves": rep["counts"]["leaves"], "gaussians": rep["counts"]["gaussians"],
            "input": inp, "usdz_bytes": size, "glb_bytes": glb.stat().st_size, "usdz_parts": parts,
            "ratio_ply": round(inp["ply"] / size, 1), "ratio_spz": round(inp["spz"] / size, 2),
            "ratio_splat": round(inp["splat"] / size, 2),
            "validation_errors": validate_file(usdz).count("error"),
            "labels": "ground truth" if labels else "automatic", "convert_seconds": round(dt, 1)}


def _render_rows(path: Path) -> dict:
    """{plant: (IoU min, PSNR, SSIM)} from a benchmarks/render.py results JSON ({} if absent)."""
    if not path.is_file():
        return {}
    rows = {}
    for r in json.loads(path.read_text()).get("plants", []):
        name = r.get("plant") or r.get("name")
        iou = r.get("iou_min", r.get("silhouette_iou_min"))
        rows[name] = (iou, r.get("psnr"), r.get("ssim"))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plants", default=None, help="comma-separated plant names (default: all)")
    ap.add_argument("--sets", default="samples,paper8,real", help="samples, paper8, real")
    ap.add_argument("--labels-gt", action="store_true", help="ground-truth labels where there are some")
    ap.add_argument("--out", default="/tmp/leaffit_size", help="where the converted assets go")
    ap.add_argument("--render", default=str(ROOT / "benchmarks" / "results" / "render.json"))
    ap.add_argument("--render-before", default=None, help="an earlier render.py results JSON")
    args = ap.parse_args(argv)
    import logging

    logging.getLogger("leaffit_usd").setLevel(logging.WARNING)
    names = args.plants.split(",") if args.plants else None
    rows = []
    print(f"{'plant':20s} {'leaves':>6s} {'PLY MB':>7s} {'SPZ MB':>7s} {'splat MB':>8s} {'usdz MB':>8s} "
          f"{'glb MB':>7s} {'xPLY':>6s} {'xSPZ':>5s} {'stage':>6s} {'geom':>6s} {'tex':>6s} {'mask':>5s} "
          f"{'err':>3s} {'s':>5s}")
    for name, src, labels, up in plants(args.sets.split(","), names, args.labels_gt):
        r = measure(name, src, labels, up, Path(args.out))
        rows.append(r)
        p, i = r["usdz_parts"], r["input"]
        share = {k: 100.0 * v / r["usdz_bytes"] for k, v in p.items()}
        print(f"{name:20s} {r['leaves']:6d} {i['ply'] / 1e6:7.2f} {i['spz'] / 1e6:7.2f} "
              f"{i['splat'] / 1e6:8.2f} {r['usdz_bytes'] / 1e6:8.3f} {r['glb_bytes'] / 1e6:7.3f} "
              f"{r['ratio_ply']:5.1f}x {r['ratio_spz']:4.1f}x {share['stage']:5.0f}% {share['geometry']:5.0f}% "
              f"{share['textures']:5.0f}% {share['masks']:4.0f}% {r['validation_errors']:3d} "
              f"{r['convert_seconds']:5.1f}", flush=True)
    if rows:
        print(f"median compression against the input PLY: {statistics.median(r['ratio_ply'] for r in rows):.1f}x "
              f"(SPZ {statistics.median(r['ratio_spz'] for r in rows):.2f}x); the paper's asset: 1.13 MB")
    after, before = _render_rows(Path(args.render)), _render_rows(Path(args.render_before or ""))
    shown = [r["plant"] for r in rows if r["plant"] in after]
    if shown:
        print(f"render fidelity ({args.render}{', before | after' if before else ''}): IoU min, PSNR, SSIM")
        for n in shown:
            b = f"{before[n]}  |  " if n in before else ""
            print(f"  {n:20s} {b}{after[n]}")
    out = ROOT / "benchmarks" / "results" / "size.json"
    atomic_write_bytes(out, (json.dumps({"paper_usdz_bytes": PAPER_USDZ_BYTES, "plants": rows},
                                        indent=2) + "\n").encode())
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
