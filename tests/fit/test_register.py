"""fit_leaves: the LeafFits contract, optimisation gain, degenerate leaves, template choice."""
import logging

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.mls import deform_points
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.fit.params import FitParams
from leaffit_usd.fit.adam import Adam
from leaffit_usd.fit.register import fit_leaves
from leaffit_usd.fit.result import LeafFits
from samples.synthetic.fit import make_plant
from leaffit_usd.segment.result import Segmentation
from leaffit_usd.serialize import load_value, save_value

FAST = dict()                  # the default fit (Gauss-Newton) is fast enough for the tests


@pytest.fixture(scope="module")
def plant():
    return make_plant(n_leaves=5, n_gaussians=12000, seed=3)


@pytest.fixture(scope="module")
def fits(plant):
    torch.set_num_threads(1)
    return fit_leaves(plant.cloud, plant.seg, FitParams(**FAST))


@pytest.fixture(scope="module")
def fits_noopt(plant):
    return fit_leaves(plant.cloud, plant.seg, FitParams(optimize=False))


def _deformed_working(f: LeafFits, j: int, pts_local=None):
    """The LeafFits contract: leaf_j(v) = leaf_to_working[j] @ MLS(p -> q_j)(v)."""
    v = f.template_points if pts_local is None else pts_local
    d = deform_points(f.template_controls, f.targets[j], v, f.sigma, f.reg)
    m = f.leaf_to_working[j]
    return d @ m[:3, :3].T + m[:3, 3]


def _nn_error(plant, f, j):
    pts = plant.cloud.means[plant.seg.leaf_indices(j + 1)]
    d, _ = cKDTree(pts).query(_deformed_working(f, j))
    return float(np.median(d))


def test_fits_shapes_and_contract(plant, fits):
    L, K = plant.seg.n_leaves, FitParams().K
    assert fits.targets.shape == (L, K, 3) and fits.targets.dtype == np.float32
    assert fits.template_controls.shape == (K, 3)
    assert fits.leaf_to_working.shape == (L, 4, 4)
    assert fits.leaf_labels.tolist() == list(range(1, L + 1))
    assert np.isfinite(fits.targets).all() and not fits.fallback.any()
    assert 1 <= fits.template_label <= L
    assert (plant.seg.labels[fits.template_gaussians] == fits.template_label).all()
    # leaf_to_working is a similarity: R^T R = s^2 I with s = size relative to the template
    for j in range(L):
        a = fits.leaf_to_working[j, :3, :3]
        s2 = (a.T @ a)[0, 0]
        np.testing.assert_allclose(a.T @ a, s2 * np.eye(3), atol=1e-9)
        assert np.linalg.det(a) > 0
        # origin at the petiole base, +X towards the apex
        base = plant.cloud.means[plant.seg.leaf_base[j]]
        tip = plant.cloud.means[plant.seg.leaf_tip[j]]
        np.testing.assert_allclose(fits.leaf_to_working[j, :3, 3], base, atol=1e-6)
        assert (tip - base) @ a[:, 0] > 0
        assert a[2, 2] > -1e-6 or abs(a[2, 2]) < 0.1 * np.sqrt(s2)   # normal to the upper side
    t = fits.template_label - 1
    np.testing.assert_allclose(fits.targets[t], fits.template_controls)
    assert np.linalg.det(fits.leaf_to_working[t, :3, :3]) == pytest.approx(1.0)


def test_deformed_template_lies_on_each_leaf(plant, fits):
    """Every leaf, rebuilt from the template through LeafFits, sits on that leaf's Gaussians."""
    for j in range(plant.seg.n_leaves):
        pts = plant.cloud.means[plant.seg.leaf_indices(j + 1)]
        size = np.ptp(pts, axis=0).max()
        err = _nn_error(plant, fits, j)
        assert err < 0.03 * size, (j, err, size)
        assert fits.errors[j] < 0.05 * size


def test_optimisation_beats_initial_correspondence(plant, fits, fits_noopt):
    t = fits.template_label - 1
    others = [j for j in range(plant.seg.n_leaves) if j != t]
    assert fits.errors[others].mean() < 0.85 * fits_noopt.errors[others].mean()
    # same frames and template either way
    np.testing.assert_allclose(fits.leaf_to_working, fits_noopt.leaf_to_working)


