"""Render fidelity: the input 3DGS against the converted asset, from 8 views around each plant.

For every plant (the committed sample plants, regenerated with their exact tube surfaces, and
the external ``paper8`` plants of ``../shared/plants`` when that folder exists), with the
ground-truth labels, up axis and root (so the asset is judged alone, not the segmentation):

1. ``convert`` (the whole pipeline, default parameters) writes the USD asset (``--reuse``: the
   stage an earlier run, or another commit's code, left in ``--work``);
2. views: orthographic, 8 azimuths 45 degrees apart at 20 degrees elevation, 384 px, the bounds
   of the plant's Gaussians; the input is the plant's Gaussians (floaters and scene Gaussians,
   which conversion removes on purpose, left out) through the project's splat renderer
   (:func:`leaffit_usd.splats.render.render_orthographic_np`), DC colours;
3. per plant: silhouette IoU (alpha > 0.5; min and mean over the views), PSNR and SSIM (Gaussian
   window, sigma 1.5) inside the union of both silhouettes; the surface errors against ground
   truth with ``../shared/plants/eval_deform.py`` (leaves: Corr-l2, HD, outline error OE; stem:
   ``evaluate_stem``'s mean pred->GT distance and HD), x10 of plant-height-normalised distances;
   the template texture's leaf coverage (texels inside the front sheet's UV triangles with
   alpha > 0.5: the same figure for a JPEG texture without alpha).

How the asset is drawn for the comparison, and why. A splat render is not a surface render: a
Gaussian on the surface spreads its opacity past the surface's edge, so the input's alpha > 0.5
silhouette is wider than the true surface by about a splat's footprint all round (on the
rubber tree's 2.9 mm pixels, 1-2 px: the true leaf mesh, rasterised, scores IoU 0.84-0.91
against the input's leaf Gaussians in the 8 views). Drawing the asset
as a surface (the rasteriser, as before; still printed as ``raster min``) therefore scores the
splats' spread, not the asset: even the true surface would stay under 0.9. So the asset is
re-expressed as the input's kind of splats (:func:`asset_splats`): its surface (the leaves' front
sheet with the alpha cut-out; the stem) is sampled with the local areal density of the input
Gaussians nearest to it, each sample taking the covariance and opacity of its nearest input
Gaussian, turned so its shortest axis lies along the surface normal, and the colour of the
texture side (x tint) or stem vertex colour the camera sees. Both images then have the same
footprint and only the surfaces and their colours differ. What this allows is measured: the true
leaf surface (the generator's leaf meshes) through the same sampling scores ``GT leaf`` against
the input's leaf Gaussians (rubber_tree 0.95: the input's off-surface noise and fuzz, which a
surface does not have), beside the asset's own leaves (``leaf IoU``). The same for the whole
silhouette is ``ceil min`` (:func:`true_surface_splats`: the true leaf surface's splats and the
input's stem Gaussians moved onto the true tubes): what a perfect asset scores in its worst
view. Its limit: a part of the asset far from every input Gaussian takes the density of the
nearest ones (not zero), so a spurious part still shows.

Writes ``benchmarks/results/render.json`` (or ``--out``) and, with ``--pictures DIR``, input |
asset (rasterised) side-by-side PNGs. ``--compare BEFORE.json`` prints before | after per plant;
``--from-json`` prints tables of earlier runs without rendering. The "before" stage of an issue:
``git worktree add --detach /tmp/before COMMIT`` then ``--convert-with /tmp/before`` converts
with that commit's code (a subprocess) and renders with this benchmark. Without ``../shared/plants`` it
runs on the sample plants only and prints why (the surface errors need ``eval_deform.py``; the
render metrics do not).

    .venv/bin/python benchmarks/render.py [--sets suite,paper8] [--plants a,b] [--size 384]
        [--work DIR] [--reuse] [--pictures DIR] [--compare before.json] [-K 64]
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


def paper8_plants(seed: int = 1) -> list[Path]:
    """The external generator's paper8 plants of ``seed``, generated once into the shared cache
    by ``external_plants.ensure_set`` (with the generator's own Python, which has its Pillow)."""
    from benchmarks.external_plants import ensure_set, plants

    return plants(ensure_set("paper8", seed))


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
            alpha[sel] = tex[rr, cc, 3] if tex.shape[2] == 4 else 1.0   # a JPEG has no cut-out
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


def input_density(means: np.ndarray, k: int = 8) -> np.ndarray:
    """(N,) areal density of the Gaussians around each centre (per unit area, input units): k over
    the area of the disc reaching the k-th nearest other centre (the centres sample surfaces)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(means).query(means, k + 1)
    return k / (np.pi * np.maximum(d[:, -1], 1e-12) ** 2)


def surface_gaussians(P, F, means, cov, opac, dens, seed: int = 0):
    """A triangle surface (P (V, 3), F (G, 3)) re-expressed as the input's kind of splats.

    Samples are drawn uniformly by area with the local density ``dens`` of the input Gaussians
    nearest to each face (so the surface gets as many splats as the input has there); each takes
    the covariance and opacity of the input Gaussian nearest to it (the same footprint), turned
    so its shortest axis (the splat's normal) lies along the face's normal. Deterministic.

    Returns (means (n, 3), cov (n, 3, 3), opacities (n,), face (n,) int, bary (n, 3), normals (n, 3)
    unit face normals as the faces wind).
    """
    from scipy.spatial import cKDTree

    P, F = np.asarray(P, np.float64), np.asarray(F, np.int64)
    e1, e2 = P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]]
    cr = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    nf = cr / np.maximum(2 * area, 1e-300)[:, None]
    tree = cKDTree(means)
    _, j = tree.query(P[F].mean(1))
    w = area * dens[j]
    n = int(round(float(w.sum())))
    if n == 0:
        z = np.zeros((0, 3))
        return z, np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0, np.int64), z, z
    rng = np.random.default_rng(seed)
    fi = rng.choice(len(F), n, p=w / w.sum())
    r1, r2 = rng.uniform(size=n), rng.uniform(size=n)
    s1 = np.sqrt(r1)
    bary = np.stack([1 - s1, s1 * (1 - r2), s1 * r2], 1)
    pos = np.einsum("nk,nkd->nd", bary, P[F[fi]])
    _, j = tree.query(pos)
    C = cov[j]
    _, vec = np.linalg.eigh(C)
    n_in, n_to = vec[:, :, 0], nf[fi]
    n_to = np.where((np.einsum("nd,nd->n", n_in, n_to) < 0)[:, None], -n_to, n_to)
    v = np.cross(n_in, n_to)                      # Rodrigues: the rotation taking n_in to n_to
    c = np.einsum("nd,nd->n", n_in, n_to)
    K = np.zeros((n, 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    Q = np.eye(3)[None] + K + np.einsum("nij,njk->nik", K, K) / (1 + np.maximum(c, -0.999999))[:, None, None]
    return pos, np.einsum("nij,njk,nlk->nil", Q, C, Q), opac[j], fi, bary, nf[fi]


def true_surface_splats(leaf_splats, gtp: Path, stem_means, stem_cov, stem_opac):
    """The ground truth as splats, for the IoU ceiling: the true leaf surface's splats
    (``leaf_splats``, :func:`surface_gaussians` of the GT leaf meshes) and the input's stem
    Gaussians each moved onto the true tube surface (to the nearest of ``stem_samples``, 20,000
    points uniform by area; their spacing is far below a pixel), keeping its covariance and
    opacity: the true stem with the input's count, density and footprint. Without
    ``stem_samples`` the input's stem Gaussians stay where they are. Returns (means, cov, opac)."""
    from scipy.spatial import cKDTree

    with np.load(gtp) as z:
        S = np.asarray(z["stem_samples"], np.float64) if "stem_samples" in z.files else np.zeros((0, 3))
    if len(S) and len(stem_means):
        stem_means = S[cKDTree(S).query(stem_means)[1]]
    return (np.concatenate([leaf_splats[0], stem_means]), np.concatenate([leaf_splats[1], stem_cov]),
            np.concatenate([leaf_splats[2], stem_opac]))


def _texture_at(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    H, W = tex.shape[:2]
    cc = np.clip((uv[:, 0] * W).astype(int), 0, W - 1)
    rr = np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1)
    t = tex[rr, cc]
    return t if t.shape[1] == 4 else np.concatenate([t[:, :3], np.ones((len(t), 1))], 1)


def _tinted(col: np.ndarray, gain) -> np.ndarray:
    """sRGB colours (n, 3) x a linear-RGB gain (n, 3), back to sRGB."""
    lin = np.where(col <= 0.04045, col / 12.92, ((col + 0.055) / 1.055) ** 2.4) * gain
    lin = np.clip(lin, 0.0, 1.0)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


def asset_splats(scene: dict, means, cov, opac, dens, seed: int = 0) -> dict:
    """The asset's surface as splats of the input's footprint (:func:`surface_gaussians`): the
    leaves' front sheet (one sheet: a leaf's two textures are its two sides) with the front and
    back texture colours (x tint) at each sample and the alpha cut-out (samples where the
    texture's alpha < 0.5 dropped), the stem with its vertex colours."""
    kind = scene["face_kind"]
    sel = np.flatnonzero(kind != 1)             # front leaf faces and the stem
    F = scene["faces"][sel]
    pos, C, op, fi, bary, nrm = surface_gaussians(scene["points"], F, means, cov, opac, dens, seed)
    f = sel[fi]
    leaf = kind[f] == 0
    front = np.zeros((len(pos), 3))
    back = np.zeros((len(pos), 3))
    keep = np.ones(len(pos), bool)
    if leaf.any():
        uv = np.einsum("pk,pkc->pc", bary[leaf], scene["uvs"][scene["faces"][f[leaf]]])
        tf = _texture_at(scene["textures"][0], uv)
        tb = _texture_at(scene["textures"][1], np.stack([1.0 - uv[:, 0], uv[:, 1]], 1))
        cf, cb = tf[:, :3], tb[:, :3]
        if scene.get("tints") is not None:
            g = scene["tints"][scene["face_leaf"][f[leaf]]]
            cf, cb = _tinted(cf, g), _tinted(cb, g)
        front[leaf], back[leaf] = cf, cb
        keep[np.flatnonzero(leaf)[tf[:, 3] < 0.5]] = False
    st = ~leaf
    if st.any():
        col = np.einsum("pk,pkc->pc", bary[st], scene["colors"][scene["faces"][f[st]]])
        front[st] = back[st] = col
    return dict(means=pos[keep], cov=C[keep], opac=op[keep], front=front[keep], back=back[keep],
                normals=nrm[keep], leaf=leaf[keep])


def texture_leaf_coverage(asset, tex: np.ndarray) -> float:
    """Fraction of the front texture's texels that show leaf: inside the front sheet's UV
    triangles and, when the texture has alpha, with alpha > 0.5 (the cut-out)."""
    from leaffit_usd.edit.raster import rasterize

    H, W = tex.shape[:2]
    side = np.asarray(asset.template_side, np.int64)
    F = np.asarray(asset.template_faces, np.int64)
    F = F[(side[F] == 0).all(1)]
    uv = np.asarray(asset.template_uvs, np.float64)
    pts = np.column_stack([uv * [W, H], np.zeros(len(uv))])
    m = rasterize(pts, F, W, H, (0.0, float(W), 0.0, float(H))).mask   # row 0 = v 1, as images
    if tex.shape[2] == 4:
        m &= tex[..., 3] > 0.5
    return float(m.mean())


def render_splats(means, cov, colors, opac, R, centre, size, bounds):
    """(H, W, 3) colours (premultiplied on black) and (H, W) alpha of splats seen through R."""
    from leaffit_usd.splats.render import render_orthographic_np

    m = (np.asarray(means, np.float64) - centre) @ R.T
    c = np.einsum("ij,njk,lk->nil", R, np.asarray(cov, np.float64), R)
    r = render_orthographic_np(m, c, np.asarray(colors, np.float64), np.asarray(opac, np.float64),
                               size, size, bounds)
    return np.asarray(r.color, np.float64), np.asarray(r.alpha, np.float64)


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
CONVERT_ELSEWHERE = """
import json, sys
import numpy as np
from leaffit_usd.pipeline import ConvertOptions, convert
ply, out, gt, saved = sys.argv[1:5]
with np.load(gt) as z:
    up, root = np.asarray(z["up"], float), np.asarray(z["root"], float)
rep = convert(ply, out, ConvertOptions(up=up, root=root, labels=gt))
open(saved, "w").write(json.dumps(rep, default=str))
"""


def convert_with(code: Path, ply: Path, out: Path, gtp: Path, saved: Path) -> None:
    """``convert`` as the code in ``code`` (a worktree of another commit, e.g. the one before an
    issue's work) does it, in a subprocess with that tree first on the path; same options."""
    out.parent.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(code)}
    subprocess.run([sys.executable, "-c", CONVERT_ELSEWHERE, str(ply), str(out), str(gtp), str(saved)],
                   check=True, cwd=str(code), env=env)


def run_plant(d: Path, work: Path, size: int, pictures: Path | None, tag: str,
              reuse: bool = False, code: Path | None = None, K: int | None = None) -> dict:
    """K: control points per leaf for ``convert`` (None = the default ``FitParams().K``)."""
    from leaffit_usd.fit.params import FitParams
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
    elif code is not None:                            # --convert-with: another commit's code
        convert_with(code, d / "point_cloud.ply", out, gtp, saved)
        report = json.loads(saved.read_text())
    else:
        report = convert(d / "point_cloud.ply", out,
                         ConvertOptions(up=up, root=root_pt, labels=str(gtp),
                                        fit=FitParams() if K is None else FitParams(K=K)))
        saved.write_text(json.dumps(report, default=str))
    t_convert = time.perf_counter() - t0
    asset = read_stage(out)
    scene = asset_scene(out, asset)
    cloud = load_cloud(d / "point_cloud.ply")
    row = dict(set=tag, plant=name, leaves=int(asset.n_leaves), convert_s=round(t_convert, 1),
               stem_vertices=int(len(asset.stem_points)),
               texture_coverage=texture_leaf_coverage(asset, scene["textures"][0]))
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
    in_means = np.asarray(plant_cloud.means, np.float64)
    in_cov = plant_cloud.covariances().astype(np.float64)
    in_op = np.asarray(plant_cloud.opacities, np.float64)
    in_col = np.asarray(plant_cloud.colors, np.float64)
    dens = input_density(in_means)
    spl = asset_splats(scene, in_means, in_cov, in_op, dens)
    with np.load(gtp) as z:
        gv, gf = np.asarray(z["leaf_vertices"], np.float64), np.asarray(z["leaf_faces"], np.int64)
    gt = surface_gaussians(gv, gf, in_means, in_cov, in_op, dens, seed=1)
    in_leaf = lab[lab >= 0] > 0
    true_means, true_cov, true_op = true_surface_splats(gt, gtp, in_means[~in_leaf],
                                                        in_cov[~in_leaf], in_op[~in_leaf])
    grey = lambda n: np.full((n, 3), 0.5)  # noqa: E731 - silhouettes only
    ious, ious_raster, psnrs, ssims, leaf_as, leaf_gt, ceil = [], [], [], [], [], [], []
    iou = lambda a, b: float((a & b).sum() / max((a | b).sum(), 1))  # noqa: E731
    for v in range(N_VIEWS):
        R = view_basis(up, 360.0 * v / N_VIEWS, ELEVATION)
        from leaffit_usd.splats.render import fit_bounds

        q = (plant_pts - centre) @ R.T
        bounds = fit_bounds(q, size, size, 0.05)
        img_in, a_in = render_splats(in_means, in_cov, in_col, in_op, R, centre, size, bounds)
        m_in = a_in > 0.5
        facing = spl["normals"] @ R[2] > 0      # the side of each leaf sample the camera sees
        col = np.where(facing[:, None], spl["front"], spl["back"])
        img_as, a_as = render_splats(spl["means"], spl["cov"], col, spl["opac"], R, centre, size, bounds)
        m_as = a_as > 0.5
        union = m_in | m_as
        ious.append(iou(m_in, m_as))
        img_raster, m_raster = render_asset(scene, R, centre, size, bounds)
        ious_raster.append(iou(m_in, m_raster))
        mse = float(((img_in - img_as) ** 2)[union].mean())
        psnrs.append(10 * np.log10(1.0 / max(mse, 1e-12)))
        ssims.append(float(ssim_map(img_in, img_as)[union].mean()))
        # leaves alone: the asset's leaves and the true leaf surface, both as splats, against
        # the input's leaf Gaussians (the true surface's score is what the comparison allows)
        _, a_il = render_splats(in_means[in_leaf], in_cov[in_leaf], grey(int(in_leaf.sum())),
                                in_op[in_leaf], R, centre, size, bounds)
        _, a_al = render_splats(spl["means"][spl["leaf"]], spl["cov"][spl["leaf"]],
                                grey(int(spl["leaf"].sum())), spl["opac"][spl["leaf"]], R, centre,
                                size, bounds)
        _, a_gl = render_splats(gt[0], gt[1], grey(len(gt[0])), gt[2], R, centre, size, bounds)
        leaf_as.append(iou(a_il > 0.5, a_al > 0.5))
        leaf_gt.append(iou(a_il > 0.5, a_gl > 0.5))
        # the ceiling of the whole-silhouette IoU: what a perfect asset, drawn the same way,
        # scores in this view (the true leaf surface's splats and the true stem's)
        _, a_ceil = render_splats(true_means, true_cov, grey(len(true_means)), true_op, R, centre,
                                  size, bounds)
        ceil.append(iou(m_in, a_ceil > 0.5))
        if pictures is not None and v in (0, 2):
            from leaffit_usd.image_io import write_image

            pictures.mkdir(parents=True, exist_ok=True)
            pair = np.concatenate([img_in, np.ones((size, 4, 3)), img_raster], 1)
            rgba = np.concatenate([pair, np.ones(pair.shape[:2] + (1,))], 2)
            write_image(pictures / f"render_{name}_view{v}.png",
                        np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8))
    row.update(iou_raster_min=min(ious_raster), iou_raster_mean=float(np.mean(ious_raster)),
               leaf_iou_asset=float(np.mean(leaf_as)), leaf_iou_gt=float(np.mean(leaf_gt)),
               iou_ceiling_min=min(ceil), iou_ceiling_views=[round(x, 4) for x in ceil],
               asset_splats=int(len(spl["means"])), input_gaussians=int(len(in_means)))
    row.update(iou_min=min(ious), iou_mean=float(np.mean(ious)), psnr=float(np.mean(psnrs)),
               ssim=float(np.mean(ssims)), iou_views=[round(x, 4) for x in ious])
    return row


