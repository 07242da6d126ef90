"""The pot of a capture whose up direction is known (from the table, or the user's ``--up``), and
the pot's axis when nothing else shows the up direction.

:func:`pot_and_soil`: a circle fitted to the lowest slab of the plant's component (Kasa least
squares, trimmed) that is wide (>= ``min_pot_radius`` x the plant height), round (coverage of
the angles) and thin (small residual) is the pot's foot; the wall is followed upwards ring by
ring while a full circle of Gaussians stays near the expected radius; ``r(h)`` is a
straight-line fit of the ring radii (a truncated cone). The soil is the densest level of
up-facing Gaussians inside the rim; everything inside the rim below it is soil too.

:func:`find_pot_axis`: with no table and no soil disc (:mod:`leaffit_usd.isolate.soil`), the
pot's foot and wall are looked for along 300 directions spread over the sphere, on a 5k-sample;
the axis is the mean of the directions whose wall rises at least ``AXIS_AGREE`` x as high as the
best's (within 30 degrees of it), refined by a pattern search that maximises the samples on the
wall (a thin shell around the fitted ``r(h)``). A plant without a pot gives no direction: no
slab of a trimmed plant is a wide, thin, round ring with a wall rising from it.

Input frame, input units.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from leaffit_usd.geometry.plane import plane_basis
from leaffit_usd.geometry.sampling import position_order_sample
from leaffit_usd.isolate.result import PLANT, POT, SOIL
from leaffit_usd.isolate.shapes import angular_coverage, circle_fit

if TYPE_CHECKING:
    from leaffit_usd.isolate.scene import IsolateParams

log = logging.getLogger("leaffit_usd")
def pot_and_soil(cloud, pts, classes, up, d0, thr, p_: IsolateParams):
    """Find a pot and its soil among the PLANT Gaussians (classes updated in place).

    up : (3,) unit; d0 : ground plane offset (heights h = pts @ up + d0) or None (heights from
    the plant's lowest point); thr : the ground plane's noise threshold (input units).
    Returns the pot (dict: centre on the ground (3,), axis (3,), radii, heights; input frame and
    units) or None.
    """
    plant = np.flatnonzero(classes == PLANT)
    if len(plant) < 100:
        return None
    sel = plant[position_order_sample(pts[plant], p_.sample, p_.seed + 1)]  # free of file order
    h_all = pts[plant] @ up
    base = -d0 if d0 is not None else float(np.quantile(h_all, 0.001))
    hs = pts[sel] @ up - base
    H = float(np.quantile(hs, 0.99))
    if H <= 0:
        return None
    basis = plane_basis(up)
    shape = pot_shape(pts[sel] @ basis, hs, H, thr, p_)
    if shape is None:
        return None
    c, r_of, h_top, step = shape
    # every plant Gaussian: height, radial distance
    hp = h_all - base
    xyp = pts[plant] @ basis
    rp = np.linalg.norm(xyp - c, axis=1)
    is_pot, is_soil, soil_h = pot_wall_and_soil(cloud, plant, hp, xyp, rp, c, r_of, h_top, step,
                                                 H, thr, up, basis)
    classes[plant[is_pot]] = POT
    classes[plant[is_soil]] = SOIL
    r_top = float(r_of(h_top))
    pot = {"center": basis @ c + up * base, "axis": up.copy(), "radius_bottom": float(r_of(0.0)),
           "radius_top": r_top, "height": h_top,
           "soil_height": float("nan") if soil_h is None else soil_h, "plant_height": H}
    log.debug("pot: radius %.4g -> %.4g, height %.4g, soil at %s", pot["radius_bottom"], r_top,
              h_top, soil_h)
    return pot


def stem_base(pts, classes, pot) -> int | None:
    """The stem base: the middle of the lowest PLANT Gaussians inside the pot's rim (index into
    ``pts`` (N, 3), input frame), or None when none is inside. ``pot`` from :func:`pot_and_soil`."""
    plant = np.flatnonzero(classes == PLANT)
    up = np.asarray(pot["axis"], np.float64)
    rel = pts[plant] - np.asarray(pot["center"], np.float64)
    hp = rel @ up
    rp = np.linalg.norm(rel - np.outer(hp, up), axis=1)
    idx = np.flatnonzero(rp < pot["radius_top"])
    if not len(idx):
        return None
    hr = hp[idx]
    lo = float(np.quantile(hr, 0.002))
    band = idx[hr <= lo + 0.01 * pot["plant_height"]]
    med = np.median(pts[plant[band]], axis=0)
    return int(plant[band[np.argmin(np.linalg.norm(pts[plant[band]] - med, axis=1))]])


def pot_shape(xy, hs, H, thr, p_: IsolateParams):
    """The pot's foot circle and wall profile from the samples' in-plane positions (M, 2) and
    heights (M,) above the ground: (centre (2,), r(h) callable, rim height, ring step) or None
    when the lowest slab is not a wide, round, thin circle or no wall rises from it."""
    slab = 0.04 * H
    foot = hs <= slab
    if foot.sum() < 30:
        return None
    c, r, inl = circle_fit(xy[foot])
    res = np.abs(np.linalg.norm(xy[foot] - c, axis=1) - r)
    if not (p_.min_pot_radius * H <= r <= 0.8 * H) or inl.mean() < 0.5 \
            or angular_coverage(xy[foot][inl], c) < 0.6 or np.median(res[inl]) > 0.05 * r:
        return None
    # climb the outer wall ring by ring: the outermost full ring near the previous radius
    step = slab / 2
    rho = np.linalg.norm(xy - c, axis=1)
    rings = [(0.5 * slab, r)]
    r_prev, misses, h = r, 0, slab
    while h < 0.7 * H:
        band = (hs >= h) & (hs < h + step)
        r_bin, cov = r_prev, 0.0
        for _ in range(2):
            near = band & (np.abs(rho - r_bin) <= 0.1 * r_bin)
            if near.sum() < 8:
                break
            r_bin = float(np.quantile(rho[near], 0.7))  # outer surface (inner wall, soil lie inside)
        else:
            tight = band & (np.abs(rho - r_bin) <= 0.05 * r_bin + thr)
            cov = angular_coverage(xy[tight], c)
        if cov >= 0.6:
            rings.append((h + step / 2, r_bin))
            r_prev, misses = r_bin, 0
        else:
            misses += 1
            if misses > 1:
                break
        h += step
    rings = np.array(rings)
    h_top = float(rings[-1, 0] + step / 2)
    if h_top >= 0.7 * H or len(rings) < 3:
        return None
    slope, icpt = np.polyfit(rings[:, 0], rings[:, 1], 1)

    def r_of(hh):
        return icpt + slope * np.clip(hh, 0, h_top)

    return c, r_of, h_top, step


def pot_wall_and_soil(cloud, plant, hp, xyp, rp, c, r_of, h_top, step, H, thr, up, basis):
    """Which plant Gaussians (indices ``plant``, heights ``hp``, in-plane ``xyp``, radial
    distances ``rp``) are the pot's wall and which its soil: (is_pot, is_soil, soil height or
    None). The soil is the densest level of up-facing Gaussians inside the rim, spread over the
    rim's disk; the inner wall between it and the rim (vertical, facing the axis) is pot."""
    r_top = float(r_of(h_top))
    wall_band = 0.06 * r_of(hp) + thr
    below_rim = hp <= h_top + step
    is_pot = below_rim & (np.abs(rp - r_of(hp)) <= wall_band)
    inside = (rp < 0.95 * r_top) & (hp > 0.2 * h_top) & (hp < h_top + 0.1 * H) & ~is_pot
    is_soil = np.zeros(len(plant), bool)
    cand = np.flatnonzero(inside)
    if len(cand) < 20:
        return is_pot, is_soil, None
    nrm = cloud.subset(plant[cand]).shortest_axes()
    flat = np.abs(nrm @ up) > 0.8
    if flat.sum() < 20:
        return is_pot, is_soil, None
    hf = hp[cand[flat]]
    bins = np.arange(hf.min(), hf.max() + step / 4, step / 4)
    if len(bins) < 2:
        return is_pot, is_soil, None
    hist, edges = np.histogram(hf, bins=bins)
    k = int(np.argmax(hist))
    h0 = 0.5 * (edges[k] + edges[k + 1])
    near0 = np.abs(hf - h0) <= step
    soil_h = float(np.median(hf[near0]))
    sig = 1.4826 * float(np.median(np.abs(hf[near0] - soil_h)))
    tol = max(3.0 * sig, thr)
    # a real soil surface: up-facing Gaussians spread over the rim's disk
    if angular_coverage(xyp[cand[flat]][near0], c, 12) < 0.75 or near0.sum() < 20:
        return is_pot, is_soil, None
    is_soil = (rp < r_of(hp) + wall_band) & (hp <= soil_h + tol) & ~is_pot
    # the inner wall between the soil and the rim: vertical Gaussians facing the axis
    wall = np.flatnonzero(below_rim & (hp > soil_h + tol) & (rp >= 0.6 * r_of(hp))
                          & (rp <= r_of(hp) + wall_band) & ~is_pot)
    if len(wall):
        nw = cloud.subset(plant[wall]).shortest_axes().astype(np.float64)
        radial = (xyp[wall] - c) @ basis.T
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-30)
        facing = np.abs(np.einsum("ij,ij->i", nw, radial)) > 0.6
        is_pot[wall[facing]] = True
    return is_pot, is_soil & ~is_pot, soil_h


