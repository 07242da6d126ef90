"""Gauss-Newton registration of the target control points, all leaves in one batch (ours; the
default fit; ``FitParams.paper()`` runs the paper's Adam instead, :mod:`leaffit_usd.fit.adam`).

The affine MLS field is linear in the target control points q (``fit.mls``: the deformed
template is ``f = A q``, A (M, K) fixed by the template), so with the nearest neighbours held
fixed the objective is a linear least-squares problem in the K x 3 unknowns of each leaf,
solved exactly; every iteration re-pairs the neighbours (kd-trees) and solves again:

    E(q) = w_plane * mean_a (n_a . (A_a q - y_a))^2                      (depth term)
         + lam * [mean_a |A_a q - y_a|^2 + mean_b |A_b' q - y_b|^2]      (Chamfer, paper Eq.)
         + lam * w_lm * sum_l |A_l q - z_l|^2                            (landmarks)
         + lam * w_o * [mean_o |(A_o q)_xy - y_o|^2 + mean_c |(A_c' q)_xy - y_c|^2]   (outline)

a = the template's points, y_a its nearest target point, n_a the target's local plane normal
there (``fit.denoise``); b = the target's points, b' its nearest deformed template point. The
depth term is L_depth without the raster: for a leaf seen along its normal (the PCA-aligned
view), the depth difference at a pixel is the distance between the two sheets along the normal.
The landmarks l are the petiole base (the local origin) and the apex of the template and the
target: the tip is thin and sparsely observed, so the Chamfer terms alone let the deformed
template fall short of it. The outline term pairs the template's splat silhouette outline with
each leaf's (``outlines``, rendered once per leaf: the one place this fit needs the splat
renderer), in the leaf plane: the surface Chamfer is carried by the blade's interior, where every
point has a partner within half a spacing whatever the outline does, so without it the smooth
field stops short of the leaf's rim.

The point sets are farthest-point samples (``refine_points``): uniform over the blade's area,
as the area-sampled shape errors are (a random subset weights the densely captured parts).

Steps: Levenberg-Marquardt with the damping scaled by each unknown's own curvature (Marquardt:
``mu_i = d * H_ii``), d falling geometrically from ``damping_start`` to ``damping`` over the
``refine`` iterations. Why: a handle at the rim has little data and a small H_ii; damping by the
mean diagonal let it jump, the field swung past the rim, and the re-paired neighbours then held
it in a worse basin (the Hausdorff distance); damping each by its own curvature moves every
handle a similar fraction of its way per iteration, the path Adam takes, at a tenth of its cost.

Start (``FitParams.start``): "rigid" = the template placed by the leaf's frame and scale
(q = p); "assignment" = the paper's initial correspondence (FPS of the leaf matched to p by
Jonker-Volgenant); "best" (ours) = both in one batch of 2B problems, keeping per leaf the result
with the lower objective (:class:`GaussNewtonResult`'s energy). From the paper's start
Gauss-Newton can follow a crossed pairing of neighbouring handles; from the rigid start the
field unfolds smoothly, except on an arched strap leaf (lucky bamboo), whose PCA frame is far
from the template's.

All leaves are solved together: stacked (B, 3K, 3K) normal equations, one batched solve per
iteration. Frames: each leaf's local frame, template units. Returns (B, K, 3) float64.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.fit.mls import mls_weights
from leaffit_usd.fit.params import FitParams
from leaffit_usd.geometry.sampling import farthest_point_sampling


def _fps(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of at most ``n`` farthest-point samples (all when ``n`` is 0 or enough), from the
    point nearest the local origin (the petiole base)."""
    if n <= 0 or len(points) <= n:
        return np.arange(len(points))
    start = int(np.argmin((np.asarray(points) ** 2).sum(1)))
    return farthest_point_sampling(points, n, start=start)


def _kron3(H: np.ndarray, E: np.ndarray) -> np.ndarray:
    """(B, 3K, 3K) = kron(H[b], E) for H (B, K, K), E (3, 3)."""
    B, K, _ = H.shape
    return (H[:, :, None, :, None] * E[None, None, :, None, :]).reshape(B, 3 * K, 3 * K)


class _Padded:
    """Per-leaf point sets stacked (B, nmax, d) with weights 1/n (0 on the padding rows)."""

    def __init__(self, sets: list):
        B = len(sets)
        d = sets[0].shape[1] if B and sets[0].ndim == 2 else 3
        self.n = np.array([len(s) for s in sets])
        nmax = max(int(self.n.max(initial=0)), 1)
        self.pts = np.zeros((B, nmax, d))
        self.w = np.zeros((B, nmax))
        for b, s in enumerate(sets):
            self.pts[b, :len(s)] = s
            self.w[b, :len(s)] = 1.0 / max(len(s), 1)
        self.trees = [cKDTree(s) if len(s) else None for s in sets]


