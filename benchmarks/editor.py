"""The segmentation editor's two budgets (issue 37): a 1M-Gaussian capture opens in < 10 s, and
the fitted-leaf preview shows within 1 s of an edit.

* **open**: ``leaffit-usd edit CAPTURE --no-browser`` started as a process, the page loaded in
  headless Chromium (launched beforehand: a user's browser is already running); measured from
  the process start to the page's first frame of splats (``window.leaffit.drawn``), and to the
  editor being ready (segmentation, geodesics, BVH: ``window.leaffit.ready``).
* **edit -> preview**: on a 100k-Gaussian plant, through the server's HTTP API (flask test
  client: JSON in and out as the page sends them): one edit (``split_at`` with two seeds at the
  far ends of a leaf, or a brush + assign growing a leaf) then ``api/leaf`` for that leaf; the
  seconds from sending the edit to having the fitted leaf, per leaf of the plant.

    python -m benchmarks.editor [--open CAPTURE_1M.ply] [--preview CAPTURE_100k.ply]

(``python -m samples.generate --preset green_pepper --gaussians 1000000 --out /tmp/x`` makes a
capture.) Writes benchmarks/results/editor.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "editor.json"


def time_open(capture: Path) -> dict:
    """Seconds from starting ``edit`` to the first frame and to ready, in headless Chromium."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium",
                                    args=["--no-sandbox", "--headless=new"])
        page = browser.new_page(viewport={"width": 1100, "height": 750})
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "leaffit_usd", "edit", str(capture), "--no-browser",
                                 "--edits-out", os.devnull, "--labels-out", os.devnull],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
        try:
            line = ""
            while "http://" not in line:
                line = proc.stdout.readline()
                if not line and proc.poll() is not None:
                    raise RuntimeError("edit exited before serving")
            t_url = time.perf_counter() - t0
            page.goto(line.split("open ", 1)[1].strip())
            page.wait_for_function("() => window.leaffit && window.leaffit.drawn", timeout=120000, polling=20)
            t_frame = time.perf_counter() - t0
            page.wait_for_function("() => window.leaffit.ready", timeout=300000, polling=50)
            t_ready = time.perf_counter() - t0
            n = page.evaluate("window.leaffit.state().leaves.length")
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=60)
            browser.close()
    return {"capture": capture.name, "url_s": round(t_url, 2), "first_frame_s": round(t_frame, 2),
            "ready_s": round(t_ready, 2), "leaves": n}


def time_preview(capture: Path) -> dict:
    """Edit -> fitted-leaf seconds on every leaf of ``capture`` (see the module docstring)."""
    from leaffit_usd.commands.edit import automatic_labels, prepare_capture
    from leaffit_usd.viewer.server import build_session, create_app

    prep = prepare_capture(capture)
    labels, root, frame, conf = automatic_labels(prep)
    s = build_session(prep.plant, labels, capture, os.devnull, os.devnull, root_index=root,
                      height=frame.height, up=frame.up, confidence=conf, frame=frame)
    t0 = time.perf_counter()
    s.warm_preview()
    warm = time.perf_counter() - t0
    app = create_app(s, "bench")
    client = app.test_client()
    rows = []
    pos = np.asarray(s.cloud.means, np.float64)
    for leaf in range(1, int(labels.max()) + 1):
        idx = np.flatnonzero(s.segmenter.labels == leaf)
        if len(idx) < 200:
            continue
        far = idx[np.argmax(np.linalg.norm(pos[idx] - pos[idx].mean(0), axis=1))]
        other = idx[np.argmax(np.linalg.norm(pos[idx] - pos[far], axis=1))]
        for op in ({"op": "split_at", "seeds": [int(far), int(other)]},):
            t = time.perf_counter()
            r = client.post("/bench/api/op", json={"op": op})
            assert r.status_code == 200, r.get_json()
            p = client.post("/bench/api/leaf", json={"label": leaf}).get_json()
            dt = time.perf_counter() - t
            assert "vertices" in p, p
            rows.append({"leaf": leaf, "gaussians": int(len(idx)), "op": op["op"],
                         "edit_to_preview_s": round(dt, 3), "fit_ms": round(p["ms"], 1)})
            client.post("/bench/api/undo", json={})
    lat = np.array([r["edit_to_preview_s"] for r in rows])
    return {"capture": capture.name, "gaussians": len(s.cloud), "template_choice_s": round(warm, 2),
            "median_s": round(float(np.median(lat)), 3), "max_s": round(float(lat.max()), 3),
            "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--open", type=Path, help="a 1M-Gaussian capture to time the opening on")
    ap.add_argument("--preview", type=Path, help="a 100k-Gaussian capture to time edit -> preview on")
    a = ap.parse_args(argv)
    out = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    out["cores"] = os.cpu_count()
    if a.preview:
        out["preview"] = time_preview(a.preview)
        print(json.dumps({k: v for k, v in out["preview"].items() if k != "rows"}))
    if a.open:
        out["open"] = time_open(a.open)
        print(json.dumps(out["open"]))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
