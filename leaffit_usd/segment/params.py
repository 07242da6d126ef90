"""``SegmentParams``: the automatic segmentation's parameters, declared once (paper defaults
and ours, each with its reason), for both methods (``segment.blades``, the default, and
``segment.apex``, the paper's). See :mod:`leaffit_usd.segment.apex` for the paper's method and
where ours departs from it."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError



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
