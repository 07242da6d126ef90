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
  ``antialias=True`` is Mip-Splatting's 2D filter (Yu et al. 2024): the opacity is scaled by
  ``sqrt(det S / det(S + dilation I))`` (S the undilated 2D covariance, px^2), so the dilation
  spreads a splat's mass without adding to it and a sub-pixel splat covers what its size says.
  Without it, 3DGS's dilation turns every sub-pixel splat into a ~0.55 px blob of its full
  opacity, and a surface covered by many of them renders wider as the splats get denser.
  Differences from the CUDA rasteriser: no early stop at T < 1e-4 (contributions below 1e-4 are
  kept, which only makes it exact and smooth), global depth sort of centres as in 3DGS.
* ``depth`` is the composited **view-frame z coordinate** (not a distance), normalised by the
  accumulated alpha: ``sum_i T_i alpha_i z_i / alpha`` where ``alpha > DEPTH_ALPHA_MIN``, else 0.
  Per-Gaussian depth is the centre's z (as 3DGS).

Speed: Gaussians are binned into square tiles (4, 8 or 16 px, chosen from the splats' median
footprint) by their 1/255 cut-off radius (3DGS's ``ceil(3 sigma)`` box would be larger); each tile
composites only its own Gaussians, vectorised over tiles in chunks bounded by ``max_elements``
(memory); the Gaussian exponents of a tile are one matmul of pixel features [x^2, y^2, xy, x, y, 1]
with per-Gaussian coefficients; compositing has a hand-written backward (``_Composite``).
Gradients flow to ``means``, ``cov``, ``colors`` and ``opacities`` (the binning is done under
``no_grad`` and does not need them). Measured (1 torch thread, CPU time, forward + backward):
2,000 Gaussians at 64^2 px ~25 ms, 7,000 at 128^2 ~85 ms, 20,000 at 256^2 ~0.25 s (the first
tiled version was 1.5-2.5x slower). On a shared, oversubscribed
machine call ``torch.set_num_threads(1)``: torch's OpenMP pool turns each small op into a
multi-millisecond stall there (measured 3 ms -> 110 ms for a 6-Gaussian render).

For several small images (e.g. one per leaf) lay them side by side in one call: offset each
group's x by a multiple of its width; the tiling keeps them independent.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from leaffit_usd.determinism import deterministic_torch
from leaffit_usd.errors import ParameterError

ALPHA_MIN = 1.0 / 255.0      # 3DGS: contributions below are skipped
LOG_ALPHA_MIN = math.log(ALPHA_MIN)
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
                        tile: int | None = None, max_elements: int = 1 << 23,
                        antialias: bool = False) -> RenderResult:
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
    tile : tile side in pixels (4, 8 or 16); None = chosen from the Gaussians' median footprint
        (small splats -> small tiles: the work is ~ (tile + 2 radius)^2 per Gaussian)
    max_elements : bound on (pixels x Gaussians) per vectorised chunk (memory ~ 40 B each)
    antialias : Mip-Splatting's 2D filter: opacities scaled by sqrt(det S / det(S + dilation))
        (module doc), so the render of a surface does not widen as its splats shrink

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
    if antialias:
        det0 = ((a - dilation) * (c - dilation) - b * b).clamp_min(1e-12)
        opacities = opacities * torch.sqrt(det0 / det)

    bins = _bin_tiles(u, v, a, c, det, z, opacities, W, H, tile, from_below)
    ts, n_tx, n_ty = bins.ts, bins.n_tx, bins.n_ty
    P = ts * ts
    # pixel features of a tile, tile-local coordinates: [x^2, y^2, xy, x, y, 1]
    py, px = torch.meshgrid(torch.arange(ts, device=dev, dtype=dtype),
                            torch.arange(ts, device=dev, dtype=dtype), indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    feats = torch.stack([px * px, py * py, px * py, px, py, torch.ones_like(px)], -1)   # (P, 6)
    # values composited per Gaussian: colour channels, z, 1 (accumulated alpha)
    vals = torch.cat([colors, z[:, None], torch.ones_like(z)[:, None]], 1)               # (N, C+2)
    log_op = torch.log(opacities.clamp_min(1e-30))

    out = torch.zeros(n_tx * n_ty, P, C + 2, dtype=dtype, device=dev)
    active = torch.nonzero(bins.per_tile).flatten()
    if active.numel():
        _composite_active(out, active, bins, max_elements, u, v, ia, ib, ic, log_op, vals, feats)

    out = out.reshape(n_ty, n_tx, ts, ts, C + 2).transpose(1, 2).reshape(n_ty * ts, n_tx * ts, C + 2)
    out = out[:H, :W]
    alpha_img = out[..., C + 1]
    color_img = out[..., :C] + (1.0 - alpha_img)[..., None] * bg
    covered = alpha_img > DEPTH_ALPHA_MIN
    depth_img = torch.where(covered, out[..., C] / torch.where(covered, alpha_img,
                                                                torch.ones_like(alpha_img)),
                            torch.zeros_like(alpha_img))
    return RenderResult(color_img, depth_img, alpha_img)


class _Bins(NamedTuple):
    """Gaussian/tile pairs sorted by tile, then depth (nearest first)."""

    ts: int                  # tile side, pixels
    n_tx: int
    n_ty: int
    gid: torch.Tensor        # (pairs,) Gaussian of each pair
    per_tile: torch.Tensor   # (tiles,) pairs per tile
    tstart: torch.Tensor     # (tiles,) first pair of each tile


def _bin_tiles(u, v, a, c, det, z, opacities, W: int, H: int, tile, from_below: bool) -> _Bins:
    """Assign each visible Gaussian to the tiles its 1/255-alpha footprint touches."""
    n, dev = u.shape[0], u.device
    with torch.no_grad():
        op = opacities.detach().clamp(0.0, 1.0)
        # radius where o * exp(-0.5 r^2 / lambda_max) = 1/255; beyond it alpha < 1/255
        mid = 0.5 * (a + c).detach()
        lam = mid + torch.sqrt((mid * mid - det.detach()).clamp_min(0.0))
        k2 = 2.0 * torch.log((op * 255.0).clamp_min(1.0))
        rad = torch.sqrt(lam * k2)
        if tile is None:
            r_med = float(rad.median()) if n else 0.0
            ts = 4 if r_med <= 2.5 else 8 if r_med <= 6 else 16
        else:
            if tile not in (1, 2, 4, 8, 16, 32):
                raise ParameterError("tile", "one of 1, 2, 4, 8, 16, 32 or None", tile)
            ts = int(tile)
        n_tx, n_ty = -(-W // ts), -(-H // ts)
        n_tiles = n_tx * n_ty
        ud, vd = u.detach(), v.detach()
        tx0 = torch.floor((ud - rad + 0.5) / ts).clamp(0, n_tx - 1).long()
        tx1 = torch.floor((ud + rad + 0.5) / ts).clamp(0, n_tx - 1).long()
        ty0 = torch.floor((vd - rad + 0.5) / ts).clamp(0, n_ty - 1).long()
        ty1 = torch.floor((vd + rad + 0.5) / ts).clamp(0, n_ty - 1).long()
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
        tile_of = (ty0[gid] + local // nxr) * n_tx + (tx0[gid] + local % nxr)
        # depth order, nearest first: larger z is nearer from above
        order_key = -z.detach() if not from_below else z.detach()
        rank = torch.empty(n, dtype=torch.long, device=dev)
        rank[torch.argsort(order_key, stable=True)] = torch.arange(n, device=dev)
        srt = torch.argsort(tile_of * n + rank[gid])
        gid, tile_of = gid[srt], tile_of[srt]
        per_tile = torch.bincount(tile_of, minlength=n_tiles)
        tstart = torch.cumsum(per_tile, 0) - per_tile
    return _Bins(ts, n_tx, n_ty, gid, per_tile, tstart)


def _composite_active(out, active, bins: _Bins, max_elements: int, u, v, ia, ib, ic, log_op, vals,
                      feats) -> None:
    """Composite every active tile into ``out`` (tiles, P, C + 2), in chunks of tiles with
    similar Gaussian counts (so padding stays small). Each chunk is copied into its tiles' rows
    as it is done (``index_copy_``; autograd follows), so only one chunk's values are held at
    a time besides ``out`` (a 2048^2 bake render: ~250 MB less than concatenating them)."""
    P = bins.ts * bins.ts
    counts = bins.per_tile[active]
    act_order = torch.argsort(counts)
    active, counts = active[act_order], counts[act_order].tolist()
    i = 0
    while i < active.numel():
        # grow the chunk while memory allows (counts are ascending: gmax = last count)
        # and, once the chunk is worth a call (>= 64k elements), while the padding it adds
        # stays small (counts within 1.5x of the chunk's first)
        j = i + 1
        while j < active.numel() and (j - i + 1) * P * counts[j] <= max_elements and (
                counts[j] <= 1.5 * counts[i] or (j - i) * P * counts[j - 1] < 65536):
            j += 1
        tiles = active[i:j]
        out.index_copy_(0, tiles, _composite_chunk(tiles, counts[j - 1], bins.ts, bins.n_tx, bins.gid,
                                                   bins.tstart, bins.per_tile, u, v, ia, ib, ic,
                                                   log_op, vals, feats))
        i = j


def _composite_chunk(tiles, gmax, ts, n_tx, gid, tstart, per_tile, u, v, ia, ib, ic, log_op,
                     vals, feats):
    """Composite the tiles ``tiles`` (T,), each with up to ``gmax`` Gaussians, front to back.

    Returns (T, P, C + 2): sum_i T_i alpha_i [colour_i, z_i, 1] per pixel.
    The Gaussian exponent (plus log opacity) is a quadratic form in tile-local pixel
    coordinates, so it is one batched matmul (T, P, 6) @ (T, 6, G).
    """
    T = tiles.numel()
    dev = u.device
    dtype = u.dtype
    with torch.no_grad():
        cnt = per_tile[tiles]
        k = torch.arange(gmax, device=dev)[None, :]
        valid = k < cnt[:, None]                                               # (T, G)
        pair = (tstart[tiles][:, None] + k).clamp_max(gid.numel() - 1)
        g = torch.where(valid, gid[pair], torch.zeros_like(pair))
        ox = ((tiles % n_tx) * ts).to(dtype)[:, None]
        oy = ((tiles // n_tx) * ts).to(dtype)[:, None]
    u0 = u[g] - ox                                                             # (T, G) tile-local
    v0 = v[g] - oy
    a, b, c = ia[g], ib[g], ic[g]
    # -0.5 a (x-u0)^2 - 0.5 c (y-v0)^2 - b (x-u0)(y-v0) + log o
    coef = torch.stack([-0.5 * a, -0.5 * c, -b,
                        a * u0 + b * v0, c * v0 + b * u0,
                        -0.5 * a * u0 * u0 - 0.5 * c * v0 * v0 - b * u0 * v0 + log_op[g]], 1)
    coef = torch.where(valid[:, None, :], coef, torch.tensor(0.0, dtype=dtype, device=dev))
    # padding: constant term -1e4 -> alpha 0
    pad = torch.zeros(1, 6, 1, dtype=dtype, device=dev)
    pad[0, 5, 0] = -1e4
    coef = coef + (~valid)[:, None, :].to(dtype) * pad
    power = feats @ coef                                                       # (T, P, G)
    return _Composite.apply(power, vals[g])                                    # (T, P, C+2)


class _Composite(torch.autograd.Function):
    """Front-to-back alpha compositing with a hand-written backward (the autograd graph of
    exp/clamp/cumprod is ~3x slower on the CPU and keeps more tensors alive).

    power : (T, P, G) Gaussian exponent + log opacity, Gaussians in depth order
    vals : (T, G, V) per-Gaussian values. Returns (T, P, V) = sum_i T_i alpha_i vals_i with
    alpha_i = min(0.99, exp(power_i)), zero where exp(power_i) < 1/255, T_i = prod_{k<i} (1 - alpha_k).

    Backward: with c_k = w_k (vals_k . g), dL/dalpha_i = T_i (vals_i . g) - sum_{k>i} c_k / (1 - alpha_i)
    (the 3DGS rasteriser's back-to-front recursion written as a suffix sum);
    dalpha/dpower = alpha where 1/255 <= alpha < 0.99, else 0.
    """

    @staticmethod
    def forward(ctx, power, vals):
        # exp of very negative arguments takes a slow path (denormals): clamp first; anything
        # below log(1/255) is zeroed anyway
        alpha = torch.exp(power.clamp_min(-20.0)).clamp_max(ALPHA_MAX)
        alpha = torch.where(power < LOG_ALPHA_MIN, torch.zeros_like(alpha), alpha)
        one_minus = 1.0 - alpha
        trans = torch.cumprod(one_minus, -1).div_(one_minus)                  # exclusive product
        w = trans * alpha
        ctx.save_for_backward(alpha, trans, vals)
        return w @ vals

    @staticmethod
    def backward(ctx, g):
        alpha, trans, vals = ctx.saved_tensors
        w = trans * alpha
        d_vals = w.transpose(1, 2) @ g if ctx.needs_input_grad[1] else None
        d_power = None
        if ctx.needs_input_grad[0]:
            vg = g @ vals.transpose(1, 2)                                     # (T, P, G)
            c = w * vg
            suffix = c.sum(-1, keepdim=True) - torch.cumsum(c, -1)            # sum_{k>i} c_k
            d_alpha = trans * vg - suffix / (1.0 - alpha)
            d_power = torch.where(alpha < ALPHA_MAX, d_alpha * alpha, torch.zeros_like(alpha))
        return d_power, d_vals


def render_orthographic_np(means, cov, colors, opacities, width: int, height: int, bounds,
                           background=None, from_below: bool = False,
                           dilation: float = DILATION, antialias: bool = False) -> RenderResult:
    """Numpy in / numpy out wrapper of :func:`render_orthographic` (float32, no gradients).

    Arguments as :func:`render_orthographic` but numpy arrays; returns float32 arrays.
    """
    with torch.no_grad(), deterministic_torch():    # thread-count independent (determinism.py)
        t = lambda x: torch.as_tensor(np.ascontiguousarray(x, np.float32))  # noqa: E731
        r = render_orthographic(t(means), t(cov), t(colors), t(opacities), width, height, bounds,
                                background=None if background is None else t(background),
                                from_below=from_below, dilation=dilation, antialias=antialias)
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
                     from_below=False, dilation=DILATION, antialias=False) -> RenderResult:
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
        S0 = J @ cov[i, :2, :2] @ J.T
        S = S0 + dilation * np.eye(2)
        Si = np.linalg.inv(S)
        o = op[i] * np.sqrt(max(np.linalg.det(S0), 0.0) / np.linalg.det(S)) if antialias else op[i]
        d = np.stack([(x - means[i, 0]) / sx, -(y - means[i, 1]) / sy], -1)
        power = -0.5 * np.einsum("hwi,ij,hwj->hw", d, Si, d)
        a = np.minimum(ALPHA_MAX, o * np.exp(np.minimum(power, 0.0)))
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
