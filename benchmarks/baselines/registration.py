"""Registration baselines of the deformation benchmark (LeafFit Tab. 3): PCA, NR-ICP, CPD.

All work in the target leaf's local frame in template units (the frame ``fit_leaves`` optimises
in, after the PCA similarity), deform the template's *mesh vertices*, and return them in that
frame; the caller maps them with the leaf's ``leaf_to_working``. So every method starts from the
same PCA alignment and scale and only the non-rigid part differs.

* **PCA** (rigid + uniform scale): the identity in that frame.
* **NR-ICP**: Amberg et al. 2007 optimal-step non-rigid ICP, ``trimesh.registration.nricp_amberg``
  (trimesh's implementation, default stiffness schedule), source = the template mesh, target =
  the target leaf's denoised Gaussian centres; run on data normalised to unit RMS radius (its
  stiffness and distance threshold are not scale-free), matches up to 1 RMS radius.
* **CPD**: Myronenko & Song 2010 coherent point drift, non-rigid, ``pycpd.DeformableRegistration``
  (alpha = 2, beta = 2: the library defaults, on data normalised to unit RMS radius), source = up
  to ``max_points`` template Gaussian centres (FPS), target = up to ``max_points`` target centres.
  The paper compares with BCPD (Hirose 2021); no maintained BCPD installs here (probreg needs a
  C++ build), so this is CPD, BCPD's predecessor with the same Gaussian-kernel motion coherence.
  The fitted displacement field v(z) = sum_m W_m exp(-|z - y_m|^2 / (2 beta^2)) is evaluated at
  the mesh vertices (pycpd only applies it to its own source points).
"""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.geometry.sampling import farthest_point_sampling

log = logging.getLogger("leaffit_usd")


def _normaliser(points: np.ndarray):
    c = points.mean(0)
    r = float(np.sqrt(((points - c) ** 2).sum(1).mean()))
    return c, max(r, 1e-12)


def pca_baseline(template_vertices: np.ndarray) -> np.ndarray:
    """(V, 3) -> (V, 3): rigid + scale alignment only (identity in the aligned frame)."""
    return np.asarray(template_vertices, np.float64).copy()


def nricp_baseline(template_vertices: np.ndarray, template_faces: np.ndarray,
                   target_points: np.ndarray) -> np.ndarray:
    """NR-ICP (Amberg et al. 2007, trimesh) of the template mesh onto target points.

    template_vertices : (V, 3), template_faces : (F, 3), target_points : (N, 3), all in the
    target's aligned frame. Returns (V, 3) deformed vertices.
    """
    import trimesh
    from trimesh.registration import nricp_amberg

    v = np.asarray(template_vertices, np.float64)
    c, r = _normaliser(v)
    mesh = trimesh.Trimesh((v - c) / r, np.asarray(template_faces, np.int64), process=False)
    tgt = (np.asarray(target_points, np.float64) - c) / r
    try:
        with np.errstate(divide="ignore", invalid="ignore"):      # zero-length edges
            out = nricp_amberg(mesh, tgt, distance_threshold=1.0, use_faces=False)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:   # singular system
        log.warning("NR-ICP failed (%s); keeping the PCA alignment", exc)
        return v.copy()
    out = np.asarray(out, np.float64) * r + c
    return out if np.isfinite(out).all() else v.copy()


def cpd_baseline(template_points: np.ndarray, target_points: np.ndarray,
                 template_vertices: np.ndarray, max_points: int = 600, alpha: float = 2.0,
                 beta: float = 2.0, max_iterations: int = 100) -> np.ndarray:
    """Non-rigid CPD (pycpd) from template points to target points, applied to mesh vertices.

    template_points : (M, 3) template Gaussian centres; target_points : (N, 3);
    template_vertices : (V, 3) the mesh to deform. All in the target's aligned frame.
    Returns (V, 3).
    """
    from pycpd import DeformableRegistration

    src = np.asarray(template_points, np.float64)
    tgt = np.asarray(target_points, np.float64)
    if len(src) > max_points:
        src = src[farthest_point_sampling(src, max_points)]
    if len(tgt) > max_points:
        tgt = tgt[farthest_point_sampling(tgt, max_points)]
    c, r = _normaliser(src)
    reg = DeformableRegistration(X=(tgt - c) / r, Y=(src - c) / r, alpha=alpha, beta=beta,
                                 max_iterations=max_iterations)
    reg.register()
    Y = (src - c) / r
    z = (np.asarray(template_vertices, np.float64) - c) / r
    d2 = ((z[:, None, :] - Y[None, :, :]) ** 2).sum(-1)
    out = (z + np.exp(-d2 / (2 * beta**2)) @ reg.W) * r + c
    return out if np.isfinite(out).all() else np.asarray(template_vertices, np.float64).copy()
