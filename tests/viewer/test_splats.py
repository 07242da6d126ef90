"""The splats payload (``ViewerSession.splats_bytes``) and the fitted-leaf preview, server side."""
import numpy as np
import pytest

from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.viewer.leaf_preview import LeafPreviewer, sheet_grid
from leaffit_usd.viewer.server import ViewerSession, build_session


def _decode(buf: bytes, n: int):
    """The page's reading of the payload (splats.js parseSplats + the shader's unpacking)."""
    pos = np.frombuffer(buf, "<f4", 3 * n).reshape(n, 3)
    scales = np.frombuffer(buf, "<f2", 3 * n, 12 * n).reshape(n, 3).astype(np.float64)
    q = np.frombuffer(buf, "<i2", 4 * n, 18 * n).reshape(n, 4).astype(np.float64)
    rgba = np.frombuffer(buf, np.uint8, 4 * n, 26 * n).reshape(n, 4)
    return pos, scales, q / np.linalg.norm(q, axis=1, keepdims=True), rgba


def _cov(scales, q):
    from leaffit_usd.geometry.quaternion import quat_to_matrix

    r = quat_to_matrix(q).astype(np.float64)
    return np.einsum("nij,nj,nkj->nik", r, scales ** 2, r)


def _screen_cov(cov, pos, f=800.0):
    """EWA: J W Sigma W^T J^T for a camera at (0, 0, 3) looking down -Z (W = I), focal f px."""
    cam = pos - [0.0, 0.0, 3.0]
    z = -cam[:, 2]
    J = np.zeros((len(pos), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = f / z
    J[:, 0, 2] = f * cam[:, 0] / z ** 2
    J[:, 1, 2] = f * cam[:, 1] / z ** 2
    return J @ cov @ J.transpose(0, 2, 1)


def test_payload_layout_and_precision():
    rng = np.random.default_rng(3)
    n = 2000
    q = rng.normal(size=(n, 4))
    scales = np.exp(rng.uniform(np.log(2e-4), np.log(0.03), (n, 3))) * 2.0  # input units
    cloud = GaussianCloud.from_activated(rng.uniform(-1, 1, (n, 3)), scales, q,
                                         rng.uniform(0.01, 0.99, n), colors=rng.uniform(0, 1, (n, 3)))
    s = ViewerSession.starting(cloud, 2.0, "e.json", "l.npz")
    buf = s.splats_bytes()
    assert len(buf) == 30 * n and s.splats_bytes() is buf  # computed once
    pos, sc, qq, rgba = _decode(buf, n)
    assert np.allclose(pos * 2.0 + s.centre, cloud.means, atol=1e-6)
    assert np.allclose(sc * 2.0, cloud.scales, rtol=1e-3)
    assert np.abs(rgba[:, 3] / 255 - cloud.opacities).max() <= 0.5 / 255 + 1e-6
    assert np.abs(rgba[:, :3] / 255 - cloud.colors).max() <= 0.5 / 255 + 1e-6
    # the projected ellipses from the compact values against float64 from the cloud: within
    # 0.2% (Frobenius, relative) everywhere, needles with 150:1 axes included
    exact = _screen_cov(_cov(np.asarray(cloud.scales, np.float64) / 2.0, cloud.rotations), pos)
    got = _screen_cov(_cov(sc, qq), pos)
    err = np.linalg.norm(got - exact, axis=(1, 2)) / np.linalg.norm(exact, axis=(1, 2))
    assert err.max() < 0.002, err.max()


def test_sheet_grid_covers_the_points():
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1, 4000)
    v = rng.uniform(-1, 1, 4000) * np.sin(np.pi * u)
    pts = np.c_[u, 0.2 * v, 0.05 * np.sin(np.pi * u)]
    verts, faces, edges = sheet_grid(pts, cells=20)
    assert faces.max() < len(verts) and edges.max() < len(verts) and len(faces) > 100
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts).query(verts)
    assert d.max() < 0.06  # every node near the leaf (0.75 of a 0.05 cell in the plane, plus height)
    d2, _ = cKDTree(verts[:, :2]).query(pts[:, :2])
    assert d2.max() < 0.05  # and the leaf covered by the nodes


def test_leaf_preview_lies_on_the_leaf(plant, heat, tmp_path):
    """The fitted leaf of an instance (the template leaf deformed by MLS onto it) lies on that
    instance's Gaussians and covers it; an edit that changes the instance changes the preview."""
    from scipy.spatial import cKDTree

    from leaffit_usd.splats import load_cloud, write_ply

    write_ply(plant[0], tmp_path / "p.ply")
    cloud = load_cloud(tmp_path / "p.ply")
    truth = plant[1][cloud.file_index]
    s = build_session(cloud, truth, tmp_path / "p.ply", tmp_path / "e.json", tmp_path / "l.npz",
                      n_samples=800, solver_factory=heat, height=0.8, up=(0.0, 0.0, 1.0))
    out = s.leaf_preview(2)
    assert set(out) >= {"vertices", "faces", "edges", "ms", "fallback"} and not out["fallback"]
    import base64

    v = np.frombuffer(base64.b64decode(out["vertices"]), "<f4").reshape(-1, 3) * s.height + s.centre
    leaf = np.asarray(cloud.means[truth == 2], np.float64)
    d, _ = cKDTree(leaf).query(v)
    assert np.median(d) < 0.01 and d.max() < 0.05  # plant height 0.8: on the leaf
    d2, _ = cKDTree(v).query(leaf)
    assert np.percentile(d2, 95) < 0.04  # and covering it
    assert s.leaf_preview(2)["vertices"] == out["vertices"]  # same Gaussians: the cached fit
    assert "too few" in s.leaf_preview(99)["none"]
    # trim the leaf to its inner half: the preview follows
    outer = np.flatnonzero((truth == 2) & (cloud.means[:, 0] > 0.25))
    s.segmenter.apply({"op": "brush", "centers": [int(outer[0])], "radius": 0.0, "mode": "replace"})
    s.segmenter.state.selection[outer] = True  # (the selection a brush stroke would make)
    s.segmenter.apply({"op": "split", "label": 2})
    v2 = np.frombuffer(base64.b64decode(s.leaf_preview(2)["vertices"]), "<f4").reshape(-1, 3)
    assert (v2[:, 0] * s.height + s.centre[0]).max() < 0.25 + 0.03 < (v[:, 0]).max()


def test_previewer_needs_a_leaf(plant):
    prev = LeafPreviewer(plant[0], np.zeros(len(plant[0]), np.int32), np.eye(4))
    with pytest.raises(LookupError, match="no leaf"):
        prev.choose_template()
    with pytest.raises(LookupError, match="too few"):
        prev.preview(1, np.arange(10))
