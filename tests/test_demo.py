"""The demo: summary + quick-look PNG (the conversion itself runs in make demo); exit 2 on a missing input."""
import numpy as np
import OpenImageIO as oiio

from leaffit_usd.demo import BACKGROUND, main, splat_points
from leaffit_usd.splats import write_ply
from tests.splats.splat_synth import make_plant


def test_splat_points_nearest_wins_and_orientation():
    pts = np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    cols = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1.0]], np.float32)
    img = splat_points(pts, cols, np.array([0.0, 5.0, 0.0]), 11, 11, (0, 1, 0, 1), radius=0)
    assert np.allclose(img[0, 0], [0, 1, 0])      # top-left: y = ymax is row 0; nearer (green) wins
    assert np.allclose(img[10, 10], [0, 0, 1])    # bottom-right
    assert np.allclose(img[5, 5], BACKGROUND)


def test_demo_writes_png(tmp_path, capsys):
    write_ply(make_plant(1, sh_degree=1).cloud, tmp_path / "p.ply")
    assert main([str(tmp_path / "p.ply"), str(tmp_path / "out"), "--size", "128", "--no-convert"]) == 0
    out = capsys.readouterr().out
    assert "gaussians" in out and "quicklook.png" in out
    buf = oiio.ImageBuf(str(tmp_path / "out" / "quicklook.png"))
    spec = buf.spec()
    assert (spec.width, spec.height, spec.nchannels) == (256, 128, 3)
    px = buf.get_pixels(oiio.FLOAT).reshape(128, 256, 3)
    green = (px[..., 1] > px[..., 0] + 0.1).mean()
    assert green > 0.02  # the leaves show up
    # plant upright: more coloured pixels in the upper half than in the bottom tenth
    fg = np.abs(px - np.asarray(BACKGROUND)).sum(-1) > 0.05
    assert fg[:64].sum() > fg[-13:].sum()


def test_demo_missing_input(tmp_path, capsys):
    assert main([str(tmp_path / "missing.ply"), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "no such file" in err
    assert not (tmp_path / "out").exists()
