"""``leaffit-usd convert INPUT -o OUT.usda|usdc|usdz``: the whole pipeline."""
from __future__ import annotations

import json

NAME = "convert"
HELP = "convert a 3DGS plant capture (.ply / USD splats) into a LeafFit USD asset"
DESCRIPTION = """Run the whole LeafFit pipeline: load -> isolate the plant (table, pot, soil,
background and floaters removed; the table normal and the stem base at the soil set the frame)
-> frame (up axis, root) -> segment leaves
-> fit the template leaf to every leaf (MLS) -> template mesh + textures + stem -> USD stage.

Outputs .usda / .usdc (textures in textures/ and the baked-leaves payload beside the stage) or
.usdz (textures packed; the baked payload only with --baked yes), or glTF 2.0 .glb / .gltf
(the evaluated leaves + stem, metres, +Y up; --instanced: template + GPU instancing). Paper defaults where the paper
is right (--paper-rules, --paper-fit restore it where we differ); every parameter is in working
units (root at the origin, up +Z, plant height 1). A failed conversion leaves no output behind.

examples:
  leaffit-usd convert plant.ply -o plant.usda
  leaffit-usd convert plant.ply -o plant.usdz --height 0.45 --up +y --report report.json
  leaffit-usd convert plant.ply -o plant.usdc --labels labels.npz -K 16 --steps 100
  leaffit-usd convert plant.ply -o plant.glb --height 0.45"""
ORDER = 10


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import add_input_argument

    add_input_argument(p)
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output stage (.usda, .usdc, .usd or .usdz) or glTF (.glb, .gltf)")
    p.add_argument("--report", metavar="R.json", help="write timings, counts, sizes (each file, and each prim's share of the stage's data) and fit errors as JSON")
    add_options(p)


def add_options(p) -> None:
    """The conversion options (frame, isolation, segmentation, fit, mesh, output), read back by
    :func:`options_from_args`; shared with ``batch``."""
    from leaffit_usd.commands._args import (add_frame_arguments, add_isolate_arguments,
                                            add_segment_arguments, default, pos_float, pos_int)
    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.mesh.params import MeshParams
    from leaffit_usd.segment.edits import add_edits_argument
    from leaffit_usd.usd.writer import TEXTURE_FORMATS, WriteOptions

    def _sigma(text):
        return "auto" if text.strip().lower() == "auto" else pos_float(text)

    def fit(name):
        return default(FitParams, name)

    add_frame_arguments(p)
    add_isolate_arguments(p)
    g = add_segment_arguments(p)
    g.add_argument("--labels", metavar="L.npz", help="reuse a segmentation: .npz with 'labels' (int per input Gaussian, file order, 0 = stem)")
    add_edits_argument(g)
    g = p.add_argument_group("fit (Gauss-Newton; paper defaults otherwise, except K, sigma and the regulariser: see --paper-fit)")
    g.add_argument("--template", default=None, metavar="ID|auto",
                   help=f"template leaf: auto or a leaf label ({fit('template')})")
    g.add_argument("-K", type=pos_int, default=None, help=f"control points per leaf ({fit('K')})")
    g.add_argument("--steps", type=pos_int, default=None, help=f"Adam steps before Gauss-Newton ({fit('steps')}; the paper: {FitParams.paper().steps})")
    g.add_argument("--lr", type=pos_float, default=None, help=f"learning rate ({fit('lr')})")
    g.add_argument("--lam", type=float, default=None, help=f"Chamfer weight lambda ({fit('lam')})")
    g.add_argument("--sigma", type=_sigma, default=None, metavar="auto|S",
                   help=f"MLS kernel width: auto = {fit('sigma_relative')} x the template leaf's size "
                        f"({fit('sigma')}), or working units (paper: {FitParams.paper().sigma:g})")
    g.add_argument("--refine", type=pos_int, default=None, metavar="N",
                   help=f"Gauss-Newton iterations ({fit('refine')}; 0 = Adam only)")
    g.add_argument("--paper-fit", action="store_true",
                   help="the paper's registration exactly: K 32, sigma 0.1, 200 Adam steps, no Gauss-Newton")
    g.add_argument("--no-optimize", action="store_true", help="initial correspondence only (ablation)")
    g.add_argument("--seed", type=pos_int, default=None,
                   help="random seed of every stage: isolation's samples, the segmentation's subsets, "
                        f"the fit ({fit('seed')})")
    g = p.add_argument_group("mesh")
    g.add_argument("--vertex-budget", type=pos_int, default=None,
                   help=f"template sheet vertices ({default(MeshParams, 'vertex_budget')})")
    g.add_argument("--bake-size", type=pos_int, default=None,
                   help=f"resolution the textures are baked at (default: --texture-size)")
    g = p.add_argument_group("output")
    g.add_argument("--pot", action="store_true",
                   help="when isolation finds a pot, add it and its soil as meshes (Pot and Soil prims, "
                        "glTF nodes): a surface of revolution fitted to the pot's Gaussians and a soil disc, "
                        "coloured from theirs; never part of the leaves or the stem")
    g.add_argument("--up-axis", choices=["Y", "Z", "y", "z"], default="Y", help="the stage's upAxis (%(default)s)")
    g.add_argument("--meters-per-unit", type=pos_float, default=1.0, help="the stage's metersPerUnit (%(default)g)")
    g.add_argument("--height", type=pos_float, default=None, metavar="M",
                   help="real plant height in metres (default: keep the capture's units)")
    g.add_argument("--texture-format", choices=TEXTURE_FORMATS, default=WriteOptions.texture_format,
                   help="png (keeps the alpha cut-out of the leaf's outline) or jpg (compact, no alpha) (%(default)s)")
    g.add_argument("--texture-size", type=pos_int, default=WriteOptions.texture_max_size,
                   help="texture resolution in pixels: the bake and the written files (%(default)s)")
    g.add_argument("--baked", choices=["auto", "yes", "no"], default="auto",
                   help="baked-leaves payload (variant leafRepresentation=baked) for tools without the "
                        "deformer: auto = beside .usda/.usdc, not packed into .usdz (default)")
    from leaffit_usd.commands.export import add_gltf_arguments
    add_gltf_arguments(p)


