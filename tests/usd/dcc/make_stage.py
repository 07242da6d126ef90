"""Stage for ``make dcc-check``: prints 'PATH LEAVES' for blender_check.py.

    python tests/usd/dcc/make_stage.py [PLANT.usda]

Without an argument, writes the synthetic 5-leaf plant of the usd tests (real template mesh
layout, textures, stem, baked payload) to build/dcc/plant.usda; with one, reports that file.
"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from leaffit_usd.usd.reader import read_stage  # noqa: E402


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1]:
        path = Path(sys.argv[1])
    else:
        import synthetic as syn

        from leaffit_usd.usd.assemble import asset_from_results
        from leaffit_usd.usd.writer import LeafTextures, write_stage

        t = syn.template_mesh(tex=256)
        asset = asset_from_results(t, syn.leaf_fits(t), syn.stem(), syn.frame(), up_axis="Z")
        path = HERE.parent.parent.parent / "build" / "dcc" / "plant.usda"
        write_stage(path, asset, LeafTextures(t.front_texture, t.back_texture))
    print(path.resolve(), read_stage(path).n_leaves)
    return 0


if __name__ == "__main__":
    sys.exit(main())
