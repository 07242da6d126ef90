"""image_io: the one image reader/writer (formats, alpha, resize, atomicity, errors)."""
import numpy as np
import pytest

from leaffit_usd.image_io import (ImageError, image_has_alpha, read_image, read_image_u8,
                                  write_image)


def _rgba(h=8, w=12):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (h, w, 4)).astype(np.uint8)
    img[0, 0, 3] = 0           # a transparent texel keeps its colour (straight alpha)
    img[0, 0, :3] = (200, 100, 50)
    return img


def test_png_round_trip_is_exact_with_straight_alpha(tmp_path):
    img = _rgba()
    write_image(tmp_path / "a.png", img)
    assert np.array_equal(read_image_u8(tmp_path / "a.png"), img)
    assert image_has_alpha(tmp_path / "a.png")
    f = read_image(tmp_path / "a.png")
    assert f.dtype == np.float32 and f.shape == (8, 12, 4)


def test_float_input_jpg_drops_alpha_and_exr_is_linear(tmp_path):
    img = _rgba().astype(np.float32) / 255
    write_image(tmp_path / "a.jpg", img, jpeg_quality=100)
    assert not image_has_alpha(tmp_path / "a.jpg")
    back = read_image(tmp_path / "a.jpg")
    assert back.shape == (8, 12, 4) and np.all(back[..., 3] == 1)
    write_image(tmp_path / "a.exr", img)
    np.testing.assert_allclose(read_image(tmp_path / "a.exr"), img, atol=2e-3)  # sRGB -> linear -> sRGB
    import OpenImageIO as oiio
    raw = np.asarray(oiio.ImageBuf(str(tmp_path / "a.exr")).get_pixels(oiio.FLOAT))
    assert raw[1, 1, 0] < img[1, 1, 0] or img[1, 1, 0] in (0, 1)  # stored linear (darker)


def test_max_size_and_grey(tmp_path):
    img = np.full((40, 100, 3), 128, np.uint8)
    write_image(tmp_path / "s.png", img, max_size=25)
    back = read_image_u8(tmp_path / "s.png")
    assert back.shape == (10, 25, 4)
    assert np.all(np.abs(back[..., :3].astype(int) - 128) <= 1) and np.all(back[..., 3] == 255)


def test_errors_are_image_errors_and_leave_nothing(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(ImageError, match="bad.png"):
        read_image(tmp_path / "bad.png")
    with pytest.raises(ImageError, match="no such"):
        read_image(tmp_path / "missing.png")
    with pytest.raises(ImageError, match="type"):
        write_image(tmp_path / "x.tga", _rgba())
    with pytest.raises(ImageError, match="shape"):
        write_image(tmp_path / "x.png", np.zeros((4, 4)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.png"]


def _png_row_filters(path) -> set:
    """The filter byte of every row of an 8-bit RGBA PNG (the IDAT stream, inflated)."""
    import struct
    import zlib

    data = path.read_bytes()
    pos, idat, width = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            width = struct.unpack(">I", body[:4])[0]
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = 1 + 4 * width
    return {raw[i] for i in range(0, len(raw), stride)}


def test_png_rows_use_the_up_filter(tmp_path):
    # image_io writes PNG with libpng's "up" row filter (2 in the file) at zlib level 7: as small
    # as level 9's adaptive filters on leaf textures, in a tenth of the time
    rng = np.random.default_rng(0)
    img = np.clip(np.cumsum(rng.integers(-3, 4, (64, 48, 4)), axis=0) + 128, 0, 255).astype(np.uint8)
    p = tmp_path / "t.png"
    write_image(p, img)
    assert _png_row_filters(p) <= {0, 2} and 2 in _png_row_filters(p)
    assert (read_image_u8(p) == img).all()
