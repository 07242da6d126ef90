"""edits.json: save, load, replay == interactive result; edits that do not fit are refused."""
import json
import logging

import numpy as np
import pytest

from leaffit_usd.errors import InputFileError, UserError
from leaffit_usd.segment.edits import (Edits, add_edits_argument, apply_edits, apply_edits_file, labels_sha256,
                                       load_edits, save_edits, to_cloud_operations)
from leaffit_usd.splats import load_cloud, write_ply
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.viewer.server import build_session


@pytest.fixture(scope="module")
def plant_file(plant, tmp_path_factory):
    """The two-leaf plant as a PLY with three invalid Gaussians (dropped at load)."""
    cloud = plant[0]
    bad = cloud.subset(np.arange(len(cloud)))
    bad.means = bad.means.copy()
    bad.means[[5, 700, 2000]] = np.nan  # file indices 5, 700, 2000 get dropped
    path = tmp_path_factory.mktemp("edits") / "plant.ply"
    write_ply(bad, path)
    return path


def interactive_session(plant, plant_file, heat, tmp_path, base=None):
    cloud = load_cloud(plant_file)
    assert len(cloud) == cloud.file_count - 3
    truth = plant[1][cloud.file_index]
    labels = np.zeros(len(cloud), np.int32) if base is None else base
    s = build_session(cloud, labels, plant_file, tmp_path / "e.json", tmp_path / "l.npz",
                      n_samples=1500, solver_factory=heat)
    tip = [int(np.flatnonzero(truth == k)[np.argmax(np.abs(cloud.means[truth == k, 0]))]) for k in (1, 2)]
    def at(k, x):  # a Gaussian of leaf k at |x| ~ x
        return int(np.flatnonzero(truth == k)[np.argmin(np.abs(np.abs(cloud.means[truth == k, 0]) - x))])

    mid = [at(1, 0.04), at(2, 0.25)]
    seg = s.segmenter
    seg.apply({"op": "drag", "source": tip[0], "target": mid[0]})
    seg.apply({"op": "assign", "label": "new"})
    seg.apply({"op": "brush", "centers": [tip[1], mid[1]], "radius": 0.12, "mode": "add"})
    seg.apply({"op": "brush", "centers": [at(2, 0.3)], "radius": 0.02, "mode": "erase"})
    seg.apply({"op": "assign", "label": "new"})
    seg.apply({"op": "assign", "label": 2})  # empty selection: a no-op that must replay too
    return cloud, truth, s


def test_replay_equals_interactive(plant, plant_file, heat, tmp_path):
    cloud, truth, s = interactive_session(plant, plant_file, heat, tmp_path)
    out = s.save()
    assert out["operations"] == 6 and out["leaves"] == 2
    saved = np.load(tmp_path / "l.npz")["labels"]
    assert saved.dtype == np.int32 and saved.shape == (cloud.file_count,)
    assert np.array_equal(saved[cloud.file_index], s.segmenter.final_labels())
    assert (saved[[5, 700, 2000]] == 0).all()  # dropped Gaussians are stem in the file
    data = json.loads((tmp_path / "e.json").read_text())
    assert data["input"]["gaussians"] == cloud.file_count and data["version"] == 1
    # indices in the file are file-order positions
    first = s.segmenter.operations[0]
    assert data["operations"][0]["source"] == int(cloud.file_index[first["source"]])
    # the edits separate the leaves (the interactive result is meaningful)
    assert (truth[saved[cloud.file_index] == 1] == 1).mean() > 0.97
    assert (truth[saved[cloud.file_index] == 2] == 2).mean() > 0.97
    # replay through the public API, on a freshly loaded cloud and a fresh solver
    cloud2 = load_cloud(plant_file)
    edits = load_edits(tmp_path / "e.json", plant_file)
    replayed = apply_edits(np.zeros(len(cloud2), np.int32), cloud2, edits, solver_factory=heat)
    assert np.array_equal(cloud2.to_file_order(replayed), saved)
    again = apply_edits_file(np.zeros(len(cloud2), np.int32), cloud2, tmp_path / "e.json", plant_file,
                             solver_factory=heat)
    assert np.array_equal(again, replayed)


