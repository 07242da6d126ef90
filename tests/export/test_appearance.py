"""Per-leaf tint: measured from each leaf's Gaussians against the template texture
(``mesh.appearance``), and the per-leaf ΔE of the asset against the input (``export.appearance``),
on a synthetic plant whose leaves are the template texture times a known gain."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "usd"))
import synthetic as syn  # noqa: E402

from leaffit_usd.export.appearance import delta_e76, leaf_color_errors, linear_to_lab  # noqa: E402
from leaffit_usd.fit.mls import deform, mls_weights  # noqa: E402
from leaffit_usd.image_io import linear_to_srgb, srgb_to_linear  # noqa: E402
from leaffit_usd.mesh.appearance import measure_leaf_tints, sample_texture  # noqa: E402
from leaffit_usd.geometry.normals import vertex_normals  # noqa: E402
from leaffit_usd.splats.cloud import GaussianCloud  # noqa: E402

GAINS = np.array([[0.6, 0.9, 1.0], [1.0, 1.0, 1.0], [0.8, 0.55, 0.7], [1.0, 0.75, 0.5],
                  [0.5, 0.8, 0.95]])


def _texture(base, size=64):
    img = np.zeros((size, size, 4), np.uint8)
    img[..., :3] = base
    img[..., 1] = np.clip(base[1] + np.linspace(-25, 25, size)[None, :], 0, 255).astype(np.uint8)
    img[..., 3] = 255
    return img


@pytest.fixture(scope="module")
def plant():
    """(template, fits, working cloud, labels): leaf j's Gaussians show the texture x GAINS[j]."""
    import dataclasses

    t = syn.template_mesh()
    t = dataclasses.replace(t, front_texture=_texture((150, 170, 90)), back_texture=_texture((120, 140, 110)))
    fits = syn.leaf_fits(t)
    rng = np.random.default_rng(0)
    S = len(t.sheet_points)
    faces = np.asarray(t.sheet_faces)
    means, cols, labels = [], [], []
    for j in range(len(fits.leaf_labels)):
        f = faces[rng.integers(0, len(faces), 1200)]
        b = rng.dirichlet(np.ones(3), len(f))
        p = np.einsum("nk,nkc->nc", b, t.points[f].astype(np.float64))
        side = rng.random(len(f)) < 0.5                                   # True = back layer
        uv = np.einsum("nk,nkc->nc", b, t.uvs[np.where(side[:, None], f + S, f)])
        rgb_f, _ = sample_texture(t.front_texture, uv)
        rgb_b, _ = sample_texture(t.back_texture, uv)
        rgb = np.where(side[:, None], rgb_b, rgb_f)
        local = deform(mls_weights(fits.template_controls, p, fits.sigma, fits.reg), fits.targets[j])
        # the two layers sit 0.002 above / below the deformed sheet, along its own normals (an
        # offset pushed through the MLS would be scaled, even flipped, by its normal response)
        sheet = deform(mls_weights(fits.template_controls, t.points[:S], fits.sigma, fits.reg), fits.targets[j])
        nrm = np.einsum("nk,nkc->nc", b, vertex_normals(sheet, faces)[f])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        local += np.where(side, -1.0, 1.0)[:, None] * 0.002 * nrm
        M = fits.leaf_to_working[j]
        means.append(local @ M[:3, :3].T + M[:3, 3])
        cols.append(linear_to_srgb(srgb_to_linear(rgb) * GAINS[j]))
        labels.append(np.full(len(p), fits.leaf_labels[j]))
    means = np.concatenate(means)
    n = len(means)
    cloud = GaussianCloud.from_activated(means, np.full((n, 3), 0.004), np.tile([1.0, 0, 0, 0], (n, 1)),
                                         np.full(n, 0.95), colors=np.concatenate(cols))
    return t, fits, cloud, np.concatenate(labels)


def test_measured_tints_recover_the_gains(plant):
    t, fits, cloud, labels = plant
    res = measure_leaf_tints(cloud, labels, fits, t)
    assert res.tints.shape == (5, 3) and res.tints.dtype == np.float32
    assert (res.samples > 500).all()
    np.testing.assert_allclose(res.tints, GAINS, rtol=0.04)


def test_tints_need_enough_gaussians(plant):
    t, fits, cloud, labels = plant
    lab = labels.copy()
    lab[lab == fits.leaf_labels[2]] = 0          # leaf 3 has no Gaussians left
    res = measure_leaf_tints(cloud, lab, fits, t)
    assert np.array_equal(res.tints[2], [1, 1, 1]) and res.samples[2] == 0
    with pytest.raises(ValueError):
        measure_leaf_tints(cloud, labels[:-1], fits, t)


def test_delta_e_drops_with_the_tint(plant):
    """The asset leaf with its tint matches the input leaf's colour; without it, it does not."""
    from leaffit_usd.usd.assemble import asset_from_results

    t, fits, cloud_w, labels = plant
    fr = syn.frame()
    a = asset_from_results(t, fits, syn.stem(), fr, up_axis="Y")
    a.tints = GAINS.astype(np.float32)
    W = fr.working_to_input
    s = float(np.cbrt(np.linalg.det(W[:3, :3])))
    cloud_in = GaussianCloud.from_activated(
        np.asarray(cloud_w.means, np.float64) @ W[:3, :3].T + W[:3, 3], np.full((len(cloud_w), 3), 0.004 * s),
        np.tile([1.0, 0, 0, 0], (len(cloud_w), 1)), np.full(len(cloud_w), 0.95), colors=cloud_w.colors)
    with_tint = leaf_color_errors(a, t.front_texture, cloud_in, labels, tinted=True, res=96)
    without = leaf_color_errors(a, t.front_texture, cloud_in, labels, tinted=False, res=96)
    assert np.isfinite(with_tint).all() and np.isfinite(without).all()
    # the splat and mesh renders differ at the rim and where the two layers mix: ~2-5 ΔE of
    # rendering noise per leaf; the gains of 0.5-0.8 make 10-30 ΔE without the tint
    off = np.abs(GAINS - 1).max(1) > 0.2
    assert np.median(with_tint) < 3.0, (with_tint, without)
    assert (without[off] > 8).all() and (without[off] > 2 * with_tint[off]).all(), (with_tint, without)
    assert abs(without[1] - with_tint[1]) < 0.5   # leaf 2 has gain 1: the tint changes nothing


def test_lab_reference_values():
    """CIELAB of sRGB primaries (D65), and ΔE between white and black = 100."""
    np.testing.assert_allclose(linear_to_lab(np.array([1.0, 1, 1])), [100, 0, 0], atol=1e-3)
    np.testing.assert_allclose(linear_to_lab(np.array([1.0, 0, 0])), [53.24, 80.09, 67.20], atol=0.05)
    assert delta_e76(np.ones(3), np.zeros(3)) == pytest.approx(100, abs=1e-4)