def test_deterministic_and_serialisable(plant, fits, tmp_path):
    again = fit_leaves(plant.cloud, plant.seg, FitParams(**FAST))
    np.testing.assert_array_equal(again.targets, fits.targets)
    save_value(fits, tmp_path / "fits.npz")
    back = load_value(LeafFits, tmp_path / "fits.npz")
    np.testing.assert_array_equal(back.targets, fits.targets)
    assert back.params["K"] == FitParams().K and back.template_label == fits.template_label


def test_explicit_template_and_bad_parameters(plant):
    f = fit_leaves(plant.cloud, plant.seg, FitParams(template="2", optimize=False))
    assert f.template_label == 2
    for bad in [dict(template=0), dict(template="leaf"), dict(K=0), dict(lr=-1.0),
                dict(steps=1.5), dict(lam=float("nan")), dict(max_scale_ratio=0.5)]:
        with pytest.raises(ParameterError):
            fit_leaves(plant.cloud, plant.seg, FitParams(**{"optimize": False, **bad}))
    with pytest.raises(ParameterError):
        fit_leaves(plant.cloud, plant.seg, FitParams(template=99, optimize=False))
    seg = Segmentation(labels=plant.seg.labels[:-1], root_index=0)
    with pytest.raises(ParameterError):
        fit_leaves(plant.cloud, seg)


def test_degenerate_leaves_fall_back_rigid(plant, caplog):
    """Fewer Gaussians than K, a collinear 'leaf' (stem points), a leaf 6x larger: warning,
    rigid fit (targets = template controls), finite everywhere; the others still fit."""
    cloud = plant.cloud.subset(np.arange(len(plant.cloud)))
    labels = plant.seg.labels.copy()
    L = plant.seg.n_leaves
    means = cloud.means.astype(np.float64)
    stem = np.flatnonzero(labels == 0)
    labels[stem[:200]] = L + 1                                  # collinear
    few = plant.seg.leaf_indices(1)[:10]
    labels[few] = L + 2                                         # 10 < K Gaussians
    big = plant.seg.leaf_indices(2)
    base = means[plant.seg.leaf_base[1]]
    means[big] = base + (means[big] - base) * 6.0               # 6x the size
    cloud.means = means.astype(np.float32)
    seg = Segmentation(labels=labels, root_index=0,
                       leaf_tip=np.r_[plant.seg.leaf_tip, stem[199], few[-1]],
                       leaf_base=np.r_[plant.seg.leaf_base, stem[0], few[0]])
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        f = fit_leaves(cloud, seg, FitParams(**FAST))
    assert np.isfinite(f.targets).all() and np.isfinite(f.leaf_to_working).all()
    assert np.isfinite(f.errors).all()
    for lab in (2, L + 1, L + 2):
        assert f.fallback[lab - 1], lab
        np.testing.assert_allclose(f.targets[lab - 1], f.template_controls)
        assert f"leaf {lab} is degenerate" in caplog.text
    assert not f.fallback[[0, 2, 3, 4]].any()
    assert f.template_label not in (2, L + 1, L + 2)


def test_auto_template_avoids_incomplete_leaf():
    """The median-sized leaf with half its blade missing is not the auto template."""
    p = make_plant(n_leaves=5, n_gaussians=12000, seed=3, size_spread=0.0)
    base = fit_leaves(p.cloud, p.seg, FitParams(optimize=False))
    t = base.template_label
    # cut away one side of the chosen template (local y > 0)
    idx = p.seg.leaf_indices(t)
    m = base.leaf_to_working[t - 1]
    local = (p.cloud.means[idx] - m[:3, 3]) @ m[:3, :3]
    labels = p.seg.labels.copy()
    labels[idx[local[:, 1] > 0.0]] = 0
    seg = Segmentation(labels=labels, root_index=0, leaf_tip=p.seg.leaf_tip, leaf_base=p.seg.leaf_base)
    f = fit_leaves(p.cloud, seg, FitParams(optimize=False))
    assert f.template_label != t


def test_no_leaves_gives_empty_fits(plant):
    seg = Segmentation(labels=np.zeros(len(plant.cloud), np.int32), root_index=0)
    f = fit_leaves(plant.cloud, seg)
    assert f.targets.shape == (0, FitParams().K, 3) and f.leaf_to_working.shape == (0, 4, 4)


