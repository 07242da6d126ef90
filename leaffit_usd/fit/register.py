"""Leaf registration (LeafFit Sec. "Leaf Registration using Moving Least Squares").

Per plant, in the working frame (root at origin, +Z up, height 1):

1. **Denoise** each leaf's Gaussian centres (``fit.denoise``: MLS projection on local planes,
   outliers removed).
2. **Leaf frames** (``geometry.pca.leaf_frame``): origin at the petiole base, +X base -> apex in
   the principal plane, +Z the normal to the upper side. Each leaf gets a uniform **scale**
   ``s_j = size_j / size_template`` (size = RMS distance of the points from their centroid in the
   leaf plane), so its points in *template units* are ``R_j^T (x - base_j) / s_j``.
3. **Template**: ``params.template`` (a leaf label) or ``"auto"`` (:mod:`.template_choice`:
   symmetric, filled, well observed, of middling size).
4. **Control points**: farthest point sampling of K template points (``p``). The paper's start
   (``start="assignment"``): K points of each target leaf matched one to one to ``p`` by the
   least summed squared distance in the aligned frames (Jonker-Volgenant,
   ``scipy.optimize.linear_sum_assignment``); ours (``"rigid"``): ``q = p``, the template placed
   by the leaf's frame and scale.
5. **Optimisation** (``params.optimize``), all leaves at once:
   * ours: Gauss-Newton on the depth + Chamfer objective with base/apex landmarks and the
     silhouette outlines (:mod:`.gauss_newton`; the apex moved to the edge of the denoised
     blade: :func:`leaffit_usd.fit.leaf_ends.apex_at_blade_edge`), ``refine`` iterations;
   * the paper's (``FitParams.paper()``): Adam on ``L_depth + lam * L_chamfer`` through the splat
     renderer, lr 7e-3, 200 steps (:mod:`.adam`); with ``steps`` > 0 and ``refine`` > 0 Adam
     runs first and Gauss-Newton finishes.
6. **Degenerate leaves** (fewer than K Gaussians after denoising, collinear, a size ratio to the
   template beyond ``max_scale_ratio``, or a non-finite result) get a warning and the rigid fit:
   ``targets = p`` (identity MLS) with the leaf's frame and scale. Never NaN.

Departures from the paper (``FitParams.paper()`` restores it; ``benchmarks/deformation.py``
prints both rows, on 10 generated plants / 110 target leaves):

* **Kernel width relative to the leaf**: sigma = 0.7 x the template leaf's size (RMS radius in its
  plane) instead of 0.1 plant heights. An absolute width ties the fit to how large the leaves
  are relative to the plant: on the generated plants (leaf sizes 0.05-0.14) 0.1 is 0.7-2 leaf
  sizes, too smooth for the smaller leaves to follow their fold, droop and twist. Relative to the
  template, the field has the same stiffness on any plant.
* **48 control points, MLS regulariser 0.03** (the paper: 32; no regulariser): see
  ``FitParams`` and :mod:`leaffit_usd.fit.mls`.
* **Gauss-Newton from the rigid start** instead of 200 Adam steps (step 5): the field is linear
  in the targets, so each solve is exact; 10 of them cost what 20 Adam steps did.
The denoising sigma stays the paper's 0.1 (``denoise``).

Timing (``benchmarks/profile_convert.py``): a 9-leaf, 100k-Gaussian plant fits in ~5 s of CPU
(denoising ~2 s, outlines ~1 s, Gauss-Newton ~2 s); the paper's Adam ~25 s. One torch thread,
always, for byte-identical results (``leaffit_usd.determinism``).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from leaffit_usd.determinism import deterministic
from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.adam import Covariances, optimize_adam, start_index
from leaffit_usd.fit.denoise import DenoiseParams, denoise_leaf
from leaffit_usd.fit.gauss_newton import gauss_newton, refine_targets
from leaffit_usd.fit.mls import DEFAULT_SIGMA, mls_weights
from leaffit_usd.fit.params import FACE_ON_MAX_DEG, FitParams
from leaffit_usd.fit.result import LeafFits
from leaffit_usd.fit.template_choice import choose_template
from leaffit_usd.geometry.pca import leaf_frame, pca
from leaffit_usd.geometry.sampling import farthest_point_sampling, sample_at_most
from leaffit_usd.segment.result import Segmentation
from leaffit_usd.fit.leaf_ends import apex_at_blade_edge, base_apex
from leaffit_usd.splats.cloud import GaussianCloud

log = logging.getLogger("leaffit_usd")


@dataclass
class _Leaf:
    label: int
    gaussians: np.ndarray          # (M,) indices of kept (denoised) Gaussians
    local: np.ndarray              # (M, 3) denoised centres, leaf local frame, leaf units (unscaled)
    normals: np.ndarray            # (M, 3) unit local-plane normals at ``local`` (denoiser), local frame
    frame: np.ndarray              # (4, 4) rigid local -> working
    size: float
    degenerate: str = ""           # reason, "" if fine
    apex: np.ndarray = field(default_factory=lambda: np.zeros(3))   # (3,) apex landmark, local frame
    scale: float = 1.0
    all_gaussians: np.ndarray | None = None  # (A,) every Gaussian of the leaf (segmentation)
    sampled: np.ndarray | None = None        # (S,) those that entered denoising (<= leaf_gaussians)
    residual_limit: float = np.inf           # the denoiser's outlier residual limit, working units

    @property
    def capped(self) -> bool:
        """Whether only a subset of the leaf's Gaussians entered denoising (``leaf_gaussians``)."""
        return self.all_gaussians is not None and len(self.sampled) < len(self.all_gaussians)


