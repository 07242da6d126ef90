"""The front half every command shares (leaffit_usd.prepare): convert, segment and edit see the
same isolated plant, frame and automatic labels, on a capture that needs isolation."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.prepare import FrameOptions, PreparedPlant
from leaffit_usd.splats import write_ply
from samples.generate import make_plant, preset


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A plant on a pot with soil, a table and clutter (about 24k Gaussians)."""
    cloud, gt = make_plant(preset("green_pepper", gaussians=12_000, scene=True), 5)
    path = tmp_path_factory.mktemp("prepare") / "capture.ply"
    write_ply(cloud, path)
    return path, gt


def test_convert_segment_and_edit_give_the_same_labels(capture, tmp_path, monkeypatch):
    from leaffit_usd import pipeline
    from leaffit_usd.cli import main
    from leaffit_usd.commands.edit import automatic_labels, prepare_capture

    path, gt = capture
    assert main(["segment", str(path), "-o", str(tmp_path / "seg.npz"), "-q"]) == 0
    by_segment = np.load(tmp_path / "seg.npz")["labels"]
    assert (by_segment == -1).sum() > 0.3 * len(by_segment)   # isolation removed the scene

    prep = prepare_capture(path)
    by_edit = prep.file_labels(automatic_labels(prep)[0])

    seen = {}
    original = pipeline._segment_stage

    def record(prep_, cloud, o, input_path):
        seg = original(prep_, cloud, o, input_path)
        seen["labels"] = prep_.file_labels(seg.labels)
        raise _Stop   # the fit and the rest are not what this test is about
    monkeypatch.setattr(pipeline, "_segment_stage", record)
    with pytest.raises(_Stop):
        pipeline.convert(path, tmp_path / "plant.usda")
    assert np.array_equal(seen["labels"], by_segment)
    assert np.array_equal(by_edit, by_segment)
    assert by_segment.max() >= 5


def test_index_spaces(capture):
    path, _ = capture
    prep = PreparedPlant.open(path, FrameOptions())
    assert np.array_equal(prep.loaded.file_index[prep.plant_in_loaded], prep.plant.file_index)
    assert len(prep.working) == len(prep.plant) and 0 <= prep.root_index < len(prep.plant)
    lab = np.arange(1, len(prep.plant) + 1, dtype=np.int32)
    fl = prep.file_labels(lab)
    assert np.array_equal(fl[prep.plant.file_index], lab)
    removed = np.setdiff1d(np.arange(prep.loaded.file_count), prep.plant.file_index)
    assert (fl[removed] <= 0).all() and (prep.file_classes()[prep.plant.file_index] == 0).all()
