"""The viewer driven for real in headless Chromium (Playwright): brush a leaf, assign, save.

The saved labels must equal what the saved edits give through ``apply_edits`` (the path
``segment/convert --edits`` take). Skipped when Chromium or Playwright is missing.
"""
import shutil
from pathlib import Path

import numpy as np
import pytest

from leaffit_usd.segment.edits import apply_edits, load_edits
from leaffit_usd.splats import load_cloud, write_ply
from leaffit_usd.viewer.server import ViewerServer, build_session

CHROMIUM = "/usr/bin/chromium"
SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "plants" / "rubber_tree.ply"

pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists() and not shutil.which("chromium"),
                                reason="chromium not installed (apt-get install chromium)")


def _open_editor(playwright, server):
    """(browser, page, page errors) with the editor loaded from ``server`` in headless Chromium."""
    browser = playwright.chromium.launch(
        executable_path=CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium"),
        args=["--no-sandbox", "--disable-gpu", "--headless=new"])
    page = browser.new_page(viewport={"width": 1100, "height": 750})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.url)
    page.wait_for_function("() => window.leaffit && window.leaffit.ready", timeout=30000)
    return browser, page, errors


@pytest.fixture(scope="module")
def sample(plant, tmp_path_factory):
    """(ply path, ground-truth labels in file order): a bundled sample plant, else the synthetic one."""
    gt = SAMPLE.with_name(SAMPLE.name.replace(".ply", ".gt.npz"))
    if SAMPLE.exists() and gt.exists():
        return SAMPLE, np.load(gt)["labels"]
    d = tmp_path_factory.mktemp("browser")
    write_ply(plant[0], d / "plant.ply")
    return d / "plant.ply", plant[1]