def _pair(trees: list, X: np.ndarray) -> np.ndarray:
    """(B, M) index of each X[b] row's nearest point in ``trees[b]`` (0 without a tree)."""
    out = np.zeros(X.shape[:2], np.int64)
    for b, t in enumerate(trees):
        if t is not None:
            out[b] = t.query(X[b], k=1)[1]
    return out


def _back_pair(X: np.ndarray, Y: _Padded) -> np.ndarray:
    """(B, nmax) index into X[b] (B, M, d) of the nearest deformed point to each Y[b] row."""
    out = np.zeros(Y.w.shape, np.int64)
    for b in range(len(X)):
        n = int(Y.n[b])
        if n:
            out[b, :n] = cKDTree(X[b]).query(Y.pts[b, :n], k=1)[1]
    return out


class GaussNewtonResult(NamedTuple):
    """targets : (B, K, 3) float64, template units; energy : (B,) the objective at them (its
    neighbours re-paired there), template units squared."""

    targets: np.ndarray
    energy: np.ndarray


def refine_targets(template, leaves: list, p: np.ndarray, q0: np.ndarray, params: FitParams,
                   outlines: list | None = None) -> np.ndarray:
    """:func:`gauss_newton`'s targets alone: (B, K, 3) float64."""
    return gauss_newton(template, leaves, p, q0, params, outlines).targets


def gauss_newton(template, leaves: list, p: np.ndarray, q0: np.ndarray, params: FitParams,
                 outlines: list | None = None) -> GaussNewtonResult:
    """Gauss-Newton on the objective of the module doc, every leaf at once.

    template : the template leaf (``local`` (M, 3) its denoised centres, ``apex`` (3,), local
        frame, template units); leaves : B target leaves (``local`` (n, 3), ``normals`` (n, 3),
        ``apex`` (3,), local frame, leaf units; ``scale`` its size / the template's)
    p : (K, 3) template control points; q0 : (B, K, 3) start targets (template units)
    outlines : None, or the template's then each leaf's silhouette outline ((n, 2) each, local
        frame, template units; (0, 2) where a leaf has none)
    Returns :class:`GaussNewtonResult` (targets, template units, and the objective there).
    """
    q = np.array(q0, np.float64).reshape(len(leaves), len(p), 3)
    B, K = q.shape[:2]
    if B == 0 or params.refine <= 0:
        return GaussNewtonResult(q, np.zeros(B))
    X = template.local[_fps(template.local, params.refine_points)]
    A = mls_weights(p, X, params.sigma, params.reg)                      # (M, K)
    M = len(X)
    subs = [_fps(lf.local, params.refine_points) for lf in leaves]
    Y = _Padded([lf.local[s] / lf.scale for lf, s in zip(leaves, subs)])
    Nrm = _Padded([lf.normals[s] for lf, s in zip(leaves, subs)]).pts
    A_lm = mls_weights(p, np.stack([np.zeros(3), template.apex]), params.sigma, params.reg)  # (2, K)
    H_lm = params.landmark_weight * A_lm.T @ A_lm
    z_lm = np.stack([np.stack([np.zeros(3), lf.apex / lf.scale]) for lf in leaves])         # (B, 2, 3)
    g_lm = params.landmark_weight * np.einsum("lk,blc->bkc", A_lm, z_lm)
    H_tt = A.T @ A / M                   # the template's own Chamfer term: the same for every leaf
    outline = _OutlineTerm(outlines, X, p, params) if outlines is not None else None
    I3 = np.eye(3)
    for it in range(params.refine):
        Xd = np.matmul(A, q)                             # (B, M, 3)
        ia = _pair(Y.trees, Xd)
        ib = _back_pair(Xd, Y)
        Ya = np.take_along_axis(Y.pts, ia[..., None], 1)                # (B, M, 3)
        Na = np.take_along_axis(Nrm, ia[..., None], 1)
        Ab = A[ib] * Y.w[..., None]                                     # (B, n, K), weighted
        H_pt = H_tt[None] + np.matmul(A[ib].transpose(0, 2, 1), Ab) + H_lm[None]
        g_pt = np.matmul(A.T, Ya) / M + np.matmul(Ab.transpose(0, 2, 1), Y.pts) + g_lm
        J = (A[None, :, :, None] * Na[:, :, None, :]).reshape(B, M, 3 * K)   # row a: n_a^T A_a
        r = (Na * Ya).sum(-1)                                           # (B, M)
        H = params.lam * _kron3(H_pt, I3) + params.plane_weight * np.matmul(
            J.transpose(0, 2, 1), J) / M
        g = params.lam * g_pt.reshape(B, -1) + params.plane_weight * np.matmul(
            J.transpose(0, 2, 1), r[..., None])[..., 0] / M
        if outline is not None:
            dH, dg = outline.normal_equations(q)
            H, g = H + dH, g + dg
        frac = it / max(params.refine - 1, 1)
        d = params.damping_start ** (1.0 - frac) * params.damping ** frac
        D = d * np.diagonal(H, axis1=1, axis2=2)                        # (B, 3K) Marquardt
        H = H + D[:, :, None] * np.eye(3 * K)[None]
        q = np.linalg.solve(H, (g + D * q.reshape(B, -1))[..., None])[..., 0].reshape(B, K, 3)
    # the objective at the result, its neighbours re-paired there
    Xd = np.matmul(A, q)
    ia, ib = _pair(Y.trees, Xd), _back_pair(Xd, Y)
    d_a = Xd - np.take_along_axis(Y.pts, ia[..., None], 1)
    d_b = np.take_along_axis(Xd, ib[..., None], 1) - Y.pts
    energy = params.lam * ((d_a ** 2).sum(-1).mean(1) + ((d_b ** 2).sum(-1) * Y.w).sum(1))
    energy += params.plane_weight * ((d_a * np.take_along_axis(Nrm, ia[..., None], 1)).sum(-1) ** 2).mean(1)
    energy += params.lam * params.landmark_weight * ((np.einsum("lk,bkc->blc", A_lm, q) - z_lm) ** 2).sum((1, 2))
    if outline is not None:
        energy += outline.energy(q)
    return GaussNewtonResult(q, energy)


