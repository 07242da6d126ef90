"""The GLB loaded by three.js (GLTFLoader, the vendored bundle) in headless Chromium: both leaf
materials load, the leaves cover the view and show the texture's green. Skipped without
Chromium or Playwright."""
import numpy as np
import pytest

from leaffit_usd.export.gltf import GltfOptions, write_gltf
from leaffit_usd.viewer.gltf_view import find_chromium, render_glb

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="chromium not installed (apt-get install chromium)")


@pytest.mark.parametrize("instanced", [False, True])
def test_three_renders_the_leaves(tinted, tmp_path, instanced):
    pytest.importorskip("playwright.sync_api")
    a, tex = tinted
    glb = tmp_path / "plant.glb"
    write_gltf(glb, a, tex, GltfOptions(instanced=instanced))
    r = render_glb(glb, png=tmp_path / "shot.png", size=320)
    assert not r.get("error") and not r["pageErrors"], r
    assert r["hasLeaves"] and r["hasStem"]
    assert r["leafMaterials"] == ["LeafBack", "LeafFront"]
    if instanced:   # EXT_mesh_gpu_instancing -> InstancedMesh, _COLOR_0 -> instanceColor
        assert r["instances"] == 2 * a.n_leaves and r["instanceColors"]   # front + back sheet
    else:           # COLOR_0 -> vertex colours
        assert r["leafVertices"] == a.n_leaves * len(a.template_points) and r["vertexColors"]
    # the leaves alone cover a good part of the image, in the texture's green
    cover, mean = r["leaves"]["fraction"], np.array(r["leaves"]["mean"])
    assert cover > 0.02, r
    assert mean[1] > mean[0] and mean[1] > mean[2], mean
    assert (tmp_path / "shot.png").stat().st_size > 1000


def test_render_sees_a_missing_texture(tinted, tmp_path):
    """The check can fail: untextured flat-grey leaves are not green."""
    pytest.importorskip("playwright.sync_api")
    from leaffit_usd.usd.writer import LeafTextures

    a, tex = tinted
    grey = np.full_like(tex.front, 128)
    grey[..., 3] = 255
    glb = tmp_path / "grey.glb"
    write_gltf(glb, a, LeafTextures(grey, grey), GltfOptions(tint=False))
    r = render_glb(glb, size=200)
    mean = np.array(r["leaves"]["mean"])
    assert r["leaves"]["fraction"] > 0.02 and abs(mean[1] - mean[0]) < 8, mean