def test_adam_matches_torch():
    torch.manual_seed(0)
    a = torch.randn(5, 3, requires_grad=True)
    b = a.detach().clone().requires_grad_(True)
    o1, o2 = Adam(a, lr=7e-3), torch.optim.Adam([b], lr=7e-3)
    for _ in range(30):
        for x, o in ((a, o1), (b, o2)):
            x.grad = None
            ((x ** 2).sum() + x.sin().sum()).backward()
            o.step()
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_all_leaves_degenerate_is_finite(plant, caplog):
    """Only tiny leaves: warnings, rigid placement, no NaN, no crash."""
    labels = np.zeros(len(plant.cloud), np.int32)
    for lab in (1, 2):
        labels[plant.seg.leaf_indices(lab)[:5]] = lab
    seg = Segmentation(labels=labels, root_index=0)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        f = fit_leaves(plant.cloud, seg, FitParams(**FAST))
    assert f.fallback.all() and np.isfinite(f.targets).all() and np.isfinite(f.leaf_to_working).all()
    assert "degenerate" in caplog.text


def test_refinement_recovers_a_known_mls_deformation():
    """Known answer: the target leaf IS the template deformed by an MLS field p -> q_true (a
    bend, a twist and a local bump). From q0 = p the Gauss-Newton refinement must land the
    deformed template on the target to < 8 % of the initial error, and lower the paper's
    objective (Chamfer) monotonically enough that 10 iterations beat 2."""
    from leaffit_usd.fit.denoise import denoise_leaf
    from leaffit_usd.fit.gauss_newton import refine_targets
    from leaffit_usd.fit.register import _Leaf

    rng = np.random.default_rng(0)
    u = rng.uniform(0, 0.4, 6000)
    w = rng.uniform(-1, 1, 6000) * 0.12 * np.sin(np.pi * u / 0.4)
    X = np.c_[u, w, 0.02 * w**2 / 0.12]                               # template sheet
    p = X[farthest_point_sampling(X, 32, start=0)]
    q_true = p + np.c_[0.01 * np.sin(6 * p[:, 1]), 0.02 * p[:, 1],
                       0.25 * p[:, 0] ** 2 + 0.15 * p[:, 0] * p[:, 1]
                       + 0.01 * np.exp(-((p[:, 0] - 0.2) ** 2 + p[:, 1] ** 2) / 0.003)]
    Y = deform_points(p, q_true, X, 0.05)
    res = denoise_leaf(Y)                                    # the target's local-plane normals
    ident = np.eye(4)
    T = _Leaf(1, np.arange(len(X)), X, np.tile([0, 0, 1.0], (len(X), 1)), ident, 1.0)
    tgt = _Leaf(2, np.flatnonzero(res.keep), Y[res.keep], res.normals, ident, 1.0)
    errs = {}
    for n in (2, 10):
        q = refine_targets(T, [tgt], p, p[None].copy(), FitParams(sigma=0.05, refine=n))[0]
        d, _ = cKDTree(Y).query(deform_points(p, q, X, 0.05))
        errs[n] = d.mean()
    d0, _ = cKDTree(Y).query(X)
    assert errs[10] < 0.08 * d0.mean(), (errs, d0.mean())   # floor: ~1/4 of the point spacing
    assert errs[10] < errs[2]


def test_convert_fit_flags_reach_fit_params(capsys):
    """--paper-fit gives the paper's registration (sigma 0.1, Adam only), explicit flags win over
    it, --sigma auto is ours, and a bad --sigma is a one-line usage error (exit 2)."""
    import argparse

    from leaffit_usd.cli import main
    from leaffit_usd.commands import convert

    def fit_of(*argv):
        p = argparse.ArgumentParser()
        convert.add_arguments(p)
        return convert.options_from_args(p.parse_args(["x.ply", "-o", "y.usda", *argv])).fit

    assert fit_of() == FitParams() and FitParams().sigma == "auto" and FitParams().refine > 0
    assert fit_of("--paper-fit") == FitParams.paper() == FitParams(
        K=32, sigma=0.1, steps=200, lr=7e-3, refine=0, reg=0.01, start="assignment")
    assert fit_of("--paper-fit", "--refine", "3").refine == 3
    assert fit_of("--sigma", "AUTO").sigma == "auto" and fit_of("--sigma", "0.05").sigma == 0.05
    with pytest.raises(SystemExit) as e:
        main(["convert", "x.ply", "-o", "y.usda", "--sigma", "wide"])
    assert e.value.code == 2 and len(capsys.readouterr().err.strip().splitlines()) == 1
    for bad in (dict(sigma="wide"), dict(sigma=-1.0), dict(refine=-1), dict(landmark_weight=-1.0),
                dict(start="random"), dict(damping_start=-1.0)):
        with pytest.raises(ParameterError):
            FitParams(**bad).validate()


