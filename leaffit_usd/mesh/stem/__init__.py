"""Stem generation: smooth swept tubes along a skeleton of the stem Gaussians (paper, "Stem
Generation", extended).

1. **Skeleton.** The stem Gaussians (label 0) are joined in a k-nearest-neighbour graph;
   isolated specks (floaters) are dropped, pieces of the stem separated by a gap are bridged to
   the root's piece. Geodesic distance from the root over that graph is cut into level sets of
   width ``level_width``; every connected piece of a level set is one skeleton node at the
   centroid of its Gaussians (for a tube sampled around its circumference, the centroid lies on
   the axis), linked to the piece of the previous level it touches. Short terminal spurs are
   pruned. Stem Gaussians off every tube of that skeleton (a thin petiole or a branch base
   that the wide level sets of a thick stem swallowed) become extra chains
   (:func:`missed_tubes`). A branch that shared its parent's level sets past the true fork is
   re-hung where its own direction meets the parent (:func:`continue_branches`). Once the
   tubes are swept, the Gaussians still far outside all of them go through the same chain
   building once more (groups too short for level sets, down to 4 Gaussians, as one node), and
   the tubes are swept again (:func:`cover_missed`). A terminal tube that explains none of
   the Gaussians (the other tubes hold them) and whose surface stands out of the data (a second
   arc of another tube's surface made into a tube of its own) is dropped
   (:func:`_redundant_tubes`); so is such a tail of a branch tube past its last child
   (:func:`trim_redundant_tails`). When the capture has too few stem
   Gaussians the segmentation's rootward tree is the skeleton instead (``skeleton="tree"``, the
   paper's).
2. **Streams.** At every junction the child with the longest subtree continues its parent, so
   the main stem is one tube from the root to its top and every branch / petiole one tube
   starting *on its parent's axis* (the junction is continuous: the branch grows out of the
   parent, no sphere lumps), as thick as itself from the start; the part of a branch hidden
   whole inside its parent is cut off (:func:`seat_branches`).
3. **Smoothing.** Each stream's node centroids (weighted by their Gaussian counts) are
   smoothed by a cubic smoothing spline per coordinate against arc length
   (``scipy.interpolate.make_smoothing_spline``, cut-off ``axis_smoothing`` level widths),
   then resampled with rings every ``ring_spacing`` local radii.
4. **Radii.** Each node's observed radius is the median distance of its Gaussians to the smooth
   axis. Cross-section areas ``a = r^2`` are then solved in one sparse least-squares problem:
   data (each node's observed area, weighted by its Gaussian count) + smoothness along each
   stream + **Leonardo's rule as a regulariser** (``a_parent = sum a_children`` at every
   junction, weight ``leonardo_weight``); a node without data takes the Leonardo/tapering prior
   of the tree (:func:`leaffit_usd.mesh.stem.radii.leonardo_prior`, below). Rows are relative
   (divided by the local area), so thin petioles weigh as much as the trunk.
5. **Tubes.** Rings of ``sides`` vertices, rotation-minimising frames (double reflection), an
   open base (``root_cap`` closes it), and a tapered, closed tip at the end of every stream (a petiole at
   its leaf base): the radius rounds off to a point over ``tip_length`` radii.
6. **Colour.** Every vertex takes the mean colour of its nearest stem Gaussians (vertex colours,
   sRGB in [0, 1]; the writer converts to linear ``displayColor``).

The same skeleton is swept at coarser levels of detail (fewer sides, sparser rings) for the
stage's ``LOD`` variant set (:data:`LOD_LEVELS`).

The tree-based Leonardo rule of the paper (the prior): the area at node ``u`` is
``A = s(t(u)) * n(u) * pi * r_p**2`` with ``n`` the tips it feeds, ``t`` its relative position
from the root (0) to the farthest tip below it (1) and ``s`` interpolated from the root scale
to 1 at the tips, so it holds exactly at every junction.

The modules: :mod:`.params` (``StemParams``), :mod:`.skeleton` (the tree of axis nodes and its
operations), :mod:`.level_sets` (the skeleton from the Gaussians, the missed-tube pass),
:mod:`.tubes` (axes, sweeping, seating, the mesh), :mod:`.radii`, :mod:`.coverage` (the swept
tubes checked against the Gaussians); this one assembles them (:func:`build_stem`).
"""

from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh.result import Stem, StemMesh
from leaffit_usd.mesh.stem.coverage import (cover_missed, cover_tau, drop_redundant,
                                            trim_redundant_tails)
