"""Render fidelity: the input 3DGS against the converted asset, from 8 views around each plant.

For every plant (the committed sample plants, regenerated with their exact tube surfaces, and
the external ``paper8`` plants of ``../shared/plants`` when that folder exists), with the
ground-truth labels, up axis and root (so the asset is judged alone, not the segmentation):

1. ``convert`` (the whole pipeline, default parameters) writes the USD asset;
2. the input Gaussians are rendered with the project's splat renderer
   (:func:`leaffit_usd.splats.render.render_orthographic_np`), and the asset -- the evaluated
   leaves textured with the written PNG textures, their alpha cut-out and the per-leaf tint the
   material multiplies in (linear RGB), and the stem with its
   vertex colours -- with the project's triangle rasteriser (:mod:`leaffit_usd.edit.raster`),
   orthographic, 8 azimuths 45 degrees apart at 20 degrees elevation, same bounds, unlit (DC
   colours against texture colours);
3. per plant: silhouette IoU (input alpha > 0.5 vs asset coverage; min and mean over views;
   the input without its floaters and scene Gaussians, which conversion removes on purpose),
   PSNR and SSIM (Gaussian window, sigma 1.5) inside the union of both silhouettes; and the
   surface errors against ground truth with ``../shared/plants/eval_deform.py`` (leaves: Corr-l2,
   HD, outline error OE; stem: ``evaluate_stem``'s mean pred->GT distance and HD), x10 of
   plant-height-normalised distances, plus the template texture's alpha coverage.

Writes ``benchmarks/results/render.json`` (or ``--out``) and, with ``--pictures DIR``, input |
asset side-by-side PNGs. Without ``../shared/plants`` it runs on the sample plants only and
prints why (the surface errors need ``eval_deform.py``; the render metrics do not).

    .venv/bin/python benchmarks/render.py [--sets suite,paper8] [--plants a,b] [--size 384]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "plants"
RESULTS = ROOT / "benchmarks" / "results"
N_VIEWS, ELEVATION = 8, 20.0


# ---- plants ------------------------------------------------------------------------------------
def suite_plants(out: Path) -> list[Path]:
    """The committed sample plants, regenerated (identical PLYs) with their GT in the external
    format (``point_cloud.ply`` + ``gt.npz`` with ``plant_height`` and ``stem_samples``)."""
    from leaffit_usd.splats.ply import write_ply
    from samples.generate import committed_plants, make_plant

    dirs = []
    for name, (spec, seed) in committed_plants().items():
        d = out / name
        if not (d / "gt.npz").is_file():
            d.mkdir(parents=True, exist_ok=True)
            cloud, gt = make_plant(spec, seed)
            write_ply(cloud, d / "point_cloud.ply")
            np.savez(d / "gt.npz", labels=gt.labels, root=gt.root, up=gt.up, plant_height=gt.height,
                     leaf_vertices=gt.leaf_vertices, leaf_faces=gt.leaf_faces,
                     leaf_vertex_ids=gt.leaf_vertex_ids, stem_samples=gt.stem_samples)
        dirs.append(d)
    return dirs


def paper8_plants(out: Path, seed: int = 1) -> list[Path]:
    """The external generator's paper8 plants (generated once into ``out``)."""
    d = out / f"paper8-{seed}"
    if not (d / "index.json").is_file():
        subprocess.run([sys.executable, str(SHARED / "make_plants.py"), "--out", str(d), "--seed",
                        str(seed), "--preset", "paper8"], check=True, stdout=subprocess.DEVNULL)
    names = [p["name"] for p in json.loads((d / "index.json").read_text())["plants"]]
    return [d / n for n in names]


