"""Capture realism (``PlantSpec(realism="capture")``): calibrated statistics, labels, the pot,
determinism, and the ideal mode left as it was."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from samples.capture import LAYER_SPACING
from samples.generate import (PlantSpec, capture_realism_plants, capture_suite, load_ground_truth,
                              main, make_plant, preset, save_plant)
from samples.scene import FLOATER, POT, SOIL

from tests.samples.test_samples_generate import _check_gt, _mesh_distance, MESH_DIST_REL

# the calibrated ranges (the real houseplant: median opacity 0.20, 23.5 % below 0.1, 49 %
# needles, flatness median 2.8; benchmarks/capture_stats.py)
OPACITY_MEDIAN_MAX = 0.35
OPACITY_MEDIAN_MIN = 0.1
FAINT_RANGE = (0.12, 0.35)          # share of opacities below 0.1
NEEDLES_MIN = 0.3                   # share with largest / middle > 3
FLATNESS_MEDIAN_MAX = 4.0           # middle / smallest
POT_SOIL_RANGE = (0.3, 0.5)         # share of pot and soil Gaussians

SPEC = preset("rubber_tree", gaussians=12_000, realism="capture", pot="ceramic")


@pytest.fixture(scope="module")
def plant():
    return make_plant(SPEC, seed=31)


def _stats(cloud):
    op = cloud.opacities.astype(np.float64)
    s = np.sort(cloud.scales.astype(np.float64), axis=1)[:, ::-1]
    return (float(np.median(op)), float((op < 0.1).mean()), float((s[:, 0] / s[:, 1] > 3).mean()),
            float(np.median(s[:, 1] / s[:, 2])))


def _in_calibrated_ranges(cloud) -> bool:
    med, faint, needles, flat = _stats(cloud)
    return (OPACITY_MEDIAN_MIN < med < OPACITY_MEDIAN_MAX and FAINT_RANGE[0] < faint < FAINT_RANGE[1]
            and needles > NEEDLES_MIN and flat < FLATNESS_MEDIAN_MAX)


def test_capture_statistics_are_in_the_calibrated_ranges(plant):
    cloud, _ = plant
    med, faint, needles, flat = _stats(cloud)
    assert OPACITY_MEDIAN_MIN < med < OPACITY_MEDIAN_MAX, med
    assert FAINT_RANGE[0] < faint < FAINT_RANGE[1], faint
    assert needles > NEEDLES_MIN, needles
    assert flat < FLATNESS_MEDIAN_MAX, flat


def test_ideal_plant_is_outside_the_calibrated_ranges():
    """The check above fails on the ideal generator's clean discs."""
    cloud, _ = make_plant(dataclasses.replace(SPEC, realism="ideal", scene=False, pot=None), seed=31)
    med, faint, needles, flat = _stats(cloud)
    assert med > OPACITY_MEDIAN_MAX and needles < NEEDLES_MIN and flat > FLATNESS_MEDIAN_MAX
    assert not _in_calibrated_ranges(cloud)


@pytest.mark.parametrize("name", sorted(capture_realism_plants()))
def test_capture_plants_are_in_the_calibrated_ranges(name):
    spec, seed = capture_realism_plants(gaussians=8000)[name]
    cloud, _ = make_plant(spec, seed)
    assert _in_calibrated_ranges(cloud), _stats(cloud)


def test_labels_cover_every_gaussian(plant):
    cloud, gt = plant
    n = len(cloud)
    _check_gt(cloud, gt, SPEC.leaves)
    assert gt.labels.shape == (n,) and gt.scene_class.shape == (n,)
    assert set(np.unique(gt.labels)) == {-2, -1, *range(SPEC.leaves + 1)}
    # plant, its floaters and the pot scene: every Gaussian has one class, the pot scene has
    # only pot, soil and floaters (no table or background)
    assert set(np.unique(gt.scene_class[gt.labels == -2])) == {POT, SOIL, FLOATER}
    assert (gt.labels != -2).sum() == SPEC.gaussians
    share = float(np.isin(gt.scene_class, (POT, SOIL)).mean())
    assert POT_SOIL_RANGE[0] < share < POT_SOIL_RANGE[1], share
    # leaf Gaussians (layers and edge fuzz included) lie on their own leaf's GT mesh
    assert _mesh_distance(cloud, gt, np.random.default_rng(0), per_leaf=200) < MESH_DIST_REL