COLS = [("set", "set", "{}", 7), ("plant", "plant", "{}", 17), ("IoU min", "iou_min", "{:.3f}", 8),
        ("IoU mean", "iou_mean", "{:.3f}", 9), ("ceil min", "iou_ceiling_min", "{:.3f}", 9),
        ("raster min", "iou_raster_min", "{:.3f}", 11),
        ("leaf IoU", "leaf_iou_asset", "{:.3f}", 9), ("GT leaf", "leaf_iou_gt", "{:.3f}", 8),
        ("PSNR", "psnr", "{:.2f}", 7), ("SSIM", "ssim", "{:.3f}", 6),
        ("leaf Corr", "leaf_corr", "{:.4f}", 10), ("leaf HD", "leaf_hd", "{:.4f}", 8),
        ("leaf OE", "leaf_oe", "{:.4f}", 8), ("stem Corr", "stem_corr", "{:.4f}", 10),
        ("stem HD", "stem_hd", "{:.4f}", 8), ("tex cov", "texture_coverage", "{:.2f}", 8)]
MIN_KEYS = ("iou_min", "iou_raster_min", "iou_ceiling_min")
LEGEND = ("(IoU: input 3DGS vs the asset re-expressed as splats of the input's footprint, alpha > "
          "0.5, worst / mean of 8 views; ceil min: the same for the true surface (the true leaf "
          "surface's splats, the input's stem Gaussians moved onto the true tubes), what a perfect "
          "asset scores; raster min: vs the asset drawn as a surface; leaf IoU / GT "
          "leaf: leaves alone, the asset's / the true leaf surface's splats vs the input's leaf "
          "Gaussians, mean of the views; PSNR/SSIM inside the union of both silhouettes; surface "
          "errors x10 of plant height; stem Corr = mean distance asset stem -> true tube surface; "
          "tex cov = texels of the front texture with leaf)")


