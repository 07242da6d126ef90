"""Capture realism: Gaussians with the statistics of a trained 3DGS capture
(``PlantSpec(realism="capture")``, ``python -m samples.generate --realism capture``).

The ideal generator (``realism="ideal"``) draws clean, nearly opaque discs lying in the leaf
surface. A trained capture does not look like that. Measured on the real capture
``../shared/real/houseplant.splat`` (Marcel Padilla, CC-BY-4.0; 113,648 Gaussians, a potted
houseplant with its white ceramic pot and soil kept, the background removed; plant height
H ~ 0.7 of its units; the plant / soil / pot split below is by height and colour, see
``benchmarks/capture_stats.py``):

==================================  ==========================  =================================
statistic (real capture)            value                       how this mode matches it
==================================  ==========================  =================================
opacity                             logit-normal: logit mean    opacity = sigmoid(N(mu, sd)) per
                                    -1.40, sd 1.17 (median      class, the real classes' fits:
                                    0.20, 23.5 % below 0.1);    plant (-1.45, 1.08; mean raised
                                    plant -1.55 sd 1.08, soil   0.1 for the faint floaters and
                                    -0.91 / 1.11, pot -1.72 /   edge fuzz), soil (-0.91, 1.11),
                                    1.25                        pot (-1.72, 1.25)
opacity vs size                     weak: corr(log size,        the same coupling: the logit's
                                    logit) -0.08 plant, -0.20   normal draw is correlated -0.08 /
                                    soil; the largest 20 % a    -0.20 with the class's standard-
                                    little fainter              ised log size
largest / middle axis               ln ratio ~ Gamma(k 2,       the same Gamma; about half of the
                                    scale 0.65): median 2.96,   Gaussians are needles (> 3)
                                    49 % needles (> 3)
middle / smallest axis              ln ratio ~ Gamma(k 1.5):    the same Gamma, scale 1.05 plant
(flatness)                          median 3.5 plant, 2.0       (median 3.5), 0.58 soil (2.0),
                                    soil, 2.6 pot, 2.8 all      0.82 pot (2.6)
shortest axis vs the local          |cos| median 0.970, 0.82    a roll about the long axis of
surface normal (PCA of a 0.8 %      above 0.8; the lower the    N(0, 0.36 / sqrt(ln flatness))
H patch)                            flatness the worse (0.87    rad (12 %: uniform, the normal
                                    below 1.5, 0.99 above 8)    lost) and a 0.06 rad tilt of the
                                                                long axis out of the surface
sheet thickness (std of the         0.94e-3 H (median over      2-3 layers per leaf (half each)
normal offsets in a 0.8 % H         sheet-like patches)         1.0e-3 H +- 20 % apart, each with
patch)                                                          half the ideal surface noise
                                                                (1.0-1.1e-3 H measured)
coverage (areal density x pi x      6.3; axes 0.0080, 0.0023,   in-plane area of the ideal disc
largest x middle axis)              0.0006 H (medians)          x 2 (coverage 5.6-6.7; axes
                                                                0.0075, 0.0022, 0.0006 H on the
                                                                36k rubber tree)
Gaussians per leaf layer            1.2e5 per H^2 of sheet (all the ideal density (the plant's
                                    layers; ~5e4 per layer)     count): 1.3-1.4e5 per H^2 at 36k
floaters                            0.6 % with their 8th        0.7 % plant floaters (label -1;
                                    neighbour > 5x the median   the ideal 0.3 %) and 1 % of the
                                    distance                    plant count round the pot (label
                                                                -2, class 5): 0.8 % isolated
pot and soil                        34-42 % of the Gaussians;   pot 0.28 x, soil 0.40 x the
                                    pot (white ceramic, median  plant's count (40 %); rim-heavy
                                    RGB 0.97 0.91 0.86) mostly  pot (the outer wall 35 %);
                                    at its rim, the wall a few  ceramic base 1.07 1.01 0.95
                                    large faint Gaussians; soil (shaded, clipped: median 0.96
                                    dark (median 0.145 0.051    0.91 0.86), soil 0.145 0.051
                                    0.039), denser than leaves  0.039 x exp(N(0, 0.6)), 3 %
                                                                perlite
==================================  ==========================  =================================

Edge fuzz (Gaussians spilling off the leaf margin) cannot be measured without leaf labels; the
mode moves ``EDGE_FUZZ`` of each leaf's Gaussians within 2 % H of its margin up to ~1 % H
beyond it (larger, fainter), as trained captures blur silhouettes. Leaf fuzz keeps its leaf's
label. ``benchmarks/capture_stats.py`` prints these statistics for the real capture, this mode
and the ideal samples side by side.

Everything here draws from its own random stream (``capture_rng``), so the ideal plant's
arrays are never touched when the mode is off.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from samples.scene import (FLOATER, POT, SOIL, PotGeometry, frame_from_normal, unit,
                           pot_gaussians, soil_gaussians)

REALISMS = ("ideal", "capture")
POT_KINDS = ("ceramic", "terracotta", "plastic")

#: opacity logit (mean, sd) and its correlation with the standardised log size, per class
OPACITY_LOGIT = {"plant": (-1.45, 1.08, -0.08), "soil": (-0.91, 1.11, -0.20),
                 "pot": (-1.72, 1.25, -0.10)}
#: ln(largest / middle) ~ Gamma(shape, scale), all classes
NEEDLE_GAMMA = (2.0, 0.65)
#: ln(middle / smallest) ~ Gamma(shape, scale), per class
FLAT_GAMMA = {"plant": (1.5, 1.05), "soil": (1.5, 0.58), "pot": (1.5, 0.82)}
#: roll about the long axis: sd = ROLL / sqrt(ln flatness) rad, at most ROLL_MAX
ROLL, ROLL_MAX = 0.36, 1.2
LOST_NORMAL = 0.12              # share whose roll is uniform (the normal not pinned at all)
TILT = 0.06                     # sd of the long axis' tilt out of the surface, rad
LAYER_SPACING = 1.0e-3          # distance between a leaf's layers / plant height
LAYER_NOISE = 0.5               # each layer's off-surface noise / the ideal surface noise
COVERAGE_FACTOR = 2.0           # in-plane area (largest x middle) / the ideal disc's
EDGE_FUZZ = 0.04                # share of a leaf's Gaussians pushed over its margin
EDGE_BAND = 0.02                # the margin band they come from / plant height
EDGE_REACH = 0.006              # how far beyond the margin (sd of a half-normal) / plant height
FLOATERS = 0.007                # plant floaters (label -1) / all plant Gaussians
POT_SHARE, SOIL_SHARE, POT_FLOATERS = 0.28, 0.40, 0.01   # of the plant's Gaussian count
POT_COLOURS = {"ceramic": (1.07, 1.01, 0.95), "terracotta": (0.70, 0.38, 0.22),
               "plastic": (0.18, 0.18, 0.19)}
SOIL_COLOUR, SOIL_SPREAD, PERLITE = (0.145, 0.051, 0.039), 0.6, 0.03


def capture_rng(seed: int) -> np.random.Generator:
    """The random stream of everything capture realism adds to a plant of seed ``seed``."""
    return np.random.default_rng([int(seed), 0xCA97])


@dataclass
class LeafSites:
    """Where each leaf Gaussian sits on its blade (canonical frame, metres).

    normal : (N, 3) float64 unit blade normal at the sample (before off-surface noise)
    outward : (N, 3) float64 unit in-plane direction towards the nearest margin (along the
        outline's polar ray)
    to_margin : (N,) float64 in-plane distance to the margin along that ray, metres
    """

    normal: np.ndarray
    outward: np.ndarray
    to_margin: np.ndarray


def layer_and_fuzz(pos: np.ndarray, sites: LeafSites, leaf: np.ndarray, height: float,
                   rng: np.random.Generator):
    """Split each leaf's Gaussians into 2-3 stacked layers and push a few over the margin.

    pos : (N, 3) float64 canonical positions of leaf Gaussians; leaf : (N,) int their labels;
    height : plant height (m). Returns new positions (N, 3) and a (N,) bool mask of the edge
    fuzz (the caller enlarges and fades them).
    """
    pos = pos.copy()
    fuzz = np.zeros(len(pos), bool)
    for lab in np.unique(leaf):
        idx = np.flatnonzero(leaf == lab)
        n_layers = int(rng.integers(2, 4))
        gap = LAYER_SPACING * height * float(rng.uniform(0.8, 1.2))
        layer = rng.integers(0, n_layers, len(idx))
        off = (layer - 0.5 * (n_layers - 1)) * gap
        pos[idx] += off[:, None] * sites.normal[idx]
        near = idx[sites.to_margin[idx] < EDGE_BAND * height]
        k = min(len(near), int(round(EDGE_FUZZ * len(idx))))
        if k:
            pick = rng.choice(near, k, replace=False)
            beyond = sites.to_margin[pick] + np.abs(rng.normal(0, EDGE_REACH * height, k))
            pos[pick] += beyond[:, None] * sites.outward[pick]
            fuzz[pick] = True
    return pos, fuzz


def reshape(scales: np.ndarray, R: np.ndarray, cls: str, rng: np.random.Generator,
            keep_long_axis: bool = False):
    """Needles and thick discs from flat discs: new scales and rotations.

    scales : (N, 3) ideal scales (in-plane, in-plane, normal), R : (N, 3, 3) their axes as
    columns (the third is the surface normal); cls : "plant" | "soil" | "pot";
    keep_long_axis : the first axis stays the long one (tubes: along the centreline), else the
    long axis takes a random in-plane direction. Returns (scales (N, 3), R (N, 3, 3)), the
    axes ordered largest, middle, smallest.
    """
    n = len(scales)
    area = scales[:, 0] * scales[:, 1] * COVERAGE_FACTOR
    r_n = np.exp(rng.gamma(NEEDLE_GAMMA[0], NEEDLE_GAMMA[1], n))
    k, th = FLAT_GAMMA[cls]
    ln_f = rng.gamma(k, th, n)
    s_long = np.sqrt(area * r_n)
    s_mid = np.sqrt(area / r_n)
    new = np.stack([s_long, s_mid, s_mid / np.exp(ln_f)], 1)
    a1, a2, nrm = R[:, :, 0], R[:, :, 1], R[:, :, 2]
    psi = rng.normal(0, 0.3, n) if keep_long_axis else rng.uniform(0, np.pi, n)
    u = np.cos(psi)[:, None] * a1 + np.sin(psi)[:, None] * a2
    v = np.cross(nrm, u)
    # the normal is poorly pinned where middle ~ smallest: roll about the long axis
    phi = rng.normal(0, 1, n) * np.minimum(ROLL / np.sqrt(np.maximum(ln_f, 1e-3)), ROLL_MAX)
    phi = np.where(rng.uniform(size=n) < LOST_NORMAL, rng.uniform(-np.pi / 2, np.pi / 2, n), phi)
    v, w = np.cos(phi)[:, None] * v + np.sin(phi)[:, None] * nrm, \
        -np.sin(phi)[:, None] * v + np.cos(phi)[:, None] * nrm
    chi = rng.normal(0, TILT, n)  # the long axis tilts out of the surface a little
    u, w = np.cos(chi)[:, None] * u + np.sin(chi)[:, None] * w, \
        -np.sin(chi)[:, None] * u + np.cos(chi)[:, None] * w
    return new, np.stack([u, v, w], 2)


def opacity(scales: np.ndarray, cls: str, rng: np.random.Generator) -> np.ndarray:
    """(N,) logit-normal opacities of class ``cls``, weakly fainter for larger Gaussians."""
    mu, sd, rho = OPACITY_LOGIT[cls]
    ls = np.log(np.sqrt(scales[:, 0] * scales[:, 1]))
    z = (ls - ls.mean()) / max(float(ls.std()), 1e-12)
    e = rho * z + np.sqrt(1 - rho * rho) * rng.normal(0, 1, len(scales))
    return 1.0 / (1.0 + np.exp(-(mu + sd * e)))


def _soil_colour(m: int, rng: np.random.Generator) -> np.ndarray:
    col = np.array(SOIL_COLOUR) * np.exp(rng.normal(0, SOIL_SPREAD, (m, 1))) \
        * np.exp(rng.normal(0, 0.1, (m, 3)))
    perlite = rng.uniform(size=m) < PERLITE
    col[perlite] = np.array([0.85, 0.84, 0.80]) * rng.uniform(0.8, 1.1, (int(perlite.sum()), 1))
    return col


def make_pot_scene(height: float, n: int, rng: np.random.Generator, kind: str | None = None):
    """A pot with soil under a plant, a few floaters round it, nothing else (a capture with the
    background removed, as the houseplant). Canonical frame, metres, root at 0, +Z up.

    height : plant height (m); n : the plant's
    Gaussian count (the pot takes ``POT_SHARE`` n, the soil ``SOIL_SHARE`` n); kind : one of
    ``POT_KINDS``, None = ceramic or terracotta from ``rng``.
    Returns (pos, scales, R, colour, opacity, classes) as ``samples.scene.make_scene`` does
    (opacities still ideal: the caller redraws them) and a dict describing the pot.
    """
    H = float(height)
    r_top = float(np.clip(rng.uniform(0.15, 0.25) * H, 0.05, 0.2))
    r_bot = r_top * rng.uniform(0.7, 0.9)
    ph = r_top * rng.uniform(1.2, 1.8)
    z_soil = -rng.uniform(0.003, 0.008)
    z_rim = z_soil + rng.uniform(0.01, 0.04)
    if kind is None:
        kind = ("ceramic", "terracotta")[int(rng.integers(2))]
    geo = PotGeometry(r_top, r_bot, ph, z_soil, z_rim)
    parts = []

    def faint(m):  # placeholder opacities (redrawn by the caller's capture pass)
        return np.full(m, 0.5)

    parts += pot_gaussians(geo, max(50, int(POT_SHARE * n)), np.array(POT_COLOURS[kind]), rng,
                           faint, shares=(0.35, 0.25))
    parts.append(soil_gaussians(geo, max(50, int(SOIL_SHARE * n)), rng, faint, colour=_soil_colour))
    m = max(10, int(POT_FLOATERS * n))
    lo = np.array([-1.3 * r_top, -1.3 * r_top, geo.z_bot])
    hi = np.array([1.3 * r_top, 1.3 * r_top, z_rim + 0.1 * H])
    fpos = lo + rng.uniform(0, 1, (m, 3)) * (hi - lo)
    fsc = np.exp(rng.normal(np.log(0.004), 0.6, (m, 3)))
    fR = frame_from_normal(unit(rng.normal(size=(m, 3))))
    parts.append((fpos, fsc, fR, rng.uniform(0.2, 0.8, (m, 3)), rng.uniform(0.02, 0.5, m), FLOATER))
    cat = [np.concatenate([p[i] for p in parts]) for i in range(5)]
    cls = np.concatenate([np.full(len(p[0]), p[5], np.int32) for p in parts])
    cat[3] = np.clip(cat[3], 0.01, 0.99)
    info = {"pot": kind, "pot_radius_top_m": r_top, "pot_radius_bottom_m": r_bot,
            "pot_height_m": ph, "rim_z_m": z_rim, "soil_z_m": z_soil, "table_z_m": geo.z_bot,
            "surroundings": "pot"}
    return (*cat, cls, info)


def realise_plant(pos, scales, R, opa, labels, sites: LeafSites, height: float,
                  rng: np.random.Generator):
    """The capture pass over a plant's Gaussians (canonical frame, metres).

    pos, scales : (N, 3); R : (N, 3, 3) axes as columns, the third the surface normal;
    opa : (N,) ideal opacities; labels : (N,) 0 tubes, 1..L leaves, -1 floaters (kept as
    drawn); sites : the leaf Gaussians' ``LeafSites``, in their order in the arrays;
    height : plant height (m). Returns new (pos, scales, R, opa); labels are unchanged (edge
    fuzz keeps its leaf's label).
    """
    pos, scales, R, opa = pos.copy(), scales.copy(), R.copy(), opa.copy()
    leaf, tube = labels > 0, labels == 0
    pos[leaf], fuzz = layer_and_fuzz(pos[leaf], sites, labels[leaf], height, rng)
    scales[leaf], R[leaf] = reshape(scales[leaf], R[leaf], "plant", rng)
    scales[tube], R[tube] = reshape(scales[tube], R[tube], "plant", rng, keep_long_axis=True)
    plant = leaf | tube
    opa[plant] = opacity(scales[plant], "plant", rng)
    # edge fuzz: larger and fainter than the blade it spills from
    li = np.flatnonzero(leaf)[fuzz]
    scales[li] *= 1.5
    opa[li] *= 0.5
    return pos, scales, R, opa


def realise_scene(scales, R, opa, classes, rng: np.random.Generator):
    """The capture pass over the surroundings: soil Gaussians get the soil's statistics,
    floaters (class 5) stay as drawn, everything else (pot, table, clutter, wall) the pot's.
    scales (N, 3), R (N, 3, 3), opa (N,), classes (N,) int. Returns new (scales, R, opa)."""
    scales, R, opa = scales.copy(), R.copy(), opa.copy()
    soil = classes == SOIL
    rest = ~soil & (classes != FLOATER)
    for sel, cls in ((soil, "soil"), (rest, "pot")):
        if sel.any():
            scales[sel], R[sel] = reshape(scales[sel], R[sel], cls, rng)
            opa[sel] = opacity(scales[sel], cls, rng)
    return scales, R, opa
