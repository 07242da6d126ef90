"""Template mesh, two-sided UVs, texture bake and texture files (leaffit_usd.mesh.template)."""
import logging

import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh import surface as S
from samples.synthetic.mesh import BOTTOM_RGB, TOP_RGB, synthetic_leaf
from leaffit_usd.image_io import read_image_u8 as read_image
from leaffit_usd.mesh.params import MeshParams
from leaffit_usd.mesh.template import build_template_mesh
from leaffit_usd.mesh.texture_files import write_textures
from leaffit_usd.mesh.uv_chart import rasterize_polygon

from .conftest import SHEET_MAX_DIST_REL, SHEET_MEAN_DIST_REL

SMALL = dict(vertex_budget=400, texture_size=64)


def test_template_is_thin_disk_within_budget(leaf_mesh):
    r = leaf_mesh.report
    assert r["is_disk"] and r["components"] == 1 and r["boundary_loops"] == 1 and r["euler"] == 1
    assert r["holes_after"] == 0 and r["nonmanifold_edges"] == 0
    assert r["sheet_vertices"] <= 800 and r["vertices"] == 2 * r["sheet_vertices"]
    assert r["fold_ratio"] < 0.01
    assert r["points_dist_mean_rel"] < SHEET_MEAN_DIST_REL
    assert r["points_dist_max_rel"] < SHEET_MAX_DIST_REL
    assert r["gauss_dist_mean_rel"] < SHEET_MEAN_DIST_REL


@pytest.mark.parametrize("budget", [50, 333])
def test_vertex_budget_honoured(leaf, budget):
    cloud, fits = leaf
    m = build_template_mesh(cloud, fits, MeshParams(vertex_budget=budget, texture_size=32))
    assert 0.5 * budget <= len(m.sheet_points) <= budget
    assert len(m.points) == 2 * len(m.sheet_points)


def test_two_sided_layout(leaf_mesh):
    m = leaf_mesh
    V = len(m.points)
    S_ = V // 2
    assert np.array_equal(m.side, np.repeat([0, 1], S_).astype(np.uint8))
    assert np.array_equal(m.points[:S_], m.points[S_:])
    G = len(m.faces) // 2
    front, back = m.faces[:G], m.faces[G:]
    assert front.max() < S_ and back.min() >= S_
    assert np.array_equal(back - S_, front[:, ::-1])
    # front faces CCW seen from +Z, back faces CW; normals split
    fn = np.cross(m.points[front[:, 1]] - m.points[front[:, 0]], m.points[front[:, 2]] - m.points[front[:, 0]])
    assert (fn[:, 2] > 0).mean() > 0.99
    assert (m.normals[:S_, 2] > 0).mean() > 0.99 and np.allclose(m.normals[S_:], -m.normals[:S_])
    # UVs: own patch per side, back mirrored in u
    assert m.uvs.min() >= 0 and m.uvs.max() <= 1
    assert np.allclose(m.uvs[S_:, 0], 1 - m.uvs[:S_, 0]) and np.allclose(m.uvs[S_:, 1], m.uvs[:S_, 1])
    # envelope chart (the default): u follows x (base -> apex) exactly, v increases with y
    assert np.corrcoef(m.uvs[:S_, 0], m.points[:S_, 0])[0, 1] > 0.999
    assert np.corrcoef(m.uvs[:S_, 1], m.points[:S_, 1])[0, 1] > 0.95
    assert m.report["uv_chart"] == "envelope"
    assert m.faces.dtype == np.int32 and m.points.dtype == np.float32
    assert m.front_texture.shape == (128, 128, 4) and m.front_texture.dtype == np.uint8


def _texel(tex, uv):
    H, W = tex.shape[:2]
    c = np.clip((uv[:, 0] * W).astype(int), 0, W - 1)
    r = np.clip(((1 - uv[:, 1]) * H).astype(int), 0, H - 1)
    return tex[r, c]


def test_textures_show_the_two_sides(leaf_mesh):
    m = leaf_mesh
    S_ = len(m.points) // 2
    # interior vertices (not on the rim) sample opaque texels of their own side's texture
    rim = np.unique(np.concatenate(S.boundary_loops(m.sheet_faces.astype(np.int64), S_)))
    inner = np.setdiff1d(np.arange(S_), rim)
    f = _texel(m.front_texture, m.uvs[:S_][inner]).astype(float)
    b = _texel(m.back_texture, m.uvs[S_:][inner]).astype(float)
    assert (f[:, 3] > 128).mean() > 0.98 and (b[:, 3] > 128).mean() > 0.98
    # front is the green top layer, back the pale bottom layer
    top, bottom = np.asarray(TOP_RGB) * 255, np.asarray(BOTTOM_RGB) * 255
    fm, bm = f[:, :3].mean(0), b[:, :3].mean(0)
    assert np.linalg.norm(fm - top) < np.linalg.norm(fm - bottom)
    assert np.linalg.norm(bm - bottom) < np.linalg.norm(bm - top)
    # the back texture is the front's mirror image in silhouette
    af, ab = m.front_texture[..., 3] > 128, m.back_texture[..., 3] > 128
    iou = (af & ab[:, ::-1]).sum() / (af | ab[:, ::-1]).sum()
    assert iou > 0.95