def options_from_args(args):
    """The typed :class:`leaffit_usd.pipeline.ConvertOptions` of a parsed command line."""
    from dataclasses import replace

    from leaffit_usd.commands._args import frame_options, segment_params
    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.mesh.params import MeshParams
    from leaffit_usd.pipeline import ConvertOptions
    from leaffit_usd.usd.writer import WriteOptions

    given = lambda **kw: {k: v for k, v in kw.items() if v is not None}  # noqa: E731
    fit = given(K=args.K, steps=args.steps, lr=args.lr, lam=args.lam, sigma=args.sigma,
                refine=args.refine, seed=args.seed)
    if args.template is not None:
        t = str(args.template).strip()
        fit["template"] = int(t) if t.isdigit() else t
    if args.no_optimize:
        fit["optimize"] = False
    from leaffit_usd.isolate import IsolateParams

    seeded = {} if args.seed is None else {"seed": args.seed}   # one --seed for every stage
    return ConvertOptions(
        **frame_options(args), labels=args.labels, edits=args.edits,
        segment=segment_params(args, **seeded), isolate=IsolateParams(**seeded),
        fit=replace(FitParams.paper() if args.paper_fit else FitParams(), **fit),
        mesh=MeshParams(**given(vertex_budget=args.vertex_budget,
                                texture_size=args.bake_size if args.bake_size is not None else args.texture_size)),
        write=WriteOptions(texture_format=args.texture_format, texture_max_size=args.texture_size,
                           baked={"auto": "auto", "yes": True, "no": False}[args.baked]),
        up_axis=args.up_axis.upper(), meters_per_unit=args.meters_per_unit, height_m=args.height,
        keep_scene=bool(args.keep_scene), crop=args.crop, tint=not args.no_tint,
        instanced=args.instanced, pot=bool(args.pot))


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
        if Path(args.output).suffix.lower() in (".usda", ".usdc", ".usd", ".usdz"):
            from leaffit_usd.usd.prim_sizes import prim_data_sizes
            report["sizes"]["prims"] = prim_data_sizes(args.output)   # what each byte is for
        atomic_write_bytes(args.report, (json.dumps(report, indent=2) + "\n").encode())
    return 0
