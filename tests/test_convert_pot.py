"""convert --pot: a capture with a pot and soil gets Pot and Soil meshes beside its leaves and
stem (USD prims that validate, read back, glTF nodes); without --pot it gets none."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.test_convert_memory import _options


@pytest.fixture(scope="module")
def potted(tmp_path_factory):
    from samples.generate import capture_realism_plants, make_plant, save_plant

    spec, seed = capture_realism_plants(14_000)["rubber_tree_capture"]
    cloud, gt = make_plant(spec, seed)
    ply, _ = save_plant(cloud, gt, tmp_path_factory.mktemp("pot"), "potted")
    return ply, gt


def test_pot_and_soil_prims(potted, tmp_path):
    from pxr import Usd

    from leaffit_usd.export.gltf import GltfOptions, write_gltf
    from leaffit_usd.pipeline import convert
    from leaffit_usd.usd.reader import read_stage
    from leaffit_usd.usd.validate import validate_file

    ply, gt = potted
    convert(ply, tmp_path / "p.usda", _options(pot=True))
    stage = Usd.Stage.Open(str(tmp_path / "p.usda"))
    roles = {p.GetName(): p.GetCustomDataByKey("leaffit:role") for p in stage.Traverse()}
    assert roles.get("Pot") == "pot" and roles.get("Soil") == "soil"
    assert validate_file(tmp_path / "p.usda").count("error") == 0
    asset = read_stage(tmp_path / "p.usda")
    assert asset.pot is not None and len(asset.pot.pot_faces) and len(asset.pot.soil_faces)
    g = write_gltf(tmp_path / "p.glb", asset, None, GltfOptions())
    assert g.bytes > 0
    blob = (tmp_path / "p.glb").read_bytes()
    n = int.from_bytes(blob[12:16], "little")
    nodes = {nd.get("name") for nd in json.loads(blob[20:20 + n])["nodes"]}
    assert {"Pot", "Soil", "Leaves"} <= nodes
    convert(ply, tmp_path / "q.usda", _options())
    plain = Usd.Stage.Open(str(tmp_path / "q.usda"))
    names = {p.GetName() for p in plain.Traverse()}
    assert "Pot" not in names and "Soil" not in names
