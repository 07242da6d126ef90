"""``leaffit-usd segment INPUT -o labels.npz``: automatic leaf instance segmentation."""
from __future__ import annotations

import json
import logging
import time

import numpy as np

from leaffit_usd.commands import _args
from leaffit_usd.determinism import one_blas_thread
from leaffit_usd.errors import ParameterError

NAME = "segment"
HELP = "segment a 3DGS plant into leaves (leaflets) and stem; write labels.npz"
DESCRIPTION = """\
Automatic leaf instance segmentation. The default method (--method blades) tells leaf blades
(sheets: the Gaussians' normals agree) from the stem, petioles and rachises (tubes: the normals
turn round) on a surface graph, measures the heat-method geodesic distance from the root, and
cuts each blade at its stalks and where leaflets meet at their bases. Each leaf gets a
confidence in [0, 1]. A capture of more than 120,000 Gaussians is segmented on a 120,000
random sample (drawn in position order: the file order does not matter) and every other
Gaussian takes its nearest sampled neighbour's label, so a denser capture finds the same leaves
as a 100k one (about 12 s at 1M on 2 cores). --method apex runs the paper's march (LeafFit,
Sec. "Leaf Instance Segmentation": apexes as maxima of the root distance, a rootward tree, the
triangle-inequality grouping, a petiole cut) with our fixes; --paper-rules runs it exactly as
published.

The plant is isolated first, as 'convert' does (table, pot, soil, background, floaters; see
'leaffit-usd isolate'); --keep-scene skips that.

Output (.npz, one row per Gaussian of the INPUT FILE, in file order):
  labels        int32, 0 = stem / unassigned, 1..L = leaves, -1 = removed by isolation (the file
                'convert --labels' takes)
  isolation     uint8, the isolation class (0 plant, 1 ground, 2 pot, 3 soil, 4 background,
                5 floater, 255 dropped at load)
  root_index    int, the root Gaussian (file order)
  apex_indices  int64, every detected apex (file order; blades: each leaf's tip); apex_labels:
                its leaf (0 = none)
  leaf_tip, leaf_base   int64 per leaf (file order)
  tree_nodes, tree_parent, tree_leaf   the rootward tree (nodes in file order; parent indexes
                tree_nodes, -1 at the root; leaf label of each node, 0 = stem)
  dist_root     float32 geodesic distance from the root, working units (plant height 1;
                NaN for Gaussians dropped at load, inf where unreachable)
  confidence    float64 per leaf in [0, 1]: how sure the segmentation is of each leaf (leaves
                under 0.5 are worth a look in 'leaffit-usd edit')
  input_to_working   4x4, the frame the parameters are measured in; params: JSON string

Lengths are in working units (root at 0, +Z up, plant height 1). The up axis, when not given,
comes from the table under the plant or is estimated; with --up and --root given the command
does less work (see README, segmentation timings).

Examples:
  leaffit-usd segment plant.ply -o labels.npz --preview seg.png
  leaffit-usd segment plant.ply -o labels.npz --up +y --root 0.1,-0.4,0.02
  leaffit-usd segment plant.usda -o labels.npz --root-index 1234 --tau 0.4
"""
ORDER = 20

log = logging.getLogger("leaffit_usd")


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import (add_frame_arguments, add_isolate_arguments,
                                            add_segment_arguments, default, pos_int)
    from leaffit_usd.segment.auto import SegmentParams
    from leaffit_usd.segment.edits import add_edits_argument

    from leaffit_usd.commands._args import add_input_argument

    add_input_argument(p)
    p.add_argument("-o", "--output", required=True, metavar="LABELS.npz", help="output labels file (.npz)")
    p.add_argument("--preview", metavar="SEG.png", help="also draw the segmentation (two orthographic views)")
    add_edits_argument(p)
    p.add_argument("--report", metavar="R.json", help="write timings and counts as JSON")
    p.add_argument("--prim", default=None, metavar="PATH", help="USD only: the splat prim when there are several")
    add_frame_arguments(p)
    add_isolate_arguments(p)
    g = add_segment_arguments(p, "parameters (paper defaults, working units: plant height 1)")
    g.add_argument("--seed", type=pos_int,
                   help=f"seed of isolation's samples and the segmentation's random subsets "
                        f"({default(SegmentParams, 'seed')})")


def params_from_args(args):
    """The validated ``SegmentParams`` of a parsed command line."""
    seed = getattr(args, "seed", None)
    return _args.segment_params(args, **({} if seed is None else {"seed": seed}))


