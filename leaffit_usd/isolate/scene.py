"""Plant isolation: find the table / ground plane, the pot, the soil, background objects and
floaters in a capture, and keep the plant.

Everything here is in the input frame and free of units: distances are measured against the
capture's own Gaussian spacing and the plant's height above the ground plane. The scene analysis
runs on a deterministic random subsample of at most ``IsolateParams.sample`` Gaussians; every
Gaussian then follows its nearest sample, or the exact geometric rule where there is one.

1. **Planes** -- RANSAC plane hypotheses on a voxel subsample (area-even), up to ``max_planes``
   times on what is left, each refined to a least-squares fixed point.
2. **Ground** -- a candidate is the ground (table, floor) only when it looks like one from the
   plant's side, not like a big leaf or a flat group of leaves: the largest connected patch of its
   inliers (a leaf's plane also cuts the rest of the plant at scattered points; those are not a
   patch) is large next to the height of what stands on it (``min_plane_area``) and wider than
   that object's footprint (``min_plane_span``); the object touches it and rises from it; and over
   the patch almost nothing lies behind the plane (``max_below``; a leaf has the rest of its plant
   on both sides). Among those passing, the one with most inliers. Its inliers are GROUND,
   everything behind it BACKGROUND, and its normal (on the plant's side) is the scene's up.
3. **Components** -- the samples above the ground (all, without one) are linked to their 10
   nearest neighbours closer than ``link`` x the median 4-NN spacing (scipy
   ``connected_components``). The largest component is the plant (with its pot and soil);
   components within ``near_gap`` of it stay with it; the others are background objects
   (``min_background`` samples or more) or floaters.
4. **Pot and soil** -- with no ground plane, the soil disc over a pot's shell
   (:mod:`leaffit_usd.isolate.soil`) gives the up direction and removes the pot and soil; else,
   with the up direction known (the table, the user's ``--up``, or the pot's own axis found by
   :func:`leaffit_usd.isolate.pot.find_pot_axis`), :func:`leaffit_usd.isolate.pot.pot_and_soil`
   fits the pot's foot circle and wall and the soil inside its rim.
5. **Floaters** -- on a fresh position-order sample of what is still PLANT (the same density and
   population with or without a scene around the plant), samples that are statistical outliers
   (``outlier_neighbors``, ``outlier_std``; :func:`leaffit_usd.geometry.outliers.statistical_inliers`)
   AND isolated (at most one other sample within the linking radius): FLOATER. A sparsely
   sampled stem is a statistical outlier too, but a chain. The stem base (``root``) is then the
   middle of the lowest plant Gaussians inside the pot's rim.

A trimmed plant (no plane passes, no pot) loses only what lies far from it.

RANSAC: numpy, not open3d's ``segment_plane``. open3d 0.20's parallel RANSAC gave different
planes at 1 and 2 threads here even with ``o3d.utility.random.seed`` set (so the output was not
the same bytes across machines), and ``import open3d`` alone costs ~1.3 s (it pulls in its
plotly/dash visualisation), twice this whole stage's budget on 100k Gaussians.
scikit-learn's ``RANSACRegressor`` fits a function y = f(x), not a plane in 3-D with orthogonal
residuals, and pyransac3d draws from Python's global ``random`` state. The hypotheses here are
drawn from one seeded ``numpy.random.Generator`` and scored with element-wise numpy (no BLAS
reductions), so the result is the same bytes at any thread count.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry import knn as _knn
from leaffit_usd.geometry.plane import plane_basis
from leaffit_usd.geometry.sampling import position_order_sample
from leaffit_usd.isolate.shapes import (components, fit_plane, heights, in_grid, knn_graph,
                                        largest_patch, ransac_plane, span, voxel_down)
from leaffit_usd.isolate.pot import find_pot_axis, pot_and_soil, stem_base
from leaffit_usd.isolate.soil import classify_pot_and_soil, find_soil
from leaffit_usd.isolate.result import (BACKGROUND, FLOATER, GROUND, PLANT,
                                        Isolation)

log = logging.getLogger("leaffit_usd")


@dataclass
class IsolateParams:
    """Parameters of :func:`isolate_plant` (relative: no input units anywhere).

    sample : Gaussians the scene analysis runs on (deterministic random subsample; all when fewer)
    plane_voxels : at most this many voxels in the area-even sample given to RANSAC
    plane_threshold : RANSAC inlier distance, x the voxel size
    plane_iterations : RANSAC hypotheses per plane; max_planes : candidate planes tried
    min_plane_area : the area of a ground plane's largest inlier patch / (height of what stands on
        it)^2, at least
    min_plane_span : the patch's width / the width of what stands on it, at least
    max_below : largest fraction of the off-plane samples over the patch that lie behind a ground
        plane
    link : component linking radius, x the median distance to the 4th nearest sample
    near_gap : components closer than this x the plant's size to the plant are part of it
    min_background : far components with at least this many samples are background objects
    outlier_neighbors, outlier_std : the floater test's statistical outliers on the plant's own
        sample (0 neighbours = no floater test); a floater is also isolated (see step 5)
    pot : look for a pot and soil; min_pot_radius : smallest pot radius, x plant height
    seed : RANSAC and subsample seed
    """

    sample: int = 20_000
    plane_voxels: int = 20_000
    plane_threshold: float = 1.0
    plane_iterations: int = 1000
    max_planes: int = 4
    min_plane_area: float = 0.15
    min_plane_span: float = 1.2
    max_below: float = 0.05
    link: float = 4.0
    near_gap: float = 0.04
    min_background: int = 30
    outlier_neighbors: int = 16
    outlier_std: float = 5.0
    pot: bool = True
    min_pot_radius: float = 0.04
    seed: int = 0

    def validate(self) -> "IsolateParams":
        for name, least in (("sample", 1000), ("plane_voxels", 1000), ("plane_iterations", 1),
                            ("max_planes", 0), ("min_background", 1), ("outlier_neighbors", 0)):
            if int(getattr(self, name)) < least:
                raise ParameterError(name, f"an integer >= {least}", getattr(self, name))
        for name in ("plane_threshold", "min_plane_area", "min_plane_span", "link", "near_gap",
                     "outlier_std", "min_pot_radius"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise ParameterError(name, "a positive number", v)
        if not 0 <= float(self.max_below) < 1:
            raise ParameterError("max_below", "a fraction in [0, 1)", self.max_below)
        return self

    def to_dict(self) -> dict:
        return asdict(self)


# ---- crop -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Crop:
    """A region of the input frame to keep: ``kind`` "box" (values = xmin, ymin, zmin, xmax,
    ymax, zmax) or "sphere" (values = cx, cy, cz, radius). Input units."""

    kind: str
    values: tuple

    @staticmethod
    def parse(text: str) -> "Crop":
        """``box:X0,Y0,Z0,X1,Y1,Z1`` or ``sphere:CX,CY,CZ,R`` -> Crop. Raises ParameterError."""
        expected = "box:X0,Y0,Z0,X1,Y1,Z1 or sphere:CX,CY,CZ,R (input frame)"
        kind, _, rest = str(text).strip().partition(":")
        kind = kind.strip().lower()
        try:
            vals = tuple(float(v) for v in rest.split(","))
        except ValueError:
            raise ParameterError("--crop", expected, text) from None
        if kind not in ("box", "sphere") or len(vals) != (6 if kind == "box" else 4) \
                or not np.isfinite(vals).all():
            raise ParameterError("--crop", expected, text)
        if kind == "box" and not all(vals[i] < vals[i + 3] for i in range(3)):
            raise ParameterError("--crop", "a box with min < max on every axis", text)
        if kind == "sphere" and vals[3] <= 0:
            raise ParameterError("--crop", "a sphere with a positive radius", text)
        return Crop(kind, vals)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) input frame -> (N,) bool."""
        p = np.asarray(points, np.float64)
        v = np.asarray(self.values, np.float64)
        if self.kind == "box":
            return np.all((p >= v[:3]) & (p <= v[3:]), axis=1)
        return np.einsum("ij,ij->i", p - v[:3], p - v[:3]) <= v[3] ** 2

    def __str__(self) -> str:
        return f"{self.kind}:" + ",".join(f"{v:g}" for v in self.values)




