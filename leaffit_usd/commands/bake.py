"""``leaffit-usd bake PLANT.usda -o leaves.npz | baked.usda``: explicit leaf meshes."""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError, ParameterError

NAME = "bake"
ORDER = 60
HELP = "evaluate the MLS deformer: write every leaf as an explicit mesh (.npz or .usda)"
DESCRIPTION = """\
Evaluate a LeafFit stage with the CPU reference evaluator and write the explicit, deformed mesh of
every leaf (and the stem), for tools that cannot run the deformer.

  -o leaves.npz   vertices, faces, leaf_vertex_ids (+ leaf_labels, normals, uvs, side,
                  stem_vertices, stem_faces, frame); default: the input capture's frame,
                  coplanar front/back sheets (the exact MLS image of the template)
  -o baked.usda   one Mesh per leaf (+ the stem) with the stage's materials (.usdc/.usd too);
                  default: the asset (stage) frame, so it lines up with the plant, and the
                  sheets pushed apart like the stage's own baked variant

Examples:
  leaffit-usd bake plant.usda -o leaves.npz
  leaffit-usd bake plant.usdz -o baked.usda --frame asset
"""

log = logging.getLogger("leaffit_usd")


def add_arguments(parser) -> None:
    parser.add_argument("stage", help="a LeafFit stage written by 'leaffit-usd convert' "
                                      "(.usda/.usdc/.usdz)")
    parser.add_argument("-o", "--output", required=True,
                        help="output file: .npz (arrays) or .usda/.usdc/.usd (one Mesh per leaf)")
    parser.add_argument("--frame", choices=("input", "asset"), default=None,
                        help="coordinate frame of the output: 'input' = the capture's frame, "
                             "'asset' = the USD stage's frame (default: input for .npz, "
                             "asset for USD)")
    parser.add_argument("--sheets", choices=("coplanar", "separated"), default=None,
                        help="'coplanar' = the exact MLS image (front and back sheets coincide); "
                             "'separated' = sheets pushed apart by the stage's sheetOffset along "
                             "their deformed normals, as the stage's baked variant (no z-fighting "
                             "in viewers that draw back faces). Default: coplanar for .npz, "
                             "separated for USD")
    parser.add_argument("--float64", action="store_true",
                        help="store .npz vertices as float64 instead of float32")


def bake(stage_path, output, frame: str | None = None, float64: bool = False,
         sheets: str | None = None) -> dict:
    """Read ``stage_path``, evaluate it and write ``output``. Returns a small report dict."""
    from leaffit_usd.runtime.bake import NPZ_FORMATS, USD_FORMATS, npz_arrays, write_baked_usd, write_npz
    from leaffit_usd.runtime.evaluator import evaluate
    from leaffit_usd.usd.reader import read_stage

    stage_path, output = Path(stage_path), Path(output)
    ext = output.suffix.lower()
    if ext not in NPZ_FORMATS + USD_FORMATS:
        raise ParameterError("--output", f"a file ending in {', '.join(NPZ_FORMATS + USD_FORMATS)}",
                             str(output))
    if output.exists() and stage_path.exists() and output.resolve() == stage_path.resolve():
        raise ParameterError("--output", "a path other than the input stage", str(output))
    if frame is None:
        frame = "input" if ext in NPZ_FORMATS else "asset"
    if sheets is None:
        sheets = "coplanar" if ext in NPZ_FORMATS else "separated"

    t0 = time.perf_counter()
    asset = read_stage(stage_path)               # InputFileError for missing / non-LeafFit files
    t1 = time.perf_counter()
    dtype = np.float64 if (float64 or ext in USD_FORMATS) else np.float32
    baked = evaluate(asset, frame=frame, dtype=dtype, separate_sheets=(sheets == "separated"))
    t2 = time.perf_counter()
    log.info("evaluated %d leaves x %d vertices (K=%d) in %.1f ms (%s frame)", baked.n_leaves,
             len(asset.template_points), asset.targets.shape[1], 1e3 * (t2 - t1), frame)
    try:
        if ext in NPZ_FORMATS:
            write_npz(output, npz_arrays(baked, asset.template_uvs, asset.template_side))
        else:
            write_baked_usd(output, baked, asset, source=stage_path)
    except OSError as e:
        raise InputFileError(output, f"cannot write: {e.strerror or e}") from None
    t3 = time.perf_counter()
    log.info("wrote %s (%d bytes) in %.1f ms", output, output.stat().st_size, 1e3 * (t3 - t2))
    return {"leaves": baked.n_leaves, "vertices": int(len(baked.vertices)), "frame": frame,
            "sheets": sheets,
            "seconds": {"read": t1 - t0, "evaluate": t2 - t1, "write": t3 - t2}}


def run(args) -> int:
    bake(args.stage, args.output, frame=args.frame, float64=args.float64, sheets=args.sheets)
    return 0