def test_leaf_gaussian_cap_keeps_the_fit(plant, fits):
    """A leaf capped to a few hundred Gaussians fits about as well as with all of them; the
    template still bakes from (nearly) all of its leaf's Gaussians."""
    torch.set_num_threads(1)
    capped = fit_leaves(plant.cloud, plant.seg,
                        FitParams(**FAST, leaf_gaussians=600, template=int(fits.template_label)))
    sizes = np.bincount(plant.seg.labels)[1:]
    assert sizes.min() > 600  # the cap really applies to every leaf
    for j in range(plant.seg.n_leaves):
        pts = plant.cloud.means[plant.seg.leaf_indices(j + 1)]
        size = np.ptp(pts, axis=0).max()
        assert _nn_error(plant, capped, j) < 0.03 * size
        assert abs(_nn_error(plant, capped, j) - _nn_error(plant, fits, j)) < 0.01 * size
    # the bake set: far more than the cap, close to the uncapped kept set
    full, cut = set(fits.template_gaussians.tolist()), set(capped.template_gaussians.tolist())
    assert len(cut) > 600 and len(full & cut) > 0.95 * len(full)
    with pytest.raises(ParameterError):
        fit_leaves(plant.cloud, plant.seg, FitParams(leaf_gaussians=-1))


def test_leaf_gaussian_cap_bounds_what_the_fit_reads(plant, monkeypatch):
    """The cap holds: denoising (and so the frame, the refinement and the error) sees at most
    ``leaf_gaussians`` of a leaf, and covariances are computed only for the Gaussians rendered
    (the cost of a 5M-Gaussian capture's fit must not grow with its leaves)."""
    import leaffit_usd.fit.register as reg

    seen, cov_rows = [], []
    real_dn, real_cov = reg.denoise_leaf, reg.Covariances.__getitem__
    monkeypatch.setattr(reg, "denoise_leaf", lambda pts, p: seen.append(len(pts)) or real_dn(pts, p))

    def spy_cov(self, idx):
        out = real_cov(self, idx)
        cov_rows.append(len(out))
        assert np.array_equal(out, self.cloud.covariances()[np.asarray(idx)].astype(np.float64))
        return out

    monkeypatch.setattr(reg.Covariances, "__getitem__", spy_cov)
    fit_leaves(plant.cloud, plant.seg, FitParams(steps=1, refine=0, leaf_gaussians=500, max_points=64))
    assert len(seen) == plant.seg.n_leaves and max(seen) == 500
    assert cov_rows and max(cov_rows) <= 64


def test_a_capped_fit_does_not_depend_on_the_file_order(plant):
    """The same capture in another file order (a format converter may sort the splats, e.g. by
    Morton code) fits the same capped subsets, so the same leaves: the subset is drawn in
    position order, not by index."""
    from dataclasses import replace

    n = len(plant.cloud.means)
    perm = np.random.default_rng(5).permutation(n)
    inv = np.argsort(perm)                                  # old index -> new index
    seg = plant.seg
    seg_p = replace(seg, labels=seg.labels[perm], root_index=int(inv[seg.root_index]),
                    apex_indices=inv[seg.apex_indices], leaf_tip=inv[seg.leaf_tip],
                    leaf_base=inv[seg.leaf_base], tree_nodes=inv[seg.tree_nodes],
                    dist_root=seg.dist_root[perm] if len(seg.dist_root) == n else seg.dist_root)
    params = FitParams(optimize=False, leaf_gaussians=600)
    a = fit_leaves(plant.cloud, seg, params)
    b = fit_leaves(plant.cloud.subset(perm), seg_p, params)
    assert np.bincount(seg.labels)[1:].min() > 600          # every leaf is capped
    assert a.template_label == b.template_label
    np.testing.assert_allclose(b.leaf_to_working, a.leaf_to_working, atol=1e-9)
    assert np.array_equal(np.sort(perm[b.template_gaussians]), np.sort(a.template_gaussians))
    # the same control points (FPS returns them in index order, so in another order) and the
    # same deformation of the template: the same leaves
    order = cKDTree(a.template_controls).query(b.template_controls)[1]
    np.testing.assert_allclose(b.template_controls, a.template_controls[order], atol=1e-6)
    for j in range(plant.seg.n_leaves):
        np.testing.assert_allclose(_deformed_working(b, j, a.template_points),
                                   _deformed_working(a, j), atol=1e-5)


