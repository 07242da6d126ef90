"""Sheet reconstruction and its topology checks (leaffit_usd.mesh.surface)."""
import numpy as np
import pytest

from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.mesh import sheet_topology
from leaffit_usd.mesh import surface as S


def cross2(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def grid_sheet(n=8, hole=False):
    """A CCW triangulated n x n grid in the xy plane (optionally with one interior quad removed)."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    p = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(x.ravel())], 1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            if hole and i in (3, 4) and j in (3, 4):
                continue
            f += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return p, np.asarray(f, np.int64)


@pytest.fixture(scope="module")
def samples(leaf):
    _, fits = leaf
    pts = fits.template_points.astype(float)
    return pts[farthest_point_sampling(pts, 800)]


@pytest.mark.parametrize("fn", [S.bpa_sheet, S.planar_sheet])
def test_sheet_is_a_thin_disk(samples, fn):
    sheet = fn(samples)
    checks = S.sheet_checks(sheet.points, sheet.faces)
    assert checks["is_disk"], checks
    assert checks["fold_ratio"] < 0.01
    assert len(sheet.points) <= len(samples)
    # vertices are samples, unchanged (hole filling adds none)
    assert np.allclose(sheet.points, samples[sheet.sample_index])
    # CCW seen from +Z: every face's projected area positive for this near-flat leaf
    n = np.cross(sheet.points[sheet.faces[:, 1]] - sheet.points[sheet.faces[:, 0]],
                 sheet.points[sheet.faces[:, 2]] - sheet.points[sheet.faces[:, 0]])
    assert (n[:, 2] > 0).mean() > 0.99


def test_fill_holes_closes_interior_hole_without_new_vertices():
    p, f = grid_sheet(hole=True)
    assert S.sheet_checks(p, f)["boundary_loops"] == 2
    f2, before, after = S.fill_holes(p, f)
    assert (before, after) == (1, 0)
    c = S.sheet_checks(p, f2)
    assert c["is_disk"], c
    assert f2.max() < len(p)
    # the filled area equals the hole's area (2 x 2 quads = 4 in xy)
    a = lambda ff: 0.5 * cross2(p[ff[:, 1], :2] - p[ff[:, 0], :2], p[ff[:, 2], :2] - p[ff[:, 0], :2]).sum()
    assert a(f2) - a(f) == pytest.approx(4.0)


def test_checks_reject_two_components():
    p, f = grid_sheet(4)
    p2 = np.concatenate([p, p + [10, 0, 0]])
    f2 = np.concatenate([f, f + len(p)])
    c = S.sheet_checks(p2, f2)
    assert c["components"] == 2 and not c["is_disk"]


def test_checks_reject_double_wall():
    p, f = grid_sheet(5)
    p2 = np.concatenate([p, p + [0, 0, 0.01]])
    f2 = np.concatenate([f, f + len(p)])
    # one component: join the two layers along one rim edge strip so only the wall test fails
    c = S.sheet_checks(p2, f2)
    assert not c["is_disk"]
    assert S.fold_ratio(p2, f2) > 0.9


def test_checks_reject_nonmanifold_edge_and_hole():
    p, f = grid_sheet(4)
    extra = np.array([[0.5, -1.0, 0.0]])
    p2 = np.concatenate([p, extra, extra + [0, 0, 1]])
    # faces 0 and 1 share the edge (0, 5); add two more faces on it
    f2 = np.concatenate([f, [[0, 5, len(p)], [5, 0, len(p) + 1]]])
    assert S.sheet_checks(p2, f2)["nonmanifold_edges"] >= 1
    assert not S.sheet_checks(p2, f2)["is_disk"]
    ph, fh = grid_sheet(hole=True)
    assert not S.sheet_checks(ph, fh)["is_disk"]


def test_repairs_remove_nonmanifold_edges_and_islands():
    p, f = grid_sheet(6)
    extra = np.array([[0.5, 0.5, 1.0], [20.0, 20.0, 0.0], [21.0, 20.0, 0.0], [20.0, 21.0, 0.0]])
    p2 = np.concatenate([p, extra])
    n = len(p)
    f2 = np.concatenate([f, [[0, 7, n]], [[n + 1, n + 2, n + 3]]])
    f2 = S.fix_nonmanifold_edges(p2, f2)
    assert S.sheet_checks(p2, f2)["nonmanifold_edges"] == 0
    f3, removed = S.largest_component(p2, f2)
    assert removed >= 1 and f3.max() < n + 1


def test_ear_clip_concave_polygon():
    poly = np.array([[0, 0], [4, 0], [4, 4], [2, 1.5], [0, 4]], float)
    tris = sheet_topology._ear_clip(poly)
    assert len(tris) == 3
    area = sum(0.5 * cross2(poly[b] - poly[a], poly[c] - poly[a]) for a, b, c in tris)
    assert area == pytest.approx(S.signed_area_xy(poly))
    assert all(cross2(poly[b] - poly[a], poly[c] - poly[a]) > 0 for a, b, c in tris)


def test_planar_sheet_fills_capture_holes():
    from samples.synthetic.mesh import synthetic_leaf

    _, fits = synthetic_leaf(2500, seed=3, holes=True)
    pts = fits.template_points.astype(float)
    sheet = S.planar_sheet(pts[farthest_point_sampling(pts, 600)])
    c = S.sheet_checks(sheet.points, sheet.faces)
    assert c["is_disk"] and c["boundary_loops"] == 1
    assert sheet.info["holes_before"] >= 1


def test_degenerate_inputs_do_not_raise():
    line = np.stack([np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)], 1)
    sheet = S.planar_sheet(line)
    assert len(sheet.faces) == 0
    q = S.fallback_quad(line)
    assert S.sheet_checks(q.points, q.faces)["is_disk"]
    assert S.fallback_quad(np.zeros((0, 3))).faces.shape == (2, 3)


def test_fill_notches_closes_sharp_rim_notch():
    # a fan of a half-disc with one thin wedge missing at the rim
    ang = np.linspace(0, np.pi, 13)
    rim = np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)
    p = np.concatenate([[[0.0, 0.0, 0.0]], rim, [[0.0, 0.0, 0.0]]])[:-1]
    f = np.array([[0, i, i + 1] for i in range(1, 13)], np.int64)
    # notch: move the centre of one rim edge's triangle apex outwards -> drop that face, add a
    # vertex slightly inside so the rim has a sharp reflex corner
    p = np.concatenate([p, [[0.5 * np.cos(ang[6] + 0.13), 0.5 * np.sin(ang[6] + 0.13), 0.0]]])
    v = len(p) - 1
    f = np.concatenate([f[f[:, 1] != 7], [[0, 7, v], [0, v, 8]]])
    before = S.sheet_checks(p, f)
    assert before["is_disk"]
    f2, added = S.fill_notches(p, f, max_gap=1.0)
    assert added == 1
    after = S.sheet_checks(p, f2)
    assert after["is_disk"] and len(f2) == len(f) + 1
