"""``leaffit-usd convert plant.ply -o plant.glb`` end to end on a small generated plant: the
whole pipeline, the per-leaf tint in the report and in COLOR_0, the Khronos validator."""
import importlib.util
import json

import numpy as np
import pytest

from leaffit_usd.cli import main
from leaffit_usd.export.gltf import read_glb_leaves
from leaffit_usd.export.validator import find_validator, validate_gltf

STAGES = ["leaffit_usd.segment.auto", "leaffit_usd.fit.register", "leaffit_usd.mesh.template",
          "leaffit_usd.mesh.stem", "samples.generate"]
MISSING = [m for m in STAGES if importlib.util.find_spec(m) is None]
FAST = ["-K", "12", "--steps", "4", "--n-samples", "1024", "--n-neighbors", "128",
        "--vertex-budget", "256", "--bake-size", "128", "--texture-size", "128"]


@pytest.mark.skipif(bool(MISSING), reason=f"stage modules missing: {MISSING}")
def test_convert_to_glb(tmp_path):
    from samples.generate import PlantSpec, make_plant, save_plant

    cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=3, gaussians=4000, holes=0.0,
                                     floaters=0.0, height=0.5), seed=3)
    ply, gtp = save_plant(cloud, gt, tmp_path, "small")
    out, rep = tmp_path / "plant.glb", tmp_path / "r.json"
    assert main(["convert", str(ply), "-o", str(out), "--labels", str(gtp), "--report", str(rep),
                 "--height", "0.5", "-q", *FAST]) == 0
    report = json.loads(rep.read_text())
    n = report["counts"]["leaves"]
    tints = np.asarray(report["tint"]["per_leaf"])
    assert tints.shape == (n, 3) and np.all(tints > 0)
    assert report["outputs"] == {"gltf": str(out)}
    pos, faces, extras = read_glb_leaves(out)
    assert len(extras["leafLabels"]) == n and len(pos) == n * extras["verticesPerLeaf"]
    # metres, +Y up: a 0.5 m plant, standing on y ~ 0
    assert 0.2 < pos[:, 1].max() - min(pos[:, 1].min(), 0.0) <= 0.6
    if find_validator() is not None:
        v = validate_gltf(out)
        assert v.errors == 0 and v.warnings == 0, v.messages[:5]
    # a .usdc from the same run carries the same tints as its primvar
    assert main(["convert", str(ply), "-o", str(tmp_path / "p.usdc"), "--labels", str(gtp),
                 "--height", "0.5", "-q", *FAST]) == 0
    from leaffit_usd.usd.reader import read_stage

    np.testing.assert_allclose(read_stage(tmp_path / "p.usdc").tints, tints, atol=1e-4)