def test_labels_check_catches_a_wrong_scene_class(plant):
    cloud, gt = plant
    wrong = dataclasses.replace(gt, scene_class=np.where(gt.labels >= 0, 3, gt.scene_class).astype(np.int8))
    with pytest.raises(AssertionError):
        _check_gt(cloud, wrong, SPEC.leaves)


def _offsets(cloud, gt, n=3000):
    """Leaf Gaussians' offsets from their GT mesh / plant height: along the mesh normal, and
    in-plane (non-zero where the closest mesh point is on the blade's rim)."""
    import open3d as o3d

    idx = np.random.default_rng(1).choice(np.flatnonzero(gt.labels > 0), n, replace=False)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(gt.leaf_vertices), o3d.core.Tensor(gt.leaf_faces.astype(np.uint32)))
    ans = scene.compute_closest_points(o3d.core.Tensor(cloud.means[idx]))
    d = (cloud.means[idx] - ans["points"].numpy()).astype(np.float64)
    nrm = ans["primitive_normals"].numpy().astype(np.float64)
    along = np.einsum("nd,nd->n", d, nrm)
    across = np.linalg.norm(d - along[:, None] * nrm, axis=1)
    return along / gt.height, across / gt.height


def test_leaves_are_layered():
    """Without off-surface noise, an ideal blade is two sheets half its thickness (~0.3e-3 H)
    either side of the surface; a capture blade is 2-3 layers LAYER_SPACING x H apart."""
    quiet = dict(surface_noise=1e-7, fuzz=0.0)
    cap, gtc = make_plant(dataclasses.replace(SPEC, **quiet), seed=31)
    ide, gti = make_plant(dataclasses.replace(SPEC, realism="ideal", scene=False, pot=None, **quiet), seed=31)
    a_cap, x_cap = _offsets(cap, gtc)
    a_ide, _ = _offsets(ide, gti)
    inside = x_cap < 1e-4  # not edge fuzz
    assert np.std(a_cap[inside]) > 0.6 * LAYER_SPACING > 1.5 * np.std(a_ide)


def test_edge_fuzz_spills_over_the_margin(plant):
    """Some leaf Gaussians lie beyond their blade's rim (their closest GT point is on the rim,
    off to the side), far more than in the ideal plant."""
    cloud, gt = plant
    ide, gti = make_plant(dataclasses.replace(SPEC, realism="ideal", scene=False, pot=None), seed=31)
    _, x_cap = _offsets(cloud, gt)
    _, x_ide = _offsets(ide, gti)
    beyond_cap, beyond_ide = (x_cap > 0.002).mean(), (x_ide > 0.002).mean()
    assert beyond_cap > 0.005 and beyond_cap > 3 * beyond_ide, (beyond_cap, beyond_ide)


@pytest.mark.parametrize("pot, rgb_order", [("ceramic", None), ("terracotta", (0, 1, 2))])
def test_pot_kind_and_soil_colour(pot, rgb_order):
    cloud, gt = make_plant(dataclasses.replace(SPEC, pot=pot, gaussians=6000), seed=2)
    col = cloud.colors.astype(np.float64)
    pot_c = np.median(col[gt.scene_class == POT], 0)
    soil_c = np.median(col[gt.scene_class == SOIL], 0)
    assert json.loads(gt.spec)["scene"]["pot"] == pot
    if rgb_order is None:   # white ceramic
        assert pot_c.min() > 0.75
    else:                   # terracotta: red > green > blue
        assert pot_c[0] > pot_c[1] > pot_c[2] and pot_c[0] > 1.4 * pot_c[2]
    assert soil_c.max() < 0.25 and soil_c[0] > soil_c[2]  # dark, reddish brown


