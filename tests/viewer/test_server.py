"""The local server's security and API (flask test client + one real socket + the CLI's Ctrl-C)."""
import base64
import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from leaffit_usd.splats import write_ply
from leaffit_usd.viewer.server import MAX_BODY, ViewerServer, build_session, create_app, is_loopback

TOKEN = "t0k3n-for-tests"


@pytest.fixture(scope="module")
def served(plant, heat, tmp_path_factory):
    d = tmp_path_factory.mktemp("server")
    cloud = plant[0]
    write_ply(cloud, d / "plant.ply")
    s = build_session(cloud, np.zeros(len(cloud), np.int32), d / "plant.ply", d / "out.edits.json",
                      d / "out.labels.npz", n_samples=1500, solver_factory=heat)
    return s, d


@pytest.fixture()
def client(served):
    app = create_app(served[0], TOKEN)
    app.testing = True
    return app.test_client()


def test_token_required_on_every_route(client):
    for path in ["/", "/api/meta", "/static/app.js", f"/{TOKEN}x/api/meta", "/x/api/state", "/favicon.ico"]:
        assert client.get(path).status_code == 403, path
    assert client.post("/api/op", json={"op": {"op": "clear"}}).status_code == 403
    assert client.get(f"/{TOKEN}/").status_code == 200
    assert client.get(f"/{TOKEN}/api/meta").status_code == 200
    r = client.get(f"/{TOKEN}/static/app.js")
    assert r.status_code == 200 and "text/javascript" in r.content_type
    assert client.get(f"/{TOKEN}/static/three.bundle.min.js").status_code == 200
    assert client.get(f"/{TOKEN}/static/../server.py").status_code in (403, 404)
    assert client.get(f"/{TOKEN}/static/BUILD.md").status_code == 404  # only the page's files


def test_non_loopback_clients_and_hosts_are_refused(client):
    for addr in ["10.0.0.5", "192.168.1.20", "8.8.8.8", "::ffff:10.0.0.1"]:
        r = client.get(f"/{TOKEN}/api/meta", environ_base={"REMOTE_ADDR": addr})
        assert r.status_code == 403, addr
    assert client.get(f"/{TOKEN}/api/meta", environ_base={"REMOTE_ADDR": "127.0.0.2"}).status_code == 200
    assert client.get(f"/{TOKEN}/api/meta", environ_base={"REMOTE_ADDR": "::1"}).status_code == 200
    # DNS rebinding: a foreign Host name pointing at 127.0.0.1
    assert client.get(f"/{TOKEN}/api/meta", headers={"Host": "evil.example:8000"}).status_code == 403
    assert not is_loopback("") and not is_loopback("garbage") and is_loopback("127.0.0.1")


