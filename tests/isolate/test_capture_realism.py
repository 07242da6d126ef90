"""Isolation on Gaussians with a real capture's statistics (``realism="capture"``: faint,
needle-shaped, layered, fuzzy, with a pot and soil and no table): the soil or the pot gives the
up axis, the pot and soil go, the plant stays."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.isolate import PLANT
from leaffit_usd.isolate.stage import isolate_stage
from samples.generate import capture_realism_plants, make_plant


@pytest.mark.parametrize("name, gaussians", [("rubber_tree_capture", 36_000), ("green_pepper_capture", 36_000),
                                             ("golden_pothos_capture", 36_000),
                                             # sparse: a layer of its leaves looks like a soil disc
                                             ("green_pepper_capture", 16_000)])
def test_capture_realism_pot_and_soil_go_and_the_plant_stays(name, gaussians):
    spec, seed = capture_realism_plants(gaussians)[name]
    cloud, gt = make_plant(spec, seed)
    _, iso = isolate_stage(cloud)
    assert iso.up_source in ("soil", "pot")
    assert np.degrees(np.arccos(np.clip(iso.up @ gt.up, -1, 1))) < 5
    kept = iso.classes == PLANT
    assert kept[gt.labels >= 0].mean() >= 0.995
    assert kept[gt.labels == -2].mean() < 0.05   # the pot and the soil
