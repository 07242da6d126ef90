"""Lead-owned core pieces: atomic writes, serialisation, FPS, frames."""
import dataclasses

import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.sampling import _fps_numpy, farthest_point_sampling
from leaffit_usd.io_util import atomic_path, atomic_write_bytes
from leaffit_usd.segment.result import Segmentation
from leaffit_usd.serialize import load_value, save_value
from leaffit_usd.splats.frame import Frame, rotation_to_z


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.usda"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_atomic_output_gets_the_usual_file_mode(tmp_path):
    import os
    import stat

    atomic_write_bytes(tmp_path / "m.bin", b"x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE((tmp_path / "m.bin").stat().st_mode) == 0o666 & ~mask


def test_atomic_write_replaces(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")
    atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


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


def test_fps_fast_path_equals_reference_set():
    p = np.random.default_rng(1).normal(size=(5000, 3))
    fast = farthest_point_sampling(p, 300)
    ref = np.sort(_fps_numpy(p, 300, 0))
    np.testing.assert_array_equal(fast, ref)


def test_fps_is_spread_out():
    # FPS of a dense grid picks points whose min pairwise distance is far above random sampling
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, 30)] * 2), -1).reshape(-1, 2)
    p = np.c_[g, np.zeros(len(g))]
    idx = farthest_point_sampling(p, 50)
    q = p[idx]
    d = np.linalg.norm(q[:, None] - q[None], axis=-1) + np.eye(50) * 9
    assert d.min() > 0.08  # random picks of 50 of 900 grid points come within one grid step (0.034)


def test_fps_bad_k_and_duplicates():
    with pytest.raises(ParameterError):
        farthest_point_sampling(np.zeros((5, 3)), 0)
    dup = np.zeros((10, 3))
    assert len(farthest_point_sampling(dup, 20)) == 1


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0.3, -0.8, 0.1)])
def test_rotation_to_z(up):
    r = rotation_to_z(np.array(up, float))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0)
    np.testing.assert_allclose(r @ (np.array(up) / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)


def test_frame_round_trip_and_units():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3)) * 3 + 7
    up = np.array([0.2, 0.9, -0.1])
    lowest = int(np.argmin(pts @ up))
    f = Frame.from_root_up(pts, pts[lowest], up)
    w = f.to_working(pts)
    np.testing.assert_allclose(w[lowest], 0, atol=1e-12)
    assert w[:, 2].max() == pytest.approx(1.0)
    np.testing.assert_allclose(f.to_input(w), pts, atol=1e-10)
    h = np.c_[pts, np.ones(100)]
    np.testing.assert_allclose((h @ f.input_to_working.T)[:, :3], w, atol=1e-10)
    np.testing.assert_allclose(f.working_to_input @ f.input_to_working, np.eye(4), atol=1e-12)
    assert Frame.from_dict(f.to_dict()).height == f.height
