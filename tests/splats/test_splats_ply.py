"""PLY reader/writer: bit-exact round trips and validation (each validator has a failing test)."""
import numpy as np
import pytest

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats import load_cloud, read_ply, write_ply
from tests.splats.plyfiles import INRIA, inria_rows, raw_ply, small_cloud, write_ply_order


def assert_clouds_identical(a, b):
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh", "file_index"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype and x.shape == y.shape, k
        assert x.tobytes() == y.tobytes(), k  # bit-exact, NaN payloads included
    assert list(a.extra) == list(b.extra)
    for k in a.extra:
        assert np.array_equal(a.extra[k], b.extra[k]) and a.extra[k].dtype.kind == b.extra[k].dtype.kind, k


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("ascii", [False, True])
@pytest.mark.parametrize("extra", [False, True], ids=["all-float", "mixed-types"])
def test_round_trip_bit_exact(tmp_path, degree, ascii, extra):
    """all-float files take the column-gather path of the reader, mixed types the per-field one."""
    cloud = small_cloud(150, degree, seed=degree, extra=extra)
    if not extra:
        cloud.extra = {"nx": np.zeros(150, np.float32), "ny": np.zeros(150, np.float32),
                       "nz": np.zeros(150, np.float32)}
    p1, p2 = tmp_path / "a.ply", tmp_path / "b.ply"
    write_ply(cloud, p1, ascii=ascii)
    back = read_ply(p1)
    assert back.sh_degree == degree and len(back) == 150
    assert_clouds_identical(cloud, back)
    write_ply(back, p2, ascii=ascii)
    assert p1.read_bytes() == p2.read_bytes()  # file -> cloud -> file is byte-identical


@pytest.mark.parametrize("extra", [False, True])
def test_big_endian_reads_same_values(tmp_path, extra):
    cloud = small_cloud(100, 2, extra=extra)
    write_ply(cloud, tmp_path / "le.ply")
    write_ply_order(cloud, tmp_path / "be.ply", ">")
    a, b = read_ply(tmp_path / "le.ply"), read_ply(tmp_path / "be.ply")
    assert_clouds_identical(a, b)


def test_chunked_read_spans_chunks(tmp_path, monkeypatch):
    """A file larger than one read chunk is stitched together exactly."""
    import leaffit_usd.splats.ply as ply

    monkeypatch.setattr(ply, "_CHUNK", 7)
    cloud = small_cloud(50, 3)
    write_ply(cloud, tmp_path / "c.ply")
    whole = read_ply(tmp_path / "c.ply")
    assert whole.means.tobytes() == cloud.means.tobytes()
    assert whole.sh.tobytes() == cloud.sh.tobytes()
    write_ply(whole, tmp_path / "d.ply")
    assert (tmp_path / "c.ply").read_bytes() == (tmp_path / "d.ply").read_bytes()


def test_channel_major_f_rest_layout(tmp_path):
    """f_rest_* is channel-major: f_rest_0..m-1 are red, next m green, last m blue."""
    names = INRIA + [f"f_rest_{i}" for i in range(9)]
    rows = inria_rows(4)
    rest = np.arange(9, dtype=np.float32)[None].repeat(4, 0)
    p = raw_ply(tmp_path / "c.ply", names, np.concatenate([rows, rest], 1))
    c = read_ply(p)
    assert c.sh.shape == (4, 4, 3)
    np.testing.assert_array_equal(c.sh[0, 1:, 0], [0, 1, 2])  # red coefficients
    np.testing.assert_array_equal(c.sh[0, 1:, 2], [6, 7, 8])  # blue coefficients


def test_plyfile_written_file_reads(tmp_path):
    """A file written by another tool (plyfile) with comments reads with the same values."""
    plyfile = pytest.importorskip("plyfile")
    rows = inria_rows(50)
    arr = np.zeros(50, dtype=[(n, "f4") for n in INRIA])
    for i, n in enumerate(INRIA):
        arr[n] = rows[:, i]
    el = plyfile.PlyElement.describe(arr, "vertex")
    plyfile.PlyData([el], comments=["made by plyfile"]).write(str(tmp_path / "p.ply"))
    c = read_ply(tmp_path / "p.ply")
    np.testing.assert_array_equal(c.means, rows[:, :3])
    np.testing.assert_array_equal(c.quats, rows[:, 13:17])


