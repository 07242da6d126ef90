"""``leaffit-usd isolate INPUT -o OUT.ply``: keep the plant, drop the table, pot, soil,
background and floaters of a capture."""
from __future__ import annotations

import json
import logging

import numpy as np

NAME = "isolate"
HELP = "remove the table, pot, soil, background and floaters from a capture; write the plant"
DESCRIPTION = """\
Plant isolation, the stage 'convert' runs before the frame: finds the ground or table plane
(seeded RANSAC, tested to look like a table from the plant's side), background objects and
floaters (connected components, statistical outliers), the pot (a ring fitted around the stem
axis, followed up its wall) and the soil inside its rim, and keeps the plant. The result is a cleaned capture (.ply, or USD splats for .usd/.usda/.usdc)
in the input frame; its Gaussians are a subset of the input's, in the same order.

--classes writes, per Gaussian of the INPUT file (file order), its class (uint8: 0 plant,
1 ground, 2 pot, 3 soil, 4 background, 5 floater, 255 dropped at load) and 'kept_index' (the
input file index of each Gaussian of OUT), so labels on OUT map back to the input.
--preview draws the capture from the front, the side and the top (up = the table normal when
one was found): kept plant in its colours, ground blue-grey, pot orange, soil brown, background
violet, floaters red.

examples:
  leaffit-usd isolate capture.ply -o plant.ply --preview isolate.png
  leaffit-usd isolate capture.ply -o plant.ply --crop=sphere:0.1,-0.3,1.2,0.8 --classes classes.npz
  leaffit-usd isolate capture.ply -o plant.ply --keep-scene --crop box:0,0,0,1,1,1"""
ORDER = 15

log = logging.getLogger("leaffit_usd")


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import add_isolate_arguments

    p.add_argument("input", metavar="INPUT", help="3DGS capture: INRIA .ply or USD ParticleField3DGaussianSplat")
    p.add_argument("-o", "--output", required=True, metavar="OUT.ply",
                   help="the isolated plant (.ply; .usd/.usda/.usdc for USD splats)")
    p.add_argument("--preview", metavar="ISOLATE.png", help="also draw what was removed (three views)")
    p.add_argument("--classes", metavar="C.npz", help="per-input-Gaussian classes (file order) and kept_index")
    p.add_argument("--report", metavar="R.json", help="write counts per class, the plane, pot and timings as JSON")
    p.add_argument("--prim", default=None, metavar="PATH", help="USD only: the splat prim when there are several")
    p.add_argument("--up", default="auto",
                   help="the up direction when known (+z, -y, X,Y,Z): the ground plane must "
                        "face it and the pot is looked for along it; default auto (the table's normal)")
    add_isolate_arguments(p)


def run(args) -> int:
    from pathlib import Path

    from leaffit_usd.errors import InputFileError, ParameterError
    from leaffit_usd.io_util import atomic_path, atomic_write_bytes
    from leaffit_usd.isolate import CLASS_NAMES
    from leaffit_usd.isolate.stage import isolate_stage
    from leaffit_usd.splats import load_cloud, write_ply

    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix not in (".ply", ".usd", ".usda", ".usdc"):
        raise ParameterError("-o/--output", "a .ply, .usd, .usda or .usdc path", str(out))
    if args.classes and not str(args.classes).lower().endswith(".npz"):
        raise ParameterError("--classes", "a .npz path", args.classes)
    if args.report and not str(args.report).lower().endswith(".json"):
        raise ParameterError("--report", "a .json path", args.report)
    if args.preview:
        from leaffit_usd.commands._args import check_image_output

        check_image_output("--preview", args.preview)
    if not Path(args.input).exists():
        raise InputFileError(args.input, "no such file")
    cloud = load_cloud(args.input, prim=args.prim)
    log.info("%d Gaussians", len(cloud))
    from leaffit_usd.commands._args import parse_up

    plant, iso = isolate_stage(cloud, args.keep_scene, args.crop, parse_up(args.up))
    if suffix == ".ply":
        write_ply(plant, out)
    else:
        from leaffit_usd.splats.usd_io import write_usd_splats

        write_usd_splats(plant, out)
    log.info("%d plant Gaussians -> %s", len(plant), out)
    if args.classes:
        file_classes = cloud.to_file_order(np.asarray(iso.classes, np.uint8), fill=255).astype(np.uint8)
        with atomic_path(args.classes) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, classes=file_classes, kept_index=np.asarray(plant.file_index, np.int64),
                                class_names=np.array(CLASS_NAMES))
        log.info("classes -> %s", args.classes)
    if args.preview:
        from leaffit_usd.isolate.preview import write_isolation_preview

        write_isolation_preview(args.preview, cloud, iso)
        log.info("preview -> %s", args.preview)
    if args.report:
        rep = {"input": str(args.input), "output": str(out), "gaussians": len(cloud),
               "gaussians_in_file": int(cloud.file_count), "kept": len(plant),
               "removed": iso.removed(), "isolation": iso.to_dict()}
        atomic_write_bytes(args.report, (json.dumps(rep, indent=1) + "\n").encode())
    return 0
