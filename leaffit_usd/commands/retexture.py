"""``leaffit-usd retexture``: edit the template's textures once; every leaf shows the edit."""
from __future__ import annotations

import logging
from pathlib import Path

NAME = "retexture"
ORDER = 70
HELP = "edit the leaf texture once (replace, decal, masked fill); every leaf shows it"
DESCRIPTION = """\
Edit the template leaf's front and/or back texture. Every leaf is the template deformed by MLS and
shares its UVs, so the edit shows on all of them. Writes a new stage (-o) with new texture files;
the input is left untouched unless --in-place.

One edit per call:
  --image IMG                 replace the texture (resized to the template's; the leaf silhouette
                              (alpha) is kept unless IMG has its own alpha)
  --decal IMG --uv U,V        overlay an image with alpha centred at texture coordinate (U, V)
        [--scale S] [--rotation DEG]   S = decal width / texture width; DEG counter-clockwise
  --fill-mask MASK            repaint the white region of MASK (any resolution) from its
                              surroundings (OpenImageIO push-pull)

Examples:
  leaffit-usd retexture plant.usda -o plant_logo.usda --decal logo.png --uv 0.5,0.4 --scale 0.3
  leaffit-usd retexture plant.usda --in-place --side back --image bark.jpg
"""

log = logging.getLogger("leaffit_usd")


def add_arguments(parser) -> None:
    parser.add_argument("stage", help="a LeafFit stage (.usda/.usdc/.usdz)")
    out = parser.add_mutually_exclusive_group(required=True)
    out.add_argument("-o", "--output", help="the edited stage to write (.usda/.usdc/.usdz)")
    out.add_argument("--in-place", action="store_true", help="replace the input stage (atomically)")
    op = parser.add_mutually_exclusive_group(required=True)
    op.add_argument("--image", help="replace the texture with this image")
    op.add_argument("--decal", help="overlay this image (with alpha) at --uv")
    op.add_argument("--fill-mask", help="repaint the white region of this mask image")
    parser.add_argument("--side", choices=("front", "back", "both"), default="front",
                        help="which texture to edit (default: %(default)s)")
    parser.add_argument("--uv", default="0.5,0.5", help="decal centre U,V in [0,1] (default %(default)s)")
    parser.add_argument("--scale", type=float, default=0.25,
                        help="decal width as a fraction of the texture width (default %(default)g)")
    parser.add_argument("--rotation", type=float, default=0.0,
                        help="decal rotation in degrees, counter-clockwise (default %(default)g)")


def _parse_uv(text):
    from leaffit_usd.errors import ParameterError

    try:
        u, v = (float(t) for t in text.split(","))
    except ValueError:
        raise ParameterError("--uv", "two numbers U,V", text) from None
    return u, v


def run(args) -> int:
    from leaffit_usd.edit import texture as T
    from leaffit_usd.edit.plant_io import load_plant, save_plant
    from leaffit_usd.image_io import image_has_alpha, read_image

    # read every user input before anything is written
    plant = load_plant(args.stage)
    sides = ("front", "back") if args.side == "both" else (args.side,)
    if args.image:
        img = read_image(args.image)
        alpha = image_has_alpha(args.image)
        edit = lambda tex: T.replace_texture(tex, img, new_has_alpha=alpha)  # noqa: E731
        what = f"replaced with {args.image}"
    elif args.decal:
        img = read_image(args.decal)
        uv = _parse_uv(args.uv)
        edit = lambda tex: T.overlay_decal(tex, img, uv, args.scale, args.rotation)  # noqa: E731
        what = f"decal {args.decal} at uv {uv}"
    else:
        mask = read_image(args.fill_mask)[..., :3].mean(-1, keepdims=True)
        # the mask may be drawn at any resolution: resampled to the texture's
        edit = lambda tex: T.masked_fill(tex, T.resize_image(mask, *tex.shape[:2])[..., 0])  # noqa: E731
        what = f"masked fill from {args.fill_mask}"
    for side in sides:
        setattr(plant, side, edit(getattr(plant, side)))
    out = Path(args.stage) if args.in_place else Path(args.output)
    if not args.in_place and out.suffix.lower() not in (".usda", ".usdc", ".usd", ".usdz"):
        from leaffit_usd.errors import ParameterError
        raise ParameterError("-o/--output", "a .usda/.usdc/.usd/.usdz file", str(out))
    result = save_plant(plant, out, source=args.stage, in_place=args.in_place)
    log.info("%s texture %s; %d leaves share it; wrote %s", "+".join(sides), what,
             plant.asset.n_leaves, result.path)
    print(result.path)
    return 0