# ---- validation: each check has an input that trips it ----------------------------------------
def _expect(path, fragment):
    with pytest.raises(InputFileError) as e:
        load_cloud(path)
    msg = str(e.value)
    assert str(path) in msg and fragment in msg, msg
    assert "\n" not in msg


def test_not_ply(tmp_path):
    p = tmp_path / "g.ply"
    p.write_bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    _expect(p, "not a PLY")


def test_no_end_header(tmp_path):
    p = tmp_path / "h.ply"
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n")
    _expect(p, "end_header")


def test_bad_format_line(tmp_path):
    p = raw_ply(tmp_path / "f.ply", INRIA, inria_rows(3), fmt="binary_middle_endian")
    _expect(p, "format")


def test_bad_property_type(tmp_path):
    p = raw_ply(tmp_path / "t.ply", INRIA, inria_rows(3), types=["float"] * 16 + ["quaternion"])
    _expect(p, "bad property line")


def test_missing_properties(tmp_path):
    names = [n for n in INRIA if n not in ("opacity", "rot_3")]
    p = raw_ply(tmp_path / "m.ply", names, inria_rows(5)[:, :len(names)])
    _expect(p, "missing properties opacity, rot_3")


def test_wrong_rest_count(tmp_path):
    names = INRIA + [f"f_rest_{i}" for i in range(10)]
    p = raw_ply(tmp_path / "r.ply", names, np.zeros((3, len(names))))
    _expect(p, "10 f_rest_*")


def test_truncated(tmp_path):
    p = tmp_path / "tr.ply"
    write_ply(small_cloud(100), p)
    p.write_bytes(p.read_bytes()[:-37])
    _expect(p, "truncated")


def test_truncated_ascii(tmp_path):
    p = tmp_path / "tra.ply"
    write_ply(small_cloud(10), p, ascii=True)
    lines = p.read_bytes().splitlines(keepends=True)
    p.write_bytes(b"".join(lines[:-3]))
    _expect(p, "truncated")


def test_ascii_garbage_values(tmp_path):
    p = raw_ply(tmp_path / "ag.ply", INRIA, inria_rows(1), fmt="ascii")
    head = p.read_bytes().split(b"end_header\n")[0]
    p.write_bytes(head + b"end_header\n1 2 three\n")
    _expect(p, "ASCII")


def test_zero_vertices(tmp_path):
    p = raw_ply(tmp_path / "z.ply", INRIA, np.zeros((0, len(INRIA))))
    _expect(p, "no Gaussians")


def test_empty_file(tmp_path):
    p = tmp_path / "e.ply"
    p.write_bytes(b"")
    _expect(p, "empty")


def test_list_property(tmp_path):
    p = tmp_path / "l.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar int vertex_indices\n"
                  + "".join(f"property float {n}\n" for n in INRIA).encode() + b"end_header\n")
    _expect(p, "list property")


def test_few_nan_dropped_with_warning(tmp_path, caplog):
    rows = inria_rows(100)
    rows[[3, 50], 0] = np.nan
    rows[7, 13:17] = 0.0  # zero quaternion
    p = raw_ply(tmp_path / "n.ply", INRIA, rows)
    with caplog.at_level("WARNING", logger="leaffit_usd"):
        c = load_cloud(p)
    assert len(c) == 97 and c.file_count == 100
    assert 3 not in c.file_index and 7 not in c.file_index
    assert "dropped 3 of 100" in caplog.text
    labels = c.to_file_order(np.ones(len(c), np.int32), fill=-1)
    assert labels.shape == (100,) and labels[3] == -1 and labels[4] == 1


def test_many_nan_is_an_error(tmp_path):
    rows = inria_rows(10)
    rows[:8, 10] = np.inf
    _expect(raw_ply(tmp_path / "nn.ply", INRIA, rows), "8 of 10 Gaussians are invalid")


def test_all_zero_quaternions_is_an_error(tmp_path):
    rows = inria_rows(10)
    rows[:, 13:17] = 0
    _expect(raw_ply(tmp_path / "zq.ply", INRIA, rows), "zero-length quaternion")


def test_directory_and_missing(tmp_path):
    _expect(tmp_path, "directory")
    _expect(tmp_path / "nope.ply", "no such file")


def test_unknown_extension(tmp_path):
    p = tmp_path / "plant.obj"
    p.write_text("v 0 0 0\n")
    _expect(p, "unknown file type '.obj'")


def test_content_wins_over_extension(tmp_path):
    p = tmp_path / "actually_ply.dat"
    write_ply(small_cloud(20), p)
    assert len(load_cloud(p)) == 20