# one BLAS thread: segmentation's linear algebra is many small products (benchmarks/
# segment_time.py: 2.64 -> 2.51 s with the up axis estimated, same labels)
@one_blas_thread
def run(args) -> int:
    from leaffit_usd.prepare import FrameOptions, PreparedPlant
    from leaffit_usd.segment.labels_file import write_labels_file
    from leaffit_usd.segment.result import DOUBTFUL_CONFIDENCE
    from leaffit_usd.splats import load_cloud

    if not str(args.output).lower().endswith(".npz"):
        raise ParameterError("-o/--output", "a .npz file", args.output)
    if getattr(args, "preview", None):
        _args.check_image_output("--preview", args.preview)
    params = params_from_args(args)
    t0 = time.perf_counter()
    cloud_in = load_cloud(args.input, prim=args.prim)
    t_read = time.perf_counter() - t0
    t1 = time.perf_counter()
    fo = _args.frame_options(args)
    front = {}
    from leaffit_usd.isolate import IsolateParams

    iso_params = IsolateParams(seed=params.seed)   # one --seed: isolation's samples too
    prep = PreparedPlant.from_cloud(cloud_in, FrameOptions(**fo), iso_params, getattr(args, "keep_scene", False),
                                    getattr(args, "crop", None), timings=front)   # as convert does
    t_iso = front["isolate"]
    cloud, iso, frame = prep.plant, prep.iso, prep.frame
    pts = np.asarray(prep.working.means, np.float64)
    timings = {}
    seg = prep.segment(params, timings=timings)
    t_seg = time.perf_counter() - t1
    labels = seg.labels
    if getattr(args, "edits", None):
        from leaffit_usd.segment.edits import apply_edits_file

        labels = apply_edits_file(seg.labels, cloud, args.edits, args.input)
    fi = cloud.file_index

    def fo(idx):
        return fi[np.asarray(idx, np.int64)].astype(np.int64)

    dist = cloud.to_file_order(seg.dist_root.astype(np.float32), fill=np.nan).astype(np.float32)
    file_labels = prep.file_labels(labels)
    iso_classes = prep.file_classes()
    out = {
        "isolation": iso_classes,
        "apex_indices": fo(seg.apex_indices),
        "apex_labels": seg.apex_labels.astype(np.int32),
        "leaf_tip": fo(seg.leaf_tip),
        "leaf_base": fo(seg.leaf_base),
        "tree_nodes": fo(seg.tree_nodes),
        "tree_parent": seg.tree_parent.astype(np.int64),
        "tree_leaf": seg.tree_leaf.astype(np.int32),
        "dist_root": dist,
        "input_to_working": frame.input_to_working,
        "params": np.array(json.dumps(seg.params)),
    }
    # after edits the automatic leaves' confidence is stale
    conf = None if getattr(args, "edits", None) else np.asarray(seg.confidence, np.float64)
    write_labels_file(args.output, file_labels, root_index=int(fi[seg.root_index]), confidence=conf, **out)
    log.info("%d leaves, %d apexes, %d of %d Gaussians on leaves -> %s", seg.n_leaves,
             len(seg.apex_indices), int((seg.labels > 0).sum()), len(seg.labels), args.output)
    doubtful = [i + 1 for i, c in enumerate(np.asarray(seg.confidence)) if c < DOUBTFUL_CONFIDENCE]
    if doubtful:
        log.info("leaves to check (confidence < 0.5): %s; 'leaffit-usd edit' opens on the least "
                 "confident", ", ".join(map(str, doubtful)))
    if args.preview:
        from leaffit_usd.segment.preview import write_preview

        write_preview(args.preview, pts, seg)
        log.info("preview -> %s", args.preview)
    if args.report:
        from leaffit_usd.io_util import atomic_write_bytes

        rep = {"input": str(args.input), "gaussians": len(cloud_in), "file_gaussians": int(cloud.file_count),
               "gaussians_isolated": len(cloud),
               "leaves": seg.n_leaves, "apexes": int(len(seg.apex_indices)),
               "leaf_sizes": np.bincount(seg.labels, minlength=seg.n_leaves + 1)[1:].tolist(),
               "confidence": [round(float(c), 4) for c in seg.confidence],
               "timings": {"read": t_read, "isolate": t_iso, "segment_total": t_seg, **timings},
               "params": seg.params, "isolation": iso.to_dict(),
               "frame": frame.to_dict(), "root_index": int(fi[seg.root_index])}
        atomic_write_bytes(args.report, json.dumps(rep, indent=1).encode())
    return 0