# ---------------------------------------------------------------------------------------------
# public entry point
# ---------------------------------------------------------------------------------------------

@deterministic   # one torch thread: the result must not depend on the thread count
def fit_leaves(cloud_working: GaussianCloud, seg: Segmentation,
               params: FitParams = FitParams()) -> LeafFits:
    """Register one template leaf to every leaf of a plant.

    cloud_working : GaussianCloud, working frame (root at origin, +Z up, height 1)
    seg : Segmentation of that cloud (labels 1..L; ``leaf_base`` / ``leaf_tip`` Gaussian indices
        give each leaf's petiole base and apex; when absent, the leaf point nearest to / farthest
        from the root along ``seg.dist_root`` (or Euclidean from the origin) is used)
    Returns ``LeafFits`` (targets in template units, instance local frame; see its docstring).
    """
    params.validate()
    t0 = time.perf_counter()
    torch.manual_seed(params.seed)
    n_leaves = seg.n_leaves
    if len(seg.labels) != len(cloud_working):
        raise ParameterError("seg.labels", f"{len(cloud_working)} labels (one per Gaussian)",
                             len(seg.labels))
    means = np.asarray(cloud_working.means, np.float64)
    # covariances only of the Gaussians the optimisation renders (``_subset``): all N of them
    # were ~150 B per Gaussian of transient memory (0.75 GB at 5M)
    covs = Covariances(cloud_working)
    opac = cloud_working.opacities.astype(np.float64)

    leaves = [_prepare_leaf(l, means, seg, params.denoise, params.leaf_gaussians, params.seed)
              for l in range(1, n_leaves + 1)]
    for lf in leaves:
        if not lf.degenerate and len(lf.local) < params.K:
            lf.degenerate = f"{len(lf.local)} Gaussians after denoising, fewer than K={params.K}"
    if n_leaves == 0:
        log.warning("fit: the segmentation has no leaves; nothing to fit")
        return _empty_fits(params)

    tmpl = choose_template(leaves, params)
    T = leaves[tmpl - 1]
    if params.sigma == "auto":
        sigma = params.sigma_relative * T.size if T.size > 0 else DEFAULT_SIGMA
        log.info("fit: MLS kernel width sigma = %.4f (%.2f x template size %.4f)", sigma,
                 params.sigma_relative, T.size)
        params = replace(params, sigma=float(sigma))
    _scale_to_template(leaves, T, tmpl, params)
    P_all = T.local                                            # template units (scale 1)
    p = _template_controls(P_all, tmpl, params)
    L = n_leaves
    fallback = np.array([bool(lf.degenerate) for lf in leaves])
    targets, init_ok = _initial_targets(leaves, p, tmpl, fallback)
    if params.optimize and init_ok and params.start in ("rigid", "best") and params.steps > 0:
        targets[init_ok] = p                  # the template placed by each leaf's frame and scale
    if params.optimize and params.steps > 0 and init_ok:
        opt = optimize_adam(T, [leaves[j] for j in init_ok], p, targets[init_ok], means, covs,
                            opac, params)
        targets[init_ok] = opt
    if params.optimize and params.refine > 0 and init_ok:
        outlines = None
        if params.outline_weight > 0 and _seen_face_on(T):
            outlines = [_silhouette_outline(lf, covs, opac, params.fg_alpha, means)
                        if _seen_face_on(lf) else np.zeros((0, 2))
                        for lf in [T] + [leaves[j] for j in init_ok]]
        targets[init_ok] = _solve(T, [leaves[j] for j in init_ok], p, targets[init_ok], params,
                                  outlines)

    bad = ~np.isfinite(targets).all(axis=(1, 2))
    for j in np.flatnonzero(bad):
        log.warning("fit: leaf %d gave a non-finite fit; using a rigid fit", leaves[j].label)
        targets[j] = p
        fallback[j] = True

    errors = _fit_errors(leaves, p, P_all, targets, params)
    l2w = np.stack([lf.frame @ np.diag([lf.scale, lf.scale, lf.scale, 1.0]) for lf in leaves])
    info = params.to_dict()          # no timings here: the output must be byte-deterministic
    info["degenerate"] = {str(lf.label): lf.degenerate for lf in leaves if lf.degenerate}
    info["template_rule"] = "auto" if params.template == "auto" else "user"
    log.info("fit: %d leaves, template %d, %d rigid fallbacks, %.1f s", L, tmpl,
             int(fallback.sum()), time.perf_counter() - t0)
    return LeafFits(
        template_label=int(tmpl),
        template_points=P_all.astype(np.float32),
        template_gaussians=_all_kept(T, means).astype(np.int64),
        template_controls=p.astype(np.float32),
        leaf_labels=np.arange(1, L + 1, dtype=np.int32),
        targets=targets.astype(np.float32),
        leaf_to_working=l2w,
        errors=errors,
        fallback=fallback,
        sigma=float(params.sigma),
        reg=float(params.reg),
        params=info,
    )


