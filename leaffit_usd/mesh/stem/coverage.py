"""The swept tubes checked against the stem Gaussians: those still outside every tube become
chains (:func:`cover_missed`); a tube or a branch's tail built from a second arc of another
tube's surface is dropped (:func:`_redundant_tubes`, :func:`trim_redundant_tails`).
"""
from __future__ import annotations

import numpy as np

from leaffit_usd.mesh.stem.params import StemParams
from leaffit_usd.mesh.stem.skeleton import drop_subtrees, Skeleton
from leaffit_usd.mesh.stem.level_sets import GraphContext, missed_tubes, SMALL_MIN
from leaffit_usd.mesh.stem.tubes import polyline_distance, sweep, Tube, tube_residual


def _hysteresis(ctx: GraphContext, members: np.ndarray, weak: np.ndarray, strong: np.ndarray) -> np.ndarray:
    """(len(members),) bool: the ``weak`` members connected (neighbour graph, through weak
    members) to a ``strong`` one — a miss is found by its far core and taken whole, out to where
    its Gaussians meet a tube."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    M = len(ctx.idx)
    loc = np.searchsorted(ctx.idx, members)
    w = np.zeros(M, bool)
    w[loc[weak]] = True
    Gc = ctx.G.tocoo()
    e = w[Gc.row] & w[Gc.col]
    _, comp = connected_components(coo_matrix((np.ones(int(e.sum())), (Gc.row[e], Gc.col[e])), shape=(M, M)),
                                   directed=False)
    hit = np.zeros(M, bool)
    hit[np.unique(comp[loc[strong & weak]])] = True
    return weak & hit[comp[loc]]


def cover_tau(tubes: list[Tube], q: np.ndarray, w_thin: float) -> float:
    """How far outside the swept tubes a stem Gaussian q (M, 3) may lie and still be on them:
    three robust standard deviations of all the Gaussians' offsets, at least a quarter of the
    thin tubes' level width."""
    res = tube_residual(tubes, q)
    return max(3.0 * 1.4826 * float(np.median(np.abs(res))), 0.25 * float(w_thin))


def cover_missed(sk: Skeleton, tubes: list[Tube], points: np.ndarray, params: StemParams) -> Skeleton:
    """The skeleton with chains added for the stem Gaussians the swept tubes still miss.

    :func:`missed_tubes` judges the Gaussians against the skeleton's straight node-to-node
    segments with the nodes' spreads as radii; the tubes are swept along smoothed axes with
    radii solved under Leonardo's rule, and pruning, smoothing and seating move them: a petiole's
    last Gaussians beyond its tip, a thin branch's end past a fork, one of two touching parallel
    petioles can end up outside every tube by several of its radii (the true surface there has no
    mesh near it). Those Gaussians go through the same chain building as the first pass: the
    groups of Gaussians outside the tubes by more than the first pass's threshold (three robust
    standard deviations of all the offsets, a quarter of the thin tubes' level width) that
    reach twice as far out somewhere (a miss, not the tubes' own noise). The same skeleton
    (``is``) when none are found.
    """
    from scipy.spatial import cKDTree

    ctx = sk.graph
    if ctx is None or not len(sk.members):
        return sk
    res = tube_residual(tubes, points[sk.members])
    tau = max(3.0 * 1.4826 * float(np.median(np.abs(res))), 0.25 * float(ctx.w_thin))
    off = _hysteresis(ctx, sk.members, res > tau, res > 2.0 * tau)
    if off.sum() < SMALL_MIN:
        return sk
    out = missed_tubes(sk, points, ctx.idx, ctx.G, ctx.g, params, ctx.w_thin, off=off, add_only=True)
    if out is sk:
        return sk
    # the old nodes keep their positions; a new node whose circle fit put it inside an existing
    # tube found that tube's own wall (a second arc of it), not a missed tube: it goes, with
    # what hangs from it
    old = cKDTree(sk.pos).query(out.pos)[0] <= 1e-12
    inside = ~old & (tube_residual(tubes, out.pos) < 0)
    return drop_subtrees(out, inside)


def _surface_gaps(tubes: list[Tube], tree, sides: int) -> list[np.ndarray]:
    """Per tube, (V,) the distance of each vertex of its swept surface (``sides`` per ring, one
    ring per fine axis sample) to the nearest stem Gaussian (``tree``: a cKDTree of them)."""
    out = []
    for tb in tubes:
        v, _ = sweep(tb.axis, tb.radii, sides, False, False)
        out.append(tree.query(v)[0])
    return out


def _gap_reference(gaps: list, i: int) -> float:
    """The capture's own gaps between stem Gaussians, seen from tube surfaces: the 99th
    percentile of ``gaps`` (per tube, each surface sample's distance to the nearest stem Gaussian,
    :func:`_surface_gaps`) over every tube but ``i``. A surface standing out of the data by more
    than a multiple of this is off it (:func:`_redundant_tubes`, :func:`trim_redundant_tails`)."""
    return float(np.percentile(np.concatenate([g for j, g in enumerate(gaps) if j != i]
                                              or [np.zeros(1)]), 99))


