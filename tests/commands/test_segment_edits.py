"""`leaffit-usd segment --edits`: the saved labels are the automatic ones with the edits replayed."""
import numpy as np

from leaffit_usd.cli import main
from leaffit_usd.io_util import file_sha256
from leaffit_usd.segment.edits import Edits, save_edits
from leaffit_usd.splats import write_ply
from tests.segment.two_leaf import two_leaf_plant


def test_segment_with_edits_replays_them(tmp_path):
    cloud, truth, tips, bases = two_leaf_plant()
    ply = tmp_path / "p.ply"
    write_ply(cloud, ply)
    auto = tmp_path / "auto.npz"
    assert main(["segment", str(ply), "-o", str(auto), "--up", "+z", "-q"]) == 0
    # send the whole right leaf back to the stem, with one brush stroke at its tip
    edits = Edits(input_sha256=file_sha256(ply), n_gaussians=len(cloud), height=1.0, n_samples=1500,
                  operations=[{"op": "brush", "centers": [int(tips[1])], "radius": 0.45, "mode": "replace"},
                              {"op": "assign", "label": 0}])
    save_edits(edits, tmp_path / "e.json")
    edited = tmp_path / "edited.npz"
    assert main(["segment", str(ply), "-o", str(edited), "--up", "+z", "--edits", str(tmp_path / "e.json"),
                 "-q"]) == 0
    a, e = np.load(auto)["labels"], np.load(edited)["labels"]
    right = truth == 2
    assert (a[right] > 0).mean() > 0.9          # the automatic run found the right leaf
    assert (e[right] == 0).mean() > 0.9         # the edit sent it to the stem
    left = truth == 1
    np.testing.assert_array_equal(e[left], a[left])   # the rest is untouched
    # edits recorded on another file are refused with exit 2
    other = tmp_path / "q.ply"
    write_ply(cloud.subset(np.arange(len(cloud) - 1)), other)
    assert main(["segment", str(other), "-o", str(tmp_path / "x.npz"), "--edits", str(tmp_path / "e.json"),
                 "-q"]) == 2
    assert not (tmp_path / "x.npz").exists()
