"""Where the render benchmark's silhouettes disagree, per view: a converted plant's asset against
its input 3DGS (``benchmarks/render.py``'s views and splat re-expression).

Per view: IoU; ``ceil`` = the IoU the true leaf surfaces (the generator's leaf meshes) would score
with the asset's stem, through the same re-expression (what an asset whose leaves were exact could
reach); pixels only the input covers (``miss``) or only the asset covers (``extra``), split by
what covers them (leaf / stem: the input's labels, the asset's parts); the leaves alone: the
asset's and the true leaf surface's IoU against the input's leaf Gaussians and their missing /
extra pixels. ``--picture`` writes view 0 (or the first of ``--views``): grey = both, red / yellow =
input only (leaf / stem), blue / cyan = asset only (leaf / stem); right: asset leaves against the
true leaves (red = true only, blue = asset only).

    .venv/bin/python benchmarks/render_diag.py PLANT_DIR STAGE_DIR [--views 0,5] [--picture P.png]

PLANT_DIR holds ``point_cloud.ply`` and ``gt.npz`` (render.py's ``--work``: suite/NAME or
external/paper8-1/NAME); STAGE_DIR the converted ``plant.usda`` (``--work``'s out/SET/NAME).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None) -> int:
    import render as B
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.splats.render import fit_bounds
    from leaffit_usd.usd.reader import read_stage

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plant")
    ap.add_argument("stage")
    ap.add_argument("--views", default="0,1,2,3,4,5,6,7")
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--picture", default=None)
    a = ap.parse_args(argv)
    d, outd, size = Path(a.plant), Path(a.stage), a.size
    views = [int(v) for v in a.views.split(",")]
    z = np.load(d / "gt.npz")
    up = np.asarray(z["up"], float)
    asset = read_stage(outd / "plant.usda")
    scene = B.asset_scene(outd / "plant.usda", asset)
    cloud = load_cloud(d / "point_cloud.ply")
    lab = np.asarray(z["labels"])[np.asarray(cloud.file_index)]
    pc = cloud.subset(np.flatnonzero(lab >= 0))
    pl = lab[lab >= 0]
    M = np.asarray(pc.means, float)
    C = pc.covariances().astype(float)
    O = np.asarray(pc.opacities, float)
    centre = 0.5 * (M.min(0) + M.max(0))
    dens = B.input_density(M)
    spl = B.asset_splats(scene, M, C, O, dens)
    gv, gf = np.asarray(z["leaf_vertices"], float), np.asarray(z["leaf_faces"], np.int64)
    gt = B.surface_gaussians(gv, gf, M, C, O, dens, seed=1)
    st = ~spl["leaf"]
    cm = np.concatenate([gt[0], spl["means"][st]])
    cc = np.concatenate([gt[1], spl["cov"][st]])
    co = np.concatenate([gt[2], spl["opac"][st]])
    iou = lambda x, y: float((x & y).sum() / max((x | y).sum(), 1))  # noqa: E731
    grey = lambda n: np.full((n, 3), 0.5)  # noqa: E731
    for v in views:
        R = B.view_basis(up, 360.0 * v / B.N_VIEWS, B.ELEVATION)
        bounds = fit_bounds((M - centre) @ R.T, size, size, 0.05)
        col = np.zeros((len(M), 3))
        col[pl == 0, 0] = 1
        col[pl > 0, 1] = 1
        ci, ai = B.render_splats(M, C, col, O, R, centre, size, bounds)
        m_in, in_stem = ai > 0.5, ci[..., 0] > ci[..., 1]
        col = np.zeros((len(spl["means"]), 3))
        col[st, 0] = 1
        col[~st, 1] = 1
        ca, aa = B.render_splats(spl["means"], spl["cov"], col, spl["opac"], R, centre, size, bounds)
        m_as, as_stem = aa > 0.5, ca[..., 0] > ca[..., 1]
        _, a_ceil = B.render_splats(cm, cc, grey(len(cm)), co, R, centre, size, bounds)
        _, ag = B.render_splats(gt[0], gt[1], grey(len(gt[0])), gt[2], R, centre, size, bounds)
        lf = pl > 0
        _, ail = B.render_splats(M[lf], C[lf], grey(int(lf.sum())), O[lf], R, centre, size, bounds)
        _, aal = B.render_splats(spl["means"][~st], spl["cov"][~st], grey(int((~st).sum())),
                                 spl["opac"][~st], R, centre, size, bounds)
        mil, mal, mgl = ail > 0.5, aal > 0.5, ag > 0.5
        miss, extra = m_in & ~m_as, m_as & ~m_in
        print(f"view {v}: IoU {iou(m_in, m_as):.3f} ceil {iou(m_in, a_ceil > 0.5):.3f} | union "
              f"{int((m_in | m_as).sum())} px, miss leaf {int((miss & ~in_stem).sum())} stem "
              f"{int((miss & in_stem).sum())}, extra leaf {int((extra & ~as_stem).sum())} stem "
              f"{int((extra & as_stem).sum())} | leaves: asset IoU {iou(mil, mal):.3f} miss "
              f"{int((mil & ~mal).sum())} extra {int((mal & ~mil).sum())}; true IoU {iou(mil, mgl):.3f} "
              f"miss {int((mil & ~mgl).sum())} extra {int((mgl & ~mil).sum())}", flush=True)
        if a.picture and v == views[0]:
            from leaffit_usd.image_io import write_image

            vis = np.zeros((size, size, 3))
            vis[m_in & m_as] = 0.5
            vis[miss & ~in_stem] = [1, 0.2, 0.2]
            vis[miss & in_stem] = [1, 1, 0]
            vis[extra & ~as_stem] = [0.2, 0.4, 1]
            vis[extra & as_stem] = [0, 1, 1]
            vis2 = np.zeros((size, size, 3))
            vis2[mal & mgl] = 0.5
            vis2[mgl & ~mal] = [1, 0.2, 0.2]
            vis2[mal & ~mgl] = [0.2, 0.4, 1]
            pair = np.concatenate([vis, np.ones((size, 3, 3)), vis2], 1)
            rgba = np.concatenate([pair, np.ones(pair.shape[:2] + (1,))], 2)
            write_image(a.picture, np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8))
    return 0


if __name__ == "__main__":
    sys.exit(main())
