"""Compressed PLY, SPZ, SOG and .splat inputs equal the INRIA PLY they were written from.

The fixtures (tests/splats/fixtures/formats/, made by scripts/make_format_fixtures.py) were
written by writers independent of our readers: PlayCanvas's splat-transform 3.7.0 (the
reference writer of compressed PLY and SOG; SPZ v3 and v4) and gaussforge 0.6.0 (.splat).
Each decoded cloud is compared with ``sh3.ply`` / ``sh0.ply`` read by our PLY reader, to a
tolerance derived from the format's quantisation (one quantisation step unless stated):

==============  =================================================================================
compressed PLY  per 256-Gaussian chunk: position 11/10/11 bits and log-scale 11/10/11 bits of
                the chunk extent (bounded here by the whole cloud's extent), colour 8 bits of the
                chunk's range, opacity 8 bits, rotation smallest-three 10 bits in +-1/sqrt2, SH
                bands 8 bits over [-4, 4]
SPZ             position 24-bit fixed point with 12 fractional bits, log-scale (x+10)*16 in 8
                bits, colour 8 bits with 0.15 scale, opacity 8 bits, rotation smallest-three, SH
                band 1 to 5 bits and bands 2-3 to 4 bits of x*128+128
SOG             position 16 bits of sign(x) ln(|x|+1) in the file's [mins, maxs]; scales and
                colour: the nearest of 256 codebook values; opacity 8 bits; rotation
                smallest-three 8 bits; higher SH: a palette of SH vectors (k-means) coded in a
                256-value codebook -- the fixture draws its SH from 16 vectors, which a palette
                holds exactly, so the bound is the codebook's
.splat          position and scales float32 (exact), colour and opacity 8 bits, rotation 8 bits
                per component (writers differ by up to one step in the byte convention)
==============  =================================================================================

The largest quaternion component is rebuilt from the three stored ones, so rotations are held
to sqrt(3) stored steps. Writers reorder Gaussians (Morton order for compressed PLY and SOG);
Gaussians are paired by nearest position, which is far below the fixtures' spacing.
"""
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from leaffit_usd.cli import main
from leaffit_usd.splats import detect_format, load_cloud, read_ply, write_ply
from leaffit_usd.splats.cloud import SH_C0, GaussianCloud

FIX = Path(__file__).parent / "fixtures" / "formats"
SQ2 = np.sqrt(2.0)
gsply = pytest.importorskip("gsply", reason="the [formats] extra (make setup installs it)")


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def _paired(ref: GaussianCloud, got: GaussianCloud, max_dist: float) -> GaussianCloud:
    """``ref`` reordered to ``got``'s order by nearest position (checked one-to-one and close)."""
    d, idx = cKDTree(ref.means).query(got.means)
    assert len(got) == len(ref) and len(set(idx.tolist())) == len(ref), "not a one-to-one pairing"
    assert d.max() <= max_dist
    return ref.subset(idx)


def _quat_err(a: GaussianCloud, b: GaussianCloud) -> float:
    qa, qb = a.rotations.astype(np.float64), b.rotations.astype(np.float64)
    s = np.where((qa * qb).sum(1, keepdims=True) < 0, -1.0, 1.0)  # q and -q are one rotation
    return float(np.abs(qa * s - qb).max())


def _codebook_bound(codebook, values) -> float:
    """Largest distance from any of ``values`` to its nearest codebook entry can be."""
    c = np.sort(np.asarray(codebook, np.float64))
    v = np.asarray(values, np.float64)
    return float(max(np.diff(c).max() / 2, c[0] - v.min(), v.max() - c[-1], 0.0)) + 1e-6


def _check_common(ref, got, *, pos, log_scale, dc, quat, opacity=1 / 255):
    assert (np.abs(got.means - ref.means).max(axis=0) <= np.broadcast_to(pos, 3) + 1e-7).all(), "positions"
    assert np.abs(got.log_scales - ref.log_scales).max() <= log_scale + 1e-6, "scales"
    assert np.abs(_sigmoid(got.opacity_logits) - _sigmoid(ref.opacity_logits)).max() <= opacity + 1e-6
    assert np.abs(got.sh[:, 0] - ref.sh[:, 0]).max() <= dc + 1e-5, "colour (SH DC)"
    assert _quat_err(got, ref) <= quat + 1e-5, "rotations"


@pytest.mark.parametrize("name", ["sh3", "sh0"])
def test_compressed_ply_equals_ply(name):
    ref, path = read_ply(FIX / f"{name}.ply"), FIX / f"{name}.compressed.ply"
    assert detect_format(path) == "compressed_ply"
    got = load_cloud(path)
    extent = ref.means.max(0) - ref.means.min(0)
    pos = extent / np.array([2047, 1023, 2047])
    ref = _paired(ref, got, float(np.linalg.norm(pos)))
    ls = ref.log_scales
    dc = float(np.ptp(ref.sh[:, 0])) / 255
    _check_common(ref, got, pos=pos, log_scale=float(np.ptp(ls)) / 1023, dc=dc,
                  quat=np.sqrt(3) * SQ2 / 1023)
    assert got.sh_degree == ref.sh_degree
    if ref.sh_degree:
        assert np.abs(got.sh[:, 1:] - ref.sh[:, 1:]).max() <= 8 / 255 + 1e-6


