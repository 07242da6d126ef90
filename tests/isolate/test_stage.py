"""isolate_stage as the commands run it: the plant is never lost (the capture is kept whole, with
one warning naming --keep-scene, when isolation would remove most of it or of the root's
surroundings)."""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.isolate import BACKGROUND, PLANT
from leaffit_usd.isolate.stage import isolate_stage
from leaffit_usd.splats.cloud import GaussianCloud


def _blobs(sizes, gap=3.0, seed=0):
    """Flat square patches of ``sizes`` Gaussians side by side along x, ``gap`` x their width
    apart: pieces of a plant whose holes broke it apart, or separate objects."""
    rng = np.random.default_rng(seed)
    pos = []
    for i, n in enumerate(sizes):
        xy = rng.uniform(0, 1, (n, 2))
        pos.append(np.c_[xy[:, 0] + i * (1 + gap), xy[:, 1], 0.002 * rng.normal(size=n)])
    p = np.concatenate(pos)
    n = len(p)
    return GaussianCloud.from_activated(p, np.full((n, 3), 0.005), np.tile([1.0, 0, 0, 0], (n, 1)),
                                        np.full(n, 0.8), colors=np.full((n, 3), 0.4))


def test_isolation_that_would_remove_most_of_the_capture_keeps_it_whole(caplog):
    cloud = _blobs([3000, 2500, 2500])
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        _, iso = isolate_stage(cloud)
    assert (iso.classes == PLANT).all()
    assert "kept_whole" in iso.params
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1 and "--keep-scene" in lines[0]


def test_a_small_separate_object_is_still_removed():
    cloud = _blobs([5000, 1000])
    _, iso = isolate_stage(cloud)
    assert (iso.classes[5000:] == BACKGROUND).all() and (iso.classes[:5000] == PLANT).all()


def test_a_root_on_what_isolation_removes_keeps_the_capture_whole(caplog):
    cloud = _blobs([5000, 1000])
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        _, iso = isolate_stage(cloud, root=cloud.means[5500].astype(np.float64))
    assert (iso.classes == PLANT).all()
    assert any("root" in r.getMessage() for r in caplog.records)
    _, iso = isolate_stage(cloud, root_index=int(cloud.file_index[5500]))
    assert (iso.classes == PLANT).all()
    _, iso = isolate_stage(cloud, root_index=10)  # a root on the plant: isolation as usual
    assert (iso.classes[5000:] == BACKGROUND).all()


def test_a_sparsely_sampled_part_of_the_plant_is_kept():
    """Uneven density: a leaf sampled 12x more sparsely than the rest of the plant, touching
    it, is the plant's (the components' link follows the local spacing), not background."""
    rng = np.random.default_rng(3)
    dense = np.c_[rng.uniform(0, 1, (10000, 2)), 0.002 * rng.normal(size=10000)]
    sparse = np.c_[rng.uniform(0, 1, (800, 2)) + [1.0, 0.0], 0.002 * rng.normal(size=800)]
    p = np.r_[dense, sparse]
    n = len(p)
    cloud = GaussianCloud.from_activated(p, np.full((n, 3), 0.005), np.tile([1.0, 0, 0, 0], (n, 1)),
                                         np.full(n, 0.8), colors=np.full((n, 3), 0.4))
    _, iso = isolate_stage(cloud)
    assert (iso.classes[10000:] == PLANT).mean() > 0.99
    assert "kept_whole" not in iso.params
