"""A potted plant's soil surface, and the pot around and below it, when no table shows the up
direction (a capture whose background was removed: the plant, its soil and its pot, nothing else).

The soil is the strongest surface such a capture has: a dense, flat disc that RANSAC finds as
one of the first planes. A plane is the soil (:func:`find_soil`) when, seen along its normal:

* its largest connected inlier patch is a **filled disc**: inlier points all round its centre
  (``DISC_COVERAGE`` of ``SECTORS`` sectors in the outer half of its radius) and at least
  ``DISC_FILL`` of the disc's area occupied;
* on one side (below) there is a **pot**: at least ``MIN_POT_SHARE`` of the samples, nearly all
  (``CONTAINED``) within ``FOOTPRINT`` x the disc's radius of its axis, many of them
  (``WALL_SHARE``) at a wall's distance from it (beyond ``WALL_RADIUS`` x the radius) and in
  ``WALL_COVERAGE`` of the sectors around it, reaching at least ``MIN_DEPTH`` x the radius
  below the disc -- a shell under the disc all round, not a plant's stem and leaves;
* on the other side (above) stands the plant: more samples than below, rising at least
  ``MIN_RISE`` inlier distances;
* the disc is not of the plant's colour: its median colour is at least ``SOIL_CONTRAST`` (RGB
  distance) from the median colour of the far part of each side: the plant's upper part, the
  pot's bottom (:func:`_unlike_both_sides`; a leaf layer read upside down has the plant's colour
  on its pot side). Soil, bark, pebbles are not
  foliage; a layer of touching leaflets in a flat canopy can look like a disc with leaves above
  it in a shell, and only its colour tells it from soil (a hard4 soybean: 0.05-0.06, against
  0.22-0.49 for the real houseplant's soil and the capture-realism samples'). Soil under green
  moss fails this test and the plant's shape then gives the up axis.

A big round leaf fails the pot test (the rest of its plant is not a shell under it, nor within
its footprint); a table fails the disc test or passes the ground test first
(:mod:`leaffit_usd.isolate.scene`). Among the planes passing, the one with the most patch points.

Then every Gaussian (:func:`classify_pot_and_soil`): everything below the soil surface inside
the pot's footprint is pot (at the wall) or soil; the surface layer inside the rim is soil, and
so are the Gaussians just above it whose colour is nearer the soil's or the pot's than the plant's; the rim
standing above the soil is followed ring by ring while a full ring of Gaussians stays at the
wall's radius, and its Gaussians whose colour is nearer the pot's (learnt from the wall below the
soil, whatever that colour is) than the plant's are pot.

Input frame and input units; distances relative to the RANSAC inlier distance and the disc.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from leaffit_usd.geometry.plane import plane_basis
from leaffit_usd.isolate.result import PLANT, POT, SOIL
from leaffit_usd.isolate.shapes import angular_coverage, heights, largest_patch

log = logging.getLogger("leaffit_usd")

SECTORS = 24
DISC_COVERAGE = 0.85   # sectors of the disc's outer half holding patch points, at least
DISC_FILL = 0.45       # occupied share of the disc's area (pi R^2), at least
MIN_POT_SHARE = 0.02   # samples below the soil, at least this share of all
CONTAINED = 0.9        # share of those within FOOTPRINT x R of the disc's axis, at least
FOOTPRINT = 1.6    # the pot (its wall, its rim lip) lies within this x the soil disc's radius
WALL_RADIUS = 0.6      # a wall sample lies beyond this x R from the axis
WALL_SHARE = 0.4       # share of the samples below that are wall, at least
WALL_COVERAGE = 0.85   # sectors around the axis holding wall samples, at least
MIN_DEPTH = 0.5        # the pot reaches this x R below the soil (90th percentile), at least
MIN_RISE = 10.0        # the plant rises at least this many inlier distances above the soil
SOIL_CONTRAST = 0.15   # RGB distance between the disc's and the plant's median colours, at least
RIM_RING = (0.8, 1.15)  # the rim's ring: radial band, x (R, outer radius)
RIM_COVERAGE = 0.6     # sectors of a rim ring holding Gaussians, at least
RIM_MAX = 0.5          # the rim is looked for up to this x the plant's height above the soil


@dataclass(frozen=True)
class SoilDisc:
    """The soil surface of a potted plant (input frame and units).

    normal : (3,) float64 unit, towards the plant (the capture's up); d : the plane is
        ``normal . x + d = 0`` (heights above the soil: ``x . normal + d``)
    centre : (3,) float64, the disc's centre on the plane; radius : its radius (90th percentile
        of the patch's distances from the centre: the pot's inner radius at the soil)
    thr : the soil's surface layer, half its thickness (4 robust standard deviations of its patch
        samples' heights, between 0.2 and 1 x the RANSAC inlier distance); patch : patch samples
    """

    normal: np.ndarray
    d: float
    centre: np.ndarray
    radius: float
    thr: float
    patch: int


def _disc(xy: np.ndarray, cells: int, cell: float):
    """(centre (2,), radius, passes) of a patch's in-plane points (M, 2) occupying ``cells``
    grid cells of side ``cell``: a filled disc (see the module docstring)."""
    c = np.median(xy, axis=0)
    r = np.linalg.norm(xy - c, axis=1)
    radius = float(np.quantile(r, 0.9))
    if radius <= 0:
        return c, radius, False
    outer = xy[r >= 0.5 * radius]
    ok = (angular_coverage(outer, c, SECTORS) >= DISC_COVERAGE
          and cells * cell ** 2 >= DISC_FILL * np.pi * radius ** 2)
    return c, radius, ok


def _pot_below(h, xy, rho, thr, radius) -> bool:
    """Whether the samples below the plane (heights ``h`` (M,), in-plane offsets ``xy`` (M, 2)
    from the disc's centre and their lengths ``rho`` (M,)) are a pot under a disc of ``radius``
    and the plant stands above it."""
    below, above = h < -thr, h > thr
    nb = int(below.sum())
    if nb < MIN_POT_SHARE * len(h) or nb >= above.sum():
        return False
    rb = rho[below]
    wall = below & (rho >= WALL_RADIUS * radius) & (rho <= FOOTPRINT * radius)
    if (rb <= FOOTPRINT * radius).mean() < CONTAINED or wall.sum() < WALL_SHARE * nb \
            or angular_coverage(xy[wall], np.zeros(2), SECTORS) < WALL_COVERAGE \
            or float(np.quantile(-h[below], 0.9)) < MIN_DEPTH * radius:
        return False
    return float(np.quantile(h[above], 0.99)) >= MIN_RISE * thr


def _unlike_both_sides(colors: np.ndarray, disc: np.ndarray, h: np.ndarray) -> bool:
    """Whether the disc's median colour (samples ``disc``) is at least ``SOIL_CONTRAST`` from
    the median colour of the far part (beyond 30 % of the reach) of each side of the plane
    (heights ``h`` (M,)): the plant's top on one side, the pot's bottom on the other. A layer of
    leaves has the plant's colour on one side or the other, whichever way up it is read."""
    c = np.median(colors[disc], axis=0)
    for hs in (h, -h):
        far = hs > 0.3 * float(np.quantile(hs, 0.99))
        if far.any() and np.linalg.norm(c - np.median(colors[far], axis=0)) < SOIL_CONTRAST:
            return False
    return True


def find_soil(s: np.ndarray, colors: np.ndarray, planes: list, thr: float, voxel: float,
              up=None) -> SoilDisc | None:
    """The soil among the candidate ``planes`` [(unit normal (3,), d)] of the samples ``s``
    (M, 3) with RGB ``colors`` (M, 3) in [0, 1], or None. thr : inlier distance; voxel : the
    plane sample's voxel size (the patch grid is twice it); up : the user's up (3,) or None --
    with it only planes within 45 degrees of it, facing it, are tried. See the module docstring."""
    best = None
    for n0, d0 in planes:
        h0 = heights(s, n0, d0)
        on = np.flatnonzero(np.abs(h0) <= thr)
        if len(on) < 50:
            continue
        basis = plane_basis(n0)
        xy = s[on] @ basis
        in_patch, _, (lo, cell) = largest_patch(xy, 2 * voxel)
        pxy = xy[in_patch]
        cells = len(np.unique(np.floor((pxy - lo) / cell).astype(np.int64), axis=0))
        c, radius, ok = _disc(pxy, cells, cell)
        if not ok:
            continue
        off = s @ basis - c
        rho = np.linalg.norm(off, axis=1)
        for sign in (1.0, -1.0):
            n_, d_ = sign * n0, sign * d0
            if up is not None and n_ @ up < np.cos(np.radians(45)):
                continue
            if not _pot_below(sign * h0, off, rho, thr, radius):
                continue
            if not _unlike_both_sides(colors, on[in_patch], h0):
                continue
            if best is None or len(pxy) > best.patch:
                centre = basis @ c - n_ * (d_ + float(n_ @ (basis @ c)))
                hp = h0[on[in_patch]]  # the soil's own roughness: its surface layer's thickness
                rough = 4 * 1.4826 * float(np.median(np.abs(hp - np.median(hp))))
                best = SoilDisc(normal=np.asarray(n_, np.float64), d=float(d_), centre=centre,
                                radius=radius, thr=float(np.clip(rough, 0.2 * thr, thr)),
                                patch=int(len(pxy)))
    if best is not None:
        log.debug("soil: n=(%.3f %.3f %.3f), radius %.4g, %d patch samples", *best.normal,
                  best.radius, best.patch)
    return best


def _not_plant(colors: np.ndarray, plant: np.ndarray, *others: np.ndarray) -> np.ndarray:
    """(M,) bool: which RGB ``colors`` (M, 3) are nearer one of the colours ``others`` (each (3,))
    than the plant's colour ``plant`` (3,)."""
    d_plant = ((colors - plant) ** 2).sum(1)
    return np.min([((colors - o) ** 2).sum(1) for o in others], axis=0) < d_plant


def classify_pot_and_soil(pts: np.ndarray, colors: np.ndarray, classes: np.ndarray,
                          soil: SoilDisc) -> dict:
    """Mark the pot and the soil among the PLANT Gaussians (``classes`` (N,) uint8, in place).

    pts : (N, 3) input frame; colors : (N, 3) RGB in [0, 1]. Returns the pot (dict: ``center``
    (3,) on the soil surface, ``axis`` (3,), ``radius_bottom`` (the wall's outer radius below the
    soil), ``radius_top`` (the soil disc's), ``height`` (the rim above the soil), ``soil_height``
    0.0 (heights are above the soil), ``plant_height``; input units).
    """
    n, thr, r_in = soil.normal, soil.thr, soil.radius
    plant = np.flatnonzero(classes == PLANT)
    h = heights(pts[plant], n, soil.d)
    rel = pts[plant] - soil.centre
    rho = np.linalg.norm(rel - np.outer(rel @ n, n), axis=1)
    H = float(np.quantile(h, 0.99))
    wall_below = (h < -thr) & (h > -0.3 * r_in) & (rho >= WALL_RADIUS * r_in)
    r_out = float(np.clip(np.quantile(rho[wall_below], 0.95), r_in, FOOTPRINT * r_in)) \
        if wall_below.sum() >= 10 else r_in
    foot = rho <= RIM_RING[1] * r_out
    below = (h <= thr) & foot  # under the soil surface, and the surface layer itself
    is_pot = below & (rho >= 0.85 * r_in)
    is_soil = below & ~is_pot
    col = colors[plant]
    plant_col = np.median(col[h > 0.3 * H], axis=0) if (h > 0.3 * H).any() else np.full(3, 0.5)
    soil_col = np.median(col[np.abs(h) <= thr], axis=0)
    pot_col = np.median(col[is_pot], axis=0) if is_pot.any() else soil_col
    rim_h = _rim_height(pts[plant] @ plane_basis(n) - soil.centre @ plane_basis(n), h, rho, r_in,
                        r_out, thr, H)
    low = (h > thr) & (h <= max(3 * thr, 0.5 * rim_h))
    is_soil |= low & (rho <= r_in) & _not_plant(col, plant_col, soil_col, pot_col)
    ring = (rho >= RIM_RING[0] * r_in) & foot & (h > thr) & (h <= rim_h)
    is_pot |= ring & (low | _not_plant(col, plant_col, pot_col, soil_col))
    is_soil &= ~is_pot
    classes[plant[is_pot]] = POT
    classes[plant[is_soil]] = SOIL
    return {"center": soil.centre.copy(), "axis": n.copy(), "radius_bottom": r_out,
            "radius_top": r_in, "height": rim_h, "soil_height": 0.0, "plant_height": H}


def _rim_height(xy, h, rho, r_in, r_out, thr, H) -> float:
    """Height above the soil of the pot's rim: rings of height ``2 thr`` climbed from the soil
    while one in two holds Gaussians at the wall's radius in ``RIM_COVERAGE`` of the sectors
    around the axis (xy (M, 2) in-plane offsets from the axis; h, rho (M,)). 0 when none does."""
    step = 2 * thr
    band = (rho >= RIM_RING[0] * r_in) & (rho <= RIM_RING[1] * r_out)
    top, misses, z = 0.0, 0, thr
    while z < RIM_MAX * H and misses < 2:
        sel = band & (h > z) & (h <= z + step)
        if angular_coverage(xy[sel], np.zeros(2), SECTORS) >= RIM_COVERAGE:
            top, misses = z + step, 0
        else:
            misses += 1
        z += step
    return top
