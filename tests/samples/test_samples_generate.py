"""The procedural plant generator: determinism, ground-truth consistency, committed plants."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import open3d as o3d

from leaffit_usd.splats.frame import Frame
from leaffit_usd.splats.ply import read_ply
from samples import PLANTS_DIR, ensure_plants
from samples.generate import (STEM_SAMPLES, GroundTruth, PlantSpec, benchmark_suite,
                              committed_plants, load_ground_truth, main, make_plant, plant_tubes,
                              preset, save_plant, stem_samples_rng, tube_surface_samples)

# tolerances, in one place
MESH_DIST_REL = 0.02       # mean Gaussian->GT-mesh distance / leaf size
PETIOLE_WIDTH_REL = 0.5    # petiole diameter / blade width must stay below this
MAX_PLY_BYTES = 5.0e6      # a committed .ply
MAX_GT_BYTES = 1.5e6       # its .gt.npz

SMALL = PlantSpec(kind="mixed", leaves=6, gaussians=12_000, sh_degree=2, overlap="all")


@pytest.fixture(scope="module")
def small():
    return make_plant(SMALL, seed=5)


def test_same_seed_gives_identical_ply(tmp_path):
    a = make_plant(SMALL, seed=5)
    b = make_plant(SMALL, seed=5)
    save_plant(*a, tmp_path / "a", "p")
    save_plant(*b, tmp_path / "b", "p")
    assert (tmp_path / "a/p.ply").read_bytes() == (tmp_path / "b/p.ply").read_bytes()
    np.testing.assert_array_equal(a[1].labels, b[1].labels)
    c = make_plant(SMALL, seed=6)
    assert not np.array_equal(a[0].means, c[0].means)


def test_sampling_options_keep_the_geometry():
    """Gaussian count / noise come from their own random stream: same plant geometry."""
    spec = preset("rubber_tree", gaussians=8000)
    _, a = make_plant(spec, seed=2)
    _, b = make_plant(dataclasses.replace(spec, gaussians=12_000, surface_noise=0.001), seed=2)
    np.testing.assert_allclose(a.leaf_vertices, b.leaf_vertices, rtol=1e-6, atol=1e-6 * a.scale)
    np.testing.assert_array_equal(a.canonical_to_input, b.canonical_to_input)


def _check_gt(cloud, gt: GroundTruth, n_leaves: int):
    n = len(cloud)
    assert gt.labels.shape == (n,) and gt.labels.dtype == np.int32
    assert gt.petiole_of.shape == (n,)
    if gt.scene_class is None:
        assert set(np.unique(gt.labels)) <= set(range(-1, n_leaves + 1))
    else:  # surroundings: label -2, their class 1..5; the plant class 0, its floaters 5
        assert set(np.unique(gt.labels)) <= set(range(-2, n_leaves + 1))
        assert gt.scene_class.shape == (n,)
        np.testing.assert_array_equal(gt.scene_class[gt.labels >= 0], 0)
        np.testing.assert_array_equal(gt.scene_class[gt.labels == -1], 5)
        assert set(np.unique(gt.scene_class[gt.labels == -2])) <= {1, 2, 3, 4, 5}
    present = set(np.unique(gt.labels[gt.labels > 0]))
    assert present == set(range(1, n_leaves + 1)), "every leaf label must be present"
    assert (gt.labels == 0).any() and (gt.labels == -1).any()
    assert np.all(gt.labels[gt.petiole_of > 0] == 0), "petioles are stem (label 0)"
    assert gt.leaf_apex.shape == (n_leaves, 3) and gt.leaf_base.shape == (n_leaves, 3)
    assert set(np.unique(gt.leaf_vertex_ids)) == set(range(1, n_leaves + 1))
    assert gt.leaf_faces.min() >= 0 and gt.leaf_faces.max() < len(gt.leaf_vertices)
    assert gt.labels[gt.root_index] == 0
    # canonical_to_input is a similarity consistent with root and up
    M = gt.canonical_to_input
    A = M[:3, :3]
    s = gt.scale
    np.testing.assert_allclose(A.T @ A, s * s * np.eye(3), rtol=1e-9, atol=1e-9 * s * s)
    assert np.linalg.det(A) > 0
    np.testing.assert_allclose(M[:3, 3], gt.root, atol=1e-9 * max(1, s))
    np.testing.assert_allclose(A @ [0, 0, 1] / s, gt.up, atol=1e-9)
    assert abs(np.linalg.norm(gt.up) - 1) < 1e-9
    # root_index is the stem Gaussian nearest the root
    stem = np.flatnonzero(gt.labels == 0)
    d = np.linalg.norm(cloud.means[stem].astype(np.float64) - gt.root, axis=1)
    assert gt.root_index == stem[np.argmin(d)]
    # height: Frame.from_root_up over the plant (non-floater) Gaussians
    fr = Frame.from_root_up(cloud.means[gt.labels >= 0], gt.root, gt.up)
    assert fr.height == pytest.approx(gt.height, rel=1e-6)
    canon_h = json.loads(gt.spec)["canonical_height_m"]
    assert 0.3 - 1e-6 <= canon_h <= 1.2 + 1e-6  # documented range of plant heights (metres)
    # leaf apex above/below: apex lies on the leaf's GT mesh, base near the mesh
    for j in range(1, n_leaves + 1):
        v, _ = gt.leaf_mesh(j)
        size = float(np.linalg.norm(np.ptp(v, axis=0)))
        assert np.linalg.norm(v - gt.leaf_apex[j - 1], axis=1).min() < 1e-3 * size
        assert np.linalg.norm(v - gt.leaf_base[j - 1], axis=1).min() < 0.05 * size


def _mesh_distance(cloud, gt, rng, per_leaf=300):
    worst = 0.0
    for j in range(1, gt.n_leaves + 1):
        v, f = gt.leaf_mesh(j)
        # exact point-to-triangle distance (trimesh's closest_point needs rtree, not installed)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
        idx = np.flatnonzero(gt.labels == j)
        idx = rng.choice(idx, size=min(per_leaf, len(idx)), replace=False)
        dist = scene.compute_distance(o3d.core.Tensor(cloud.means[idx].astype(np.float32))).numpy()
        size = float(np.linalg.norm(np.ptp(v, axis=0)))
        worst = max(worst, float(dist.mean()) / size)
    return worst


def test_ground_truth_consistent(small):
    cloud, gt = small
    _check_gt(cloud, gt, SMALL.leaves)
    assert len(gt.overlap_pairs) >= 2  # "all" builds one pair of each type when it can


def test_plant_tubes_are_the_tubes_the_stem_samples_lie_on(small):
    """``plant_tubes`` gives the plant's own tubes: the stem samples drawn on them with the
    ground truth's stream are its ``stem_samples`` under one similarity (scale, rotation, shift),
    and they are not another seed's."""
    _, gt = small
    tubes = plant_tubes(SMALL, 5)
    assert sum(a.kind == "petiole" for a in tubes) == SMALL.leaves
    X = tube_surface_samples(tubes, STEM_SAMPLES, stem_samples_rng(5))
    A = np.linalg.lstsq(np.c_[X, np.ones(len(X))], gt.stem_samples, rcond=None)[0]
    size = float(np.ptp(gt.stem_samples, axis=0).max())
    assert np.abs(np.c_[X, np.ones(len(X))] @ A - gt.stem_samples).max() < 1e-9 * size
    sv = np.linalg.svd(A[:3], compute_uv=False)
    assert sv.max() - sv.min() < 1e-9 * sv.max()  # a similarity: no shear
    other = tube_surface_samples(plant_tubes(SMALL, 6), STEM_SAMPLES, stem_samples_rng(6))
    B = np.linalg.lstsq(np.c_[other, np.ones(len(other))], gt.stem_samples, rcond=None)[0]
    assert np.abs(np.c_[other, np.ones(len(other))] @ B - gt.stem_samples).max() > 1e-3 * size