from leaffit_usd.mesh.stem.level_sets import gaussian_skeleton
from leaffit_usd.mesh.stem.params import SKELETONS, StemParams
from leaffit_usd.mesh.stem.radii import (DEFAULT_PETIOLE_RADIUS, DEFAULT_ROOT_RADIUS,
                                         estimate_radii, leonardo_prior, observed_areas,
                                         prior_radii, solve_areas)
from leaffit_usd.mesh.stem.skeleton import Skeleton, stem_edges, tree_skeleton
from leaffit_usd.mesh.stem.tubes import (LOD_LEVELS, seat_branches, stream_tubes, sweep, Tube,
                                         tubes_mesh, vertex_colors)

log = logging.getLogger("leaffit_usd")

__all__ = ["StemParams", "build_stem", "stem_labels", "estimate_radii", "stem_edges", "sweep",
           "Skeleton", "LOD_LEVELS", "SKELETONS", "DEFAULT_ROOT_RADIUS", "DEFAULT_PETIOLE_RADIUS"]


def _empty_stem() -> Stem:
    return Stem(starts=np.zeros((0, 3), np.float32), ends=np.zeros((0, 3), np.float32),
                radii_start=np.zeros(0, np.float32), radii_end=np.zeros(0, np.float32),
                parent=np.zeros(0, np.int64), points=np.zeros((0, 3), np.float32),
                faces=np.zeros((0, 3), np.int32))


def _check_inputs(seg, pts_all: np.ndarray) -> None:
    """Named errors for a points array that is not (N, 3) or a tree that does not index it."""
    if pts_all.ndim != 2 or pts_all.shape[1] != 3:
        raise ParameterError("points_working", "an (N, 3) array", pts_all.shape)
    nodes = np.asarray(seg.tree_nodes, np.int64)
    if len(nodes) and (nodes.min() < 0 or nodes.max() >= len(pts_all)):
        raise ParameterError("seg.tree_nodes", f"indices in [0, {len(pts_all)})",
                             f"range [{nodes.min()}, {nodes.max()}]")
    if len(np.asarray(seg.tree_parent)) != len(nodes) or len(np.asarray(seg.tree_leaf)) != len(nodes):
        raise ParameterError("seg.tree_parent/tree_leaf", f"{len(nodes)} entries (one per tree node)",
                             f"{len(np.asarray(seg.tree_parent))}/{len(np.asarray(seg.tree_leaf))}")


def _choose_skeleton(seg, pts_all: np.ndarray, labels: np.ndarray,
                     params: StemParams) -> tuple[Skeleton | None, str]:
    """(skeleton, kind): the Gaussian skeleton when asked for and possible, else the tree's."""
    sk = None
    kind = "tree"
    if params.skeleton in ("auto", "gaussians") and len(labels) == len(pts_all):
        sk = gaussian_skeleton(pts_all, labels, int(seg.root_index), params)
        kind = "gaussians"
        if sk is None or len(sk.pos) < 2:
            sk = None
            if params.skeleton == "gaussians":
                log.warning("stem: too few stem Gaussians for a skeleton; using the segmentation tree")
    if sk is None:
        sk, kind = tree_skeleton(seg, pts_all), "tree"
        if sk is not None and len(sk.pos) == 2:
            log.warning("stem: the segmentation tree has a single stem edge; the stem is one tapered tube")
    return sk, kind


def _skeleton_tubes(sk: Skeleton, kind: str, seg, pts_all: np.ndarray, fits,
                    params: StemParams) -> tuple[list[Tube], float, float]:
    """(tubes, root radius, petiole radius) of a skeleton: measured radii regularised by
    Leonardo's rule (the prior alone on the tree skeleton), smoothed axes, seated branches."""
    obs, wt = observed_areas(sk, pts_all, params) if kind == "gaussians" else \
        (np.zeros(len(sk.pos)), np.zeros(len(sk.pos)))
    root_r, pet_r = prior_radii(sk, obs, wt, seg, pts_all, fits, params)
    prior = leonardo_prior(sk, float(root_r), float(pet_r))
    # nothing measured (tree skeleton): the prior is the whole answer
    areas = solve_areas(sk, obs, wt, prior, params) if (wt > 0).any() else prior
    areas = np.maximum(areas, (0.25 * pet_r) ** 2)
    return seat_branches(stream_tubes(sk, areas, pts_all, params)), float(root_r), float(pet_r)


