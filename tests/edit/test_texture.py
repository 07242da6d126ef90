"""Texture edits: decal placement/orientation, replacement, masked fill, image I/O errors."""
import numpy as np
import pytest

from leaffit_usd.edit.texture import masked_fill, overlay_decal, replace_texture
from leaffit_usd.image_io import read_image, write_image
from leaffit_usd.errors import UserError


@pytest.fixture
def tex():
    t = np.zeros((64, 64, 4), np.float32)
    t[..., 1] = 0.6
    t[..., 3] = 1.0
    return t


@pytest.fixture
def decal():
    d = np.zeros((10, 20, 4), np.float32)
    d[..., 0] = 1.0
    d[..., 3] = 1.0
    d[:, :10, 2] = 1.0  # left half magenta, right half red: shows the orientation
    return d


def test_decal_lands_at_uv_with_scale(tex, decal):
    out = overlay_decal(tex, decal, uv=(0.5, 0.75), scale=0.5)
    ys, xs = np.nonzero(out[..., 0] > 0.5)
    # 32 px wide (0.5 of 64), 16 px high, centred at x = 32, y = (1 - 0.75) * 64 = 16
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (8, 23, 16, 47)
    ys, xs = np.nonzero(out[..., 2] > 0.5)
    assert xs.max() <= 32  # the magenta half stays on the left
    assert np.allclose(out[40:, :, :3], [0, 0.6, 0])  # untouched elsewhere


def test_decal_rotation_is_counter_clockwise_in_uv(tex, decal):
    out = overlay_decal(tex, decal, uv=(0.5, 0.5), scale=0.5, rotation_deg=90)
    ys, xs = np.nonzero(out[..., 2] > 0.5)
    assert ys.min() >= 31  # the left half turned CCW (v up) ends below the centre (rows grow down)


def test_decal_keeps_the_leaf_silhouette(tex, decal):
    tex[:, :20, 3] = 0.0
    out = overlay_decal(tex, decal, uv=(0.3, 0.5), scale=0.5)
    np.testing.assert_array_equal(out[..., 3], tex[..., 3])


def test_decal_outside_uv_square_is_refused(tex, decal):
    with pytest.raises(UserError):
        overlay_decal(tex, decal, uv=(1.5, 0.5))
    with pytest.raises(UserError):
        overlay_decal(tex, decal, scale=0)


def test_replace_resizes_and_keeps_alpha(tex):
    tex[:10, :, 3] = 0
    new = np.zeros((16, 16, 4), np.float32)
    new[..., 2] = 1.0
    new[..., 3] = 1.0
    out = replace_texture(tex, new)
    assert out.shape == tex.shape
    np.testing.assert_allclose(out[..., 2], 1.0, atol=1e-5)
    np.testing.assert_array_equal(out[..., 3], tex[..., 3])
    np.testing.assert_allclose(replace_texture(tex, new, new_has_alpha=True)[..., 3], 1.0, atol=1e-5)


def test_masked_fill_repaints_from_surroundings(tex):
    t = tex.copy()
    t[20:30, 20:30, :3] = [1, 0, 0]  # a blemish
    m = np.zeros((64, 64), bool)
    m[20:30, 20:30] = True
    out = masked_fill(t, m)
    np.testing.assert_allclose(out[20:30, 20:30, :3], np.broadcast_to([0, 0.6, 0], (10, 10, 3)), atol=1e-3)
    np.testing.assert_array_equal(out[~m], t[~m])
    with pytest.raises(UserError):
        masked_fill(t, np.zeros((8, 8), bool))


def test_masked_fill_ignores_transparent_background(tex):
    t = tex.copy()
    t[:, 32:, 3] = 0.0
    t[:, 32:, :3] = [0, 0, 1]  # colour under zero alpha must not leak in
    m = np.zeros((64, 64), bool)
    m[28:36, 24:31] = True
    out = masked_fill(t, m)
    assert out[28:36, 24:31, 2].max() < 1e-3


def test_image_round_trip_and_errors(tmp_path, tex):
    write_image(tmp_path / "t.png", tex)
    back = read_image(tmp_path / "t.png")
    np.testing.assert_allclose(back, tex, atol=1 / 255)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(UserError):
        read_image(tmp_path / "bad.png")
    with pytest.raises(UserError):
        read_image(tmp_path / "missing.png")