def test_overlap_pairs_are_built_close():
    """Hard plants: each requested overlap type is built, its blades a few mm apart (not crossing)."""
    for overlap, types in [("touching", {1}), ("vertical", {2}), ("horizontal", {3})]:
        cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=8, gaussians=8000, overlap=overlap), seed=3)
        assert set(gt.overlap_types.tolist()) == types
        assert gt.overlap_pairs.shape == (len(gt.overlap_types), 2)
        gaps_mm = gt.overlap_gaps / gt.scale * 1000
        assert np.all(gaps_mm > 0.3) and np.all(gaps_mm < 7.0), gaps_mm
    _, gt = make_plant(PlantSpec(kind="elliptic", leaves=8, gaussians=8000), seed=3)
    assert len(gt.overlap_pairs) == 0


def test_leaf_gaussians_lie_on_their_gt_mesh(small):
    cloud, gt = small
    assert _mesh_distance(cloud, gt, np.random.default_rng(0)) < MESH_DIST_REL


def test_mesh_distance_check_fails_on_wrong_labels(small):
    """The mesh-distance check must catch labels that are shuffled between leaves."""
    cloud, gt = small
    wrong = GroundTruth(**{**gt.__dict__, "labels": np.where(gt.labels > 0, gt.labels % gt.n_leaves + 1, gt.labels)})
    assert _mesh_distance(cloud, wrong, np.random.default_rng(0)) > MESH_DIST_REL


