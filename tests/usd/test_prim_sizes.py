"""What each byte is for: the data each prim of a written stage holds, largest first."""
from __future__ import annotations

import numpy as np

from leaffit_usd.usd.prim_sizes import prim_data_sizes


def test_the_template_stem_and_instancer_hold_the_data(tmp_path):
    from leaffit_usd.runtime.evaluator import asset_leaves
    from leaffit_usd.usd.writer import write_stage
    from tests.export.conftest import make_asset

    asset, textures = make_asset()
    out = tmp_path / "p.usda"
    write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    r = prim_data_sizes(out, top=5)
    paths = [p["path"] for p in r["prims"]]
    assert r["total_bytes"] > 0 and len(r["prims"]) <= 6
    assert any(p.endswith("/TemplateLeaf") for p in paths) and any(p.endswith("/Stem") for p in paths)
    assert abs(sum(p["share"] for p in r["prims"]) - 1.0) < 0.01
    b = [p["bytes"] for p in r["prims"] if p["path"] != "(other prims)"]
    assert b == sorted(b, reverse=True)
    # the template's points are counted: 12 bytes a vertex at least
    tmpl = next(p for p in r["prims"] if p["path"].endswith("/TemplateLeaf"))
    assert tmpl["bytes"] >= 12 * len(np.asarray(asset.template_points))


def test_convert_report_lists_the_prims(tmp_path):
    import json

    from leaffit_usd.cli import main
    from samples import PLANTS_DIR, ensure_plants

    ensure_plants()
    out, rep = tmp_path / "p.usdz", tmp_path / "r.json"
    assert main(["convert", str(PLANTS_DIR / "pothos_sh3.ply"), "-o", str(out), "--report", str(rep),
                 "-q", "--steps", "0", "--refine", "1"]) == 0
    prims = json.loads(rep.read_text())["sizes"]["prims"]
    assert prims["total_bytes"] > 0 and any(p["path"].endswith("/TemplateLeaf") for p in prims["prims"])
