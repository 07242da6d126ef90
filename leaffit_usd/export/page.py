"""``leaffit-usd export plant.usda -o plant.html``: one self-contained web page of the plant.

The page holds everything it needs, so it opens from a file, offline: the vendored three.js
bundle (``viewer/static/three.bundle.min.js``, with its GLTFLoader and OrbitControls), the asset
as the evaluated GLB this package writes (base64), and the wind data (``usd.wind``: each leaf's
pivot, axis and phase in the glTF frame). ``plant_page.js`` draws it with orbit controls and a
wind slider: every leaf turns about its axis through its pivot as in the CPU evaluator and the
GLSL deformer; the stem stays still.
"""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

from leaffit_usd.io_util import atomic_write_bytes
from leaffit_usd.usd.wind import WindParams, wind_data

THREE_BUNDLE = Path(__file__).resolve().parents[1] / "viewer" / "static" / "three.bundle.min.js"
PAGE_JS = Path(__file__).with_name("plant_page.js")

_HTML = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>html,body{{margin:0;height:100%;overflow:hidden;font:13px sans-serif}}
#ui{{position:fixed;left:12px;top:10px;background:#fffc;padding:6px 10px;border-radius:6px}}</style>
</head><body>
<div id="ui">{title} &middot; wind <input id="strength" type="range" min="0" max="1" step="0.01" value="{strength}"></div>
<script type="text/plain" id="three">{three}</script>
<script type="application/json" id="wind">{wind}</script>
<script type="text/plain" id="glb">{glb}</script>
<script type="module">{page}</script>
</body></html>
"""


def _inline(text: str) -> str:
    """Text safe inside a <script> element (no closing tag in it)."""
    return text.replace("</script", "<\\/script")


def write_page(path, asset, textures=None, options=None, wind: WindParams | None = None) -> int:
    """Write the page of ``asset`` (PlantAsset) atomically; returns its size in bytes.
    textures : LeafTextures or None; options : ``export.gltf.GltfOptions`` for the embedded GLB
    (always the evaluated layout); wind : the slider's starting strength and the frequency."""
    import dataclasses

    from leaffit_usd.export.gltf import GltfOptions, asset_to_gltf, build_gltf

    opts = dataclasses.replace(options or GltfOptions(), instanced=False)
    gltf, _ = build_gltf(asset, textures, opts, name=Path(path).stem)
    glb = b"".join(gltf.save_to_bytes())
    w = wind or WindParams()
    d = wind_data(asset)
    G = asset_to_gltf(asset)
    rG = G[:3, :3] / float(np.cbrt(np.linalg.det(G[:3, :3])))
    data = {"pivots": np.round(np.asarray(d.pivots, np.float64) @ G[:3, :3].T + G[:3, 3], 6).tolist(),
            "axes": np.round(np.asarray(d.axes, np.float64) @ rG.T, 6).tolist(),
            "phases": np.round(np.asarray(d.phases, np.float64), 6).tolist(),
            "verticesPerLeaf": int(len(asset.template_points)), "frequency": float(w.frequency)}
    html = _HTML.format(title=Path(path).stem, strength=f"{float(w.strength):.2f}",
                        three=_inline(THREE_BUNDLE.read_text()), wind=_inline(json.dumps(data)),
                        glb=base64.b64encode(glb).decode(), page=_inline(PAGE_JS.read_text()))
    raw = html.encode()
    atomic_write_bytes(path, raw)
    return len(raw)
