"""The paper's optimisation of the target control points: Adam on the depth + Chamfer loss
(LeafFit Sec. "Leaf Registration using Moving Least Squares", Parameter settings: 200 steps,
lr 7e-3, lambda 0.7), kept exactly as the reference (``FitParams.paper()``, ``convert
--paper-fit``); the default fit solves the same problem by Gauss-Newton
(:mod:`leaffit_usd.fit.gauss_newton`).

* ``L_depth``: mean squared difference of the depth maps (``splats.render``, orthographic, in
  the target's PCA-aligned view, looking down its -Z) of the deformed template Gaussians and of
  the target Gaussians, over the pixels where both are foreground (alpha > ``fg_alpha``);
* ``L_chamfer``: symmetric Chamfer distance with squared distances (paper Eq.), template units.

The template's MLS weights (``fit.mls``, affine) are precomputed once: the deformed centres are
``A @ q`` and each deformed Gaussian's covariance is ``J cov J^T`` with the MLS Jacobian
``J = sum_k q_k (dA_k/dv)^T`` (also linear in q). Each leaf is represented by at most
``max_points`` Gaussians (farthest point sampling), template and target alike; pixels the subset
leaves uncovered are outside Omega. All leaves are optimised at once in one atlas image
(independent problems; Adam is per-coordinate, so batching does not couple them). ~60 ms per
step for 13 leaves x 1,024 Gaussians, 64^2 px, one torch thread.

Frames: every leaf's points in its own local frame (petiole base at the origin, +Z its normal),
template units (the leaf's uniform scale divided out).
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial import cKDTree

from leaffit_usd.fit.mls import mls_weights
from leaffit_usd.fit.params import FitParams
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.render import render_orthographic


def start_index(points: np.ndarray) -> int:
    """FPS start: the point nearest to the local origin (the petiole base): deterministic and
    comparable across leaves."""
    return int(np.argmin((np.asarray(points) ** 2).sum(1))) if len(points) else 0


class Covariances:
    """``covs[idx]`` : (len(idx), 3, 3) float64 covariances of the Gaussians ``idx`` of a cloud
    (working frame), computed on demand; equal to ``cloud.covariances()[idx]``."""

    def __init__(self, cloud: GaussianCloud):
        self.cloud = cloud

    def __getitem__(self, idx) -> np.ndarray:
        return self.cloud.subset(np.asarray(idx, np.int64)).covariances().astype(np.float64)



def leaf_gaussians(lf, n: int, covs_working: "Covariances", opac: np.ndarray):
    """At most n of the leaf's Gaussians (FPS), template units, leaf local frame: centres (n, 3),
    covariances (n, 3, 3), opacities (n,). The covariances are the Gaussians' own (widening
    them to close the gaps of the subset blurs the depth maps, and biases them where the blade
    is tilted in the view: measured worse on the benchmark)."""
    Q = lf.local / lf.scale
    sel = farthest_point_sampling(Q, n, start=start_index(Q)) if len(Q) > n else np.arange(len(Q))
    R = lf.frame[:3, :3]
    cov = np.einsum("ji,njk,kl->nil", R, covs_working[lf.gaussians[sel]], R) / lf.scale**2
    pts = Q[sel]
    return pts, cov, opac[lf.gaussians[sel]]



def mls_jacobian_weights(p: np.ndarray, v: np.ndarray, sigma: float, reg: float) -> np.ndarray:
    """dA/dv : (V, K, 3) float64 by central differences of ``mls_weights`` (step 1e-4 sigma)."""
    h = 1e-4 * sigma
    out = np.empty((len(v), len(p), 3))
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        out[:, :, a] = (mls_weights(p, v + e, sigma, reg) - mls_weights(p, v - e, sigma, reg)) / (2 * h)
    return out



def optimize_adam(T, leaves: list, p: np.ndarray, q0: np.ndarray, means, covs, opac,
              params: FitParams) -> np.ndarray:
    """Adam on the target control points of ``leaves`` (B of them) at once. Returns (B, K, 3)."""
    dt = torch.float32
    B, K = len(leaves), len(p)
    S = int(-(-params.image_size // 16) * 16)      # slots aligned to every tile size
    X, Xcov, Xop = leaf_gaussians(T, params.max_points, covs, opac)
    A = torch.tensor(mls_weights(p, X, params.sigma, params.reg), dtype=dt)          # (M, K)
    dA = torch.tensor(mls_jacobian_weights(p, X, params.sigma, params.reg), dtype=dt)  # (M, K, 3)
    Xcov_t = torch.tensor(Xcov, dtype=dt)
    Xop_t = torch.tensor(Xop, dtype=dt)
    M = len(X)

    # targets: Chamfer points, depth maps, per-leaf pixel frames
    tgt_pts, tgt_n, pix = [], [], []
    all_m, all_c, all_o = [], [], []
    for b, lf in enumerate(leaves):
        Y, Ycov, Yop = leaf_gaussians(lf, params.max_points, covs, opac)
        tgt_pts.append(Y)
        tgt_n.append(len(Y))
        lo, hi = Y[:, :2].min(0), Y[:, :2].max(0)
        ctr = 0.5 * (lo + hi)
        px = max(float((hi - lo).max()) * 1.2 / S, 1e-9)   # 10 % margin each side
        org = ctr - 0.5 * S * px                            # (xmin, ymin) of this leaf's image
        pix.append((org, px))
        m, c = to_atlas(torch.tensor(Y, dtype=dt), torch.tensor(Ycov, dtype=dt), org, px, b, S)
        all_m.append(m)
        all_c.append(c)
        all_o.append(torch.tensor(Yop, dtype=dt))
    with torch.no_grad():
        ones = torch.ones(sum(tgt_n), 1, dtype=dt)
        tr = render_orthographic(torch.cat(all_m), torch.cat(all_c), ones, torch.cat(all_o),
                                 B * S, S, (0.0, float(B * S), 0.0, float(S)))
    d_tgt = tr.depth
    fg_tgt = tr.alpha > params.fg_alpha
    nmax = max(tgt_n)
    Ypad = torch.zeros(B, nmax, 3, dtype=dt)
    ymask = torch.zeros(B, nmax, dtype=dt)
    for b, Y in enumerate(tgt_pts):
        Ypad[b, :len(Y)] = torch.tensor(Y, dtype=dt)
        Ypad[b, len(Y):] = torch.tensor(Y[0], dtype=dt)
        ymask[b, :len(Y)] = 1.0
    ycount = ymask.sum(1)
    tgt_trees = [cKDTree(Y) for Y in tgt_pts]

    orgs = torch.tensor(np.stack([o for o, _ in pix]), dtype=dt)         # (B, 2)
    pxs = torch.tensor([s for _, s in pix], dtype=dt)                     # (B,)
    offs = torch.arange(B, dtype=dt) * S

    q = torch.tensor(q0, dtype=dt, requires_grad=True)
    optim = Adam(q, lr=params.lr)
    op_rep = Xop_t.repeat(B)
    ones = torch.ones(B * M, 1, dtype=dt)
    bounds = (0.0, float(B * S), 0.0, float(S))
    for step in range(params.steps):
        q.grad = None
        Xd = torch.einsum("mk,bkc->bmc", A, q)                              # (B, M, 3)
        J = torch.einsum("bka,mkc->bmac", q, dA)                             # (B, M, 3, 3)
        cov_d = J @ Xcov_t[None] @ J.transpose(-1, -2)
        # atlas (pixel) coordinates for the whole batch
        sc = (1.0 / pxs)[:, None]
        mx = (Xd[..., 0] - orgs[:, None, 0]) * sc + offs[:, None]
        my = (Xd[..., 1] - orgs[:, None, 1]) * sc
        m_atlas = torch.stack([mx, my, Xd[..., 2]], -1).reshape(-1, 3)
        D = torch.diag_embed(torch.stack([sc.expand(B, 1)[:, 0], sc[:, 0],
                                          torch.ones(B, dtype=dt)], -1))       # (B, 3, 3)
        c_atlas = (D[:, None] @ cov_d @ D[:, None]).reshape(-1, 3, 3)
        r = render_orthographic(m_atlas, c_atlas, ones, op_rep, B * S, S, bounds)
        omega = (fg_tgt & (r.alpha > params.fg_alpha)).to(dt)
        diff = (r.depth - d_tgt) ** 2 * omega
        # per-leaf mean over its foreground pixels, summed over leaves
        per_leaf_px = omega.reshape(S, B, S).sum((0, 2)).clamp_min(1.0)
        l_depth = (diff.reshape(S, B, S).sum((0, 2)) / per_leaf_px).sum()
        # Chamfer: nearest neighbours found exactly (kd-trees, no grad); the loss through the
        # gathered pairs has the same value and gradient as min over all pairs
        nn_t, nn_j = nearest_pairs(Xd.detach().numpy(), tgt_pts, tgt_trees)
        l_t = ((Xd - torch.gather(Ypad, 1, nn_t[..., None].expand(-1, -1, 3))) ** 2).sum(-1).mean(1)
        l_j = (((torch.gather(Xd, 1, nn_j[..., None].expand(-1, -1, 3)) - Ypad) ** 2).sum(-1)
               * ymask).sum(1) / ycount
        l_cham = (l_t + l_j).sum()
        loss = l_depth + params.lam * l_cham
        loss.backward()
        optim.step()
        if not torch.isfinite(q).all():
            break
    return q.detach().double().numpy()




class Adam:
    """Adam (Kingma & Ba 2015) on one tensor, the update of ``torch.optim.Adam`` with its defaults
    (betas 0.9/0.999, eps 1e-8, no weight decay), written out because constructing
    ``torch.optim.Adam`` imports torch._dynamo (~2 s of CPU per process). Tested equal to it."""

    def __init__(self, param, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        self.p, self.lr, self.b1, self.b2, self.eps = param, lr, betas[0], betas[1], eps
        self.m = torch.zeros_like(param)
        self.v = torch.zeros_like(param)
        self.t = 0

    @torch.no_grad()
    def step(self) -> None:
        g = self.p.grad
        self.t += 1
        self.m.mul_(self.b1).add_(g, alpha=1 - self.b1)
        self.v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
        bc1 = 1 - self.b1 ** self.t
        bc2 = 1 - self.b2 ** self.t
        denom = (self.v.sqrt() / math.sqrt(bc2)).add_(self.eps)
        self.p.addcdiv_(self.m, denom, value=-self.lr / bc1)



def nearest_pairs(X: np.ndarray, tgt_pts: list, tgt_trees: list):
    """Nearest-neighbour indices both ways. X : (B, M, 3) deformed template points; tgt_pts[b] :
    (n_b, 3). Returns nn_t (B, M) index into target b, nn_j (B, nmax) index into X[b] (0 for
    padding rows)."""
    B, M = X.shape[:2]
    nmax = max(len(y) for y in tgt_pts)
    nn_t = np.empty((B, M), np.int64)
    nn_j = np.zeros((B, nmax), np.int64)
    for b in range(B):
        nn_t[b] = tgt_trees[b].query(X[b], k=1)[1]
        nn_j[b, :len(tgt_pts[b])] = cKDTree(X[b]).query(tgt_pts[b], k=1)[1]
    return torch.from_numpy(nn_t), torch.from_numpy(nn_j)



def to_atlas(m, c, org, px, b, S):
    """Leaf local (template units) -> atlas pixel frame of slot b (x in [b S, (b+1) S))."""
    sc = 1.0 / px
    mm = torch.stack([(m[:, 0] - float(org[0])) * sc + b * S, (m[:, 1] - float(org[1])) * sc,
                      m[:, 2]], -1)
    D = torch.diag(torch.tensor([sc, sc, 1.0], dtype=m.dtype))
    return mm, D @ c @ D