def test_brush_assign_save_in_chromium(sample, heat, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    ply, truth = sample
    cloud = load_cloud(ply)
    truth_c = truth[cloud.file_index]
    session = build_session(cloud, np.zeros(len(cloud), np.int32), ply, tmp_path / "e.json",
                            tmp_path / "l.npz", solver_factory=heat)
    server = ViewerServer(session).start_background()
    try:
        with sync_api.sync_playwright() as p:
            browser, page, errors = _open_editor(p, server)
            page.eval_on_selector("#radius", "e => { e.value = '0.04'; e.dispatchEvent(new Event('input')); }")
            # choose the leaf with the most Gaussians visible under the cursor; a stroke along it
            rng = np.random.default_rng(0)
            best = None
            for leaf in [k for k in np.unique(truth_c) if k > 0][:6]:
                idx = rng.choice(np.flatnonzero(truth_c == leaf), 24, replace=False)
                hits = page.evaluate("""async (ids) => {
                    const out = [];
                    for (const i of ids) {
                      const s = window.leaffit.screenOf(i);
                      out.push([s.x, s.y, await window.leaffit.pick(s.x, s.y)]);
                    }
                    return out; }""", idx.tolist())
                good = [(x, y) for x, y, g in hits if g >= 0 and truth_c[g] == leaf]
                if best is None or len(good) > len(best[1]):
                    best = (leaf, good)
            leaf, good = best
            assert len(good) >= 4, "no leaf is visible from the default camera"
            pts = np.array(good)
            order = np.argsort(pts @ np.linalg.svd(pts - pts.mean(0))[2][0])  # along the leaf
            stroke = pts[order][np.linspace(0, len(pts) - 1, 4).astype(int)]
            page.mouse.move(*stroke[0])
            page.mouse.down()
            for x, y in stroke[1:]:
                page.mouse.move(x, y, steps=4)
            page.mouse.up()
            page.wait_for_function("() => !window.leaffit.busy && window.leaffit.state().n_ops === 1", timeout=30000)
            assert page.evaluate("window.leaffit.state().selected") > 0
            page.select_option("[data-testid=target]", "new")
            page.click("[data-testid=assign]")
            page.wait_for_function("() => window.leaffit.state().n_ops === 2", timeout=30000)
            assert "Leaf 1" in page.inner_text("[data-testid=leaves]")
            page.click("[data-testid=undo]")  # undo / redo round trip through the page
            page.wait_for_function("() => window.leaffit.state().n_ops === 1 && window.leaffit.state().can_redo")
            assert "Leaf 1" not in page.inner_text("[data-testid=leaves]")
            page.keyboard.press("Control+Shift+Z")
            page.wait_for_function("() => window.leaffit.state().n_ops === 2")
            # the drag tool: press at one end of the leaf, drag to the other; then Esc clears
            page.check("[data-testid=tool-drag]")
            page.mouse.move(*stroke[-1])
            page.mouse.down()
            page.mouse.move(*stroke[0], steps=5)
            page.mouse.up()
            page.wait_for_function("() => !window.leaffit.busy && window.leaffit.state().n_ops === 3", timeout=30000)
            assert page.evaluate("window.leaffit.state().selected") > 0
            page.keyboard.press("Escape")
            page.wait_for_function("() => window.leaffit.state().n_ops === 4")
            page.click("[data-testid=save]")
            page.wait_for_function("() => document.getElementById('outputs').textContent.startsWith('saved')",
                                   timeout=30000)
            assert not errors, errors
            browser.close()
    finally:
        server.stop()
    saved = np.load(tmp_path / "l.npz")["labels"]
    ops = load_edits(tmp_path / "e.json", ply).operations
    assert [o["op"] for o in ops] == ["brush", "assign", "drag", "clear"] and len(ops[0]["centers"]) >= 2
    assert ops[2]["source"] != ops[2]["target"]
    # same edits through the replay path (fresh cloud, fresh solver)
    cloud2 = load_cloud(ply)
    replayed = apply_edits(np.zeros(len(cloud2), np.int32), cloud2, load_edits(tmp_path / "e.json", ply),
                           solver_factory=heat)
    assert np.array_equal(cloud2.to_file_order(replayed), saved)
    # and the brushed leaf is the one under the stroke
    new = saved[cloud.file_index] == 1
    assert new.sum() > 50 and (truth_c[new] == leaf).mean() > 0.9


def test_opens_on_the_least_confident_leaf(plant, heat, tmp_path):
    """The page checks the least confident leaf on open, points the camera at it, marks the
    doubtful leaves with '?', and 'Next ?' goes through them (small synthetic plant: fast)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    cloud, truth = plant[0], plant[1].copy()
    truth[(truth == 1) & (cloud.means[:, 0] < -0.3)] = 3  # the outer half of leaf 1 as leaf 3
    write_ply(cloud, tmp_path / "plant.ply")
    cloud = load_cloud(tmp_path / "plant.ply")
    labels = truth[cloud.file_index]
    session = build_session(cloud, labels, tmp_path / "plant.ply", tmp_path / "e.json", tmp_path / "l.npz",
                            n_samples=300, solver_factory=heat, height=0.8, up=(0.0, 0.0, 1.0),
                            confidence=np.array([0.9, 0.2, 0.4]))
    server = ViewerServer(session).start_background()
    try:
        with sync_api.sync_playwright() as p:
            browser, page, errors = _open_editor(p, server)
            assert page.evaluate("window.leaffit.checked()") == [2]
            status = page.inner_text("[data-testid=status]")
            assert "leaf 2 is the least confident (0.20)" in status and "2 doubtful leaves" in status
            # the camera looks at leaf 2's box centre (display frame)
            pos = (cloud.means[labels == 2] - session.centre) / session.height
            centre = (pos.min(0) + pos.max(0)) / 2
            assert np.allclose(page.evaluate("window.leaffit.target()"), centre, atol=1e-4)
            # rows: least confident first; doubtful ones marked '?'
            rows = page.eval_on_selector_all(
                "#leaves .leaf", "rs => rs.map(r => [+r.dataset.label, r.className, r.innerText])")
            assert [r[0] for r in rows] == [0, 2, 3, 1]
            cls = {r[0]: r[1] for r in rows}
            assert "doubtful" in cls[2] and "least" in cls[2] and "doubtful" in cls[3] and "doubtful" not in cls[1]
            assert "?" in rows[1][2] and "0.20" in rows[1][2] and "?" not in rows[3][2]
            page.click("[data-testid=next-doubtful]")
            assert page.evaluate("window.leaffit.checked()") == [3]
            page.keyboard.press("n")
            assert page.evaluate("window.leaffit.checked()") == [2]
            assert page.evaluate("window.leaffit.state().n_ops") == 0  # looking records nothing
            assert not errors, errors
            browser.close()
    finally:
        server.stop()


def test_splats_split_and_fitted_leaf_in_chromium(plant, heat, tmp_path):
    """The two leaves of the two-leaf plant merged into one instance: the page draws splats (not
    the dots, which it also offers), shows the fitted leaf of the checked instance, and the
    Split tool's two clicks (one per leaf) cut it in two; the saved split_at replays exactly."""
    sync_api = pytest.importorskip("playwright.sync_api")
    write_ply(plant[0], tmp_path / "plant.ply")
    cloud = load_cloud(tmp_path / "plant.ply")
    truth = plant[1][cloud.file_index]
    merged = np.where(truth > 0, 1, 0).astype(np.int32)
    session = build_session(cloud, merged, tmp_path / "plant.ply", tmp_path / "e.json", tmp_path / "l.npz",
                            n_samples=1500, solver_factory=heat, height=0.8, up=(0.0, 0.0, 1.0))
    server = ViewerServer(session).start_background()
    try:
        with sync_api.sync_playwright() as p:
            browser, page, errors = _open_editor(p, server)
            page.wait_for_function("() => window.leaffit.drawn")
            assert page.evaluate("window.leaffit.mode()") == "splats"
            splat_png = page.locator("#view canvas").screenshot()
            page.check("[data-testid=dots]")
            page.wait_for_timeout(300)
            dots_png = page.locator("#view canvas").screenshot()
            page.uncheck("[data-testid=dots]")
            img = _pixels(splat_png)
            lit = (np.abs(img - [29, 31, 33]).sum(-1) > 30).mean()
            assert 0.01 < lit < 0.9, lit  # the plant covers part of the view
            differ = (np.abs(img - _pixels(dots_png)).sum(-1) > 30).mean()
            assert differ > 0.2 * lit, (differ, lit)  # splats, not the dots
            # the fitted leaf of the checked instance
            page.check("#leaves input[data-label='1']")
            page.wait_for_function("() => window.leaffit.preview() && window.leaffit.preview().vertices > 50",
                                   timeout=30000)
            # two clicks, one on each true leaf (Gaussians visible under the cursor)
            def visible_on(k):
                ids = np.flatnonzero(truth == k)
                ids = ids[np.argsort(np.abs(np.abs(cloud.means[ids, 0]) - 0.25))][:30]
                for i in ids.tolist():
                    s = page.evaluate(f"window.leaffit.screenOf({i})")
                    g = page.evaluate(f"window.leaffit.pick({s['x']}, {s['y']})")
                    if g >= 0 and truth[g] == k:
                        return s
                raise AssertionError(f"no Gaussian of leaf {k} visible")
            a, b = visible_on(1), visible_on(2)
            page.check("[data-testid=tool-split]")
            page.mouse.click(a["x"], a["y"])
            page.wait_for_function("() => document.getElementById('status').textContent.includes('other leaf')")
            page.mouse.click(b["x"], b["y"])
            page.wait_for_function("() => window.leaffit.state().n_ops === 1", timeout=30000)
            assert len(page.evaluate("window.leaffit.state().leaves")) == 2
            # the preview follows the edit: leaf 1 is now one leaf, fitted again
            page.wait_for_function("() => window.leaffit.preview().ops === 1 && window.leaffit.preview().vertices",
                                   timeout=30000)
            page.click("[data-testid=save]")
            page.wait_for_function("() => document.getElementById('outputs').textContent.startsWith('saved')")
            assert not errors, errors
            browser.close()
    finally:
        server.stop()
    saved = np.load(tmp_path / "l.npz")["labels"][cloud.file_index]
    assert (saved[truth == 1] == saved[truth == 1][0]).mean() > 0.97
    assert (saved[truth == 2] == saved[truth == 2][0]).mean() > 0.97 and saved[truth == 1][0] != saved[truth == 2][0]
    ops = load_edits(tmp_path / "e.json", tmp_path / "plant.ply").operations
    assert [o["op"] for o in ops] == ["split_at"]
    cloud2 = load_cloud(tmp_path / "plant.ply")
    replayed = apply_edits(merged.copy(), cloud2, load_edits(tmp_path / "e.json", tmp_path / "plant.ply"),
                           solver_factory=heat)
    assert np.array_equal(replayed, saved)


def _pixels(png: bytes) -> np.ndarray:
    """(H, W, 3) float64 0..255 of a PNG screenshot (the project's one image reader)."""
    import tempfile

    from leaffit_usd.image_io import read_image_u8

    with tempfile.NamedTemporaryFile(suffix=".png") as f:
        f.write(png)
        f.flush()
        return np.asarray(read_image_u8(f.name), np.float64)[..., :3]
