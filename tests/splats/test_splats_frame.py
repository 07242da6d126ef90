"""Frame helpers: transform_cloud, estimate_up, resolve_root, make_frame."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from leaffit_usd.errors import ParameterError
from leaffit_usd.commands._args import parse_root
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.frame import make_frame
from leaffit_usd.splats.root import resolve_root
from leaffit_usd.splats.transform import transform_cloud
from leaffit_usd.splats.up_axis import estimate_up, estimate_up_with_confidence
from tests.splats.plyfiles import small_cloud
from tests.splats.splat_synth import make_plant

ANGLE_TOL = 15.0   # degrees, median over random plants
ROOT_TOL = 0.03    # fraction of plant height


def _similarity(seed, scale=2.5):
    m = np.eye(4)
    m[:3, :3] = scale * Rotation.random(random_state=seed).as_matrix()
    m[:3, 3] = [0.5, -1.0, 2.0]
    return m


def _angle(a, b):
    return np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


# ---- transform_cloud ---------------------------------------------------------------------------
def test_transform_similarity_covariances_and_inverse():
    c = small_cloud(300, 2)
    m = _similarity(3)
    t = transform_cloud(c, m)
    s = 2.5
    a = m[:3, :3]
    np.testing.assert_allclose(t.means, c.means @ a.T + m[:3, 3], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(t.covariances(), np.einsum("ij,njk,lk->nil", a, c.covariances(), a),
                               rtol=1e-4, atol=1e-9 * s * s)
    np.testing.assert_allclose(t.log_scales, c.log_scales + np.log(s), atol=1e-6)
    # unnormalised quaternions keep their length
    np.testing.assert_allclose(np.linalg.norm(t.quats, axis=1), np.linalg.norm(c.quats, axis=1), rtol=1e-6)
    # SH rotate with the cloud: the colour seen along R d after equals the colour along d before
    from leaffit_usd.splats.sh import eval_sh

    d = np.random.default_rng(0).normal(size=(len(c), 3))
    np.testing.assert_allclose(eval_sh(t.sh, d @ (a / s).T), eval_sh(c.sh, d), atol=2e-5)
    np.testing.assert_array_equal(t.sh[:, 0], c.sh[:, 0])
    back = transform_cloud(t, np.linalg.inv(m))
    np.testing.assert_allclose(back.means, c.means, atol=1e-5)
    np.testing.assert_allclose(back.covariances(), c.covariances(), rtol=1e-4, atol=1e-12)


def test_transform_rejects_non_similarity_unless_affine():
    c = small_cloud(50)
    shear = np.eye(4)
    shear[0, 1] = 0.5
    with pytest.raises(ParameterError, match="similarity"):
        transform_cloud(c, shear)
    mirror = np.diag([-1.0, 1, 1, 1])
    with pytest.raises(ParameterError, match="reflection"):
        transform_cloud(c, mirror)
    with pytest.raises(ParameterError, match="4x4"):
        transform_cloud(c, np.eye(3))
    t = transform_cloud(c, shear, allow_affine=True)
    a = shear[:3, :3]
    np.testing.assert_allclose(t.covariances(), np.einsum("ij,njk,lk->nil", a, c.covariances(), a),
                               rtol=1e-4, atol=1e-10)


# ---- estimate_up -------------------------------------------------------------------------------
def test_estimate_up_on_random_rotated_plants():
    errs, confs = [], []
    for seed in range(8):
        sp = make_plant(seed, n_leaves=4 + seed % 5)
        e = estimate_up_with_confidence(sp.cloud.means)
        assert e.up.shape == (3,) and abs(np.linalg.norm(e.up) - 1) < 1e-9
        assert 0.0 <= e.confidence <= 1.0
        errs.append(_angle(e.up, sp.up))
        confs.append(e.confidence)
    errs = np.array(errs)
    assert np.median(errs) < ANGLE_TOL, errs
    assert (errs < 30).mean() >= 0.75, errs
    # when it is wrong it should say so: confident answers are right
    assert all(err < 30 for err, cf in zip(errs, confs) if cf > 0.3), list(zip(errs, confs))


def test_estimate_up_is_rotation_equivariant_and_deterministic():
    sp = make_plant(2, rotate=False)
    u0 = estimate_up(sp.cloud.means)
    assert np.array_equal(u0, estimate_up(sp.cloud.means))
    assert _angle(u0, [0, 0, 1]) < ANGLE_TOL
    r = Rotation.random(random_state=7).as_matrix()
    u1 = estimate_up(sp.cloud.means @ r.T)
    assert _angle(u1, r @ u0) < 5.0


def _reference_root_score(p, u):
    """The up score of one direction written out with np.quantile / np.median, as the docstring
    of ``_root_scores`` states it (the oracle for the batched implementation)."""
    from leaffit_usd.geometry.plane import plane_basis

    xyz, nrm = p[:, :3], (p[:, 3:6] if p.shape[1] == 6 else None)
    h = xyz @ u
    lo, hi = np.quantile(h, [0.001, 0.999])
    ext = hi - lo
    b = plane_basis(u)
    x = xyz @ b
    canopy = h > lo + 0.3 * ext
    c = np.median(x[canopy] if canopy.sum() >= 10 else x, axis=0)
    radius = np.quantile(np.linalg.norm(x - c, axis=1), 0.9)
    widths, centre0, flat = [], None, 0.0
    fourth = np.sort(h[h <= lo + 0.25 * ext])[3]
    for f in (0.05, 0.10, 0.15, 0.20, 0.25):
        band = (h >= lo) & (h <= lo + f * ext)
        if band.sum() < 3:
            band = h <= fourth
        cb = np.median(x[band], axis=0)
        centre0 = cb if centre0 is None else centre0
        widths.append(np.quantile(np.linalg.norm(x[band] - cb, axis=1), 0.9))
        if f == 0.10 and band.sum() >= 5:
            for m in (np.cov(x[band].T), None if nrm is None else (nrm[band] @ b).T @ (nrm[band] @ b) / band.sum()):
                if m is not None:
                    ev = np.linalg.eigvalsh(m)
                    flat += 1 - np.sqrt(max(ev[0], 0) / ev[1])
    score = (np.mean(widths) + 0.1 * np.linalg.norm(centre0 - c)) / radius + 0.05 * flat
    return score, b @ centre0 + u * lo


def test_up_scores_of_many_directions_match_one_at_a_time():
    """The batched score (directions grouped by their bottom counts, scattered back) equals the
    written-out single-direction score for every direction, with and without normals, also for
    directions whose bottom bands hold fewer than 3 points (the lowest-four fallback)."""
    from leaffit_usd.splats.up_axis import _root_scores, fibonacci_sphere

    sp = make_plant(5, n_leaves=6)
    rng = np.random.default_rng(0)
    pts = sp.cloud.means[rng.choice(len(sp.cloud), 1500, replace=False)].astype(np.float64)
    pts -= pts.mean(0)
    nrm = sp.cloud.shortest_axes()[:1500]
    dirs = np.r_[fibonacci_sphere(70), -sp.up[None] / np.linalg.norm(sp.up)]
    for p in (pts, np.c_[pts, nrm]):
        sc, roots = _root_scores(p, dirs)
        for d, s_, r in zip(dirs, sc, roots):
            ref_s, ref_r = _reference_root_score(p, d)
            assert abs(s_ - ref_s) <= 1e-9 * max(1.0, abs(ref_s)), (d, s_, ref_s)
            np.testing.assert_allclose(r, ref_r, atol=1e-9)
    # the fallback was exercised: some directions have < 3 points in their 5 % band
    h = dirs @ pts.T
    lo, hi = np.quantile(h, [0.001, 0.999], axis=1)
    assert (((h >= lo[:, None]) & (h <= (lo + 0.05 * (hi - lo))[:, None])).sum(1) < 3).any()


def test_estimate_up_bad_input():
    with pytest.raises(ParameterError):
        estimate_up(np.zeros((5, 3)))
    with pytest.raises(ParameterError):
        estimate_up(np.zeros((100, 2)))


# ---- resolve_root --------------------------------------------------------------------------------
def test_root_auto_ignores_floaters_below():
    sp = make_plant(4, n_floaters=0)
    c = sp.cloud
    # a single floater and a small clump far below the plant
    below = sp.root - 0.5 * sp.height * sp.up
    clump = below + np.random.default_rng(0).normal(0, 0.005 * sp.height, (12, 3))
    pts = np.concatenate([c.means, below[None], clump]).astype(np.float32)
    from leaffit_usd.splats.cloud import GaussianCloud
    n = len(pts) - len(c)
    big = GaussianCloud(means=pts, log_scales=np.concatenate([c.log_scales, np.repeat(c.log_scales[:1], n, 0)]),
                        quats=np.concatenate([c.quats, np.repeat(c.quats[:1], n, 0)]),
                        opacity_logits=np.concatenate([c.opacity_logits, np.zeros(n, np.float32)]),
                        sh=np.concatenate([c.sh, np.repeat(c.sh[:1], n, 0)]))
    i = resolve_root(big, None, None, sp.up)
    assert i < len(c)
    assert np.linalg.norm(big.means[i] - sp.root) < ROOT_TOL * sp.height


def test_root_point_and_index():
    sp = make_plant(5)
    c = sp.cloud
    target = c.means[123] + 1e-4
    assert resolve_root(c, parse_root(f"{target[0]},{target[1]},{target[2]}"), None, sp.up) == 123
    with pytest.raises(ParameterError, match="near the plant"):
        far = sp.root + 2 * sp.height * sp.up
        resolve_root(c, parse_root(",".join(map(str, far))), None, sp.up)
    for bad in ("1,2", "a,b,c", "1,2,nan"):
        with pytest.raises(ParameterError, match="--root"):
            resolve_root(c, parse_root(bad), None, sp.up)
    assert resolve_root(c, None, 17, sp.up) == 17
    for bad in (-1, len(c), 2.5):
        with pytest.raises(ParameterError, match="--root-index"):
            resolve_root(c, None, bad, sp.up)
    with pytest.raises(ParameterError, match="not both"):
        resolve_root(c, parse_root("1,2,3"), 4, sp.up)


def test_root_index_is_in_file_order_after_drops():
    c = small_cloud(20).subset(np.r_[0:5, 6:20])  # Gaussian 5 was dropped at load
    c.file_count = 20
    assert resolve_root(c, None, 7, np.array([0, 0, 1.0])) == 6
    with pytest.raises(ParameterError, match="dropped"):
        resolve_root(c, None, 5, np.array([0, 0, 1.0]))


# ---- make_frame ----------------------------------------------------------------------------------
def test_make_frame_normalises_plant():
    sp = make_plant(6, n_floaters=20)
    fc = make_frame(sp.cloud, up=sp.up, root=None)
    f = fc.frame
    assert f.height == pytest.approx(sp.height, rel=0.05)
    w = f.to_working(sp.cloud.means)
    assert np.allclose(w[fc.root_index], 0, atol=1e-6)
    np.testing.assert_allclose(f.rotation @ sp.up, [0, 0, 1], atol=1e-9)
    # working frame: the plant spans about [0, 1] in z (floaters aside)
    assert np.quantile(w[:, 2], 0.99) < 1.0 + 1e-6 and np.quantile(w[:, 2], 0.01) > -0.05
    np.testing.assert_allclose(f.to_input(w), sp.cloud.means, atol=1e-5 * sp.height)
    # estimated up gives the same kind of result
    fc2 = make_frame(sp.cloud, up=None)
    assert _angle(fc2.frame.up, sp.up) < 30
    with pytest.raises(ParameterError):
        make_frame(sp.cloud, up="sideways")



def test_root_auto_joins_a_stem_cut_off_from_the_canopy():
    """The lower stem is a connected component of its own (a gap where it is sparsely sampled):
    the automatic root is still its base, not the lowest point of the canopy's component (the
    trimmed rubber tree's root was a leaf 0.4 x the height above the stem base), and a small
    clump under the plant still does not count."""
    from leaffit_usd.splats.cloud import GaussianCloud

    sp = make_plant(4, n_floaters=0, rotate=False)
    c = sp.cloud
    h = (c.means - sp.root) @ sp.up
    stem_piece = np.linalg.norm(np.cross(c.means - sp.root, sp.up), axis=1) < 0.05 * sp.height
    gap = stem_piece & (h > 0.08 * sp.height) & (h < 0.2 * sp.height)
    below = sp.root - 0.5 * sp.height * sp.up
    clump = below + np.random.default_rng(0).normal(0, 0.005 * sp.height, (12, 3))
    keep = np.flatnonzero(~gap)
    pts = np.concatenate([c.means[keep], clump]).astype(np.float32)
    n = len(clump)
    cut = GaussianCloud(means=pts, log_scales=np.concatenate([c.log_scales[keep], np.repeat(c.log_scales[:1], n, 0)]),
                        quats=np.concatenate([c.quats[keep], np.repeat(c.quats[:1], n, 0)]),
                        opacity_logits=np.concatenate([c.opacity_logits[keep], np.zeros(n, np.float32)]),
                        sh=np.concatenate([c.sh[keep], np.repeat(c.sh[:1], n, 0)]))
    from leaffit_usd.splats.root import MainBlob

    blob = MainBlob(cut.means)
    lower = ((cut.means[:len(keep)] - sp.root) @ sp.up < 0.08 * sp.height)
    assert blob.contains(cut.means[:len(keep)][lower]).all()
    assert not blob.contains(clump).any()
    i = resolve_root(cut, None, None, sp.up)
    assert np.linalg.norm(cut.means[i] - sp.root) < ROOT_TOL * sp.height


def test_an_estimated_up_that_puts_the_given_root_on_top_is_turned(monkeypatch):
    """A sparse scan's up estimate can point from the plant to the root the user clicked; the
    root is the plant's bottom, so the frame turns the estimate round instead of failing with
    no extent above the root."""
    from leaffit_usd.splats import frame as frame_mod
    from leaffit_usd.splats.up_axis import UpEstimate

    rng = np.random.default_rng(0)
    z = rng.uniform(0, 1, 3000)
    p = np.c_[0.3 * z * rng.normal(size=3000), 0.3 * z * rng.normal(size=3000), z]  # a cone, tip at 0
    n = len(p)
    cloud = GaussianCloud.from_activated(p, np.full((n, 3), 0.01), np.tile([1.0, 0, 0, 0], (n, 1)),
                                         np.full(n, 0.8))
    wrong = UpEstimate(up=np.array([0.0, 0.0, -1.0]), confidence=0.05, root=np.zeros(3))
    monkeypatch.setattr(frame_mod, "estimate_up_with_confidence", lambda *a, **k: wrong)
    choice = frame_mod.make_frame(cloud, root=p[np.argmin(z)])
    assert choice.frame.up @ [0, 0, 1.0] > 0.99 and choice.frame.height > 0.9
