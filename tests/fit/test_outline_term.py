"""The refinement's silhouette-outline term (``fit.register._silhouette_outline`` and the outline
Chamfer in ``fit.gauss_newton.refine_targets``): each leaf's outline where its splats end, in template units, and the
deformed template's outline drawn onto it."""
import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.fit.mls import deform_points
from leaffit_usd.fit.params import FitParams
from leaffit_usd.fit.gauss_newton import refine_targets as _refine
from leaffit_usd.fit.register import _Leaf, _silhouette_outline
from leaffit_usd.geometry.sampling import farthest_point_sampling


class _Covs:
    """covs[idx] -> flat isotropic splats (std ``s`` in the plane, s / 10 across), working frame."""

    def __init__(self, s):
        self.s = s

    def __getitem__(self, idx):
        return np.tile(np.diag([self.s ** 2, self.s ** 2, (0.1 * self.s) ** 2]), (len(idx), 1, 1))


def _blade(a, b, n, rng, bulge=0.0):
    """n uniform points of an elliptic blade from the origin (petiole base) to (2a, 0), half
    width b, one side bulged out by ``bulge`` near its middle; z = 0."""
    pts = []
    while sum(len(q) for q in pts) < n:
        q = np.c_[rng.uniform(0, 2 * a, n), rng.uniform(-b - bulge, b + bulge, n)]
        half = b * np.sqrt(np.clip(1 - ((q[:, 0] - a) / a) ** 2, 0, 1))
        half_y = half + np.where(q[:, 1] > 0, bulge * np.exp(-((q[:, 0] - a) / (0.4 * a)) ** 2), 0)
        pts.append(q[np.abs(q[:, 1]) <= half_y])
    q = np.concatenate(pts)[:n]
    return np.c_[q, np.zeros(n)]


def _leaf(label, pts, scale=1.0):
    n = len(pts)
    return _Leaf(label, np.arange(n), pts, np.tile([0, 0, 1.0], (n, 1)), np.eye(4),
                 1.0, apex=pts[np.argmax(pts[:, 0])], scale=scale)


def test_silhouette_outline_is_the_splats_edge_in_template_units():
    rng = np.random.default_rng(0)
    r = np.sqrt(rng.uniform(0, 1, 4000)) * 0.1
    t = rng.uniform(0, 2 * np.pi, 4000)
    disk = np.c_[r * np.cos(t), r * np.sin(t), np.zeros(4000)]
    op = np.full(4000, 0.8)
    out = _silhouette_outline(_leaf(1, disk), _Covs(0.003), op, 0.5, disk)
    rad = np.hypot(out[:, 0], out[:, 1])
    assert 0.1 < np.median(rad) < 0.1 + 3 * 0.003, np.median(rad)     # past the centres, by a splat
    assert rad.min() > 0.09                                             # only the rim: holes filled
    ang = np.floor((np.arctan2(out[:, 1], out[:, 0]) + np.pi) / (2 * np.pi) * 36).astype(int)
    assert len(np.unique(ang)) == 36                                    # all round
    # the same leaf twice as large (its splats too): the same outline in template units
    big = _silhouette_outline(_leaf(2, 2 * disk, scale=2.0), _Covs(0.006), op, 0.5, 2 * disk)
    assert abs(np.median(np.hypot(big[:, 0], big[:, 1])) - np.median(rad)) < 0.002
    assert _silhouette_outline(_leaf(3, disk[:2]), _Covs(0.003), op, 0.5, disk[:2]).shape == (0, 2)


def test_refinement_draws_the_template_outline_onto_the_leafs():
    """A leaf wider than the template and bulged on one side: the surface terms alone leave the
    deformed template's outline inside the leaf's (its interior points all have partners); with
    the outline term the outlines' Chamfer falls and the width comes out right."""
    rng = np.random.default_rng(1)
    X = _blade(0.2, 0.08, 3000, rng)
    Y = _blade(0.2, 0.09, 3400, rng, bulge=0.03)
    T, tgt = _leaf(1, X), _leaf(2, Y)
    op = np.full(len(Y), 0.8)
    oT, oY = (_silhouette_outline(lf, _Covs(0.004), op, 0.5, lf.local) for lf in (T, tgt))
    p = X[farthest_point_sampling(X, 32, start=0)]
    sigma = 0.07
    res = {}
    for w in (0.0, 1.0):
        prm = FitParams(sigma=sigma, refine=10, outline_weight=w)
        q = _refine(T, [tgt], p, p[None].copy(), prm, [oT, oY])[0]
        z = X[cKDTree(X[:, :2]).query(oT)[1], 2]
        do = deform_points(p, q, np.c_[oT, z], sigma)[:, :2]
        cham = 0.5 * (cKDTree(oY).query(do)[0].mean() + cKDTree(do).query(oY)[0].mean())
        res[w] = (cham, np.ptp(do[:, 1]) / np.ptp(oY[:, 1]))
    # (Marquardt-damped Gauss-Newton: the surface terms alone reach 0.0021, the outline term 0.0018)
    assert res[1.0][0] < 0.9 * res[0.0][0], res
    assert abs(res[1.0][1] - 1) < 0.03, res
    # outline_weight=0 is the refinement without outlines, exactly
    q0 = _refine(T, [tgt], p, p[None].copy(), FitParams(sigma=sigma, refine=3, outline_weight=0.0),
                 [oT, oY])
    q1 = _refine(T, [tgt], p, p[None].copy(), FitParams(sigma=sigma, refine=3))
    assert np.array_equal(q0, q1)


def test_outline_weight_must_be_a_number_at_least_zero():
    import pytest

    from leaffit_usd.errors import ParameterError

    FitParams(outline_weight=0.0).validate()
    with pytest.raises(ParameterError):
        FitParams(outline_weight=-1.0).validate()


def test_outline_term_only_for_leaves_seen_face_on():
    """An arched strap leaf whose fit frame sees it edge-on (normals across the frame's +Z) gets
    no outline term: its xy silhouette is the arch's side view."""
    from leaffit_usd.fit.register import _seen_face_on

    rng = np.random.default_rng(2)
    flat = _blade(0.2, 0.08, 500, rng)
    tilted = _leaf(2, flat)
    tilted.normals = np.tile([0.0, np.sin(np.radians(50)), np.cos(np.radians(50))], (500, 1))
    curled = _leaf(3, flat)
    t = np.radians(rng.uniform(-25, 25, 500))                       # a curl, +-25 degrees
    curled.normals = np.c_[np.zeros(500), np.sin(t), np.cos(t) * rng.choice([-1, 1], 500)]
    assert _seen_face_on(_leaf(1, flat)) and _seen_face_on(curled)
    assert not _seen_face_on(tilted)