def test_oversized_bodies_are_refused(client):
    big = json.dumps({"op": {"op": "brush", "centers": [1] * (MAX_BODY // 2), "radius": 0.1}})
    assert len(big) > MAX_BODY
    r = client.post(f"/{TOKEN}/api/op", data=big, content_type="application/json")
    assert r.status_code == 413
    r = client.post(f"/{TOKEN}/api/pick", data=b"x" * (MAX_BODY + 1), content_type="application/json")
    assert r.status_code == 413


def test_api_pick_preview_op_undo_save(client, served, plant):
    s, d = served
    cloud, truth, tips, _ = plant
    meta = client.get(f"/{TOKEN}/api/meta").get_json()
    assert meta["n"] == len(cloud) and meta["edits_out"] == "out.edits.json"
    pts = client.get(f"/{TOKEN}/api/points").data
    assert len(pts) == 15 * len(cloud)
    pos = np.frombuffer(pts[: 12 * len(cloud)], "<f4").reshape(-1, 3)
    assert np.allclose(pos * s.height + s.centre, cloud.means, atol=1e-5)
    # a ray straight down onto the tip of leaf 2, in the display frame
    o = pos[tips[1]] + np.array([0, 0, 2.0])
    r = client.post(f"/{TOKEN}/api/pick", json={"origin": o.tolist(), "direction": [0, 0, -1]}).get_json()
    assert r["index"] >= 0 and truth[r["index"]] == 2
    assert client.post(f"/{TOKEN}/api/pick", json={"origin": "x"}).status_code == 400
    op = {"op": "brush", "centers": [r["index"]], "radius": 0.1, "mode": "add"}
    prev = client.post(f"/{TOKEN}/api/preview", json={"op": op}).get_json()
    sel = np.unpackbits(np.frombuffer(base64.b64decode(prev["selection"]), np.uint8))[: len(cloud)].astype(bool)
    assert sel.sum() == prev["selected"] > 0 and (truth[sel] == 2).all()
    st = client.get(f"/{TOKEN}/api/state").get_json()
    assert st["n_ops"] == 0 and st["selected"] == 0  # preview records nothing
    st = client.post(f"/{TOKEN}/api/op", json={"op": op}).get_json()
    assert st["selected"] == sel.sum() and st["can_undo"] and st["dirty"]
    # a client cannot choose where files go: extra fields are ignored, paths never read
    st = client.post(f"/{TOKEN}/api/op", json={"op": {"op": "assign", "label": "new", "path": "/tmp/evil"},
                                                "path": "/tmp/evil"}).get_json()
    labels = np.frombuffer(base64.b64decode(st["labels"]), "<i4")
    assert np.array_equal(labels == 1, sel) and st["leaves"] == [
        {"label": 1, "count": int(sel.sum()), "confidence": None, "doubtful": False}]
    bad = client.post(f"/{TOKEN}/api/op", json={"op": {"op": "assign", "label": -3}})
    assert bad.status_code == 400 and "label" in bad.get_json()["error"]
    assert client.post(f"/{TOKEN}/api/op", json=[1, 2]).status_code == 400
    assert client.post(f"/{TOKEN}/api/undo", json={}).get_json()["n_ops"] == 1
    assert client.post(f"/{TOKEN}/api/redo", json={}).get_json()["n_ops"] == 2
    out = client.post(f"/{TOKEN}/api/save", json={"edits": "/tmp/evil.json"}).get_json()
    assert out["edits"] == "out.edits.json" and not os.path.exists("/tmp/evil.json")
    saved = np.load(d / "out.labels.npz")["labels"]
    assert np.array_equal(saved == 1, sel)
    assert json.loads((d / "out.edits.json").read_text())["operations"][1] == {"op": "assign", "label": "new"}
    assert out["state"]["dirty"] is False
    r = client.get(f"/{TOKEN}/")
    assert "script-src 'self'" in r.headers["Content-Security-Policy"] and r.headers["Cache-Control"] == "no-store"


def test_real_socket_is_loopback_only(served):
    import http.client

    server = ViewerServer(served[0], port=0).start_background()
    try:
        # an oversized chunked body (no Content-Length) is refused as well
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
        chunks = [b'{"op": {"op": "brush", "centers": ['] + [b"1," * 1000] * (MAX_BODY // 2000 + 4) + [b"1]}}"]
        conn.request("POST", f"/{server.token}/api/preview", body=iter(chunks), encode_chunked=True,
                     headers={"Content-Type": "application/json", "Transfer-Encoding": "chunked"})
        assert conn.getresponse().status == 413
        conn.close()
        host, port = server._server.server_address[:2]
        assert host == "127.0.0.1" and port > 0 and server.url.startswith(f"http://127.0.0.1:{port}/")
        assert len(server.token) >= 32
        with urllib.request.urlopen(server.url + "api/meta", timeout=10) as r:
            assert r.status == 200
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/meta", timeout=10)
        assert e.value.code == 403
        # the page's Quit button stops the server
        req = urllib.request.Request(server.url + "api/stop", data=b"{}", method="POST",
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=10) as r:
            assert json.loads(r.read())["stopping"]
        server._thread.join(timeout=10)
        assert not server._thread.is_alive()
    finally:
        server.stop()
    with pytest.raises(OSError):
        urllib.request.urlopen(server.url + "api/meta", timeout=2)


def test_cli_continues_a_session_prints_url_and_stops_cleanly_on_ctrl_c(served, tmp_path):
    from leaffit_usd.io_util import file_sha256
    from leaffit_usd.segment.edits import Edits, save_edits

    d = served[1]
    n = len(served[0].cloud)
    save_edits(Edits(input_sha256=file_sha256(d / "plant.ply"), n_gaussians=n, height=1.0, n_samples=1000,
                     operations=[{"op": "brush", "centers": [n - 5], "radius": 0.05, "mode": "add"},
                                 {"op": "assign", "label": "new"}]), tmp_path / "prev.json")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "leaffit_usd", "edit", str(d / "plant.ply"), "--no-browser",
                          "--empty", "--edits", str(tmp_path / "prev.json"), "--labels-out", str(tmp_path / "l.npz")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = ""
        deadline = time.time() + 60
        while "http://" not in line and time.time() < deadline:
            line = p.stdout.readline()
            if not line and p.poll() is not None:
                break
        assert "http://127.0.0.1:" in line, p.stderr.read()
        url = line.split("open ", 1)[1].strip()
        st = {"ready": False}
        while not st["ready"] and time.time() < deadline:  # the page is served while it starts
            with urllib.request.urlopen(url + "api/state", timeout=10) as r:
                st = json.loads(r.read())
            assert st["ready"] or st["phase"] in ("segmenting", "geodesics", "replaying edits"), st
            time.sleep(0.05)
        assert st["n_ops"] == 2 and len(st["leaves"]) == 1 and st["can_undo"] and not st["dirty"]
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=20)
        assert p.returncode == 0, err
        assert "stopped" in out and "Traceback" not in err
    finally:
        if p.poll() is None:
            p.kill()


def test_cli_refuses_bad_labels_file(served, tmp_path):
    d = served[1]
    np.savez(tmp_path / "short.npz", labels=np.zeros(5, np.int32))
    r = subprocess.run([sys.executable, "-m", "leaffit_usd", "edit", str(d / "plant.ply"), "--no-browser",
                        "--labels", str(tmp_path / "short.npz")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "labels" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("extra, words", [
    (["--port", "70000"], "--port"),
    (["--samples", "3"], "--samples"),
    (["--labels", "x.npz", "--empty"], "--empty"),
])
def test_cli_bad_options(served, capsys, extra, words):
    from leaffit_usd.cli import main

    assert main(["edit", str(served[1] / "plant.ply"), "--no-browser", *extra]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


def test_cli_missing_input(capsys, tmp_path):
    from leaffit_usd.cli import main

    assert main(["edit", str(tmp_path / "nope.ply"), "--no-browser"]) == 2
    assert "nope.ply" in capsys.readouterr().err


def test_automatic_start_and_its_fallback(plant, monkeypatch, caplog, tmp_path):
    """edit starts from convert's automatic segmentation; if that fails, from an empty one."""
    import logging

    from leaffit_usd.commands.edit import automatic_labels, prepare_capture
    from leaffit_usd.errors import UserError
    from leaffit_usd.prepare import FrameOptions, PreparedPlant

    cloud = plant[0]
    prep = PreparedPlant.from_cloud(cloud, FrameOptions(up=np.array([0.0, 0.0, 1.0])))
    labels, root, frame, conf = automatic_labels(prep)
    assert labels.shape == (len(prep.plant),) and labels.dtype == np.int32 and 0 <= root < len(prep.plant)
    assert frame.height > 0
    # the segmentation's confidence comes out with the labels: one value in [0, 1] per leaf
    assert labels.max() >= 1 and conf.shape == (labels.max(),) and ((conf >= 0) & (conf <= 1)).all()

    def fail(*a, **k):
        raise UserError("no apex found")

    monkeypatch.setattr(PreparedPlant, "segment", fail)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        labels, _, _, conf = automatic_labels(prep)
    assert not labels.any() and conf is None and "automatic segmentation failed" in caplog.text
    from leaffit_usd.errors import ParameterError

    write_ply(cloud, tmp_path / "p.ply")
    with pytest.raises(ParameterError):  # a bad --up is an error, not a fallback
        prepare_capture(tmp_path / "p.ply", up="sideways")


# ---- per-leaf confidence ------------------------------------------------------------------

def test_carried_confidence_follows_leaves_not_numbers():
    from leaffit_usd.viewer.server import carried_confidence, least_confident

    start = np.array([0, 1, 1, 1, 1, 1, 2, 2, 2, 3, 3], np.int32)
    conf = np.array([0.9, 0.2, 0.7])
    assert carried_confidence(start, start, conf) == {1: 0.9, 2: 0.2, 3: 0.7}
    assert carried_confidence(start, start, None) == {}
    now = start.copy()
    now[6] = 1               # leaf 1 grows by one Gaussian of leaf 2: both keep theirs
    now[[9, 10]] = 0         # leaf 3 deleted ...
    now[[4, 5]] = 3          # ... and its number reused for a new leaf cut from leaf 1: unknown
    assert carried_confidence(start, now, conf) == {1: 0.9, 2: 0.2}
    now2 = start.copy()
    now2[now2 == 1] = 2      # leaf 1 merged into leaf 2 (3 of its 8 Gaussians are its own): unknown
    assert carried_confidence(start, now2, conf) == {3: 0.7}
    rows = [{"label": 1, "confidence": 0.9}, {"label": 2, "confidence": None}, {"label": 3, "confidence": 0.4}]
    assert least_confident(rows) == 3
    assert least_confident([{"label": 1, "confidence": 1.0}, {"label": 2, "confidence": None}]) is None
    assert least_confident([{"label": 4, "confidence": 0.3}, {"label": 2, "confidence": 0.3}]) == 2


@pytest.fixture(scope="module")
def confident(plant, served):
    """A session on the two-leaf plant starting from the truth, with leaf 2 doubtful (it shares
    the served session's geodesics and BVH: building them again would only cost time)."""
    import dataclasses
    import threading

    from leaffit_usd.segment.manual import ManualSegmenter

    s = served[0]
    seg = ManualSegmenter(plant[0].means, plant[1], s.height, geodesics=s.segmenter.geodesics)
    return dataclasses.replace(s, segmenter=seg, confidence=np.array([0.93, 0.31]), saved_ops=[],
                               lock=threading.Lock())


def test_state_gives_each_leaf_its_confidence_and_the_least_confident(confident, plant):
    from leaffit_usd.segment.result import DOUBTFUL_CONFIDENCE

    truth = plant[1]
    app = create_app(confident, TOKEN)
    client = app.test_client()
    assert client.get(f"/{TOKEN}/api/meta").get_json()["doubtful_below"] == DOUBTFUL_CONFIDENCE == 0.5
    st = client.get(f"/{TOKEN}/api/state").get_json()
    assert st["leaves"] == [
        {"label": 1, "count": int((truth == 1).sum()), "confidence": 0.93, "doubtful": False},
        {"label": 2, "count": int((truth == 2).sum()), "confidence": 0.31, "doubtful": True}]
    assert st["least_confident"] == 2
    from leaffit_usd.commands.edit import doubtful_lines

    assert doubtful_lines(confident) == [
        "leaffit-usd edit: leaves to check (confidence < 0.5): 2 (0.31); the page opens on leaf 2"]
    try:
        # trim leaf 2 (a brush at its tip, to the stem): still leaf 2, still doubtful
        tip2 = int(plant[2][1])
        client.post(f"/{TOKEN}/api/op", json={"op": {"op": "brush", "centers": [tip2], "radius": 0.08}})
        st = client.post(f"/{TOKEN}/api/op", json={"op": {"op": "assign", "label": 0}}).get_json()
        two = [r for r in st["leaves"] if r["label"] == 2][0]
        assert 0 < two["count"] < (truth == 2).sum() and two["confidence"] == 0.31 and two["doubtful"]
        # delete leaf 2; a new leaf cut from leaf 1 takes the number 2 but not its confidence
        client.post(f"/{TOKEN}/api/op", json={"op": {"op": "delete", "label": 2}})
        tip1 = int(plant[2][0])
        client.post(f"/{TOKEN}/api/op", json={"op": {"op": "brush", "centers": [tip1], "radius": 0.08,
                                                         "mode": "replace"}})
        st = client.post(f"/{TOKEN}/api/op", json={"op": {"op": "split", "label": 1}}).get_json()
        rows = {r["label"]: r for r in st["leaves"]}
        assert set(rows) == {1, 2} and rows[2]["confidence"] is None and not rows[2]["doubtful"]
        assert rows[1]["confidence"] == 0.93 and st["least_confident"] == 1
        # undo brings the doubtful leaf back
        for _ in range(3):
            st = client.post(f"/{TOKEN}/api/undo", json={}).get_json()
        assert st["least_confident"] == 2
    finally:
        while confident.segmenter.undo():
            pass


def test_no_confidence_means_no_least_confident(client, served, confident):
    from leaffit_usd.commands.edit import doubtful_lines

    st = client.get(f"/{TOKEN}/api/state").get_json()
    assert st["least_confident"] is None
    assert all(r["confidence"] is None and r["doubtful"] is False for r in st["leaves"])
    assert doubtful_lines(served[0]) == []
    confident.confidence = np.array([1.0, 0.8])
    try:
        assert doubtful_lines(confident) == [
            "leaffit-usd edit: no doubtful leaf (all 2 with confidence >= 0.5; lowest: leaf 2, 0.80)"]
        assert confident.state()["least_confident"] == 2
        confident.confidence = np.ones(2)  # a method that gives none: nothing to point at
        assert confident.state()["least_confident"] is None
    finally:
        confident.confidence = np.array([0.93, 0.31])


def test_build_session_refuses_a_confidence_that_does_not_fit(plant, heat, served):
    from leaffit_usd.errors import ParameterError

    d = served[1]
    for bad in (np.array([0.5]), np.array([0.5, 1.5]), np.array([0.5, np.nan])):
        with pytest.raises(ParameterError, match="confidence"):
            build_session(plant[0], plant[1], d / "plant.ply", d / "x.json", d / "x.npz", n_samples=64,
                          solver_factory=heat, confidence=bad)


def test_labels_file_confidence_is_read_and_mapped(plant, tmp_path, caplog):
    """A labels file's confidence follows its leaves through load_labels' renumbering."""
    import logging

    from leaffit_usd.commands.edit import read_labels_file

    cloud, truth = plant[0], plant[1]
    gappy = np.where(truth == 2, 5, truth).astype(np.int32)  # leaves 1 and 5 -> renumbered 1, 2
    np.savez(tmp_path / "a.npz", labels=gappy, confidence=np.array([0.8, 0.1, 0.1, 0.1, 0.25]))
    labels, _, conf = read_labels_file(tmp_path / "a.npz", cloud)
    assert np.array_equal(labels, truth[cloud.file_index]) and conf.tolist() == [0.8, 0.25]
    np.savez(tmp_path / "b.npz", labels=truth, root_index=np.int64(3))
    assert read_labels_file(tmp_path / "b.npz", cloud)[1:] == (int(np.flatnonzero(cloud.file_index == 3)[0]), None)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        np.savez(tmp_path / "c.npz", labels=truth, confidence=np.array([0.5, 0.5, 0.5]))
        assert read_labels_file(tmp_path / "c.npz", cloud)[2] is None
        np.savez(tmp_path / "d.npz", labels=truth, confidence=np.array([0.5, 7.0]))
        assert read_labels_file(tmp_path / "d.npz", cloud)[2] is None
    assert caplog.text.count("ignoring its 'confidence'") == 2


def test_cli_prints_doubtful_leaves_and_serves_them(served, plant, tmp_path):
    d = served[1]
    np.savez(tmp_path / "seg.npz", labels=plant[1], confidence=np.array([0.45, 0.2]))
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "leaffit_usd", "edit", str(d / "plant.ply"), "--no-browser",
                          "--labels", str(tmp_path / "seg.npz"), "--samples", "500",
                          "--labels-out", str(tmp_path / "l.npz")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        lines = []
        deadline = time.time() + 60
        while not any("leaves to check" in x for x in lines) and time.time() < deadline:
            line = p.stdout.readline()
            if not line and p.poll() is not None:
                break
            lines.append(line)
        url = [x for x in lines if "http://" in x][0].split("open ", 1)[1].strip()
        check = [x for x in lines if "leaves to check" in x]
        assert check and "2 (0.20), 1 (0.45)" in check[0] and "opens on leaf 2" in check[0], lines
        with urllib.request.urlopen(url + "api/state", timeout=10) as r:
            st = json.loads(r.read())
        assert st["least_confident"] == 2 and [r["doubtful"] for r in st["leaves"]] == [True, True]
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=20)
        assert p.returncode == 0 and "Traceback" not in err, err
    finally:
        if p.poll() is None:
            p.kill()


def test_starting_session_serves_the_capture_and_refuses_edits(served):
    """While a session starts, the page gets the capture (meta, splats) and the phase; editing
    routes answer 503; once the built session is attached, they work."""
    from leaffit_usd.viewer.server import ViewerSession

    built = served[0]
    s = ViewerSession.starting(built.cloud, built.height, built.edits_out, built.labels_out,
                               up=built.up, input_name="plant.ply", phase="geodesics")
    app = create_app(s, TOKEN)
    app.testing = True
    c = app.test_client()
    meta = c.get(f"/{TOKEN}/api/meta").get_json()
    assert meta["ready"] is False and meta["phase"] == "geodesics" and meta["samples"] is None
    assert len(c.get(f"/{TOKEN}/api/splats").data) == 30 * len(built.cloud)
    assert c.get(f"/{TOKEN}/api/state").get_json() == {"ready": False, "phase": "geodesics", "failed": None}
    for route in ("op", "pick", "preview", "undo", "save", "leaf"):
        r = c.post(f"/{TOKEN}/api/{route}", json={"op": {"op": "clear"}})
        assert r.status_code == 503 and "still starting: geodesics" in r.get_json()["error"], route
    with pytest.raises(ValueError):
        s.attach(ViewerSession.starting(built.cloud, built.height + 1, "a", "b"))
    s.attach(built)
    assert c.get(f"/{TOKEN}/api/state").get_json()["ready"] is True
    assert c.post(f"/{TOKEN}/api/op", json={"op": {"op": "clear"}}).status_code == 200
    built.segmenter.undo()


def test_cli_edits_that_fail_to_replay_exit_2(served, tmp_path):
    """An --edits file whose operations cannot be replayed (a split across two leaves) is found
    while starting, behind the served page: the server stops and edit exits 2 with one line."""
    from leaffit_usd.io_util import file_sha256
    from leaffit_usd.segment.edits import Edits, save_edits

    d = served[1]
    n = len(served[0].cloud)
    save_edits(Edits(input_sha256=file_sha256(d / "plant.ply"), n_gaussians=n, height=1.0, n_samples=500,
                     operations=[{"op": "split_at", "seeds": [0, n - 1]}]), tmp_path / "bad.json")
    r = subprocess.run([sys.executable, "-m", "leaffit_usd", "edit", str(d / "plant.ply"), "--no-browser",
                        "--empty", "--edits", str(tmp_path / "bad.json")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2, r.stderr
    assert "split_at" in r.stderr and "Traceback" not in r.stderr
