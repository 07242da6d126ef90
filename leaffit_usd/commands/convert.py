"""``leaffit-usd convert INPUT -o OUT.usda|usdc|usdz``: the whole pipeline."""
from __future__ import annotations

import json

NAME = "convert"
HELP = "convert a 3DGS plant capture (.ply / USD splats) into a LeafFit USD asset"
DESCRIPTION = """Run the whole LeafFit pipeline: load -> frame (up axis, root) -> segment leaves
-> fit the template leaf to every leaf (MLS) -> template mesh + textures + stem -> USD stage.

Outputs .usda / .usdc (textures in textures/ and the baked-leaves payload beside the stage) or
.usdz (textures packed; the baked payload only with --baked yes). Paper defaults where the paper
is right (--paper-rules, --paper-fit restore it where we differ); every parameter is in working
units (root at the origin, up +Z, plant height 1). A failed conversion leaves no output behind.

examples:
  leaffit-usd convert plant.ply -o plant.usda
  leaffit-usd convert plant.ply -o plant.usdz --height 0.45 --up +y --report report.json
  leaffit-usd convert plant.ply -o plant.usdc --labels labels.npz -K 16 --steps 100"""
ORDER = 10


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import add_frame_arguments, add_segment_arguments
    from leaffit_usd.commands._args import pos_float as _pos_float
    from leaffit_usd.commands._args import pos_int as _pos_int
    from leaffit_usd.segment.edits import add_edits_argument

    def _sigma(text):
        return "auto" if text.strip().lower() == "auto" else _pos_float(text)

    p.add_argument("input", metavar="INPUT",
                   help="3DGS capture: INRIA .ply, .compressed.ply, .spz, .sog, .splat or USD "
                        "ParticleField3DGaussianSplat (see README, input formats)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output stage (.usda, .usdc, .usd or .usdz)")
    p.add_argument("--report", metavar="R.json", help="write timings, counts, sizes and fit errors as JSON")
    add_frame_arguments(p)
    g = add_segment_arguments(p)
    g.add_argument("--labels", metavar="L.npz", help="reuse a segmentation: .npz with 'labels' (int per input Gaussian, file order, 0 = stem)")
    add_edits_argument(g)
    g = p.add_argument_group("fit (paper defaults, except sigma and the refinement: see --paper-fit)")
    g.add_argument("--template", default=None, metavar="ID|auto", help="template leaf: auto (default) or a leaf label")
    g.add_argument("-K", type=_pos_int, default=None, help="control points per leaf (32)")
    g.add_argument("--steps", type=_pos_int, default=None, help="optimisation steps (200)")
    g.add_argument("--lr", type=_pos_float, default=None, help="learning rate (7e-3)")
    g.add_argument("--lam", type=float, default=None, help="Chamfer weight lambda (0.7)")
    g.add_argument("--sigma", type=_sigma, default=None, metavar="auto|S",
                   help="MLS kernel width: auto = 0.7 x the template leaf's size (default), or "
                        "working units (paper: 0.1)")
    g.add_argument("--refine", type=_pos_int, default=None, metavar="N",
                   help="Gauss-Newton refinement iterations after Adam (10; 0 = Adam only)")
    g.add_argument("--paper-fit", action="store_true",
                   help="the paper's registration exactly: sigma 0.1, no refinement")
    g.add_argument("--no-optimize", action="store_true", help="initial correspondence only (ablation)")
    g.add_argument("--seed", type=_pos_int, default=None, help="random seed (0)")
    g = p.add_argument_group("mesh")
    g.add_argument("--vertex-budget", type=_pos_int, default=None, help="template sheet vertices (2048)")
    g.add_argument("--bake-size", type=_pos_int, default=None, help="resolution the textures are baked at (1024)")
    g = p.add_argument_group("output")
    g.add_argument("--up-axis", choices=["Y", "Z", "y", "z"], default="Y", help="the stage's upAxis (Y)")
    g.add_argument("--meters-per-unit", type=_pos_float, default=1.0, help="the stage's metersPerUnit (1)")
    g.add_argument("--height", type=_pos_float, default=None, metavar="M",
                   help="real plant height in metres (default: keep the capture's units)")
    g.add_argument("--texture-format", choices=["jpg", "png"], default="jpg",
                   help="jpg (compact, default) or png (keeps alpha)")
    g.add_argument("--texture-size", type=_pos_int, default=1024, help="longest side of the written textures (1024)")
    g.add_argument("--baked", choices=["auto", "yes", "no"], default="auto",
                   help="baked-leaves payload (variant leafRepresentation=baked) for tools without the "
                        "deformer: auto = beside .usda/.usdc, not packed into .usdz (default)")


def options_from_args(args):
    from leaffit_usd.pipeline import ConvertOptions

    from leaffit_usd.commands._args import frame_options, segment_overrides

    seg = segment_overrides(args)
    from leaffit_usd.fit.register import PAPER_FIT

    fit = dict(PAPER_FIT) if args.paper_fit else {}
    fit.update({k: v for k, v in (("K", args.K), ("steps", args.steps), ("lr", args.lr),
                                  ("lam", args.lam), ("sigma", args.sigma), ("refine", args.refine),
                                  ("seed", args.seed)) if v is not None})
    if args.template is not None:
        t = str(args.template).strip()
        fit["template"] = int(t) if t.isdigit() else t
    if args.no_optimize:
        fit["optimize"] = False
    mesh = {k: v for k, v in (("vertex_budget", args.vertex_budget), ("texture_size", args.bake_size))
            if v is not None}
    return ConvertOptions(
        **frame_options(args), labels=args.labels, edits=args.edits,
        segment=seg, fit=fit, mesh=mesh, up_axis=args.up_axis.upper(),
        meters_per_unit=args.meters_per_unit, height_m=args.height,
        texture_format=args.texture_format, texture_size=args.texture_size, baked={"auto": "auto", "yes": True, "no": False}[args.baked])


def run(args) -> int:
    from pathlib import Path

    from leaffit_usd.errors import InputFileError, ParameterError
    from leaffit_usd.io_util import atomic_write_bytes
    from leaffit_usd.pipeline import convert

    if not Path(args.input).is_file():
        raise InputFileError(args.input, "no such file")
    if args.report and Path(args.report).suffix.lower() != ".json":
        raise ParameterError("--report", "a .json path", args.report)
    report = convert(args.input, args.output, options_from_args(args))
    if args.report:
        atomic_write_bytes(args.report, (json.dumps(report, indent=2) + "\n").encode())
    return 0