def _cell(v, f: str, w: int) -> str:
    return f"{(f.format(v) if v is not None else '-'):>{w}s}"


def fmt(rows: list[dict]) -> str:
    lines = ["".join(f"{h:>{w}s}" for h, _, _, w in COLS)]
    for r in rows:
        lines.append("".join(_cell(r.get(k), f, w) for _, k, f, w in COLS))
    for tag in sorted({r["set"] for r in rows}):
        rs = [r for r in rows if r["set"] == tag]
        cells = [f"{tag:>7s}", f"{'mean':>17s}"]
        for _, k, f, w in COLS[2:]:
            vals = [r[k] for r in rs if r.get(k) is not None]
            cells.append(_cell((min(vals) if k in MIN_KEYS else float(np.mean(vals))) if vals else None, f, w))
        lines.append("".join(cells))
    lines.append(LEGEND)
    lines.append("IoU per view (azimuth 0, 45, ... 315 degrees):")
    lines += [f"{r['plant']} {r['iou_views']}" for r in rows]
    if any(r.get("iou_ceiling_views") for r in rows):
        lines.append("ceiling per view (the true surface as splats, same views):")
        lines += [f"{r['plant']} {r['iou_ceiling_views']}" for r in rows if r.get("iou_ceiling_views")]
    return "\n".join(lines)