def test_texture_edges_clean_and_padded(leaf_mesh):
    m = leaf_mesh
    for tex in (m.front_texture, m.back_texture):
        a = tex[..., 3]
        assert a[0].max() == 0 and a[-1].max() == 0 and a[:, 0].max() == 0  # empty border
        # edge dilation: transparent texels carry leaf colours, not black
        clear = a == 0
        assert clear.any() and tex[clear][:, 1].min() > 60
        # the cut-out edge is sharp: few partially transparent texels relative to the rim
        partial = (a > 0) & (a < 255)
        solid = a == 255
        assert partial.sum() < 3 * np.sqrt(solid.sum()) * 4


def test_rasterize_polygon_area():
    sq = np.array([[0.1, 0.1], [0.6, 0.1], [0.6, 0.6], [0.1, 0.6]])
    mask = rasterize_polygon(sq, 100, 100, (0, 1, 0, 1))
    assert mask.sum() == 2500
    # row 0 = top (y = ymax): the square lies in the lower part of the image
    assert mask[-20].any() and not mask[20].any()


def test_write_read_textures_roundtrip(leaf_mesh, tmp_path):
    for fmt in ("png", "exr"):
        paths = write_textures(leaf_mesh, tmp_path, fmt)
        assert paths.front.name == f"leaf_front.{fmt}" and paths.back.exists()
        back = read_image(paths.back)
        tol = 0 if fmt == "png" else 2
        assert np.abs(back.astype(int) - leaf_mesh.back_texture.astype(int)).max() <= tol
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    with pytest.raises(ParameterError):
        write_textures(leaf_mesh, tmp_path, "jpg")


@pytest.mark.parametrize("bad", [dict(vertex_budget=2), dict(texture_size=4),
                                 dict(method="poisson"), dict(bpa_radii=()), dict(alpha_threshold=1.5),
                                 dict(uv_layout="xatlas"), dict(chart_min_width=0.0)])
def test_params_validation(leaf, bad):
    cloud, fits = leaf
    with pytest.raises(ParameterError):
        build_template_mesh(cloud, fits, MeshParams(**bad))


def test_missing_template_row_is_reported(leaf):
    import dataclasses

    cloud, fits = leaf
    with pytest.raises(ParameterError):
        build_template_mesh(cloud, dataclasses.replace(fits, template_label=7), MeshParams(**SMALL))


def test_deterministic():
    cloud, fits = synthetic_leaf(1000, seed=8)
    a = build_template_mesh(cloud, fits, MeshParams(**SMALL))
    b = build_template_mesh(cloud, fits, MeshParams(**SMALL))
    assert np.array_equal(a.points, b.points) and np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.front_texture, b.front_texture)


# ---- degenerate inputs: fallback + warning, never a crash -------------------------------------
def test_bpa_failure_falls_back_to_planar(leaf, caplog):
    cloud, fits = leaf
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        m = build_template_mesh(cloud, fits, MeshParams(bpa_radii=(0.05,), **SMALL))
    assert m.report["method"].split("+")[0] == "planar" and m.report["is_disk"]
    assert "fell back" in caplog.text


@pytest.mark.parametrize("n", [2, 3, 12])
def test_too_few_points(n, caplog):
    cloud, fits = synthetic_leaf(40, seed=2)
    import dataclasses

    fits = dataclasses.replace(fits, template_points=fits.template_points[:n],
                               template_gaussians=fits.template_gaussians[:n])
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        m = build_template_mesh(cloud, fits, MeshParams(**SMALL))
    assert len(m.faces) >= 4 and len(m.sheet_points) <= max(n, 4)
    assert caplog.records


def test_leaf_seen_from_one_side(caplog):
    cloud, fits = synthetic_leaf(1500, seed=4, two_sided=False)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        m = build_template_mesh(cloud, fits, MeshParams(**SMALL))
    # one layer: both sides see it; the back is its mirror image
    f, b = m.front_texture.astype(int), m.back_texture[:, ::-1].astype(int)
    solid = (f[..., 3] > 128) & (b[..., 3] > 128)
    assert solid.mean() > 0.1
    assert np.abs(f[solid, :3] - b[solid, :3]).mean() < 40


def test_sparse_splats_are_inpainted(caplog):
    cloud, fits = synthetic_leaf(300, seed=5)
    cloud.log_scales[:] = np.log(1e-5)  # points, not splats: almost no coverage
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        m = build_template_mesh(cloud, fits, MeshParams(vertex_budget=200, texture_size=256))
    assert m.report["texture_fallback"] == "inpainted"
    assert "inpainted" in caplog.text
    assert (m.front_texture[..., 3] > 128).mean() > 0.05


