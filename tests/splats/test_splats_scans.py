"""Point-cloud scans (leaffit_usd.splats.scans): PLY x y z [rgb], ASCII .xyz/.txt/.pts, LAS/LAZ.

Every fixture is written here by an independent writer (plyfile, numpy.savetxt, laspy) and read
back through ``load_cloud``: positions exactly (float32), colours to float rounding, extra
properties verbatim in file order, and the Gaussians lie flat on the scanned sheet (their
shortest axis is the sheet's normal). Bad files stop ``inspect`` with exit 2 and one line.
"""
import json
import sys

import numpy as np
import plyfile
import pytest

from tests.test_cli_negative_args import run  # the CLI run helper (exit code, stdout, stderr)
from leaffit_usd.errors import InputFileError
from leaffit_usd.splats import FORMAT_NAMES, detect_format, load_cloud, read_ply
from leaffit_usd.splats.points import MIN_POINTS

N = 900
COLOR_TOL = 1e-6
NORMAL_COS = 0.95  # |cos| between a Gaussian's shortest axis and the flat sheet's normal (+z)


def sheet(n=N, seed=0):
    """(n, 3) float64 points on a flat 1 x 0.6 sheet at z = 0.3, in random order."""
    r = np.random.default_rng(seed)
    return np.c_[r.uniform(0, 1, n), r.uniform(0, 0.6, n), np.full(n, 0.3)]


def assert_flat(cloud):
    cos = np.abs(cloud.shortest_axes()[:, 2])
    assert np.median(cos) > NORMAL_COS and (cos > 0.8).mean() > 0.95


# ---- PLY ---------------------------------------------------------------------------------
def _ply(path, pts, color_fields=(), extra=(), text=False):
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4"), *color_fields, *extra]
    v = np.zeros(len(pts), dtype=fields)
    v["x"], v["y"], v["z"] = pts.T
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], text=text).write(str(path))
    return v


@pytest.mark.parametrize("text", [False, True])
def test_point_ply_uchar_rgb_and_extras_round_trip(tmp_path, text):
    pts = sheet()
    r = np.random.default_rng(1)
    p = tmp_path / "scan.ply"
    w = _ply(p, pts, [("red", "u1"), ("green", "u1"), ("blue", "u1")], [("label", "i4"), ("conf", "f8")], text)
    w["red"], w["green"], w["blue"] = r.integers(0, 256, (3, N))
    w["label"], w["conf"] = r.integers(0, 9, N), r.normal(size=N)
    plyfile.PlyData([plyfile.PlyElement.describe(w, "vertex")], text=text).write(str(p))
    assert detect_format(p) == "ply_points"
    c = load_cloud(p)
    assert len(c) == N and c.sh_degree == 0
    np.testing.assert_array_equal(c.means, pts.astype(np.float32))
    rgb = np.c_[w["red"], w["green"], w["blue"]] / 255.0
    assert np.abs(c.colors - rgb).max() < COLOR_TOL
    assert list(c.extra) == ["label", "conf"] and c.extra["label"].dtype == np.int32
    np.testing.assert_array_equal(c.extra["label"], w["label"])
    np.testing.assert_array_equal(c.extra["conf"], w["conf"])
    assert_flat(c)


def test_point_ply_float_rgb_and_no_colour(tmp_path):
    pts = sheet(seed=2)
    rgb = np.random.default_rng(3).uniform(0, 1, (N, 3))
    p = tmp_path / "f.ply"
    w = _ply(p, pts, [("r", "f4"), ("g", "f4"), ("b", "f4")])
    w["r"], w["g"], w["b"] = rgb.T
    plyfile.PlyData([plyfile.PlyElement.describe(w, "vertex")]).write(str(p))
    assert np.abs(load_cloud(p).colors - rgb.astype(np.float32)).max() < COLOR_TOL
    _ply(tmp_path / "grey.ply", pts)
    assert np.allclose(load_cloud(tmp_path / "grey.ply").colors, 0.5, atol=COLOR_TOL)


def test_read_ply_refuses_a_point_cloud_and_names_load_cloud(tmp_path):
    _ply(tmp_path / "p.ply", sheet())
    with pytest.raises(InputFileError, match="point-cloud PLY.*load_cloud"):
        read_ply(tmp_path / "p.ply")


def test_dropped_points_keep_their_extras_aligned(tmp_path):
    pts = sheet()
    pts[5] = np.nan
    p = tmp_path / "nan.ply"
    w = _ply(p, pts, extra=[("label", "u2")])
    w["label"] = np.arange(N)
    plyfile.PlyData([plyfile.PlyElement.describe(w, "vertex")]).write(str(p))
    c = load_cloud(p)
    assert len(c) == N - 1 and c.file_count == N
    np.testing.assert_array_equal(c.extra["label"], c.file_index)


# ---- ASCII -------------------------------------------------------------------------------
@pytest.mark.parametrize("layout", ["xyz", "xyz_rgb255", "xyz_rgb01_comma", "pts_leica", "xyz_i"])
def test_ascii_points_round_trip(tmp_path, layout):
    pts = sheet(seed=4)
    r = np.random.default_rng(5)
    rgb = r.integers(0, 256, (N, 3))
    inten = r.integers(-2048, 2048, N).astype(float)
    suffix, delim, header, table, fmt = {
        "xyz": (".xyz", " ", "", pts, "%.17g"),
        "xyz_rgb255": (".txt", " ", "# x y z r g b\n", np.c_[pts, rgb], ["%.17g"] * 3 + ["%d"] * 3),
        "xyz_rgb01_comma": (".xyz", ", ", "", np.c_[pts, rgb / 255.0], "%.17g"),
        "pts_leica": (".pts", " ", f"{N}\n", np.c_[pts, inten, rgb], ["%.17g"] * 3 + ["%d"] * 4),
        "xyz_i": (".xyz", "\t", "", np.c_[pts, inten], "%.17g"),
    }[layout]
    p = tmp_path / f"scan{suffix}"
    with open(p, "w") as f:
        f.write(header)
        np.savetxt(f, table, fmt=fmt, delimiter=delim)
    assert detect_format(p) == "xyz"
    c = load_cloud(p)
    assert len(c) == N
    np.testing.assert_array_equal(c.means, pts.astype(np.float32))
    want = np.full((N, 3), 0.5) if layout in ("xyz", "xyz_i") else rgb / 255.0
    assert np.abs(c.colors - want).max() < 1e-6
    if layout in ("pts_leica", "xyz_i"):
        np.testing.assert_array_equal(c.extra["intensity"], inten)
    else:
        assert c.extra == {}
    assert_flat(c)


