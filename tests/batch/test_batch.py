"""``leaffit-usd batch``: naming, manifests, failures recorded, resume, SIGTERM, Dask == local.

The conversions are real (every stage, each in its own worker process) on small generated plants
(3 leaves, 3,000 Gaussians) with reduced iteration counts, so the module stays fast.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from leaffit_usd.batch.captures import capture_name, collect_captures, read_manifest
from leaffit_usd.batch.runner import plan_parallelism
from leaffit_usd.cli import main

FAST = ["-K", "8", "--steps", "3", "--refine", "1", "--n-samples", "768", "--n-neighbors", "96",
        "--vertex-budget", "160", "--bake-size", "64", "--texture-size", "64"]


def _plant(d: Path, name: str, seed: int) -> Path:
    from samples.generate import PlantSpec, make_plant, save_plant

    cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=3, gaussians=3000, holes=0.0,
                                     floaters=0.0, height=0.5), seed=seed)
    ply, _ = save_plant(cloud, gt, d, name)
    return Path(ply)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """A folder with 2 small plants, an empty capture and a truncated one."""
    d = tmp_path_factory.mktemp("captures")
    a = _plant(d, "plant_a", 3)
    b = _plant(d, "plant_b", 5)
    (d / "empty.ply").write_bytes(b"")
    data = a.read_bytes()
    (d / "truncated.ply").write_bytes(data[: len(data) // 2])
    for gt in d.glob("*.gt.npz"):
        gt.rename(d.parent / gt.name)          # keep only captures in the folder
    return d


def _stage_bytes(capdir: Path) -> dict:
    """{relative path: bytes} of a capture's stage, payload and textures (not log / report)."""
    return {p.relative_to(capdir).as_posix(): p.read_bytes() for p in sorted(capdir.rglob("*"))
            if p.is_file() and p.name not in ("convert.log", "report.json")}


