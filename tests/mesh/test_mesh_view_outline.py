"""The template sheet's view (leaffit_usd.mesh.view_frame) and its outline out to the splats'
silhouette (leaffit_usd.mesh.outline_fit)."""
import numpy as np
import pytest

from leaffit_usd.mesh.outline_fit import splat_alpha_image
from leaffit_usd.mesh.template import MeshParams, build_template_mesh
from leaffit_usd.mesh.template_gaussians import template_gaussians_local
from leaffit_usd.mesh.view_frame import sheet_view_rotation
from samples.synthetic.mesh import leaf_surface, synthetic_leaf

P = dict(vertex_budget=500, texture_size=128, lod_vertices=(128,))


def _area(points, faces) -> float:
    p, f = np.asarray(points, np.float64), np.asarray(faces, np.int64)
    return 0.5 * float(np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1).sum())


def _true_area(**kw) -> float:
    u, v = np.meshgrid(np.linspace(0, 1, 401), np.linspace(-1, 1, 201), indexing="ij")
    p = leaf_surface(u.ravel(), v.ravel(), **kw)[0].reshape(401, 201, 3)
    a, b = p[1:, :-1] - p[:-1, :-1], p[:-1, 1:] - p[:-1, :-1]
    c, d = p[1:, 1:] - p[1:, :-1], p[1:, 1:] - p[:-1, 1:]
    return 0.5 * float((np.linalg.norm(np.cross(a, b), axis=-1) + np.linalg.norm(np.cross(c, d), axis=-1)).sum())


def _edge_on(fits):
    """The same fit with its template frame turned 90 degrees about +X: +Z along the leaf's
    width, as PCA picks for an arched strap leaf whose arch is deeper than its half-width."""
    Q = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    for k in ("template_points", "template_controls", "targets"):
        setattr(fits, k, (np.asarray(getattr(fits, k), np.float64) @ Q.T).astype(np.float32))
    Qh = np.eye(4)
    Qh[:3, :3] = Q.T
    fits.leaf_to_working = fits.leaf_to_working @ Qh
    return fits


STRAP = dict(length=1.0, width=0.12, cup=0.0, arch=2.5)   # turns by 2 atan(2.5) = 136 degrees


@pytest.fixture(scope="module")
def strap():
    cloud, fits = synthetic_leaf(4000, seed=4, **STRAP)
    return cloud, _edge_on(fits)


def test_view_rotation_identity_for_a_leaf_seen_along_its_normal():
    _, fits = synthetic_leaf(3000, seed=1)
    assert np.array_equal(sheet_view_rotation(np.asarray(fits.template_points)), np.eye(3))


def test_view_rotation_looks_along_the_mean_normal_of_an_edge_on_strap(strap):
    _, fits = strap
    R = sheet_view_rotation(np.asarray(fits.template_points))
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
    # the strap's mean normal is the leaf frame's +Z, i.e. -Y of the turned template frame...
    assert abs(R[2] @ [0.0, -1.0, 0.0]) > 0.97
    # ...and the view keeps +X (base -> apex)
    assert R[0] @ [1.0, 0.0, 0.0] > 0.97


def test_edge_on_strap_gets_a_whole_sheet_and_a_full_texture(strap):
    """Seen along its width the strap is a wavy band: the sheet left a third of the leaf off
    (lucky_bamboo) and the texture held ~60 % leaf. Seen along its mean normal: all of it."""
    cloud, fits = strap
    m = build_template_mesh(cloud, fits, MeshParams(**P))
    r = m.report
    assert r["sheet_view_tilt_deg"] > 80
    assert r["is_disk"] and r["off_sheet_fraction"] < 0.01
    assert r["points_dist_max_rel"] < 0.02
    assert r["alpha_coverage_front"] > 0.7
    assert _area(m.sheet_points, m.sheet_faces) > 0.95 * _true_area(**STRAP)
    # front faces still face the front layer (+Z of the leaf: -Y of the turned frame)
    S = len(m.points) // 2
    assert (np.asarray(m.normals[:S]) @ [0.0, -1.0, 0.0]).mean() > 0.5 or \
           (np.asarray(m.normals[:S]) @ [0.0, 1.0, 0.0]).mean() > 0.5


def test_only_a_leaf_seen_face_on_gets_the_splat_cut_out(strap, leaf_mesh):
    """A strap seen in a tilted view has steep parts whose splats, seen nearly edge-on, leave
    gaps that are no edge of the leaf: its alpha is the sheet's silhouette, opaque inside and
    nothing outside (no anti-aliased cut-out rim). A leaf seen face-on keeps the cut-out, with
    its rim."""
    cloud, fits = strap
    m = build_template_mesh(cloud, fits, MeshParams(**P))
    assert m.report["sheet_view_tilt_deg"] > 80 and m.report["alpha_cut_out"] is False
    for tex in (m.front_texture, m.back_texture):
        a = np.asarray(tex)[..., 3]
        assert set(np.unique(a).tolist()) <= {0, 255}
        assert (a == 255).mean() > 0.7
    assert np.array_equal(np.asarray(m.front_texture)[..., 3], np.asarray(m.back_texture)[:, ::-1, 3])
    assert leaf_mesh.report["alpha_cut_out"] is True
    rim = np.asarray(leaf_mesh.front_texture)[..., 3]
    assert ((rim > 0) & (rim < 255)).any()


def test_outline_reaches_the_splat_silhouette():
    """The centres stop short of the edge: the sheet through them is smaller than what the
    splats show; the grown outline covers the splats' alpha > 0.5 silhouette, reaching a little
    past its bumps (a running maximum: the alpha cut-out trims the rest, it cannot add)."""
    cloud, fits = synthetic_leaf(4000, seed=2)
    means, cov, _, opac = template_gaussians_local(cloud, fits)
    alpha, b = splat_alpha_image(means, cov, opac, pad=0.05, long_side=1024)
    px = (b[1] - b[0]) / alpha.shape[1]
    silhouette = float((alpha > 0.5).sum()) * px * px

    def xy_area(m):
        p = np.asarray(m.sheet_points, np.float64).copy()
        p[:, 2] = 0.0
        return _area(p, m.sheet_faces)

    grown = xy_area(build_template_mesh(cloud, fits, MeshParams(**P)))
    kept = xy_area(build_template_mesh(cloud, fits, MeshParams(**P, outline_grow=0.0)))
    assert 0.99 < grown / silhouette < 1.06
    assert kept / silhouette < 0.95
