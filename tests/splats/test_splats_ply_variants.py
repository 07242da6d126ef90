"""2DGS and Gaussian Opacity Fields PLYs (leaffit_usd.splats.ply_variants), written by plyfile in
the layouts their trainers' ``save_ply`` write (hbb1/2d-gaussian-splatting: no ``scale_2``;
autonomousvision/gaussian-opacity-fields: ``filter_3D`` after ``rot_3``).

Expected values are computed here in float64 from the written arrays, by the rules the trainers
render with, not by calling the module's functions.
"""
import json

import numpy as np
import plyfile
import pytest
from scipy.spatial.transform import Rotation

from leaffit_usd.cli import main
from leaffit_usd.splats import FORMAT_NAMES, detect_format, load_cloud, read_ply
from leaffit_usd.splats.ply_variants import SURFEL_THICKNESS, ply_kind

N = 300
REST = 9  # SH degree 1


def _fields(scales: int, gof: bool):
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
             *[f"f_rest_{i}" for i in range(REST)], "opacity",
             *[f"scale_{i}" for i in range(scales)], *[f"rot_{i}" for i in range(4)]]
    return names + (["filter_3D"] if gof else [])


def _write(path, scales: int, gof: bool, seed=0):
    r = np.random.default_rng(seed)
    names = _fields(scales, gof)
    v = np.zeros(N, dtype=[(n, "f4") for n in names])
    for n in names:
        v[n] = r.normal(size=N)
    for i in range(scales):
        v[f"scale_{i}"] = r.uniform(-6, -2, N)
    if gof:
        v["filter_3D"] = r.uniform(0.0, 0.02, N)
        v["filter_3D"][:10] = 0.0
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(path))
    return v


def test_kinds_from_property_names():
    assert ply_kind(_fields(3, False)) == "ply"
    assert ply_kind(_fields(2, False)) == "ply_2dgs"
    assert ply_kind(_fields(3, True)) == "ply_gof"
    assert ply_kind(["x", "y", "z", "red", "green", "blue", "label"]) == "ply_points"
    assert ply_kind(["x", "y", "z", "opacity"]) == "ply"  # a broken 3DGS: the 3DGS reader says what is missing


def test_2dgs_surfels_get_a_thin_third_scale_along_their_normal(tmp_path):
    v = _write(tmp_path / "s.ply", scales=2, gof=False)
    assert detect_format(tmp_path / "s.ply") == "ply_2dgs"
    c = read_ply(tmp_path / "s.ply")
    assert len(c) == N
    ls = np.c_[v["scale_0"], v["scale_1"]].astype(np.float64)
    np.testing.assert_array_equal(c.log_scales[:, :2], ls.astype(np.float32))
    want = np.exp(ls.min(1)) * SURFEL_THICKNESS
    assert np.allclose(np.exp(c.log_scales[:, 2].astype(np.float64)), want, rtol=1e-5)
    # 2DGS's surfel normal is its rotation's third column (local z); (w, x, y, z) in the file
    q = np.c_[v["rot_1"], v["rot_2"], v["rot_3"], v["rot_0"]].astype(np.float64)
    normal = Rotation.from_quat(q).as_matrix()[:, :, 2]
    cos = np.abs(np.einsum("ij,ij->i", c.shortest_axes().astype(np.float64), normal))
    assert cos.min() > 1 - 1e-5
    np.testing.assert_array_equal(c.opacity_logits, v["opacity"])
    np.testing.assert_array_equal(c.sh[:, 0, 1], v["f_dc_1"])
    np.testing.assert_array_equal(c.sh[:, 1:, 0], np.c_[[v[f"f_rest_{i}"] for i in range(3)]].T)
    assert set(c.extra) == {"nx", "ny", "nz"}


def test_gof_filter_is_applied_as_gof_renders(tmp_path):
    v = _write(tmp_path / "g.ply", scales=3, gof=True, seed=1)
    assert detect_format(tmp_path / "g.ply") == "ply_gof"
    c = load_cloud(tmp_path / "g.ply")
    s = np.exp(np.c_[v["scale_0"], v["scale_1"], v["scale_2"]].astype(np.float64))
    f = v["filter_3D"].astype(np.float64)[:, None]
    want_s = np.sqrt(s ** 2 + f ** 2)                                # get_scaling_with_3D_filter
    op = 1 / (1 + np.exp(-v["opacity"].astype(np.float64)))
    want_op = op * np.sqrt(np.prod(s ** 2, 1) / np.prod(s ** 2 + f ** 2, 1))  # get_opacity_with_3D_filter
    assert np.allclose(c.scales, want_s, rtol=1e-5)
    assert np.allclose(c.opacities, want_op, rtol=1e-4, atol=1e-6)
    assert (c.opacities[10:] < op[10:].astype(np.float32)).all()  # a filter only blurs and dims
    np.testing.assert_allclose(c.opacity_logits[:10], v["opacity"][:10], rtol=1e-5, atol=1e-5)  # f = 0
    assert "filter_3D" not in c.extra  # applied once; written back it would be applied again


@pytest.mark.parametrize("scales, gof, name", [(2, False, "2DGS"), (3, True, "Gaussian Opacity Fields")])
def test_inspect_names_the_variant(tmp_path, capsys, scales, gof, name):
    _write(tmp_path / "v.ply", scales, gof)
    assert main(["inspect", str(tmp_path / "v.ply"), "--up", "+z"]) == 0
    assert name in capsys.readouterr().out.splitlines()[0]
    assert main(["inspect", str(tmp_path / "v.ply"), "--json", "--up", "+z"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["format_name"] == FORMAT_NAMES[js["format"]] and name in js["format_name"]


def test_truncated_2dgs_exits_2(tmp_path, capsys):
    _write(tmp_path / "s.ply", scales=2, gof=False)
    (tmp_path / "t.ply").write_bytes((tmp_path / "s.ply").read_bytes()[:-500])
    try:
        code = main(["inspect", str(tmp_path / "t.ply"), "--up", "+z"])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "truncated" in err, err