def _redundant_tubes(tubes: list[Tube], q: np.ndarray, tau: float, sides: int,
                     share: float = 0.9, stand_out: float = 1.5) -> list[int]:
    """Indices of the terminal branch tubes that explain no Gaussian and stand out of the data.

    - **Explain nothing:** at least ``share`` of the tube's own Gaussians lie within ``tau``
      outside (or inside) the other tubes still kept.
    - **Stand out:** somewhere its surface is farther from every stem Gaussian (``q`` (M, 3))
      than ``stand_out`` x the 99th percentile of that distance over the other tubes' surfaces
      (the capture's own gaps between Gaussians).

    Such a tube was built from a second arc of another tube's surface, swept around an axis that
    lies on that surface: the level sets of a thick petiole leaving a thin branch split the
    petiole's ring in two past the fork, and the far arc became a chain of its own (pothos: the
    end of the branch past the fork got a 0.013 tube, as thick as the petiole, half of it in the
    air 0.02 from any true surface). A tube made of a few Gaussians the other tubes also cover,
    but whose surface lies on the data, stays: it may still be the only mesh over part of a true
    tube. Tubes are judged one at a time against the tubes still kept (most explained, then
    fewest Gaussians, first), so of two tubes that explain each other one stays."""
    from scipy.spatial import cKDTree

    has_kid = {tb.parent_tube for tb in tubes}
    cand = [i for i, tb in enumerate(tubes)
            if tb.parent_tube >= 0 and i not in has_kid and tb.own is not None and len(tb.own)]
    if not cand or not len(q):
        return []
    gaps = _surface_gaps(tubes, cKDTree(q), sides)
    cand = [i for i in cand if float(gaps[i].max()) > stand_out * _gap_reference(gaps, i)]
    if not cand:
        return []
    lo = np.stack([tb.axis.min(0) - tb.radii.max() for tb in tubes])
    hi = np.stack([tb.axis.max(0) + tb.radii.max() for tb in tubes])
    res = {}  # candidate -> (own, tubes) residuals, inf where the tube is out of reach
    for i in cand:
        own = tubes[i].own
        r = np.full((len(own), len(tubes)), np.inf)
        near = ((lo <= own.max(0) + tau) & (hi >= own.min(0) - tau)).all(1)
        near[i] = False
        for j in np.flatnonzero(near):
            r[:, j] = tube_residual([tubes[j]], own)
        res[i] = r
    kept = np.ones(len(tubes), bool)
    while True:
        left = [i for i in cand if kept[i]]
        if not left:
            break
        frac = {}
        for i in left:
            k = kept.copy()
            k[i] = False
            frac[i] = float(np.mean(res[i][:, k].min(1, initial=np.inf) <= tau))
        best = min(left, key=lambda i: (-frac[i], len(tubes[i].own), i))
        if frac[best] < share:
            break
        kept[best] = False
    return [int(i) for i in np.flatnonzero(~kept)]


def drop_redundant(tubes: list[Tube], q: np.ndarray, tau: float, sides: int) -> list[Tube]:
    """The tubes without those of :func:`_redundant_tubes` (nothing hangs from them), parents
    renumbered; every other tube stays as it was swept."""
    gone = set(_redundant_tubes(tubes, q, tau, sides))
    if not gone:
        return tubes
    new = {}
    for i in range(len(tubes)):
        if i not in gone:
            new[i] = len(new)
    out = [tubes[i] for i in sorted(new)]
    for tb in out:
        tb.parent_tube = new.get(tb.parent_tube, -1)
    return out


def trim_redundant_tails(tubes: list[Tube], q: np.ndarray, tau: float, sides: int,
                          share: float = 0.9, stand_out: float = 1.5) -> list[Tube]:
    """The tubes with each branch tube's redundant tail cut off: the part past where its last
    child leaves it, judged as :func:`_redundant_tubes` judges a terminal tube (at least
    ``share`` of the tail's own Gaussians lie within ``tau`` of the other tubes, and its surface
    somewhere stands farther from every stem Gaussian ``q`` (M, 3) than ``stand_out`` x the
    99th percentile of that gap over the other tubes' surfaces). A chain that runs along a
    thin branch's end and then onto a second arc of the thick petiole beside it is one stream
    (the arc is its longer subtree), so the arc is no terminal tube of its own and the terminal
    rule never sees it (pothos_sh3's upper fork: the arc's tube, 0.0105-0.0143 thick around an
    axis on the petiole's surface, stood 0.02 from every true tube). The tail keeps its first
    fine sample past the last child's start (the child still grows out of it) and a rounded tip."""
    from scipy.spatial import cKDTree

    parents = {tb.parent_tube for tb in tubes if tb.parent_tube >= 0}
    cand = [i for i in sorted(parents) if tubes[i].parent_tube >= 0 and tubes[i].own is not None
            and len(tubes[i].own)]
    if not cand or not len(q):
        return tubes
    gaps = _surface_gaps(tubes, cKDTree(q), sides)
    for i in cand:
        tb = tubes[i]
        last = max(float(polyline_distance(c.attach[None], tb.axis)[1][0])
                   for c in tubes if c.parent_tube == i)
        k = int(np.ceil(last)) + 1  # first sample of the tail
        if k >= len(tb.axis) - 2:
            continue
        if float(gaps[i].reshape(len(tb.axis), sides)[k:].max()) <= stand_out * _gap_reference(gaps, i):
            continue
        t_own = polyline_distance(tb.own, tb.axis)[1]
        tail = tb.own[t_own > k]
        if len(tail) < SMALL_MIN:
            continue
        head = Tube(axis=tb.axis[:k + 1], radii=tb.radii[:k + 1], cap_start=False, parent_tube=-1,
                     attach=tb.attach)
        others = [tubes[j] for j in range(len(tubes)) if j != i] + [head]
        if float(np.mean(tube_residual(others, tail) <= tau)) < share:
            continue
        tb.axis, tb.radii, tb.own = tb.axis[:k + 1], tb.radii[:k + 1], tb.own[t_own <= k]
    return tubes
