"""Diagnostic: can a local cue tell a leaf's stalk entry from a second stalk contact on the same
blade (a stem brushing it, a petiole touching both sides of a sinus)?

The blades segmentation splits a blade at every stalk contact (``segment.blades``, step 3). When
one true leaf has two contacts, it is cut in two. This script runs the default segmentation with
the ground-truth up and root, and for every blade with two or more contacts prints, per contact,
three cues and whether it is the true leaf's entry (its contact nearest the root in ``D_r``) or a
spurious one (a further contact of the same true leaf):

* ``cont``: does the stem go on past the contact? The largest ``D_r`` reached through stem graph
  points within ``--reach`` (working units) of the contact's stem neighbours, minus theirs.
* ``cover``: is the stem near the contact under the blade? The share of stem points within
  ``--cover-links`` attachment links of the contact whose projection on the contact's tangent
  plane lands within 1.5 spacings of a point of the blade.
* ``inplane``: how many of the contact's points keep a stem edge inside their tangent plane
  (``|e . n| <= tangent_sin``).

A cue separates the cases when the entries' and the spurious contacts' ranges do not overlap;
the summary prints both ranges per cue.

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
        centre = g.points[grp].mean(0)
        nv = g.normals[grp] * np.sign(g.normals[grp] @ g.normals[grp[0]])[:, None]
        n = nv.mean(0) / np.linalg.norm(nv.mean(0))
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
        out.append((cont, cover, inplane, len(grp)))
    return out


def observe(name, cloud, gt_labels, frame_choice, args, rows):
    """Segment one plant, appending one row per contact of every multi-contact blade."""
    seen = {}
    find_leaves, attachment_groups = blades.find_leaves, blades._attachment_groups
    params = SegmentParams()

    def wrapped_find(g, sheet, stem, d_root, p):
        seen.update(g=g, sheet=sheet, stem=stem, d_root=d_root)
        return find_leaves(g, sheet, stem, d_root, p)

    def wrapped_groups(g, members, attached, link):
        groups = attachment_groups(g, members, attached, link)
        if len(groups) > 1:
            cues = contact_cues(g, seen["sheet"], seen["stem"], seen["d_root"], members, groups, link,
                                params, args.reach, args.cover_links)
            true_leaf = [int(np.bincount(np.maximum(gt_labels[cloud.file_index[g.domain[grp]]], 0)).argmax())
                         for grp in groups]
            depth = [float(np.median(seen["d_root"][grp])) for grp in groups]
            for k, (cont, cover, inplane, n) in enumerate(cues):
                same = [j for j in range(len(groups)) if true_leaf[j] == true_leaf[k]]
                entry = min(same, key=lambda j: depth[j]) == k
                rows.append(dict(plant=name, leaf=true_leaf[k], n=n, cont=cont, cover=cover,
                                 inplane=inplane, entry=entry))
                print(f"{name:24s} leaf {true_leaf[k]:3d} n {n:3d}  cont {cont:6.3f}  cover {cover:4.2f}  "
                      f"in-plane {inplane:3d}/{n:<3d} {'entry' if entry else 'SPURIOUS'}", flush=True)
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
    rows = []
    if args.suite:
        from samples.generate import benchmark_suite, make_plant

        for name, spec, seed in benchmark_suite():
            cloud, gt = make_plant(spec, seed)
            fc = make_frame(cloud, up=gt.up, root=None, root_index=int(gt.root_index))
            observe(name, cloud, gt.labels, fc, args, rows)
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
                    observe(f"{set_name}-{seed}/{d.name}", cloud, gt["labels"], fc, args, rows)
    entries = [r for r in rows if r["entry"]]
    spurious = [r for r in rows if not r["entry"]]
    print(f"\n{len(rows)} contacts on multi-contact blades: {len(entries)} entries, {len(spurious)} spurious")
    for cue in ("cont", "cover", "inplane_share"):
        def val(r):
            return r["inplane"] / r["n"] if cue == "inplane_share" else r[cue]

        for label, rs in (("entries", entries), ("spurious", spurious)):
            v = np.array([val(r) for r in rs], float)
            v = v[np.isfinite(v)]
            if len(v):
                print(f"  {cue:14s} {label:9s} {v.min():6.3f} .. {v.max():6.3f}  (median {np.median(v):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
