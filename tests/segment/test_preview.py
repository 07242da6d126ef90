"""The segmentation preview raster."""
import numpy as np

from leaffit_usd.segment.preview import leaf_colors, render_preview, write_preview
from leaffit_usd.segment.result import Segmentation


def _seg():
    rng = np.random.default_rng(0)
    pts = np.r_[np.c_[np.zeros(200), np.zeros(200), np.linspace(0, 1, 200)],
                np.c_[rng.random(300) * 0.3 + 0.05, rng.random(300) * 0.1, np.full(300, 0.6)]]
    labels = np.r_[np.zeros(200, np.int32), np.ones(300, np.int32)]
    tip = 200 + int(np.argmax(pts[200:, 0]))
    seg = Segmentation(labels=labels, root_index=0, apex_indices=np.array([tip]),
                       apex_labels=np.array([1], np.int32), leaf_tip=np.array([tip]),
                       leaf_base=np.array([200 + int(np.argmin(pts[200:, 0]))]),
                       tree_nodes=np.array([0, 120, tip]), tree_parent=np.array([-1, 0, 1]),
                       tree_leaf=np.array([0, 0, 1], np.int32), dist_root=np.zeros(500, np.float32))
    return pts, seg


def test_render_two_views_with_marks():
    pts, seg = _seg()
    img = render_preview(pts, seg, size=200)
    assert img.shape == (200, 400, 3) and img.dtype == np.float32
    leaf = leaf_colors(1)[1]
    for half in (img[:, :200], img[:, 200:]):
        assert (np.abs(half - leaf).sum(-1) < 1e-5).sum() > 5            # the leaf, in both views
        assert (np.abs(half - [0.9, 0.05, 0.05]).sum(-1) < 1e-5).any()   # apex ring
        assert (np.abs(half - [0.05, 0.2, 0.95]).sum(-1) < 1e-5).any()   # petiole base
        assert (np.abs(half - 0.05).sum(-1) < 1e-5).any()                 # tree edges


def test_write_preview_png(tmp_path):
    import OpenImageIO as oiio

    pts, seg = _seg()
    out = tmp_path / "p.png"
    write_preview(out, pts, seg, size=64)
    buf = oiio.ImageBuf(str(out))
    assert (buf.spec().width, buf.spec().height, buf.spec().nchannels) == (128, 64, 3)
    assert not list(tmp_path.glob(".p.*"))  # no temporary left behind