def test_gaussians_left_out_of_the_cap_keep_the_denoisers_plane_test():
    """A leaf larger than the cap: the Gaussians left out of its subset join the template's set
    only when they lie on the blade (within the denoiser's residual limit of their nearest kept
    subset Gaussian's plane), so fuzz off the blade stays out at any density."""
    from leaffit_usd.fit.denoise import DenoiseParams
    from leaffit_usd.fit.register import _all_kept, _prepare_leaf
    from leaffit_usd.segment.result import Segmentation

    rng = np.random.default_rng(5)
    r, a = 0.2 * np.sqrt(rng.random(20000)), rng.random(20000) * 2 * np.pi
    blade = np.stack([r * np.cos(a), r * np.sin(a), rng.normal(0, 0.0005, 20000)], 1)
    fuzz = blade[:200] + np.array([0.0, 0.0, 0.03])          # 1 % of the leaf, 3 cm above it
    means = np.concatenate([blade, fuzz])
    seg = Segmentation(labels=np.ones(len(means), np.int32), root_index=0,
                       leaf_base=np.array([int(np.argmin(means[:, 0]))]),
                       leaf_tip=np.array([int(np.argmax(means[:, 0]))]))
    lf = _prepare_leaf(1, means, seg, DenoiseParams(), cap=2000, seed=0)
    assert len(lf.sampled) == 2000 and np.isfinite(lf.residual_limit)
    kept = _all_kept(lf, means)
    assert np.isin(np.arange(20000, 20200), kept).sum() == 0         # no fuzz comes back
    assert np.isin(np.arange(20000), kept).mean() > 0.97             # the blade does