def fmt_compare(before: list[dict], after: list[dict]) -> str:
    """Before | after of the render metrics and texture coverage, per plant both runs have."""
    keys = [("IoU min", "iou_min", "{:.3f}"), ("IoU mean", "iou_mean", "{:.3f}"),
            ("PSNR", "psnr", "{:.2f}"), ("SSIM", "ssim", "{:.3f}"), ("leaf OE", "leaf_oe", "{:.4f}"),
            ("tex cov", "texture_coverage", "{:.2f}")]
    w = 17
    lines = [f"{'set':>7s}{'plant':>17s}" + "".join(f"{h + ' b|a':>{w}s}" for h, _, _ in keys)]
    bmap = {(r["set"], r["plant"]): r for r in before}
    pairs = [(bmap[(r["set"], r["plant"])], r) for r in after if (r["set"], r["plant"]) in bmap]
    def both(b, a, k, f):
        g = lambda r: f.format(r[k]) if r.get(k) is not None else "-"  # noqa: E731
        return f"{g(b) + ' | ' + g(a):>{w}s}"
    for b, a in pairs:
        lines.append(f"{a['set']:>7s}{a['plant']:>17s}" + "".join(both(b, a, k, f) for _, k, f in keys))
    for tag in sorted({a["set"] for _, a in pairs}):
        ps = [(b, a) for b, a in pairs if a["set"] == tag]
        agg = {}
        for side, rs in (("b", [b for b, _ in ps]), ("a", [a for _, a in ps])):
            agg[side] = {k: (min if k == "iou_min" else np.mean)([r[k] for r in rs if r.get(k) is not None] or [np.nan])
                         for _, k, _ in keys}
        lines.append(f"{tag:>7s}{'mean':>17s}" + "".join(both(agg["b"], agg["a"], k, f) for _, k, f in keys))
    lines.append("(before | after; IoU as in the table above; IoU min of a set = its worst view)")
    return "\n".join(lines)


