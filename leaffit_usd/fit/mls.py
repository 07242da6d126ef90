"""Moving Least Squares deformation: the ONE formulation used by fitting, the CPU evaluator and
(transcribed line by line) the GLSL snippet.

Variant: **affine** MLS (Schaefer et al. 2006, Sec. 2.1) in 3D with a Gaussian kernel of width
sigma. Affine MLS is linear in the target control points q, so every vertex v has fixed weights
A[v, j] (depending only on the template control points p and v) and

    f(v) = sum_j A[v, j] q_j .

That makes fitting a linear map (cheap gradients), the runtime one (V, K) @ (K, 3) product per
leaf, and the shader a K-term sum. Similarity/rigid MLS are not linear in q and cannot be
precomputed. The affine variant can shear, which the depth + Chamfer fit uses to follow
bending and asymmetric leaf outlines.

Formulation (row vectors; w_hat are normalised weights so the regulariser is scale-aware):

    d2_i   = |v - p_i|^2;   w_i = exp(-(d2_i - min_k d2_k) / sigma^2);   w_hat_i = w_i / sum w
    p*     = sum_i w_hat_i p_i;   p_hat_i = p_i - p*
    P      = sum_i w_hat_i p_hat_i^T p_hat_i + (reg * sigma)^2 I          (3 x 3)
    A[v,j] = w_hat_j * (1 + (v - p*) P^{-1} p_hat_j^T)

The shift by min_k d2_k leaves w_hat unchanged and keeps the exponentials from underflowing in
float32. The regulariser makes P invertible for a flat (coplanar) template, where the affine
moment matrix is singular; every implementation uses the same ``reg`` (the stage stores it).

Why ``reg`` = 0.03 and not the 0.01 that invertibility alone needs: on a curved template the
control points within a kernel width differ in height across the sheet by a few thousandths of
the leaf, so P's smallest eigenvalue is that tiny spread squared, and the field's derivative
across the sheet is whatever the targets' small height differences make of it (up to 55x a rigid
map's on rubber_tree at K = 32, ``benchmarks/fit_diag.py``). Every fitted point lies on the sheet,
so nothing in the fit constrains that derivative, and the points a hair off the fitted sheet
(the template mesh's rim, grown out to the splats' silhouette) are thrown. (0.03 sigma)^2 damps
that direction only: the spread along the sheet, about 0.1-0.3 sigma^2 within a kernel, is left
as it was. 13 render plants, K = 48: reg 0.01 -> 0.03 lowers leaf HD on 10 (rubber_tree 0.127 ->
0.109) (``benchmarks/render.py``, README).

Frames: p, v and q are in one frame (the leaf's local frame, working units).
"""
from __future__ import annotations

import numpy as np

DEFAULT_SIGMA = 0.1   # kernel width, working units: the paper's (fit_leaves defaults to one relative to the template leaf)
DEFAULT_REG = 0.03    # regulariser, as a fraction of sigma (why 0.03: the module docstring)


def mls_weights(p: np.ndarray, v: np.ndarray, sigma: float = DEFAULT_SIGMA,
                reg: float = DEFAULT_REG) -> np.ndarray:
    """Affine-MLS weights.

    p : (K, 3) template control points; v : (V, 3) points to deform (same frame).
    Returns A : (V, K) float64 with f(v) = A @ q. Rows sum to 1 (affine invariance).
    """
    p = np.asarray(p, np.float64)
    v = np.asarray(v, np.float64)
    d2 = ((v[:, None, :] - p[None, :, :]) ** 2).sum(-1)                      # (V, K)
    w = np.exp(-(d2 - d2.min(1, keepdims=True)) / sigma**2)
    w /= w.sum(1, keepdims=True)
    p_star = w @ p                                                           # (V, 3)
    p_hat = p[None, :, :] - p_star[:, None, :]                               # (V, K, 3)
    P = np.einsum("vk,vki,vkj->vij", w, p_hat, p_hat) + (reg * sigma) ** 2 * np.eye(3)
    x = np.linalg.solve(P, (v - p_star)[:, :, None])[:, :, 0]                # P^-1 (v - p*)
    return w * (1.0 + np.einsum("vki,vi->vk", p_hat, x))


def mls_weights_torch(p, v, sigma: float = DEFAULT_SIGMA, reg: float = DEFAULT_REG):
    """Torch twin of :func:`mls_weights` (same formula, differentiable in p and v).

    p : (K, 3) tensor; v : (V, 3) tensor. Returns (V, K) tensor of p's dtype.
    """
    import torch

    d2 = ((v[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    w = torch.exp(-(d2 - d2.min(1, keepdim=True).values.detach()) / sigma**2)
    w = w / w.sum(1, keepdim=True)
    p_star = w @ p
    p_hat = p[None, :, :] - p_star[:, None, :]
    eye = torch.eye(3, dtype=p.dtype, device=p.device)
    P = torch.einsum("vk,vki,vkj->vij", w, p_hat, p_hat) + (reg * sigma) ** 2 * eye
    x = torch.linalg.solve(P, (v - p_star)[:, :, None])[:, :, 0]
    return w * (1.0 + torch.einsum("vki,vi->vk", p_hat, x))


def deform(weights: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Apply precomputed weights to targets.

    weights : (V, K); q : (K, 3) or (L, K, 3) targets. Returns (V, 3) or (L, V, 3), q's frame.
    """
    q = np.asarray(q)
    if q.ndim == 2:
        return weights @ q
    return np.einsum("vk,lkc->lvc", weights, q, optimize=True)


def deform_points(p: np.ndarray, q: np.ndarray, v: np.ndarray, sigma: float = DEFAULT_SIGMA,
                  reg: float = DEFAULT_REG) -> np.ndarray:
    """One-off: deform points v (V, 3) by the MLS field p (K, 3) -> q (K, 3) or (L, K, 3)."""
    return deform(mls_weights(p, v, sigma, reg), q)