# ---- the stage --------------------------------------------------------------------------------
def isolate_plant(cloud, params: IsolateParams | None = None, up: np.ndarray | None = None,
                  crop: Crop | None = None) -> Isolation:
    """Classify every Gaussian of ``cloud`` (a GaussianCloud, input frame) as plant, ground, pot,
    soil, background or floater. See the module docstring for the method.

    up : optional (3,) unit vector, input frame (the user's ``--up``): the ground plane must
        face it, and the pot is looked for along it even without a plane.
    crop : optional region to keep; Gaussians outside are BACKGROUND.
    Returns an :class:`Isolation` (classes in cloud order). Deterministic for a given seed, the
    same at any thread count.
    """
    p_ = (params or IsolateParams()).validate()
    t_all = time.perf_counter()
    timings = {}
    pts = np.asarray(cloud.means, np.float64)
    classes = np.zeros(len(pts), np.uint8)
    if crop is not None:
        classes[~crop.contains(pts)] = BACKGROUND
    if up is not None:
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
    cand_idx = np.flatnonzero(classes == PLANT)
    if len(cand_idx) < 50:
        return Isolation(classes, params=p_.to_dict(), timings={"total": time.perf_counter() - t_all})

    # 1-3 on the samples -----------------------------------------------------------------------
    # the same Gaussians in another file order give the same samples, hence the same classes
    sidx = cand_idx[position_order_sample(pts[cand_idx], p_.sample, p_.seed)]
    scls, ground, soil, thr, radius = _analyse_samples(pts[sidx], cloud.colors[sidx], p_, up, timings)

    # every Gaussian: its sample's class, the ground plane's exact rule --------------------------
    t0 = time.perf_counter()
    full = _spread(pts, cand_idx, sidx, scls, radius)
    if ground is not None:
        hf = heights(pts[cand_idx], *ground)
        full[(np.abs(hf) <= thr) & (full != BACKGROUND)] = GROUND
        full[hf < -thr] = BACKGROUND
    classes[cand_idx] = full
    timings["spread"] = time.perf_counter() - t0

    # 4. pot and soil ------------------------------------------------------------------------------
    t0 = time.perf_counter()
    up_vec = ground[0] if ground is not None else up
    pot = root = root_index = None
    pot_up = None
    if p_.pot and up_vec is None and soil is None:
        pot_up = up_vec = find_pot_axis(pts[sidx], thr, p_, p_.seed)
    if p_.pot and soil is not None:
        pot = classify_pot_and_soil(pts, cloud.colors, classes, soil)
    elif p_.pot and up_vec is not None:
        pot = pot_and_soil(cloud, pts, classes, up_vec, None if ground is None else ground[1], thr, p_)
    timings["pot"] = time.perf_counter() - t0

    # 5. floaters among what is left of the plant, then the stem base -----------------------------
    t0 = time.perf_counter()
    if p_.outlier_neighbors > 0:
        _plant_floaters(pts, classes, p_)
    timings["outliers"] = time.perf_counter() - t0
    if pot is not None:
        root_index = stem_base(pts, classes, pot)
        if root_index is not None:
            root = pts[root_index].copy()
    timings["total"] = time.perf_counter() - t_all
    scene_up, source = (ground[0], "table") if ground is not None else \
        (soil.normal, "soil") if soil is not None else \
        (pot_up, "pot") if pot_up is not None and pot is not None else (None, None)
    return Isolation(classes, up=None if scene_up is None else scene_up.copy(),
                     up_source=source, root=root,
                     root_index=root_index, plane=None if ground is None else np.r_[ground[0], ground[1]],
                     pot=pot, params={**p_.to_dict(), "crop": None if crop is None else str(crop)},
                     timings=timings)