def _solve(T, leaves: list, p: np.ndarray, q0: np.ndarray, params: FitParams, outlines):
    """Gauss-Newton (:mod:`.gauss_newton`) from ``q0`` (B, K, 3), the assignment (or Adam's
    result); with ``start`` "rigid" from ``p``, with "best" from both, keeping per leaf the
    lower objective (one batch of 2B problems). Returns (B, K, 3)."""
    B = len(leaves)
    if params.steps > 0 or params.start == "assignment":
        return refine_targets(T, leaves, p, q0, params, outlines)
    rigid = np.repeat(p[None], B, 0)
    if params.start == "rigid":
        return refine_targets(T, leaves, p, rigid, params, outlines)
    both = None if outlines is None else outlines + outlines[1:]
    r = gauss_newton(T, leaves + leaves, p, np.concatenate([rigid, q0]), params, both)
    use_q0 = r.energy[B:] < r.energy[:B]
    return np.where(use_q0[:, None, None], r.targets[B:], r.targets[:B])


def _scale_to_template(leaves: list, T, tmpl: int, params: FitParams) -> None:
    """Each leaf's size relative to the template leaf ``T``; a leaf beyond max_scale_ratio (or
    already degenerate) is marked for a rigid fit (logged)."""
    for lf in leaves:
        lf.scale = float(np.clip(lf.size / T.size, 1e-3, 1e3)) if lf.size > 0 and T.size > 0 else 1.0
        if not lf.degenerate and lf.label != tmpl and not (
                1.0 / params.max_scale_ratio <= lf.scale <= params.max_scale_ratio):
            lf.degenerate = (f"size ratio {lf.scale:.2f} to the template leaf {tmpl} is beyond "
                             f"max_scale_ratio={params.max_scale_ratio:g}")
    for lf in leaves:
        if lf.degenerate:
            log.warning("fit: leaf %d is degenerate (%s); using a rigid fit", lf.label, lf.degenerate)


