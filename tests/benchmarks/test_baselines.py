"""Benchmark baselines (NR-ICP via trimesh, CPD via pycpd): they run and move towards the target."""
import numpy as np
import pytest

from benchmarks.baselines.registration import cpd_baseline, nricp_baseline, pca_baseline
from samples.synthetic.fit import leaf_sheet
from leaffit_usd.metrics.deformation import mesh_metrics


@pytest.fixture(scope="module")
def pair():
    src_v, f = leaf_sheet(length=0.2, width=0.08, bend=0.0, curl=0.0, twist=0.0, nu=14, nv=7)
    tgt_v, _ = leaf_sheet(length=0.2, width=0.08, bend=0.2, curl=0.5, twist=0.4, nu=14, nv=7)
    rng = np.random.default_rng(0)
    src_pts, _ = leaf_sheet(length=0.2, width=0.08, bend=0.0, curl=0.0, twist=0.0, nu=30, nv=12)
    tgt_pts, _ = leaf_sheet(length=0.2, width=0.08, bend=0.2, curl=0.5, twist=0.4, nu=30, nv=12)
    return src_v, f, tgt_v, src_pts, tgt_pts + rng.normal(0, 1e-4, tgt_pts.shape)


def _trim(v, f, nu, nv):
    """Drop the first and last rows of a leaf_sheet grid (zero width: duplicate vertices)."""
    keep = np.arange(nv, (nu - 1) * nv)
    remap = -np.ones(len(v), int)
    remap[keep] = np.arange(len(keep))
    ff = remap[f]
    return v[keep], ff[(ff >= 0).all(1)]


def test_baselines_improve_on_pca(pair):
    src_v, f, tgt_v, src_pts, tgt_pts = pair
    src_v, f2 = _trim(src_v, f, 14, 7)
    tgt_v, _ = _trim(tgt_v, f, 14, 7)
    f = f2
    pca = mesh_metrics(pca_baseline(src_v), f, tgt_v, f, n=3000)
    nr = mesh_metrics(nricp_baseline(src_v, f, tgt_pts), f, tgt_v, f, n=3000)
    cpd = mesh_metrics(cpd_baseline(src_pts, tgt_pts, src_v, max_points=200), f, tgt_v, f, n=3000)
    assert nr.corr < 0.5 * pca.corr
    assert cpd.corr < 0.5 * pca.corr
    assert np.isfinite([nr.hd, cpd.hd]).all()


def test_nricp_singular_input_falls_back():
    v, f = leaf_sheet(nu=6, nv=5)                  # duplicate vertices at base and apex
    out = nricp_baseline(v, f, v + 0.01)
    assert out.shape == v.shape and np.isfinite(out).all()