def test_refused_when_input_differs(plant, plant_file, heat, tmp_path):
    cloud, _, s = interactive_session(plant, plant_file, heat, tmp_path)
    s.save()
    other = load_cloud(plant_file)
    other.means = other.means + 1e-3
    write_ply(other, tmp_path / "other.ply")
    with pytest.raises(InputFileError, match="different input file"):
        load_edits(tmp_path / "e.json", tmp_path / "other.ply")
    # with a cloud instead of a path only the count can be checked
    smaller = other.subset(np.arange(100))
    smaller.file_count = 100
    with pytest.raises(InputFileError, match="100"):
        load_edits(tmp_path / "e.json", smaller)
    with pytest.raises(UserError, match="Gaussians"):
        apply_edits(np.zeros(100, np.int32), smaller, load_edits(tmp_path / "e.json", plant_file))


def write_edits(tmp_path, plant_file, ops, n=None, **kw):
    cloud = load_cloud(plant_file)
    from leaffit_usd.io_util import file_sha256

    e = Edits(input_sha256=file_sha256(plant_file), n_gaussians=n or cloud.file_count, height=1.0,
              n_samples=1500, operations=ops, **kw)
    save_edits(e, tmp_path / "x.json")
    return tmp_path / "x.json", cloud


@pytest.mark.parametrize("ops, words", [
    ([{"op": "drag", "source": 3, "target": 10 ** 6}], "not a Gaussian index"),
    ([{"op": "brush", "centers": [1, -4], "radius": 0.1}], "not a Gaussian index"),
    ([{"op": "brush", "centers": [1, 2.5], "radius": 0.1}], "not a Gaussian index"),
])
def test_refused_indices_out_of_range(plant_file, tmp_path, ops, words):
    path, _ = write_edits(tmp_path, plant_file, ops)
    with pytest.raises(InputFileError, match=words):
        load_edits(path, plant_file)


def test_refused_dropped_gaussian_and_bad_operation(plant_file, heat, tmp_path):
    path, cloud = write_edits(tmp_path, plant_file, [{"op": "brush", "centers": [700], "radius": 0.1}])
    edits = load_edits(path, plant_file)
    with pytest.raises(UserError, match="dropped"):
        apply_edits(np.zeros(len(cloud), np.int32), cloud, edits, solver_factory=heat)
    path, cloud = write_edits(tmp_path, plant_file, [{"op": "assign", "label": "new"}, {"op": "explode"}])
    with pytest.raises(UserError, match="operation 1: unknown operation 'explode'"):
        apply_edits(np.zeros(len(cloud), np.int32), cloud, load_edits(path, plant_file), solver_factory=heat)
    with pytest.raises(UserError, match="labels"):
        apply_edits(np.zeros(3, np.int32), cloud, load_edits(path, plant_file), solver_factory=heat)


@pytest.mark.parametrize("text, words", [
    ("not json", "JSON"),
    ('{"format": "something"}', "not a leaffit-usd edits file"),
    ('{"format": "leaffit-usd-edits", "version": 99}', "version 99"),
    ('{"format": "leaffit-usd-edits", "version": 1, "input": {}}', "missing field"),
    ('{"format": "leaffit-usd-edits", "version": 1, "input": {"sha256": "ab", "gaussians": 3},'
     ' "geodesics": {"height": 1, "samples": 10}, "operations": []}', "sha256"),
    ('{"format": "leaffit-usd-edits", "version": 1, "input": {"sha256": "' + "a" * 64 + '", "gaussians": 3},'
     ' "geodesics": {"height": -1, "samples": 10}, "operations": []}', "height"),
    ('{"format": "leaffit-usd-edits", "version": 1, "input": {"sha256": "' + "a" * 64 + '", "gaussians": 3},'
     ' "geodesics": {"height": 1, "samples": 10}, "operations": [3]}', "operations"),
    ('{"format": "leaffit-usd-edits", "version": 1, "input": {"sha256": "' + "a" * 64 + '", "gaussians": 3},'
     ' "geodesics": {"height": 1, "samples": 10, "normals": "up"}, "operations": []}', "normals"),
])
def test_malformed_files_are_refused(tmp_path, plant_file, text, words):
    p = tmp_path / "bad.json"
    p.write_text(text)
    with pytest.raises(InputFileError, match=words):
        load_edits(p, plant_file)
    with pytest.raises(InputFileError, match="no such"):
        load_edits(tmp_path / "missing.json", plant_file)


