"""Fixtures for the glTF export tests: the usd tests' synthetic plant, with per-leaf tints."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "usd"))
import synthetic as syn  # noqa: E402

from leaffit_usd.usd.assemble import asset_from_results  # noqa: E402
from leaffit_usd.usd.writer import LeafTextures  # noqa: E402


def make_asset(up_axis="Y", meters_per_unit=1.0, tints=True):
    t = syn.template_mesh()
    f = syn.leaf_fits(t)
    a = asset_from_results(t, f, syn.stem(), syn.frame(), up_axis=up_axis,
                           meters_per_unit=meters_per_unit, input_sha256="cd" * 32)
    if tints:
        rng = np.random.default_rng(5)
        a.tints = rng.uniform(0.5, 1.0, (a.n_leaves, 3)).astype(np.float32)
    return a, LeafTextures(t.front_texture, t.back_texture)


@pytest.fixture(scope="session")
def tinted():
    """(PlantAsset with tints, LeafTextures), Y up, metres."""
    return make_asset()


@pytest.fixture()
def tinted_stage(tmp_path, tinted):
    from leaffit_usd.runtime.evaluator import asset_leaves
    from leaffit_usd.usd.writer import write_stage

    out = tmp_path / "plant.usda"
    write_stage(out, *tinted, leaves=asset_leaves(tinted[0], separate_sheets=True))
    return out
