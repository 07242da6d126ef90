"""Shared synthetic inputs for the mesh tests (small, so the whole area runs in seconds)."""
import pytest

from samples.synthetic.mesh import synthetic_leaf, synthetic_tree

# tolerances in one place (relative to the leaf length)
SHEET_MEAN_DIST_REL = 0.01
SHEET_MAX_DIST_REL = 0.03


@pytest.fixture(scope="session")
def leaf():
    """(cloud_working, fits) of a two-sided curved leaf of 3,000 Gaussians."""
    return synthetic_leaf(3000, seed=1)


@pytest.fixture(scope="session")
def leaf_mesh(leaf):
    from leaffit_usd.mesh.template import MeshParams, build_template_mesh

    cloud, fits = leaf
    return build_template_mesh(cloud, fits, MeshParams(vertex_budget=800, texture_size=128))


@pytest.fixture(scope="session")
def tree():
    return synthetic_tree(n_branches=3, leaves_per_branch=2)
