"""Diagnostic: how the MLS field behaves per leaf after the refinement, beside the leaf's error.

Converts each plant with its ground-truth labels, up axis and root (as ``benchmarks/render.py``)
and ``-K`` control points, observing the registration's refinement (it wraps
``fit.gauss_newton.refine_targets``; nothing is changed). Per fitted leaf, in the refinement's template
units and leaf frame:

* ``out>10``: how many of the outline term's template points (the template's silhouette
  outline at the height of its nearest Gaussian, as the term evaluates them) the final field
  puts more than 10 leaf spacings (median nearest-neighbour distance of the leaf's Gaussians in
  its plane) from the leaf's own silhouette outline, of how many; ``out max``: the farthest,
  in spacings;
* ``dz med / max``: the length of the field's derivative along the template frame's z (across
  the sheet; 1 = a rigid map) at those outline points, by a finite difference of 0.0005;
  ``at``: where the largest is, along the template from its base (0) to its apex (1);
* ``handles off``: the share of the K handle targets farther than 10 % of the leaf's length
  from every one of its Gaussians; ``far``: the farthest, in leaf lengths;
* with ``../shared/plants``: the leaf's HD and outline error OE (``eval_deform``, x10 of plant
  height) of the converted asset against the ground truth.

    .venv/bin/python benchmarks/fit_diag.py PLANT_DIR [PLANT_DIR ...] [-K 64] [--work DIR]

A PLANT_DIR holds ``point_cloud.ply`` and ``gt.npz`` (``render.py --work``'s suite/NAME, or an
external plant's folder, e.g. ``~/.cache/leaffit-plants/sets/paper8-1/p4_apple``).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from scipy.spatial import cKDTree  # noqa: E402

import leaffit_usd.fit.register as register  # noqa: E402
from leaffit_usd.fit.mls import deform_points  # noqa: E402
from leaffit_usd.fit.params import FitParams  # noqa: E402
from render import SHARED, asset_scene  # noqa: E402

DZ_STEP = 0.0005


def field_rows(seen: dict) -> dict:
    """Per leaf label: the field's figures from one observed refinement (see the module doc)."""
    T, p, sigma, reg = seen["T"], seen["p"], seen["sigma"], seen["reg"]
    outlines = seen["outlines"]
    rows = {}
    if outlines is None:
        return rows
    BT = np.asarray(outlines[0], np.float64)
    P0 = np.column_stack([BT, T.local[cKDTree(T.local[:, :2]).query(BT)[1], 2]])
    along = (P0[:, 0] - T.local[:, 0].min()) / max(float(np.ptp(T.local[:, 0])), 1e-12)
    for b, lf in enumerate(seen["leaves"]):
        Yo = np.asarray(outlines[b + 1], np.float64)
        if len(Yo) < 3:
            continue
        Y = lf.local / lf.scale
        spacing = float(np.median(cKDTree(Y[:, :2]).query(Y[:, :2], k=2)[0][:, 1]))
        q = seen["q"][b]
        f0 = deform_points(p, q, P0, sigma, reg)
        dz = np.linalg.norm(deform_points(p, q, P0 + [0.0, 0.0, DZ_STEP], sigma, reg) - f0, axis=1) / DZ_STEP
        off = cKDTree(Yo).query(f0[:, :2])[0] / spacing
        length = float(np.ptp(Y[:, 0]))
        hd = cKDTree(Y).query(q)[0] / length
        rows[int(lf.label)] = dict(out=int((off > 10).sum()), n_out=len(off), out_max=float(off.max()),
                                   dz_med=float(np.median(dz)), dz_max=float(dz.max()),
                                   dz_at=float(along[np.argmax(dz)]),
                                   handles_off=float((hd > 0.1).mean()), handle_far=float(hd.max()))
    return rows


def run_plant(d: Path, K: int, work: Path) -> None:
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.usd.reader import read_stage

    seen = {}
    refine = register.refine_targets

    def observed(T, leaves, p, q0, params, outlines=None):
        q = refine(T, leaves, p, q0, params, outlines)
        seen.update(T=T, leaves=leaves, p=p, q=q, outlines=outlines, sigma=params.sigma, reg=params.reg)
        return q

    with np.load(d / "gt.npz") as z:
        up, root = np.asarray(z["up"], float), np.asarray(z["root"], float)
    out = work / d.name / "plant.usda"
    register.refine_targets = observed
    try:
        convert(d / "point_cloud.ply", out, ConvertOptions(up=up, root=root, labels=str(d / "gt.npz"),
                                                           fit=FitParams(K=K)))
    finally:
        register.refine_targets = refine
    rows = field_rows(seen) if seen else {}
    errors = {}
    if (SHARED / "eval_deform.py").is_file():
        sys.path.insert(0, str(SHARED))
        from eval_deform import evaluate_files

        b = asset_scene(out, read_stage(out))["baked"]
        npz = work / d.name / "leaves.npz"
        np.savez(npz, vertices=b.vertices, faces=b.faces, leaf_vertex_ids=b.leaf_vertex_ids)
        errors = {lf["gt_id"]: lf for lf in evaluate_files(d / "gt.npz", npz)["leaves"]}
    print(f"\n{d.name}, K = {K}" + ("" if rows else ": the fit used no outline term (template not face-on)"))
    print(f"{'leaf':>4} {'out>10':>9} {'out max':>8} {'dz med':>7} {'dz max':>7} {'at':>5} {'handles off':>11} "
          f"{'far':>5} {'HD':>7} {'OE':>7}")
    for lab in sorted(set(rows) | set(errors)):
        r, e = rows.get(lab), errors.get(lab)
        field = (f"{r['out']:>4}/{r['n_out']:<4} {r['out_max']:8.1f} {r['dz_med']:7.1f} {r['dz_max']:7.1f} "
                 f"{r['dz_at']:5.2f} {r['handles_off']:11.2f} {r['handle_far']:5.2f}") if r else \
            f"{'(template or no outline)':>58}"
        err = f" {e['hausdorff']:7.4f} {e['outline']:7.4f}" if e else ""
        print(f"{lab:>4} {field}{err}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plants", nargs="+", help="folders with point_cloud.ply and gt.npz")
    ap.add_argument("-K", type=int, default=FitParams().K, help="control points per leaf (default %(default)s)")
    ap.add_argument("--work", default=None, help="folder for the converted stages (default: a temp dir)")
    args = ap.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="leaffit_fitdiag_"))
    if not (SHARED / "eval_deform.py").is_file():
        print(f"HD and OE skipped: {SHARED / 'eval_deform.py'} is absent")
    for d in args.plants:
        d = Path(d).expanduser()
        if not (d / "gt.npz").is_file() or not (d / "point_cloud.ply").is_file():
            ap.error(f"{d}: needs point_cloud.ply and gt.npz")
        run_plant(d, args.K, work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