AXIS_DIRECTIONS = 300   # directions of the search
AXIS_SAMPLE = 5000      # samples it runs on
AXIS_AGREE = 0.8        # directions whose wall rises this x as high as the best's are averaged
AXIS_CONES = (6.0, 3.0, 1.5)  # pattern search, degrees


def _wall_fit(s: np.ndarray, u: np.ndarray, thr: float, p_: "IsolateParams"):
    """The pot found at the bottom of the samples ``s`` (M, 3) along ``u`` (3,): (rim height /
    plant height, samples on the wall) or None when there is none (see :func:`pot_shape`)."""
    h = s @ u
    hs = h - float(np.quantile(h, 0.001))
    H = float(np.quantile(hs, 0.99))
    if H <= 0:
        return None
    xy = s @ plane_basis(u)
    shape = pot_shape(xy, hs, H, thr, p_)
    if shape is None:
        return None
    c, r_of, h_top, _ = shape
    r = r_of(hs)
    on = (hs <= h_top) & (np.abs(np.linalg.norm(xy - c, axis=1) - r) <= 0.05 * r + thr)
    return h_top / H, int(on.sum())


def find_pot_axis(s: np.ndarray, thr: float, p_: "IsolateParams", seed: int = 0) -> np.ndarray | None:
    """The pot's axis (3,) unit vector, pointing from the pot to the plant, or None: see the
    module docstring. s : (M, 3) samples, input frame; thr : the planes' inlier distance."""
    from leaffit_usd.splats.up_axis import fibonacci_sphere

    s = np.asarray(s, np.float64)
    s = s[position_order_sample(s, AXIS_SAMPLE, seed)]
    dirs = fibonacci_sphere(AXIS_DIRECTIONS)
    found = [(f[0], u) for u in dirs if (f := _wall_fit(s, u, thr, p_)) is not None]
    if not found:
        return None
    top, u_best = max(found, key=lambda x: x[0])
    near = [u for rim, u in found if rim >= AXIS_AGREE * top and u @ u_best >= np.cos(np.radians(30))]
    u = np.sum(near, axis=0)
    u /= np.linalg.norm(u)
    best = _wall_fit(s, u, thr, p_)
    if best is None:
        u, best = u_best, _wall_fit(s, u_best, thr, p_)
    ring = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    for cone in np.radians(AXIS_CONES):
        moved = True
        while moved:
            moved = False
            b = plane_basis(u)
            for a in ring:
                v = np.cos(cone) * u + np.sin(cone) * (b @ [np.cos(a), np.sin(a)])
                f = _wall_fit(s, v / np.linalg.norm(v), thr, p_)
                if f is not None and f[1] > best[1]:
                    u, best, moved = v / np.linalg.norm(v), f, True
    log.debug("pot axis (%.3f %.3f %.3f): %d directions found a pot, %d on its wall", *u, len(found), best[1])
    return u