# ---- rendering ---------------------------------------------------------------------------------
def view_basis(up: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """(3, 3) rows: right, screen-up, towards-the-camera, for a camera at that azimuth/elevation
    around ``up`` (input frame)."""
    e3 = up / np.linalg.norm(up)
    a = np.array([1.0, 0, 0]) if abs(e3[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = a - (a @ e3) * e3
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e3, e1)
    th, ph = np.radians(azimuth_deg), np.radians(elevation_deg)
    c = np.cos(ph) * (np.cos(th) * e1 + np.sin(th) * e2) + np.sin(ph) * e3
    r = np.cross(-c, e3)
    r /= np.linalg.norm(r)
    u = np.cross(r, -c)
    return np.stack([r, u, c])


def render_input(cloud, R, centre, size, bounds):
    from leaffit_usd.splats.render import render_orthographic_np

    m = (np.asarray(cloud.means, np.float64) - centre) @ R.T
    cov = np.einsum("ij,njk,lk->nil", R, cloud.covariances().astype(np.float64), R)
    r = render_orthographic_np(m, cov, np.asarray(cloud.colors, np.float64),
                               np.asarray(cloud.opacities, np.float64), size, size, bounds)
    return np.asarray(r.color, np.float64), np.asarray(r.alpha, np.float64) > 0.5


def render_asset(scene, R, centre, size, bounds):
    """The asset seen through R: (H, W, 3) colours (sRGB, premultiplied on black), (H, W) mask."""
    from leaffit_usd.edit.raster import rasterize

    pts = (scene["points"] - centre) @ R.T
    ras = rasterize(pts, scene["faces"], size, size, bounds)
    img = np.zeros((size, size, 3))
    mask = ras.mask.copy()
    f = ras.face[ras.mask]
    bary = ras.bary[ras.mask]
    tri = scene["faces"][f]
    is_leaf = scene["face_kind"][f] < 2
    out = np.zeros((len(f), 3))
    keep = np.ones(len(f), bool)
    if is_leaf.any():
        uv = np.einsum("pk,pkc->pc", bary[is_leaf], scene["uvs"][tri[is_leaf]])
        side = scene["face_kind"][f[is_leaf]]
        col = np.zeros((len(uv), 3))
        alpha = np.zeros(len(uv))
        for s, tex in enumerate(scene["textures"]):
            sel = side == s
            H, W = tex.shape[:2]
            cc = np.clip((uv[sel, 0] * W).astype(int), 0, W - 1)
            rr = np.clip(((1 - uv[sel, 1]) * H).astype(int), 0, H - 1)
            col[sel] = tex[rr, cc, :3]
            alpha[sel] = tex[rr, cc, 3]
        if scene.get("tints") is not None:   # the material's per-leaf gain, in linear RGB
            g = scene["tints"][scene["face_leaf"][f[is_leaf]]]
            lin = np.where(col <= 0.04045, col / 12.92, ((col + 0.055) / 1.055) ** 2.4) * g
            lin = np.clip(lin, 0.0, 1.0)
            col = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
        out[is_leaf] = col
        keep[np.flatnonzero(is_leaf)[alpha < 0.5]] = False   # the alpha cut-out
    st = ~is_leaf
    if st.any():
        out[st] = np.einsum("pk,pkc->pc", bary[st], scene["colors"][tri[st]])
    rows, cols = np.nonzero(ras.mask)
    img[rows[keep], cols[keep]] = out[keep]
    mask[rows[~keep], cols[~keep]] = False
    return img, mask


def ssim_map(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """(H, W) SSIM of two (H, W, 3) images in [0, 1] (channel mean), Gaussian window."""
    from scipy.ndimage import gaussian_filter

    c1, c2 = 0.01 ** 2, 0.03 ** 2
    out = np.zeros(a.shape[:2])
    for k in range(a.shape[2]):
        x, y = a[..., k], b[..., k]
        mx, my = gaussian_filter(x, sigma), gaussian_filter(y, sigma)
        vx = gaussian_filter(x * x, sigma) - mx * mx
        vy = gaussian_filter(y * y, sigma) - my * my
        cxy = gaussian_filter(x * y, sigma) - mx * my
        out += ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return out / a.shape[2]


def asset_scene(stage_path: Path, asset) -> dict:
    """Triangles of the evaluated asset in the input frame with what the rasteriser shades."""
    from pxr import Usd, UsdGeom

    from leaffit_usd.image_io import read_image
    from leaffit_usd.runtime.evaluator import evaluate

    baked = evaluate(asset, frame="input")
    L = asset.n_leaves
    V = len(asset.template_points)
    side_v = np.tile(np.asarray(asset.template_side, np.int64), L)
    lf = np.asarray(baked.faces, np.int64)
    face_side = (side_v[lf].sum(1) >= 2).astype(np.int64)
    sv = np.asarray(baked.stem_vertices, np.float64)
    sf = np.asarray(baked.stem_faces, np.int64) + len(baked.vertices)
    stage = Usd.Stage.Open(str(stage_path))
    root = stage.GetDefaultPrim()
    colors = np.full((len(sv), 3), 0.4)
    stem_prim = stage.GetPrimAtPath(f"{root.GetPath()}/Stem")
    if stem_prim and len(sv):
        pv = UsdGeom.PrimvarsAPI(stem_prim).GetPrimvar("displayColor")
        if pv and pv.HasValue():
            lin = np.clip(np.asarray(pv.Get(), np.float64), 0, 1)
            if lin.shape == colors.shape:
                colors = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    tex = [np.asarray(read_image(stage_path.parent / p.lstrip("./")), np.float64)
           for p in (asset.front_texture, asset.back_texture)]
    n_leaf_v = len(baked.vertices)
    return dict(points=np.vstack([np.asarray(baked.vertices, np.float64), sv]),
                faces=np.vstack([lf, sf]),
                face_kind=np.r_[face_side, np.full(len(sf), 2)],
                uvs=np.vstack([np.tile(np.asarray(asset.template_uvs, np.float64), (L, 1)),
                               np.zeros((len(sv), 2))]),
                colors=np.vstack([np.zeros((n_leaf_v, 3)), colors]),
                textures=tex, baked=baked, V=V,
                face_leaf=np.r_[lf[:, 0] // V, np.zeros(len(sf), np.int64)],
                tints=None if asset.tints is None else np.asarray(asset.tints, np.float64))


# ---- one plant -----------------------------------------------------------------------------------
def run_plant(d: Path, work: Path, size: int, pictures: Path | None, tag: str,
              reuse: bool = False) -> dict:
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.usd.reader import read_stage

    name = d.name
    gtp = d / "gt.npz"
    with np.load(gtp) as z:
        up, root_pt, H = np.asarray(z["up"], float), np.asarray(z["root"], float), float(z["plant_height"])
    out = work / name / "plant.usda"
    saved = work / name / "convert_report.json"
    t0 = time.perf_counter()
    if reuse and out.is_file() and saved.is_file():   # --reuse: the stage of an earlier run
        report = json.loads(saved.read_text())
    else:
        report = convert(d / "point_cloud.ply", out,
                         ConvertOptions(up=up, root=root_pt, labels=str(gtp)))
        saved.write_text(json.dumps(report, default=str))
    t_convert = time.perf_counter() - t0
    asset = read_stage(out)
    scene = asset_scene(out, asset)
    cloud = load_cloud(d / "point_cloud.ply")
    row = dict(set=tag, plant=name, leaves=int(asset.n_leaves), convert_s=round(t_convert, 1),
               stem_vertices=int(len(asset.stem_points)),
               texture_coverage=float(report["mesh_report"].get("alpha_coverage_front", float("nan"))))
    # surface errors (external evaluator)
    if (SHARED / "eval_deform.py").is_file():
        sys.path.insert(0, str(SHARED))
        from eval_deform import evaluate_files, evaluate_stem

        b = scene["baked"]
        leaves_npz, stem_npz = work / name / "leaves.npz", work / name / "stem.npz"
        np.savez(leaves_npz, vertices=b.vertices, faces=b.faces, leaf_vertex_ids=b.leaf_vertex_ids)
        np.savez(stem_npz, vertices=b.stem_vertices, faces=b.stem_faces)
        lr = evaluate_files(gtp, leaves_npz)
        row.update(leaf_corr=lr["corr_l2"], leaf_hd=lr["hausdorff"], leaf_oe=lr["outline"],
                   leaves_matched=f"{lr['n_matched']}/{lr['n_gt']}")
        sr = evaluate_stem(gtp, stem_npz)
        if sr is not None:
            row.update(stem_corr=sr["stem_corr"], stem_comp=sr["stem_comp"], stem_hd=sr["stem_hd"])
    # renders
    pts = np.asarray(cloud.means, np.float64)
    with np.load(gtp) as z:
        lab = np.asarray(z["labels"])[np.asarray(cloud.file_index)]
    plant_pts = pts[lab >= 0]
    # the input as the asset should show it: the plant's Gaussians (floaters, label -1, and
    # scene clutter, -2, are what conversion removes on purpose)
    plant_cloud = cloud.subset(np.flatnonzero(lab >= 0))
    centre = 0.5 * (plant_pts.min(0) + plant_pts.max(0))
    ious, psnrs, ssims = [], [], []
    for v in range(N_VIEWS):
        R = view_basis(up, 360.0 * v / N_VIEWS, ELEVATION)
        from leaffit_usd.splats.render import fit_bounds

        q = (plant_pts - centre) @ R.T
        bounds = fit_bounds(q, size, size, 0.05)
        img_in, m_in = render_input(plant_cloud, R, centre, size, bounds)
        img_as, m_as = render_asset(scene, R, centre, size, bounds)
        union = m_in | m_as
        ious.append(float((m_in & m_as).sum() / max(union.sum(), 1)))
        mse = float(((img_in - img_as) ** 2)[union].mean())
        psnrs.append(10 * np.log10(1.0 / max(mse, 1e-12)))
        ssims.append(float(ssim_map(img_in, img_as)[union].mean()))
        if pictures is not None and v in (0, 2):
            from leaffit_usd.image_io import write_image

            pictures.mkdir(parents=True, exist_ok=True)
            pair = np.concatenate([img_in, np.ones((size, 4, 3)), img_as], 1)
            rgba = np.concatenate([pair, np.ones(pair.shape[:2] + (1,))], 2)
            write_image(pictures / f"render_{name}_view{v}.png",
                        np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8))
    row.update(iou_min=min(ious), iou_mean=float(np.mean(ious)), psnr=float(np.mean(psnrs)),
               ssim=float(np.mean(ssims)), iou_views=[round(x, 4) for x in ious])
    return row


def fmt(rows: list[dict]) -> str:
    cols = [("set", "{}", 7), ("plant", "{}", 17), ("IoU min", "{:.3f}", 8), ("IoU mean", "{:.3f}", 9),
            ("PSNR", "{:.2f}", 7), ("SSIM", "{:.3f}", 6), ("leaf Corr", "{:.4f}", 10), ("leaf HD", "{:.4f}", 8),
            ("leaf OE", "{:.4f}", 8), ("stem Corr", "{:.4f}", 10), ("stem HD", "{:.4f}", 8),
            ("tex cov", "{:.2f}", 8)]
    keys = ["set", "plant", "iou_min", "iou_mean", "psnr", "ssim", "leaf_corr", "leaf_hd", "leaf_oe",
            "stem_corr", "stem_hd", "texture_coverage"]
    lines = ["".join(f"{h:>{w}s}" for h, _, w in cols)]
    for r in rows:
        cells = []
        for (h, f, w), k in zip(cols, keys):
            v = r.get(k)
            cells.append(f"{(f.format(v) if v is not None else '-'):>{w}s}")
        lines.append("".join(cells))
    for tag in sorted({r["set"] for r in rows}):
        rs = [r for r in rows if r["set"] == tag]
        cells = [f"{tag:>7s}", f"{'mean':>17s}"]
        for (h, f, w), k in list(zip(cols, keys))[2:]:
            vals = [r[k] for r in rs if r.get(k) is not None]
            cells.append(f"{(f.format(min(vals) if k == 'iou_min' else float(np.mean(vals))) if vals else '-'):>{w}s}")
        lines.append("".join(cells))
    lines.append("(IoU min: worst of 8 views; PSNR/SSIM inside the union of both silhouettes; surface "
                 "errors x10 of plant height; stem Corr = mean distance asset stem -> true tube surface)")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="suite,paper8", help="suite and/or paper8 (default: both)")
    ap.add_argument("--plants", default=None, help="comma-separated plant names (default: all)")
    ap.add_argument("--size", type=int, default=384, help="render size in pixels (384)")
    ap.add_argument("--work", default=None, help="folder for plants and outputs (default: a temp dir)")
    ap.add_argument("--pictures", default=None, help="write input | asset PNGs here")
    ap.add_argument("--reuse", action="store_true",
                    help="render the stages an earlier run left in --work instead of converting again")
    ap.add_argument("--out", default=str(RESULTS / "render.json"))
    args = ap.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="leaffit_render_"))
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    plants = []
    if "suite" in sets:
        plants += [("suite", d) for d in suite_plants(work / "suite")]
    if "paper8" in sets:
        import importlib.util

        if not (SHARED / "make_plants.py").is_file():
            print(f"skipping paper8: {SHARED} is absent (the external plants are not part of the repo)")
        elif importlib.util.find_spec("PIL") is None:
            print("skipping paper8: the external generator needs Pillow (pip install pillow)")
        else:
            plants += [("paper8", d) for d in paper8_plants(work / "external")]
    if not (SHARED / "eval_deform.py").is_file():
        print(f"surface errors skipped: {SHARED / 'eval_deform.py'} is absent")
    if args.plants:
        want = set(args.plants.split(","))
        plants = [(t, d) for t, d in plants if d.name in want]
    rows = []
    for tag, d in plants:
        row = run_plant(d, work / "out" / tag, args.size,
                        Path(args.pictures) if args.pictures else None, tag, args.reuse)
        rows.append(row)
        print(f"{tag} {d.name}: IoU min {row['iou_min']:.3f}, PSNR {row['psnr']:.2f}, SSIM {row['ssim']:.3f}, "
              f"stem Corr {row.get('stem_corr', float('nan')):.4f} HD {row.get('stem_hd', float('nan')):.4f}, "
              f"leaf Corr {row.get('leaf_corr', float('nan')):.4f} OE {row.get('leaf_oe', float('nan')):.4f}",
              flush=True)
    print(fmt(rows))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    from leaffit_usd.io_util import atomic_write_bytes

    atomic_write_bytes(args.out, (json.dumps(dict(rows=rows, size=args.size, views=N_VIEWS,
                                                  elevation=ELEVATION,
                                                  load_average=os.getloadavg()[0]), indent=1) + "\n").encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