def stem_labels(seg) -> np.ndarray:
    """(N,) the segmentation's labels with the unassigned Gaussians it never reached from the
    root set to -1: label 0 means "stem or unassigned", and only the reached ones are stem.
    Why: a piece the segmentation left apart from the plant (``dist_root`` infinite) is not
    stem, but the level-set skeleton bridges gaps and swept a tube through it: the pot-rim
    remnants that isolation kept on two capture-like samples (185 of green_pepper's Gaussians,
    all unreached) became a ring of tubes 0.14 plant heights from the stem
    (``benchmarks/isolation.py --convert``). Labels unchanged when ``dist_root`` is absent."""
    labels = np.asarray(seg.labels)
    d = np.asarray(seg.dist_root)
    if len(d) != len(labels):
        return labels
    return np.where((labels == 0) & ~np.isfinite(d), -1, labels)


def build_stem(seg, points_working, fits=None, params: StemParams | None = None,
               colors=None) -> Stem:
    """The stem as smooth swept tubes (module docstring).

    seg : Segmentation (labels, root_index; tree_nodes, tree_parent, tree_leaf, leaf_base for the
        tree skeleton and the radius prior)
    points_working : (N, 3) float, the Gaussians the segmentation ran on, working frame
    fits : LeafFits or None (unused by the geometry; accepted so callers pass the whole state)
    colors : (N, 3) float sRGB in [0, 1] of those Gaussians, or None (no vertex colours)
    Returns a ``Stem`` (working frame) with LOD0 in points/faces/colors and the coarser levels
    in ``lods``. No stem Gaussians and no stem edges give an empty stem and a warning.
    """
    params = params or StemParams()
    params.validate()
    pts_all = np.asarray(points_working, np.float64)
    _check_inputs(seg, pts_all)
    labels = stem_labels(seg)
    sk, kind = _choose_skeleton(seg, pts_all, labels, params)
    if sk is None or len(sk.pos) < 2:
        log.warning("stem: the segmentation tree has no stem edges and no stem Gaussians; writing no stem")
        return _empty_stem()
    tubes, root_r, pet_r = _skeleton_tubes(sk, kind, seg, pts_all, fits, params)
    if kind == "gaussians" and tubes:
        w_thin = float(sk.graph.w_thin) if sk.graph is not None else float(params.level_width)
        covered = cover_missed(sk, tubes, pts_all, params)
        if covered is not sk:
            sk = covered
            tubes, root_r, pet_r = _skeleton_tubes(sk, kind, seg, pts_all, fits, params)
        q = pts_all[sk.members]
        tau = cover_tau(tubes, q, w_thin)
        tubes = drop_redundant(tubes, q, tau, int(params.sides))
        tubes = trim_redundant_tails(tubes, q, tau, int(params.sides))
    if not tubes:
        log.warning("stem: no tube could be swept; writing no stem")
        return _empty_stem()
    # colour sources: the skeleton's Gaussians, or every stem-labelled one
    src = sk.members if len(sk.members) else np.flatnonzero(labels == 0) if len(labels) == len(pts_all) \
        else np.zeros(0, np.int64)
    col = None if colors is None else np.asarray(colors, np.float64)

    def level(sides, mult):
        v, f, segs = tubes_mesh(tubes, sides, mult, params)
        c = vertex_colors(v, pts_all[src], col[src]) if col is not None and len(src) else None
        return v, f, segs, c

    v, f, (st, en, r0, r1, par), c = level(int(params.sides), 1.0)
    lods = []
    for sides, mult in LOD_LEVELS:
        lv, lf, _, lc = level(min(int(sides), int(params.sides)), mult)
        lods.append(StemMesh(points=lv.astype(np.float32), faces=lf.astype(np.int32),
                             colors=None if lc is None else lc.astype(np.float32)))
    log.info("stem: %s skeleton, %d nodes, %d tubes, %d vertices (LOD0)", kind, len(sk.pos),
             len(tubes), len(v))
    return Stem(starts=st.astype(np.float32), ends=en.astype(np.float32),
                radii_start=r0.astype(np.float32), radii_end=r1.astype(np.float32),
                parent=par, points=v.astype(np.float32), faces=f.astype(np.int32),
                colors=None if c is None else c.astype(np.float32), lods=lods,
                info=dict(skeleton=kind, nodes=int(len(sk.pos)), tubes=len(tubes),
                          root_radius=float(root_r), petiole_radius=float(pet_r)))
