"""A texture edit made once on the template shows on every leaf (evaluator + rasteriser)."""
import numpy as np

from leaffit_usd.edit.preview import render_leaves
from leaffit_usd.edit.texture import overlay_decal
from leaffit_usd.runtime.evaluator import evaluate
from tests.edit.leaves import asset_from_sheet, sheet


def test_decal_reaches_every_leaf():
    pts, faces = sheet("ellipse")
    asset = asset_from_sheet(pts, faces, n_leaves=6, seed=5)
    # spread the instances apart so each is visible from above (asset frame, looking down -Z)
    asset.positions[:] = np.c_[np.arange(6) * 1.5, np.zeros(6), np.zeros(6)]
    tex = np.zeros((128, 128, 4), np.float32)
    tex[..., 1] = 0.5
    tex[..., 3] = 1.0
    decal = np.zeros((16, 16, 4), np.float32)
    decal[..., 0] = 1.0
    decal[..., 2] = 1.0
    decal[..., 3] = 1.0
    # the sheet's UVs map x in [0, 1] to u; put the decal at the leaf's middle
    edited = overlay_decal(tex, decal, uv=(0.5, 0.25), scale=0.2)
    baked = evaluate(asset, frame="asset")
    V = len(asset.template_points)
    uvs = np.tile(asset.template_uvs, (6, 1))
    side = np.tile(asset.template_side, 6)
    rot = np.eye(3)
    before, _ = render_leaves(baked.vertices, baked.faces, uvs, side, tex, tex, rot, width=600, background=(0, 0, 0))
    after, face = render_leaves(baked.vertices, baked.faces, uvs, side, edited, edited, rot, width=600, background=(0, 0, 0))
    magenta = (after[..., 0] > 0.9) & (after[..., 2] > 0.9) & (after[..., 1] < 0.1)
    assert not ((before[..., 0] > 0.9) & (before[..., 2] > 0.9)).any()
    leaf_of_pixel = np.where(face >= 0, baked.leaf_vertex_ids[baked.faces[np.maximum(face, 0), 0]], -1)
    for j in range(6):
        assert magenta[leaf_of_pixel == j].sum() > 20, f"decal missing on leaf {j}"
    assert V * 6 == len(baked.vertices)
