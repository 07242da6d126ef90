"""Automatic leaf instance segmentation with heat geodesics (paper Sec. "Leaf Instance Segmentation").

Steps, in the working frame (root at the origin, +Z up, plant height 1; tau, delta, epsilon are in
these units):

1. ``D_r``: heat-method geodesic distance from the root Gaussian (one factorisation, see
   :mod:`leaffit_usd.geometry.heat`).
2. Farthest point sampling to ``N_s`` samples; ``N_k`` Euclidean nearest samples each; apex
   candidates = strict local maxima of ``D_r`` over those neighbours.
3. The rootward tree: from each apex (farthest first) steepest descent of ``D_r``, with the
   deferred-merge rule (a path touching a visited node merges only if its next
   node also touches one); junctions are the nodes where paths meet.
4. ``D_a`` from every apex (all solved together); apexes a, a' are on one leaf when
   ``D_a[a'] < D_a[lca] + D_a'[lca] - tau``; leaves are the connected components.
5. Petiole: from the primary tip (largest ``D_r``) along its path, the local diameter
   ``d = max |p_k - g|`` over the Gaussians with ``|D_a[g] - D_a[p_k]| <= delta/2``; the first node
   past the protection window (fraction ``rho`` of the path from the tip to its first junction)
   with ``d < epsilon`` is the base; the Gaussians with ``D_a`` below the base's are the leaf.

Choices the paper leaves open, and deviations (each with its reason; all switchable):

* Geodesic domain: the operator is built on the N_s FPS samples plus a seeded random subset of the
  Gaussians (``geodesic_points``; random keeps the relative density of thin stems, which FPS and
  voxel grids thin out) and distances are interpolated to every Gaussian; ~0.6 s on 20k points
  instead of ~5 s on 100k, with D_r within ~1% of the plant height of the full solve.
* Floaters (``outlier_factor``) are left out of the geodesics; afterwards those within twice the
  outlier radius of the plant (off-surface fuzz of a leaf) take their nearest Gaussian's label,
  the others stay unassigned. Pieces cut off by a gap narrower than
  ``bridge_gap`` are joined across it; pieces still apart from the root stay unassigned.
* Apex test (``apex_surface_neighbors``): of the N_k Euclidean neighbours only those reachable
  along the surface within the same radius vote; a 512-sample ball around a small leaf's tip
  otherwise reaches into the neighbouring leaf, whose higher D_r vetoes the apex.
* Tree: steepest descent over the geodesic operator's surface graph (a Euclidean neighbourhood
  among the samples leaps across the air between leaves); "the neighbourhood contains a visited
  node" is read as "a visited node lies on the same cross-section ring" (connected piece of the
  D_r iso-band), so paths on opposite sides of a thick stem merge, and paths on two leaves close
  in space never do. Deferred-merge rule as in the paper.
* Petiole (``blade_first``): the base can be found only after the march crossed the blade
  (diameter >= epsilon once), besides the protection window; long tapering tips otherwise stop
  the march early. An instance whose diameter never reaches epsilon has no blade (e.g. the top of
  a bare stem) and is dropped (``require_blade``). From the first node under epsilon the base
  moves on to where the diameter reaches the petiole's own (``base_refine``): a blade's base is
  narrower than epsilon over ~10% of its length.
* Grouping (``lca_on_blade``): besides the tau test, both paths must reach the LCA over a blade
  (a cross-section ring at least epsilon wide just above it); apexes whose paths come down
  petioles to meet on a stem are different leaves, even when touching blades short-cut the
  geodesic between them.
* Lobes (``tau_relative``): the paper's tau = 0.5 is an absolute margin, but its units cannot be
  recovered (delta = 0.01 is "approx. 1 cm", so 1 unit ~ 1 m and tau ~ 50 cm, more than a whole
  potted plant; in our units, plant height 1, no two lobe tips of one leaf are ever 0.5 apart
  along the blade). The test's meaning is "the direct geodesic is clearly shorter than the path
  through the LCA", which scales with the paths involved, so we also group two apexes when
  ``D_a[a'] < (1 - tau_relative) (D_a[lca] + D_a'[lca])`` and both paths, once past their narrow
  tips, stay on the blade all the way to the LCA (no cross-section ring down to it passes the
  petiole rule below: no petiole in between). Why 0.1: two lobe tips a lobe length apart fanning at
  60-90 deg with a sinus at half the lobe length give a ratio of 0.6-0.8 (a deep sinus -> 1);
  apexes of different leaves whose path runs through the stem give 1 minus the heat method's
  error (measured 0.97-0.99). Leaves whose blades touch can short-cut far more (ratios 0.88 on a
  bushy plant), which is why the relative test alone is not enough and needs the no-petiole
  condition (a petiole, or a stem, lies between two leaves' blades; never between two lobes).
  Known cost: where one leaf lies on another (the paper's horizontal-overlap failure) a tip's path
  crosses onto the other blade and the two look like lobes of one blade (ratios 0.73-0.80 on the
  generated overlap plants): hard_horizontal loses a leaf to this rule.
  ``tau_relative = 0`` restores the paper's absolute test alone.
* Petiole (``petiole_relative``): epsilon = 0.05 alone is the width of a blade on long-thin
  (grass-like) or narrow-lobed leaves, whose own width then hovers around it and the march stops
  on the blade. A petiole is a stalk, much narrower than the blade it carries, while a blade's
  width changes little between consecutive delta bands; so the base also needs the diameter under
  ``petiole_relative`` (0.5) x the widest diameter the march has seen on this leaf. Elliptic
  blades narrow smoothly from > 0.1 to the petiole, where both tests hold at once.
* A Gaussian claimed by several leaves goes to the one where it lies deepest (smallest
  ``D_a / base distance``).
* Optionally (``orientation_aware``, off by default) with ``normals`` (each flat Gaussian's
  smallest-scale axis), the geodesic operator drops elements that leave a Gaussian's tangent
  plane, so a leaf lying just above another is not short-cut (never cutting a piece off: see
  :mod:`leaffit_usd.geometry.heat`). It works on clean stacked sheets (tests/geometry) but the
  generated plants' Gaussian axes are noisy enough that it costs more than it gains there.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError, UserError
from leaffit_usd.geometry.heat import GeodesicSolver
from leaffit_usd.geometry.outliers import inlier_mask
from leaffit_usd.geometry.sampling import farthest_point_sampling, position_order_sample
from leaffit_usd.segment.result import Segmentation

log = logging.getLogger("leaffit_usd")


METHODS = ("blades", "apex")


@dataclass
class SegmentParams:
    """Parameters of the automatic segmentation; paper defaults, working units (plant height 1).

    n_samples : N_s, farthest point samples (8192)
    n_neighbors : N_k, Euclidean neighbours among the samples for the apex test (512)
    tau : grouping margin of the triangle-inequality test (0.5)
    delta : width of the iso-geodesic band for the local diameter (0.01)
    epsilon : diameter under which the petiole starts (0.05)
    rho : early protection window, fraction of the tip-to-first-junction path (0.25)
    geodesic_points : extra random Gaussians in the geodesic domain (ours; 12000)
    fps_candidates : FPS runs on a seeded random subset of this many Gaussians (ours; 40000;
        0 = all): FPS costs O(N N_s), 0.6-1.5 s on 100k points, and the subset is still dense
        (~5 Gaussians per sample) so tips and margins are kept
    outlier_factor : a Gaussian whose 8th-neighbour distance exceeds this factor times the median
        is a floater, left unassigned (ours; 4.0 = 16x sparser than typical; 0 disables)
    bridge_gap : pieces of the cloud cut off by a gap narrower than this (working units) are joined
        to the plant across it (ours; 0.05 = epsilon: a gap narrower than a petiole, e.g. a petiole
        that stops short of its blade, is a capture artefact, not a separate object; 0 disables)
    t_coef : heat-method time step as a multiple of h^2 (geometry-central's 1.0)
    orientation_aware : use normals in the geodesic operator when they are given (ours; False:
        on the generated benchmark the Gaussians' smallest axes are too noisy a normal; dropping
        elements by them lowered mIoU on 10 of the 14 benchmark plants, raised it on 4; see
        benchmarks/results/segmentation.json)
    apex_surface_neighbors : of the N_k Euclidean neighbours, the apex test uses only those also
        within reach along the surface (ours; True; False = the paper's test exactly)
    blade_first : the petiole base can only be found after the march has crossed the blade
        (a node with diameter >= epsilon): the protection window's purpose, without its failure on
        long tapering tips (ours; True)
    base_refine : from the first node under epsilon, move on to where the blade has narrowed to
        the petiole's own diameter (ours; True): an elliptic blade's base is narrower than epsilon
        over ~10% of its length, which the paper's rule leaves to the stem
    lca_on_blade : two apexes are grouped only if both their paths come to the LCA over a blade
        (a cross-section ring at least epsilon wide within epsilon of D_r above it), besides the
        tau test (ours; True): paths that come down petioles to meet on a stem belong to
        different leaves, whatever a geodesic short-cut between two touching blades says
    require_blade : drop an instance whose local diameter never reaches epsilon (ours; True)
    tau_relative : (ours; 0.1; 0 = the paper's absolute tau only) also group two apexes when the
        direct geodesic is shorter than (1 - tau_relative) x the path through the LCA and both
        paths stay on the blade (past the tip, no ring narrow enough to be a petiole by the
        epsilon / petiole_relative rule) down to the LCA: lobes of one blade. See the module
        docstring for why a relative margin.
    petiole_relative : (ours; 0.5; 0 = epsilon alone) the petiole base also needs the local
        diameter under this fraction of the widest diameter seen so far on the leaf's march, so a
        blade about epsilon wide (long-thin leaves, narrow lobes) is not cut on itself
    seed : seed of the random domain subset

    method : "blades" (ours, the default: sheets and tubes from the Gaussians' normals, see
        :mod:`leaffit_usd.segment.blades`) or "apex" (the paper's apex -> tree -> petiole march,
        with the deviations above; ``SegmentParams.paper()`` turns those off too)
    The blades method's own parameters (working units; ignored by "apex"):
    domain_points : uniform (voxel) subsample the surface graph is built on (25000)
    graph_k : nearest neighbours joined in the surface graph (10)
    stalk_radius : radius of the normal tensor of the tube test (0.015: a stem or petiole up to
        about this diameter turns its normals through a half circle within it; a leaf blade curved
        less than ~1.3x this radius does not)
    stalk_ratio : a point is a tube where the tensor's second eigenvalue exceeds this fraction of
        its first (0.3: a sheet gives ~0, normals around a tube ~1, a 90-degree fold ~0.2)
    tangent_sin : a sheet edge leaves neither end's tangent plane by more than asin(this) (0.5, 30 deg)
    normal_cos : and joins normals at most acos(this) apart (0.87, 30 deg)
    tube_ratio : a found leaf whose normals over the whole leaf exceed this ratio is a stem piece
        (0.65)
    palm_fraction : two branches of one blade that merge with less than this fraction of their
        size below the saddle are two leaves met at their bases (0.15)
    stalk_narrow : two branches are also two leaves when what lies below their saddle is
        narrower than this fraction of the narrower branch (points per unit of distance from
        the attachment: width x sampling density; 0.75, >= 0; 0 = the palm test alone). Why: on
        a real scan a stalk can be a flat strip that the tube test misses (the MVS tomato
        seedling's hypocotyl of ../shared/real, seen from one side): its two cotyledons met
        above a strip too long for ``palm_fraction`` (0.19 below) and were one leaf; that strip
        is 0.58 and 0.39 of them on the two dates, the lobes of one blade 1.85 or more (every
        saddle between branches of leaf size on paper8, hard4 and heliosdev8 seed 1)
    min_leaf_fraction : smallest leaf, as a fraction of the domain points (0.002)
    attach_link : attachment points within this many median spacings are one stalk's entry (3.0)
    stem_contacts : a sheet piece touching the stem at this many separate places or more (its
        attachments, clustered by ``attach_link``, without those that touch its face:
        ``blades.face_contacts``) is stem, not leaves (4, >= 2). Why: a leaf is entered by its
        stalk; two touching leaves, each on its own stalk, make 2-3 contacts (at most 3 on every
        piece of paper8, hard4 and heliosdev8 seeds 1-3 and the maize scans), while a stretch
        of stem the tube test missed, touching the stem wherever the test held, makes many (7
        on the MVS tomato seedling's lower stem of ../shared/real, which was cut into five
        "leaves" by them). Face contacts do not count: a stem passing under a blade can brush
        it in several places (white_flag_bush in the suite)
    piece_thick : a piece whose normals wrap around (``tube_ratio``) is a tube only when its
        positions say so too: the median over its points of the neighbourhood's thickness
        lambda_3 / lambda_2 (position covariance within 2 and 4 x ``stalk_radius``, the larger)
        exceeds this, or it is ``tube_elongation`` times longer along its axis than across
        (0.2, in [0, 1]; measured: sheets, curled or not, 0.02-0.12 on the maize and tomato
        scans of ../shared/real and on the generated leaves, stems 0.4-0.8). Why: a leaf curled
        along its length, a cupped or folded blade, turns its normals as a tube does, and on
        real scans whole leaves went to the stem that way (benchmarks/real_scans.py)
    blade_thick : a piece found as a leaf (a sheet piece apart from the stem) is a tube by its
        thickness only above this, more than ``piece_thick`` (0.3, in [0, 1]: a half ring of
        tube gives 0.29, a full one 0.67-1). Why: a leaf folded at its midrib or rolled into a U
        is as thick as a stem seen from one side; three whole maize leaves of ../shared/real
        (median 0.20-0.26, their normals wrapping round) went to the stem at 0.2; the stem
        pieces this test found on the generated sets (hard4 apple_uneven, seeds 1-3) are
        0.78-0.90
    tube_elongation : length along the wrap axis over the extent across it above which such a
        piece is a tube (2.0, >= 1: a stem segment is longer than it is thick; a curled leaf is
        only its width long on that axis)
    tube_radial : and only when it is closed round that axis: the median over its points of
        ``|n . r|``, ``r`` the direction to the point from its cross-section's centroid
        (``blades.radial_share``), above this (0.8, in [0, 1]: a ring 1.0, a half ring 0.81, a
        quarter 0.47, a twisted strap ~0). Why: a maize whorl's youngest leaf, rolled and
        twisted along its length, turns its normals about its long axis and passed the
        elongation test alone (two whole leaves of the maize scans of ../shared/real went to
        the stem that way; radial 0.49 and 0.34)
    stem_gap : a tube piece of leaf size and thick across (``piece_thick``) within this many
        ``stalk_radius`` of the stem along the surface graph continues the stem (4.0, >= 0;
        0 = only the root's piece): where a scanner sees a stem from one side or its points
        are noisy, the tube test drops out for a stretch and the stem above was left a "blade"
    max_gaussians : above this many Gaussians the blades method runs on a random subset of this
        many (a seeded sample in position order, so free of file order) and every other Gaussian
        takes the label of its nearest one (120000; 0 = never). Why: the method was designed and
        validated at 15k-115k Gaussians a plant (every benchmark plant); denser input changes what
        the 25k-point surface graph sees (the capture's floaters are ~0.4 % of the Gaussians at
        any density, and the voxel subsample keeps each isolated one, so their share of the graph
        grows with N: 100 of 25k graph points at 100k, 1,000 at 1M), and the same capsicum cut a
        leaf at 1M and merged two at 5M, while each of three random 120k subsets of either gives
        99.8-99.9 mIoU, as at 100k (scratch runs of ``benchmarks/seg_external.py``'s
        ``run_plant`` with the GT root; ``benchmarks/scale.py`` prints the leaves found at 1M
        and 5M)
    """

    n_samples: int = 8192
    n_neighbors: int = 512
    tau: float = 0.5
    delta: float = 0.01
    epsilon: float = 0.05
    rho: float = 0.25
    geodesic_points: int = 12000
    fps_candidates: int = 40000
    outlier_factor: float = 4.0
    bridge_gap: float = 0.05
    t_coef: float = 1.0
    orientation_aware: bool = False
    apex_surface_neighbors: bool = True
    require_blade: bool = True
    blade_first: bool = True
    base_refine: bool = True
    lca_on_blade: bool = True
    tau_relative: float = 0.1
    petiole_relative: float = 0.5
    seed: int = 0
    method: str = "blades"
    domain_points: int = 25000
    graph_k: int = 10
    stalk_radius: float = 0.015
    stalk_ratio: float = 0.3
    tangent_sin: float = 0.5
    normal_cos: float = 0.87
    tube_ratio: float = 0.65
    palm_fraction: float = 0.15
    stalk_narrow: float = 0.75
    min_leaf_fraction: float = 0.002
    attach_link: float = 3.0
    stem_contacts: int = 4
    piece_thick: float = 0.2
    blade_thick: float = 0.3
    tube_elongation: float = 2.0
    tube_radial: float = 0.8
    stem_gap: float = 4.0
    max_gaussians: int = 120_000

    @classmethod
    def paper(cls, **overrides) -> "SegmentParams":
        """The paper's algorithm exactly: the apex method with every deviation of ours off."""
        kw = dict(method="apex", apex_surface_neighbors=False, blade_first=False, base_refine=False,
                  lca_on_blade=False, require_blade=False, orientation_aware=False, tau_relative=0.0,
                  petiole_relative=0.0)
        kw.update(overrides)
        return cls(**kw)

    def validate(self) -> "SegmentParams":
        ints = {"n_samples": 2, "n_neighbors": 1, "geodesic_points": 0, "fps_candidates": 0}
        for name, lo in ints.items():
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < lo:
                raise ParameterError(name, f"an integer >= {lo}", v)
        if not (np.isfinite(self.bridge_gap) and self.bridge_gap >= 0):
            raise ParameterError("bridge_gap", "a number >= 0 (0 disables)", self.bridge_gap)
        for name in ("tau", "delta", "epsilon", "t_coef"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive number (working units)", v)
        if not (np.isfinite(self.outlier_factor) and self.outlier_factor >= 0):
            raise ParameterError("outlier_factor", "a number >= 0 (0 disables)", self.outlier_factor)
        for name in ("tau_relative", "petiole_relative"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v < 1):
                raise ParameterError(name, "a fraction in [0, 1) (0 disables)", v)
        if not (0 <= self.rho < 1):
            raise ParameterError("rho", "a fraction in [0, 1)", self.rho)
        if self.method not in METHODS:
            raise ParameterError("method", " or ".join(METHODS), self.method)
        for name, lo in {"domain_points": 100, "graph_k": 3, "max_gaussians": 0,
                         "stem_contacts": 2}.items():
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < lo:
                raise ParameterError(name, f"an integer >= {lo}", v)
        for name in ("stalk_radius", "attach_link"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ParameterError(name, "a positive number", v)
        for name, lo in {"tube_elongation": 1.0, "stem_gap": 0.0, "stalk_narrow": 0.0}.items():
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= lo):
                raise ParameterError(name, f"a number >= {lo}", v)
        for name in ("stalk_ratio", "tangent_sin", "normal_cos", "tube_ratio", "palm_fraction",
                     "min_leaf_fraction", "piece_thick", "blade_thick", "tube_radial"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise ParameterError(name, "a number in [0, 1]", v)
        return self


@dataclass
class _Tree:
    nodes: list          # domain positions, in insertion order
    parent: list         # index into nodes, -1 for the root
    pos: dict            # domain position -> node index
    ring: np.ndarray | None = None  # (M,) cross-section ring id of every domain point


@dataclass
class _Geodesics:
    """The apex method's geodesic domain and D_r (steps 1-2 of the module docstring).

    solver : the heat-method operator on the FPS samples plus the random domain subset
    inlier : (N,) bool, not a floater (the root always is)
    d_root : (N,) float64 D_r, working units; inf at floaters and pieces apart from the root
    reach : (N,) bool, finite ``d_root``
    samples : (S,) int64 Gaussians, the FPS samples connected to the root (the root included)
    """

    solver: GeodesicSolver
    inlier: np.ndarray
    d_root: np.ndarray
    reach: np.ndarray
    samples: np.ndarray


@dataclass
class _ApexTree:
    """Apexes and the rootward tree (step 3).

    apex_g : (A,) int64 apex Gaussians, largest D_r first
    apex_d : (A,) int64 their domain positions
    tree : the rootward tree over domain positions
    paths : A arrays of tree node indices, apex -> root
    dr_dom : (M,) float64 D_r at the domain points
    """

    apex_g: np.ndarray
    apex_d: np.ndarray
    tree: _Tree
    paths: list
    dr_dom: np.ndarray


@dataclass
class _Leaves:
    """Per apex group (step 5), before the labels.

    groups : (G,) int group ids (sorted); dist : (N, G) float64 D_a from each group's primary tip
    (inf at floaters); keep : columns of the groups that are leaves (a blade was found);
    tip, base : Gaussian indices, base_dist : D_a at the base, one per kept group
    """

    groups: np.ndarray
    dist: np.ndarray
    keep: list
    tip: list
    base: list
    base_dist: list


@dataclass
class _RingWidths:
    """Surface cross-section width at a domain point: its ring's extent, cached per ring.

    x : (M, 3) domain points, working frame; ring : (M,) ring id of each (``_Tree.ring``).
    """

    x: np.ndarray
    ring: np.ndarray
    cache: dict = field(default_factory=dict)

    def __call__(self, node_d: int) -> float:
        r = int(self.ring[node_d])
        if r not in self.cache:
            mem = self.x[self.ring == r]
            self.cache[r] = float(np.sqrt(((mem - self.x[node_d]) ** 2).sum(1).max())) if len(mem) else 0.0
        return self.cache[r]


def segment_plant(points_working: np.ndarray, root_index: int, params: SegmentParams | None = None,
                  normals: np.ndarray | None = None, timings: dict | None = None) -> Segmentation:
    """Automatic leaf instance segmentation of one plant.

    points_working : (N, 3) float, working frame (root at origin, +Z up, height 1)
    root_index : index of the root Gaussian
    params : :class:`SegmentParams` (paper defaults)
    normals : optional (N, 3) float, working frame, each Gaussian's smallest-scale axis (NaN rows
        where it is ill-defined); used by the orientation-aware geodesics
    timings : optional dict filled with seconds per step
    Returns a :class:`Segmentation` with every field filled (indices into ``points_working``).
    Gaussians outside the connected component of the root are left unassigned (0), with a warning.
    """
    p = (params or SegmentParams()).validate()
    pts = _checked_points(points_working)
    n = len(pts)
    if not (isinstance(root_index, (int, np.integer)) and 0 <= root_index < n):
        raise ParameterError("root_index", f"an index in [0, {n})", root_index)
    root = int(root_index)
    tm = timings if timings is not None else {}
    t0 = time.perf_counter()
    if p.method == "blades" and 0 < p.max_gaussians < n:
        return _segment_subset(pts, root, normals, p, tm, t0)
    inlier = inlier_mask(pts, p.outlier_factor)
    inlier[root] = True
    if (~inlier).any():
        log.info("%d isolated Gaussians (floaters) left out of the segmentation", int((~inlier).sum()))
    if p.method == "blades":
        return _segment_blades(pts, root, inlier, normals, p, tm, t0)
    return _segment_apex(pts, root, inlier, normals, p, tm, t0)


def _segment_subset(pts, root, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The blades method on ``p.max_gaussians`` of the Gaussians (see ``SegmentParams``), the
    result extended to all ``N``: each other Gaussian takes the label and D_r (+ the distance) of
    its nearest subset Gaussian, when that one was placed (finite D_r) and is within the
    floater-attach distance (2 x ``outlier_factor`` x the subset's median 8th-neighbour distance,
    as for the subset's own floaters); the rest are floaters (0, infinite D_r)."""
    keep = np.union1d(position_order_sample(pts, p.max_gaussians - 1, p.seed), [root])
    sub = segment_plant(pts[keep], int(np.searchsorted(keep, root)), p,
                        normals=None if normals is None else np.asarray(normals)[keep], timings=tm)
    t1 = time.perf_counter()
    placed = keep[np.isfinite(sub.dist_root)]
    d, j = _nearest_within_reach(pts[placed], pts, p)
    near = np.isfinite(d)
    full_labels = np.zeros(len(pts), np.int32)
    dist = np.full(len(pts), np.inf, np.float32)
    sub_of = np.searchsorted(keep, placed[j[near]])
    full_labels[near] = sub.labels[sub_of]
    dist[near] = sub.dist_root[sub_of] + d[near]
    full_labels[keep] = sub.labels  # the subset keeps its own labels (its floaters too)
    dist[keep] = sub.dist_root
    tm["propagate"] = time.perf_counter() - t1
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation on %d of %d Gaussians, labels propagated to the rest (%.2f s)",
             len(keep), len(pts), tm["propagate"])
    return Segmentation(
        labels=full_labels, root_index=int(root), apex_indices=keep[sub.apex_indices],
        apex_labels=sub.apex_labels, leaf_tip=keep[sub.leaf_tip], leaf_base=keep[sub.leaf_base],
        tree_nodes=keep[sub.tree_nodes], tree_parent=sub.tree_parent, tree_leaf=sub.tree_leaf,
        dist_root=dist, params=asdict(p), confidence=sub.confidence)


def _checked_points(points_working) -> np.ndarray:
    """(N, 3) float64 of the caller's points, or ParameterError / UserError saying what is wrong."""
    pts = np.asarray(points_working, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ParameterError("points", "an (N, 3) array", getattr(pts, "shape", None))
    n = len(pts)
    if n < 8:
        raise UserError(f"the cloud has {n} Gaussians: too few to segment (need at least 8)")
    if not np.isfinite(pts).all():
        raise ParameterError("points", "finite coordinates", "NaN or inf values")
    if float(np.ptp(pts, 0).max()) < 1e-6:
        raise UserError("the cloud has no extent (all Gaussians at one point, working units): "
                        "nothing to segment")
    return pts


def _segment_apex(pts, root, inlier, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The paper's method (steps 1-5 of the module docstring), with our deviations as ``p`` says."""
    n = len(pts)
    samples, domain = _sample_domain(pts, root, inlier, p)
    tm["sampling"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    nrm = normals if (normals is not None and p.orientation_aware) else None
    solver = GeodesicSolver(pts, nrm, domain=domain, t_coef=p.t_coef,
                            bridge_gap=p.bridge_gap if p.bridge_gap > 0 else None)
    tm["geodesic_build"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    geo = _root_distance(solver, root, inlier, samples)
    tm["distance_root"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    apex_g = _find_apexes(pts, geo, root, p)
    tm["apexes"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    at = _apex_tree(geo, apex_g, root, p)
    tm["tree"] = time.perf_counter() - t1
    seg_params = asdict(p)
    if len(apex_g) == 0:
        log.warning("no leaf apex found (no sample is a strict local maximum of the distance "
                    "from the root over its %d neighbours): every Gaussian is stem",
                    int(min(p.n_neighbors, len(geo.samples) - 1)))
        return _result(n, root, solver.domain, at.tree, np.zeros(0, np.int64), np.zeros(0, np.int32),
                       [], [], np.zeros(n, np.int32), geo.d_root, seg_params)
    t1 = time.perf_counter()
    Dd = solver.domain_distances([[int(a)] for a in at.apex_d])  # (M, A) D_a on the domain
    group = _group_apexes(geo, at, Dd, p)
    tm["grouping"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    leaves = _leaf_bases(pts, geo, at, group, Dd, p)
    labels, group_label, leaf_tip, leaf_base = _label_leaves(geo.d_root, leaves)
    labels[~geo.reach | ~inlier] = 0
    if (~inlier).any() and inlier.sum() > 1:
        _attach_outliers(pts, labels, geo.d_root, inlier, geo.reach, p)
    apex_labels = group_label[np.searchsorted(leaves.groups, group)].astype(np.int32)
    tm["petiole_labels"] = time.perf_counter() - t1
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation: %d apexes, %d leaves (%.2f s)", len(apex_g), int(labels.max(initial=0)),
             tm["total"])
    return _result(n, root, solver.domain, at.tree, apex_g, apex_labels, leaf_tip, leaf_base, labels,
                   geo.d_root, seg_params)


def _sample_domain(pts, root, inlier, p: SegmentParams):
    """(samples, domain): (S,) int64 FPS samples of the inliers (the root included) and (M,) int64
    the geodesic domain, the samples plus ``geodesic_points`` random inliers (seeded by ``p.seed``)."""
    rng = np.random.default_rng(p.seed)
    pool = np.flatnonzero(inlier)
    if len(pool) > p.fps_candidates > 0:  # FPS cost is O(N N_s): run it on a random subset
        pool = np.union1d(rng.choice(pool, p.fps_candidates, replace=False), [root])
    start = int(np.searchsorted(pool, root))
    samples = pool[farthest_point_sampling(pts[pool], p.n_samples, start=start)]
    if root not in set(samples.tolist()):
        samples = np.union1d(samples, [root])
    inl = np.flatnonzero(inlier)
    extra = rng.choice(inl, size=min(len(inl), p.geodesic_points), replace=False)
    return samples, np.union1d(samples, extra)


def _root_distance(solver: GeodesicSolver, root, inlier, samples) -> _Geodesics:
    """D_r from the root; floaters and pieces apart from the root are unreached (warned about)."""
    d_root = solver.distance(root)
    d_root[~inlier] = np.inf  # floaters are left out: not reached
    reach = np.isfinite(d_root)
    n = len(d_root)
    lost = int((~reach & inlier).sum())  # connected pieces apart from the root's
    if lost:
        (log.warning if lost > 0.005 * n else log.info)(
            "the cloud is disconnected: %d of %d Gaussians are not connected to the root and stay "
            "unassigned", lost, n)
    return _Geodesics(solver=solver, inlier=inlier, d_root=d_root, reach=reach,
                      samples=samples[reach[samples]])


def _find_apexes(pts, geo: _Geodesics, root, p: SegmentParams) -> np.ndarray:
    """(A,) int64 apex Gaussians, largest D_r first: samples whose D_r is a strict maximum over
    their N_k nearest samples (with ``apex_surface_neighbors``, those also near on the surface)."""
    samples = geo.samples
    sp_pts = pts[samples]
    dr_s = geo.d_root[samples]
    tree_kd = cKDTree(sp_pts)
    nk = int(min(p.n_neighbors, len(samples) - 1))
    apex_local = np.zeros(0, np.int64)
    if nk >= 1:
        kq = int(min(16, nk))
        _, nb16 = tree_kd.query(sp_pts, k=kq + 1, workers=-1)
        # a strict maximum over N_k neighbours is one over its nearest 16 first: test the few
        # survivors against all N_k (same result, ~20x less kNN work)
        cand = np.flatnonzero((dr_s[nb16[:, 1:]] < dr_s[:, None]).all(1) & (samples != root))
        if len(cand):
            d_c, nb_c = tree_kd.query(sp_pts[cand], k=nk + 1, workers=-1)
            d_c, nb_c = d_c.reshape(len(cand), -1), nb_c.reshape(len(cand), -1)
            others = np.where(nb_c == cand[:, None], -1, nb_c)  # drop self
            if p.apex_surface_neighbors:
                others = _surface_filter(geo.solver, samples, cand, others, d_c)
            vals = np.where(others >= 0, dr_s[np.maximum(others, 0)], -np.inf)
            apex_local = cand[(vals < dr_s[cand, None]).all(1)]
    order = apex_local[np.argsort(-dr_s[apex_local], kind="stable")]
    return samples[order]


def _apex_tree(geo: _Geodesics, apex_g, root, p: SegmentParams) -> _ApexTree:
    """The rootward tree through every apex (:func:`_build_tree`)."""
    solver = geo.solver
    dr_dom = geo.d_root[solver.domain]
    tree, paths = _build_tree(solver, dr_dom, apex_g, root, p)
    return _ApexTree(apex_g=apex_g, apex_d=solver.nearest_domain(apex_g), tree=tree,
                     paths=[np.asarray(pth) for pth in paths], dr_dom=dr_dom)


def _group_apexes(geo: _Geodesics, at: _ApexTree, Dd, p: SegmentParams) -> np.ndarray:
    """(A,) int group id per apex: apexes on one leaf (the tau test and ours, see SegmentParams)
    are joined, the groups are the connected components.

    Dd : (M, A) float64 D_a of every apex on the domain points.
    """
    widths = _RingWidths(geo.solver.domain_points, at.tree.ring)
    anc = at.paths  # tree node indices, apex -> root
    A = len(at.apex_g)
    adj_r, adj_c = [], []
    for i in range(A):
        set_i = {v: k for k, v in enumerate(anc[i].tolist())}
        for j in range(i + 1, A):
            lca = next((v for v in anc[j].tolist() if v in set_i), None)
            if lca is None:
                continue
            pos_j = {v: k for k, v in enumerate(anc[j].tolist())}
            if _one_leaf(geo, at, Dd, widths, (i, set_i[lca]), (j, pos_j[lca]), lca, p):
                adj_r.append(i), adj_c.append(j)
    g = coo_matrix((np.ones(len(adj_r)), (adj_r, adj_c)), shape=(A, A))
    return connected_components(g, directed=False)[1]


def _one_leaf(geo: _Geodesics, at: _ApexTree, Dd, widths: _RingWidths, ik, jk, lca,
              p: SegmentParams) -> bool:
    """Are apexes i and j on one leaf? ik, jk : (apex, position of the LCA on its path); lca : the
    LCA's tree node. Lobes of one blade (``tau_relative``), or the paper's tau test (with
    ``lca_on_blade``, both paths coming to the LCA over a blade)."""
    (i, ki), (j, kj) = ik, jk
    lca_d = int(geo.solver.nearest_domain(geo.solver.domain[at.tree.nodes[lca]]))
    direct = 0.5 * (Dd[at.apex_d[j], i] + Dd[at.apex_d[i], j])
    via = Dd[lca_d, i] + Dd[lca_d, j]
    log.debug("apex pair %d,%d: direct %.3f via lca %.3f (lca D_r %.3f)", i, j, direct, via,
              at.dr_dom[at.tree.nodes[lca]])
    if p.tau_relative > 0 and direct < (1 - p.tau_relative) * via and (
            _all_blade(at, widths, i, ki, p) and _all_blade(at, widths, j, kj, p)):
        return True  # lobes of one blade (see tau_relative)
    return bool(direct < via - p.tau and (not p.lca_on_blade or (
        _on_blade(at, widths, i, ki, lca, p) and _on_blade(at, widths, j, kj, lca, p))))


def _on_blade(at: _ApexTree, widths: _RingWidths, i, k_lca, lca, p: SegmentParams) -> bool:
    """Does apex i's path cross a ring at least epsilon wide within epsilon (in D_r) before
    reaching the LCA? (Lobes of one blade meet where the blade fans out; two leaves meet on
    the stem, each coming down a petiole.)"""
    tree = at.tree
    d0 = at.dr_dom[tree.nodes[lca]]
    for v in at.paths[i][:k_lca][::-1].tolist():
        node_d = tree.nodes[v]
        if at.dr_dom[node_d] > d0 + p.epsilon:
            return False
        if widths(node_d) >= p.epsilon:
            return True
    return False


def _all_blade(at: _ApexTree, widths: _RingWidths, i, k_lca, p: SegmentParams) -> bool:
    """Does apex i's path, once past its narrow tip (a ring at least epsilon wide), stay on
    the blade down to the LCA, never passing a petiole (a ring narrower than epsilon and, with
    ``petiole_relative``, than that fraction of the widest ring seen: the petiole rule)?"""
    w = np.asarray([widths(at.tree.nodes[v]) for v in at.paths[i][:k_lca + 1].tolist()])
    wide = np.flatnonzero(w >= p.epsilon)
    if not len(wide):
        return False
    w = w[wide[0]:]
    petiole = w < p.epsilon
    if p.petiole_relative > 0:
        petiole &= w < p.petiole_relative * np.maximum.accumulate(w)
    return not petiole.any()


def _leaf_bases(pts, geo: _Geodesics, at: _ApexTree, group, Dd, p: SegmentParams) -> _Leaves:
    """Per group, D_a from its primary tip (largest D_r) at every Gaussian and the petiole base
    along the tip's path (:func:`_petiole_base`); groups without a blade are dropped when
    ``require_blade``."""
    solver, tree = geo.solver, at.tree
    children = np.zeros(len(tree.nodes), np.int64)
    par = np.asarray(tree.parent)
    np.add.at(children, par[par >= 0], 1)
    groups = np.unique(group)
    tips_j = [int(max(np.flatnonzero(group == gid), key=lambda j: geo.d_root[at.apex_g[j]]))
              for gid in groups]
    D_all = solver.transfer(Dd[:, tips_j], [[int(at.apex_g[j])] for j in tips_j])  # (N, G)
    D_all[~geo.inlier] = np.inf  # a floater's interpolated distance means nothing
    leaves = _Leaves(groups=groups, dist=D_all, keep=[], tip=[], base=[], base_dist=[])
    for col, j in enumerate(tips_j):
        cpath = at.paths[j]
        junction = next((k for k in range(1, len(cpath)) if children[cpath[k]] >= 2), len(cpath) - 1)
        junction_g = int(solver.domain[tree.nodes[cpath[junction]]])
        path_g = solver.domain[np.asarray([tree.nodes[v] for v in at.paths[j].tolist()])]
        base_g, b, has_blade = _petiole_base(pts, D_all[:, col], path_g, junction_g, p)
        if p.require_blade and not has_blade:
            log.info("apex %d: no blade wider than epsilon=%.3g along its path; not a leaf",
                     int(at.apex_g[j]), p.epsilon)
            continue
        leaves.keep.append(col), leaves.tip.append(int(at.apex_g[j]))
        leaves.base.append(base_g), leaves.base_dist.append(b)
    return leaves


def _label_leaves(d_root, leaves: _Leaves):
    """(labels (N,) int32, group_label (G,) int32, leaf_tip, leaf_base): each Gaussian goes to the
    leaf where it lies deepest (smallest D_a / base distance) if that is below 1; leaves are
    numbered 1..L bottom to top (D_r of the base)."""
    n = len(d_root)
    labels = np.zeros(n, np.int32)
    group_label = np.zeros(len(leaves.groups), np.int32)
    leaf_tip, leaf_base = leaves.tip, leaves.base
    if leaves.keep:
        ratio = leaves.dist[:, leaves.keep] / np.maximum(np.asarray(leaves.base_dist), 1e-12)[None]
        best = np.argmin(ratio, axis=1)
        inside = ratio[np.arange(n), best] < 1.0
        # order leaves bottom to top (D_r of the base), deterministic labels 1..L
        rank = np.argsort(np.argsort(d_root[np.asarray(leaf_base)], kind="stable"), kind="stable")
        labels[inside] = (rank[best[inside]] + 1).astype(np.int32)
        for k, col in enumerate(leaves.keep):
            group_label[col] = rank[k] + 1
        perm = np.argsort(rank)
        leaf_tip = np.asarray(leaf_tip, np.int64)[perm]
        leaf_base = np.asarray(leaf_base, np.int64)[perm]
    return labels, group_label, leaf_tip, leaf_base


def _segment_blades(pts, root, inlier, normals, p: SegmentParams, tm: dict, t0: float) -> Segmentation:
    """The default method (:mod:`leaffit_usd.segment.blades`), packed as a Segmentation."""
    from leaffit_usd.segment.blades import segment_blades

    res = segment_blades(pts, root, inlier, normals, p, tm)
    labels = res.labels.copy()
    d_root = res.d_root.copy()
    lost = int((~np.isfinite(d_root) & inlier).sum())
    if lost:
        log.info("the cloud is in pieces: %d of %d Gaussians are not connected to the root (no "
                 "root distance; their leaves are still found)", lost, len(pts))
    if (~inlier).any() and inlier.sum() > 1:
        _attach_outliers(pts, labels, d_root, inlier, np.ones(len(pts), bool), p)
    n_leaves = len(res.leaf_tip)
    tree_leaf = labels[res.tree_nodes].astype(np.int32)
    tm["total"] = time.perf_counter() - t0
    log.info("segmentation: %d leaves (%.2f s)", n_leaves, tm["total"])
    return Segmentation(
        labels=labels.astype(np.int32), root_index=int(root), apex_indices=res.leaf_tip.astype(np.int64),
        apex_labels=np.arange(1, n_leaves + 1, dtype=np.int32), leaf_tip=res.leaf_tip.astype(np.int64),
        leaf_base=res.leaf_base.astype(np.int64), tree_nodes=res.tree_nodes.astype(np.int64),
        tree_parent=res.tree_parent.astype(np.int64), tree_leaf=tree_leaf,
        dist_root=d_root.astype(np.float32), params=asdict(p), confidence=res.confidence)


def _surface_filter(solver, samples, cand, nbrs, dists):
    """Keep, of each candidate's N_k Euclidean neighbours, those also reachable along the surface
    graph within the same radius (the distance to its N_k-th neighbour); the rest become -1.

    A Euclidean ball of N_k = 512 of 8192 samples is about one leaf's area: around the tip of a
    small leaf it reaches across the air gap into a neighbouring leaf, whose higher D_r then
    vetoes the apex. Removing only the neighbours that are not on the same surface patch keeps the
    paper's test (and its robustness to noise) where leaves are apart, and fixes crowded plants.
    """
    from scipy.sparse.csgraph import dijkstra

    graph = solver.adjacency(lengths=True)
    near = solver.nearest_domain
    radius = np.where(np.isfinite(dists), dists, 0).max(1)
    out = nbrs.copy()
    step = 64
    for lo in range(0, len(cand), step):
        c = cand[lo:lo + step]
        geo = dijkstra(graph, indices=near(samples[c]), limit=float(radius[lo:lo + step].max()) * 1.5)
        nb = nbrs[lo:lo + step]
        g = np.take_along_axis(geo, near(samples[np.maximum(nb, 0)]), axis=1)
        # along the surface a neighbour is never closer than in space; allow the graph's detour
        # (paths on a point-cloud graph are ~1.2-1.4x the true geodesic)
        far = ~(g <= 1.5 * radius[lo:lo + step, None])
        out[lo:lo + step] = np.where(far, -1, nb)
    return out


def _attach_outliers(pts, labels, d_root, inlier, reach, p: SegmentParams, k: int = 8) -> None:
    """Isolated Gaussians close to the plant (a leaf's off-surface fuzz) take the label and D_r of
    their nearest segmented Gaussian if it is within 2 x the outlier radius (outlier_factor x the
    median 8th-neighbour distance); farther ones (true floaters) stay unassigned. In place."""
    ok = np.flatnonzero(inlier & reach)
    if len(ok) < k + 1:
        return
    out = np.flatnonzero(~inlier)
    d, j = _nearest_within_reach(pts[ok], pts[out], p, k)
    near = np.isfinite(d)
    labels[out[near]] = labels[ok[j[near]]]
    d_root[out[near]] = d_root[ok[j[near]]] + d[near]


def _nearest_within_reach(src: np.ndarray, query: np.ndarray, p: SegmentParams, k: int = 8):
    """Each query point's nearest ``src`` point (both (n, 3), working frame) if it lies within
    the floater-attach distance, 2 x ``outlier_factor`` x the median distance of src's points to
    their k-th neighbour (measured on at most ~20k of them). Returns (d, j): (Q,) distances, inf
    where none is within reach, and (Q,) indices into src (len(src) there)."""
    tree = cKDTree(src)
    med = float(np.median(tree.query(src[:: max(1, len(src) // 20000)], k=k + 1, workers=-1)[0][:, -1]))
    return tree.query(query, k=1, distance_upper_bound=2 * p.outlier_factor * med, workers=-1)


def _build_tree(solver: GeodesicSolver, dr_dom, apex_g, root, p: SegmentParams):
    """Rootward tree by steepest descent of D_r with the deferred-merge rule.

    The descent runs over the geodesic operator's own surface graph (its triangle and 1-D element
    edges between domain points), so a path never leaps across the air gap between two leaves, as
    a Euclidean neighbourhood among the samples does. "The neighbourhood of p_k contains a visited
    node" is read on the surface too: p_k touches the tree when a visited point lies on the same
    cross-section ring, i.e. in the same connected piece of the D_r iso-band (width
    max(delta, 3 h)) through p_k (the girth of a stem, the width of a blade). Paths on opposite
    sides of a thick stem thus meet at the first ring they share, and paths on two leaves that
    are close in space but not on one surface never do. Deferred merge: the first touch is
    ignored; if the next point touches too, the path attaches to the nearest visited point of its
    ring (the junction).

    dr_dom : (M,) D_r at the domain points; apex_g : (A,) apex Gaussians, farthest first.
    Returns the tree (nodes = domain positions) and per apex its path apex -> root (node indices).
    """
    adj = solver.adjacency()
    ring = _cross_section_rings(solver, adj, dr_dom, p)
    root_d = int(solver.nearest_domain(root))
    tree = _Tree(nodes=[root_d], parent=[-1], pos={root_d: 0}, ring=ring)
    ring_nodes = {int(ring[root_d]): [0]}  # ring id -> tree nodes on it
    paths = []
    for a in apex_g.tolist():
        a_d = int(solver.nearest_domain(a))
        if a_d not in tree.pos:
            chain, attach_node = _descend(solver, adj, dr_dom, tree, ring_nodes, a_d)
            par_node = attach_node
            for v in reversed(chain):
                tree.pos[v] = len(tree.nodes)
                tree.nodes.append(v)
                tree.parent.append(par_node)
                par_node = tree.pos[v]
                ring_nodes.setdefault(int(ring[v]), []).append(par_node)
        paths.append(_path_to_root(tree, tree.pos[a_d]))
    return tree, paths


def _cross_section_rings(solver: GeodesicSolver, adj, dr_dom, p: SegmentParams) -> np.ndarray:
    """(M,) int ring id of each domain point: the connected pieces (over the surface graph
    ``adj``) of the D_r iso-bands of width max(delta, 3 h); unreached points share band -1."""
    m = len(dr_dom)
    w = max(p.delta, 3 * solver.h)
    band = np.where(np.isfinite(dr_dom), np.floor(np.nan_to_num(dr_dom, posinf=-w) / w), -1).astype(np.int64)
    coo = adj.tocoo()
    same = band[coo.row] == band[coo.col]
    sub = coo_matrix((np.ones(int(same.sum())), (coo.row[same], coo.col[same])), shape=(m, m))
    return connected_components(sub, directed=False)[1]


def _descend(solver: GeodesicSolver, adj, dr_dom, tree: _Tree, ring_nodes: dict, start: int):
    """Steepest descent of D_r over the surface graph from domain position ``start`` until the
    path meets the tree (deferred merge). Returns (chain: the new domain positions, start first;
    the tree node the chain's last point attaches to)."""
    x = solver.domain_points
    m = len(x)
    cur, chain, pending, attach_node = start, [start], False, 0
    for _ in range(m + 1):
        hit = _touched(x, tree, ring_nodes, cur)
        if hit >= 0 and pending:
            attach_node = hit
            break
        pending = hit >= 0
        nb = adj.indices[adj.indptr[cur]:adj.indptr[cur + 1]]
        lower = nb[dr_dom[nb] < dr_dom[cur]]
        if len(lower) == 0:  # a local minimum of the graph (noise): look a little wider
            wnb = solver.domain_neighbors(x[cur], int(min(32, m)))
            lower = wnb[dr_dom[wnb] < dr_dom[cur]]
        if len(lower) == 0:
            attach_node = hit if hit >= 0 else 0
            break
        nxt = int(lower[np.argmin(dr_dom[lower])])
        if nxt in tree.pos:
            attach_node = tree.pos[nxt]
            break
        chain.append(nxt)
        cur = nxt
    return chain, attach_node


def _touched(x, tree: _Tree, ring_nodes: dict, c: int) -> int:
    """The tree node on domain point c's ring nearest to it, or -1 when the ring has none."""
    cand = ring_nodes.get(int(tree.ring[c]))
    if not cand:
        return -1
    pos = x[[tree.nodes[t] for t in cand]]
    return int(cand[int(np.argmin(((pos - x[c]) ** 2).sum(1)))])


def _path_to_root(tree: _Tree, node: int) -> list:
    out = []
    while node >= 0:
        out.append(node)
        node = tree.parent[node]
    return out


def _petiole_base(pts, d_a, path_g, junction_g, p: SegmentParams):
    """March from the tip along ``path_g`` (Gaussians, tip -> root); returns (base Gaussian,
    base distance D_a[base], whether some node had a local diameter >= epsilon).

    d_a : (N,) D_a of this leaf's primary tip at every Gaussian; junction_g : the Gaussian at the
    first junction of the tip's path in the paper's tree (the protection window is the first
    ``rho`` of D_a up to it).
    """
    dvals = d_a[path_g]
    protect = p.rho * d_a[junction_g]
    junction = int(np.searchsorted(np.maximum.accumulate(dvals), d_a[junction_g]))
    junction = min(max(junction, 1), len(path_g) - 1)
    fin = np.isfinite(d_a)
    limit = dvals.max() + p.delta
    cand = np.flatnonzero(fin & (d_a <= limit))
    order = cand[np.argsort(d_a[cand], kind="stable")]
    sd = d_a[order]
    has_blade = False

    def diameter(k):
        c = dvals[k]
        lo = np.searchsorted(sd, c - p.delta / 2, side="left")
        hi = np.searchsorted(sd, c + p.delta / 2, side="right")
        band = order[lo:hi]
        return float(np.sqrt(((pts[band] - pts[path_g[k]]) ** 2).sum(1).max())) if len(band) else 0.0

    widest = 0.0
    for k in range(1, len(path_g)):
        c = dvals[k]
        diam = diameter(k)
        widest = max(widest, diam)
        if diam >= p.epsilon:
            has_blade = True
        narrow = diam < p.epsilon and (p.petiole_relative <= 0 or diam < p.petiole_relative * widest)
        if c >= protect and narrow and (has_blade or not p.blade_first):
            if p.base_refine:
                k = _refine_base(k, diam, dvals, diameter, p)
            return int(path_g[k]), float(dvals[k]), has_blade
    # never narrower than epsilon before the root: base at the first junction
    return int(path_g[junction]), float(dvals[junction]), has_blade


def _refine_base(k0, d0, dvals, diameter, p: SegmentParams) -> int:
    """From the first node under epsilon, move on to where the blade has narrowed to the
    petiole's own diameter: the least diameter within 2 epsilon further on (the petiole plateau),
    and the first node within max(1.25 x, + delta) of it."""
    ks = [k0]
    ds = [d0]
    k = k0 + 1
    while k < len(dvals) and dvals[k] <= dvals[k0] + 2 * p.epsilon:
        ks.append(k)
        ds.append(diameter(k))
        k += 1
    plateau = min(ds)
    level = max(1.25 * plateau, plateau + p.delta)
    for kk, dd in zip(ks, ds):
        if dd <= level:
            return kk
    return k0


def _result(n, root, samples, tree, apex_g, apex_labels, leaf_tip, leaf_base, labels, d_root, prm):
    nodes = samples[np.asarray(tree.nodes, np.int64)]
    parent = np.asarray(tree.parent, np.int64)
    return Segmentation(
        labels=labels.astype(np.int32),
        root_index=int(root),
        apex_indices=np.asarray(apex_g, np.int64),
        apex_labels=np.asarray(apex_labels, np.int32),
        leaf_tip=np.asarray(leaf_tip, np.int64),
        leaf_base=np.asarray(leaf_base, np.int64),
        tree_nodes=nodes,
        tree_parent=parent,
        tree_leaf=labels[nodes].astype(np.int32),
        dist_root=d_root.astype(np.float32),
        params=prm,
    )


def working_normals(cloud, rotation: np.ndarray | None = None, flat_ratio: float = 0.5) -> np.ndarray:
    """(N, 3) float64 unit normals of a GaussianCloud's Gaussians (``cloud.shortest_axes()``) in
    the working frame, NaN where the Gaussian is not flat (smallest scale > ``flat_ratio`` x the
    middle one: a round Gaussian's smallest axis says nothing about a surface).
    rotation : (3, 3) input axes -> working axes (``Frame.rotation``); None keeps the input frame.
    """
    n = cloud.shortest_axes().astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    s = np.sort(cloud.scales.astype(np.float64), axis=1)
    if rotation is not None:
        n = n @ np.asarray(rotation, np.float64).T
    n[s[:, 0] > flat_ratio * s[:, 1]] = np.nan
    return n