def _save(args, rows: list[dict]) -> None:
    from leaffit_usd.io_util import atomic_write_bytes

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    from benchmarks.machine import machine_info

    from leaffit_usd.fit.params import FitParams

    K = None if args.convert_with or args.reuse else (args.K or FitParams().K)   # None: not this code's
    atomic_write_bytes(args.out, (json.dumps(dict(rows=rows, size=args.size, views=N_VIEWS,
                                                  elevation=ELEVATION, K=K, machine=machine_info()),
                                             indent=1) + "\n").encode())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="suite,paper8", help="suite and/or paper8 (default: both)")
    ap.add_argument("--plants", default=None, help="comma-separated plant names (default: all)")
    ap.add_argument("--size", type=int, default=384, help="render size in pixels (384)")
    ap.add_argument("--work", default=None, help="folder for plants and outputs (default: a temp dir)")
    ap.add_argument("--pictures", default=None, help="write input | asset PNGs here")
    ap.add_argument("--reuse", action="store_true",
                    help="render the stages an earlier run left in --work instead of converting again")
    ap.add_argument("-K", type=int, default=None,
                    help="control points per leaf for convert (default: FitParams' default)")
    ap.add_argument("--out", default=str(RESULTS / "render.json"))
    ap.add_argument("--convert-with", default=None,
                    help="convert with the code in this folder (a git worktree of another commit: "
                         "the 'before' stage), render with this benchmark")
    ap.add_argument("--from-json", default=None,
                    help="comma-separated results JSONs of earlier runs: print their joined table "
                         "(and --compare) without rendering")
    ap.add_argument("--compare", default=None,
                    help="a results JSON of an earlier stage (the 'before'): print before | after")
    args = ap.parse_args(argv)
    if args.from_json:
        rows = [r for f in args.from_json.split(",") for r in json.loads(Path(f).read_text())["rows"]]
        print(fmt(rows))
        if args.compare:
            before = [r for f in args.compare.split(",") for r in json.loads(Path(f).read_text())["rows"]]
            print(fmt_compare(before, rows))
        return 0
    if args.K is not None and (args.convert_with or args.reuse):
        ap.error("-K applies to this code's convert only (not with --convert-with or --reuse)")
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="leaffit_render_"))
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    plants = []
    if "suite" in sets:
        plants += [("suite", d) for d in suite_plants(work / "suite")]
    if "paper8" in sets:
        if not (SHARED / "make_plants.py").is_file():
            print(f"skipping paper8: {SHARED} is absent (the external plants are not part of the repo)")
        else:
            plants += [("paper8", d) for d in paper8_plants()]
    if not (SHARED / "eval_deform.py").is_file():
        print(f"surface errors skipped: {SHARED / 'eval_deform.py'} is absent")
    if args.plants:
        want = set(args.plants.split(","))
        plants = [(t, d) for t, d in plants if d.name in want]
    rows = []
    for tag, d in plants:
        row = run_plant(d, work / "out" / tag, args.size,
                        Path(args.pictures) if args.pictures else None, tag, args.reuse,
                        Path(args.convert_with) if args.convert_with else None, args.K)
        rows.append(row)
        print(f"{tag} {d.name}: IoU min {row['iou_min']:.3f}, PSNR {row['psnr']:.2f}, SSIM {row['ssim']:.3f}, "
              f"stem Corr {row.get('stem_corr', float('nan')):.4f} HD {row.get('stem_hd', float('nan')):.4f}, "
              f"leaf Corr {row.get('leaf_corr', float('nan')):.4f} OE {row.get('leaf_oe', float('nan')):.4f}",
              flush=True)
        _save(args, rows)              # after every plant: a long run stopped early keeps its rows
    print(fmt(rows))
    if args.compare:
        before = [r for f in args.compare.split(",") for r in json.loads(Path(f).read_text())["rows"]]
        print(fmt_compare(before, rows))
    _save(args, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