def test_different_base_labels_warn_but_apply(plant_file, heat, tmp_path, caplog):
    path, cloud = write_edits(tmp_path, plant_file, [{"op": "delete", "label": 1}],
                              base_labels_sha256=labels_sha256(np.zeros(3300, np.int32)), base_leaves=0)
    base = np.ones(len(cloud), np.int32)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        out = apply_edits(base, cloud, load_edits(path, plant_file), solver_factory=heat)
    assert "different starting labels" in caplog.text
    assert (out == 0).all()


def test_operation_index_mapping_round_trip(plant_file):
    cloud = load_cloud(plant_file)
    ops = [{"op": "drag", "source": 4, "target": 701, "mode": "add"}, {"op": "brush", "centers": [0, 2001]}]
    mapped = to_cloud_operations(ops, cloud)
    assert mapped[0]["source"] == 4 and mapped[0]["target"] == 699 and mapped[1]["centers"] == [0, 1998]
    from leaffit_usd.segment.edits import to_file_operations

    assert to_file_operations(mapped, cloud) == ops


def test_add_edits_argument():
    import argparse

    p = argparse.ArgumentParser()
    add_edits_argument(p)
    assert p.parse_args(["--edits", "e.json"]).edits == "e.json"
    assert p.parse_args([]).edits is None


def test_cloud_without_drops(plant, heat, tmp_path):
    """A plain GaussianCloud (file_index = arange) works the same way."""
    cloud: GaussianCloud = plant[0]
    assert np.array_equal(cloud.file_index, np.arange(len(cloud)))


def test_split_at_separates_merged_leaves_and_replays(plant, plant_file, heat, tmp_path):
    """Two leaves merged into one instance, split by one click on each: the geodesic partition
    gives the two leaves back, is saved as ``split_at`` with file indices, and replays exactly."""
    cloud = load_cloud(plant_file)
    truth = plant[1][cloud.file_index]
    merged = np.where(truth > 0, 1, 0).astype(np.int32)
    s = build_session(cloud, merged, plant_file, tmp_path / "e.json", tmp_path / "l.npz",
                      n_samples=1500, solver_factory=heat)
    def mid(k):  # a Gaussian in the middle of true leaf k
        x = np.abs(cloud.means[:, 0]) + 10 * (truth != k)
        return int(np.argmin(np.abs(x - 0.25)))

    a, b = mid(1), mid(2)
    s.segmenter.apply({"op": "split_at", "seeds": [a, b]})
    got = s.segmenter.final_labels()
    assert set(np.unique(got)) == {0, 1, 2}
    assert (got[truth == 1] == 1).mean() > 0.98 and (got[truth == 2] == 2).mean() > 0.98
    assert (got[truth == 0] == 0).all()  # the stem is not touched
    s.save()
    data = json.loads((tmp_path / "e.json").read_text())
    assert data["operations"] == [{"op": "split_at", "seeds": [int(cloud.file_index[a]),
                                                                int(cloud.file_index[b])]}]
    cloud2 = load_cloud(plant_file)
    replayed = apply_edits(merged.copy(), cloud2, load_edits(tmp_path / "e.json", plant_file),
                           solver_factory=heat)
    assert np.array_equal(cloud2.to_file_order(replayed), np.load(tmp_path / "l.npz")["labels"])
    # refused with one line: clicks on two leaves, on the stem, twice on one spot, one seed only
    seg = s.segmenter
    stem = int(np.flatnonzero(truth == 0)[0])
    for op, words in [({"op": "split_at", "seeds": [a, stem]}, "stem"),
                      ({"op": "split_at", "seeds": [a, int(np.flatnonzero(got == 2)[0])]}, "different leaves"),
                      ({"op": "split_at", "seeds": [a, a]}, "same spot"),
                      ({"op": "split_at", "seeds": [a]}, "two Gaussian indices")]:
        with pytest.raises(UserError, match=words):
            seg.apply(op)
        assert "\n" not in str(pytest.raises(UserError, seg.apply, op).value)
    # the file's seeds are index fields: out of range is refused at load
    bad = dict(data, operations=[{"op": "split_at", "seeds": [0, cloud.file_count]}])
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(InputFileError, match="not a Gaussian index"):
        load_edits(tmp_path / "bad.json", plant_file)
