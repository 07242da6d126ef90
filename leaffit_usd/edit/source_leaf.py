"""A template leaf from a single-leaf 3DGS capture (``retarget --source-leaf leaf.ply``).

The capture holds one leaf (optionally with its petiole). It is normalised to a typical leaf size
in working units, its base and apex are found, and it goes through the same stages as a plant's
template: ``fit.register.fit_leaves`` (one leaf, no optimisation: only its frame and denoised
points are needed) and ``mesh.template.build_template_mesh`` (sheet + two-sided bake).

Base and apex: the two ends of the leaf's long (first PCA) axis. The base is the end with a
petiole (a run of slabs narrower than 15 % of the blade's width), or else the end nearer the
widest slab (most leaves are widest below the middle: ovate, cordate, elliptic).
"""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.errors import UserError
from leaffit_usd.splats.cloud import GaussianCloud

log = logging.getLogger("leaffit_usd")

LEAF_SIZE = 0.1          # long-axis length of the normalised leaf, working units
MIN_ELONGATION = 1.05    # long / short extent below which no apex can be told apart


def find_base_apex(points: np.ndarray, n_slabs: int = 20) -> tuple[int, int]:
    """Indices of the petiole base and the apex of a single leaf.

    points : (N, 3) float, any frame. Raises UserError when the leaf is too round or too small
    for an apex to be detected.
    """
    pts = np.asarray(points, np.float64)
    if len(pts) < 50:
        raise UserError(f"the source leaf has only {len(pts)} Gaussians: no apex can be detected")
    c = pts.mean(0)
    _, s, vt = np.linalg.svd(pts - c, full_matrices=False)
    t = (pts - c) @ vt[0]
    w = (pts - c) @ vt[1]
    lo_t, hi_t = np.percentile(t, [0.5, 99.5])
    lo_w, hi_w = np.percentile(w, [0.5, 99.5])
    if (hi_t - lo_t) < MIN_ELONGATION * (hi_w - lo_w):
        raise UserError("the source leaf has no detectable apex: it is as wide as it is long")
    slab = np.clip(((t - lo_t) / (hi_t - lo_t) * n_slabs).astype(int), 0, n_slabs - 1)
    width = np.array([np.ptp(w[slab == k]) if (slab == k).sum() > 2 else 0.0 for k in range(n_slabs)])
    blade = width.max()
    thin = width < 0.15 * blade
    run_lo = int(np.argmin(thin)) if not thin.all() else 0          # thin slabs at the low end
    run_hi = int(np.argmin(thin[::-1])) if not thin.all() else 0    # at the high end
    if run_lo >= 2 and run_lo > run_hi:
        base_low = True
    elif run_hi >= 2 and run_hi > run_lo:
        base_low = False
    else:
        base_low = int(np.argmax(width)) < n_slabs / 2
    i_lo, i_hi = int(np.argmin(t)), int(np.argmax(t))
    return (i_lo, i_hi) if base_low else (i_hi, i_lo)


def template_from_leaf_cloud(cloud: GaussianCloud, base_point=None, apex_point=None):
    """An ``EditablePlant`` whose template is the captured leaf (no instances).

    cloud : GaussianCloud of one leaf, input frame.
    base_point, apex_point : (3,) optional, input frame: the Gaussians nearest to them are the
        petiole base and the apex (otherwise both are detected, see :func:`find_base_apex`).
    """
    from leaffit_usd.edit.plant_io import EditablePlant
    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.fit.register import fit_leaves
    from leaffit_usd.mesh.template import build_template_mesh
    from leaffit_usd.segment.result import Segmentation
    from leaffit_usd.splats.transform import transform_cloud
    from leaffit_usd.usd.asset import PlantAsset

    base, apex = find_base_apex(cloud.means) if base_point is None or apex_point is None else (-1, -1)
    if base_point is not None:
        base = int(np.argmin(np.linalg.norm(cloud.means - np.asarray(base_point, np.float32), axis=1)))
    if apex_point is not None:
        apex = int(np.argmin(np.linalg.norm(cloud.means - np.asarray(apex_point, np.float32), axis=1)))
    if base == apex:
        raise UserError("the source leaf's base and apex are the same Gaussian")
    length = float(np.linalg.norm(cloud.means[apex].astype(np.float64) - cloud.means[base]))
    if not np.isfinite(length) or length <= 0:
        raise UserError("the source leaf has no detectable apex (zero length)")
    s = LEAF_SIZE / length
    m = np.eye(4)
    m[:3, :3] *= s
    m[:3, 3] = -s * cloud.means[base].astype(np.float64)
    work = transform_cloud(cloud, m)
    n = len(work)
    seg = Segmentation(labels=np.ones(n, np.int32), root_index=int(base),
                       leaf_tip=np.array([apex], np.int64), leaf_base=np.array([base], np.int64))
    fits = fit_leaves(work, seg, FitParams(optimize=False, template=1))
    if len(fits.template_points) < 8:
        raise UserError("the source leaf has too few Gaussians left after denoising")
    mesh = build_template_mesh(work, fits)
    asset = PlantAsset(
        template_points=mesh.points, template_faces=mesh.faces, template_normals=mesh.normals,
        template_uvs=mesh.uvs, template_side=mesh.side, template_controls=fits.template_controls,
        targets=np.zeros((0, len(fits.template_controls), 3), np.float32),
        positions=np.zeros((0, 3), np.float32), orientations=np.zeros((0, 4), np.float32),
        scales=np.zeros((0, 3), np.float32), leaf_labels=np.zeros(0, np.int32),
        sigma=fits.sigma, reg=fits.reg, stem_points=np.zeros((0, 3), np.float32),
        stem_faces=np.zeros((0, 3), np.int32), asset_to_input=np.eye(4), metadata={})
    to_f = lambda im: np.asarray(im, np.float32) / 255.0  # noqa: E731
    log.info("source leaf: %d Gaussians, template mesh %d vertices", n, len(mesh.points))
    return EditablePlant(asset, to_f(mesh.front_texture), to_f(mesh.back_texture), "png")


def load_source_leaf(path, base_point=None, apex_point=None):
    """The source template of ``retarget``: a LeafFit stage's template, or a single-leaf capture
    (.ply or a USD ParticleField3DGaussianSplat)."""
    from leaffit_usd.edit.plant_io import load_plant
    from leaffit_usd.splats import detect_format, load_cloud

    if detect_format(path) == "usd":
        from leaffit_usd.usd.reader import find_instancer, open_stage

        if find_instancer(open_stage(path)) is not None:
            return load_plant(path)
    return template_from_leaf_cloud(load_cloud(path), base_point, apex_point)
