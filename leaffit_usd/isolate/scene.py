"""Plant isolation: find the table / ground plane, the pot, the soil, background objects and
floaters in a capture, and keep the plant.

Everything here is in the input frame and free of units: distances are measured against the
capture's own Gaussian spacing and the plant's height above the ground plane. Steps (on a
deterministic subsample of at most ``IsolateParams.sample`` Gaussians; every Gaussian then
follows its nearest sample, or the exact geometric rule where there is one):

1. **Planes** -- open3d's RANSAC ``segment_plane`` on a voxel subsample (area-even), up to
   ``max_planes`` times on what is left. A candidate must be large (its occupied area at least
   ``min_plane_area`` x the squared height of what stands on it) and one-sided (at most
   ``max_below`` of the off-plane points behind it): a leaf, however flat, is small next to its
   plant; a table or floor is not.
2. **Components** -- the samples off every candidate plane are linked to their 10 nearest
   neighbours closer than ``link`` x the median 4-NN spacing (scipy ``connected_components``).
   The largest component is the plant (with its pot and soil); components within ``near_gap``
   of it stay with it; the others are background objects (``min_background`` samples or more)
   or floaters.
3. **Ground** -- the candidate plane the plant's component rests on (its lowest points within a
   few thresholds of the plane): its inliers are GROUND, everything behind it BACKGROUND, and
   its normal (on the plant's side) is the scene's up. Other candidate planes (walls) are
   BACKGROUND.
4. **Outliers** -- open3d's ``remove_statistical_outlier`` on the plant component's samples
   (``outlier_neighbors``, ``outlier_std``): FLOATER.
5. **Pot and soil** (when the up direction is known) -- a circle fitted to the lowest slab of the
   plant's component (Kasa least squares, trimmed) that is wide (>= ``min_pot_radius`` x the
   plant height), round (coverage of the angles) and thin (small residual) is the pot's foot;
   the wall is followed upwards ring by ring while a full circle of Gaussians stays near the
   expected radius; ``r(h)`` is a straight-line fit of the ring radii (a truncated cone). The
   soil is the densest level of up-facing Gaussians inside the rim; everything inside the rim
   below it is soil too. The stem base (``root``) is the middle of the lowest plant Gaussians
   above the soil inside the rim.

A trimmed plant (no plane large enough, no pot) loses only what lies far from it.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.isolate.result import (BACKGROUND, FLOATER, GROUND, PLANT, POT, SOIL,
                                        Isolation)

log = logging.getLogger("leaffit_usd")


@dataclass
class IsolateParams:
    """Parameters of :func:`isolate_plant` (relative: no input units anywhere).

    sample : Gaussians the scene analysis runs on (deterministic random subsample; all when fewer)
    plane_voxels : about this many voxels in the area-even sample given to RANSAC
    plane_threshold : RANSAC inlier distance, x the voxel size
    plane_iterations : RANSAC iterations per plane; max_planes : candidate planes tried
    min_plane_area : a plane's occupied area / (height of what stands on it)^2, at least
    max_below : largest fraction of off-plane points behind a ground plane
    link : component linking radius, x the median distance to the 4th nearest sample
    near_gap : components closer than this x the plant's size to the plant are part of it
    min_background : far components with at least this many samples are background objects
    outlier_neighbors, outlier_std : open3d statistical outlier removal on the plant's samples
        (0 neighbours = off)
    pot : look for a pot and soil; min_pot_radius : smallest pot radius, x plant height
    seed : RANSAC and subsample seed
    """

    sample: int = 200_000
    plane_voxels: int = 20_000
    plane_threshold: float = 1.0
    plane_iterations: int = 1000
    max_planes: int = 4
    min_plane_area: float = 0.15
    max_below: float = 0.2
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
        for name in ("plane_threshold", "min_plane_area", "link", "near_gap", "outlier_std",
                     "min_pot_radius"):
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


# ---- helpers ----------------------------------------------------------------------------------
def _plane_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to unit ``u``."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], axis=1)


def _fit_plane(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through (M, 3) points -> (unit normal (3,), d) with n.x + d = 0."""
    c = p.mean(0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    n = vt[-1] / np.linalg.norm(vt[-1])
    return n, -float(n @ c)


def _components(s: np.ndarray, link: float) -> tuple[np.ndarray, float]:
    """Connected components of samples (M, 3): 10-NN graph with edges shorter than
    ``link`` x median 4-NN distance. Returns (labels (M,) int64 sorted by size: 0 = largest,
    the linking radius)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from leaffit_usd.geometry.knn import knn

    m = len(s)
    if m < 2:
        return np.zeros(m, np.int64), 0.0
    k = min(11, m)
    d, nb = knn(s, k)
    radius = link * float(np.median(d[:, min(4, k - 1)]))
    ok = (d[:, 1:] <= radius)
    rows = np.repeat(np.arange(m), k - 1)[ok.ravel()]
    g = coo_matrix((np.ones(len(rows), np.int8), (rows, nb[:, 1:].ravel()[ok.ravel()])), shape=(m, m))
    _, lab = connected_components(g, directed=False)
    sizes = np.bincount(lab)
    order = np.argsort(-sizes, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[lab].astype(np.int64), radius


def _circle_fit(xy: np.ndarray, iters: int = 4) -> tuple[np.ndarray, float, np.ndarray]:
    """Trimmed Kasa circle fit of (M, 2) points -> (centre (2,), radius, inlier mask (M,))."""
    keep = np.ones(len(xy), bool)
    c, r = xy.mean(0), 0.0
    for _ in range(iters):
        q = xy[keep]
        if len(q) < 6:
            break
        a = np.c_[2 * q, np.ones(len(q))]
        b = (q ** 2).sum(1)
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        c = sol[:2]
        r = float(np.sqrt(max(sol[2] + c @ c, 0.0)))
        res = np.abs(np.linalg.norm(xy - c, axis=1) - r)
        mad = float(np.median(res[keep])) * 1.4826 + 1e-12
        keep = res <= max(2.5 * mad, 0.02 * r)
    return c, r, keep


def _coverage(xy: np.ndarray, c: np.ndarray, bins: int = 24) -> float:
    """Fraction of ``bins`` angular sectors around ``c`` holding at least one of (M, 2) points."""
    if len(xy) == 0:
        return 0.0
    a = np.arctan2(xy[:, 1] - c[1], xy[:, 0] - c[0])
    k = np.floor((a + np.pi) / (2 * np.pi) * bins).astype(int) % bins
    return len(np.unique(k)) / bins


def _sample_index(n: int, k: int, seed: int) -> np.ndarray:
    if n <= k:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, k, replace=False))


# ---- the stage --------------------------------------------------------------------------------
def isolate_plant(cloud, params: IsolateParams | None = None, up: np.ndarray | None = None,
                  crop: Crop | None = None) -> Isolation:
    """Classify every Gaussian of ``cloud`` (a GaussianCloud, input frame) as plant, ground, pot,
    soil, background or floater. See the module docstring for the method.

    up : optional (3,) unit vector, input frame (the user's ``--up``): the ground plane must
        face it, and the pot is looked for along it even without a plane.
    crop : optional region to keep; Gaussians outside are BACKGROUND.
    Returns an :class:`Isolation` (classes in cloud order). Deterministic for a given seed.
    """
    p_ = (params or IsolateParams()).validate()
    t_all = time.perf_counter()
    timings = {}
    pts = np.asarray(cloud.means, np.float64)
    n = len(pts)
    classes = np.zeros(n, np.uint8)
    if crop is not None:
        classes[~crop.contains(pts)] = BACKGROUND
    if up is not None:
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
    cand_idx = np.flatnonzero(classes == PLANT)
    if len(cand_idx) < 50:
        return Isolation(classes, params=p_.to_dict(), timings={"total": time.perf_counter() - t_all})

    # 1. candidate planes ------------------------------------------------------------------
    t0 = time.perf_counter()
    sidx = cand_idx[_sample_index(len(cand_idx), p_.sample, p_.seed)]
    s = pts[sidx]
    planes, voxel = _candidate_planes(s, p_, up)
    timings["planes"] = time.perf_counter() - t0

    # 2. components off the planes, 3. the ground plane ---------------------------------------
    t0 = time.perf_counter()
    thr = p_.plane_threshold * voxel
    scls = np.full(len(s), PLANT, np.uint8)
    ground = None
    if planes:
        # first pass: off every candidate, to find the plane the plant's group stands on
        off = np.ones(len(s), bool)
        for n_, d_, _ in planes:
            off &= np.abs(s @ n_ + d_) > thr
        g1 = _group(s, off, p_)
        ground = _choose_ground(s, g1["group"], planes, thr, up)
        if ground is not None:  # the ground's own noise: the tolerance from here on
            hg = s @ ground[0] + ground[1]
            hg = hg[np.abs(hg) <= thr]
            if len(hg) >= 10:
                thr = float(np.clip(4 * 1.4826 * np.median(np.abs(hg - np.median(hg))), 0.2 * thr, thr))
        # second pass: off the ground only (other candidates may be flat leaves; walls and
        # shelves fall apart into background components anyway)
        off = np.ones(len(s), bool) if ground is None else (s @ ground[0] + ground[1]) > thr
        prefer = g1["group"] if ground is not None else None
        grp = _group(s, off, p_, prefer)
    else:
        grp = _group(s, np.ones(len(s), bool), p_)
    radius = grp["radius"]
    if grp["far_members"] is not None:
        scls[grp["far_members"]] = grp["far_cls"]
    if ground is not None:
        hs = s @ ground[0] + ground[1]
        scls[np.abs(hs) <= thr] = GROUND
        scls[hs < -thr] = BACKGROUND
    timings["components"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # 4. statistical outliers of the plant's samples ----------------------------------------------
    if p_.outlier_neighbors > 0:
        keep = np.flatnonzero(scls == PLANT)
        if len(keep) > 4 * p_.outlier_neighbors:
            import open3d as o3d

            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s[keep]))
            _, inl = pc.remove_statistical_outlier(int(p_.outlier_neighbors), float(p_.outlier_std))
            bad = np.ones(len(keep), bool)
            bad[np.asarray(inl, np.int64)] = False
            scls[keep[bad]] = FLOATER
    timings["outliers"] = time.perf_counter() - t0

    # every Gaussian: its sample's class, the planes' exact rule --------------------------------------
    t0 = time.perf_counter()
    full = _spread(pts, cand_idx, sidx, scls, radius)
    if ground is not None:
        hf = pts[cand_idx] @ ground[0] + ground[1]
        sub = full.copy()
        sub[(np.abs(hf) <= thr) & (sub != BACKGROUND)] = GROUND
        sub[hf < -thr] = BACKGROUND
        full = sub
    classes[cand_idx] = full
    timings["spread"] = time.perf_counter() - t0

    # 5. pot, soil, stem base -------------------------------------------------------------------
    t0 = time.perf_counter()
    up_vec = ground[0] if ground is not None else up
    pot = root = root_index = None
    if p_.pot and up_vec is not None:
        pot, root_index = _pot_and_soil(cloud, pts, classes, up_vec,
                                        None if ground is None else ground[1], thr, p_)
        if root_index is not None:
            root = pts[root_index].copy()
    timings["pot"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_all
    plane = None if ground is None else np.r_[ground[0], ground[1]]
    up_source = "table" if ground is not None else None
    iso = Isolation(classes, up=None if ground is None else ground[0].copy(), up_source=up_source,
                    root=root, root_index=root_index, plane=plane, pot=pot,
                    params={**p_.to_dict(), "crop": None if crop is None else str(crop)},
                    timings=timings)
    return iso


def _group(s: np.ndarray, off: np.ndarray, p_: IsolateParams, prefer: np.ndarray | None = None) -> dict:
    """Components of the samples ``s[off]``: the plant's (the largest, or the one holding most
    of the samples ``prefer``) with the components near it ("group"), and the far ones
    ("far_members", their class "far_cls": background when large, floater when small)."""
    from scipy.spatial import cKDTree

    off_idx = np.flatnonzero(off)
    comp, radius = _components(s[off_idx], p_.link)
    out = {"radius": radius, "group": off_idx, "main": off_idx, "far_members": None, "far_cls": None}
    if not len(comp):
        return out
    main_id = 0
    if prefer is not None and len(prefer):
        pos = np.searchsorted(off_idx, prefer)
        ok = (pos < len(off_idx)) & (off_idx[np.minimum(pos, len(off_idx) - 1)] == prefer)
        if ok.any():
            main_id = int(np.bincount(comp[pos[ok]]).argmax())
    main = off_idx[comp == main_id]
    out["main"] = out["group"] = main
    log.debug("components: %d samples, %d components, plant's %d, link radius %.3g",
              len(off_idx), int(comp.max()) + 1, len(main), radius)
    other = comp != main_id
    if not other.any():
        return out
    size = float(np.linalg.norm(np.ptp(s[main], axis=0)))
    members, mcomp = off_idx[other], comp[other]
    gap = p_.near_gap * size  # bounded queries: far points return inf at once
    d, _ = cKDTree(s[main]).query(s[members], k=1, distance_upper_bound=gap * 1.0001, workers=-1)
    dmin = np.full(int(comp.max()) + 1, np.inf)
    np.minimum.at(dmin, mcomp, d)  # each component's gap to the plant
    counts = np.bincount(comp)
    far = dmin[mcomp] > gap
    out["far_members"] = members[far]
    out["far_cls"] = np.where(counts[mcomp[far]] >= p_.min_background, BACKGROUND, FLOATER).astype(np.uint8)
    out["group"] = np.sort(np.concatenate([main, members[~far]]))
    return out


def _choose_ground(s, group, planes, thr, up):
    """The candidate plane the plant's group stands on -> (unit normal towards it, d) or None.
    Among several (a flat leaf under the pot's rim can pass too), the one with most samples."""
    best = None
    for k, (n_, d_, span) in enumerate(planes):
        support = int((np.abs(s @ n_ + d_) <= thr).sum())
        if not len(group):
            break
        h = s[group] @ n_ + d_
        if np.median(h) < 0:
            n_, d_, h = -n_, -d_, -h
        if up is not None and n_ @ up < np.cos(np.radians(45)):
            continue
        lo, hi = np.quantile(h, [0.001, 0.99])
        xy = s[group] @ _plane_basis(n_)
        foot = float(np.max(np.subtract(*np.quantile(xy, [0.95, 0.05], axis=0))))
        behind = float((h < -thr).mean())
        log.debug("ground test plane %d: lo %.3g hi %.3g thr %.3g behind %.4f span %.3g foot %.3g",
                  k, lo, hi, thr, behind, span, foot)
        # the plant stands on it: touches it, rises well above it, nothing of it behind, and the
        # plane reaches wider than the plant's footprint (a leaf, even a big flat one, does not)
        if lo <= 6 * thr and hi > 10 * thr and behind < 0.01 and span >= 1.2 * foot:
            if best is None or support > best[2]:
                best = (n_, d_, support)
    return None if best is None else (best[0], best[1])


def _candidate_planes(s: np.ndarray, p_: IsolateParams, up) -> tuple[list, float]:
    """Large one-sided planes of the samples (M, 3): list of (unit normal, d, in-plane span of
    the inliers), and the voxel size."""
    import open3d as o3d

    lo, hi = np.quantile(s, [0.005, 0.995], axis=0)
    ext = float(np.linalg.norm(hi - lo)) or 1.0
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s))
    voxel = ext / 100.0
    v = pc.voxel_down_sample(voxel)
    target = min(p_.plane_voxels, len(s) / 4)  # a voxel holds a few samples
    for _ in range(6):  # surfaces: voxel count ~ 1 / size^2
        ratio = len(v.points) / target
        if 0.7 <= ratio <= 1.4:
            break
        voxel *= np.sqrt(ratio)
        v = pc.voxel_down_sample(voxel)
    vp = np.asarray(v.points)
    thr = p_.plane_threshold * voxel
    o3d.utility.random.seed(int(p_.seed))
    planes = []
    rest = np.arange(len(vp))
    for _ in range(int(p_.max_planes)):
        if len(rest) < 100:
            break
        sub = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vp[rest]))
        model, inl = sub.segment_plane(distance_threshold=thr, ransac_n=3,
                                       num_iterations=int(p_.plane_iterations))
        inl = rest[np.asarray(inl, np.int64)]
        if len(inl) < 50:
            break
        # refine to a fixed point of (inliers -> least-squares plane): open3d's parallel RANSAC
        # may return slightly different models run to run; the fixed point does not
        for _ in range(10):
            n_, d_ = _fit_plane(vp[inl])
            if n_[int(np.argmax(np.abs(n_)))] < 0:
                n_, d_ = -n_, -d_
            dist = vp @ n_ + d_
            new = np.flatnonzero(np.abs(dist) <= thr)
            if np.array_equal(new, inl):
                break
            inl = new
        rest = np.setdiff1d(rest, inl)
        offp = dist[np.abs(dist) > 2 * thr]
        if len(offp) < 10:
            continue
        if (offp > 0).mean() < 0.5:
            n_, d_, dist, offp = -n_, -d_, -dist, -offp
        below = (offp < 0).mean()
        height = float(np.quantile(offp[offp > 0], 0.9)) if (offp > 0).any() else 0.0
        xy = vp[inl] @ _plane_basis(n_)
        cells = np.unique(np.floor(xy / (2 * voxel)).astype(np.int64), axis=0)
        area = len(cells) * (2 * voxel) ** 2
        span = float(np.max(np.subtract(*np.quantile(xy, [0.95, 0.05], axis=0))))
        ok = below <= p_.max_below and height > 0 and area >= p_.min_plane_area * height ** 2
        log.debug("plane candidate n=(%.2f %.2f %.2f): %d inliers, area/h^2 %.3f, below %.2f -> %s",
                  *n_, len(inl), area / max(height ** 2, 1e-30), below, ok)
        if ok:
            planes.append((n_, d_, span))
    return planes, voxel


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
        d, i = tree.query(q[a:a + (1 << 18)], k=1, distance_upper_bound=radius, workers=-1)
        c = scls[np.minimum(i, len(scls) - 1)]
        c = np.where(np.isinf(d), FLOATER, c)  # farther than the linking radius from every sample
        out[a:a + len(c)] = c
    out[pos] = scls
    return out


