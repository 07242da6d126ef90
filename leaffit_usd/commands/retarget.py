"""``leaffit-usd retarget``: swap the plant's template leaf for another species' leaf."""
from __future__ import annotations

import json
import logging
from pathlib import Path

NAME = "retarget"
ORDER = 71
HELP = "replace the template leaf by another species' leaf; every leaf keeps its place and shape"
DESCRIPTION = """\
Cross-species geometry retargeting (LeafFit's 2D cage transfer): the source leaf's outline and the
plant's template outline become two cages (apex -> left side -> petiole base -> right side);
interior samples of the source are carried into the template by mean value coordinates and lifted
with both depth maps; every instance's MLS targets are then refitted so the new leaf covers the
old one. The new stage uses the source leaf's mesh and textures.

  --source-leaf OTHER.usda   another LeafFit plant: its template leaf is used
  --source-leaf LEAF.ply     a 3DGS capture of one leaf (with or without its petiole): it is
                             meshed and baked like a template (base = petiole end, apex = the
                             other end of its long axis)

Example:
  leaffit-usd retarget pepper.usda --source-leaf maple.usda -o pepper_maple.usda --report r.json
"""

log = logging.getLogger("leaffit_usd")


def add_arguments(parser) -> None:
    parser.add_argument("stage", help="the LeafFit plant to retarget (.usda/.usdc/.usdz)")
    parser.add_argument("--source-leaf", required=True,
                        help="a LeafFit stage whose template leaf replaces this plant's, or a "
                             "single-leaf 3DGS capture (.ply / USD splats)")
    parser.add_argument("-o", "--output", required=True, help="the new stage (.usda/.usdc/.usdz)")
    parser.add_argument("--source-base", metavar="X,Y,Z",
                        help="single-leaf capture only: the petiole base (nearest Gaussian, the "
                             "capture's frame); default: detected")
    parser.add_argument("--source-apex", metavar="X,Y,Z",
                        help="single-leaf capture only: the leaf tip; default: detected")
    parser.add_argument("--cage-points", type=int, default=32,
                        help="cage vertices per leaf side (default %(default)s)")
    parser.add_argument("--samples", type=int, default=512,
                        help="interior correspondences (default %(default)s)")
    parser.add_argument("--report", help="write per-instance silhouette IoU etc. as JSON")


def _point(text, name):
    from leaffit_usd.errors import ParameterError

    if text is None:
        return None
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3:
        raise ParameterError(name, "a point X,Y,Z", text)
    return v


def run(args) -> int:
    from leaffit_usd.edit.plant_io import load_plant, save_plant
    from leaffit_usd.edit.retarget import RetargetParams, retarget_asset
    from leaffit_usd.edit.source_leaf import load_source_leaf
    from leaffit_usd.errors import ParameterError
    from leaffit_usd.io_util import atomic_write_bytes

    if args.cage_points < 4:
        raise ParameterError("--cage-points", "an integer >= 4", args.cage_points)
    if args.samples < 16:
        raise ParameterError("--samples", "an integer >= 16", args.samples)
    out = Path(args.output)
    if out.suffix.lower() not in (".usda", ".usdc", ".usd", ".usdz"):
        raise ParameterError("-o/--output", "a .usda/.usdc/.usd/.usdz file", str(out))
    target = load_plant(args.stage)
    source = load_source_leaf(args.source_leaf, _point(args.source_base, "--source-base"),
                              _point(args.source_apex, "--source-apex"))
    new_asset, report = retarget_asset(target.asset, source.asset,
                                       RetargetParams(n_side=args.cage_points, n_samples=args.samples))
    target.asset, target.front, target.back = new_asset, source.front, source.back
    target.texture_format = source.texture_format
    result = save_plant(target, out, source=args.stage)
    if args.report:
        atomic_write_bytes(args.report, json.dumps(report, indent=2).encode())
    log.info("retargeted %d leaves; silhouette IoU min %.3f, mean %.3f; wrote %s",
             report["instances"], report["iou_min"], report["iou_mean"], result.path)
    print(result.path)
    return 0
