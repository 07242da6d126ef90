"""Render a .glb with three.js in headless Chromium (Playwright): the check that a GLB loads and
draws in a web engine, and the README's screenshot.

The page (``static/gltf_view.html`` + ``gltf_view.js``, the vendored three.js bundle with its
GLTFLoader) is served from a temporary folder by a local HTTP server (ES modules do not load
from file://). Needs the ``playwright`` package and a Chromium (``/usr/bin/chromium``).
"""
from __future__ import annotations

import functools
import shutil
import tempfile
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

STATIC = Path(__file__).with_name("static")
PAGE_FILES = ("gltf_view.html", "gltf_view.js", "three.bundle.min.js")


def find_chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    for c in ("/usr/bin/chromium", shutil.which("chromium"), shutil.which("chromium-browser")):
        if c and Path(c).exists():
            return c
    return None


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):  # no request log on stderr
        pass


def render_glb(glb, png=None, size: int = 800, view=(0.0, 0.35, 1.0), timeout_ms: int = 60000) -> dict:
    """Load ``glb`` in three.js, render it and return what the page measured:

    ``meshes``, ``instances`` (InstancedMesh instance count), ``leafVertices``, ``leafMaterials``,
    ``hasLeaves``, ``hasStem``, ``vertexColors``, ``leaves`` / ``all`` = {fraction of the
    ``size`` x ``size`` image covered, mean sRGB colour 0..255 of the covered pixels} for the
    leaves alone and the whole plant, ``pageErrors``. ``png``: also save a screenshot there.
    view : direction from the plant's centre to the camera (glTF frame, +Y up).
    Raises RuntimeError when Chromium or Playwright is missing.
    """
    chromium = find_chromium()
    if chromium is None:
        raise RuntimeError("chromium not installed (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="leaffit-gltf-view-") as d:
        for f in PAGE_FILES:
            shutil.copy(STATIC / f, Path(d) / f)
        shutil.copy(glb, Path(d) / "plant.glb")
        server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=d))
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=chromium, args=[
                    "--no-sandbox", "--headless=new", "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"])
                try:
                    page = browser.new_page(viewport={"width": size, "height": size})
                    errors = []
                    page.on("pageerror", lambda e: errors.append(str(e)))
                    v = ",".join(str(float(x)) for x in view)
                    page.goto(f"http://127.0.0.1:{server.server_address[1]}/gltf_view.html"
                              f"?glb=plant.glb&w={size}&h={size}&view={v}")
                    page.wait_for_function("() => window.leaffitGltf && window.leaffitGltf.ready",
                                           timeout=timeout_ms)
                    out = page.evaluate("window.leaffitGltf")
                    if png is not None:
                        Path(png).parent.mkdir(parents=True, exist_ok=True)
                        page.locator("canvas").screenshot(path=str(png))
                    out["pageErrors"] = errors
                finally:
                    browser.close()
        finally:
            server.shutdown()
            server.server_close()
    return out