def _pot_and_soil(cloud, pts, classes, up, d0, thr, p_: IsolateParams):
    """Find a pot and its soil among the PLANT Gaussians (classes updated in place).

    up : (3,) unit; d0 : ground plane offset (heights h = pts @ up + d0) or None (heights from
    the plant's lowest point); thr : the ground plane's noise threshold (input units).
    Returns (pot dict or None, root index or None).
    """
    plant = np.flatnonzero(classes == PLANT)
    if len(plant) < 100:
        return None, None
    sel = plant[_sample_index(len(plant), p_.sample, p_.seed + 1)]
    h_all = pts[plant] @ up
    base = -d0 if d0 is not None else float(np.quantile(h_all, 0.001))
    hs = pts[sel] @ up - base
    H = float(np.quantile(hs, 0.99))
    if H <= 0:
        return None, None
    basis = _plane_basis(up)
    xy = pts[sel] @ basis
    slab = 0.04 * H
    foot = hs <= slab
    if foot.sum() < 30:
        return None, None
    c, r, inl = _circle_fit(xy[foot])
    res = np.abs(np.linalg.norm(xy[foot] - c, axis=1) - r)
    if not (p_.min_pot_radius * H <= r <= 0.8 * H) or inl.mean() < 0.5 \
            or _coverage(xy[foot][inl], c) < 0.6 or np.median(res[inl]) > 0.05 * r:
        return None, None
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
            cov = _coverage(xy[tight], c)
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
        return None, None
    slope, icpt = np.polyfit(rings[:, 0], rings[:, 1], 1)

    def r_of(hh):
        return icpt + slope * np.clip(hh, 0, h_top)

    r_top = float(r_of(h_top))
    # every plant Gaussian: height, radial distance
    hp = h_all - base
    xyp = pts[plant] @ basis
    rp = np.linalg.norm(xyp - c, axis=1)
    wall_band = 0.06 * r_of(hp) + thr
    below_rim = hp <= h_top + step
    is_pot = below_rim & (np.abs(rp - r_of(hp)) <= wall_band)
    # soil: the densest level of up-facing Gaussians inside the rim
    inside = (rp < 0.95 * r_top) & (hp > 0.2 * h_top) & (hp < h_top + 0.1 * H) & ~is_pot
    soil_h = None
    is_soil = np.zeros(len(plant), bool)
    cand = np.flatnonzero(inside)
    if len(cand) >= 20:
        nrm = cloud.subset(plant[cand]).shortest_axes()
        flat = np.abs(nrm @ up) > 0.8
        if flat.sum() >= 20:
            hf = hp[cand[flat]]
            bins = np.arange(hf.min(), hf.max() + step / 4, step / 4)
            if len(bins) >= 2:
                hist, edges = np.histogram(hf, bins=bins)
                k = int(np.argmax(hist))
                h0 = 0.5 * (edges[k] + edges[k + 1])
                near0 = np.abs(hf - h0) <= step
                soil_h = float(np.median(hf[near0]))
                sig = 1.4826 * float(np.median(np.abs(hf[near0] - soil_h)))
                tol = max(3.0 * sig, thr)
                # a real soil surface: up-facing Gaussians spread over the rim's disk
                spread = _coverage(xyp[cand[flat]][near0], c, 12)
                if spread >= 0.75 and near0.sum() >= 20:
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
                    is_soil &= ~is_pot
                else:
                    soil_h = None
    classes[plant[is_pot]] = POT
    classes[plant[is_soil]] = SOIL
    pot = {"center": basis @ c + up * base, "axis": up.copy(), "radius_bottom": float(r_of(0.0)),
           "radius_top": r_top, "height": h_top,
           "soil_height": float("nan") if soil_h is None else soil_h}
    log.debug("pot: radius %.4g -> %.4g, height %.4g, soil at %s", pot["radius_bottom"], r_top,
              h_top, soil_h)
    # stem base: lowest remaining plant Gaussians inside the rim
    rest = ~(is_pot | is_soil) & (rp < r_top)
    if rest.sum() == 0:
        return pot, None
    idx = np.flatnonzero(rest)
    hr = hp[idx]
    lo = float(np.quantile(hr, 0.002))
    band = idx[hr <= lo + 0.01 * H]
    med = np.median(pts[plant[band]], axis=0)
    root = plant[band[np.argmin(np.linalg.norm(pts[plant[band]] - med, axis=1))]]
    return pot, int(root)
