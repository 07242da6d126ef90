"""Round trips and frame helpers on every sample plant (samples/plants/*.ply, generated at set-up)."""
import numpy as np
import pytest

from leaffit_usd.splats import load_cloud, read_ply, write_ply
from leaffit_usd.splats.root import resolve_root
from leaffit_usd.splats.up_axis import estimate_up_with_confidence
from leaffit_usd.splats.usd_io import write_usd_splats

from samples import PLANTS_DIR, ensure_plants
from samples.generate import committed_plants

PLANTS = [PLANTS_DIR / f"{name}.ply" for name in sorted(committed_plants())]


@pytest.fixture(scope="module", autouse=True)
def _plants():
    ensure_plants()


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.stem)
def test_sample_round_trips(tmp_path, path):
    cloud = read_ply(path, drop_bad=False)
    write_ply(cloud, tmp_path / "rt.ply")
    assert (tmp_path / "rt.ply").read_bytes() == path.read_bytes()  # PLY -> cloud -> PLY bit-exact
    write_usd_splats(cloud, tmp_path / "rt.usdc")
    usd = load_cloud(tmp_path / "rt.usdc")
    assert len(usd) == len(cloud) and usd.sh_degree == cloud.sh_degree
    np.testing.assert_array_equal(usd.means, cloud.means)
    np.testing.assert_array_equal(usd.sh, cloud.sh)
    np.testing.assert_allclose(usd.scales, cloud.scales, rtol=3e-7)
    np.testing.assert_allclose(usd.opacities, cloud.opacities, rtol=3e-7, atol=1e-7)
    np.testing.assert_allclose(usd.rotations, cloud.rotations, atol=2e-7)


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.stem)
def test_sample_up_and_root(path):
    cloud = load_cloud(path)
    gt = np.load(path.with_name(path.stem + ".gt.npz"))  # keys per samples/README.md
    up, root, height = gt["up"], gt["root"], float(gt["height"])
    est = estimate_up_with_confidence(cloud.means, cloud.shortest_axes())  # as make_frame does
    # 30 degrees: generated stems lean up to ~20 degrees from the true (gravity) up, and the
    # estimator follows the stem
    assert np.degrees(np.arccos(np.clip(est.up @ up, -1, 1))) < 30
    ri = resolve_root(cloud, None, None, up)
    assert np.linalg.norm(cloud.means[ri] - root) < 0.05 * height