# ---- LAS / LAZ ---------------------------------------------------------------------------
@pytest.mark.parametrize("suffix, eight_bit", [(".las", False), (".laz", False), (".las", True)])
def test_las_round_trip(tmp_path, suffix, eight_bit):
    laspy = pytest.importorskip("laspy", reason="the [scans] extra (make setup installs it)")
    pts = sheet(seed=6) + [1000.0, 2000.0, 0.0]
    r = np.random.default_rng(7)
    rgb = r.integers(0, 256, (N, 3)).astype(np.uint16)
    h = laspy.LasHeader(point_format=3, version="1.2")
    h.offsets, h.scales = [1000.0, 2000.0, 0.0], [1e-5] * 3
    h.add_extra_dim(laspy.ExtraBytesParams(name="label", type=np.int32))
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts.T
    stored = rgb if eight_bit else rgb * 257
    las.red, las.green, las.blue = stored.T
    las.classification = (np.arange(N) % 5).astype(np.uint8)
    las.label = r.integers(0, 20, N).astype(np.int32)
    p = tmp_path / f"scan{suffix}"
    las.write(str(p))
    assert detect_format(p) == "las"
    c = load_cloud(p)
    back = laspy.read(str(p))
    np.testing.assert_array_equal(c.means, np.c_[back.x, back.y, back.z].astype(np.float32))
    assert np.abs(c.means - pts).max() < 1e-3  # float32 at 2000 units
    assert np.abs(c.colors - rgb / 255.0).max() < COLOR_TOL
    np.testing.assert_array_equal(c.extra["classification"], np.arange(N) % 5)
    np.testing.assert_array_equal(c.extra["label"], las.label)
    assert_flat(c)


def test_truncated_las_exits_2(tmp_path, capsys):
    laspy = pytest.importorskip("laspy", reason="the [scans] extra")
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = sheet().T
    las.write(str(tmp_path / "ok.las"))
    (tmp_path / "cut.las").write_bytes((tmp_path / "ok.las").read_bytes()[:-1000])
    code, _, err = run(capsys, "inspect", tmp_path / "cut.las", "--up", "+z")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "LAS" in err, err


def test_las_without_the_extra_names_the_pip_command(tmp_path, capsys, monkeypatch):
    (tmp_path / "a.las").write_bytes(b"LASF" + bytes(400))
    monkeypatch.setitem(sys.modules, "laspy", None)  # import laspy -> ImportError
    code, _, err = run(capsys, "inspect", tmp_path / "a.las", "--up", "+z")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "pip install 'leaffit-usd[scans]'" in err


# ---- inspect: the kind, and bad files -------------------------------------------------------
def test_inspect_names_a_point_cloud(tmp_path, capsys):
    np.savetxt(tmp_path / "s.xyz", sheet())
    _ply(tmp_path / "s.ply", sheet())
    for f, key in (("s.xyz", "xyz"), ("s.ply", "ply_points")):
        code, out, err = run(capsys, "inspect", tmp_path / f, "--up", "+z")
        assert code == 0, err
        assert "point cloud" in out.splitlines()[0] and "neighbourhood" in out.splitlines()[0]
        code, out, _ = run(capsys, "inspect", tmp_path / f, "--json", "--up", "+z")
        js = json.loads(out)
        assert js["format"] == key and js["format_name"] == FORMAT_NAMES[key] and js["gaussians"] == N


def _bad_files(d):
    few = sheet(MIN_POINTS - 1)
    np.savetxt(d / "few.xyz", few)
    np.savetxt(d / "dupes.xyz", np.repeat(few[:10], 50, axis=0))
    (d / "words.xyz").write_text("1 2 3\n4 five 6\n" * 300)
    (d / "ragged.txt").write_text("1 2 3\n" * 300 + "1 2 3 4\n")
    (d / "comments.pts").write_text("# nothing\n\n# here\n")
    (d / "two.xyz").write_text("1 2\n3 4\n")
    _ply(d / "few.ply", few)
    ok = d / "ok.ply"
    _ply(ok, sheet())
    (d / "trunc.ply").write_bytes(ok.read_bytes()[:-100])
    (d / "garbage.las").write_bytes(b"LASF" + bytes(range(256)) * 2)
    return {"few.xyz": "at least 200", "dupes.xyz": "10 distinct points", "words.xyz": "bad point list",
            "ragged.txt": "bad point list", "comments.pts": "no points", "two.xyz": "at least x y z",
            "few.ply": "at least 200", "trunc.ply": "truncated", "garbage.las": "LAS"}


def test_bad_scans_exit_2_with_one_line(tmp_path, capsys):
    for name, fragment in _bad_files(tmp_path).items():
        code, out, err = run(capsys, "inspect", tmp_path / name, "--up", "+z")
        assert code == 2 and len(err.strip().splitlines()) == 1, (name, err)
        assert fragment in err and "Traceback" not in err, (name, err)
