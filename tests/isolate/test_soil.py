"""The soil disc of a potted plant without a table (a capture whose background was removed):
found as the scene's up, everything below it removed, and a big round leaf never taken for it."""
from __future__ import annotations

import numpy as np
import pytest

from leaffit_usd.isolate import PLANT, POT, SOIL, isolate_plant
from leaffit_usd.splats.cloud import GaussianCloud
from samples.generate import make_plant, preset


def _flat(pos, normal, size, rng):
    """Flat Gaussians at (n, 3) ``pos`` facing (n, 3) unit ``normal``."""
    from leaffit_usd.geometry.quaternion import matrix_to_quat

    a = np.where(np.abs(normal[:, 2:3]) < 0.9, [[0, 0, 1.0]], [[1.0, 0, 0]])
    e1 = np.cross(normal, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    rot = np.stack([e1, np.cross(normal, e1), normal], axis=2)
    scales = np.c_[np.full(len(pos), size), np.full(len(pos), size), np.full(len(pos), size / 10)]
    return scales, matrix_to_quat(rot)


def potted_capture(seed: int = 0, rim: float = 0.04):
    """A generated plant on a white pot with soil, no table, in a tilted frame.

    Returns (cloud, classes (N,) int: 0 plant, POT, SOIL; up (3,) input frame; soil height
    along up in the input frame)."""
    rng = np.random.default_rng(seed)
    plant, gt = make_plant(preset("rubber_tree", gaussians=20_000), 1)
    # the generator's frame is random: bring the plant to +Z up, root at the origin
    up_in = np.asarray(gt.up, np.float64)
    from leaffit_usd.geometry.plane import plane_basis
    rot = np.c_[plane_basis(up_in), up_in].T  # input -> canonical
    p = (plant.means.astype(np.float64) - gt.root) @ rot.T
    H = float(np.quantile(p[:, 2], 0.99))
    r_top, depth = 0.22 * H, 0.3 * H
    n_soil, n_wall = 8000, 6000
    rr = r_top * np.sqrt(rng.uniform(0, 1, n_soil))
    th = rng.uniform(0, 2 * np.pi, n_soil)
    soil = np.c_[rr * np.cos(th), rr * np.sin(th), rng.normal(0, 0.002 * H, n_soil)]
    hw = rng.uniform(-depth, rim * H, n_wall)
    th = rng.uniform(0, 2 * np.pi, n_wall)
    rw = r_top * (1 + 0.1 * hw / depth)
    wall = np.c_[rw * np.cos(th), rw * np.sin(th), hw]
    wall_n = np.c_[np.cos(th), np.sin(th), np.zeros(n_wall)]
    s_sc, s_q = _flat(soil, np.tile([0, 0, 1.0], (n_soil, 1)), 0.004 * H, rng)
    w_sc, w_q = _flat(wall, wall_n, 0.004 * H, rng)
    tilt = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    tilt *= np.sign(np.linalg.det(tilt))
    means = np.r_[p, soil, wall] @ tilt.T
    scene = GaussianCloud.from_activated(
        np.r_[soil, wall] @ tilt.T, np.r_[s_sc, w_sc], np.r_[s_q, w_q], np.full(n_soil + n_wall, 0.5),
        colors=np.r_[np.tile([0.25, 0.15, 0.08], (n_soil, 1)), np.tile([0.9, 0.9, 0.88], (n_wall, 1))])
    from leaffit_usd.geometry.quaternion import matrix_to_quat, quat_multiply
    q_tilt = matrix_to_quat(np.tile(tilt @ rot, (len(plant), 1, 1)))
    plant_q = quat_multiply(q_tilt, plant.rotations.astype(np.float64))
    cloud = GaussianCloud(
        means=np.ascontiguousarray(means, np.float32),
        log_scales=np.r_[plant.log_scales, scene.log_scales], quats=np.r_[plant_q.astype(np.float32), scene.quats],
        opacity_logits=np.r_[plant.opacity_logits, scene.opacity_logits],
        sh=np.r_[plant.sh[:, :1], scene.sh])
    classes = np.r_[np.zeros(len(plant), int), np.full(n_soil, SOIL), np.full(n_wall, POT)]
    return cloud, classes, tilt @ np.array([0, 0, 1.0]), gt


@pytest.fixture(scope="module")
def potted():
    return potted_capture()


def test_the_soil_gives_the_up_axis_and_everything_below_it_goes(potted):
    cloud, truth, up, _ = potted
    iso = isolate_plant(cloud)
    assert iso.up_source == "soil"
    assert np.degrees(np.arccos(np.clip(iso.up @ up, -1, 1))) < 3
    kept = iso.classes == PLANT
    assert kept[truth == 0].mean() > 0.99
    assert kept[truth != 0].mean() < 0.01
    soil_h = float(np.median(cloud.means[truth == SOIL] @ up))
    # nothing kept lies below the soil surface (beyond its noise)
    assert ((cloud.means[kept] @ up) < soil_h - 0.01 * iso.pot["plant_height"]).sum() == 0
    assert iso.root is not None and abs(float(iso.root @ up) - soil_h) < 0.05 * iso.pot["plant_height"]


def test_with_the_user_up_the_soil_is_found_the_same(potted):
    cloud, truth, up, _ = potted
    iso = isolate_plant(cloud, up=up)
    assert iso.up_source == "soil"
    assert (iso.classes == PLANT)[truth != 0].mean() < 0.01


@pytest.mark.parametrize("seed", [1, 3])
def test_a_big_round_leaf_is_not_soil(seed):
    """Broad cordate leaves with the rest of the plant under them are no soil disc: no pot's
    shell under them all round."""
    cloud, gt = make_plant(preset("golden_pothos", gaussians=8000), seed)
    iso = isolate_plant(cloud)
    assert iso.up_source is None and iso.pot is None


def test_a_disc_of_the_plants_own_colour_is_not_soil(potted):
    """A flat layer of touching leaflets with leaves above it in a shell is shaped like soil over
    a pot; only its colour tells them apart."""
    cloud, truth, up, _ = potted
    leafy = cloud.subset(np.arange(len(cloud)))
    plant_dc = np.median(cloud.sh[truth == 0, 0], axis=0)
    leafy.sh = leafy.sh.copy()
    leafy.sh[truth != 0, 0] = plant_dc
    iso = isolate_plant(leafy)
    assert iso.up_source != "soil" and (iso.classes == PLANT)[truth == 0].mean() > 0.99
