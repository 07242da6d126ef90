"""``export plant.usda -o plant.html``: one self-contained page that opens from a file, offline,
in the real browser (headless Chromium): the leaves sway with the wind, the stem stays still."""
from __future__ import annotations

import base64

import numpy as np
import pytest

from leaffit_usd.image_io import read_image


@pytest.fixture(scope="module")
def page_file(tmp_path_factory, tinted):
    from leaffit_usd.export.page import write_page

    asset, textures = tinted
    path = tmp_path_factory.mktemp("page") / "plant.html"
    n = write_page(path, asset, textures)
    assert n == path.stat().st_size and b"three" in path.read_bytes()[:4000].lower()
    return path


def _frame(pg, t, strength, leaves=True, out=None):
    url = pg.evaluate(f"() => {{ window.leaffitPage.showLeaves({str(leaves).lower()}); "
                      f"window.leaffitPage.frame({t}, {strength}); "
                      "return document.querySelector('canvas').toDataURL('image/png'); }")
    out.write_bytes(base64.b64decode(url.split(",", 1)[1]))
    return read_image(out)


def test_the_page_sways_where_the_leaves_are_and_not_at_the_stem(page_file, tmp_path):
    from leaffit_usd.viewer.gltf_view import find_chromium

    chromium = find_chromium()
    playwright = pytest.importorskip("playwright.sync_api")
    if chromium is None:
        pytest.skip("no Chromium")
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium, args=[
            "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--ignore-gpu-blocklist"])
        try:
            pg = b.new_page(viewport={"width": 320, "height": 320})
            errors = []
            pg.on("pageerror", lambda e: errors.append(str(e)))
            pg.goto(page_file.as_uri())   # from a file: everything is inside the page
            pg.wait_for_function("() => window.leaffitPage && window.leaffitPage.ready", timeout=60000)
            a = _frame(pg, 0.0, 0.6, out=tmp_path / "a.png")
            c = _frame(pg, 0.3, 0.6, out=tmp_path / "b.png")
            stem_a = _frame(pg, 0.0, 0.6, leaves=False, out=tmp_path / "sa.png")
            stem_b = _frame(pg, 0.3, 0.6, leaves=False, out=tmp_path / "sb.png")
            assert errors == []
        finally:
            b.close()
    changed = np.abs(a - c).sum(-1) > 0.05
    assert changed.mean() > 0.002                               # the leaves moved
    background = np.abs(stem_a - stem_a[0, 0]).sum(-1) < 0.02
    assert (~background).mean() > 0.001                         # the stem is drawn
    assert np.array_equal(stem_a, stem_b)                       # and it stays still
