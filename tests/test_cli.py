"""The command line: --help/--version, inspect, and the malformed-input suite.

Every malformed input must give exit code 2 and exactly one line on stderr naming the file,
never a traceback. Most cases run ``cli.main`` in-process (fast); a few run the real interpreter.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from leaffit_usd import __version__
from leaffit_usd.cli import main
from leaffit_usd.splats import write_ply
from leaffit_usd.splats.usd_io import write_usd_splats
from tests.splats.formatfiles import malformed_format_files
from tests.splats.plyfiles import INRIA, inria_rows, raw_ply, small_cloud, write_ply_order

REPO = Path(__file__).resolve().parents[1]


def run_cli(capsys, *argv):
    try:
        code = main(list(map(str, argv)))
    except SystemExit as e:  # argparse usage errors exit from inside main
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def _bad_files(d: Path) -> dict:
    """name -> (path, fragment expected in the one-line message)."""
    files = {}
    ok = d / "ok.ply"
    write_ply(small_cloud(60), ok)
    t = d / "truncated.ply"
    t.write_bytes(ok.read_bytes()[:-100])
    files["truncated"] = (t, "truncated")
    g = d / "garbage.ply"
    g.write_bytes(np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    files["garbage"] = (g, "not a PLY")
    h = d / "wrong_header.ply"
    h.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nnot_a_keyword\nend_header\n")
    files["wrong_header"] = (h, "malformed PLY header")
    nh = d / "no_end_header.ply"
    nh.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 2\n")
    files["no_end_header"] = (nh, "end_header")
    rows = inria_rows(20)
    rows[:15, 0] = np.nan
    files["many_nan"] = (raw_ply(d / "many_nan.ply", INRIA, rows), "15 of 20 Gaussians are invalid")
    e = d / "empty.ply"
    e.write_bytes(b"")
    files["empty_file"] = (e, "empty")
    files["zero_gaussians"] = (raw_ply(d / "zero.ply", INRIA, np.zeros((0, 17))), "no Gaussians")
    names = [n for n in INRIA if n not in ("scale_1",)]
    files["missing_fields"] = (raw_ply(d / "missing.ply", names, inria_rows(4)[:, :16]),
                               "missing properties scale_1")
    rows = inria_rows(10)
    rows[:, 13:17] = 0
    files["zero_quaternions"] = (raw_ply(d / "zeroq.ply", INRIA, rows), "zero-length quaternion")
    files["directory"] = (d, "directory")
    files["missing_file"] = (d / "does_not_exist.ply", "no such file")
    u = d / "plant.obj"
    u.write_text("1 2 3\n")
    files["unknown_extension"] = (u, "unknown file type")
    a = d / "trunc_ascii.ply"
    write_ply(small_cloud(10), a, ascii=True)
    a.write_bytes(a.read_bytes()[:-60])
    files["truncated_ascii"] = (a, "")
    ru = d / "rest.ply"
    names = INRIA + [f"f_rest_{i}" for i in range(7)]
    files["bad_sh_count"] = (raw_ply(ru, names, np.ones((3, len(names)))), "7 f_rest_*")
    bu = d / "bad.usda"
    bu.write_text("#usda 1.0\ndef Mesh \"M\" {\n  point3f[] points = [(0, 0\n")
    files["broken_usda"] = (bu, "parse error at line 4")
    gu = d / "garbage.usdc"
    gu.write_bytes(b"PXR-USDC" + bytes(range(256)) * 3)
    files["garbage_usdc"] = (gu, "not a readable USD file")
    nu = d / "nosplat.usda"
    nu.write_text("#usda 1.0\ndef Xform \"World\" {\n}\n")
    files["usd_without_splats"] = (nu, "no ParticleField3DGaussianSplat prim")
    two = d / "two.usda"
    write_usd_splats(small_cloud(5), d / "one.usda")
    txt = (d / "one.usda").read_text()
    body = txt[txt.index("def ParticleField3DGaussianSplat"):]
    two.write_text(txt + "\n" + body.replace('"Splats"', '"Splats2"', 1))
    files["usd_two_prims"] = (two, "choose one with --prim")
    files.update(malformed_format_files(d))  # compressed PLY, SPZ, SOG, .splat
    return files


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory):
    return _bad_files(tmp_path_factory.mktemp("bad"))


CASES = ["truncated", "garbage", "wrong_header", "no_end_header", "many_nan", "empty_file",
         "zero_gaussians", "missing_fields", "zero_quaternions", "directory", "missing_file",
         "unknown_extension", "truncated_ascii", "bad_sh_count", "broken_usda", "garbage_usdc",
         "usd_without_splats", "usd_two_prims",
         "compressed_ply_truncated", "spz_truncated", "spz_v4_truncated", "spz_garbage",
         "sog_truncated", "sog_missing_image", "sog_bad_meta", "splat_truncated", "splat_not_splat",
         "splat_empty"]


@pytest.mark.parametrize("case", CASES)
def test_malformed_input_exit_2_one_line(capsys, bad_files, case):
    path, fragment = bad_files[case]
    code, out, err = run_cli(capsys, "inspect", path)
    assert code == 2, (case, err)
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and lines[0].startswith("leaffit-usd inspect: error: ")
    assert str(path) in lines[0] and fragment in lines[0], lines[0]
    assert out == ""


def test_malformed_input_real_interpreter(bad_files):
    """Same contract through `python -m leaffit_usd` (no test harness in between)."""
    for case in ("garbage", "truncated", "broken_usda", "garbage_usdc", "usd_two_prims",
                 "spz_garbage", "sog_truncated"):
        path, _ = bad_files[case]
        r = subprocess.run([sys.executable, "-m", "leaffit_usd", "inspect", str(path)],
                           capture_output=True, text=True, cwd=REPO, timeout=120)
        assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
        assert "Traceback" not in r.stderr


def test_usage_errors_exit_2(capsys, bad_files, tmp_path):
    code, _, err = run_cli(capsys, "inspect")
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    write_ply(small_cloud(30), tmp_path / "a.ply")
    code, _, err = run_cli(capsys, "inspect", tmp_path / "a.ply", "--up", "sideways")
    assert code == 2 and len(err.splitlines()) == 1 and "--up" in err
    code, _, err = run_cli(capsys, "inspect", tmp_path / "a.ply", "--prim", "/X")
    assert code == 2 and "USD files only" in err


# ---- valid inputs --------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_inspect_sh_degrees_json(capsys, tmp_path, degree):
    p = tmp_path / f"d{degree}.ply"
    write_ply(small_cloud(80, degree, extra=True), p)
    code, out, err = run_cli(capsys, "inspect", p, "--json", "--up", "+z")
    assert code == 0, err
    s = json.loads(out)
    assert s["sh_degree"] == degree and s["gaussians"] == 80 and s["dropped"] == 0
    assert s["extra_properties"] == {"nx": "float32", "ny": "float32", "nz": "float32",
                                     "label": "uint8", "conf": "float64", "cluster": "int32"}
    assert s["up"] == {"vector": [0.0, 0.0, 1.0], "source": "given", "confidence": None}
    assert s["memory_bytes"] > 80 * (3 + 3 + 4 + 1 + 3 * (degree + 1) ** 2) * 4


def test_inspect_ascii_and_big_endian(capsys, tmp_path):
    c = small_cloud(50, 1)
    write_ply(c, tmp_path / "a.ply", ascii=True)
    write_ply_order(c, tmp_path / "b.ply", ">")
    outs = []
    for name in ("a.ply", "b.ply"):
        code, out, err = run_cli(capsys, "inspect", tmp_path / name, "--json")
        assert code == 0, err
        outs.append(json.loads(out))
    assert outs[0]["bounds"] == outs[1]["bounds"] and outs[0]["gaussians"] == 50


def test_inspect_few_nan_warns_once_and_succeeds(capsys, tmp_path):
    rows = inria_rows(200)
    rows[5, 2] = np.nan
    rows[9, 13:17] = 0
    p = raw_ply(tmp_path / "n.ply", INRIA, rows)
    code, out, err = run_cli(capsys, "inspect", p, "--json", "-q")
    assert code == 0
    warn = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "dropped 2 of 200" in warn[0]
    s = json.loads(out)
    assert s["gaussians"] == 198 and s["dropped"] == 2 and s["file_gaussians"] == 200


def test_inspect_table_on_plant_and_usd(capsys, tmp_path):
    from tests.splats.splat_synth import make_plant

    sp = make_plant(3)
    write_usd_splats(sp.cloud, tmp_path / "p.usdc")
    code, out, err = run_cli(capsys, "inspect", tmp_path / "p.usdc")
    assert code == 0, err
    for key in ("gaussians", "SH degree", "bounds min", "up axis", "height", "memory", "opacity"):
        assert key in out
    code, out, _ = run_cli(capsys, "inspect", tmp_path / "p.usdc", "--json", "--prim", "/Splats")
    s = json.loads(out)
    assert s["format"] == "usd"
    assert s["height"] == pytest.approx(sp.height, rel=0.08)
    up = np.asarray(s["up"]["vector"])
    assert np.degrees(np.arccos(np.clip(up @ sp.up, -1, 1))) < 30


def test_help_and_version():
    r = subprocess.run([sys.executable, "-m", "leaffit_usd", "--version"], capture_output=True,
                       text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"leaffit-usd {__version__}"
    r = subprocess.run([sys.executable, "-m", "leaffit_usd", "--help"], capture_output=True,
                       text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0 and "inspect" in r.stdout and "usage:" in r.stdout
    r = subprocess.run([sys.executable, "-m", "leaffit_usd", "inspect", "--help"],
                       capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0 and "--json" in r.stdout and "--up" in r.stdout


@pytest.mark.parametrize("n", [1, 3])
def test_inspect_tiny_clouds(capsys, tmp_path, n):
    p = tmp_path / "tiny.ply"
    write_ply(small_cloud(n), p)
    code, out, err = run_cli(capsys, "inspect", p, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["gaussians"] == n and s["up"]["source"].startswith("default")


def test_a_command_imports_only_its_own_module():
    """``leaffit-usd segment ...`` builds the parser of ``segment`` alone: the other commands'
    modules (USD writing, meshing, the editor) are a second of start-up it does not need. The
    top-level help still lists every command."""
    code = ("import sys; from leaffit_usd.cli import build_parser; "
            "p = build_parser(['segment', 'x.ply']); "
            "print(sorted(m for m in sys.modules if m.startswith('leaffit_usd.commands.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO).stdout
    assert "leaffit_usd.commands.segment" in out
    for other in ("convert", "edit", "export", "bake", "batch", "retarget"):
        assert f"leaffit_usd.commands.{other}'" not in out
    full = build_parser_help()
    for name in ("convert", "segment", "edit", "export", "inspect"):
        assert name in full


def build_parser_help() -> str:
    from leaffit_usd.cli import build_parser

    return build_parser([]).format_help()


def test_inspect_names_the_scene_cue_of_a_potted_capture(capsys, tmp_path):
    """A plant in a pot with soil and no table: inspect's up comes from the soil, as convert's
    does, and names that cue; its root is the stem base at the soil, not the pot's bottom."""
    from tests.isolate.test_soil import potted_capture

    cloud, truth, up, _ = potted_capture()
    write_ply(cloud, tmp_path / "potted.ply")
    code, out, err = run_cli(capsys, "inspect", tmp_path / "potted.ply", "--json")
    assert code == 0, err
    s = json.loads(out)
    assert "soil" in s["up"]["source"]
    assert np.degrees(np.arccos(np.clip(np.asarray(s["up"]["vector"]) @ up, -1, 1))) < 3
    soil_h = float(np.median(cloud.means[truth == 3] @ up))
    assert abs(np.asarray(s["root"]["position"]) @ up - soil_h) < 0.05 * s["height"]
