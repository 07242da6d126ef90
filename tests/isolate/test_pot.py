"""The pot's axis as the capture's up when neither a table nor the soil shows it (the soil hidden
under the leaves), and no pot where there is none."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.isolate import PLANT, POT, SOIL, isolate_plant
from samples.generate import make_plant, preset
from tests.isolate.test_soil import potted_capture


def test_a_pot_without_visible_soil_gives_the_up_axis():
    cloud, truth, up, _ = potted_capture(seed=2, rim=0.04)
    # the soil under the leaves: a few patches show, too sparse for a plane
    rng = np.random.default_rng(0)
    keep = (truth != SOIL) | (rng.uniform(size=len(truth)) < 0.1)
    no_soil = cloud.subset(np.flatnonzero(keep))
    truth = truth[keep]
    iso = isolate_plant(no_soil)
    assert iso.up_source == "pot"
    assert np.degrees(np.arccos(np.clip(iso.up @ up, -1, 1))) < 5
    kept = iso.classes == PLANT
    assert kept[truth == 0].mean() > 0.99
    assert kept[truth == POT].mean() < 0.1


@pytest.mark.parametrize("name, seed", [("golden_pothos", 1), ("rubber_tree", 2)])
def test_a_plant_without_a_pot_has_no_pot_axis(name, seed):
    cloud, gt = make_plant(preset(name, gaussians=12_000), seed)
    iso = isolate_plant(cloud)
    assert iso.up_source is None and iso.pot is None
    assert (iso.classes == PLANT)[gt.labels >= 0].mean() > 0.995