def test_a_capped_leafs_silhouette_outline_is_the_whole_leafs():
    """The outline term's silhouette of a leaf capped to a tenth (a fiftieth) of its Gaussians
    is the whole leaf's: it renders every Gaussian the denoiser keeps, so it neither shrinks
    and frays (the subset at its own size) nor blurs outwards (the subset widened) with the
    capture's density."""
    from leaffit_usd.fit.denoise import DenoiseParams
    from leaffit_usd.fit.adam import Covariances as _Covariances
    from leaffit_usd.fit.register import _prepare_leaf, _silhouette_outline
    from leaffit_usd.segment.result import Segmentation
    from leaffit_usd.splats.cloud import GaussianCloud

    rng = np.random.default_rng(2)
    n = 20000
    r, a = 0.2 * np.sqrt(rng.random(n)), rng.random(n) * 2 * np.pi
    means = np.stack([1.5 * r * np.cos(a), r * np.sin(a), rng.normal(0, 0.0003, n)], 1)
    spacing = np.sqrt(np.pi * 0.3 * 0.2 / n)
    cloud = GaussianCloud.from_activated(means, np.tile([0.6 * spacing, 0.6 * spacing, 1e-5], (n, 1)),
                                         np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, 0.9))
    seg = Segmentation(labels=np.ones(n, np.int32), root_index=0,
                       leaf_base=np.array([int(np.argmin(means[:, 0]))]),
                       leaf_tip=np.array([int(np.argmax(means[:, 0]))]))
    covs, opac = _Covariances(cloud), np.full(n, 0.9)

    def outline(cap):
        lf = _prepare_leaf(1, cloud.means.astype(np.float64), seg, DenoiseParams(), cap=cap, seed=0)
        assert lf.capped == (cap > 0)
        return _silhouette_outline(lf, covs, opac, 0.5, cloud.means.astype(np.float64)) * lf.scale

    full = outline(0)
    px = np.ptp(full, 0).max() / 256
    for cap in (n // 10, n // 50):
        o = outline(cap)
        assert np.allclose(np.ptp(o, 0), np.ptp(full, 0), rtol=0.005)
        assert len(o) < 1.1 * len(full)                     # one clean rim, not a frayed one
        # the same rim: within a pixel on average both ways (the subset widened by the inverse
        # share, as before: 1.5-4.4 px and 1-5 % wider; at its own size: a few specks)
        assert cKDTree(full).query(o)[0].mean() < px and cKDTree(o).query(full)[0].mean() < px


def _tip_blade(rng, n=20000):
    """An elliptical blade (base at the origin, tip at x = 1, half-width 0.2), sampled uniformly
    along its length, so denser per area where it narrows towards the tip (as captures are)."""
    x = rng.uniform(0, 1, n)
    y = rng.uniform(-1, 1, n) * 0.2 * np.sqrt(np.clip(1 - (2 * x - 1) ** 2, 0, None))
    return np.column_stack([x, y, 0.002 * rng.standard_normal(n)])


def test_apex_landmark_moves_to_the_blade_edge():
    """The segmentation's apex (a subsample point inside the tip) walks out to the blade's tip;
    one at the tip stays near it; a tip curled back keeps its end (not the bend, farther from the base);
    too few points near it leave it alone."""
    from leaffit_usd.fit.leaf_ends import apex_at_blade_edge as _apex_at_blade_edge

    rng = np.random.default_rng(0)
    P = _tip_blade(rng)
    tip = P[np.argmax(P[:, 0])]
    moved = _apex_at_blade_edge(P, np.zeros(3), np.array([0.93, 0.01, 0.0]))
    assert moved[0] > 0.99 and abs(moved[1]) < 0.03, moved
    # one at the tip stays there: within 1 % of the leaf (the edge's mean over a cell's depth)
    assert np.linalg.norm(_apex_at_blade_edge(P, np.zeros(3), tip) - tip) < 0.01
    # beyond x = 0.8 the blade curls up and back on a circle of radius 0.06 (xz)
    t = np.linspace(0, 0.9 * np.pi, 400)
    hook = np.column_stack([0.8 + 0.06 * np.sin(t), np.zeros_like(t), 0.06 - 0.06 * np.cos(t)])
    Q = np.concatenate([P[P[:, 0] <= 0.8], np.repeat(hook, 20, 0)
                        + np.column_stack([np.zeros(8000), rng.uniform(-0.02, 0.02, 8000), np.zeros(8000)])])
    end = _apex_at_blade_edge(Q, np.zeros(3), hook[-40])
    assert np.linalg.norm(end[[0, 2]] - hook[-1][[0, 2]]) < 0.005, end
    lone = np.array([5.0, 0.0, 0.0])
    np.testing.assert_array_equal(_apex_at_blade_edge(P, np.zeros(3), lone), lone)


def test_a_leafs_apex_landmark_reaches_the_tip_when_the_segmentations_apex_falls_short(plant):
    """The leaf's apex landmark (local frame) is its blade's tip even when the segmentation's
    apex is a Gaussian 6 % of the leaf inside it (a geodesic subsample's point on a dense
    capture): the refinement pins the template's tip there."""
    from dataclasses import replace

    from leaffit_usd.fit.register import _prepare_leaf

    m = plant.cloud.means
    inner = []
    for j in range(plant.seg.n_leaves):
        idx = plant.seg.leaf_indices(j + 1)
        b, t = m[plant.seg.leaf_base[j]], m[plant.seg.leaf_tip[j]]
        inner.append(idx[np.argmin(np.linalg.norm(m[idx] - (t - 0.06 * (t - b)), axis=1))])
    short = replace(plant.seg, leaf_tip=np.asarray(inner, np.int64))
    p = FitParams()
    for j in range(plant.seg.n_leaves):
        lf = _prepare_leaf(j + 1, np.asarray(m, np.float64), short, p.denoise)
        reach = lf.local[:, 0].max()
        assert lf.apex[0] > reach - 0.01 * reach, (j, lf.apex, reach)
