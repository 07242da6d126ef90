"""``leaffit-usd export PLANT.usda -o plant.glb``: a LeafFit stage as glTF 2.0 / GLB."""
from __future__ import annotations

import logging
import time
from pathlib import Path

NAME = "export"
ORDER = 65
HELP = "write a LeafFit stage as glTF 2.0 (.glb / .gltf) for game engines, or as a web page (.html)"
DESCRIPTION = """\
Write a LeafFit stage as glTF 2.0: .glb (binary, textures embedded) or .gltf (one JSON file,
buffer and textures embedded as data URIs). Metres, +Y up (the stage's upAxis and metersPerUnit
are converted). Materials are metallic-roughness PBR built from the front and back leaf
textures; glTF has no back-face texture, so each leaf is two single-sided sheets, as in USD.
The per-leaf tint (primvars:leaffit:tint) becomes the vertex colour COLOR_0.

  default       the evaluated leaves: every leaf's exact deformed mesh (what 'bake' gives) and
                the stem, one mesh with a front and a back primitive
  --instanced   the template leaf once + EXT_mesh_gpu_instancing (one transform per leaf).
                Smaller and faster to draw, but glTF has no MLS deformer: every leaf is the
                template's shape, rigidly placed (the per-leaf deformation is lost)

  plant.html    one self-contained web page (three.js, the evaluated GLB, orbit controls and
                a wind slider: every leaf turns about its axis through its pivot); opens from
                a file, offline

The glTF carries the wind data too: _WIND per vertex (leaf flutter, branch bend, phase) and,
instanced, _WINDPIVOT / _WINDAXIS per leaf (docs/usd_layout.md says which engine reads what).

Examples:
  leaffit-usd export plant.usda -o plant.glb
  leaffit-usd export plant.usdz -o plant_instanced.glb --instanced --texture-format png
  leaffit-usd export plant.usda -o plant.html
"""

log = logging.getLogger("leaffit_usd")


def add_gltf_arguments(parser) -> None:
    """The glTF options shared by ``export`` and ``convert -o plant.glb``."""
    g = parser.add_argument_group("glTF output (.glb / .gltf)")
    g.add_argument("--instanced", action="store_true",
                   help="template once + EXT_mesh_gpu_instancing (rigid: loses the per-leaf "
                        "deformation) instead of the evaluated leaves")
    g.add_argument("--no-tint", action="store_true",
                   help="no per-leaf tint (USD primvars:leaffit:tint, glTF COLOR_0)")


def add_arguments(parser) -> None:
    from leaffit_usd.commands._args import pos_int

    parser.add_argument("stage", help="a LeafFit stage (.usda/.usdc/.usdz)")
    parser.add_argument("-o", "--output", required=True, help="output .glb or .gltf")
    parser.add_argument("--texture-format", choices=("jpg", "png"), default="jpg",
                        help="embedded textures: jpg (compact, OPAQUE) or png (alpha kept, "
                             "alphaMode MASK, cutoff 0.5). Default jpg")
    parser.add_argument("--texture-size", type=pos_int, default=1024,
                        help="longest side of the embedded textures (1024)")
    add_gltf_arguments(parser)


def export(stage_path, output, instanced: bool = False, texture_format: str = "jpg",
           texture_size: int = 1024, tint: bool = True) -> dict:
    """Read ``stage_path`` and write ``output`` (.glb/.gltf). Returns a small report dict."""
    from leaffit_usd.errors import InputFileError, ParameterError
    from leaffit_usd.export.gltf import GLTF_FORMATS, GltfOptions, write_gltf
    from leaffit_usd.usd.reader import open_stage, read_stage_object, read_texture
    from leaffit_usd.usd.writer import LeafTextures

    stage_path, output = Path(stage_path), Path(output)
    page = output.suffix.lower() == ".html"
    if output.suffix.lower() not in GLTF_FORMATS and not page:
        raise ParameterError("--output", f"a file ending in {', '.join(GLTF_FORMATS)} or .html", str(output))
    t0 = time.perf_counter()
    stage = open_stage(stage_path)
    asset = read_stage_object(stage, stage_path)
    front = read_texture(stage, asset.front_texture)
    back = read_texture(stage, asset.back_texture)
    textures = LeafTextures(front, back) if front is not None and back is not None else None
    if textures is None and (asset.front_texture or asset.back_texture):
        log.warning("export: the stage's leaf textures could not be read; leaves get a flat colour")
    opts = GltfOptions(instanced=instanced, texture_format=texture_format,
                       texture_max_size=int(texture_size), tint=tint)
    if page:   # one self-contained web page: three.js, the asset, a wind slider
        from leaffit_usd.export.page import write_page

        try:
            n = write_page(output, asset, textures, opts)
        except OSError as e:
            raise InputFileError(output, f"cannot write: {e.strerror or e}") from None
        log.info("wrote %s (web page, %d leaves, %.1f KB) in %.2f s", output, asset.n_leaves,
                 n / 1024, time.perf_counter() - t0)
        return {"output": str(output), "layout": "page", "leaves": asset.n_leaves, "bytes": n,
                "seconds": time.perf_counter() - t0}
    try:
        res = write_gltf(output, asset, textures, opts)
    except OSError as e:
        raise InputFileError(output, f"cannot write: {e.strerror or e}") from None
    dt = time.perf_counter() - t0
    log.info("wrote %s (%s, %d leaves, %d vertices, %d triangles, %.1f KB) in %.2f s", output,
             res.layout, res.leaves, res.vertices, res.triangles, res.bytes / 1024, dt)
    return {"output": str(output), "layout": res.layout, "leaves": res.leaves,
            "vertices": res.vertices, "triangles": res.triangles, "bytes": res.bytes, "seconds": dt}


def run(args) -> int:
    export(args.stage, args.output, instanced=args.instanced, texture_format=args.texture_format,
           texture_size=args.texture_size, tint=not args.no_tint)
    return 0