def test_leaf_gaussians_are_flat_and_follow_the_surface(small):
    """The smallest scale axis of blade Gaussians is the GT mesh normal; it is much smaller."""
    cloud, gt = small
    rng = np.random.default_rng(2)
    idx = rng.choice(np.flatnonzero(gt.labels > 0), 2000, replace=False)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(gt.leaf_vertices), o3d.core.Tensor(gt.leaf_faces.astype(np.uint32)))
    ans = scene.compute_closest_points(o3d.core.Tensor(cloud.means[idx]))
    normal = ans["primitive_normals"].numpy().astype(np.float64)
    R = cloud.rotation_matrices()[idx].astype(np.float64)
    sc = cloud.scales[idx]
    smallest = np.argmin(sc, axis=1)
    assert np.all(smallest == 2)  # convention of the generator: third axis = normal
    axis = R[np.arange(len(idx)), :, smallest]
    cos = np.abs(np.einsum("nd,nd->n", axis, normal))
    assert np.median(cos) > 0.97 and np.mean(cos > 0.8) > 0.95
    assert np.median(sc[:, 2] / sc[:, 0]) < 0.15


def test_back_side_is_lighter():
    """Front (upper, along the GT face normal) and back Gaussians: the back is lighter.

    Off-surface noise is switched off so the side a Gaussian was sampled on is measurable.
    """
    cloud, gt = make_plant(dataclasses.replace(SMALL, surface_noise=1e-6, fuzz=0.0), seed=5)
    idx = np.random.default_rng(3).choice(np.flatnonzero(gt.labels > 0), 3000, replace=False)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(gt.leaf_vertices), o3d.core.Tensor(gt.leaf_faces.astype(np.uint32)))
    ans = scene.compute_closest_points(o3d.core.Tensor(cloud.means[idx]))
    normal = ans["primitive_normals"].numpy().astype(np.float64)
    side = np.einsum("nd,nd->n", cloud.means[idx] - ans["points"].numpy(), normal)
    lum = cloud.colors[idx] @ np.array([0.2126, 0.7152, 0.0722])
    assert (side > 0).mean() > 0.4 and (side < 0).mean() > 0.1
    assert np.median(lum[side < 0]) > 1.15 * np.median(lum[side > 0])
    # stem Gaussians are elongated along the stem: largest scale first, >1.5x the second
    st = cloud.scales[gt.labels == 0]
    assert np.median(st[:, 0] / st[:, 1]) > 1.5


def _petiole_diameter(points: np.ndarray) -> float:
    """Diameter of a tube's point cloud from a slab across its middle (input units)."""
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    t = (points - c) @ vt[0]
    ln = float(np.ptp(t))
    slab = points[np.abs(t) < 0.2 * ln]
    if len(slab) < 8:
        return 0.0
    cs = slab.mean(0)
    perp = (slab - cs) - np.outer((slab - cs) @ vt[0], vt[0])
    return 2.0 * float(np.percentile(np.linalg.norm(perp, axis=1), 90))


def _blade_width(points: np.ndarray) -> float:
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    return float(np.ptp((points - c) @ vt[1]))


