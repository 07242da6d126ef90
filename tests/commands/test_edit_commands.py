"""retexture / retarget commands on real stages: results, untouched inputs, exit codes."""
import hashlib

import numpy as np
import pytest

from leaffit_usd.cli import main
from leaffit_usd.edit.plant_io import load_plant
from leaffit_usd.image_io import write_image
from leaffit_usd.runtime.evaluator import asset_leaves
from leaffit_usd.usd.validate import validate_file
from leaffit_usd.usd.writer import LeafTextures, WriteOptions, write_stage
from tests.edit.leaves import asset_from_sheet, sheet


def _stage(path, kind="ellipse", colour=(40, 140, 40), seed=0):
    pts, faces = sheet(kind, seed=seed)
    asset = asset_from_sheet(pts, faces, n_leaves=4, seed=seed)
    img = np.zeros((64, 64, 4), np.uint8)
    img[..., :3] = colour
    img[..., 3] = 255
    write_stage(path, asset, LeafTextures(img, img.copy()), WriteOptions(texture_format="png"),
                leaves=asset_leaves(asset, separate_sheets=True))
    return path


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def plant(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    return _stage(d / "plant.usda")


@pytest.fixture
def decal(tmp_path):
    img = np.zeros((8, 8, 4), np.float32)
    img[..., 0] = 1.0
    img[..., 3] = 1.0
    write_image(tmp_path / "decal.png", img)
    return tmp_path / "decal.png"


def test_decal_writes_new_stage_and_keeps_input(tmp_path, plant, decal):
    before = _digest(plant.parent)
    out = tmp_path / "out" / "edited.usda"
    assert main(["retexture", str(plant), "-o", str(out), "--decal", str(decal), "--uv", "0.5,0.5",
                 "--scale", "0.5", "-q"]) == 0
    assert _digest(plant.parent) == before
    edited = load_plant(out)
    assert edited.front[32, 32, 0] > 0.9 and edited.front[32, 32, 1] < 0.1
    assert edited.back[32, 32, 1] > 0.4          # only the front side was edited
    assert not validate_file(out).failed()


def test_in_place_and_usdz(tmp_path, plant, decal):
    assert main(["retexture", str(plant), "--in-place", "--side", "both", "--decal", str(decal), "-q"]) == 0
    p = load_plant(plant)
    assert p.back[32, 32, 0] > 0.9
    z = tmp_path / "p.usdz"
    assert main(["retexture", str(plant), "-o", str(z), "--fill-mask", str(decal), "-q"]) == 0
    assert load_plant(z).front.shape == (64, 64, 4)


@pytest.mark.parametrize("extra", [
    ["--decal", "DECAL", "--uv", "1.5,0.2"],
    ["--decal", "DECAL", "--uv", "nonsense"],
    ["--image", "MISSING.png"],
    ["--image", "GARBAGE"],
])
def test_bad_edits_exit_2_and_leave_no_output(tmp_path, plant, decal, extra, capsys):
    garbage = tmp_path / "garbage.png"
    garbage.write_bytes(b"\x89PNG nope")
    extra = [str(decal) if a == "DECAL" else str(tmp_path / "missing.png") if a == "MISSING.png"
             else str(garbage) if a == "GARBAGE" else a for a in extra]
    before = _digest(plant.parent)
    out = tmp_path / "out.usda"
    assert main(["retexture", str(plant), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert not out.exists() and _digest(plant.parent) == before


def test_not_a_plant_exits_2(tmp_path, decal, capsys):
    bogus = tmp_path / "x.usda"
    bogus.write_text("#usda 1.0\n")
    assert main(["retexture", str(bogus), "-o", str(tmp_path / "o.usda"), "--decal", str(decal)]) == 2


def test_retarget_command(tmp_path, plant):
    src = _stage(tmp_path / "maple.usda", kind="lobed", colour=(200, 60, 20), seed=7)
    out = tmp_path / "retargeted.usda"
    report = tmp_path / "r.json"
    assert main(["retarget", str(plant), "--source-leaf", str(src), "-o", str(out),
                 "--report", str(report), "-q"]) == 0
    import json
    r = json.loads(report.read_text())
    assert r["instances"] == 4 and r["iou_min"] >= 0.8
    new = load_plant(out)
    assert new.front[..., 0].mean() > 0.7        # the source species' texture
    assert not validate_file(out).failed()


def test_retarget_from_a_single_leaf_capture(tmp_path, plant):
    from leaffit_usd.splats import GaussianCloud, write_ply
    from tests.edit.test_retarget import _leaf_capture

    pts = _leaf_capture(n=3000, seed=3) * 0.05
    rng = np.random.default_rng(0)
    n = len(pts)
    cloud = GaussianCloud.from_activated(pts, np.full((n, 3), 0.002), np.tile([1, 0, 0, 0], (n, 1)),
                                         np.full(n, 0.9), np.tile([0.7, 0.2, 0.1], (n, 1)) + 0.05 * rng.random((n, 3)))
    write_ply(cloud, tmp_path / "leaf.ply")
    out = tmp_path / "r.usda"
    report = tmp_path / "r.json"
    assert main(["retarget", str(plant), "--source-leaf", str(tmp_path / "leaf.ply"), "-o", str(out),
                 "--report", str(report), "-q"]) == 0
    import json
    assert json.loads(report.read_text())["iou_min"] >= 0.8
    assert not validate_file(out).failed()
    # a round "leaf" has no apex: exit 2, nothing written
    r, a = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    disc = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)] * 0.05
    write_ply(GaussianCloud.from_activated(disc, np.full((n, 3), 0.002), np.tile([1, 0, 0, 0], (n, 1)),
                                           np.full(n, 0.9)), tmp_path / "disc.ply")
    out2 = tmp_path / "r2.usda"
    assert main(["retarget", str(plant), "--source-leaf", str(tmp_path / "disc.ply"), "-o", str(out2)]) == 2
    assert not out2.exists()