@pytest.mark.parametrize("name", ["sh3", "sh0"])
@pytest.mark.parametrize("version", ["v3", "v4"])
def test_spz_equals_ply(name, version):
    ref, path = read_ply(FIX / f"{name}.ply"), FIX / f"{name}.{version}.spz"
    assert detect_format(path) == "spz"
    got = load_cloud(path)
    assert np.array_equal(cKDTree(ref.means).query(got.means)[1], np.arange(len(ref)))  # order kept
    _check_common(ref, got, pos=2.0 ** -12, log_scale=1 / 16, dc=1 / (0.15 * 255),
                  quat=np.sqrt(3) * SQ2 / 511)
    assert got.sh_degree == ref.sh_degree
    if ref.sh_degree:
        assert np.abs(got.sh[:, 1:4] - ref.sh[:, 1:4]).max() <= 8 / 128 + 1 / 256   # band 1, 5 bits
        assert np.abs(got.sh[:, 4:] - ref.sh[:, 4:]).max() <= 16 / 128 + 1 / 256   # bands 2-3, 4 bits


@pytest.mark.parametrize("name", ["sh3", "sh0"])
def test_sog_equals_ply(name):
    ref, path = read_ply(FIX / f"{name}.ply"), FIX / f"{name}.sog"
    assert detect_format(path) == "sog"
    meta = json.loads(zipfile.ZipFile(path).read("meta.json"))
    got = load_cloud(path)
    step_n = (np.array(meta["means"]["maxs"]) - np.array(meta["means"]["mins"])) / 65535
    ref = _paired(ref, got, 1e-3)
    pos = (1 + np.abs(ref.means).max(0)) * step_n * 1.01
    _check_common(ref, got, pos=pos,
                  log_scale=_codebook_bound(meta["scales"]["codebook"], ref.log_scales),
                  dc=_codebook_bound(meta["sh0"]["codebook"], ref.sh[:, 0]),
                  quat=np.sqrt(3) * SQ2 / 255)
    assert got.sh_degree == ref.sh_degree
    if ref.sh_degree:
        bound = _codebook_bound(meta["shN"]["codebook"], ref.sh[:, 1:])
        assert np.abs(got.sh[:, 1:] - ref.sh[:, 1:]).max() <= bound


def test_sog_unbundled_folder_and_meta_json(tmp_path):
    """The same SOG unpacked: its folder and its meta.json read as the bundle does."""
    with zipfile.ZipFile(FIX / "sh3.sog") as z:
        z.extractall(tmp_path / "scene")
    bundle = load_cloud(FIX / "sh3.sog")
    for p in (tmp_path / "scene", tmp_path / "scene" / "meta.json"):
        assert detect_format(p) == "sog"
        c = load_cloud(p)
        assert np.array_equal(c.means, bundle.means) and np.array_equal(c.sh, bundle.sh)


@pytest.mark.parametrize("name", ["sh3", "sh0"])
def test_splat_equals_ply(name):
    ref, path = read_ply(FIX / f"{name}.ply"), FIX / f"{name}.splat"
    assert detect_format(path) == "splat"
    got = load_cloud(path)
    ref = _paired(ref, got, 0.0)  # float32 positions: exact
    _check_common(ref, got, pos=0.0, log_scale=1e-6, dc=1 / 255 / SH_C0, quat=2 / 128)
    assert got.sh_degree == 0  # .splat keeps the DC colour only


@pytest.mark.parametrize("degree", [1, 2])
def test_gsply_writers_round_trip_other_sh_degrees(degree, tmp_path):
    """gsply's own SPZ writer, for the SH degrees the fixtures (0, 3) skip. (Its compressed-PLY
    writer is left out: numba compiles it for ~20 s in every process.)"""
    from tests.splats.plyfiles import small_cloud

    ref = small_cloud(500, sh_degree=degree, seed=degree)
    ref.quats /= np.linalg.norm(ref.quats, axis=1, keepdims=True)
    ref.sh = np.clip(ref.sh, -1, 1).astype(np.float32)
    ref.log_scales = np.clip(ref.log_scales, -8, -1).astype(np.float32)
    write_ply(ref, tmp_path / "a.ply")
    gsply.write_spz(tmp_path / "a.spz", gsply.plyread(tmp_path / "a.ply"))
    got = load_cloud(tmp_path / "a.spz", drop_bad=False)
    assert got.sh_degree == degree
    r = _paired(ref, got, 0.01)
    assert np.abs(got.sh[:, 0] - r.sh[:, 0]).max() <= 1 / (0.15 * 255) + 1e-5
    assert np.abs(got.sh[:, 1:4] - r.sh[:, 1:4]).max() <= 8 / 128 + 1 / 256
    assert np.abs(got.sh[:, 4:] - r.sh[:, 4:]).max(initial=0) <= 16 / 128 + 1 / 256
    assert np.abs(got.means - r.means).max() <= 2.0 ** -12 + 1e-7


# ---- the missing extra, inspect (malformed files: tests/test_cli.py, built by formatfiles.py) ----

def test_without_the_extra_one_line_names_the_install_command(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "gsply", None)  # import gsply -> ImportError
    for f in ("sh0.compressed.ply", "sh0.v3.spz", "sh0.sog"):
        code = main(["inspect", str(FIX / f), "--up", "+z"])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "pip install 'leaffit-usd[formats]'" in err
    assert main(["inspect", str(FIX / "sh0.splat"), "--up", "+z"]) == 0  # ours: no extra needed
    capsys.readouterr()


@pytest.mark.parametrize("f, name", [("sh0.ply", "INRIA 3DGS PLY"), ("sh0.compressed.ply", "compressed PLY"),
                                     ("sh0.v4.spz", "SPZ"), ("sh0.sog", "SOG"), ("sh0.splat", ".splat")])
def test_inspect_names_the_format(f, name, capsys):
    assert main(["inspect", str(FIX / f), "--up", "+z"]) == 0  # (+z: no up estimate, faster)
    out = capsys.readouterr().out
    assert name in out.splitlines()[0]
    assert main(["inspect", str(FIX / f), "--json", "--up", "+z"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["format"] == detect_format(FIX / f) and name in js["format_name"] and js["gaussians"] == 64
