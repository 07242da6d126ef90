"""``leaffit-usd segment``: output format (file order), preview, report, exit codes."""
import json

import numpy as np
import pytest

from leaffit_usd.cli import main
from leaffit_usd.metrics import segmentation_scores
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.ply import write_ply

from tests.segment.synth import make_plant


def _frame_from_normals(n):
    """(N, 3, 3) rotations whose third column is n (NaN rows -> identity)."""
    out = np.tile(np.eye(3), (len(n), 1, 1))
    ok = np.isfinite(n).all(1)
    z = n[ok]
    a = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    x = np.cross(a, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    out[ok] = np.stack([x, y, z], axis=2)
    return out


@pytest.fixture(scope="module")
def ply(tmp_path_factory):
    """A synthetic plant written as a 3DGS PLY in a scaled, rotated input frame (+Y up), with one
    invalid Gaussian (NaN position) at file position 5, which the reader drops."""
    p = make_plant(n_leaves=4, n_points=12000, seed=5, leaf_length=0.3, leaf_width=0.2)
    rot = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # working +Z -> input +Y
    means = 2.5 * p.points @ rot.T + [1.0, 2.0, 3.0]
    flat = np.isfinite(p.normals).all(1)
    scales = np.where(flat[:, None], [[0.004, 0.004, 0.0003]], [[0.002, 0.002, 0.002]]) * 2.5
    R = np.einsum("ij,njk->nik", rot, _frame_from_normals(np.where(flat[:, None], p.normals, np.nan)))
    q = matrix_to_quat(R)
    means = np.insert(means, 5, [np.nan, 0, 0], axis=0)
    scales, q = np.insert(scales, 5, scales[0], axis=0), np.insert(q, 5, q[0], axis=0)
    labels = np.insert(p.labels, 5, -1)
    cloud = GaussianCloud.from_activated(means, scales, q, np.full(len(means), 0.8),
                                         colors=np.full((len(means), 3), 0.4))
    path = tmp_path_factory.mktemp("seg") / "plant.ply"
    write_ply(cloud, path)
    root = int(np.flatnonzero(np.arange(len(labels)) != 5)[p.root_index])
    return path, labels, root


def test_segment_writes_file_order_labels_preview_and_report(ply, tmp_path):
    path, gt, root = ply
    out, png, rep = tmp_path / "labels.npz", tmp_path / "seg.png", tmp_path / "r.json"
    rc = main(["segment", str(path), "-o", str(out), "--up", "+y", "--root-index", str(root),
               "--preview", str(png), "--report", str(rep), "-q"])
    assert rc == 0
    z = np.load(out)
    for key in ("labels", "root_index", "apex_indices", "apex_labels", "leaf_tip", "leaf_base",
                "tree_nodes", "tree_parent", "tree_leaf", "dist_root", "input_to_working", "params"):
        assert key in z.files
    labels = z["labels"]
    assert labels.dtype == np.int32 and len(labels) == len(gt)   # file order, dropped one included
    assert labels[5] == 0 and np.isnan(z["dist_root"][5])
    assert int(z["root_index"]) == root
    assert np.array_equal(labels[z["leaf_tip"]], np.arange(1, labels.max() + 1))
    s = segmentation_scores(labels, gt)
    assert labels.max() == 4 and s.miou >= 95
    assert json.loads(str(z["params"]))["tau"] == 0.5
    import OpenImageIO as oiio

    img = oiio.ImageBuf(str(png))
    assert img.spec().width == 2 * img.spec().height and img.spec().nchannels == 3
    px = img.get_pixels(oiio.FLOAT)
    assert (np.abs(px - 1).sum(-1) > 0.1).mean() > 0.01          # something drawn
    assert (np.abs(px - [0.9, 0.05, 0.05]).sum(-1) < 0.05).any()  # apex marks
    r = json.loads(rep.read_text())
    assert r["leaves"] == 4 and r["gaussians"] == len(gt) - 1 and "total" in r["timings"]


def test_root_by_point_and_params(ply, tmp_path):
    path, gt, root = ply
    out = tmp_path / "l.npz"
    rc = main(["segment", str(path), "-o", str(out), "--up", "+y", "--root", "1,2,3", "--tau", "0.4",
               "--orientation", "--paper-rules", "-q"])
    assert rc == 0
    z = np.load(out)
    prm = json.loads(str(z["params"]))
    assert prm["tau"] == 0.4 and prm["orientation_aware"] and not prm["base_refine"]
    assert prm["tau_relative"] == 0 and prm["petiole_relative"] == 0  # the paper's rules exactly
    assert segmentation_scores(z["labels"], gt).tp >= 4  # the paper's rules: leaves found


@pytest.mark.parametrize("extra", [["-o", "{tmp}/x.txt"], ["-o", "{tmp}/x.npz", "--root", "100,100,100"],
                                   ["-o", "{tmp}/x.npz", "--tau", "-1"],
                                   ["-o", "{tmp}/x.npz", "--root-index", "999999"],
                                   ["-o", "{tmp}/x.npz", "--preview", "{tmp}/x.xyz"]])
def test_bad_usage_exits_2_and_writes_nothing(ply, tmp_path, extra, capsys):
    path, _, _ = ply
    args = ["segment", str(path), "--up", "+y"] + [e.format(tmp=tmp_path) for e in extra]
    with pytest.raises(SystemExit) if "-1" in extra else _nullctx():
        rc = main(args)
        assert rc == 2
    assert not list(tmp_path.glob("x.*"))
    assert "Traceback" not in capsys.readouterr().err


class _nullctx:
    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False


def test_output_does_not_depend_on_the_file_order(ply, tmp_path):
    """``segment`` visits the Gaussians in grid order for speed; that is exact only because the
    labels, apexes and distances do not depend on the order of the Gaussians in the file."""
    from leaffit_usd.splats import load_cloud

    path, _, root = ply
    cloud = load_cloud(path, drop_bad=False)
    perm = np.random.default_rng(11).permutation(cloud.file_count)
    shuffled = cloud.subset(perm)
    shuffled.file_index = np.arange(len(perm))  # a new file, in the shuffled order
    write_ply(shuffled, tmp_path / "shuffled.ply")
    inv = np.argsort(perm)
    outs = []
    for p, r in ((path, root), (tmp_path / "shuffled.ply", int(inv[root]))):
        assert main(["segment", str(p), "-o", str(tmp_path / "o.npz"), "--up", "+y",
                     "--root-index", str(r), "-q"]) == 0
        outs.append(dict(np.load(tmp_path / "o.npz")))
    a, b = outs
    assert np.array_equal(a["labels"], b["labels"][inv])
    assert np.array_equal(a["dist_root"], b["dist_root"][inv], equal_nan=True)
    for k in ("apex_indices", "leaf_tip", "leaf_base", "tree_nodes"):
        assert np.array_equal(a[k], perm[b[k]]), k
    assert int(a["root_index"]) == int(perm[int(b["root_index"])])
    assert np.array_equal(a["confidence"], b["confidence"])


def test_segment_runs_blas_on_one_thread_and_restores_it(monkeypatch):
    """The command's linear algebra runs on one BLAS thread (faster on 2 cores, same numbers:
    OpenBLAS splits a product over its outputs); the caller's setting is back afterwards."""
    from threadpoolctl import threadpool_info

    import leaffit_usd.commands.segment as cmd

    def blas_threads():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    class Seen(Exception):
        pass

    def spy(args):  # the command's first step: note the BLAS threads, then stop
        raise Seen(blas_threads())

    before = blas_threads()
    monkeypatch.setattr(cmd, "params_from_args", spy)
    with pytest.raises(Seen) as inside:
        cmd.run(type("Args", (), {"output": "x.npz"})())
    assert inside.value.args[0] and all(n == 1 for n in inside.value.args[0])
    assert blas_threads() == before
