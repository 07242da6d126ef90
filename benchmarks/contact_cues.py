"""Diagnostic: can a local cue tell a leaf's stalk entry from a second stalk contact on the same
blade (a stem brushing it, a petiole touching both sides of a sinus)?

The blades segmentation splits a blade at every stalk contact (``segment.blades``, step 3). When
one true leaf has two contacts, it is cut in two. This script runs the default segmentation with
the ground-truth up and root, and for every blade with two or more contacts prints, per contact,
four cues and whether it is the true leaf's entry (its contact nearest the root in ``D_r``) or a
spurious one (a further contact of the same true leaf):

* ``cont``: does the stem go on past the contact? The largest ``D_r`` reached through stem graph
  points within ``--reach`` (working units) of the contact's stem neighbours, minus theirs.
* ``cover``: is the stem near the contact under the blade? The share of stem points within
  ``--cover-links`` attachment links of the contact whose projection on the contact's tangent
  plane lands within 1.5 spacings of a point of the blade.
* ``inplane``: how many of the contact's points keep a stem edge inside their tangent plane
  (``|e . n| <= tangent_sin``).

* ``encl``: is the contact surrounded by blade? Per annulus of ``blades.FACE_ANNULI``, the
  share of angular sectors around it (in its tangent plane) holding blade points
  (``blades.contact_sector_shares``). The segmentation drops a contact that fills 15 of 16
  sectors in every annulus (``blades.face_contacts``): a stem touching the blade's face.

A cue separates the cases when the entries' and the spurious contacts' ranges do not overlap;
the summary prints both ranges per cue.

Non-local cues, per pair of touching pieces of one multi-contact blade (the pieces the contacts
own after the split by graph distance), labelled "one leaf" when both pieces' majority
ground-truth leaf is the same and "two leaves" otherwise:

* ``shape_gain``: how much more leaf-like the union is than the worse of the two pieces, against
  the plant's own unsplit leaves: ``|log(aspect / median aspect)| + |log(size / median size)|``
  of the worse piece minus that of the union (aspect = sqrt of the second over the first
  principal variance; size in graph points). Positive: the union looks more like the plant's
  leaves than the pieces do (one leaf cut apart).
* ``solidity``: the union's solidity over the smaller of the pieces' (area of the filled
  occupancy grid in the best-fit plane over its convex hull's): two leaves meeting at a narrow
  contact have a waist.
* ``flatness``: the union's RMS distance from its best-fit plane over the larger of the pieces'.

    .venv/bin/python benchmarks/contact_cues.py [--suite] [--external heliosdev8:1 hard4:1 ...]
        [--gaussians N] [--count N]

It observes the segmentation by wrapping two steps of ``segment.blades`` (``find_leaves`` and
``_attachment_groups``); the labels are not changed. ``--external`` needs ``../shared/plants``
(skipped with a message when it is absent).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from scipy.sparse.csgraph import dijkstra  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

import leaffit_usd.segment.blades as blades  # noqa: E402
from leaffit_usd.geometry.plane import plane_basis  # noqa: E402
from scipy import ndimage  # noqa: E402
from scipy.spatial import ConvexHull  # noqa: E402
from leaffit_usd.segment.auto import SegmentParams, segment_plant, working_normals  # noqa: E402
from leaffit_usd.splats.frame import make_frame  # noqa: E402


def contact_cues(g, sheet, stem, d_root, members, groups, link, params, reach, cover_links):
    """Per contact (a list of graph indices in ``groups``): (cont, cover, inplane, n)."""
    sheet = sheet.tocsr()
    stem_graph = blades._restrict(sheet, stem)
    stem_idx = np.flatnonzero(stem)
    stem_tree = cKDTree(g.points[stem_idx])
    spacing = float(np.median(g.spacing))
    out = []
    for grp in groups:
        nbrs = [sheet.indices[sheet.indptr[i]:sheet.indptr[i + 1]] for i in grp]
        touch = np.unique(np.concatenate([nb[stem[nb]] for nb in nbrs]))
        dist = dijkstra(stem_graph, indices=touch, min_only=True, limit=reach)
        cont = float(np.max(d_root[np.isfinite(dist)]) - np.median(d_root[touch]))
        centre, n = blades.contact_plane(g, grp)
        basis = plane_basis(n)
        radius = cover_links * link
        near = stem_idx[stem_tree.query_ball_point(centre, radius)]
        blade_near = members[np.linalg.norm(g.points[members] - centre, axis=1) < 2 * radius]
        cover = float("nan")
        if len(near) and len(blade_near):
            d2, _ = cKDTree((g.points[blade_near] - centre) @ basis).query((g.points[near] - centre) @ basis)
            cover = float((d2 < 1.5 * spacing).mean())
        inplane = 0
        for i, nb in zip(grp, nbrs):
            e = g.points[nb[stem[nb]]] - g.points[i]
            e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-12)
            inplane += int((np.abs(e @ g.normals[i]) <= params.tangent_sin).any())
        out.append((cont, cover, inplane, len(grp), blades.contact_sector_shares(g, members, grp)))
    return out


def _plane_xy(p):
    """(K, 2) coordinates of (K, 3) points in their best-fit plane, and the RMS off it."""
    c = p - p.mean(0)
    _, sv, vt = np.linalg.svd(c, full_matrices=False)
    return c @ vt[:2].T, float(sv[2] / np.sqrt(len(p)))


def _aspect(p):
    sv = np.linalg.svd(p - p.mean(0), compute_uv=False)
    return float(sv[1] / max(sv[0], 1e-12))


def _solidity(xy, cell):
    lo = xy.min(0) - 2 * cell
    ij = np.floor((xy - lo) / cell).astype(int)
    occ = np.zeros(tuple(ij.max(0) + 3), bool)
    occ[ij[:, 0], ij[:, 1]] = True
    occ = ndimage.binary_fill_holes(ndimage.binary_closing(occ, np.ones((3, 3), bool)))
    return float(occ.sum() * cell * cell / max(ConvexHull(xy).volume, 1e-12))


def pair_cues(g, gb, blade_pieces, gl_domain, exemplar):
    """Rows of the non-local cues for every touching pair of pieces (see the module docstring).
    blade_pieces : list of (members, owner) per multi-contact blade; gl_domain : (M,) ground-truth
    leaf per graph point; exemplar : (median aspect, median size) of the unsplit leaves."""
    aspect0, size0 = exemplar
    cell = 1.5 * float(np.median(g.spacing))

    def unlike(idx):
        return abs(np.log(_aspect(g.points[idx]) / aspect0)) + abs(np.log(len(idx) / size0))

    out = []
    for members, owner in blade_pieces:
        sub = gb[members][:, members].tocoo()
        k = int(owner.max()) + 1
        touch = np.zeros((k, k), int)
        np.add.at(touch, (owner[sub.row], owner[sub.col]), 1)
        for i in range(k):
            for j in range(i + 1, k):
                a, b = members[owner == i], members[owner == j]
                if touch[i, j] == 0 or min(len(a), len(b)) < 20:
                    continue
                u = np.concatenate([a, b])
                (xa, fa), (xb, fb), (xu, fu) = (_plane_xy(g.points[x]) for x in (a, b, u))
                same = np.bincount(np.maximum(gl_domain[a], 0)).argmax() == \
                    np.bincount(np.maximum(gl_domain[b], 0)).argmax()
                out.append(dict(same=bool(same), n=(len(a), len(b)),
                                shape_gain=max(unlike(a), unlike(b)) - unlike(u),
                                solidity=_solidity(xu, cell) / min(_solidity(xa, cell), _solidity(xb, cell)),
                                flatness=fu / max(fa, fb, 1e-12)))
    return out


def observe(name, cloud, gt_labels, frame_choice, args, rows, pairs=None):
    """Segment one plant, appending one row per contact of every multi-contact blade."""
    seen = {}
    find_leaves, attachment_groups = blades.find_leaves, blades._attachment_groups
    params = SegmentParams()

    def wrapped_find(g, sheet, stem, d_root, p):
        seen.update(g=g, sheet=sheet, stem=stem, d_root=d_root, blades=[])
        found = find_leaves(g, sheet, stem, d_root, p)
        if pairs is not None and seen["blades"]:
            unsplit = [np.flatnonzero(found.labels == i + 1) for i, sp in enumerate(found.was_split) if not sp]
            if unsplit:
                ex = (float(np.median([_aspect(g.points[x]) for x in unsplit])),
                      float(np.median([len(x) for x in unsplit])))
                gl = gt_labels[cloud.file_index[g.domain]]
                for r in pair_cues(g, blades._restrict(sheet, ~stem), seen["blades"], gl, ex):
                    pairs.append(dict(plant=name, **r))
                    print(f"{name:24s} pair {r['n'][0]:5d}/{r['n'][1]:<5d} shape_gain {r['shape_gain']:6.2f}  "
                          f"solidity {r['solidity']:5.2f}  flatness {r['flatness']:5.2f}  "
                          f"{'one leaf' if r['same'] else 'two leaves'}", flush=True)
        return found

    def wrapped_groups(g, members, attached, link):
        groups = attachment_groups(g, members, attached, link)
        if len(groups) > 1:
            cues = contact_cues(g, seen["sheet"], seen["stem"], seen["d_root"], members, groups, link,
                                params, args.reach, args.cover_links)
            true_leaf = [int(np.bincount(np.maximum(gt_labels[cloud.file_index[g.domain[grp]]], 0)).argmax())
                         for grp in groups]
            depth = [float(np.median(seen["d_root"][grp])) for grp in groups]
            gb = blades._restrict(seen["sheet"], ~seen["stem"])
            dist = np.stack([dijkstra(gb, indices=grp, min_only=True)[members] for grp in groups])
            seen["blades"].append((members, np.argmin(dist, 0)))
            for k, (cont, cover, inplane, n, encl) in enumerate(cues):
                same = [j for j in range(len(groups)) if true_leaf[j] == true_leaf[k]]
                entry = min(same, key=lambda j: depth[j]) == k
                rows.append(dict(plant=name, leaf=true_leaf[k], n=n, cont=cont, cover=cover,
                                 inplane=inplane, entry=entry,
                                 **{f"encl{i}": e for i, e in enumerate(encl)}))
                print(f"{name:24s} leaf {true_leaf[k]:3d} n {n:3d}  cont {cont:6.3f}  cover {cover:4.2f}  "
                      f"in-plane {inplane:3d}/{n:<3d} encl {' '.join(f'{e:4.2f}' for e in encl)}  "
                      f"{'entry' if entry else 'SPURIOUS'}", flush=True)
        return groups

    blades.find_leaves, blades._attachment_groups = wrapped_find, wrapped_groups
    try:
        pts = frame_choice.frame.to_working(cloud.means)
        segment_plant(pts, frame_choice.root_index, params,
                      normals=working_normals(cloud, frame_choice.frame.rotation))
    finally:
        blades.find_leaves, blades._attachment_groups = find_leaves, attachment_groups


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", action="store_true", help="our samples/ suite (14 plants)")
    ap.add_argument("--external", nargs="*", default=[], metavar="SET:SEED",
                    help="shared sets, e.g. heliosdev8:1 hard4:1")
    ap.add_argument("--gaussians", type=int, default=None, help="external plants at N Gaussians")
    ap.add_argument("--count", type=int, default=None, help="the first N plants of each external set")
    ap.add_argument("--reach", type=float, default=0.05, help="cont: stem reach (working units)")
    ap.add_argument("--cover-links", type=float, default=3.0, help="cover: radius in attachment links")
    args = ap.parse_args(argv)
    rows, pairs = [], []
    if args.suite:
        from samples.generate import benchmark_suite, make_plant

        for name, spec, seed in benchmark_suite():
            cloud, gt = make_plant(spec, seed)
            fc = make_frame(cloud, up=gt.up, root=None, root_index=int(gt.root_index))
            observe(name, cloud, gt.labels, fc, args, rows, pairs)
    if args.external:
        import external_plants as ext
        from leaffit_usd.splats import load_cloud

        if ext.shared_plants_dir() is None:
            print("../shared/plants is absent: skipping the external sets")
        else:
            for item in args.external:
                set_name, seed = item.split(":")
                folder = ext.ensure_set(set_name, int(seed), gaussians=args.gaussians, count=args.count)
                for d in ext.plants(folder):
                    cloud = load_cloud(d / "point_cloud.ply")
                    gt = np.load(d / "gt.npz")
                    fc = make_frame(cloud, up=gt["up"], root=gt["root"])
                    observe(f"{set_name}-{seed}/{d.name}", cloud, gt["labels"], fc, args, rows, pairs)
    entries = [r for r in rows if r["entry"]]
    spurious = [r for r in rows if not r["entry"]]
    print(f"\n{len(rows)} contacts on multi-contact blades: {len(entries)} entries, {len(spurious)} spurious")
    for cue in ("cont", "cover", "inplane_share") + tuple(f"encl{i}" for i in range(len(blades.FACE_ANNULI))):
        def val(r):
            return r["inplane"] / r["n"] if cue == "inplane_share" else r[cue]

        for label, rs in (("entries", entries), ("spurious", spurious)):
            v = np.array([val(r) for r in rs], float)
            v = v[np.isfinite(v)]
            if len(v):
                print(f"  {cue:14s} {label:9s} {v.min():6.3f} .. {v.max():6.3f}  (median {np.median(v):.3f})")
    print(f"\n{len(pairs)} touching pairs of pieces: {sum(r['same'] for r in pairs)} of one leaf, "
          f"{sum(not r['same'] for r in pairs)} of two leaves")
    for cue in ("shape_gain", "solidity", "flatness"):
        for label, same in (("one leaf", True), ("two leaves", False)):
            v = np.array([r[cue] for r in pairs if r["same"] == same], float)
            v = v[np.isfinite(v)]
            if len(v):
                print(f"  {cue:14s} {label:10s} {v.min():6.3f} .. {v.max():6.3f}  (median {np.median(v):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