def _analyse_samples(s: np.ndarray, colors: np.ndarray, p_: IsolateParams, up, timings: dict):
    """Steps 1-3 on the samples (M, 3) with their RGB colours (M, 3): (classes (M,) uint8, ground (unit normal, d) or None,
    the soil (:class:`~leaffit_usd.isolate.soil.SoilDisc`, looked for when there is no ground) or
    None, the ground's inlier distance, the components' linking radius)."""
    t0 = time.perf_counter()
    vp, voxel = voxel_down(s, int(min(p_.plane_voxels, len(s) / 4)))  # a voxel holds a few samples
    thr = p_.plane_threshold * voxel
    planes = _candidate_planes(vp, thr, p_)
    timings["planes"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    edges = knn_graph(s, p_.link, local=True)
    ground = _choose_ground(s, planes, thr, voxel, edges, p_, up)
    soil = find_soil(s, colors, planes, thr, voxel, up) if ground is None and p_.pot else None
    scls = np.full(len(s), PLANT, np.uint8)
    off = np.ones(len(s), bool)
    if ground is not None:
        hs = heights(s, *ground)
        hg = hs[np.abs(hs) <= thr]
        if len(hg) >= 10:  # the ground's own noise: the tolerance from here on
            thr = float(np.clip(4 * 1.4826 * np.median(np.abs(hg - np.median(hg))), 0.2 * thr, thr))
        scls[np.abs(hs) <= thr] = GROUND
        scls[hs < -thr] = BACKGROUND
        off = hs > thr
    timings["ground"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    grp = _group(s, off, components(edges, off), p_)
    if grp["far_members"] is not None:
        scls[grp["far_members"]] = grp["far_cls"]
    timings["components"] = time.perf_counter() - t0

    return scls, ground, soil, thr, edges[2]


def _candidate_planes(vp: np.ndarray, thr: float, p_: IsolateParams) -> list:
    """Up to ``max_planes`` planes of the voxel centroids (V, 3), each RANSAC'd on what the
    previous ones left: list of (unit normal (3,), d)."""
    rng = np.random.default_rng(p_.seed)
    planes = []
    rest = np.arange(len(vp))
    for _ in range(int(p_.max_planes)):
        if len(rest) < 100:
            break
        n_, d_ = ransac_plane(vp[rest], thr, p_.plane_iterations, rng)
        inl = rest[np.abs(heights(vp[rest], n_, d_)) <= thr]
        if len(inl) < 50:
            break
        for _ in range(10):  # refine to a fixed point of (inliers -> least-squares plane)
            n_, d_ = fit_plane(vp[inl])
            new = np.flatnonzero(np.abs(heights(vp, n_, d_)) <= thr)
            if np.array_equal(new, inl) or len(new) < 3:
                break
            inl = new
        rest = np.setdiff1d(rest, inl)
        planes.append((n_, d_))
        log.debug("plane candidate n=(%.2f %.2f %.2f): %d of %d voxels", *n_, len(inl), len(vp))
    return planes


def _choose_ground(s, planes, thr, voxel, edges, p_: IsolateParams, up):
    """The candidate plane that is the ground (see the module docstring, step 2) -> (unit normal
    towards the plant, d) or None.

    Each candidate is tested on its own first. When several pass (a back wall also has the whole
    scene in front of it, a table included), each is tested again with the other passing planes'
    inliers taken out: the plant still stands on the table, but nothing then stands on the wall.
    Among those passing both, the one with most inlier samples."""
    cands = []
    for n_, d_ in planes:
        h = heights(s, n_, d_)
        off = np.abs(h) > thr
        if up is not None:
            flip = n_ @ up < 0
        else:  # the side most off-plane samples are on
            flip = (h[off] > 0).mean() < 0.5 if off.any() else False
        if flip:
            n_, d_, h = -n_, -d_, -h
        if up is None or n_ @ up >= np.cos(np.radians(45)):
            cands.append((n_, d_, h))
    passing = []
    for k, (n_, d_, h) in enumerate(cands):
        res = _ground_test(s, h, n_, thr, voxel, edges, p_, None)
        log.debug("ground test %d n=(%.2f %.2f %.2f): %s", k, *n_, _fmt(res))
        if res["ok"]:
            passing.append(k)
    best = None
    for k in passing:
        n_, d_, h = cands[k]
        others = np.zeros(len(s), bool)
        for j in passing:
            if j != k:
                others |= np.abs(cands[j][2]) <= thr
        if len(passing) > 1:
            res = _ground_test(s, h, n_, thr, voxel, edges, p_, others)
            log.debug("ground test %d again without the other passing planes: %s", k, _fmt(res))
            if not res["ok"]:
                continue
        support = int((np.abs(h) <= thr).sum())
        if best is None or support > best[2]:
            best = (n_, d_, support)
    return None if best is None else (best[0], best[1])


def _fmt(res: dict) -> str:
    return ", ".join(f"{a} {b:.3g}" for a, b in res.items())


def _ground_test(s, h, n_, thr, voxel, edges, p_: IsolateParams, exclude) -> dict:
    """Measures of one oriented candidate plane (heights ``h`` (M,) of the samples; ``exclude``
    (M,) bool or None: samples left out of what stands on it) and whether it passes as the
    ground: nothing much lies behind it over its largest inlier patch; what stands on it (the
    largest component above it, with the components near it: a pot that a thin stem joins only
    loosely) touches it and rises from it; and the patch is large and wider than that object."""
    out = {"ok": False}
    on = np.flatnonzero(np.abs(h) <= thr)
    if len(on) < 50:
        return out
    # the patch and what lies behind it first (cheap; most leaves and walls fail here)
    basis = plane_basis(n_)
    xy_on = s[on] @ basis
    in_patch, grid, frame = largest_patch(xy_on, 2 * voxel)
    offp = np.flatnonzero(np.abs(h) > thr)
    over = offp[in_grid(s[offp] @ basis, grid, frame)]
    out["below"] = below = float((h[over] < 0).mean()) if len(over) else 0.0
    if below > p_.max_below:
        return out
    above = h > thr
    if exclude is not None:
        above &= ~exclude
    main = _group(s, above, components(edges, above), p_)["group"]  # with what is near it
    if len(main) < 50:
        return out
    lo, hi = np.quantile(h[main], [0.001, 0.99])
    cells = np.unique(np.floor((xy_on[in_patch] - frame[0]) / frame[1]).astype(np.int64), axis=0)
    area = len(cells) * frame[1] ** 2
    width, foot = span(xy_on[in_patch]), span(s[main] @ basis)
    out.update(touch=lo / thr, rise=hi / thr, area=area / hi ** 2 if hi > 0 else 0.0,
               span=width / foot if foot > 0 else 0.0)
    out["ok"] = bool(lo <= 6 * thr and hi > 10 * thr and out["area"] >= p_.min_plane_area
                     and out["span"] >= p_.min_plane_span)
    return out


def _group(s: np.ndarray, off: np.ndarray, comp: np.ndarray, p_: IsolateParams) -> dict:
    """The plant's group among the samples ``s[off]`` (component labels ``comp``, 0 = largest):
    the largest component with the components near it, transitively (a pot and soil, and a
    plant that the 10-NN graph splits into two where a thin stem meets the soil) ("group"), and
    the far ones ("far_members", their class "far_cls": background when large, floater when
    small). Near: within ``near_gap`` x the largest component's size."""
    from scipy.spatial import cKDTree

    off_idx = np.flatnonzero(off)
    out = {"group": off_idx, "far_members": None, "far_cls": None}
    if not len(comp):
        return out
    main = off_idx[comp == 0]
    out["group"] = main
    log.debug("components: %d samples, %d components, the largest %d",
              len(off_idx), int(comp.max()) + 1, len(main))
    if not (comp != 0).any():
        return out
    gap = p_.near_gap * float(np.linalg.norm(np.ptp(s[main], axis=0)))
    joined = np.zeros(int(comp.max()) + 1, bool)
    joined[0] = True
    new = joined.copy()
    for _ in range(16):  # grow by the components near what joined last
        rest = ~joined[comp]
        if not rest.any():
            break
        # bounded queries: far points return inf at once
        d, _ = cKDTree(s[off_idx[new[comp]]]).query(s[off_idx[rest]], k=1,
                                                    distance_upper_bound=gap * 1.0001, workers=_knn.WORKERS)
        dmin = np.full(len(joined), np.inf)
        np.minimum.at(dmin, comp[rest], d)
        new = dmin <= gap
        if not new.any():
            break
        joined |= new
    far = ~joined[comp]
    out["far_members"] = off_idx[far]
    out["far_cls"] = np.where(np.bincount(comp)[comp[far]] >= p_.min_background, BACKGROUND,
                              FLOATER).astype(np.uint8)
    out["group"] = off_idx[~far]
    return out


def _spread(pts, cand_idx, sidx, scls, radius) -> np.ndarray:
    """Classes of every candidate Gaussian from its nearest sample (FLOATER when farther than
    ``radius``); samples keep their own class."""
    out = np.empty(len(cand_idx), np.uint8)
    pos = np.searchsorted(cand_idx, sidx)
    if len(sidx) == len(cand_idx):
        out[:] = scls
        return out
    from scipy.spatial import cKDTree

    tree = cKDTree(pts[sidx])
    q = pts[cand_idx]
    for a in range(0, len(q), 1 << 18):
        d, i = tree.query(q[a:a + (1 << 18)], k=1, distance_upper_bound=radius, workers=_knn.WORKERS)
        c = scls[np.minimum(i, len(scls) - 1)]
        c = np.where(np.isinf(d), FLOATER, c)  # farther than the linking radius from every sample
        out[a:a + len(c)] = c
    out[pos] = scls
    return out


def _plant_floaters(pts, classes, p_: IsolateParams) -> None:
    """Floaters left among the PLANT Gaussians (``classes`` (N,) updated in place): on a fresh
    position-order sample of them alone (so the plant's samples have the same density, and the
    statistics the same population, whether the capture kept a pot and a table or not), a sample
    is a floater when it is a statistical outlier (open3d's rule, ``outlier_neighbors`` /
    ``outlier_std``) AND isolated: at most one other sample within its local linking radius
    (``link`` x the local 4-NN spacing, see ``shapes.knn_graph``: a leaf sampled 12x more
    sparsely than the rest is not a cloud of floaters). A thin or sparsely sampled stem is a statistical
    outlier too (its neighbours lie along a line), but its samples form a chain; cutting a piece
    out of it changed the leaves found (rubber tree, cotton rose: 40 stem Gaussians, 10 to 45
    mIoU points). Every PLANT Gaussian follows its nearest sample."""
    from scipy.spatial import cKDTree

    from leaffit_usd.geometry.outliers import statistical_inliers

    plant = np.flatnonzero(classes == PLANT)
    k = int(p_.outlier_neighbors)
    if len(plant) <= 4 * k:
        return
    sidx = plant[position_order_sample(pts[plant], p_.sample, p_.seed + 2)]
    s = pts[sidx]
    _, _, _, d, local = knn_graph(s, p_.link, k)
    linked = (d[:, 1:] <= local[:, None]).sum(1)
    bad = ~statistical_inliers(s, k, float(p_.outlier_std), distances=d) & (linked <= 1)
    if not bad.any():
        return
    if len(sidx) == len(plant):
        classes[sidx[bad]] = FLOATER
        return
    _, near = cKDTree(s).query(pts[plant], k=1, workers=_knn.WORKERS)
    classes[plant[bad[near]]] = FLOATER