def _template_controls(P_all: np.ndarray, tmpl: int, params: FitParams) -> np.ndarray:
    """(K, 3) the template's control points: FPS over its (M, 3) local points (zeros if none)."""
    if len(P_all) == 0:
        log.warning("fit: the template leaf %d has no Gaussians; every leaf is placed rigidly", tmpl)
        p = np.zeros((params.K, 3))
    else:
        p = P_all[farthest_point_sampling(P_all, params.K, start=_start_index(P_all))]
    K = len(p)
    if K < params.K:
        log.warning("fit: template leaf %d has only %d distinct points; using K=%d", tmpl, K, K)
    return p


def _initial_targets(leaves: list, p: np.ndarray, tmpl: int, fallback: np.ndarray):
    """(L, K, 3) initial targets (FPS of each leaf matched to ``p`` by Jonker-Volgenant; ``p`` for
    the template and rigid leaves) and the indices of the leaves to optimise. Updates ``fallback``."""
    K = len(p)
    targets = np.repeat(p[None].astype(np.float64), len(leaves), axis=0)
    init_ok = []
    for j, lf in enumerate(leaves):
        if lf.degenerate or lf.label == tmpl:
            continue
        Q = lf.local / lf.scale
        cidx = farthest_point_sampling(Q, K, start=_start_index(Q))
        c = Q[cidx]
        if len(c) < K:
            lf.degenerate = f"only {len(c)} distinct points"
            fallback[j] = True
            log.warning("fit: leaf %d is degenerate (%s); using a rigid fit", lf.label, lf.degenerate)
            continue
        cost = ((p[:, None, :] - c[None, :, :]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(cost)
        targets[j, rows] = c[cols]
        init_ok.append(j)
    return targets, init_ok


def _fit_errors(leaves: list, p, P_all, targets, params: FitParams) -> np.ndarray:
    """(L,) float32 mean Chamfer distance of each deformed template to its leaf, working units."""
    errors = np.zeros(len(leaves), np.float32)
    A_full = mls_weights(p, P_all, params.sigma, params.reg)
    for j, lf in enumerate(leaves):
        if len(lf.local) == 0:
            continue
        deformed = A_full @ targets[j]
        errors[j] = lf.scale * _chamfer_mean(deformed, lf.local / lf.scale)
    return errors


# ---------------------------------------------------------------------------------------------
# preparation
# ---------------------------------------------------------------------------------------------

_start_index = start_index


def _leaf_subset(idx: np.ndarray, means: np.ndarray, cap: int, label: int, seed: int) -> np.ndarray:
    """At most ``cap`` of the indices ``idx`` (sorted) into ``means`` (N, 3): a seeded random
    choice per leaf, drawn in position order (``position_order_sample``), so the same capture in
    another file order fits the same subset."""
    return idx[sample_at_most(means[idx], cap, [int(seed), int(label), 0x5EED])]


def _all_kept(lf: _Leaf, means: np.ndarray) -> np.ndarray:
    """Every Gaussian of the leaf that the denoiser would keep (sorted): the kept subset, plus
    each Gaussian left out of the subset whose nearest subset Gaussian was kept and which lies
    within the denoiser's residual limit of that one's local plane (its denoised centre and
    normal).

    Why the plane test: the off-surface fuzz near a blade is a fixed share of its Gaussians at
    any density. The denoiser removes it from the subset, but a fuzz Gaussian left out of the
    subset has a kept blade Gaussian as its nearest, so without the test every one of them came
    back: the 1M capsicum's template kept ~200 fuzz Gaussians (its 100k twin: none, all its
    leaves fit in the subset), and the template outline grew with the density (auto labels,
    outline error x10 0.0108 / 0.0123 / 0.0140 at 100k / 1M / 5M)."""
    if not lf.capped:
        return lf.gaussians
    from scipy.spatial import cKDTree

    rest = np.setdiff1d(lf.all_gaussians, lf.sampled, assume_unique=True)
    if not len(rest) or not len(lf.gaussians):
        return lf.gaussians
    keep = np.isin(lf.sampled, lf.gaussians, assume_unique=True)
    _, near = cKDTree(means[lf.sampled]).query(means[rest], k=1, workers=-1)
    ok = keep[near]
    j = np.searchsorted(lf.gaussians, lf.sampled[near[ok]])  # position among the kept
    R, t = lf.frame[:3, :3], lf.frame[:3, 3]
    surface = lf.local[j] @ R.T + t                          # denoised centres, working frame
    resid = np.abs(((means[rest[ok]] - surface) * (lf.normals[j] @ R.T)).sum(1))
    ok[ok] = resid <= lf.residual_limit
    return np.sort(np.concatenate([lf.gaussians, rest[ok]]))


def _prepare_leaf(label: int, means: np.ndarray, seg: Segmentation, dn: DenoiseParams,
                  cap: int = 0, seed: int = 0) -> _Leaf:
    idx_all = seg.leaf_indices(label)
    if len(idx_all) == 0:
        return _Leaf(label, idx_all.astype(np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.eye(4), 0.0,
                     "no Gaussians in the segmentation")
    idx = _leaf_subset(idx_all, means, cap, label, seed)
    pts = means[idx]
    base, apex = base_apex(label, idx_all, means, seg)
    res = denoise_leaf(pts, dn)
    kept = idx[res.keep]
    dpts = res.points
    # the frame keeps the segmentation's apex: the walked one moves across a blunt tip with
    # the sample (a capped leaf's frame would turn with its subset); the landmark takes the edge
    tip = apex_at_blade_edge(dpts, base, apex)
    frame = leaf_frame(dpts if len(dpts) else pts, base, apex)
    local = (dpts - frame[:3, 3]) @ frame[:3, :3]
    normals = res.normals @ frame[:3, :3]
    reason = ""
    if len(dpts) >= 3:
        var = pca(dpts).variances
        # no leaf plane: collinear (cross-section std < 1 % of the length's), or thin (< 10 %)
        # with a round cross-section (a stem piece): the normal is undefined. Blades, even
        # narrow arching ones, are wider than 10 % of their length's spread (samples: >= 16 %).
        # (Local planarity does not separate them: noisy two-sided blades look less planar in
        # small neighbourhoods than surface-sampled stems.)
        if var[1] < 1e-4 * max(var[0], 1e-300):
            reason = "collinear Gaussians (no leaf plane)"
        elif var[1] < 1e-2 * var[0] and var[2] > 0.5 * var[1]:
            reason = "thin, non-planar Gaussians (a stem piece? no leaf plane)"
        size = float(np.sqrt(max(var[0] + var[1], 0.0)))
    else:
        size = 0.0
        reason = f"only {len(dpts)} Gaussians"
    if not np.isfinite(local).all():
        reason = "non-finite positions"
        local = normals = np.zeros((0, 3))
    apex_local = (tip - frame[:3, 3]) @ frame[:3, :3]
    return _Leaf(label, kept.astype(np.int64), local, normals, frame, size, reason, apex=apex_local,
                 all_gaussians=idx_all, sampled=idx, residual_limit=res.residual_limit)


def _chamfer_mean(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance, mean of Euclidean nearest-neighbour distances both ways / 2."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    da, _ = cKDTree(b).query(a, k=1)
    db, _ = cKDTree(a).query(b, k=1)
    return 0.5 * (float(da.mean()) + float(db.mean()))


def _empty_fits(params: FitParams) -> LeafFits:
    K = params.K
    return LeafFits(0, np.zeros((0, 3), np.float32), np.zeros(0, np.int64),
                    np.zeros((K, 3), np.float32), np.zeros(0, np.int32),
                    np.zeros((0, K, 3), np.float32), np.zeros((0, 4, 4)), np.zeros(0, np.float32),
                    np.zeros(0, bool), DEFAULT_SIGMA if params.sigma == "auto" else float(params.sigma),
                    float(params.reg), params.to_dict())


# ---------------------------------------------------------------------------------------------
# optimisation
# ---------------------------------------------------------------------------------------------

def _seen_face_on(lf: _Leaf) -> bool:
    """Whether the leaf's xy view (its fit frame, along -Z) sees the blade face-on: the mean of
    its denoised normals (each turned to +Z) within ``FACE_ON_MAX_DEG`` of +Z. An arched strap
    leaf (lucky bamboo, sorghum) has its PCA +Z along its width: seen edge-on, its silhouette
    is the arch's side view, not its outline (the outline term made sorghum's OE 0.0106 ->
    0.0161)."""
    n = np.asarray(lf.normals, np.float64)
    if len(n) < 3:
        return False
    m = (n * np.where(n[:, 2:3] < 0, -1.0, 1.0)).mean(0)
    r = float(np.linalg.norm(m))
    return r > 0 and m[2] / r >= np.cos(np.radians(FACE_ON_MAX_DEG))


def _silhouette_outline(lf: _Leaf, covs: "Covariances", opac: np.ndarray, thr: float,
                        means: np.ndarray, long_side: int = 256) -> np.ndarray:
    """(n, 2) the leaf's splat silhouette outline in its plane: the centres of the boundary
    pixels of the largest region (holes filled) where its kept Gaussians, rendered along the
    local -Z, cover alpha > ``thr``; leaf local frame, template units (``/ lf.scale``). A
    ``long_side`` px image over the leaf's xy extent grown by 10 %. (0, 2) for a leaf with
    fewer than 3 Gaussians. ``means`` : (N, 3) the cloud's centres, working frame: a capped
    leaf (``leaf_gaussians``) renders every Gaussian the denoiser would keep (:func:`_all_kept`:
    its subset at their denoised centres, the rest at their own).

    Why the silhouette and not the outermost centres: the Gaussians' centres stop inside the
    leaf's edge by about a splat footprint, an absolute distance (the capture's), not a fraction
    of the leaf; the template mesh's outline is grown out to the template's silhouette
    (``mesh.outline_fit``), so mapping the template's silhouette onto each leaf's own puts every
    leaf's outline where its splats end, at any size relative to the template."""
    from scipy.ndimage import binary_erosion, binary_fill_holes, label

    from leaffit_usd.splats.render import render_orthographic_np

    if len(lf.local) < 3:
        return np.zeros((0, 2))
    R, t = lf.frame[:3, :3], lf.frame[:3, 3]
    g, pts = lf.gaussians, lf.local / lf.scale
    if lf.capped:
        # a capped leaf: every Gaussian the denoiser would keep, not only its subset (those left
        # out at their own centres), so the silhouette is the one all its Gaussians cover
        extra = np.setdiff1d(_all_kept(lf, means), g, assume_unique=True)
        g = np.concatenate([g, extra])
        pts = np.vstack([pts, (means[extra] - t) @ R / lf.scale])
    cov = np.einsum("ji,njk,kl->nil", R, covs[g], R) / lf.scale ** 2
    lo, hi = pts[:, :2].min(0), pts[:, :2].max(0)
    pad = 0.1 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    px = float((hi - lo).max()) / long_side
    if not px > 0:
        return np.zeros((0, 2))
    W = max(int(np.ceil((hi[0] - lo[0]) / px)), 8)
    H = max(int(np.ceil((hi[1] - lo[1]) / px)), 8)
    bounds = (float(lo[0]), float(lo[0] + W * px), float(lo[1]), float(lo[1] + H * px))
    r = render_orthographic_np(pts, cov, np.full((len(pts), 3), 0.5), opac[g], W, H, bounds)
    fg = np.asarray(r.alpha) > thr
    lab, n = label(fg)
    if n == 0:
        return np.zeros((0, 2))
    region = binary_fill_holes(lab == 1 + int(np.argmax(np.bincount(lab.ravel())[1:])))
    rim = region & ~binary_erosion(region, border_value=0)
    rr, cc = np.nonzero(rim)
    return np.stack([bounds[0] + (cc + 0.5) * px, bounds[3] - (rr + 0.5) * px], 1)
