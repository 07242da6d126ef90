"""serialize: a stage result round-trips through .npz + JSON."""
import dataclasses

import numpy as np

from leaffit_usd.segment.result import Segmentation
from leaffit_usd.serialize import load_value, save_value


def test_segmentation_round_trip(tmp_path):
    seg = Segmentation(labels=np.array([0, 1, 1, 2], np.int32), root_index=0,
                       apex_indices=np.array([2, 3]), params={"tau": 0.5})
    save_value(seg, tmp_path / "s.npz")
    back = load_value(Segmentation, tmp_path / "s.npz")
    for f in dataclasses.fields(seg):
        a, b = getattr(seg, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == b.dtype
        else:
            assert a == b
    assert back.n_leaves == 2