@pytest.mark.parametrize("name", ["rubber_tree", "cotton_rose", "lucky_bamboo"])
def test_petiole_narrower_than_blade(name):
    spec = preset(name, gaussians=50_000)
    cloud, gt = make_plant(spec, seed=1)
    checked = 0
    for j in range(1, gt.n_leaves + 1):
        pet = cloud.means[gt.petiole_of == j].astype(np.float64)
        if len(pet) < 30:
            continue  # very short petiole (sheath): nothing to measure
        d = _petiole_diameter(pet)
        w = _blade_width(cloud.means[gt.labels == j].astype(np.float64))
        assert 0 < d < PETIOLE_WIDTH_REL * w, (j, d, w)
        checked += 1
    assert checked >= gt.n_leaves // 3


def test_benchmark_suite_covers_the_classes():
    suite = benchmark_suite(gaussians=20_000)
    assert len(suite) >= 8
    assert len({n for n, _, _ in suite}) == len(suite)
    kinds = {s.kind for _, s, _ in suite}
    assert {"elliptic", "lobed", "thin"} <= kinds
    assert all(5 <= s.leaves <= 27 for _, s, _ in suite)
    hard = [s for _, s, _ in suite if s.hard]
    assert {s.overlap for s in hard} >= {"touching", "vertical", "horizontal"}


@pytest.mark.parametrize("shape", ["elliptic", "ovate", "obovate", "lanceolate", "cordate",
                                   "maple", "cotton_rose", "linear"])
def test_every_outline_generates(shape):
    spec = PlantSpec(kind="mixed", shape=shape, leaves=5, gaussians=4000, serration=0.02)
    cloud, gt = make_plant(spec, seed=2)
    _check_gt(cloud, gt, 5)


def test_bad_spec_is_rejected():
    with pytest.raises(ValueError):
        PlantSpec(kind="fern")
    with pytest.raises(ValueError):
        PlantSpec(overlap="diagonal")
    with pytest.raises(ValueError):
        PlantSpec(sh_degree=4)
    with pytest.raises(ValueError):
        PlantSpec(leaves=10, gaussians=100)


def test_load_ground_truth_rejects_bad_files(tmp_path):
    from leaffit_usd.errors import InputFileError

    with pytest.raises(InputFileError, match="no such file"):
        load_ground_truth(tmp_path / "nope.gt.npz")
    (tmp_path / "junk.gt.npz").write_bytes(b"not a zip")
    with pytest.raises(InputFileError, match="not a ground-truth"):
        load_ground_truth(tmp_path / "junk.gt.npz")
    np.savez(tmp_path / "labels.npz", labels=np.zeros(3, np.int32))
    with pytest.raises(InputFileError, match="missing"):
        load_ground_truth(tmp_path / "labels.npz")


def test_cli_writes_plant(tmp_path, capsys):
    assert main(["--kind", "thin", "--leaves", "5", "--gaussians", "5000", "--seed", "3",
                 "--sh-degree", "1", "--out", str(tmp_path), "--name", "t", "-q"]) == 0
    cloud = read_ply(tmp_path / "t.ply")
    gt = load_ground_truth(tmp_path / "t.gt.npz")
    assert len(cloud) == 5000 and cloud.sh_degree == 1
    _check_gt(cloud, gt, 5)
    assert main(["--leaves", "0", "--out", str(tmp_path)]) == 2
    assert main(["--list"]) == 0
    assert "hard_vertical" in capsys.readouterr().out


@pytest.mark.parametrize("name", sorted(committed_plants()))
def test_committed_plant_matches_its_ground_truth(name):
    ensure_plants()
    ply = PLANTS_DIR / f"{name}.ply"
    gtp = PLANTS_DIR / f"{name}.gt.npz"
    assert ply.stat().st_size < MAX_PLY_BYTES and gtp.stat().st_size < MAX_GT_BYTES
    cloud = read_ply(ply)
    gt = load_ground_truth(gtp)
    spec, seed = committed_plants()[name]
    meta = json.loads(gt.spec)
    assert meta["seed"] == seed and PlantSpec.from_dict(meta["spec"]) == spec
    assert (gt.labels != -2).sum() == spec.gaussians and cloud.sh_degree == spec.sh_degree
    _check_gt(cloud, gt, spec.leaves)
    assert _mesh_distance(cloud, gt, np.random.default_rng(1), per_leaf=100) < MESH_DIST_REL
