"""The texture bake renders a widened random subset of a dense template leaf
(leaffit_usd.mesh.texture_bake.bake_subset, MeshParams.bake_gaussians)."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh.template import MeshParams, build_template_mesh
from leaffit_usd.mesh.texture_bake import bake_subset
from samples.synthetic.mesh import synthetic_leaf


def _points(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 1, (n, 2)) * [2.0, 0.5], rng.uniform(size=n) < 0.5


def test_bake_subset_all_when_under_the_cap():
    xy, layer = _points(100)
    idx, widen = bake_subset(xy, layer, 100)
    assert np.array_equal(idx, np.arange(100)) and widen == 1.0
    idx, widen = bake_subset(xy, layer, 0)                 # 0 = all
    assert len(idx) == 100 and widen == 1.0


def test_bake_subset_is_even_over_the_leaf_and_its_layers():
    """Sorted, distinct, deterministic; each layer keeps its share; and the subset covers the
    leaf evenly: every cell of an 8 x 8 grid keeps about a quarter of its Gaussians (a random
    quarter would scatter far more)."""
    xy, layer = _points(20_000, seed=1)
    idx, widen = bake_subset(xy, layer, 5_000)
    assert len(idx) == 5_000 and len(np.unique(idx)) == 5_000 and np.all(np.diff(idx) > 0)
    assert widen == pytest.approx(4.0)
    assert np.array_equal(idx, bake_subset(xy, layer, 5_000)[0])
    assert abs(layer[idx].mean() - layer.mean()) < 0.002
    cells = lambda i: np.bincount((np.floor(xy[i] / [0.25, 0.0625]).astype(int) @ [8, 1]), minlength=64)
    ratio = cells(idx) / cells(np.arange(len(xy)))
    rnd = np.sort(np.random.default_rng(2).choice(len(xy), 5_000, replace=False))
    assert np.abs(ratio - 0.25).max() < 0.03
    assert np.abs(ratio - 0.25).max() < np.abs(cells(rnd) / cells(np.arange(len(xy))) - 0.25).max()


@pytest.fixture(scope="module")
def dense_leaf():
    return synthetic_leaf(12_000, seed=3, marker=True)


def test_subset_bake_keeps_coverage_and_colour(dense_leaf):
    """A quarter of the Gaussians, widened, gives the same cut-out and colours as all of them;
    the same quarter NOT widened leaves the layer thin (what the widening is for)."""
    cloud, fits = dense_leaf
    p = dict(vertex_budget=400, texture_size=96, supersample=1)
    full = build_template_mesh(cloud, fits, MeshParams(**p, bake_gaussians=0))
    sub = build_template_mesh(cloud, fits, MeshParams(**p, bake_gaussians=3_000))
    assert full.report["bake_gaussians"] == 12_000 and full.report["bake_widen"] == 1.0
    assert sub.report["bake_gaussians"] == 3_000 and sub.report["bake_widen"] == pytest.approx(4.0)
    for a, b in ((full.front_texture, sub.front_texture), (full.back_texture, sub.back_texture)):
        ca, cb = a[..., 3] > 127, b[..., 3] > 127
        # the same cut-out: the outline lies on the whole set's silhouette, the cut-out inside it
        # on each bake's own splats; the widened quarter's softer edge moves it by up to a texel
        # of this 96-texel texture (a ~250-texel rim: 0.966 here)
        assert (ca & cb).sum() / (ca | cb).sum() > 0.96
        both = ca & cb
        diff = np.abs(a[both, :3].astype(float) - b[both, :3].astype(float))
        assert diff.mean() < 10.0      # of 255 (this leaf's Gaussians have random colours)
        # no colour bias: the widened own layer hides the other side as much as all of it did
        # (without widening the renderer's 0.3 px^2 dilation, the bias was 7-9 / 255)
        assert np.abs(a[both, :3].mean(0) - b[both, :3].mean(0)).max() < 2.5
    # the marker quarter (red on top) stays where it is, inside the leaf (the rim texel of the
    # cut-out mixes both layers, differently for the widened splats)
    from scipy.ndimage import binary_erosion

    inner = binary_erosion((full.front_texture[..., 3] > 127) & (sub.front_texture[..., 3] > 127))
    red = inner & ((sub.front_texture[..., 0].astype(int) - sub.front_texture[..., 1]) > 60)
    red_full = inner & ((full.front_texture[..., 0].astype(int) - full.front_texture[..., 1]) > 60)
    assert red_full.sum() > 50 and abs(int(red.sum()) - int(red_full.sum())) < 0.15 * red_full.sum()
    c, c_full = np.argwhere(red).mean(0), np.argwhere(red_full).mean(0)
    assert np.abs(c - c_full).max() < 1.5                      # pixels


def test_subset_without_widening_would_thin_the_layer(dense_leaf):
    """The check above can fail: the same subset at its own size covers visibly less."""
    import dataclasses

    from leaffit_usd.mesh.texture_bake import bake_textures
    from leaffit_usd.mesh.uv_chart import planar_chart

    cloud, fits = dense_leaf
    m = build_template_mesh(cloud, fits, MeshParams(vertex_budget=400, texture_size=96, supersample=1,
                                                    bake_gaussians=0))
    P, F = m.sheet_points.astype(np.float64), m.sheet_faces.astype(np.int64)
    outline = P[:, :2]
    args = (P, F, outline, planar_chart(outline, 96, 0.01), 96, 0.5, 0.0, 1)
    from leaffit_usd.mesh.sheet_distance import signed_sheet_offset
    from leaffit_usd.mesh.template_gaussians import template_gaussians_local

    means = template_gaussians_local(cloud, fits)[0]
    idx, _ = bake_subset(means[:, :2], signed_sheet_offset(means, P, F) >= 0, 1_500)
    thin = dataclasses.replace(fits, template_gaussians=np.asarray(fits.template_gaussians)[idx])
    _, _, i_all = bake_textures(cloud, fits, *args, max_gaussians=1_500)
    _, _, i_thin = bake_textures(cloud, thin, *args)
    assert i_all["bake_gaussians"] == i_thin["bake_gaussians"] == 1_500
    assert i_thin["own_layer_coverage_front"] < i_all["own_layer_coverage_front"] - 0.05


@pytest.mark.parametrize("bad", [-1, 2.5, True])
def test_bake_gaussians_validated(dense_leaf, bad):
    cloud, fits = dense_leaf
    with pytest.raises(ParameterError):
        build_template_mesh(cloud, fits, MeshParams(vertex_budget=400, texture_size=32, bake_gaussians=bad))