@pytest.fixture(scope="module")
def local_run(captures, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "assets"
    t0 = time.perf_counter()
    code = main(["batch", str(captures), "-o", str(out), "-q", "--jobs", "2", *FAST])
    return out, code, time.perf_counter() - t0


# ------------------------------------------------------------------------------------------
# names, manifests, parallelism (no conversion)
# ------------------------------------------------------------------------------------------

def test_capture_names(tmp_path):
    assert capture_name(Path("/x/plant.ply")) == "plant"
    assert capture_name(Path("/x/plant.compressed.ply")) == "plant"
    assert capture_name(Path("/data/ficus/point_cloud/iteration_30000/point_cloud.ply")) == "ficus"
    assert capture_name(Path("/data/monstera/point_cloud.ply")) == "monstera"
    assert capture_name(Path("/x/my plant (2).ply")) == "my_plant__2_"
    # a folder: INRIA layout (latest iteration only), clashes renamed in sorted path order
    for it in (7000, 30000):
        p = tmp_path / "in" / "ficus" / "point_cloud" / f"iteration_{it}" / "point_cloud.ply"
        p.parent.mkdir(parents=True)
        p.write_bytes(b"x")
    (tmp_path / "in" / "a").mkdir()
    (tmp_path / "in" / "a" / "ficus.ply").write_bytes(b"x")
    (tmp_path / "in" / "b.spz").write_bytes(b"x")
    (tmp_path / "in" / "notes.txt").write_bytes(b"x")
    (tmp_path / "in" / "scan.xyz").write_bytes(b"x")       # a point-cloud scan: a capture
    (tmp_path / "in" / "b.glb").write_bytes(b"x")          # a converted asset beside them: not one
    (tmp_path / "in" / "out").mkdir()
    (tmp_path / "in" / "out" / "old.ply").write_bytes(b"x")     # the output folder: not searched
    caps = collect_captures([tmp_path / "in"], exclude=tmp_path / "in" / "out")
    got = {c.name: c.path.relative_to(tmp_path / "in").as_posix() for c in caps}
    assert got == {"ficus": "a/ficus.ply", "ficus-2": "ficus/point_cloud/iteration_30000/point_cloud.ply",
                   "b": "b.spz", "scan": "scan.xyz"}
    assert [c.renamed_from for c in caps if c.name == "ficus-2"] == ["ficus"]


def test_manifest_csv_and_json(tmp_path, captures):
    (tmp_path / "m.csv").write_text(
        f"input,name,root,up,height\n{captures / 'plant_a.ply'},alpha,\"-1.5,0.2,3\",+y,0.45\n"
        f"{captures / 'plant_b.ply'},,,,\n")
    caps = read_manifest(tmp_path / "m.csv")
    assert [c.name for c in caps] == ["alpha", "plant_b"]
    assert caps[0].overrides == {"root": "-1.5,0.2,3", "up": "+y", "height_m": 0.45}
    assert caps[1].overrides == {}
    sub = tmp_path / "sub"
    sub.mkdir()
    os.symlink(captures / "plant_a.ply", sub / "a.ply")
    (sub / "m.json").write_text(json.dumps({"captures": [{"input": "a.ply", "root": [0, -1, 2.5],
                                                          "up_axis": "z"}]}))
    caps = read_manifest(sub / "m.json")
    assert caps[0].name == "a" and caps[0].overrides == {"root": "0.0,-1.0,2.5", "up_axis": "Z"}


@pytest.mark.parametrize("body, needle", [
    ("input,colour\nx.ply,red\n", "unknown column"),
    ("name\nfoo\n", "no 'input'"),
    ("input\nmissing.ply\n", "is not a file"),
    ("input,height\n{a},-2\n", "bad height"),
])
def test_manifest_errors_exit_2(tmp_path, captures, capsys, body, needle):
    m = tmp_path / "m.csv"
    m.write_text(body.format(a=captures / "plant_a.ply"))
    assert main(["batch", str(m), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "o").exists()


def test_usage_errors_exit_2(tmp_path, captures, capsys):
    for argv in (["batch", str(tmp_path / "nothing"), "-o", str(tmp_path / "o")],
                 ["batch", str(captures), "-o", str(tmp_path / "o"), "--labels", "x.npz"],
                 ["batch", str(captures), "-o", str(tmp_path / "o"), "--scheduler", "tcp://x:1"],
                 ["batch", str(tmp_path), "-o", str(tmp_path / "o")]):
        (tmp_path / "empty_dir").mkdir(exist_ok=True)
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


def test_plan_parallelism():
    assert plan_parallelism(8, None, None, cores=2) == (2, 1)       # one job per core
    assert plan_parallelism(1, None, None, cores=8) == (1, 8)       # spare cores -> threads
    assert plan_parallelism(8, 2, None, cores=8) == (2, 4)
    assert plan_parallelism(8, None, 2, cores=8) == (4, 2)
    assert plan_parallelism(8, 3, 3, cores=2) == (3, 3)             # both given: the user's call
    j, t = plan_parallelism(100, None, None, cores=6)
    assert j * t <= 6


# ------------------------------------------------------------------------------------------
# real conversions
# ------------------------------------------------------------------------------------------

def test_failures_recorded_and_stages_validate(local_run):
    from leaffit_usd.usd.validate import validate_file

    out, code, _ = local_run
    assert code == 1
    state = json.loads((out / "batch.json").read_text())
    recs = state["captures"]
    assert set(recs) == {"plant_a", "plant_b", "empty", "truncated"}
    for name in ("plant_a", "plant_b"):
        r = recs[name]
        assert r["status"] == "done" and r["error"] == "" and r["exit_code"] == 0
        assert r["counts"]["leaves"] >= 1 and r["counts"]["gaussians"] > 0
        assert set(r["timings"]) >= {"load", "segment", "fit", "write"}
        assert r["stage"] == f"{name}/{name}.usda"
        assert f"{name}.usda" in r["outputs"] and any(k.startswith("textures/") for k in r["outputs"])
        v = validate_file(out / r["stage"])
        assert v.count("error") == 0, [str(f) for f in v.findings]
        assert (out / name / "convert.log").stat().st_size > 0
    for name in ("empty", "truncated"):
        r = recs[name]
        assert r["status"] == "failed" and r["exit_code"] == 2
        assert r["error"] and "\n" not in r["error"] and f"{name}.ply" in r["error"]
        # only the log is left of a failed capture
        assert [p.name for p in (out / name).iterdir()] == ["convert.log"]
        assert r["error"] in (out / name / "convert.log").read_text()
    run = state["runs"][-1]
    assert (run["converted"], run["failed"], run["exit_code"]) == (2, 2, 1)
    # no work folder or temporary file anywhere
    assert not [p for p in out.rglob("*") if p.name.startswith((".work-", ".batch."))
                or p.suffix == ".tmp"]


def test_rerun_skips_and_force_redoes(local_run, captures, capsys):
    out, _, first = local_run
    before = {n: _stage_bytes(out / n) for n in ("plant_a", "plant_b")}
    t0 = time.perf_counter()
    assert main(["batch", str(captures), "-o", str(out), "--jobs", "2", *FAST]) == 1
    took = time.perf_counter() - t0
    table = capsys.readouterr().out
    assert "2 skipped" in table and "0 converted" in table and "2 failed (2 not retried" in table
    assert took < 0.5 * first, (took, first)
    state = json.loads((out / "batch.json").read_text())
    assert state["runs"][-1]["skipped"] == 2 and state["runs"][-1]["converted"] == 0
    assert state["runs"][-1]["not_retried"] == 2
    # another option -> converted again; --force too; the same bytes when the options are the same
    assert main(["batch", str(captures / "plant_a.ply"), "-o", str(out), "-q", "--force", *FAST]) == 0
    assert _stage_bytes(out / "plant_a") == before["plant_a"]
    assert json.loads((out / "batch.json").read_text())["runs"][-1]["converted"] == 1
    # a removed output file makes the capture incomplete: converted again
    (out / "plant_b" / "plant_b.usda").unlink()
    assert main(["batch", str(captures / "plant_b.ply"), "-o", str(out), "-q", *FAST]) == 0
    assert _stage_bytes(out / "plant_b") == before["plant_b"]


def test_timeout_recorded(captures, tmp_path):
    out = tmp_path / "t"
    assert main(["batch", str(captures / "plant_a.ply"), "-o", str(out), "-q", "--timeout", "0.3",
                 *FAST]) == 1
    r = json.loads((out / "batch.json").read_text())["captures"]["plant_a"]
    assert r["status"] == "failed" and "timed out after 0.3 s" in r["error"]
    assert [p.name for p in (out / "plant_a").iterdir()] == ["convert.log"]


def test_sigterm_then_rerun_completes(captures, tmp_path):
    out = tmp_path / "k"
    inputs = [str(captures / "plant_a.ply"), str(captures / "plant_b.ply")]
    cmd = [sys.executable, "-m", "leaffit_usd", "batch", *inputs, "-o", str(out), "-q", "--jobs", "1",
           *FAST]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    state_path = out / "batch.json"
    deadline = time.monotonic() + 300
    # wait until the first capture is done and the second one's worker is running
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            recs = json.loads(state_path.read_text())["captures"]
        except (OSError, ValueError, KeyError):
            recs = {}
        if sum(r.get("status") == "done" for r in recs.values()) == 1 and list(out.glob("*/.work-*")):
            break
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert b"interrupted" in err
    recs = json.loads(state_path.read_text())["captures"]
    statuses = sorted(r["status"] for r in recs.values())
    assert statuses == ["cancelled", "done"]
    cancelled = next(n for n, r in recs.items() if r["status"] == "cancelled")
    # no partial output: the cancelled capture has only its log, no work folder anywhere
    assert [p.name for p in (out / cancelled).iterdir()] == ["convert.log"]
    assert not list(out.glob("*/.work-*"))
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]
    # rerun: the done one is skipped, the cancelled one converted
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    state = json.loads(state_path.read_text())
    assert (state["runs"][-1]["converted"], state["runs"][-1]["skipped"]) == (1, 1)
    assert state["runs"][-2]["interrupted"] == "SIGTERM"
    assert all(x["status"] == "done" for x in state["captures"].values())
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]


def test_dask_local_cluster_byte_identical(local_run, captures, tmp_path):
    pytest.importorskip("distributed")
    out_local = local_run[0]
    out = tmp_path / "dask"
    code = main(["batch", str(captures / "plant_a.ply"), str(captures / "plant_b.ply"), "-o", str(out),
                 "-q", "--executor", "dask", "--jobs", "2", *FAST])
    assert code == 0
    state = json.loads((out / "batch.json").read_text())
    assert state["runs"][-1]["executor"] == "dask"
    for name in ("plant_a", "plant_b"):
        a, b = _stage_bytes(out_local / name), _stage_bytes(out / name)
        assert set(a) == set(b) and len(a) >= 4
        for k in a:
            assert a[k] == b[k], f"{name}/{k} differs between the local and the Dask run"
