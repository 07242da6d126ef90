"""The template's texture chart (leaffit_usd.mesh.uv_chart): planar and envelope charts."""
import numpy as np
import pytest

from leaffit_usd.mesh.uv_chart import envelope_chart, planar_chart, rasterize_polygon


def _heart(n=400):
    """A cordate outline (template frame: base near the origin, apex at +x), lobes behind the base."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1 - np.cos(t)
    return np.c_[-(r * np.cos(t)), 0.8 * r * np.sin(t)]


def _lanceolate(n=400):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[np.cos(t) + 1, 0.15 * np.sin(t) * (1 + 0.6 * np.cos(t))]


@pytest.mark.parametrize("shape", [_heart, _lanceolate])
def test_envelope_chart_fills_the_texture(shape):
    """The leaf covers more of the texture than with the planar chart, and at least 80 %."""
    poly = shape()
    env = envelope_chart(poly, 1024, 0.01)
    flat = planar_chart(poly, 1024, 0.01)
    cover = rasterize_polygon(env.polygon(poly, 1024), 512, 512, env.bounds).mean()
    cover_flat = rasterize_polygon(flat.polygon(poly, 1024), 512, 512, flat.bounds).mean()
    assert env.kind == "envelope" and flat.kind == "planar"
    assert cover > 0.8 and cover > cover_flat + 0.05, (cover, cover_flat)
    uv = env.uv(poly)
    assert uv.min() >= 0 and uv.max() <= 1


def test_envelope_chart_is_smooth_and_keeps_the_axis():
    """u follows x exactly (base -> apex), v is monotonic in y in every column, and the map's
    Jacobian (used to carry the Gaussians) matches finite differences."""
    poly = _heart()
    ch = envelope_chart(poly, 1024, 0.01)
    rng = np.random.default_rng(0)
    xy = np.c_[rng.uniform(-0.2, 1.9, 200), rng.uniform(-0.9, 0.9, 200)]
    uv = ch.uv(xy)
    b = ch.bounds
    assert np.allclose(uv[:, 0], (xy[:, 0] - b[0]) / (b[1] - b[0]))
    up = ch.uv(xy + [0, 1e-4])
    assert (up[:, 1] > uv[:, 1]).all()
    means = np.c_[xy, rng.normal(0, 0.01, 200)]
    cov = np.tile(np.eye(3) * 1e-4, (200, 1, 1))
    m2, c2 = ch.gaussians(means, cov)
    assert np.allclose(m2[:, :2], ch.to_chart(xy)) and np.allclose(m2[:, 2], means[:, 2])
    eps = 1e-6
    J = np.stack([(ch.to_chart(xy + [eps, 0]) - ch.to_chart(xy - [eps, 0])) / (2 * eps),
                  (ch.to_chart(xy + [0, eps]) - ch.to_chart(xy - [0, eps])) / (2 * eps)], 2)
    assert np.allclose(c2[:, :2, :2], 1e-4 * J @ J.transpose(0, 2, 1), rtol=1e-3, atol=1e-9)


def test_degenerate_outline_falls_back_to_planar():
    ch = envelope_chart(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]), 256, 0.01)
    assert ch.kind == "planar"
