"""Template mesh extraction on the sample plants: per-template figures for BPA and planar sheets.

For each sample plant (``samples/plants/*.ply`` with its ground truth): the working frame from
the GT root/up, the GT labels as the segmentation (so the figures measure the mesh stage, not
the segmenter), ``fit_leaves`` without optimisation (template choice, denoised template points
and frames), then ``build_template_mesh`` with ``method="bpa"`` (the paper's, repaired) and
``method="planar"``. Figures per template: sheet vertex/face counts, disk checks, holes
before/after repair, mean/max distance of the template's denoised points and raw Gaussian centres
to the sheet (relative to the leaf length), the sheet's distance to the GT blade mesh (both
ways: accuracy and completeness), boundary length, texture coverage, time. Optionally the stem
(``--stem``: runs the automatic segmentation for the tree).

Writes ``benchmarks/results/mesh.json`` and an example texture pair
``benchmarks/results/mesh_<plant>_{front,back}.png`` (1024 px, the default).

    .venv/bin/python benchmarks/mesh.py [--plants rubber_tree,...] [--size 1024] [--stem]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leaffit_usd.fit.params import FitParams  # noqa: E402
from leaffit_usd.fit.register import fit_leaves  # noqa: E402
from leaffit_usd.image_io import write_image  # noqa: E402
from leaffit_usd.mesh.params import MeshParams  # noqa: E402
from leaffit_usd.mesh.sheet_distance import point_sheet_distance  # noqa: E402
from leaffit_usd.mesh.template import build_template_mesh  # noqa: E402
from leaffit_usd.segment.result import Segmentation  # noqa: E402
from leaffit_usd.splats.frame import Frame  # noqa: E402
from leaffit_usd.splats.transform import transform_cloud  # noqa: E402
from leaffit_usd.splats.ply import read_ply  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def load_gt(path):
    """The ground-truth fields this benchmark uses (read directly: robust to added fields)."""
    from types import SimpleNamespace

    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in ("labels", "root", "up", "leaf_vertices", "leaf_faces",
                               "leaf_vertex_ids", "leaf_base", "leaf_apex", "canonical_to_input")}
        d["height"] = float(z["height"])
        d["spec"] = str(z["spec"])
    return SimpleNamespace(**d)


def load_plant(name: str):
    cloud = read_ply(ROOT / "samples" / "plants" / f"{name}.ply")
    gt = load_gt(ROOT / "samples" / "plants" / f"{name}.gt.npz")
    frame = Frame.from_root_up(cloud.means, gt.root, gt.up)
    cw = transform_cloud(cloud, frame.input_to_working)
    labels = np.asarray(gt.labels)[cloud.file_index].astype(np.int32)
    labels[labels < 0] = 0
    # petiole base and apex from the GT (nearest Gaussian of the leaf), as a segmentation gives them
    L = int(labels.max())
    base, tip = np.zeros(L, np.int64), np.zeros(L, np.int64)
    for l in range(1, L + 1):
        idx = np.flatnonzero(labels == l)
        base[l - 1] = idx[np.argmin(np.linalg.norm(cw.means[idx] - frame.to_working(gt.leaf_base[l - 1][None]), axis=1))]
        tip[l - 1] = idx[np.argmin(np.linalg.norm(cw.means[idx] - frame.to_working(gt.leaf_apex[l - 1][None]), axis=1))]
    seg = Segmentation(labels=labels, root_index=int(np.argmin(np.linalg.norm(cw.means, axis=1))),
                       leaf_base=base, leaf_tip=tip)
    return cw, seg, gt, frame


def gt_template_mesh(gt, frame, fits):
    """GT blade mesh of the template leaf, template local frame."""
    lab = fits.template_label
    vid = np.flatnonzero(gt.leaf_vertex_ids == lab)
    remap = np.full(len(gt.leaf_vertices), -1, np.int64)
    remap[vid] = np.arange(len(vid))
    faces = remap[gt.leaf_faces]
    faces = faces[(faces >= 0).all(1)]
    v = frame.to_working(gt.leaf_vertices[vid])
    row = int(np.flatnonzero(fits.leaf_labels == lab)[0])
    T = np.linalg.inv(fits.leaf_to_working[row])
    return v @ T[:3, :3].T + T[:3, 3], faces


def run_plant(name: str, size: int, methods, write_example: bool):
    cw, seg, gt, frame = load_plant(name)
    t0 = time.perf_counter()
    fits = fit_leaves(cw, seg, FitParams(optimize=False))
    t_fit = time.perf_counter() - t0
    gv, gf = gt_template_mesh(gt, frame, fits)
    rows = []
    for method in methods:
        t0 = time.perf_counter()
        m = build_template_mesh(cw, fits, MeshParams(method=method, texture_size=size))
        dt = time.perf_counter() - t0
        r = m.report
        L = r["leaf_length"]
        P, F = m.sheet_points.astype(np.float64), m.sheet_faces.astype(np.int64)
        acc = point_sheet_distance(P, gv, gf) / L          # sheet -> GT (no inflation, no folds)
        comp = point_sheet_distance(gv, P, F) / L          # GT -> sheet (completeness)
        row = dict(plant=name, template=int(fits.template_label), method=r["method"],
                   requested=method, template_points=int(len(fits.template_points)),
                   sheet_vertices=r["sheet_vertices"], sheet_faces=r["sheet_faces"],
                   vertices=r["vertices"], faces=r["faces"], is_disk=r["is_disk"],
                   components=r["components"], boundary_loops=r["boundary_loops"],
                   fold_ratio=r["fold_ratio"], holes_before=r["holes_before"],
                   holes_after=r["holes_after"], unused_samples=r["unused_samples"],
                   pts_mean=r["points_dist_mean_rel"], pts_max=r["points_dist_max_rel"],
                   gs_mean=r.get("gauss_dist_mean_rel"), gs_p95=r.get("gauss_dist_p95_rel"),
                   gs_max=r.get("gauss_dist_max_rel"),
                   gt_acc_mean=float(acc.mean()), gt_acc_max=float(acc.max()),
                   gt_comp_mean=float(comp.mean()), gt_comp_p99=float(np.percentile(comp, 99)),
                   boundary_rel=r["boundary_length_rel"], min_angle_p5=r["min_angle_deg_p5"],
                   uv_stretch_max=r["uv_stretch_max"],
                   cov_front=r["coverage_front"], cov_back=r["coverage_back"],
                   texture_coverage=r["alpha_coverage_front"], uv_chart=r.get("uv_chart"),
                   texture_fallback=r["texture_fallback"], leaf_length=L,
                   fallback_reasons=r.get("fallback_reasons", []),
                   t_surface=r["timings"]["surface"], t_bake=r["timings"]["bake"], t_total=dt,
                   t_fit_no_optim=t_fit)
        rows.append(row)
        if write_example and method == methods[0]:
            RESULTS.mkdir(parents=True, exist_ok=True)
            write_image(RESULTS / f"mesh_{name}_front.png", m.front_texture)
            write_image(RESULTS / f"mesh_{name}_back.png", m.back_texture)
    return rows


def run_stem(name: str):
    from leaffit_usd.mesh.stem import StemParams, build_stem
    from leaffit_usd.segment.auto import SegmentParams, segment_plant

    cw, seg_gt, gt, frame = load_plant(name)
    t0 = time.perf_counter()
    seg = segment_plant(cw.means, seg_gt.root_index, SegmentParams())
    t_seg = time.perf_counter() - t0
    t0 = time.perf_counter()
    st = build_stem(seg, cw.means, None, StemParams())
    dt = time.perf_counter() - t0
    # Leonardo check at every junction
    worst = 0.0
    for e in range(len(st.starts)):
        kids = np.flatnonzero(st.parent == e)
        if len(kids):
            a, b = st.radii_end[e] ** 2, (st.radii_start[kids] ** 2).sum()
            worst = max(worst, abs(a - b) / max(a, 1e-30))
    spec = json.loads(gt.spec)
    pet_true = [lf["petiole_radius_m"] for lf in spec.get("leaves", []) if "petiole_radius_m" in lf]
    return dict(plant=name, cylinders=int(len(st.starts)), stem_vertices=int(len(st.points)),
                stem_faces=int(len(st.faces)),
                root_radius=float(st.radii_start[st.parent == -1].max()) if len(st.starts) else None,
                petiole_radius=float(st.radii_end.min()) if len(st.starts) else None,
                gt_petiole_radius_median=(float(np.median(pet_true)) / spec["canonical_height_m"]
                                          if pet_true else None),
                leonardo_max_rel_error=float(worst), t_segment=t_seg, t_stem=dt)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default=None, help="comma-separated names (default: all committed)")
    ap.add_argument("--size", type=int, default=1024, help="texture size (default 1024)")
    ap.add_argument("--methods", default="bpa,planar")
    ap.add_argument("--example", default="rubber_tree", help="plant whose textures are saved")
    ap.add_argument("--stem", action="store_true", help="also run segmentation + stem per plant")
    args = ap.parse_args(argv)
    names = args.plants.split(",") if args.plants else sorted(
        p.name[:-4] for p in (ROOT / "samples" / "plants").glob("*.ply"))
    methods = args.methods.split(",")
    rows, stems = [], []
    for name in names:
        rows += run_plant(name, args.size, methods, name == args.example)
        if args.stem:
            stems.append(run_stem(name))
    hdr = ("plant", "method", "V_sheet", "F_sheet", "disk", "holes b/a", "pts mean/max",
           "gs mean/p95", "GT acc mean/max", "GT comp mean/p99", "cov f/b", "tex cov", "time s")
    print(" | ".join(hdr))
    for r in rows:
        print(f"{r['plant']}:{r['template']} | {r['method']}{'' if r['method'].split('+')[0] == r['requested'] else '*'} | "
              f"{r['sheet_vertices']} | {r['sheet_faces']} | {r['is_disk']} | "
              f"{r['holes_before']}/{r['holes_after']} | {r['pts_mean']:.4f}/{r['pts_max']:.4f} | "
              f"{r['gs_mean']:.4f}/{r['gs_p95']:.4f} | {r['gt_acc_mean']:.4f}/{r['gt_acc_max']:.4f} | "
              f"{r['gt_comp_mean']:.4f}/{r['gt_comp_p99']:.4f} | "
              f"{r['cov_front']:.3f}/{r['cov_back']:.3f} | {r['texture_coverage']:.3f} | {r['t_total']:.1f}")
    print("(distances relative to the template leaf's length; * = fell back from the requested method; "
          "cov = splat coverage of the sheet; tex cov = texels of the front texture with leaf, alpha > 0.5)")
    for s in stems:
        print(s)
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "mesh.json"
    from benchmarks.machine import machine_info

    out.write_text(json.dumps(dict(texture_size=args.size, templates=rows, stems=stems,
                                   machine=machine_info()), indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
