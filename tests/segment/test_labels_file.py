"""The segmentation file: its one writer and its one reader, round trip (file order, dropped and
removed Gaussians, renumbering, the root, the confidence) and bad files."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.errors import InputFileError
from leaffit_usd.segment.labels_file import cloud_labels, read_labels_file, write_labels_file
from leaffit_usd.splats.cloud import GaussianCloud


def _cloud(n_file: int, kept: np.ndarray) -> GaussianCloud:
    n = len(kept)
    c = GaussianCloud.from_activated(np.zeros((n, 3)), np.ones((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)),
                                     np.full(n, 0.5))
    c.file_index, c.file_count = np.asarray(kept, np.int64), n_file
    return c


def test_round_trip(tmp_path):
    # 10 Gaussians in the file; 0 and 9 dropped at load; the cloud in another order
    cloud = _cloud(10, np.array([5, 3, 1, 2, 4, 6, 8, 7]))
    labels = np.array([-1, 0, 4, 4, 0, 7, -1, 7, 9, -1], np.int32)  # leaves 4, 7, 9; -1 removed
    write_labels_file(tmp_path / "s.npz", labels, root_index=4, confidence=[0.0, 0.0, 0.0, 0.9, 0.0, 0.0, 0.2, 0.0, 0.5],
                      tree_nodes=np.arange(3))
    lf = read_labels_file(tmp_path / "s.npz")
    assert np.array_equal(lf.labels, labels) and lf.root_index == 4
    got, root, conf = cloud_labels(tmp_path / "s.npz", cloud)
    assert got.dtype == np.int32 and np.array_equal(got, [2, 1, 0, 1, 0, 0, 3, 2])
    assert root == 4 and np.allclose(conf, [0.9, 0.2, 0.5])
    write_labels_file(tmp_path / "plain.npz", labels)   # a hand-made file: labels alone
    got2, root2, conf2 = cloud_labels(tmp_path / "plain.npz", cloud)
    assert np.array_equal(got2, got) and root2 is None and conf2 is None


def test_the_segment_command_writes_what_convert_reads(tmp_path):
    """segment's file: labels in file order (-1 removed), its root and confidence, read back."""
    from leaffit_usd.cli import main
    from leaffit_usd.splats import write_ply
    from samples.generate import make_plant, preset

    cloud, _ = make_plant(preset("green_pepper", gaussians=8000), 2)
    write_ply(cloud, tmp_path / "p.ply")
    assert main(["segment", str(tmp_path / "p.ply"), "-o", str(tmp_path / "s.npz"), "-q"]) == 0
    lf = read_labels_file(tmp_path / "s.npz")
    assert len(lf.labels) == len(cloud) and lf.root_index is not None
    assert len(lf.confidence) == lf.labels.max()
    got, root, conf = cloud_labels(tmp_path / "s.npz", cloud)
    assert got.max() == lf.labels.max() and root == lf.root_index and np.allclose(conf, lf.confidence)


@pytest.mark.parametrize("what, message", [("missing", "no such file"), ("nolabels", "no 'labels'"),
                                           ("float", "1-D integer"), ("count", "labels but the input")])
def test_bad_files(tmp_path, what, message):
    p = tmp_path / "bad.npz"
    if what == "nolabels":
        np.savez(p, other=np.zeros(3))
    elif what == "float":
        np.savez(p, labels=np.zeros(10, np.float32))
    elif what == "count":
        np.savez(p, labels=np.zeros(4, np.int32))
    with pytest.raises(InputFileError, match=message):
        cloud_labels(p, _cloud(10, np.arange(10)))