class _OutlineTerm:  # noqa: D101 (doc below)
    """The outline Chamfer of the module doc (in the leaf plane), its normal equations per leaf.

    outlines : the template's (n, 2) then each leaf's outline; X (M, 3) the template points
    (z of the template's outline points: that of their nearest template point)."""

    def __init__(self, outlines: list, X: np.ndarray, p: np.ndarray, params: FitParams):
        self.w = params.lam * params.outline_weight
        BT = np.asarray(outlines[0], np.float64).reshape(-1, 2)
        self.on = bool(self.w > 0 and len(BT) >= 3 and len(X))
        if not self.on:
            return
        zt = X[cKDTree(X[:, :2]).query(BT)[1], 2]
        self.A_o = mls_weights(p, np.column_stack([BT, zt]), params.sigma, params.reg)  # (n, K)
        self.H_oo = self.A_o.T @ self.A_o / len(BT)
        leaf = [np.asarray(o, np.float64).reshape(-1, 2) for o in outlines[1:]]
        self.use = np.array([len(o) >= 3 for o in leaf])
        self.Y = _Padded([o if len(o) >= 3 else np.zeros((0, 2)) for o in leaf])
        self.E_xy = np.diag([1.0, 1.0, 0.0])

    def normal_equations(self, q: np.ndarray):
        """(dH (B, 3K, 3K), dg (B, 3K)) of the outline term at targets q (B, K, 3)."""
        B, K = q.shape[:2]
        if not self.on or not self.use.any():
            return 0.0, 0.0
        A_o = self.A_o
        Xo = np.matmul(A_o, q[:, :, :2])                 # (B, n, 2)
        io = _pair(self.Y.trees, Xo)
        Yi = np.take_along_axis(self.Y.pts, io[..., None], 1)
        ic = _back_pair(Xo, self.Y)
        Ac = A_o[ic] * self.Y.w[..., None]
        H_o = self.H_oo[None] + np.matmul(A_o[ic].transpose(0, 2, 1), Ac)
        g_o = np.matmul(A_o.T, Yi) / len(A_o) + np.matmul(Ac.transpose(0, 2, 1), self.Y.pts)
        m = self.use.astype(np.float64)
        dH = self.w * m[:, None, None] * _kron3(H_o, self.E_xy)
        dg = self.w * m[:, None] * np.concatenate([g_o, np.zeros((B, K, 1))], -1).reshape(B, -1)
        return dH, dg

    def energy(self, q: np.ndarray) -> np.ndarray:
        """(B,) the outline term's value at targets q (B, K, 3) (0 for a leaf without one)."""
        if not self.on or not self.use.any():
            return np.zeros(len(q))
        Xo = np.matmul(self.A_o, q[:, :, :2])
        d_o = Xo - np.take_along_axis(self.Y.pts, _pair(self.Y.trees, Xo)[..., None], 1)
        d_c = np.take_along_axis(Xo, _back_pair(Xo, self.Y)[..., None], 1) - self.Y.pts
        e = (d_o ** 2).sum(-1).mean(1) + ((d_c ** 2).sum(-1) * self.Y.w).sum(1)
        return self.w * self.use * e
