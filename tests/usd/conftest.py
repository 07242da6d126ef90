import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import synthetic as syn  # noqa: E402

from leaffit_usd.runtime.evaluator import asset_leaves  # noqa: E402
from leaffit_usd.usd.assemble import asset_from_results  # noqa: E402
from leaffit_usd.usd.writer import LeafTextures  # noqa: E402


@pytest.fixture(scope="session")
def results():
    t = syn.template_mesh()
    f = syn.leaf_fits(t)
    return t, f, syn.stem(), syn.frame()


@pytest.fixture(scope="session")
def asset(results):
    t, f, s, fr = results
    return asset_from_results(t, f, s, fr, up_axis="Y", input_sha256="ab" * 32)


@pytest.fixture(scope="session")
def textures(results):
    t = results[0]
    return LeafTextures(t.front_texture, t.back_texture)


@pytest.fixture()
def stage_path(tmp_path, asset, textures):
    """The synthetic plant written as a .usda (with textures) in a fresh folder."""
    from leaffit_usd.usd import writer as W

    out = tmp_path / "p.usda"
    W.write_stage(out, asset, textures, leaves=asset_leaves(asset, separate_sheets=True))
    return out
