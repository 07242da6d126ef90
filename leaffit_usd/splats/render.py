"""The ONE CPU Gaussian-splat renderer: orthographic, differentiable (torch), tiled.

Used by the fit (depth maps of leaves in their PCA-aligned view), the mesh texture bake (front and
back of the template leaf) and edit/retarget (silhouettes + depth).

Convention (owned here):

* The inputs are in a **view frame**: the camera looks down -Z from +Z (``from_below=False``)
  or up +Z from -Z (``from_below=True``). The image covers ``bounds = (xmin, xmax, ymin, ymax)``
  of the view frame's xy plane: pixel ``(row r, col c)`` has its centre at
  ``x = xmin + (c + 0.5) * (xmax - xmin) / W``, ``y = ymax - (r + 0.5) * (ymax - ymin) / H``
  (row 0 = top = ymax). The same pixel sees the same (x, y) from both sides, so a front and a
  back image of a leaf are registered pixel for pixel (the back image is *not* mirrored).
* Compositing is the 3DGS rasteriser's (Kerbl et al. 2023), front to back:
  2D covariance = the xy block of the 3D covariance (orthographic projection), in pixels,
  plus ``dilation`` px^2 on the diagonal (3DGS low-pass, 0.3); per pixel
  ``alpha_i = min(0.99, o_i exp(-0.5 d^T S_i^-1 d))``, zeroed below 1/255;
  ``T_i = prod_{k<i} (1 - alpha_k)`` in depth order (nearest first);
  ``color = sum_i T_i alpha_i c_i + T_final * background``, ``alpha = 1 - T_final``.
  Differences from the CUDA rasteriser: no early stop at T < 1e-4 (contributions below 1e-4 are
  kept, which only makes it exact and smooth), global depth sort of centres as in 3DGS.
* ``depth`` is the composited **view-frame z coordinate** (not a distance), normalised by the
  accumulated alpha: ``sum_i T_i alpha_i z_i / alpha`` where ``alpha > DEPTH_ALPHA_MIN``, else 0.
  Per-Gaussian depth is the centre's z (as 3DGS).

Speed: Gaussians are binned into 16x16-pixel tiles by their 1/255 cut-off radius (3DGS's
``ceil(3 sigma)`` box would be larger); each tile composites only its own Gaussians, vectorised over
tiles in chunks bounded by ``max_elements`` (memory). Gradients flow to ``means``, ``cov``,
``colors`` and ``opacities`` (the binning is done under ``no_grad`` and does not need them).

For several small images (e.g. one per leaf) lay them side by side in one call: offset each
group's x by a multiple of its width; the tiling keeps them independent.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from leaffit_usd.errors import ParameterError

TILE = 16
ALPHA_MIN = 1.0 / 255.0      # 3DGS: contributions below are skipped
ALPHA_MAX = 0.99             # 3DGS: clamp, so T never reaches 0 through one Gaussian
DEPTH_ALPHA_MIN = 1e-4       # depth is normalised only where the pixel is covered at all
DILATION = 0.3               # px^2, 3DGS's screen-space low-pass filter


class RenderResult(NamedTuple):
    """One rendered image.

    color : (H, W, 3) composited over ``background``
    depth : (H, W) view-frame z of what is seen (alpha-normalised), 0 where ``alpha <= 1e-4``
    alpha : (H, W) accumulated opacity in [0, 1)
    Torch tensors from :func:`render_orthographic`, float32 numpy arrays from
    :func:`render_orthographic_np`.
    """

    color: object
    depth: object
    alpha: object


def _check(name, x, shape_tail, n=None):
    if x.ndim != len(shape_tail) + 1 or tuple(x.shape[1:]) != tuple(shape_tail):
        raise ParameterError(name, f"shape (N, {', '.join(map(str, shape_tail))})".replace(", )", ")"),
                             tuple(x.shape))
    if n is not None and x.shape[0] != n:
        raise ParameterError(name, f"{n} rows (one per Gaussian)", x.shape[0])


def _validate(means, cov, colors, opacities, width, height, bounds):
    _check("means", means, (3,))
    n = means.shape[0]
    _check("cov", cov, (3, 3), n)
    _check("colors", colors, (colors.shape[1] if colors.ndim == 2 else 3,), n)
    if opacities.ndim != 1 or opacities.shape[0] != n:
        raise ParameterError("opacities", f"shape ({n},)", tuple(opacities.shape))
    for nm, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or v <= 0:
            raise ParameterError(nm, "a positive integer", v)
    if len(bounds) != 4:
        raise ParameterError("bounds", "(xmin, xmax, ymin, ymax)", bounds)
    xmin, xmax, ymin, ymax = (float(b) for b in bounds)
    if not (np.isfinite([xmin, xmax, ymin, ymax]).all() and xmax > xmin and ymax > ymin):
        raise ParameterError("bounds", "finite (xmin, xmax, ymin, ymax) with xmax > xmin, ymax > ymin",
                             bounds)
    return xmin, xmax, ymin, ymax


def render_orthographic(means, cov, colors, opacities, width: int, height: int, bounds,
                        background=None, from_below: bool = False, dilation: float = DILATION,
                        max_elements: int = 1 << 23) -> RenderResult:
    """Render Gaussians orthographically along the view frame's Z axis (differentiable).

    means : (N, 3) float tensor, view frame
    cov : (N, 3, 3) float tensor, view frame (symmetric positive semi-definite)
    colors : (N, C) float tensor (C = 3 for RGB; any C works, e.g. features or labels one-hot)
    opacities : (N,) float tensor in [0, 1]
    width, height : image size in pixels
    bounds : (xmin, xmax, ymin, ymax), view-frame units covered by the image
    background : (C,) or None (zeros)
    from_below : look up +Z from -Z instead of down -Z (same pixel layout, see module doc)
    dilation : px^2 added to the 2D covariance (3DGS: 0.3)
    max_elements : bound on (pixels x Gaussians) per vectorised chunk (memory ~ 40 B each)

    Returns :class:`RenderResult` of tensors with the dtype of ``means``.
    """
    xmin, xmax, ymin, ymax = _validate(means, cov, colors, opacities, width, height, bounds)
    dtype, dev = means.dtype, means.device
    W, H = int(width), int(height)
    C = colors.shape[1]
    sx, sy = (xmax - xmin) / W, (ymax - ymin) / H
    n = means.shape[0]
    bg = torch.zeros(C, dtype=dtype, device=dev) if background is None else \
        torch.as_tensor(background, dtype=dtype, device=dev).reshape(C)

    # screen space: u = column (pixel centres at integers), v = row
    u = (means[:, 0] - xmin) / sx - 0.5
    v = (ymax - means[:, 1]) / sy - 0.5
    a = cov[:, 0, 0] / (sx * sx) + dilation
    b = -cov[:, 0, 1] / (sx * sy)                   # the v axis points down: sign flips
    c = cov[:, 1, 1] / (sy * sy) + dilation
    det = (a * c - b * b).clamp_min(1e-12)
    ia, ib, ic = c / det, -b / det, a / det         # conic (inverse 2D covariance)
    z = means[:, 2]

    n_tx, n_ty = -(-W // TILE), -(-H // TILE)
    n_tiles = n_tx * n_ty
    with torch.no_grad():
        op = opacities.detach().clamp(0.0, 1.0)
        # radius where o * exp(-0.5 r^2 / lambda_max) = 1/255; beyond it alpha < 1/255
        mid = 0.5 * (a + c).detach()
        lam = mid + torch.sqrt((mid * mid - det.detach()).clamp_min(0.0))
        k2 = 2.0 * torch.log((op * 255.0).clamp_min(1.0))
        rad = torch.sqrt(lam * k2)
        ud, vd = u.detach(), v.detach()
        tx0 = torch.floor((ud - rad + 0.5) / TILE).clamp(0, n_tx - 1).long()
        tx1 = torch.floor((ud + rad + 0.5) / TILE).clamp(0, n_tx - 1).long()
        ty0 = torch.floor((vd - rad + 0.5) / TILE).clamp(0, n_ty - 1).long()
        ty1 = torch.floor((vd + rad + 0.5) / TILE).clamp(0, n_ty - 1).long()
        visible = (op > ALPHA_MIN) & (ud + rad > -0.5) & (ud - rad < W - 0.5) \
            & (vd + rad > -0.5) & (vd - rad < H - 0.5) & torch.isfinite(ud) & torch.isfinite(vd)
        idx = torch.nonzero(visible).flatten()
        nx = (tx1 - tx0 + 1)[idx]
        ny = (ty1 - ty0 + 1)[idx]
        cnt = nx * ny
        gid = torch.repeat_interleave(idx, cnt)                    # pair -> Gaussian
        start = torch.cumsum(cnt, 0) - cnt
        local = torch.arange(gid.numel(), device=dev) - torch.repeat_interleave(start, cnt)
        nxr = torch.repeat_interleave(nx, cnt)
        tile = (ty0[gid] + local // nxr) * n_tx + (tx0[gid] + local % nxr)
        # depth order, nearest first: larger z is nearer from above
        order_key = -z.detach() if not from_below else z.detach()
        rank = torch.empty(n, dtype=torch.long, device=dev)
        rank[torch.argsort(order_key, stable=True)] = torch.arange(n, device=dev)
        key = tile * n + rank[gid]
        srt = torch.argsort(key)
        gid, tile = gid[srt], tile[srt]
        per_tile = torch.bincount(tile, minlength=n_tiles)
        tstart = torch.cumsum(per_tile, 0) - per_tile

    color_img = torch.zeros(n_ty, n_tx, TILE, TILE, C, dtype=dtype, device=dev)
    depth_img = torch.zeros(n_ty, n_tx, TILE, TILE, dtype=dtype, device=dev)
    alpha_img = torch.zeros(n_ty, n_tx, TILE, TILE, dtype=dtype, device=dev)
    color_img = color_img.reshape(n_tiles, TILE * TILE, C)
    depth_img = depth_img.reshape(n_tiles, TILE * TILE)
    alpha_img = alpha_img.reshape(n_tiles, TILE * TILE)
    tr_img = torch.ones(n_tiles, TILE * TILE, dtype=dtype, device=dev)

    # pixel centres of every tile (tile-local -> global u, v)
    py, px = torch.meshgrid(torch.arange(TILE, device=dev), torch.arange(TILE, device=dev),
                            indexing="ij")
    px, py = px.reshape(-1).to(dtype), py.reshape(-1).to(dtype)

    active = torch.nonzero(per_tile).flatten()
    if active.numel():
        # group active tiles by their Gaussian count so padding stays small
        counts = per_tile[active]
        act_order = torch.argsort(counts)
        active, counts = active[act_order], counts[act_order]
        P = TILE * TILE
        i = 0
        outs = []
        while i < active.numel():
            # grow the chunk while memory allows (counts are ascending: gmax = last count)
            j = i + 1
            while j < active.numel():
                g = int(counts[j].item())
                if (j - i + 1) * P * g > max_elements:
                    break
                j += 1
            tiles = active[i:j]
            gmax = int(counts[j - 1].item())
            outs.append(_composite_chunk(tiles, gmax, gid, tstart, per_tile,
                                         u, v, ia, ib, ic, z, colors, opacities, px, py,
                                         n_tx, dtype))
            i = j
        tiles_all = torch.cat([o[0] for o in outs])
        color_img = color_img.index_copy(0, tiles_all, torch.cat([o[1] for o in outs]))
        depth_img = depth_img.index_copy(0, tiles_all, torch.cat([o[2] for o in outs]))
        alpha_img = alpha_img.index_copy(0, tiles_all, torch.cat([o[3] for o in outs]))
        tr_img = tr_img.index_copy(0, tiles_all, 1.0 - torch.cat([o[3] for o in outs]))

    color_img = color_img + tr_img[..., None] * bg
    covered = alpha_img > DEPTH_ALPHA_MIN
    depth_img = torch.where(covered, depth_img / torch.where(covered, alpha_img,
                                                              torch.ones_like(alpha_img)),
                            torch.zeros_like(depth_img))

    def untile(x):
        x = x.reshape(n_ty, n_tx, TILE, TILE, *x.shape[2:])
        x = x.transpose(1, 2).reshape(n_ty * TILE, n_tx * TILE, *x.shape[4:])
        return x[:H, :W]

    return RenderResult(untile(color_img), untile(depth_img), untile(alpha_img))


def _composite_chunk(tiles, gmax, gid, tstart, per_tile, u, v, ia, ib, ic, z,
                     colors, opacities, px, py, n_tx, dtype):
    """Composite the tiles ``tiles`` (T,), each with up to ``gmax`` Gaussians, front to back."""
    T = tiles.numel()
    dev = u.device
    with torch.no_grad():
        # padded (T, gmax) Gaussian index table; -1 = padding
        cnt = per_tile[tiles]
        k = torch.arange(gmax, device=dev)[None, :]
        valid = k < cnt[:, None]
        pair = (tstart[tiles][:, None] + k).clamp_max(gid.numel() - 1)
        g = torch.where(valid, gid[pair], torch.zeros_like(pair))
    ox = (tiles % n_tx).to(dtype) * TILE
    oy = (tiles // n_tx).to(dtype) * TILE
    du = (ox[:, None] + px[None, :])[:, :, None] - u[g][:, None, :]          # (T, P, G)
    dv = (oy[:, None] + py[None, :])[:, :, None] - v[g][:, None, :]
    power = -0.5 * (ia[g][:, None, :] * du * du + ic[g][:, None, :] * dv * dv) \
        - ib[g][:, None, :] * du * dv
    op = torch.where(valid, opacities[g], torch.zeros_like(opacities[g]))
    alpha = (op[:, None, :] * torch.exp(power.clamp_max(0.0))).clamp_max(ALPHA_MAX)
    alpha = torch.where(alpha < ALPHA_MIN, torch.zeros_like(alpha), alpha)
    one_minus = 1.0 - alpha
    trans = torch.cumprod(torch.cat([torch.ones_like(one_minus[..., :1]), one_minus[..., :-1]], -1), -1)
    w = trans * alpha                                                          # (T, P, G)
    col = torch.einsum("tpg,tgc->tpc", w, colors[g])
    dep = torch.einsum("tpg,tg->tp", w, z[g])
    acc = w.sum(-1)
    return tiles, col, dep, acc


def render_orthographic_np(means, cov, colors, opacities, width: int, height: int, bounds,
                           background=None, from_below: bool = False,
                           dilation: float = DILATION) -> RenderResult:
    """Numpy in / numpy out wrapper of :func:`render_orthographic` (float32, no gradients).

    Arguments as :func:`render_orthographic` but numpy arrays; returns float32 arrays.
    """
    with torch.no_grad():
        t = lambda x: torch.as_tensor(np.ascontiguousarray(x, np.float32))  # noqa: E731
        r = render_orthographic(t(means), t(cov), t(colors), t(opacities), width, height, bounds,
                                background=None if background is None else t(background),
                                from_below=from_below, dilation=dilation)
    return RenderResult(r.color.numpy(), r.depth.numpy(), r.alpha.numpy())


def fit_bounds(means_xy, width: int, height: int, margin: float = 0.05):
    """Bounds ``(xmin, xmax, ymin, ymax)`` enclosing ``means_xy`` (N, 2+) with square pixels.

    The box is grown by ``margin`` (fraction of its larger side) and to the image's aspect ratio.
    """
    m = np.asarray(means_xy, np.float64)[:, :2]
    if len(m) == 0:
        return (-1.0, 1.0, -1.0 * height / width, 1.0 * height / width)
    lo, hi = m.min(0), m.max(0)
    ctr = 0.5 * (lo + hi)
    px = max((hi[0] - lo[0]) * (1 + 2 * margin) / width, (hi[1] - lo[1]) * (1 + 2 * margin) / height,
             1e-9 / width)
    hx, hy = 0.5 * px * width, 0.5 * px * height
    return (float(ctr[0] - hx), float(ctr[0] + hx), float(ctr[1] - hy), float(ctr[1] + hy))


def render_reference(means, cov, colors, opacities, width, height, bounds, background=None,
                     from_below=False, dilation=DILATION) -> RenderResult:
    """Slow float64 numpy reference of :func:`render_orthographic` (every pixel x every Gaussian).

    For tests only; same conventions and formula, no tiling.
    """
    means = np.asarray(means, np.float64)
    cov = np.asarray(cov, np.float64)
    colors = np.asarray(colors, np.float64)
    op = np.asarray(opacities, np.float64)
    xmin, xmax, ymin, ymax = bounds
    sx, sy = (xmax - xmin) / width, (ymax - ymin) / height
    order = np.argsort(means[:, 2] if from_below else -means[:, 2], kind="stable")
    cc, rr = np.meshgrid(np.arange(width), np.arange(height))
    x = xmin + (cc + 0.5) * sx
    y = ymax - (rr + 0.5) * sy
    C = colors.shape[1]
    col = np.zeros((height, width, C))
    dep = np.zeros((height, width))
    T = np.ones((height, width))
    J = np.diag([1 / sx, -1 / sy])
    for i in order:
        S = J @ cov[i, :2, :2] @ J.T + dilation * np.eye(2)
        Si = np.linalg.inv(S)
        d = np.stack([(x - means[i, 0]) / sx, -(y - means[i, 1]) / sy], -1)
        power = -0.5 * np.einsum("hwi,ij,hwj->hw", d, Si, d)
        a = np.minimum(ALPHA_MAX, op[i] * np.exp(np.minimum(power, 0.0)))
        a = np.where(a < ALPHA_MIN, 0.0, a)
        w = T * a
        col += w[..., None] * colors[i]
        dep += w * means[i, 2]
        T = T * (1 - a)
    alpha = 1 - T
    bg = np.zeros(C) if background is None else np.asarray(background, np.float64)
    col += T[..., None] * bg
    covered = alpha > DEPTH_ALPHA_MIN
    dep = np.where(covered, dep / np.where(covered, alpha, 1.0), 0.0)
    return RenderResult(col, dep, alpha)
