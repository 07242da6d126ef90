"""The template outline grown out to the splats' silhouette as a region
(leaffit_usd.mesh.outline_fit.silhouette_outline), not vertex by vertex along the normals."""
import numpy as np

from leaffit_usd.mesh import sheet_remesh
from leaffit_usd.mesh import surface as surf
from leaffit_usd.mesh.outline_fit import mask_outline, polygon_mask, silhouette_outline


def _sheet(poly: np.ndarray):
    """A flat, gently tilted height-field sheet (points (S, 3), faces) inside a CCW polygon."""
    import triangle as tr

    n = len(poly)
    seg = np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)
    t = tr.triangulate({"vertices": poly, "segments": seg}, "pqa0.0004Q")
    V2, F = np.asarray(t["vertices"]), np.asarray(t["triangles"], np.int64)
    return np.column_stack([V2, 0.1 * V2[:, 0]]), F


def _area_xy(points, faces) -> float:
    p = np.asarray(points, np.float64)[:, :2]
    f = np.asarray(faces, np.int64)
    a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    return 0.5 * float(np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])).sum())


def test_polygon_mask_and_mask_outline_of_a_disc():
    bounds, shape = (-1.0, 1.0, -1.0, 1.0), (400, 400)
    th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    disc = 0.7 * np.stack([np.cos(th), np.sin(th)], 1)
    m = polygon_mask(disc, bounds, shape)
    px = 2.0 / 400
    assert abs(m.sum() * px * px / (np.pi * 0.49) - 1) < 0.01
    assert not m[0, 0] and m[200, 200]
    assert m[200, 200 + int(0.65 / px)] and not m[200, 200 + int(0.75 / px)]   # +x is +col
    assert m[200 - int(0.65 / px), 200] and not m[200 - int(0.75 / px), 200]   # +y is -row
    ring = mask_outline(m | (np.arange(400)[None, :] < 3), bounds)   # a separate strip: ignored
    assert surf.signed_area_xy(ring) > 0                               # CCW
    assert abs(surf.signed_area_xy(ring) / (m.sum() * px * px) - 1) < 1e-9
    assert np.abs(np.linalg.norm(ring, axis=1) - 0.7).max() < 2 * px


def test_notched_outline_grows_all_round_and_fills_the_notch():
    """A leaf sheet with a deep, narrow notch (a gap between two centre rows) inside splats that
    cover the whole square: moving the outline's vertices along their normals, the notch's two
    sides met after one step and the growth stopped everywhere (lucky_bamboo's strap template:
    0.87 of the true area). The region grows all round and fills the notch."""
    notch = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.52, 1.0], [0.52, 0.3],
                      [0.48, 0.3], [0.48, 1.0], [0.0, 1.0]])
    P, F = _sheet(notch)
    # the splats' silhouette: the square grown by 0.05 on every side
    bounds = (-0.2, 1.2, -0.2, 1.2)
    H = W = 700
    px = 1.4 / W
    xc = -0.2 + (np.arange(W) + 0.5) * px
    yc = 1.2 - (np.arange(H) + 0.5) * px
    inside = ((np.abs(xc - 0.5) <= 0.55)[None, :] & (np.abs(yc - 0.5) <= 0.55)[:, None])
    alpha = np.where(inside, 0.9, 0.0)
    grown = surf.remesh_sheet(P, F, 600, grow=silhouette_outline(alpha, bounds, 0.5, 0.08))
    kept = surf.remesh_sheet(P, F, 600)
    assert grown is not None and kept is not None
    assert surf.sheet_checks(grown.points, grown.faces)["is_disk"]
    assert len(grown.points) <= 600
    assert _area_xy(kept.points, kept.faces) < 0.99
    a = _area_xy(grown.points, grown.faces)
    assert 0.98 * 1.21 < a < 1.01 * 1.21                      # the 1.1 x 1.1 silhouette
    xy = np.asarray(grown.points)[:, :2]
    assert (xy.min(0) < -0.04).all() and (xy.max(0) > 1.04).all()   # grown on every side
    # the notch is filled: points inside it are inside the grown outline
    loop = surf.boundary_loops(np.asarray(grown.faces), len(grown.points))
    ring = xy[max(loop, key=len)]
    assert sheet_remesh._points_in_polygon(np.array([[0.5, 0.9], [0.5, 0.5]]), ring).all()
    # heights off the old sheet continue its plane (z = 0.1 x)
    assert np.abs(np.asarray(grown.points)[:, 2] - 0.1 * xy[:, 0]).max() < 1e-6


def test_growth_stays_within_max_out_of_the_old_outline():
    """Splats far beyond the sheet (another leaf's overlap, a floater) are not reached: the
    region is limited to ``max_out`` from the smooth outline."""
    P, F = _sheet(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    bounds, H, W = (-1.0, 2.0, -1.0, 2.0), 600, 600
    alpha = np.full((H, W), 0.9)
    g = surf.remesh_sheet(P, F, 400, grow=silhouette_outline(alpha, bounds, 0.5, 0.1))
    xy = np.asarray(g.points)[:, :2]
    assert xy.min() > -0.1 - 0.03 and xy.max() < 1.1 + 0.03      # (the smooth outline: +-0.02)
    assert xy.min() < -0.09 and xy.max() > 1.09