def test_surroundings_are_configurable():
    bare = dataclasses.replace(SPEC, scene=False, gaussians=6000)
    cloud, gt = make_plant(bare, seed=3)
    assert gt.scene_class is None and (gt.labels >= -1).all() and len(cloud) == 6000
    assert _in_calibrated_ranges(cloud)
    cloud, gt = make_plant(dataclasses.replace(SPEC, scene=True, gaussians=6000), seed=3)
    assert {1, 4} <= set(np.unique(gt.scene_class))  # the table and the background are there


def test_same_seed_same_bytes(tmp_path):
    spec = dataclasses.replace(SPEC, gaussians=5000)
    save_plant(*make_plant(spec, 4), tmp_path / "a", "p")
    save_plant(*make_plant(spec, 4), tmp_path / "b", "p")
    for f in ("p.ply", "p.gt.npz"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    save_plant(*make_plant(spec, 5), tmp_path / "c", "p")
    assert (tmp_path / "c/p.ply").read_bytes() != (tmp_path / "a/p.ply").read_bytes()


def test_capture_keeps_the_plant_geometry():
    """Capture realism changes the Gaussians, not the plant: same GT meshes, root and frame."""
    _, a = make_plant(dataclasses.replace(SPEC, realism="ideal", scene=False, pot=None), seed=6)
    _, b = make_plant(SPEC, seed=6)
    np.testing.assert_array_equal(a.leaf_vertices, b.leaf_vertices)
    np.testing.assert_array_equal(a.canonical_to_input, b.canonical_to_input)
    np.testing.assert_array_equal(a.root, b.root)


def test_ideal_spec_records_what_it_did_before():
    """An ideal spec's GT JSON has no ``realism``/``pot`` keys and the old defaults (the ideal
    plants keep their bytes); a capture spec records both and round-trips."""
    d = PlantSpec().to_dict()
    assert "realism" not in d and "pot" not in d
    assert d["scene"] is False and d["floaters"] == 0.003
    c = SPEC.to_dict()
    assert c["realism"] == "capture" and c["pot"] == "ceramic" and c["scene"] == "pot"
    assert c["floaters"] > d["floaters"]
    assert PlantSpec.from_dict(json.loads(json.dumps(c))) == SPEC


def test_bad_capture_options_are_rejected():
    with pytest.raises(ValueError, match="realism"):
        PlantSpec(realism="photo")
    with pytest.raises(ValueError, match="pot"):
        PlantSpec(realism="capture", pot="gold")
    with pytest.raises(ValueError, match="scene"):
        PlantSpec(scene="table")
    with pytest.raises(ValueError, match="floaters"):
        PlantSpec(floaters=0.7)


def test_capture_suite_has_the_capture_plants():
    suite = {n: s for n, s, _ in capture_suite(gaussians=10_000)}
    for name in capture_realism_plants():
        assert suite[name].realism == "capture" and suite[name].scene == "pot"
    assert {suite[n].pot for n in capture_realism_plants()} >= {"ceramic", "terracotta"}


def test_cli_capture(tmp_path):
    assert main(["--preset", "green_pepper", "--realism", "capture", "--pot", "terracotta",
                 "--gaussians", "5000", "--seed", "2", "--out", str(tmp_path), "--name", "c", "-q"]) == 0
    gt = load_ground_truth(tmp_path / "c.gt.npz")
    meta = json.loads(gt.spec)
    assert meta["spec"]["realism"] == "capture" and meta["scene"]["pot"] == "terracotta"
    assert main(["--preset", "green_pepper", "--realism", "capture", "--bare", "--gaussians", "5000",
                 "--out", str(tmp_path), "--name", "b", "-q"]) == 0
    assert load_ground_truth(tmp_path / "b.gt.npz").scene_class is None
