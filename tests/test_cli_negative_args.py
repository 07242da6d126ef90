"""``--root`` and ``--up`` take negative values as separate arguments in every command.

argparse alone refuses ``--root -1.87,1.50,2.05`` ("expected one argument": it reads the value as
an unknown option); :func:`leaffit_usd.cli.join_dash_values` joins such values to
their option. Each command that takes ``--root``/``--up`` is run through ``cli.main``.
"""
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from leaffit_usd.cli import build_parser, join_dash_values, main
from leaffit_usd.splats import write_ply
from leaffit_usd.splats.cloud import GaussianCloud
from tests.segment.synth import make_plant
from tests.splats.plyfiles import small_cloud


def run(capsys, *argv):
    try:
        code = main(list(map(str, argv)))
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def cloud_file(tmp_path_factory):
    """A small random cloud whose coordinates are all negative (so is any root on it)."""
    c = small_cloud(300, seed=3)
    c.means = (c.means * 0.1 - 2.0).astype(np.float32)
    p = tmp_path_factory.mktemp("neg") / "c.ply"
    write_ply(c, p)
    return p, c


def test_parser_joins_negative_values_only_to_options_taking_one():
    subs = build_parser()._subparsers._group_actions[0].choices
    j = lambda *a: join_dash_values(subs["convert"], list(a))  # noqa: E731
    assert j("x.ply", "--root", "-1.87,1.50,2.05") == ["x.ply", "--root=-1.87,1.50,2.05"]
    assert j("--up", "-y", "--root", "-1e-3, 2,-3") == ["--up=-y", "--root=-1e-3, 2,-3"]
    assert join_dash_values(subs["inspect"], ["--u", "-x"]) == ["--u=-x"]  # unique abbreviation
    assert j("--ro", "-1,2,3") == ["--ro", "-1,2,3"]  # ambiguous (--root, --root-index): argparse says so
    assert j("--up", "-q") == ["--up", "-q"]                        # an option of the command stays one
    assert j("--paper-fit", "-1,2,3") == ["--paper-fit", "-1,2,3"]  # a flag takes no value
    assert j("--", "--root", "-1,2,3") == ["--", "--root", "-1,2,3"]
    assert j("--root=-1,2,3") == ["--root=-1,2,3"]


def test_inspect_up_negative_axis_and_vector(cloud_file, capsys):
    p, _ = cloud_file
    code, out, err = run(capsys, "inspect", p, "--json", "--up", "-y")
    assert code == 0, err
    assert json.loads(out)["up"]["vector"] == [0.0, -1.0, 0.0]
    code, out, err = run(capsys, "inspect", p, "--json", "--up", "-3,-4,0")
    assert code == 0, err
    assert np.allclose(json.loads(out)["up"]["vector"], [-0.6, -0.8, 0.0])


@pytest.mark.parametrize("command", ["convert", "edit", "segment"])
def test_far_negative_root_reaches_the_frame(command, cloud_file, tmp_path, capsys):
    """The negative point is parsed (not refused by argparse) and checked against the cloud: the
    one-line error quotes the distance from exactly that point, so its signs were kept."""
    p, c = cloud_file
    point = np.array([-40.0, -30.5, -20.25])
    out = {"convert": ["-o", tmp_path / "x.usda"], "segment": ["-o", tmp_path / "x.npz"],
           "edit": ["--no-browser"]}[command]
    code, _, err = run(capsys, command, p, *out, "--up", "-z", "--root", "-40,-30.5,-20.25", "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "expected one argument" not in err and "--root" in err
    d = cKDTree(c.means).query(point)[0]
    assert f"nearest Gaussian is {d:.4g} away" in err
    assert not list(tmp_path.glob("x.*"))


def test_segment_with_negative_up_and_root(tmp_path, capsys):
    """A plant growing along -y with all coordinates negative: '--up -y --root -a,-b,-c' picks the
    Gaussian nearest that point as the root and finds the leaves."""
    p = make_plant(n_leaves=3, n_points=6000, seed=2, leaf_length=0.3, leaf_width=0.2)
    rot = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # working +Z -> input -Y
    means = p.points @ rot.T - [3.0, 1.0, 2.0]
    cloud = GaussianCloud.from_activated(means, np.full((len(means), 3), 0.003),
                                         np.tile([1.0, 0, 0, 0], (len(means), 1)),
                                         np.full(len(means), 0.8), colors=np.full((len(means), 3), 0.4))
    ply, out = tmp_path / "down.ply", tmp_path / "l.npz"
    write_ply(cloud, ply)
    root = cloud.means[p.root_index].astype(np.float64)
    assert (root < 0).all()
    spec = ",".join(f"{v:.6f}" for v in root)
    code, _, err = run(capsys, "segment", ply, "-o", out, "--up", "-y", "--root", spec, "-q")
    assert code == 0, err
    z = np.load(out)
    assert int(z["root_index"]) == p.root_index
    assert z["labels"].max() == 3


def test_isolate_and_convert_parse_negative_up_and_root():
    """Every command with --up/--root, at the parser (isolate's run needs a real capture)."""
    p = build_parser()
    a = p.parse_args(["isolate", "a.ply", "-o", "b.ply", "--up", "-0.1,-1,0"])
    assert a.up == "-0.1,-1,0"
    a = p.parse_args(["convert", "a.ply", "-o", "b.usda", "--up", "-y", "--root", "-1.87,1.50,2.05"])
    assert (a.up, a.root) == ("-y", "-1.87,1.50,2.05")
