"""The blades method (leaffit_usd.segment.blades): sheets vs tubes from normals, leaves that
touch or share one attachment, thick stems, the per-leaf confidence."""
import numpy as np
import pytest

from leaffit_usd.metrics import segmentation_scores
from leaffit_usd.segment.auto import SegmentParams, segment_plant
from leaffit_usd.segment.blades import build_surface_graph, normal_tensor_ratio, tube_mask

from .synth import _blade, _cylinder, make_plant

MIN_MIOU = 95.0


def _disc(centre, normal, radius, n, rng):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.cross(normal, [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    r = radius * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    p = centre + (r * np.cos(a))[:, None] * u + (r * np.sin(a))[:, None] * v
    return p, np.tile(normal, (n, 1))


def _assemble(parts, rng, noise=0.0005):
    pts = np.concatenate([p for p, _, _ in parts])
    nrm = np.concatenate([n for _, n, _ in parts])
    lab = np.concatenate([np.full(len(p), lb, np.int32) for p, _, lb in parts])
    pts = pts + rng.normal(0, noise, pts.shape)
    root = int(np.argmin(np.linalg.norm(pts, axis=1)))
    return pts, nrm, lab, root


def test_tube_test_tells_a_stem_from_a_blade():
    rng = np.random.default_rng(0)
    stem, sn = _cylinder([0, 0, 0], [0, 0, 1.0], 0.006, 6000, rng)
    blade, bn = _blade(np.array([0.3, 0, 0.5]), [1.0, 0, 0], 0.3, 0.15, 12000, rng)
    pts = np.concatenate([stem, blade])
    nrm = np.concatenate([sn, bn])
    g = build_surface_graph(pts, nrm, np.ones(len(pts), bool), SegmentParams())
    tube = tube_mask(g, SegmentParams())
    is_stem = g.domain < len(stem)
    assert tube[is_stem].mean() > 0.9 and tube[~is_stem].mean() < 0.02
    assert normal_tensor_ratio(sn) > 0.9 and normal_tensor_ratio(bn) < 0.05


def test_wide_tube_tests_run_only_where_the_narrow_one_said_no():
    """tube_mask skips the wider tests at points already found tubes: the mask equals the OR of
    all three tests computed on every point (a thick stem, which only the wide tests catch, a
    thin stem and a blade)."""
    from leaffit_usd.segment.blades import TUBE_WIDE, _tensor_ratio_within
    from leaffit_usd.geometry.heat import voxel_subsample

    rng = np.random.default_rng(5)
    thin, tn = _cylinder([0, 0, 0], [0, 0, 1.0], 0.006, 5000, rng)
    thick, kn = _cylinder([0.5, 0, 0], [0, 0, 1.0], 0.05, 8000, rng)
    blade, bn = _blade(np.array([0.3, 0, 0.5]), [1.0, 0, 0], 0.3, 0.15, 12000, rng)
    pts, nrm = np.concatenate([thin, thick, blade]), np.concatenate([tn, kn, bn])
    p = SegmentParams()
    g = build_surface_graph(pts, nrm, np.ones(len(pts), bool), p)
    every = _tensor_ratio_within(g.points, g.normals, g.points, p.stalk_radius) > p.stalk_ratio
    narrow = every.copy()
    for factor, ratio in TUBE_WIDE:
        coarse = voxel_subsample(g.points, max(64, g.size // (factor * factor)))
        every |= _tensor_ratio_within(g.points[coarse], g.normals[coarse], g.points,
                                      factor * p.stalk_radius) > ratio
    assert (every & ~narrow).sum() > 20  # the wide tests find tube points the narrow one misses
    np.testing.assert_array_equal(tube_mask(g, p), every)


def test_trifoliate_leaflets_on_one_attachment_are_three_leaves():
    """Three leaflets meeting at the end of one petiole (a trifoliate leaf): one blade component
    with one attachment; the merge tree cuts them apart at their bases. Without the palm rule
    (palm_fraction = 0) they stay one leaf."""
    rng = np.random.default_rng(3)
    parts = []
    s, n = _cylinder([0, 0, 0], [0, 0, 0.8], 0.006, 3000, rng)
    parts.append((s, n, 0))
    top = np.array([0.0, 0, 0.8])
    for j, ang in enumerate((0.0, 2.1, 4.2)):
        d = np.array([np.cos(ang), np.sin(ang), 0.0])
        p, nr = _blade(top + 0.004 * d, d, 0.25, 0.12, 5000, rng, droop=0.05)
        parts.append((p, nr, j + 1))
    pts, nrm, lab, root = _assemble(parts, rng)
    seg = segment_plant(pts, root, normals=nrm)
    sc = segmentation_scores(seg.labels, lab)
    assert seg.n_leaves == 3 and sc.miou >= 90
    merged = segment_plant(pts, root, SegmentParams(palm_fraction=0.0), normals=nrm)
    assert merged.n_leaves < 3


def test_a_tip_hanging_just_above_a_lower_leaf_is_not_joined_to_it():
    """Two parallel blades 6 mm apart (about one sample spacing), each on its own petiole: the
    sheet test (tangent plane, normals) keeps them apart; with the test off (tangent_sin = 1,
    normal_cos = 0) the graph joins them."""
    rng = np.random.default_rng(4)
    parts = [(*_cylinder([0, 0, 0], [0, 0, 0.9], 0.006, 3000, rng), 0)]
    for j, h in enumerate((0.45, 0.456)):
        pet, pn = _cylinder([0, 0, h], [0.05, 0, h], 0.003, 300, rng)
        parts.append((pet, pn, 0))
        disc, dn = _disc(np.array([0.05 + 0.15 + 0.1 * j, 0.0, h]), [0, 0, 1.0], 0.15, 9000, rng)
        parts.append((disc, dn, j + 1))
    pts, nrm, lab, root = _assemble(parts, rng, noise=0.0003)
    seg = segment_plant(pts, root, normals=nrm)
    assert seg.n_leaves == 2 and segmentation_scores(seg.labels, lab).miou >= 85
    blind = segment_plant(pts, root, SegmentParams(tangent_sin=1.0, normal_cos=0.0), normals=nrm)
    assert segmentation_scores(blind.labels, lab).miou < segmentation_scores(seg.labels, lab).miou


def test_a_thick_stem_is_stem():
    """A stem 5x thicker than stalk_radius is flat at that radius; the wide tube tests find it."""
    pl = make_plant(n_leaves=5, n_points=30000, seed=2, stem_radius=0.04)
    seg = segment_plant(pl.points, pl.root_index, normals=pl.normals)
    sc = segmentation_scores(seg.labels, pl.labels)
    assert seg.n_leaves == 5 and sc.miou >= 90
    stem = pl.labels == 0
    assert (seg.labels[stem] == 0).mean() > 0.9


def test_confidence_marks_the_leaf_cut_from_a_blade():
    """The trifoliate's leaflets are cut from one blade: lower confidence than a clean leaf."""
    pl = make_plant(n_leaves=4, n_points=20000, seed=1, leaf_length=0.3, leaf_width=0.2)
    seg = segment_plant(pl.points, pl.root_index, normals=pl.normals)
    assert seg.confidence.shape == (seg.n_leaves,)
    assert np.all((seg.confidence >= 0) & (seg.confidence <= 1))
    assert seg.confidence.min() > 0.8  # clean, separate, similar leaves


def test_blade_parameters_validated():
    from leaffit_usd.errors import ParameterError

    for kw in (dict(method="nope"), dict(stalk_radius=0.0), dict(normal_cos=1.5),
               dict(domain_points=10), dict(palm_fraction=-0.1)):
        with pytest.raises(ParameterError):
            SegmentParams(**kw).validate()


def _plant_with_one_disc(rng, noisy=0.0):
    """A stem, a petiole and one horizontal disc blade (label 1) at height 0.45; a fraction
    ``noisy`` of the blade's Gaussians have random normals (round or badly fitted Gaussians).
    Returns pts, nrm, lab, root and the noisy Gaussians' mask."""
    parts = [(*_cylinder([0, 0, 0], [0, 0, 0.9], 0.006, 3000, rng), 0)]
    pet, pn = _cylinder([0, 0, 0.45], [0.05, 0, 0.45], 0.003, 300, rng)
    parts.append((pet, pn, 0))
    disc, dn = _disc(np.array([0.2, 0.0, 0.45]), [0, 0, 1.0], 0.15, 9000, rng)
    bad = rng.random(len(disc)) < noisy
    r = rng.normal(size=(int(bad.sum()), 3))
    dn[bad] = r / np.linalg.norm(r, axis=1, keepdims=True)
    parts.append((disc, dn, 1))
    pts, nrm, lab, root = _assemble(parts, rng, noise=0.0003)
    return pts, nrm, lab, root, np.concatenate([np.zeros(3300, bool), bad])


def test_blade_points_with_stray_normals_stay_with_their_leaf():
    """Gaussians of a blade whose normals disagree with all their neighbours' are cut off by the
    sheet test one by one (sheet pieces too small to be leaves); they join their leaf through
    the graph, not the stem. (They stayed 0: ~1 % of the Gaussians of the samples' elliptic
    plants, all along the blades.)"""
    rng = np.random.default_rng(5)
    pts, nrm, lab, root, noisy = _plant_with_one_disc(rng, noisy=0.03)
    seg = segment_plant(pts, root, normals=nrm)
    assert seg.n_leaves == 1
    assert (seg.labels[noisy] == 1).mean() > 0.95


def test_a_patch_of_stem_surface_is_not_a_leaf():
    """A patch of the stem whose points the tube test missed is a sheet bordered by stem all
    round (most of its points touch the stem): it stays stem, while the real blade, touching the
    stem only where its stalk enters, is a leaf."""
    from leaffit_usd.segment.blades import find_leaves, sheet_edges

    rng = np.random.default_rng(6)
    pts, nrm, lab, root, _ = _plant_with_one_disc(rng)
    p = SegmentParams()
    g = build_surface_graph(pts, nrm, np.ones(len(pts), bool), p)
    stem = lab[g.domain] == 0
    on_stem = g.domain < 3000
    z, ang = g.points[:, 2], np.arctan2(g.points[:, 1], g.points[:, 0])
    patch = on_stem & (z > 0.2) & (z < 0.3) & (np.abs(ang) < 1.2)
    assert patch.sum() >= 20
    stem &= ~patch  # the tube test "missed" the patch
    g.normals[patch] = np.median(g.normals[patch], axis=0) / np.linalg.norm(np.median(g.normals[patch], axis=0))
    found = find_leaves(g, sheet_edges(g, stem, p), stem, np.linalg.norm(g.points, axis=1), p)
    assert found.labels.max() == 1
    assert (found.labels[patch] == 0).all() and found.stem[patch].mean() > 0.8
    assert (found.labels[lab[g.domain] == 1] == 1).mean() > 0.95


def test_a_dense_plant_is_segmented_on_a_subset_and_every_gaussian_labelled():
    """Above ``max_gaussians`` the blades run on a position-order random subset; every other
    Gaussian takes its nearest subset Gaussian's label, far floaters stay unassigned, the leaf
    indices point into the whole cloud, and the file order does not change the result."""
    pl = make_plant(n_leaves=5, n_points=24000, seed=4, floaters=0)
    far = np.array([[3.0, 3.0, 3.0], [3.01, 3.0, 3.0]])  # two floaters far from the plant
    pts = np.concatenate([pl.points, far])
    nrm = np.concatenate([pl.normals, np.full((2, 3), np.nan)])
    gt = np.concatenate([pl.labels, [-1, -1]])
    prm = SegmentParams(max_gaussians=8000, domain_points=4000)
    seg = segment_plant(pts, pl.root_index, prm, normals=nrm)
    whole = segment_plant(pts, pl.root_index, SegmentParams(max_gaussians=0, domain_points=4000),
                          normals=nrm)
    assert seg.labels.shape == (len(pts),) and seg.dist_root.shape == (len(pts),)
    assert seg.n_leaves == whole.n_leaves == 5
    assert segmentation_scores(seg.labels[:-2], gt[:-2]).miou >= MIN_MIOU
    assert np.all(seg.labels[-2:] == 0) and np.all(~np.isfinite(seg.dist_root[-2:]))
    assert np.all(seg.labels[seg.leaf_tip] == np.arange(1, 6))
    assert np.isfinite(seg.dist_root[:-2]).mean() > 0.99
    perm = np.random.default_rng(0).permutation(len(pts))
    root = int(np.flatnonzero(perm == pl.root_index)[0])
    shuffled = segment_plant(pts[perm], root, prm, normals=nrm[perm])
    assert np.array_equal(shuffled.labels, seg.labels[perm])


def test_a_stalk_contact_inside_the_blade_touches_its_face():
    """``face_contacts``: a contact in the middle of a blade (a stem brushing its face) is
    surrounded by blade; one at the margin (where a petiole enters) is open on its stalk's side."""
    from leaffit_usd.segment.blades import face_contacts

    rng = np.random.default_rng(8)
    disc, dn = _disc(np.array([0.2, 0.0, 0.45]), [0, 0, 1.0], 0.15, 9000, rng)
    g = build_surface_graph(disc, dn, np.ones(len(disc), bool), SegmentParams())
    members = np.arange(g.size)
    d = g.points - np.array([0.2, 0.0, 0.45])
    inside = np.flatnonzero(np.linalg.norm(d, axis=1) < 0.006)
    margin = np.flatnonzero(np.linalg.norm(g.points - np.array([0.05, 0.0, 0.45]), axis=1) < 0.012)
    halfway = np.flatnonzero(np.linalg.norm(g.points - np.array([0.125, 0.0, 0.45]), axis=1) < 0.006)
    assert min(len(inside), len(margin), len(halfway)) >= 2
    assert face_contacts(g, members, [inside, margin, halfway]).tolist() == [True, False, True]


def test_a_stem_touching_a_blade_from_below_does_not_cut_the_leaf():
    """A branch ending under the middle of a blade touches it: the blade then has two stalk
    contacts, its petiole's at the margin and the branch's in its face. Only the petiole enters
    the leaf; the blade stays one leaf (white_flag_bush's leaf 7 was cut in pieces this way)."""
    rng = np.random.default_rng(9)
    parts = [(*_cylinder([0, 0, 0], [0, 0, 0.9], 0.006, 3000, rng), 0)]
    parts.append((*_cylinder([0, 0, 0.45], [0.05, 0, 0.45], 0.003, 300, rng), 0))
    parts.append((*_cylinder([0, 0, 0.25], [0.2, 0.04, 0.4475], 0.003, 1200, rng), 0))
    parts.append((*_disc(np.array([0.2, 0.0, 0.45]), [0, 0, 1.0], 0.15, 9000, rng), 1))
    pts, nrm, lab, root = _assemble(parts, rng, noise=0.0003)
    seg = segment_plant(pts, root, normals=nrm)
    assert seg.n_leaves == 1
    assert segmentation_scores(seg.labels, lab).miou >= 90


def _curled_ribbon(rng, n, z0=0.5, length=0.5, width=0.08, curl=0.1, layers=0.003, noise=0.0015,
                   normal_noise=0.35):
    """A leaf leaving a vertical stem at height ``z0``: a ribbon whose midline curls up and over
    with radius ``curl`` (length / curl = 5 rad: its normals turn through more than a half
    circle, as a tube's do), sampled as a scan sees a real leaf: two layers ``layers`` apart,
    positional noise and noisy normals. (n, 3) points and (n, 3) unit normals."""
    t = rng.random(n) * length
    y = (rng.random(n) - 0.5) * width * np.minimum(1.0, 4 * t / length + 0.2)
    th = t / curl
    mid = np.stack([0.006 + curl * np.sin(th), np.zeros(n), z0 + curl * (1 - np.cos(th))], 1)
    nrm = np.stack([-np.sin(th), np.zeros(n), np.cos(th)], 1)
    side = np.where(rng.random(n) < 0.5, -0.5, 0.5) * layers
    pts = mid + y[:, None] * np.array([0, 1.0, 0]) + side[:, None] * nrm + rng.normal(0, noise, (n, 3))
    nn = nrm + rng.normal(0, normal_noise, (n, 3))
    return pts, nn / np.linalg.norm(nn, axis=1, keepdims=True)


def test_a_noisy_two_layered_curled_leaf_on_a_stem_is_a_leaf():
    """A curled leaf's normals wrap around as a tube's do (the whole-piece normal tensor ratio is
    ~1), but its positions are thin across at every scale below its curl radius: it is a leaf,
    not a piece of stem, however noisy and two-layered its sampling."""
    for normal_noise in (0.1, 0.35):  # ~6 and ~20 degrees
        rng = np.random.default_rng(11)
        stem, sn = _cylinder([0, 0, 0], [0, 0, 1.0], 0.006, 5000, rng)
        leaf, ln = _curled_ribbon(rng, 9000, normal_noise=normal_noise)
        assert normal_tensor_ratio(ln) > 0.65  # what the whole-piece tube test alone called stem
        pts, nrm = np.concatenate([stem, leaf]), np.concatenate([sn, ln])
        lab = np.r_[np.zeros(len(stem), np.int32), np.ones(len(leaf), np.int32)]
        seg = segment_plant(pts, int(np.argmin(pts[:, 2])), normals=nrm)
        assert (seg.labels[lab == 1] > 0).mean() > 0.9
        assert (seg.labels[lab == 0] == 0).mean() > 0.9
        if normal_noise < 0.2:  # noisier normals cut the sheet into pieces: leaves all the same
            assert seg.n_leaves == 1


def test_thickness_tells_a_tube_from_a_curled_sheet():
    """The position-shape measure behind it: lambda_3 / lambda_2 of the neighbourhood is ~1
    across a tube and small on a curled sheet (its normals notwithstanding)."""
    from leaffit_usd.segment.blades import piece_thickness

    rng = np.random.default_rng(12)
    stem, sn = _cylinder([0, 0, 0], [0, 0, 1.0], 0.006, 5000, rng)
    leaf, ln = _curled_ribbon(rng, 9000)
    pts = np.concatenate([stem, leaf])
    g = build_surface_graph(pts, np.concatenate([sn, ln]), np.ones(len(pts), bool), SegmentParams())
    th = piece_thickness(g, None, SegmentParams())
    on_stem = g.domain < len(stem)
    low_stem = on_stem & (g.points[:, 2] < 0.35)  # away from the leaf
    assert np.median(th[low_stem]) > 2 * SegmentParams().piece_thick
    assert np.median(th[~on_stem]) < SegmentParams().piece_thick


def test_a_stem_whose_tube_test_drops_out_is_one_stem():
    """The tube test misses a stretch of the stem (sampled from one side, noisy): the piece
    above the gap is still the stem, chained to the root's piece along the surface."""
    from leaffit_usd.segment.blades import piece_thickness, rooted_stem

    rng = np.random.default_rng(13)
    stem, sn = _cylinder([0, 0, 0], [0, 0, 1.0], 0.006, 6000, rng)
    p = SegmentParams()
    g = build_surface_graph(stem, sn, np.ones(len(stem), bool), p)
    z = g.points[:, 2]
    tube = (z < 0.4) | (z > 0.42)  # a gap 0.02 long: under stem_gap stalk radii
    link = p.attach_link * float(np.median(g.spacing))
    th = piece_thickness(g, None, p)
    old = rooted_stem(g, tube, z, link, 20)
    new = rooted_stem(g, tube, z, link, 20, thick=th, gap=p.stem_gap * p.stalk_radius, params=p)
    assert not old[z > 0.42].any()
    assert new[z > 0.42].all() and new[z < 0.4].all()


def _twisted_strap(rng, n, z0=0.5, length=0.45, width=0.05, turns=0.5):
    """A grass leaf rising from the top of a stem at height ``z0``, twisted ``turns`` half-turns
    along its length (a maize whorl's youngest leaf): its normals turn about its long axis."""
    t = rng.random(n)
    w = (rng.random(n) - 0.5) * width
    th = np.pi * turns * t
    pts = np.stack([w * np.cos(th), w * np.sin(th), z0 + length * t], 1)
    nrm = np.stack([-np.sin(th), np.cos(th), np.zeros(n)], 1)
    return pts, nrm


def test_a_twisted_strap_leaf_is_not_a_tube():
    """A strap leaf twisted along its length turns its normals about its long axis, as a tube
    does about its own, and is long on that axis; but it is no tube: it passes through that
    axis, so its cross-sections do not close round it (radial_share ~0, a tube's 1)."""
    from leaffit_usd.segment.blades import radial_share, tube_shaped

    rng = np.random.default_rng(14)
    p = SegmentParams()
    strap, sn = _twisted_strap(rng, 6000, turns=1.0)
    assert normal_tensor_ratio(sn) > p.tube_ratio  # its normals wrap around
    tube, tn = _cylinder([0, 0, 0], [0, 0, 0.4], 0.01, 6000, rng)
    axis = np.array([0, 0, 1.0])
    assert radial_share(strap, sn, axis) < 0.3 < 0.95 < radial_share(tube, tn, axis)
    assert tube_shaped(tube, tn, p)
    assert not tube_shaped(strap, sn, p)
    assert tube_shaped(strap, sn, SegmentParams(tube_radial=0.0))  # the elongation test alone


def test_a_twisted_strap_on_top_of_a_stem_is_a_leaf():
    """End to end: the twisted strap leaf on top of a stem is a leaf, and the stem stays stem."""
    rng = np.random.default_rng(15)
    stem, sn = _cylinder([0, 0, 0], [0, 0, 0.5], 0.008, 5000, rng)
    leaf, ln = _twisted_strap(rng, 9000, z0=0.5, turns=1.0)
    leaf[:, 0] += 0.006  # its base against the stem's side
    pts, nrm, lab, root = _assemble([(stem, sn, 0), (leaf, ln, 1)], rng)
    seg = segment_plant(pts, root, normals=nrm)
    assert (seg.labels[lab == 1] > 0).mean() > 0.9
    assert (seg.labels[lab == 0] == 0).mean() > 0.9


def _flat_y(rng, n, z0=0.4, strip=0.3, strip_width=0.03, blade=0.25, blade_width=0.1):
    """A flat "Y" in the x-z plane (normal +y): a strip from ``z0`` up ``strip`` long (a stalk a
    scan sees as a flat band), and at its top two elliptic blades spreading up-left and
    up-right. Returns points, normals and labels (0 strip, 1 and 2 the blades)."""
    k = int(n * strip * strip_width / (strip * strip_width + 2 * np.pi / 4 * blade * blade_width))
    s = np.stack([(rng.random(k) - 0.5) * strip_width, np.zeros(k), z0 + strip * rng.random(k)], 1)
    parts, labels = [s], [np.zeros(k, np.int32)]
    top = np.array([0, 0, z0 + strip])
    for lab, sx in ((1, -1.0), (2, 1.0)):
        d = np.array([sx, 0, 1.0]) / np.sqrt(2)
        side = np.array([-d[2], 0, d[0]])
        m = (n - k) // 2
        x, y = rng.random(4 * m), (rng.random(4 * m) - 0.5) * 2
        keep = np.abs(y) <= np.sqrt(np.clip(1 - (2 * x - 1) ** 2, 0, None))
        x, y = x[keep][:m], y[keep][:m]
        parts.append(top + (x * blade)[:, None] * d + (y * blade_width / 2)[:, None] * side)
        labels.append(np.full(len(x), lab, np.int32))
    pts = np.concatenate(parts)
    return pts, np.tile([0, 1.0, 0], (len(pts), 1)), np.concatenate(labels)


def test_two_blades_on_a_flat_strip_are_two_leaves():
    """Two blades meet at the top of a stalk that the tube test misses (a flat strip, as an MVS
    scan saw a tomato seedling's hypocotyl): the strip below their saddle is too long for the
    palm test, but narrower than either blade, so they are two leaves, not one."""
    rng = np.random.default_rng(16)
    stem, sn = _cylinder([0, 0, 0], [0, 0, 0.4], 0.008, 4000, rng)
    y, yn, ylab = _flat_y(rng, 12000)
    pts = np.concatenate([stem, y]) + rng.normal(0, 0.0005, (len(stem) + len(y), 3))
    nrm = np.concatenate([sn, yn])
    lab = np.concatenate([np.zeros(len(stem), np.int32), ylab])
    root = int(np.argmin(pts[:, 2]))
    one = segment_plant(pts, root, SegmentParams(stalk_narrow=0.0), normals=nrm)
    assert one.n_leaves == 1  # the palm test alone: one leaf
    seg = segment_plant(pts, root, normals=nrm)
    assert seg.n_leaves == 2
    for b in (1, 2):
        assert np.bincount(seg.labels[lab == b]).max() > 0.9 * (lab == b).sum()


def test_a_leaf_folded_into_a_u_is_not_a_tube():
    """A sparse piece of leaf folded at its midrib into a U (an arc of 190 degrees across, its
    normals wrapping round) is as thick across as a stem seen from one side: thick enough for
    ``piece_thick``, not for ``blade_thick`` (a half ring's 0.29): found as a leaf, it stays
    one."""
    from leaffit_usd.segment.blades import _piece_is_tube, piece_thickness

    rng = np.random.default_rng(17)
    n = 800
    ph = np.radians(rng.uniform(-95, 95, n))
    y = rng.random(n) * 0.06
    pts = np.stack([0.02 * np.sin(ph), y, 0.02 * np.cos(ph)], 1) + rng.normal(0, 0.0005, (n, 3))
    nrm = np.stack([np.sin(ph), np.zeros(n), np.cos(ph)], 1)
    p = SegmentParams()
    g = build_surface_graph(pts, nrm, np.ones(n, bool), p)
    th = piece_thickness(g, None, p)
    nodes = np.arange(g.size)
    assert p.piece_thick < np.median(th) < p.blade_thick
    assert not _piece_is_tube(g, nodes, th, p)
    assert _piece_is_tube(g, nodes, th, SegmentParams(blade_thick=p.piece_thick))


def test_a_piece_touching_the_stem_in_many_places_is_stem():
    """A flat strip with the stem's tube test holding only in patches along its margin (a scan
    sees a stem from one side): one sheet piece touching the stem at four separate places is a
    stretch of stem, not leaves; a leaf is entered by one stalk (two touching leaves make two
    contacts)."""
    from leaffit_usd.segment.blades import find_leaves, piece_thickness, sheet_edges

    rng = np.random.default_rng(18)
    n = 6000
    pts = np.stack([(rng.random(n) - 0.5) * 0.04, np.zeros(n), 0.1 + 0.45 * rng.random(n)], 1)
    nrm = np.tile([0, 1.0, 0], (n, 1))
    p = SegmentParams()
    g = build_surface_graph(pts, nrm, np.ones(n, bool), p)
    x, z = g.points[:, 0], g.points[:, 2]
    stem = (z < 0.12) | ((x < -0.012) & np.isin(np.floor((z - 0.1) / 0.02), [2, 7, 12, 17]))
    sheet = sheet_edges(g, stem, p)
    th = piece_thickness(g, None, p)
    found = find_leaves(g, sheet, stem, z, p, thick=th)
    assert found.stem.mean() > 0.95 and found.labels.max() == 0
    many = find_leaves(g, sheet, stem, z, SegmentParams(stem_contacts=100), thick=th)
    assert many.labels.max() >= 2  # cut into "leaves" at the contacts