def test_mesh_value_serialises(leaf_mesh, tmp_path):
    import json

    from leaffit_usd.mesh.result import TemplateMesh
    from leaffit_usd.serialize import load_value, save_value

    json.dumps(leaf_mesh.report)  # plain JSON: goes into the stage's metadata and --report
    save_value(leaf_mesh, tmp_path / "m.npz")
    back = load_value(TemplateMesh, tmp_path / "m.npz")
    assert np.array_equal(back.faces, leaf_mesh.faces) and np.array_equal(back.back_texture, leaf_mesh.back_texture)
    assert back.report["sheet_vertices"] == leaf_mesh.report["sheet_vertices"]


def test_textures_not_mirrored_or_flipped():
    """A red (top) / blue (bottom) patch on the base half's +Y side shows up under exactly the
    vertices of that patch in each side's texture: catches a row flip or a wrong back mirror.
    Interior vertices only: the outline lies on the splats' silhouette, where a texel holds the
    soft edge of both layers (the other side's colour shows through, as in the input)."""
    from leaffit_usd.mesh.surface import boundary_loops

    cloud, fits = synthetic_leaf(2500, seed=6, marker=True)
    m = build_template_mesh(cloud, fits, MeshParams(vertex_budget=500, texture_size=96))
    S_ = len(m.points) // 2
    p = m.sheet_points
    rim = np.zeros(len(p), bool)
    rim[np.concatenate(boundary_loops(m.sheet_faces.astype(np.int64), len(p)))] = True
    x01 = (p[:, 0] - p[:, 0].min()) / np.ptp(p[:, 0])
    patch = (x01 > 0.1) & (x01 < 0.3) & (p[:, 1] > 0.1) & ~rim
    mirror = (x01 > 0.1) & (x01 < 0.3) & (p[:, 1] < -0.1) & ~rim
    assert patch.sum() > 5 and mirror.sum() > 5
    f_in = _texel(m.front_texture, m.uvs[:S_][patch]).astype(float)
    b_in = _texel(m.back_texture, m.uvs[S_:][patch]).astype(float)
    f_out = _texel(m.front_texture, m.uvs[:S_][mirror]).astype(float)
    b_out = _texel(m.back_texture, m.uvs[S_:][mirror]).astype(float)
    assert (f_in[:, 0] > f_in[:, 1] + 50).mean() > 0.8      # red on the front
    assert (b_in[:, 2] > b_in[:, 1] + 50).mean() > 0.8      # blue on the back
    assert (f_out[:, 1] > f_out[:, 0]).mean() > 0.9          # green at the mirror position
    assert (b_out[:, 1] > b_out[:, 2]).mean() > 0.9


def test_planar_chart_uvs_are_linear(leaf):
    """uv_layout="fit": the planar chart, u and v linear in x and y."""
    cloud, fits = leaf
    m = build_template_mesh(cloud, fits, MeshParams(vertex_budget=300, texture_size=64, uv_layout="fit"))
    S_ = len(m.points) // 2
    assert m.report["uv_chart"] == "planar" and m.report["uv_interpolation_texels_max"] < 1e-3
    assert np.corrcoef(m.uvs[:S_, 0], m.points[:S_, 0])[0, 1] > 0.999
    assert np.corrcoef(m.uvs[:S_, 1], m.points[:S_, 1])[0, 1] > 0.999


def test_envelope_chart_covers_more_texels(leaf, leaf_mesh):
    """The default chart spends more of the texture on the leaf than the planar one."""
    cloud, fits = leaf
    flat = build_template_mesh(cloud, fits, MeshParams(vertex_budget=800, texture_size=128, uv_layout="fit"))
    env = leaf_mesh.report["alpha_coverage_front"]
    assert env > flat.report["alpha_coverage_front"] + 0.04 and env > 0.75


def test_texture_side_follows_the_texel_density():
    """The texture's side is the power of two giving ``texels_per_spacing`` texels per Gaussian
    spacing along the leaf, clamped to [MIN_TEXTURE_SIZE, texture_size]; 0 = texture_size."""
    from leaffit_usd.mesh.params import MIN_TEXTURE_SIZE, MeshParams

    p = MeshParams()
    # a 0.1 x 0.05 leaf (area 0.004): 4,000 Gaussians -> spacing 0.001 -> 200 texels -> 256
    assert p.texture_side(0.1, 0.004, 4000) == 256
    assert p.texture_side(0.1, 0.004, 64000) == 1024          # 800 texels -> 1024 (the cap)
    assert p.texture_side(0.1, 0.004, 16000) == 512
    assert p.texture_side(0.1, 0.004, 40) == MIN_TEXTURE_SIZE  # sparse: the floor
    assert MeshParams(texture_size=2048).texture_side(0.1, 0.004, 256000) == 2048
    assert MeshParams(texels_per_spacing=0).texture_side(0.1, 0.004, 40) == 1024
    assert p.texture_side(0.0, 0.0, 0) == 1024
    import pytest

    from leaffit_usd.errors import ParameterError
    with pytest.raises(ParameterError):
        MeshParams(texels_per_spacing=-1.0).validate()
